"""The ``urban`` preset: textured ground and road, buildings, poles, parked cars and moving vehicles."""

from __future__ import annotations

import numpy as np

from ..world import WorldArea, WorldParts, WorldSpec, along_path, distance_to_path, texture


def build(spec: WorldSpec, area: WorldArea, rng: np.random.Generator) -> WorldParts:
    """Assets and geoms of a street along ``area.path_xy``; vehicles drive the oncoming lane of the driven path."""
    parts = WorldParts()
    assets, bodies = parts.assets, parts.bodies
    moving_paths, moving_headings = parts.moving_paths, parts.moving_headings
    path_xy, centre, half = area.path_xy, area.centre, area.half
    assets += [
        texture("ground", "checker", "0.55 0.53 0.48", "0.68 0.66 0.60", 512, 0.08),
        texture("road", "checker", "0.30 0.30 0.31", "0.36 0.36 0.37", 512, 0.05),
        texture("facade", "checker", "0.55 0.45 0.38", "0.25 0.28 0.33", 256, 0.02, "edge"),
        texture("facade2", "checker", "0.70 0.68 0.60", "0.30 0.30 0.35", 256, 0.03, "cross"),
        texture("car", "gradient", "0.6 0.1 0.1", "0.15 0.15 0.2", 64, 0.0, "none"),
        '<material name="ground" texture="ground" texrepeat="120 120" texuniform="false"/>',
        '<material name="road" texture="road" texrepeat="1 40"/>',
        '<material name="facade" texture="facade" texrepeat="4 6"/>',
        '<material name="facade2" texture="facade2" texrepeat="6 8"/>',
        '<material name="car" texture="car" rgba="1 1 1 1"/>',
        '<material name="pole" rgba="0.2 0.2 0.22 1"/>',
        '<material name="plain" rgba="0.62 0.62 0.60 1"/>',
    ]
    ground = (
        f'<geom name="ground" type="plane" pos="{centre[0]} {centre[1]} 0" size="{half[0]} {half[1]} 0.1" material="ground"/>'
    )
    bodies.append(ground)
    # the road: thin boxes along the path
    points, tangents = along_path(path_xy, 6.0)
    for p, t in zip(points, tangents, strict=True):
        yaw = np.degrees(np.arctan2(t[1], t[0]))
        bodies.append(
            f'<geom type="box" pos="{p[0]:.3f} {p[1]:.3f} 0.005" euler="0 0 {yaw:.3f}" size="3.4 3.6 0.005" material="road"/>'
        )
    # buildings, poles and parked cars on both sides
    for p, t in zip(*along_path(path_xy, 11.0), strict=True):
        normal = np.array([-t[1], t[0]])
        for side in (-1.0, 1.0):
            if rng.random() < 0.2:
                continue
            depth, width, height = rng.uniform(5, 12), rng.uniform(6, 10), rng.uniform(6, 25)
            c = p + side * normal * (9.0 + depth / 2 + rng.uniform(0, 3))
            if distance_to_path(c[None], path_xy)[0] < spec.clearance + depth / 2 + 3.0:
                continue
            yaw = np.degrees(np.arctan2(t[1], t[0]))
            mat = "facade" if rng.random() < 0.5 else "facade2"
            if rng.random() < spec.texture_poor:
                mat = "plain"
            bodies.append(
                f'<geom type="box" pos="{c[0]:.3f} {c[1]:.3f} {height / 2:.3f}" euler="0 0 {yaw:.2f}" '
                f'size="{width / 2:.3f} {depth / 2:.3f} {height / 2:.3f}" material="{mat}"/>'
            )
    for p, t in zip(*along_path(path_xy, 23.0), strict=True):
        normal = np.array([-t[1], t[0]])
        side = 1.0 if rng.random() < 0.5 else -1.0
        q = p + side * normal * 5.5
        if distance_to_path(q[None], path_xy)[0] >= spec.clearance + 1.0:
            bodies.append(f'<geom type="cylinder" pos="{q[0]:.3f} {q[1]:.3f} 3" size="0.12 3" material="pole"/>')
        if rng.random() < 0.6:
            car = p + rng.uniform(-4, 4) * t - side * normal * 4.2
            if distance_to_path(car[None], path_xy)[0] >= spec.clearance:
                yaw = np.degrees(np.arctan2(t[1], t[0]))
                bodies.append(
                    f'<geom type="box" pos="{car[0]:.3f} {car[1]:.3f} 0.75" euler="0 0 {yaw:.2f}" '
                    'size="2.2 0.9 0.75" material="car"/>'
                )
    # moving vehicles: drive the path in the oncoming lane, offset in time
    path_xy = area.driven_xy  # vehicles follow the driven part
    n = len(path_xy)
    for j in range(spec.moving_vehicles):
        offset = int(rng.integers(n // 4, max(n // 4 + 1, n)))
        idx = (offset - np.arange(n)) % n
        tang = np.gradient(path_xy, axis=0)[idx]
        tang /= np.maximum(np.linalg.norm(tang, axis=1, keepdims=True), 1e-9)
        normal = np.stack([-tang[:, 1], tang[:, 0]], axis=1)
        xy = path_xy[idx] - normal * 3.5
        moving_paths.append(np.column_stack([xy, np.full(n, 0.8)]))
        moving_headings.append(np.arctan2(-tang[:, 1], -tang[:, 0]))
        bodies.append(
            f'<body name="vehicle{j}" mocap="true">'
            '<geom type="box" size="2.2 0.9 0.8" material="car" contype="0" conaffinity="0"/></body>'
        )
    return parts
