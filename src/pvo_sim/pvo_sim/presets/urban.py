"""The ``urban`` preset: a street along the path — asphalt with lane markings, kerbs and pavements, grass
verges, façades with storeys of windows, trees and hedges, street lamps, signs, benches and bins, parked
cars of several body types and colours, and vehicles driving the oncoming lane.

Cross-section, metres from the driven path (positive: right of the direction of travel): the camera's lane
[-1.75, 1.75], the oncoming lane [-5.25, -1.75], parking lanes [1.75, 4.0] and [-7.5, -5.25], pavements out
to 7 and -10.5, then verges, hedges and buildings.
"""

from __future__ import annotations

import numpy as np

from .. import shapes, textures
from ..world import (
    WorldArea,
    WorldParts,
    WorldSpec,
    along_path,
    distance_to_path,
    image_material,
    points_on_path,
    steady_directions,
)

ROAD_CENTRE = -1.75  # the road's centre line, right of the path is positive
ROAD_HALF_WIDTH = 5.75
PAVEMENT = ((4.0, 7.0), (-10.5, -7.5))
SEGMENT = 6.0  # m of road per box
FACADE_POOL = 8


def _materials(parts: WorldParts, spec: WorldSpec, rng: np.random.Generator) -> list[textures.FacadeLayout]:
    """The world's textures and materials, each drawn from ``rng``; the façade layouts in the pool."""
    add = image_material
    add(parts, "road", _road_tile(rng))
    add(parts, "pavement", textures.pavement(rng, 256, 3.0), extra='specular="0.1"')
    add(parts, "grass", textures.grass(rng, 256, 4.0), "0.25 0.25", uniform=True)
    add(parts, "foliage", textures.foliage(rng), extra='specular="0"')
    add(parts, "hedge", textures.foliage(rng), "0.8 0.8", uniform=True, extra='specular="0"')
    add(parts, "bark", textures.bark(rng))
    layouts = []
    for i in range(FACADE_POOL):
        layout = textures.FacadeLayout(int(rng.integers(2, 6)), int(rng.integers(1, 7)), bay_width=float(rng.uniform(2.6, 3.8)))
        add(parts, f"facade{i}", textures.facade(rng, layout), extra='specular="0.05"')
        layouts.append(layout)
    parts.assets += [
        '<material name="plain" rgba="0.72 0.71 0.68 1" specular="0.05"/>',
        '<material name="kerb" rgba="0.58 0.57 0.55 1"/>',
        '<material name="metal" rgba="0.30 0.31 0.33 1" specular="0.3"/>',
        '<material name="wood" rgba="0.45 0.32 0.2 1"/>',
        '<material name="glass" rgba="0.10 0.12 0.15 1" specular="0.6" shininess="0.8" reflectance="0"/>',
        '<material name="tyre" rgba="0.06 0.06 0.06 1"/>',
    ]
    for i, colour in enumerate(shapes.CAR_COLOURS):
        parts.assets.append(
            f'<material name="paint{i}" rgba="{colour[0]} {colour[1]} {colour[2]} 1" specular="0.5" shininess="0.6"/>'
        )
    return layouts


def _road_tile(rng: np.random.Generator) -> np.ndarray:
    """Asphalt for one road box: its full length (with the overlap) along, its width across."""
    return textures.asphalt(rng, SEGMENT + 0.4, 2 * ROAD_HALF_WIDTH)


def _placed(x: float, y: float, yaw: float, inner: str, name: str = "") -> str:
    named = f' name="{name}"' if name else ""
    return f'<body{named} pos="{x:.3f} {y:.3f} 0" euler="0 0 {np.degrees(yaw):.2f}">{inner}</body>'


def build(spec: WorldSpec, area: WorldArea, rng: np.random.Generator) -> WorldParts:
    """Assets and geoms of a street along ``area.path_xy``; vehicles drive the oncoming lane of the driven path."""
    parts = WorldParts()
    bodies = parts.bodies
    layouts = _materials(parts, spec, rng)
    path_xy, centre, half = area.path_xy, area.centre, area.half
    # MuJoCo draws a plane as a grid of this spacing (m), every pass: 0.1 m made it the costliest geom of the
    # scene (a quarter of the render time) while a flat plane under a directional light shades the same on any grid
    bodies.append(
        f'<geom name="ground" type="plane" pos="{centre[0]} {centre[1]} 0" size="{half[0]} {half[1]} 10" material="grass"/>'
    )

    def clear(point: np.ndarray, margin: float) -> bool:
        return bool(distance_to_path(point[None], path_xy)[0] >= margin)

    # road and pavements: boxes along the path; neighbours alternate by 1 mm in height so overlaps never z-fight
    points, tangents = along_path(path_xy, SEGMENT)
    for i, (p, t) in enumerate(zip(points, tangents, strict=True)):
        right = np.array([t[1], -t[0]])
        yaw = np.degrees(np.arctan2(t[1], t[0]))
        c = p + ROAD_CENTRE * right
        top = 0.010 - 0.001 * (i % 2)
        bodies.append(
            f'<geom type="box" pos="{c[0]:.3f} {c[1]:.3f} {top / 2:.4f}" euler="0 0 {yaw:.3f}" '
            f'size="{SEGMENT / 2 + 0.2:.3f} {ROAD_HALF_WIDTH:.3f} {top / 2:.4f}" material="road"/>'
        )
        for lo, hi in PAVEMENT:
            c = p + 0.5 * (lo + hi) * right
            bodies.append(
                f'<geom type="box" pos="{c[0]:.3f} {c[1]:.3f} {0.06 + 0.0005 * (i % 2):.4f}" euler="0 0 {yaw:.3f}" '
                f'size="{SEGMENT / 2 + 0.2:.3f} {(hi - lo) / 2:.3f} 0.06" material="pavement"/>'
            )
    # buildings on both sides, their fronts 1.5-4 m behind the pavement, heights from the façade layout
    for p, t in zip(*along_path(path_xy, 13.0), strict=True):
        right = np.array([t[1], -t[0]])
        yaw = float(np.arctan2(t[1], t[0]))
        for side, kerb in ((1.0, PAVEMENT[0][1]), (-1.0, -PAVEMENT[1][0])):
            if rng.random() < 0.15:
                continue
            which = int(rng.integers(len(layouts)))
            layout = layouts[which]
            depth = rng.uniform(6, 12)
            c = p + side * right * (kerb + rng.uniform(1.5, 4.0) + depth / 2)
            if not clear(c, spec.clearance + depth / 2 + 3.0):
                continue
            material = "plain" if rng.random() < spec.texture_poor else f"facade{which}"
            # the box's x axis runs along the street, so both long faces show the whole façade
            bodies.append(
                f'<geom type="box" pos="{c[0]:.3f} {c[1]:.3f} {layout.height_m / 2:.3f}" euler="0 0 {np.degrees(yaw):.2f}" '
                f'size="{layout.width_m / 2:.3f} {depth / 2:.3f} {layout.height_m / 2:.3f}" material="{material}"/>'
            )
    # verge: trees and hedges between pavement and buildings; street furniture on the pavements
    for p, t in zip(*along_path(path_xy, 9.0), strict=True):
        right = np.array([t[1], -t[0]])
        yaw = float(np.arctan2(t[1], t[0]))
        for side, kerb in ((1.0, PAVEMENT[0][1]), (-1.0, -PAVEMENT[1][0])):
            draw = rng.random()
            q = p + rng.uniform(-3, 3) * t + side * right * (kerb + rng.uniform(0.6, 1.2))
            if draw < 0.35 and clear(q, spec.clearance + 1.0):
                bodies.append(_placed(q[0], q[1], yaw, shapes.tree(rng, "foliage")))
            elif draw < 0.55 and clear(q, spec.clearance + 1.0):
                length = rng.uniform(2.0, 6.0)
                height = rng.uniform(0.7, 1.4)
                bodies.append(
                    f'<geom type="box" pos="{q[0]:.3f} {q[1]:.3f} {height / 2:.3f}" euler="0 0 {np.degrees(yaw):.2f}" '
                    f'size="{length / 2:.3f} 0.45 {height / 2:.3f}" material="hedge"/>'
                )
    for p, t in zip(*along_path(path_xy, 25.0), strict=True):
        right = np.array([t[1], -t[0]])
        yaw = float(np.arctan2(t[1], t[0]))
        side = 1.0 if rng.random() < 0.5 else -1.0
        kerb = PAVEMENT[0][0] if side > 0 else -PAVEMENT[1][1]
        q = p + side * right * (kerb + 0.4)
        if clear(q, spec.clearance + 0.5):
            # the lamp's arm (local -y) reaches over the road
            bodies.append(_placed(q[0], q[1], yaw + (0.0 if side > 0 else np.pi), shapes.street_lamp(rng.uniform(5.5, 7.5))))
        extra = p + rng.uniform(-8, 8) * t + side * right * (kerb + rng.uniform(1.0, 2.6))
        if clear(extra, spec.clearance + 1.0):
            kind = rng.random()
            inner = shapes.sign(rng) if kind < 0.4 else shapes.bench() if kind < 0.7 else shapes.bin_()
            bodies.append(_placed(extra[0], extra[1], yaw + (np.pi / 2 if side > 0 else -np.pi / 2), inner))
    # parked cars in both parking lanes
    kinds = list(shapes.VEHICLE_TYPES)
    for p, t in zip(*along_path(path_xy, 6.5), strict=True):
        right = np.array([t[1], -t[0]])
        yaw = float(np.arctan2(t[1], t[0]))
        for offset in (2.9, -6.4):
            if rng.random() > 0.45:
                continue
            car = p + rng.uniform(-0.8, 0.8) * t + offset * right
            if clear(car, min(abs(offset), spec.clearance) - 0.1):
                inner = shapes.vehicle(kinds[int(rng.integers(len(kinds)))], f"paint{int(rng.integers(len(shapes.CAR_COLOURS)))}")
                bodies.append(_placed(car[0], car[1], yaw + (np.pi if rng.random() < 0.2 else 0.0), inner))
    # moving vehicles in the oncoming lane: each drives the driven path backwards, offset in time (so at the
    # camera's speed of another moment), or with ``vehicle_speed`` the extended path at its own speed
    driven = area.driven_xy
    n = len(driven)
    path_length = float(np.linalg.norm(np.diff(area.path_xy, axis=0), axis=1).sum())
    for j in range(spec.moving_vehicles):
        if spec.vehicle_speed > 0.0:
            speed = spec.vehicle_speed * float(rng.uniform(0.7, 1.3))
            start = float(rng.uniform(0.0, path_length))
            # towards the path's start, round again from its far end: 80 m beyond the driven path at either end
            arc = (start - speed * spec.frame_interval * np.arange(n)) % path_length
            along, tang = points_on_path(area.path_xy, arc)
        else:
            offset = int(rng.integers(n // 4, max(n // 4 + 1, n)))
            idx = (offset - np.arange(n)) % n
            along = driven[idx]
            tang = steady_directions(driven, area.driven_heading)[idx]
        right = np.stack([tang[:, 1], -tang[:, 0]], axis=1)
        xy = along + right * (2 * ROAD_CENTRE)
        parts.moving_paths.append(np.column_stack([xy, np.zeros(n)]))
        parts.moving_headings.append(np.arctan2(-tang[:, 1], -tang[:, 0]))
        kind = kinds[int(rng.integers(len(kinds)))]
        paint = f"paint{int(rng.integers(len(shapes.CAR_COLOURS)))}"
        bodies.append(f'<body name="vehicle{j}" mocap="true">{shapes.vehicle(kind, paint, collide=False)}</body>')
    return parts
