"""The ``planetary`` preset: a rover site — terrain rough at several scales with a driveable corridor,
regolith strewn with pebbles (texture) and gravel, irregular rocks and outcrops (noise-displaced meshes);
no man-made structure."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from .. import shapes, textures
from ..world import WorldArea, WorldParts, WorldSpec, along_path, distance_to_path, image_material

Array = NDArray[np.float64]
ROCK_SHAPES = 10
RELIEF = 8.0  # m from the lowest to the highest terrain sample
HUMMOCKS = 1.8  # m: the relief of the rough terrain near the path; beyond, valley sides rise to RELIEF


def build(spec: WorldSpec, area: WorldArea, rng: np.random.Generator) -> WorldParts:
    """Terrain heights, gravel, rocks and outcrops around ``area.path_xy``."""
    parts = WorldParts()
    assets, bodies = parts.assets, parts.bodies
    path_xy, lo, hi, _centre, half = area.path_xy, area.lo, area.hi, area.centre, area.half
    tile = 4.0  # m per regolith texture tile (256 px/m: sharp at the 2-5 m where a rover camera sees the ground)
    image_material(parts, "regolith", textures.regolith(rng, 1024, tile), f"{1 / tile:.4f} {1 / tile:.4f}", uniform=True)
    image_material(parts, "rock", textures.rock(rng), extra='specular="0.05"')
    for i in range(ROCK_SHAPES):
        scale = np.array([1.0, rng.uniform(0.6, 1.0), rng.uniform(0.35, 0.8)])
        assets += shapes.rock_meshes(rng, f"rock{i}", scale, SIZE_CLASSES, roughness=rng.uniform(0.08, 0.22))
    rows = int(np.ceil(2 * half[1] / spec.terrain_resolution)) + 1
    cols = int(np.ceil(2 * half[0] / spec.terrain_resolution)) + 1
    hfield = _terrain(rows, cols, rng)
    # flatten a corridor along the path so the rig's height above ground stays as given; keep fine roughness
    dist = _corridor_distance(path_xy, lo, hi, rows, cols)
    blend = np.clip((dist - 2.5) / 12.0, 0.0, 1.0) ** 1.5
    fine = 0.02 * (rng.random((rows, cols)) - 0.5) / RELIEF  # ±1 cm bumps everywhere, the corridor too
    valley = np.clip((dist - 25.0) / 60.0, 0.0, 1.0) ** 2 * (0.5 + 0.5 * _terrain(rows, cols, rng))  # sides, far off
    hfield = hfield * blend * (HUMMOCKS / RELIEF) + valley * (1.0 - HUMMOCKS / RELIEF - 0.01)
    hfield = np.clip(hfield + fine * (1.0 - blend) + 0.01, 0.0, 1.0)
    # the corridor sits at height 0.01 * RELIEF: lower the terrain so the corridor is at z = 0
    _tiles(parts, hfield, lo, hi, -0.01 * RELIEF)

    def ground(q: Array) -> float:
        j = int(np.clip(round((q[0] - lo[0]) / (hi[0] - lo[0]) * (cols - 1)), 0, cols - 1))
        i = int(np.clip(round((q[1] - lo[1]) / (hi[1] - lo[1]) * (rows - 1)), 0, rows - 1))
        return float(hfield[i, j] * RELIEF - 0.01 * RELIEF)

    def rock(q: Array, size: float) -> str:
        shape = int(rng.integers(ROCK_SHAPES))
        yaw, tilt = rng.uniform(0, 360), rng.normal(0, 8, 2)
        z = ground(q) + 0.1 * size
        return (
            f'<body pos="{q[0]:.3f} {q[1]:.3f} {z:.3f}" euler="{tilt[0]:.1f} {tilt[1]:.1f} {yaw:.1f}">'
            f'<geom type="mesh" mesh="rock{shape}_{_size_class(size)}" material="rock"/></body>'
        )

    # gravel and rocks: sizes from a power law, most near the ground the camera sees
    for p, _ in zip(*along_path(path_xy, 2.0), strict=True):
        for _ in range(rng.poisson(spec.gravel)):
            q = p + rng.normal(0, 8.0, 2)
            size = float(np.clip(0.08 * (1.0 - rng.random()) ** (-1 / 1.2), 0.08, 1.6))
            # gravel may lie close to the path (the cameras pass over it); rocks keep the clearance
            margin = 1.0 if size < 0.25 else spec.clearance + size
            if distance_to_path(q[None], path_xy)[0] < margin:
                continue
            bodies.append(rock(q, size))
    # outcrops: clusters of large rocks away from the path
    for p, _ in zip(*along_path(path_xy, 25.0), strict=True):
        if rng.random() < 0.5:
            continue
        c = p + rng.normal(0, 18.0, 2)
        if distance_to_path(c[None], path_xy)[0] < spec.clearance + 6.0:
            continue
        for _ in range(int(rng.integers(3, 8))):
            bodies.append(rock(c + rng.normal(0, 1.5, 2), float(rng.uniform(0.8, 2.2))))
    return parts


TILE_SAMPLES = 48  # height-field samples per terrain tile side: the renderer skips tiles out of range


def _tiles(parts: WorldParts, heights: Array, lo: Array, hi: Array, z: float) -> None:
    """The terrain as square height-field tiles that share their edge samples (no cracks)."""
    rows, cols = heights.shape
    dx, dy = (hi[0] - lo[0]) / (cols - 1), (hi[1] - lo[1]) / (rows - 1)
    for i0 in range(0, rows - 1, TILE_SAMPLES):
        for j0 in range(0, cols - 1, TILE_SAMPLES):
            i1, j1 = min(i0 + TILE_SAMPLES, rows - 1), min(j0 + TILE_SAMPLES, cols - 1)
            name = f"terrain_{i0}_{j0}"
            block = heights[i0 : i1 + 1, j0 : j1 + 1]
            cx, cy = lo[0] + 0.5 * (j0 + j1) * dx, lo[1] + 0.5 * (i0 + i1) * dy
            parts.assets.append(
                f'<hfield name="{name}" nrow="{block.shape[0]}" ncol="{block.shape[1]}" '
                f'size="{0.5 * (j1 - j0) * dx:.4f} {0.5 * (i1 - i0) * dy:.4f} {RELIEF} 0.1"/>'
            )
            parts.bodies.append(f'<geom type="hfield" hfield="{name}" pos="{cx:.4f} {cy:.4f} {z:.4f}" material="regolith"/>')
            parts.hfields[name] = block


SIZE_CLASSES = (0.1, 0.2, 0.35, 0.6, 1.0, 1.6, 2.4)


def _size_class(size: float) -> int:
    return int(np.argmin(np.abs(np.log(np.asarray(SIZE_CLASSES) / size))))


def _corridor_distance(path_xy: Array, lo: Array, hi: Array, rows: int, cols: int) -> Array:
    """Distance (m) of every height-field sample to the path: the path drawn into the grid, then a
    Euclidean distance transform (linear in the grid size)."""
    import cv2

    scale = np.array([(cols - 1) / (hi[0] - lo[0]), (rows - 1) / (hi[1] - lo[1])])
    pixels = np.round((path_xy - lo) * scale).astype(np.int32)
    free = np.full((rows, cols), 255, dtype=np.uint8)
    cv2.polylines(free, [pixels.reshape(-1, 1, 2)], isClosed=False, color=0, thickness=1)
    return cv2.distanceTransform(free, cv2.DIST_L2, 5) / float(scale.mean())


def _terrain(rows: int, cols: int, rng: np.random.Generator) -> Array:
    """Rough terrain heights in [0, 1]: value-noise octaves from ~64 samples down to 2 (hills to hummocks)."""
    heights = textures.fractal_noise(rng, rows, cols, (64.0, 24.0, 9.0, 3.5, 1.5), gain=0.45).astype(np.float64)
    heights -= heights.min()
    return heights / max(float(heights.max()), 1e-9)
