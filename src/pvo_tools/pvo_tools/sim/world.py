"""Procedural worlds as MuJoCo models (MJCF), generated along the camera path.

Presets: ``urban`` (textured ground and road, buildings, poles, parked and moving vehicles) and
``planetary`` (rough height-field terrain and rocks, no man-made structure). Every object is placed
from a seeded generator along the path (cost linear in the path length); nothing is placed within
``clearance`` metres of the path so the rig never drives through geometry. The rig is a mocap body
carrying the left and right cameras (MuJoCo cameras look along their -z with y up, so the body's
axes are the optical axes with y and z flipped); the sun is a directional light.
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
PRESETS = ("urban", "planetary")
MOVING_VEHICLES = 3


@dataclass(frozen=True)
class WorldSpec:
    preset: str = "urban"
    seed: int = 0
    baseline: float = 0.54
    fovy_deg: float = 35.0
    overcast: bool = False
    clearance: float = 3.0
    terrain_resolution: float = 2.0  # planetary: metres per height-field sample
    shadow_map: int = 1024  # texels; the map covers 60 m around the camera
    image_size: tuple[int, int] = (640, 480)  # the offscreen framebuffer must hold the images
    texture_poor: float = 0.0  # fraction of buildings with plain walls
    moving_vehicles: int = MOVING_VEHICLES


@dataclass
class World:
    xml: str
    hfield: Array | None  # planetary: (rows, cols) heights in [0, 1] to copy into the model
    moving_paths: list[Array]  # per moving vehicle: (N, 3) positions per frame
    moving_headings: list[Array]
    extent: float


def _texture(name: str, builtin: str, rgb1: str, rgb2: str, size: int, random: float, mark: str = "random") -> str:
    return (
        f'<texture name="{name}" type="2d" builtin="{builtin}" rgb1="{rgb1}" rgb2="{rgb2}" width="{size}" height="{size}" '
        f'mark="{mark}" random="{random}" markrgb="0.95 0.95 0.9"/>'
    )


def _distance_to_path(points: Array, path_xy: Array) -> Array:
    """Horizontal distance of each point (M, 2) to the polyline of path samples (N, 2), chunked."""
    out = np.empty(len(points))
    for i in range(0, len(points), 256):
        d = np.linalg.norm(points[i : i + 256, None, :] - path_xy[None, :, :], axis=2)
        out[i : i + 256] = d.min(axis=1)
    return out


def _along_path(path_xy: Array, spacing: float) -> tuple[Array, Array]:
    """Points every ``spacing`` metres along the path and the unit tangents there."""
    seg = np.diff(path_xy, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    if cum[-1] < 1e-6:
        return path_xy[:1], np.array([[0.0, 1.0]])
    s = np.arange(0.0, cum[-1], spacing)
    idx = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
    frac = (s - cum[idx]) / np.maximum(lengths[idx], 1e-9)
    points = path_xy[idx] + frac[:, None] * seg[idx]
    tangents = seg[idx] / np.maximum(lengths[idx], 1e-9)[:, None]
    return points, tangents


def _extended(path_xy: Array, length: float = 80.0) -> Array:
    """The path with straight extensions at both ends, so that the world continues beyond what the camera drives."""
    if len(path_xy) < 2:
        return path_xy

    def direction(a: Array, b: Array) -> Array:
        d = b - a
        norm = float(np.linalg.norm(d))
        return d / norm if norm > 1e-9 else np.array([0.0, 1.0])

    steps = np.linspace(2.0, length, 40)[:, None]
    head = path_xy[-1] + steps * direction(path_xy[-2], path_xy[-1])
    tail = path_xy[0] + steps[::-1] * direction(path_xy[1], path_xy[0])
    return np.vstack([tail, path_xy, head])


def build_world(spec: WorldSpec, camera_poses: Array, camera_height: float) -> World:
    """The MJCF of a world around the camera path (camera_poses: (N, 4, 4) T_world,cam)."""
    if spec.preset not in PRESETS:
        raise ValueError(f"unknown preset {spec.preset!r}: choose one of {', '.join(PRESETS)}")
    rng = np.random.default_rng(spec.seed)
    path_xy = _extended(camera_poses[:, :2, 3])
    lo, hi = path_xy.min(axis=0) - 80.0, path_xy.max(axis=0) + 80.0
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    extent = float(np.linalg.norm(half)) + 10.0
    assets: list[str] = []
    bodies: list[str] = []
    hfield = None
    moving_paths: list[Array] = []
    moving_headings: list[Array] = []
    if spec.preset == "urban":
        assets += [
            _texture("ground", "checker", "0.55 0.53 0.48", "0.68 0.66 0.60", 512, 0.08),
            _texture("road", "checker", "0.30 0.30 0.31", "0.36 0.36 0.37", 512, 0.05),
            _texture("facade", "checker", "0.55 0.45 0.38", "0.25 0.28 0.33", 256, 0.02, "edge"),
            _texture("facade2", "checker", "0.70 0.68 0.60", "0.30 0.30 0.35", 256, 0.03, "cross"),
            _texture("car", "gradient", "0.6 0.1 0.1", "0.15 0.15 0.2", 64, 0.0, "none"),
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
        points, tangents = _along_path(path_xy, 6.0)
        for p, t in zip(points, tangents, strict=True):
            yaw = np.degrees(np.arctan2(t[1], t[0]))
            bodies.append(
                f'<geom type="box" pos="{p[0]:.3f} {p[1]:.3f} 0.005" euler="0 0 {yaw:.3f}" size="3.4 3.6 0.005" material="road"/>'
            )
        # buildings, poles and parked cars on both sides
        for p, t in zip(*_along_path(path_xy, 11.0), strict=True):
            normal = np.array([-t[1], t[0]])
            for side in (-1.0, 1.0):
                if rng.random() < 0.2:
                    continue
                depth, width, height = rng.uniform(5, 12), rng.uniform(6, 10), rng.uniform(6, 25)
                c = p + side * normal * (9.0 + depth / 2 + rng.uniform(0, 3))
                if _distance_to_path(c[None], path_xy)[0] < spec.clearance + depth / 2 + 3.0:
                    continue
                yaw = np.degrees(np.arctan2(t[1], t[0]))
                mat = "facade" if rng.random() < 0.5 else "facade2"
                if rng.random() < spec.texture_poor:
                    mat = "plain"
                bodies.append(
                    f'<geom type="box" pos="{c[0]:.3f} {c[1]:.3f} {height / 2:.3f}" euler="0 0 {yaw:.2f}" '
                    f'size="{width / 2:.3f} {depth / 2:.3f} {height / 2:.3f}" material="{mat}"/>'
                )
        for p, t in zip(*_along_path(path_xy, 23.0), strict=True):
            normal = np.array([-t[1], t[0]])
            side = 1.0 if rng.random() < 0.5 else -1.0
            q = p + side * normal * 5.5
            if _distance_to_path(q[None], path_xy)[0] >= spec.clearance + 1.0:
                bodies.append(f'<geom type="cylinder" pos="{q[0]:.3f} {q[1]:.3f} 3" size="0.12 3" material="pole"/>')
            if rng.random() < 0.6:
                car = p + rng.uniform(-4, 4) * t - side * normal * 4.2
                if _distance_to_path(car[None], path_xy)[0] >= spec.clearance:
                    yaw = np.degrees(np.arctan2(t[1], t[0]))
                    bodies.append(
                        f'<geom type="box" pos="{car[0]:.3f} {car[1]:.3f} 0.75" euler="0 0 {yaw:.2f}" '
                        'size="2.2 0.9 0.75" material="car"/>'
                    )
        # moving vehicles: drive the path in the oncoming lane, offset in time
        path_xy = camera_poses[:, :2, 3]  # vehicles follow the driven part
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
    else:
        assets += [
            _texture("regolith", "checker", "0.62 0.52 0.42", "0.70 0.60 0.48", 512, 0.25),
            _texture("rock", "gradient", "0.35 0.32 0.30", "0.55 0.50 0.45", 64, 0.0, "none"),
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
        for p, _ in zip(*_along_path(path_xy, 4.0), strict=True):
            for _ in range(rng.poisson(2.0)):
                q = p + rng.normal(0, 12.0, 2)
                if _distance_to_path(q[None], path_xy)[0] < spec.clearance + 1.0:
                    continue
                r = rng.uniform(0.15, 1.2, 3)
                bodies.append(
                    f'<geom type="ellipsoid" pos="{q[0]:.3f} {q[1]:.3f} {0.3 * r[2]:.3f}" '
                    f'size="{r[0]:.3f} {r[1]:.3f} {r[2]:.3f}" '
                    f'euler="0 0 {rng.uniform(0, 360):.1f}" material="rock"/>'
                )
    ambient = "0.75 0.75 0.75" if spec.overcast else "0.38 0.38 0.40"
    diffuse = "0.35 0.35 0.35" if spec.overcast else "0.95 0.93 0.88"
    shadows = "false" if spec.overcast else "true"
    xml = f"""<mujoco model={quoteattr("pvo-" + spec.preset)}>
  <compiler angle="degree"/>
  <statistic extent="{extent:.1f}" center="{centre[0]:.1f} {centre[1]:.1f} 0"/>
  <visual>
    <headlight ambient="0 0 0" diffuse="0 0 0" specular="0 0 0"/>
    <global offwidth="{max(spec.image_size[0], 64)}" offheight="{max(spec.image_size[1], 64)}"/>
    <quality shadowsize="{spec.shadow_map}" offsamples="0" numslices="12" numstacks="6"/>
    <map znear="{0.3 / extent:.6f}" zfar="{3.0:.1f}" shadowclip="{60.0 / extent:.4f}" haze="0.05"/>
    <rgba haze="0.65 0.72 0.82 1" fog="0.7 0.75 0.82 1"/>
  </visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.55 0.68 0.85" rgb2="0.85 0.88 0.92" width="256" height="256"/>
    {chr(10).join("    " + a for a in assets).strip()}
  </asset>
  <worldbody>
    <light name="sun" directional="true" castshadow="{shadows}" pos="0 0 100" dir="0 0 -1"
           ambient="{ambient}" diffuse="{diffuse}" specular="0.1 0.1 0.1"/>
    <body name="rig" mocap="true">
      <camera name="left" pos="0 0 0" fovy="{spec.fovy_deg:.6f}"/>
      <camera name="right" pos="{spec.baseline:.6f} 0 0" fovy="{spec.fovy_deg:.6f}"/>
    </body>
    {chr(10).join("    " + b for b in bodies).strip()}
  </worldbody>
</mujoco>"""
    return World(xml, hfield, moving_paths, moving_headings, extent)


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
