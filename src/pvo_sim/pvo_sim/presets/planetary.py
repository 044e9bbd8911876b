"""The ``planetary`` preset: rough height-field terrain with a flattened corridor and rocks, no man-made structure."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from ..world import WorldArea, WorldParts, WorldSpec, along_path, distance_to_path, texture

Array = NDArray[np.float64]


def build(spec: WorldSpec, area: WorldArea, rng: np.random.Generator) -> WorldParts:
    """Terrain heights and rocks around ``area.path_xy``."""
    parts = WorldParts()
    assets, bodies = parts.assets, parts.bodies
    path_xy, lo, hi, centre, half = area.path_xy, area.lo, area.hi, area.centre, area.half
    assets += [
        texture("regolith", "checker", "0.62 0.52 0.42", "0.70 0.60 0.48", 512, 0.25),
        texture("rock", "gradient", "0.35 0.32 0.30", "0.55 0.50 0.45", 64, 0.0, "none"),
        '<material name="regolith" texture="regolith" texrepeat="60 60"/>',
        '<material name="rock" texture="rock"/>',
    ]
    rows = int(np.ceil(2 * half[1] / spec.terrain_resolution)) + 1
    cols = int(np.ceil(2 * half[0] / spec.terrain_resolution)) + 1
    hfield = _terrain(rows, cols, rng)
    # flatten a corridor along the path so the rig's height above ground stays as given
    dist = _corridor_distance(path_xy, lo, hi, rows, cols)
    blend = np.clip((dist - 3.0) / 6.0, 0.0, 1.0)
    hfield = hfield * blend
    relief = 2.5
    assets.append(f'<hfield name="terrain" nrow="{rows}" ncol="{cols}" size="{half[0]} {half[1]} {relief} 0.1"/>')
    bodies.append(f'<geom type="hfield" hfield="terrain" pos="{centre[0]} {centre[1]} 0" material="regolith"/>')
    for p, _ in zip(*along_path(path_xy, 4.0), strict=True):
        for _ in range(rng.poisson(2.0)):
            q = p + rng.normal(0, 12.0, 2)
            if distance_to_path(q[None], path_xy)[0] < spec.clearance + 1.0:
                continue
            r = rng.uniform(0.15, 1.2, 3)
            bodies.append(
                f'<geom type="ellipsoid" pos="{q[0]:.3f} {q[1]:.3f} {0.3 * r[2]:.3f}" '
                f'size="{r[0]:.3f} {r[1]:.3f} {r[2]:.3f}" '
                f'euler="0 0 {rng.uniform(0, 360):.1f}" material="rock"/>'
            )
    parts.hfield = hfield
    return parts


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
    """Rough terrain heights in [0, 1]: a sum of random smooth octaves (value noise)."""
    heights = np.zeros((rows, cols))
    for octave, amplitude in ((16, 1.0), (32, 0.45), (64, 0.2), (128, 0.08)):
        coarse = rng.random((rows // max(1, rows // octave) + 2, cols // max(1, cols // octave) + 2))
        yi = np.linspace(0, coarse.shape[0] - 1.001, rows)
        xi = np.linspace(0, coarse.shape[1] - 1.001, cols)
        y0, x0 = np.floor(yi).astype(int), np.floor(xi).astype(int)
        fy, fx = (yi - y0)[:, None], (xi - x0)[None, :]
        fy, fx = fy * fy * (3 - 2 * fy), fx * fx * (3 - 2 * fx)
        c = coarse
        v = (
            c[np.ix_(y0, x0)] * (1 - fy) * (1 - fx)
            + c[np.ix_(y0 + 1, x0)] * fy * (1 - fx)
            + c[np.ix_(y0, x0 + 1)] * (1 - fy) * fx
            + c[np.ix_(y0 + 1, x0 + 1)] * fy * fx
        )
        heights += amplitude * v
    heights -= heights.min()
    return heights / max(float(heights.max()), 1e-9)
