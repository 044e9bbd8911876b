"""Procedural worlds as MuJoCo models (MJCF), generated along the camera path.

Presets: ``urban`` (textured ground and road, buildings, poles, parked and moving vehicles) and
``planetary`` (rough height-field terrain and rocks, no man-made structure). Every object is placed
from a seeded generator along the path (cost linear in the path length); nothing is placed within
``clearance`` metres of the path so the rig never drives through geometry. The rig is a mocap body
carrying the left and right cameras (MuJoCo cameras look along their -z with y up, so the body's
axes are the optical axes with y and z flipped); the sun is a directional light.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from xml.sax.saxutils import quoteattr

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
MOVING_VEHICLES = 3


@dataclass(frozen=True)
class WorldSpec:
    preset: str = "urban"
    seed: int = 0
    baseline: float = 0.54
    fovy_deg: float = 35.0
    overcast: bool = False
    clearance: float = 3.0
    terrain_resolution: float = 1.0  # planetary: metres per height-field sample
    shadow_map: int = 1024  # texels; the map covers 60 m around the camera
    image_size: tuple[int, int] = (640, 480)  # the offscreen framebuffer must hold the images
    texture_poor: float = 0.0  # fraction of buildings with plain walls
    moving_vehicles: int = MOVING_VEHICLES
    vehicle_speed: float = 0.0  # m/s (Degradations.vehicle_speed); 0: the vehicles replay the camera's path timing
    frame_interval: float = 0.1  # s between frames, for the vehicles' own speed
    gravel: float = 9.0  # planetary: stones and rocks (as meshes) per 2 m of path
    # "gradient": one sky for every sun; "sun": the skybox in the key colour, for :mod:`.sky` to replace with
    # the sky the sun makes (the renderer composites it)
    sky: str = "gradient"


@dataclass(frozen=True)
class WorldArea:
    """Where a preset builds: the extended path (M, 2), the driven path (N, 2), the ground's bounds (m) and the
    cameras' horizontal headings (N, 2)."""

    path_xy: Array
    driven_xy: Array
    lo: Array
    hi: Array
    centre: Array
    half: Array
    driven_heading: Array


@dataclass
class WorldParts:
    """What a preset contributes to the MJCF: assets, world-body elements and moving things."""

    assets: list[str] = field(default_factory=list)
    bodies: list[str] = field(default_factory=list)
    files: dict[str, bytes] = field(default_factory=dict)  # texture PNGs the assets name
    hfields: dict[str, Array] = field(default_factory=dict)  # height-field name: (rows, cols) heights in [0, 1]
    moving_paths: list[Array] = field(default_factory=list)
    moving_headings: list[Array] = field(default_factory=list)


@dataclass
class World:
    xml: str
    hfields: dict[str, Array]  # height-field name: (rows, cols) heights in [0, 1] (row 0 at the lowest y)
    moving_paths: list[Array]  # per moving vehicle: (N, 3) positions per frame
    moving_headings: list[Array]
    extent: float
    files: dict[str, bytes] = field(default_factory=dict)  # the assets MjModel.from_xml_string needs

    def compile(self):
        """The MuJoCo model, its height fields filled in."""
        import mujoco

        model = mujoco.MjModel.from_xml_string(self.xml, self.files)
        for name, heights in self.hfields.items():
            hfield = model.hfield(name)
            start, size = int(hfield.adr[0]), int(hfield.nrow[0] * hfield.ncol[0])
            model.hfield_data[start : start + size] = heights.reshape(-1)
        return model


def image_material(
    parts: WorldParts, name: str, image: NDArray[np.uint8], repeat: str = "1 1", uniform: bool = False, extra: str = ""
) -> None:
    """Add a procedural image (H, W, 3 uint8, row 0 at the top) as texture and material ``name``; with
    ``uniform``, ``repeat`` counts repetitions per metre, else per face."""
    from .textures import png_asset

    parts.files[f"{name}.png"] = png_asset(image)
    parts.assets.append(f'<texture name="{name}" type="2d" file="{name}.png"/>')
    parts.assets.append(
        f'<material name="{name}" texture="{name}" texrepeat="{repeat}" texuniform="{str(uniform).lower()}" {extra}/>'
    )


def texture(name: str, builtin: str, rgb1: str, rgb2: str, size: int, random: float, mark: str = "random") -> str:
    return (
        f'<texture name="{name}" type="2d" builtin="{builtin}" rgb1="{rgb1}" rgb2="{rgb2}" width="{size}" height="{size}" '
        f'mark="{mark}" random="{random}" markrgb="0.95 0.95 0.9"/>'
    )


def distance_to_path(points: Array, path_xy: Array) -> Array:
    """Horizontal distance of each point (M, 2) to the polyline of path samples (N, 2), chunked."""
    out = np.empty(len(points))
    for i in range(0, len(points), 256):
        d = np.linalg.norm(points[i : i + 256, None, :] - path_xy[None, :, :], axis=2)
        out[i : i + 256] = d.min(axis=1)
    return out


# below this horizontal span (m) a direction along the camera's path is the camera's heading, not the path's: at a
# standstill KITTI's poses jitter by up to ~1 cm a frame, and the direction of one such step points anywhere (before
# revision 8 a vehicle replaying the path circled the stopped camera 3.5 m away, facing every way, and the road
# beyond a path that ends stopped ran off anywhere); a camera moving 0.2 m/s or more keeps its path's directions
STEADY_SPAN = 0.02


def horizontal_headings(camera_poses: Array) -> Array:
    """Unit horizontal directions (N, 2) of the cameras' optical axes (T_world,cam (N, 4, 4), world z up) — the way
    a car faces, and drives when it drives forward; (0, 1) for a camera looking straight down."""
    axes = camera_poses[:, :2, 2]
    norms = np.linalg.norm(axes, axis=1, keepdims=True)
    return np.where(norms > 1e-9, axes / np.maximum(norms, 1e-9), np.array([0.0, 1.0]))


def steady_directions(path_xy: Array, headings: Array) -> Array:
    """Unit directions (N, 2) along the path at each sample: ``np.gradient``'s (the central difference, one-sided at
    the ends) where that spans STEADY_SPAN or more — to the last bit, so a world without a stop is drawn as
    before — and elsewhere the camera's heading there (``headings`` (N, 2), :func:`horizontal_headings`)."""
    gradient = np.gradient(path_xy, axis=0)
    out = gradient / np.maximum(np.linalg.norm(gradient, axis=1, keepdims=True), 1e-9)
    still = _central_spans(path_xy) < STEADY_SPAN
    out[still] = headings[still]
    return out


def _central_spans(path_xy: Array) -> Array:
    """|p[i+1] - p[i-1]| at each sample (N,), the one step at either end."""
    padded = np.vstack([path_xy[:1], path_xy, path_xy[-1:]])
    return np.linalg.norm(padded[2:] - padded[:-2], axis=1)


def end_direction(path_xy: Array, heading: Array, end: int) -> Array:
    """The unit direction in which the path leaves its last sample (``end`` -1) or its first (``end`` 0, pointing
    backwards): its last (first) step, or where that spans less than STEADY_SPAN the camera's ``heading`` there
    (negated at the first sample)."""
    index, neighbour = (len(path_xy) - 1, len(path_xy) - 2) if end == -1 else (0, 1)
    d = path_xy[index] - path_xy[neighbour]
    norm = float(np.linalg.norm(d))
    if norm < STEADY_SPAN:
        return np.asarray(heading, dtype=float) * (1.0 if end == -1 else -1.0)
    return d / norm


def steadied(path_xy: Array, moving_vehicles: int) -> bool:
    """Whether the steadied directions change this path's world from renderer revision 7's: where its first or
    last step spans less than STEADY_SPAN (the road's extensions), or, with moving vehicles (which replay the
    path), where any central difference does."""
    if len(path_xy) < 2:
        return False
    spans = _central_spans(path_xy)
    if min(spans[0], spans[-1]) < STEADY_SPAN:
        return True
    return bool(moving_vehicles and (spans < STEADY_SPAN).any())


def points_on_path(path_xy: Array, arc_lengths: Array) -> tuple[Array, Array]:
    """Points (K, 2) at the given distances along the path (m, in [0, its length)) and the unit tangents (K, 2)
    there; stretches where the path stands still (a stopped camera) have no length and are passed over."""
    seg = np.diff(path_xy, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    idx = np.clip(np.searchsorted(cum, arc_lengths, side="right") - 1, 0, len(seg) - 1)
    frac = (arc_lengths - cum[idx]) / np.maximum(lengths[idx], 1e-9)
    return path_xy[idx] + frac[:, None] * seg[idx], seg[idx] / np.maximum(lengths[idx], 1e-9)[:, None]


def along_path(path_xy: Array, spacing: float) -> tuple[Array, Array]:
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


def _extended(path_xy: Array, headings: Array, length: float = 80.0) -> Array:
    """The path with straight extensions at both ends, so that the world continues beyond what the camera drives
    (``headings``: the cameras' horizontal headings, for an end where the path stands still)."""
    if len(path_xy) < 2:
        return path_xy
    steps = np.linspace(2.0, length, 40)[:, None]
    head = path_xy[-1] + steps * end_direction(path_xy, headings[-1], -1)
    tail = path_xy[0] + steps[::-1] * end_direction(path_xy, headings[0], 0)
    return np.vstack([tail, path_xy, head])


def build_world(spec: WorldSpec, camera_poses: Array, camera_height: float) -> World:
    """The MJCF of a world around the camera path (camera_poses: (N, 4, 4) T_world,cam)."""
    builder = _builders().get(spec.preset)
    if builder is None:
        raise ValueError(f"unknown preset {spec.preset!r}: choose one of {', '.join(PRESETS)}")
    rng = np.random.default_rng(spec.seed)
    headings = horizontal_headings(camera_poses)
    path_xy = _extended(camera_poses[:, :2, 3], headings)
    lo, hi = path_xy.min(axis=0) - 80.0, path_xy.max(axis=0) + 80.0
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    extent = float(np.linalg.norm(half)) + 10.0
    area = WorldArea(path_xy, camera_poses[:, :2, 3], lo, hi, centre, half, headings)
    parts = builder(spec, area, rng)
    assets, bodies = parts.assets, parts.bodies
    # Sunlight with cast shadows plus skylight: a diffuse fill from the zenith and an ambient term, so that
    # faces turned from the sun are grey as in a photograph, not black. Overcast: the whole sky, no shadows.
    # The ambient term rides on the sky light: MuJoCo drops a shadow-casting light's ambient wherever its
    # shadow map says "shadowed" (faces turned from the sun went black).
    if spec.overcast:
        sky_ambient, sun_diffuse, sky_diffuse, shadows = "0.42 0.42 0.44", "0.18 0.18 0.18", "0.40 0.40 0.42", "false"
    else:
        sky_ambient, sun_diffuse, sky_diffuse, shadows = "0.09 0.095 0.11", "1.0 0.97 0.9", "0.07 0.075 0.09", "true"
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
    {_skybox(spec.sky)}
    {chr(10).join("    " + a for a in assets).strip()}
  </asset>
  <worldbody>
    <light name="sun" directional="true" castshadow="{shadows}" pos="0 0 100" dir="0 0 -1"
           ambient="0 0 0" diffuse="{sun_diffuse}" specular="0.1 0.1 0.1"/>
    <light name="sky" directional="true" castshadow="false" pos="0 0 100" dir="0.1 0.2 -1"
           ambient="{sky_ambient}" diffuse="{sky_diffuse}" specular="0 0 0"/>
    <body name="rig" mocap="true">
      <camera name="left" pos="0 0 0" fovy="{spec.fovy_deg:.6f}"/>
      <camera name="right" pos="{spec.baseline:.6f} 0 0" fovy="{spec.fovy_deg:.6f}"/>
    </body>
    {chr(10).join("    " + b for b in bodies).strip()}
  </worldbody>
</mujoco>"""
    return World(xml, parts.hfields, parts.moving_paths, parts.moving_headings, extent, parts.files)


def _skybox(sky: str) -> str:
    """The skybox texture: the gradient, or the key colour :func:`pvo_sim.sky.composite_sky` replaces."""
    if sky == "gradient":
        return '<texture name="sky" type="skybox" builtin="gradient" rgb1="0.85 0.9 1.0" rgb2="1 1 1" width="256" height="256"/>'
    if sky == "sun":
        from .sky import KEY_RGB

        key = " ".join(f"{c / 255:g}" for c in KEY_RGB)
        return f'<texture name="sky" type="skybox" builtin="flat" rgb1="{key}" rgb2="{key}" width="16" height="16"/>'
    raise ValueError(f"unknown sky {sky!r}: choose gradient or sun")


def _builders() -> dict[str, Callable[[WorldSpec, WorldArea, np.random.Generator], WorldParts]]:
    from .presets import planetary, urban

    return {"urban": urban.build, "planetary": planetary.build}


PRESETS = ("urban", "planetary")
#: Supersampling per preset by default: a camera pixel integrates light over its area, a rendered one samples
#: a point. Without it gravel at grazing angles is a blur (planetary: 70-80 VO features a frame instead of
#: 80-90, a steeper spectrum) and edges alias: on the 300-frame urban loop at 620x188 the VO drifted 2.63 % for
#: seed 2 and 1.51 % for seed 0, with it 1.20 % and 1.46 % (`pvo bench realism`).
SUPERSAMPLE = {"urban": 2, "planetary": 2}
