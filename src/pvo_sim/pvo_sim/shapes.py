"""Shaped objects for the procedural worlds: vehicles with cabins, windows and wheels, trees, street
furniture, and irregular rocks as noise-displaced meshes.

Each function returns MJCF elements in a local frame (x forward, y left, z up, origin on the ground), to
be wrapped in a ``<body pos=… euler=…>``; sizes in metres.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


@dataclass(frozen=True)
class VehicleBody:
    """Half-lengths (m) of a body type: lower body, cabin (length, width, height, x offset), wheel radius."""

    length: float
    width: float
    body_height: float
    cabin_length: float
    cabin_height: float
    cabin_offset: float
    wheel_radius: float


VEHICLE_TYPES = {
    "sedan": VehicleBody(2.30, 0.90, 0.33, 1.15, 0.36, -0.15, 0.32),
    "hatchback": VehicleBody(2.00, 0.88, 0.35, 1.15, 0.38, -0.40, 0.31),
    "suv": VehicleBody(2.35, 0.95, 0.45, 1.55, 0.42, -0.35, 0.38),
    "van": VehicleBody(2.55, 1.00, 0.55, 2.05, 0.55, -0.30, 0.36),
}

CAR_COLOURS = (
    (0.75, 0.75, 0.76),
    (0.12, 0.12, 0.13),
    (0.85, 0.85, 0.82),
    (0.55, 0.08, 0.07),
    (0.10, 0.18, 0.40),
    (0.35, 0.36, 0.38),
    (0.60, 0.58, 0.50),
    (0.15, 0.30, 0.18),
)


def vehicle(kind: str, material: str, glass: str = "glass", tyre: str = "tyre", collide: bool = True) -> str:
    """A car: lower body, a glazed cabin under a roof in the body colour, four wheels, bumpers and lights."""
    b = VEHICLE_TYPES[kind]
    flags = "" if collide else ' contype="0" conaffinity="0"'
    clearance = b.wheel_radius * 0.55
    z_body = clearance + b.body_height
    z_cabin = clearance + 2 * b.body_height + b.cabin_height
    body = f"{b.length:.3f} {b.width:.3f} {b.body_height:.3f}"
    parts = [
        f'<geom type="box" pos="0 0 {z_body:.3f}" size="{body}" material="{material}"{flags}/>',
        f'<geom type="box" pos="{b.cabin_offset:.3f} 0 {z_cabin - 0.04:.3f}" '
        f'size="{b.cabin_length:.3f} {b.width * 0.92:.3f} {b.cabin_height - 0.04:.3f}" material="{glass}"{flags}/>',
        f'<geom type="box" pos="{b.cabin_offset:.3f} 0 {z_cabin + b.cabin_height - 0.04:.3f}" '
        f'size="{b.cabin_length * 0.9:.3f} {b.width * 0.9:.3f} 0.04" material="{material}"{flags}/>',
    ]
    for sx in (-1, 1):  # bumpers, darker than the body
        parts.append(
            f'<geom type="box" pos="{sx * (b.length + 0.04):.3f} 0 {clearance + 0.18:.3f}" size="0.05 {b.width * 0.95:.3f} 0.10" '
            f'material="{tyre}"{flags}/>'
        )
    for sy in (-1, 1):  # lights: pale at the front, red at the back
        parts.append(
            f'<geom type="box" pos="{b.length + 0.01:.3f} {sy * b.width * 0.7:.3f} {z_body + 0.1:.3f}" size="0.02 0.15 0.06" '
            f'rgba="0.9 0.9 0.85 1"{flags}/>'
        )
        parts.append(
            f'<geom type="box" pos="{-b.length - 0.01:.3f} {sy * b.width * 0.7:.3f} {z_body + 0.1:.3f}" size="0.02 0.14 0.06" '
            f'rgba="0.6 0.05 0.05 1"{flags}/>'
        )
    for sx in (-1, 1):
        for sy in (-1, 1):
            x, y = sx * (b.length - b.wheel_radius - 0.35), sy * (b.width - 0.1)
            parts.append(
                f'<geom type="cylinder" pos="{x:.3f} {y:.3f} {b.wheel_radius:.3f}" size="{b.wheel_radius:.3f} 0.11" '
                f'euler="90 0 0" material="{tyre}"{flags}/>'
            )
            parts.append(
                f'<geom type="cylinder" pos="{x:.3f} {y + sy * 0.112:.3f} {b.wheel_radius:.3f}" '
                f'size="{b.wheel_radius * 0.55:.3f} 0.002" euler="90 0 0" rgba="0.6 0.6 0.62 1"{flags}/>'
            )
    return "".join(parts)


def tree(rng: np.random.Generator, foliage: str, bark: str = "bark") -> str:
    """A trunk and a crown of two to four overlapping ellipsoids."""
    height = rng.uniform(2.0, 4.0)
    radius = rng.uniform(0.10, 0.22)
    parts = [f'<geom type="cylinder" pos="0 0 {height / 2:.3f}" size="{radius:.3f} {height / 2:.3f}" material="{bark}"/>']
    crown = rng.uniform(1.2, 2.6)
    for _ in range(int(rng.integers(2, 5))):
        offset = rng.normal(0, 0.4 * crown, 2)
        size = crown * rng.uniform(0.6, 1.0, 3) * np.array([1.0, 1.0, rng.uniform(0.8, 1.4)])
        z = height + size[2] * 0.7 + rng.uniform(0, 0.6)
        parts.append(
            f'<geom type="ellipsoid" pos="{offset[0]:.3f} {offset[1]:.3f} {z:.3f}" '
            f'size="{size[0]:.3f} {size[1]:.3f} {size[2]:.3f}" material="{foliage}"/>'
        )
    return "".join(parts)


def street_lamp(height: float = 6.0) -> str:
    """A pole with an arm over the road (the road is along -y in the local frame) and a lamp head."""
    return (
        f'<geom type="cylinder" pos="0 0 {height / 2:.3f}" size="0.09 {height / 2:.3f}" material="metal"/>'
        f'<geom type="box" pos="0 -0.8 {height - 0.05:.3f}" size="0.04 0.8 0.04" material="metal"/>'
        f'<geom type="box" pos="0 -1.5 {height - 0.15:.3f}" size="0.18 0.30 0.07" material="metal"/>'
    )


def sign(rng: np.random.Generator) -> str:
    """A sign post with a round or square plate (white rim, coloured face)."""
    face = ("0.75 0.1 0.1 1", "0.1 0.25 0.65 1", "0.85 0.7 0.1 1")[int(rng.integers(3))]
    plate = (
        '<geom type="cylinder" pos="0 0 2.3" size="0.32 0.02" euler="90 0 90" rgba="0.9 0.9 0.9 1"/>'
        f'<geom type="cylinder" pos="0.021 0 2.3" size="0.26 0.002" euler="90 0 90" rgba="{face}"/>'
        if rng.random() < 0.5
        else '<geom type="box" pos="0 0 2.3" size="0.02 0.3 0.3" rgba="0.9 0.9 0.9 1"/>'
        f'<geom type="box" pos="0.021 0 2.3" size="0.002 0.25 0.25" rgba="{face}"/>'
    )
    return '<geom type="cylinder" pos="0 0 1.1" size="0.035 1.1" material="metal"/>' + plate


def bench() -> str:
    return (
        '<geom type="box" pos="0 0 0.45" size="0.9 0.22 0.03" material="wood"/>'
        '<geom type="box" pos="0 0.2 0.75" size="0.9 0.03 0.18" material="wood"/>'
        '<geom type="box" pos="-0.75 0 0.22" size="0.04 0.2 0.22" material="metal"/>'
        '<geom type="box" pos="0.75 0 0.22" size="0.04 0.2 0.22" material="metal"/>'
    )


def bin_() -> str:
    return '<geom type="cylinder" pos="0 0 0.45" size="0.28 0.45" rgba="0.15 0.3 0.2 1"/>'


def _icosphere(subdivisions: int) -> tuple[Array, NDArray[np.int64]]:
    """Unit-sphere vertices and triangles from a subdivided icosahedron."""
    t = (1.0 + 5.0**0.5) / 2.0
    vertices = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t)]
    vertices += [(t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6)]
    faces += [(7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10)]
    faces += [(8, 6, 7), (9, 8, 1)]
    verts = [np.array(v, float) / np.linalg.norm(v) for v in vertices]
    tris = [tuple(f) for f in faces]

    def midpoint(a: int, b: int, cache: dict[tuple[int, int], int]) -> int:
        key = (min(a, b), max(a, b))
        if key not in cache:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            cache[key] = len(verts) - 1
        return cache[key]

    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}
        new = []
        for a, b, c in tris:
            ab, bc, ca = midpoint(a, b, cache), midpoint(b, c, cache), midpoint(c, a, cache)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        tris = new
    return np.array(verts), np.array(tris, dtype=np.int64)


def rock_meshes(
    rng: np.random.Generator, name: str, scale: Array, sizes: tuple[float, ...], roughness: float = 0.25, subdivisions: int = 1
) -> list[str]:
    """An irregular rock as mesh assets ``{name}_{k}``, one per entry of ``sizes`` (MuJoCo scales meshes per
    asset, not per geom): an icosphere displaced along its normals by smooth random lobes plus finer bumps,
    flattened at the base (sunk into the ground by the caller), with spherical texture coordinates."""
    verts, tris = _icosphere(subdivisions)
    lobes = rng.normal(0, 1, (6, 3))
    lobes /= np.linalg.norm(lobes, axis=1, keepdims=True)
    radius = np.ones(len(verts))
    for lobe, amplitude in zip(lobes, rng.uniform(0.1, 0.35, len(lobes)), strict=True):
        radius += amplitude * np.maximum(verts @ lobe, 0.0) ** 2
    radius += roughness * rng.uniform(-1.0, 1.0, len(verts))  # facets: angular, broken faces
    points = verts * radius[:, None] * np.asarray(scale)[None, :]
    points[:, 2] = np.maximum(points[:, 2], -0.3 * scale[2])  # a flat underside
    u = 0.5 + np.arctan2(verts[:, 1], verts[:, 0]) / (2 * np.pi)
    v = 0.5 + np.arcsin(np.clip(verts[:, 2], -1, 1)) / np.pi
    vertex = " ".join(f"{x:.4f}" for x in points.reshape(-1))
    face = " ".join(str(i) for i in tris.reshape(-1))
    texcoord = " ".join(f"{x:.4f}" for x in np.column_stack([u, v]).reshape(-1))
    return [
        f'<mesh name="{name}_{k}" scale="{s} {s} {s}" vertex="{vertex}" face="{face}" texcoord="{texcoord}"/>'
        for k, s in enumerate(sizes)
    ]
