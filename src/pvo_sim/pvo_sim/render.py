"""Render a synthetic sequence: stereo images, ground-truth poses, sun, IMU, GPS and (optionally) depth.

Output is the KITTI odometry layout (``image_0``/``image_1`` grey or ``image_2``/``image_3`` colour,
``calib.txt``, ``times.txt``, ``poses.txt``) plus sidecars: ``sun.csv`` (the Sun-BCNN CSV format:
``relpath,sx,sy,sz`` in the left camera frame), ``imu.csv`` (``t,wx,wy,wz,fx,fy,fz``: angular rate
rad/s and specific force m/s² in the left camera frame), ``gps.csv`` (``t,latitude,longitude,altitude``;
``t`` in seconds from the first frame, like ``times.txt``),
``sim.yaml`` (everything needed to reproduce it) and ``depth_0/*.png`` (16-bit, metres x 256, 0 = sky).
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from pvo_core.ephemeris import GeodeticOrigin, enu_to_geodetic, sun_direction_enu, sun_elevation_azimuth
from pvo_core.lie import rotation_to_quaternion, so3_exp, so3_log

from .degrade import CameraModel, Degradations, ImageDegrader
from .paths import heading_rotation, kitti_path, procedural_path
from .sky import SKIES, composite_sky, pixel_rays, sky_values
from .world import PRESETS, SUPERSAMPLE, WorldSpec, build_world, steadied

Array = NDArray[np.float64]
GRAVITY_ENU = np.array([0.0, 0.0, -9.80665])
#: Bumped whenever the same configuration renders different images (worlds, lighting, camera): a corpus keeps a
#: sequence only if it was rendered by the same revision.
#: 7: KITTI drives levelled onto the flat ground (kitti_path); 8: where a camera's path moves under 2 cm in two
#: frames (a stop, KITTI's jitter), its direction is the camera's heading (world.steady_directions: the moving
#: vehicles that replay the path, the road beyond its ends); 9: the sun's shadows cast from its side of the camera
#: too (SUN_LIGHT_DISTANCE, RangeCuller) — every sequence with sunshine; an overcast one casts no shadow.
RENDERER_REVISION = 9
#: what revision 9 draws exactly as revision 8 did (no sunshine) keeps 8 where revision 8 changed it (steadied)...
STEADIED_REVISION = 8
#: ... and 7 where neither did, with it its content hash
UNCHANGED_SINCE_REVISION = 7


def renderer_revision(poses: Array, moving_vehicles: int, overcast: bool = False) -> int:
    """The revision a sequence of camera poses T_world,cam (N, 4, 4) is recorded with: RENDERER_REVISION where
    that revision draws it differently from the one before (sunshine casts shadows), else the latest revision that
    did (revision 8 where world.steadied changes its world, else 7) — so a corpus rendered before keeps every
    sequence a change does not touch."""
    if not overcast:
        return RENDERER_REVISION
    return STEADIED_REVISION if steadied(poses[:, :2, 3], moving_vehicles) else UNCHANGED_SINCE_REVISION


def planned_revision(config: SimConfig) -> int:
    """The revision ``simulate(config)`` records (renderer_revision of its camera path and sky)."""
    return renderer_revision(camera_trajectory(config), config.degradations.moving_vehicles, config.overcast)


def rendered_by_this_renderer(folder: Path) -> bool:
    """Whether ``folder`` holds a complete `pvo sim` sequence that this renderer would draw the same: its sim.yaml
    records the revision renderer_revision gives its own camera path (world_T_cam0 times poses.txt) and sky."""
    import yaml

    meta_file = folder / "sim.yaml"
    if not meta_file.is_file() or not (folder / "poses.txt").is_file():
        return False
    meta = yaml.safe_load(meta_file.read_text()) or {}
    try:
        relative = np.loadtxt(folder / "poses.txt", ndmin=2).reshape(-1, 3, 4)
        first = np.asarray(meta["world_T_cam0"], dtype=float)
        moving = int(meta["config"]["degradations"]["moving_vehicles"])
        overcast = bool(meta["config"].get("overcast", False))
    except (KeyError, TypeError, ValueError, AttributeError):
        return False
    poses = np.tile(np.eye(4), (len(relative), 1, 1))
    poses[:, :3, :] = relative
    return meta.get("renderer_revision") == renderer_revision(first @ poses, moving, overcast)


KITTI_FOCAL_PER_PIXEL_WIDTH = 718.856 / 1241.0  # KITTI's focal length scales with the image width


@dataclass(frozen=True)
class ImuNoise:
    """Continuous-time white noise densities and constant biases (camera frame)."""

    gyro_noise: float = 0.0  # rad/s/sqrt(Hz)
    accel_noise: float = 0.0  # m/s^2/sqrt(Hz)
    gyro_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    accel_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class SimConfig:
    preset: str = "urban"
    frames: int = 100
    width: int = 620
    height: int = 188
    focal: float = 359.4  # px; KITTI's 718.856 scaled to 620 px wide
    baseline: float = 0.54
    rate: float = 10.0
    colour: bool = False
    path: str = "loop"  # loop | straight | s-curve, or a KITTI pose file via poses_file
    poses_file: str = ""
    start_frame: int = 0
    level_frames: int = 0  # a KITTI window levelled over this many frames of its drive around it (0: itself)
    speed_scale: float = 1.0  # a KITTI drive replayed this many times faster (frame k at the drive's start + k * s)
    speed: float = 8.0
    camera_height: float = 1.65
    heading_deg: float = 0.0
    pitch_deg: float = 0.0  # the cameras pitched down by this much (a rover's mast camera looks at the ground)
    latitude: float = 49.011
    longitude: float = 8.4245
    altitude: float = 115.0
    start_time: str = "2011-09-30T11:30:00Z"
    overcast: bool = False
    # the sky: "gradient" (one for every sun, the default since revision 1) or "sun" (the CIE standard clear sky
    # about the sun, or the overcast one: pvo_sim.sky); the gradient's sim.yaml does not name it
    sky: str = "gradient"
    night: bool = False
    depth: bool = False
    seed: int = 0
    imu: ImuNoise = field(default_factory=ImuNoise)
    gps_sigma: float = 0.0  # m, horizontal and vertical
    shadow_map: int = 1024
    supersample: int = 0  # render at N times the size and average down; 0: the preset's default (SUPERSAMPLE)
    degradations: Degradations = field(default_factory=Degradations)
    camera: CameraModel = field(default_factory=CameraModel)

    def __post_init__(self) -> None:
        if self.preset not in PRESETS:
            raise ValueError(f"unknown preset {self.preset!r}: choose one of {', '.join(PRESETS)}")
        if self.sky not in SKIES:
            raise ValueError(f"--sky must be one of {', '.join(SKIES)}, got {self.sky!r}")
        if self.supersample not in (0, 1, 2, 3, 4):
            raise ValueError(f"--supersample must be 0 (the preset's default), 1, 2, 3 or 4, got {self.supersample}")
        if not -60.0 <= self.pitch_deg <= 60.0:
            raise ValueError(f"--pitch must be in [-60, 60] degrees, got {self.pitch_deg}")
        if self.frames < 2:
            raise ValueError(f"--frames must be >= 2, got {self.frames}")
        if self.level_frames < 0:
            raise ValueError(f"--level-frames must be >= 0 (0: the window levelled on itself), got {self.level_frames}")
        if not self.speed_scale > 0.0 or not np.isfinite(self.speed_scale):
            raise ValueError(f"--speed-scale must be positive (1: the drive as driven), got {self.speed_scale}")
        if self.speed_scale != 1.0 and not self.poses_file:
            raise ValueError("--speed-scale replays a KITTI drive faster: give the drive with --poses")
        if self.width < 16 or self.height < 16 or self.focal <= 0 or self.baseline <= 0 or self.rate <= 0:
            raise ValueError("image size >= 16 px, focal length, baseline and rate must be positive")

    @property
    def scale(self) -> int:
        """The supersampling factor in effect."""
        return self.supersample or SUPERSAMPLE[self.preset]

    @property
    def epoch(self) -> float:
        text = self.start_time.replace("Z", "+00:00")
        try:
            moment = datetime.fromisoformat(text)
        except ValueError:
            raise ValueError(f"--start-time {self.start_time!r} is not ISO 8601 (e.g. 2011-09-30T11:30:00Z)") from None
        if moment.tzinfo is None:
            moment = moment.replace(tzinfo=UTC)
        return moment.timestamp()


def camera_trajectory(config: SimConfig) -> Array:
    """T_world,cam (N, 4, 4) of the left camera: the path (a procedural one turned clockwise by the heading),
    the camera pitched down by ``pitch_deg`` about its x axis."""
    if config.poses_file:
        poses = kitti_path(
            Path(config.poses_file),
            config.frames,
            config.start_frame,
            config.camera_height,
            config.heading_deg,
            config.level_frames,
            config.speed_scale,
        )
    else:
        poses = procedural_path(config.path, config.frames, config.rate, config.speed, config.camera_height, config.seed)
        if config.heading_deg:
            turn = np.eye(4)
            turn[:3, :3] = heading_rotation(config.heading_deg)
            poses = turn @ poses
    if config.pitch_deg:
        pitch = np.eye(4)
        pitch[:3, :3] = so3_exp(np.array([-np.radians(config.pitch_deg), 0.0, 0.0]))
        poses = poses @ pitch
    return poses


def imu_from_trajectory(poses: Array, rate: float) -> tuple[Array, Array]:
    """Noise-free angular rate (rad/s) and specific force (m/s²) in the camera frame at each frame,
    by central differences of the poses (one-sided at the ends)."""
    n = len(poses)
    dt = 1.0 / rate
    omega = np.zeros((n, 3))
    accel = np.zeros((n, 3))
    positions = poses[:, :3, 3]
    for k in range(n):
        a, b = max(k - 1, 0), min(k + 1, n - 1)
        omega[k] = so3_log(poses[a, :3, :3].T @ poses[b, :3, :3]) / ((b - a) * dt)
        # the rate is expressed in the frame at k: rotate from the frame at a
        omega[k] = poses[k, :3, :3].T @ poses[a, :3, :3] @ omega[k]
        k0 = min(max(k, 1), n - 2)
        world_accel = (positions[k0 + 1] - 2 * positions[k0] + positions[k0 - 1]) / dt**2
        accel[k] = poses[k, :3, :3].T @ (world_accel - GRAVITY_ENU)
    return omega, accel


@dataclass
class SimResult:
    out: Path
    frames: int
    seconds_render: float
    seconds_world: float
    sun_elevation_deg: tuple[float, float]


BACKEND_PACKAGES = {"egl": "libegl1 and libgl1-mesa-dri (Mesa EGL)", "osmesa": "libosmesa6", "glfw": "a display and libglfw3"}


def _backend_error(exc: BaseException) -> ValueError:
    backend = os.environ.get("MUJOCO_GL", "egl")
    package = BACKEND_PACKAGES.get(backend, "an OpenGL driver")
    detail = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return ValueError(f"no offscreen renderer (MUJOCO_GL={backend}): install {package}, or set MUJOCO_GL=egl|osmesa ({detail})")


def _require_renderer() -> None:
    os.environ.setdefault("MUJOCO_GL", "egl")
    try:
        import mujoco  # noqa: F401
    except ModuleNotFoundError as exc:  # pragma: no cover - mujoco is pinned in requirements.txt
        raise ValueError(f"the mujoco Python package is missing ({exc}); pip install -r requirements.txt") from None
    except Exception as exc:  # noqa: BLE001 - a missing GL library surfaces as many error types at import
        raise _backend_error(exc) from None


def open_renderer(model, height: int, width: int):
    """A MuJoCo offscreen renderer, or one clear error naming the system package to install."""
    import mujoco

    try:
        return mujoco.Renderer(model, height, width)
    except Exception as exc:  # noqa: BLE001 - GL back-ends raise many types
        if "framebuffer" in str(exc):
            raise ValueError(f"renderer: {str(exc).splitlines()[0]}") from None
        raise _backend_error(exc) from None


def mocap_quaternion(rotation_world_optical: Array) -> Array:
    """MuJoCo (w, x, y, z) of a camera body whose -z looks along the optical +z and whose y is optical -y."""
    body = rotation_world_optical @ np.diag([1.0, -1.0, -1.0])
    return rotation_to_quaternion(body)


#: How far up-sun of the camera the directional sun light sits (m). MuJoCo draws a directional light's shadow map
#: as an orthographic view from the light's position along its direction, and whatever lies behind that position
#: casts no shadow; a light at the camera (revisions up to 8) dropped every caster on the sun's side of the camera
#: — the buildings across the street from the sun, trees, vehicles, rocks ahead of a low sun. From here every
#: geom the culler keeps (RangeCuller.radius) is in front of it; the map still covers the same 60 m about the line
#: through the camera, and the world's far plane (3 x its extent, at least 369 m) reaches past the ground there.
SUN_LIGHT_DISTANCE = 200.0


def place_sun(model, light: int, sun_world: Array, near: Array, distance: float = SUN_LIGHT_DISTANCE) -> None:
    """Point the directional light along the sun (ENU unit vector towards the sun): light travels along -s. It is
    placed ``distance`` m up-sun of ``near`` (the camera), so that casters between the sun and the camera cast
    their shadows too (SUN_LIGHT_DISTANCE)."""
    sun = np.asarray(sun_world, dtype=float)
    model.light_dir[light] = -sun
    model.light_pos[light] = np.asarray(near, dtype=float) + distance * sun


def place_rig(data, rig: int, pose: Array) -> None:
    """Move the camera rig (mocap ``rig``) to the left camera pose T_world,cam."""
    data.mocap_pos[rig] = pose[:3, 3]
    data.mocap_quat[rig] = mocap_quaternion(pose[:3, :3])


HIDDEN_GROUP = 5


class RangeCuller:
    """MuJoCo draws every geom of a model (no frustum culling), so a long world would cost every frame in
    proportion to its length. Per frame, geoms farther than ``radius`` m from the camera, or behind it and
    farther than ``behind`` m (nearer ones may still cast a shadow into view) unless they stand up-sun of the
    camera, where they may cast one into view from anywhere in range, move to a hidden group.

    (Coarse twins of far terrain tiles — levels of detail, switched at 20-70 m — were tried: planetary frames
    10-15 % faster, but a tile changing level between frames changes what the VO tracks: the seed-1 planetary
    held-out run drifted 3.4-3.8 % instead of 2.2 % with every tile fine.)"""

    def __init__(self, model, radius: float = 160.0, behind: float = 25.0) -> None:
        import mujoco

        self.model = model
        self.radius, self.behind = radius, behind
        self.groups = model.geom_group.copy()
        self.always = model.geom_rbound <= 0.0  # planes: unbounded
        self.option = mujoco.MjvOption()
        self.option.geomgroup[HIDDEN_GROUP] = 0

    def __call__(self, data, pose: Array, sun_world: Array | None = None):
        """Hide what the camera at ``pose`` (T_world,cam) cannot see and what casts no shadow into its view from
        the sun ``sun_world`` (ENU unit vector; None: no shadows); the scene option to render with."""
        offset = data.geom_xpos - pose[:3, 3]
        reach = np.linalg.norm(offset, axis=1) - self.model.geom_rbound
        behind = offset @ pose[:3, 2] < -self.model.geom_rbound
        if sun_world is not None:
            behind &= offset @ np.asarray(sun_world, dtype=float) < -self.model.geom_rbound
        hide = ((reach > self.radius) | (behind & (reach > self.behind))) & ~self.always
        self.model.geom_group[:] = np.where(hide, HIDDEN_GROUP, self.groups)
        return self.option


def simulate(
    config: SimConfig, out: Path, overwrite: bool = False, progress: Callable[[int, int], None] | None = None
) -> SimResult:
    """Render the sequence into ``out`` (refused if it exists, unless ``overwrite``)."""
    out = Path(out)
    if out.exists() and not overwrite:
        raise ValueError(f"{out} exists: refusing to overwrite it (use --overwrite)")
    if out.exists() and not (out.is_dir() and ((out / "sim.yaml").is_file() or not any(out.iterdir()))):
        raise ValueError(f"{out} exists and is not a pvo sim output (no sim.yaml); refusing to replace it, even with --overwrite")
    poses = camera_trajectory(config)
    n = len(poses)
    origin = GeodeticOrigin(config.latitude, config.longitude, config.altitude)
    times = config.epoch + np.arange(n) / config.rate
    elevation, _ = sun_elevation_azimuth(origin, times)
    if not config.night and float(np.min(elevation)) <= 0.0:
        when = datetime.fromtimestamp(float(times[int(np.argmin(elevation))]), tz=UTC).isoformat()
        raise ValueError(
            f"the sun is below the horizon at {config.latitude:.4f}, {config.longitude:.4f} on {when} "
            f"(elevation {float(np.min(elevation)):.1f} deg): choose another --start-time, or --night to render anyway"
        )
    sun_world = sun_direction_enu(origin, times)
    sun_camera = np.einsum("nji,nj->ni", poses[:, :3, :3], sun_world)

    _require_renderer()
    import mujoco

    t0 = time.perf_counter()
    fovy = float(np.degrees(2.0 * np.arctan(config.height / (2.0 * config.focal))))
    spec = WorldSpec(
        config.preset,
        config.seed,
        config.baseline,
        fovy,
        config.overcast,
        shadow_map=config.shadow_map,
        image_size=(config.width * config.scale, config.height * config.scale),
        texture_poor=config.degradations.texture_poor,
        moving_vehicles=config.degradations.moving_vehicles,
        vehicle_speed=config.degradations.vehicle_speed,
        frame_interval=1.0 / config.rate,
        sky=config.sky,
    )
    world = build_world(spec, poses, config.camera_height)
    model = world.compile()
    data = mujoco.MjData(model)
    seconds_world = time.perf_counter() - t0

    # Render into a hidden sibling and move it into place only when complete: an interrupted or failed
    # run leaves nothing half-written and keeps an existing output until the new one is whole.
    final = out
    out = out.parent / f".{out.name}.partial"
    if out.exists():
        shutil.rmtree(out)
    try:
        seconds_render = _render(config, out, model, data, world, poses, times, sun_world, sun_camera, origin, n, progress)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    if final.exists():
        shutil.rmtree(final)
    out.rename(final)
    return SimResult(final, n, seconds_render, seconds_world, (float(elevation.min()), float(elevation.max())))


def _render(
    config: SimConfig,
    out: Path,
    model,
    data,
    world,
    poses: Array,
    times: Array,
    sun_world: Array,
    sun_camera: Array,
    origin: GeodeticOrigin,
    n: int,
    progress: Callable[[int, int], None] | None,
) -> float:
    """Render every frame into ``out`` and write the truth files; the rendering time (s)."""
    import cv2
    import mujoco

    left_dir, right_dir = ("image_2", "image_3") if config.colour else ("image_0", "image_1")
    for d in (left_dir, right_dir, *(["depth_0"] if config.depth else [])):
        (out / d).mkdir(parents=True, exist_ok=True)
    scale = config.scale
    renderer = open_renderer(model, config.height * scale, config.width * scale)
    rig = model.body("rig").mocapid[0]
    vehicles = [model.body(f"vehicle{j}").mocapid[0] for j in range(len(world.moving_paths))]
    light = model.light("sun").id
    depth_renderer = open_renderer(model, config.height, config.width) if config.depth else None
    if depth_renderer is not None:
        depth_renderer.enable_depth_rendering()
    degrade = ImageDegrader(config.degradations, config.width, config.height, config.focal, n, config.seed, config.camera)
    cull = RangeCuller(model)
    rays = None
    if config.sky == "sun":  # the key colour must reach the image unblended: no haze band at the horizon
        renderer.scene.flags[mujoco.mjtRndFlag.mjRND_HAZE] = False
        rays = pixel_rays(config.width, config.height, config.focal)
    t1 = time.perf_counter()
    try:
        for k in range(n):
            place_rig(data, rig, poses[k])
            for j, mid in enumerate(vehicles):
                data.mocap_pos[mid] = world.moving_paths[j][k]
                h = world.moving_headings[j][k]
                data.mocap_quat[mid] = [np.cos(h / 2), 0.0, 0.0, np.sin(h / 2)]
            place_sun(model, light, sun_world[k], poses[k, :3, 3])
            mujoco.mj_kinematics(model, data)
            mujoco.mj_camlight(model, data)
            option = cull(data, poses[k], None if config.overcast else sun_world[k])
            # the sky at infinity, the same for both cameras (one rotation); up: the world's z in the optical
            # frame, row 2 of R_world,cam
            sky = None if rays is None else sky_values(rays, poses[k, 2, :3], sun_camera[k], config.overcast, colour=True)
            name = f"{k:06d}.png"
            for index, (camera, folder) in enumerate((("left", left_dir), ("right", right_dir))):
                renderer.update_scene(data, camera=camera, scene_option=option)
                rgb = renderer.render()
                if sky is not None:
                    rgb = composite_sky(rgb, sky, scale)
                elif scale > 1:  # the mean of each scale x scale block: pixel centres stay where they were
                    rgb = cv2.resize(rgb, (config.width, config.height), interpolation=cv2.INTER_AREA)
                image = rgb if config.colour else cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
                image = degrade(image, k, index)
                if config.colour:
                    image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
                cv2.imwrite(str(out / folder / name), image)
            if depth_renderer is not None:
                depth_renderer.update_scene(data, camera="left", scene_option=option)
                depth = depth_renderer.render()
                far = depth >= 0.99 * model.vis.map.zfar * model.stat.extent
                encoded = np.clip(np.round(depth * 256.0), 0, 65535).astype(np.uint16)
                encoded[far] = 0
                cv2.imwrite(str(out / "depth_0" / name), encoded)
            if progress:
                progress(k + 1, n)
    finally:
        renderer.close()
        if depth_renderer is not None:
            depth_renderer.close()
    seconds_render = time.perf_counter() - t1
    _write_sidecars(config, out, poses, times, sun_camera, origin, left_dir, world)
    return seconds_render


def recorded_config(config: SimConfig) -> dict:
    """The configuration as ``sim.yaml`` records it: the default sky and vehicles that replay the camera's path
    (vehicle_speed 0) are not named, so a sequence rendered before either was an option keeps its content hash."""
    recorded = asdict(config)
    if recorded["sky"] == "gradient":
        del recorded["sky"]
    if recorded["degradations"]["vehicle_speed"] == 0.0:
        del recorded["degradations"]["vehicle_speed"]
    return recorded


def _write_sidecars(
    config: SimConfig, out: Path, poses: Array, times: Array, sun_camera: Array, origin: GeodeticOrigin, left_dir: str, world
) -> None:
    import yaml

    n = len(poses)
    # MuJoCo's frustum is symmetric about the image centre, which lies at (W-1)/2, (H-1)/2 with pixel
    # centres at integer coordinates (the OpenCV/KITTI convention).
    # a miscalibration degradation writes a wrong calibration for the true rendering
    f = config.focal * config.degradations.focal_scale
    baseline = config.baseline * config.degradations.baseline_scale
    cu, cv = (config.width - 1) / 2.0, (config.height - 1) / 2.0
    lines = []
    for i in range(4):
        tx = -f * baseline if i % 2 == 1 else 0.0
        p = [f, 0.0, cu, tx, 0.0, f, cv, 0.0, 0.0, 0.0, 1.0, 0.0]
        lines.append(f"P{i}: " + " ".join(f"{v:.12e}" for v in p))
    (out / "calib.txt").write_text("\n".join(lines) + "\n")
    (out / "times.txt").write_text("".join(f"{t - times[0]:.6e}\n" for t in times))
    relative = np.linalg.inv(poses[0]) @ poses
    (out / "poses.txt").write_text("".join(" ".join(f"{v:.12e}" for v in p[:3].reshape(-1)) + "\n" for p in relative))
    (out / "sun.csv").write_text(
        "".join(f"{left_dir}/{k:06d}.png,{s[0]:.9f},{s[1]:.9f},{s[2]:.9f}\n" for k, s in enumerate(sun_camera))
    )
    rng = np.random.default_rng(config.seed + 7919)
    omega, accel = imu_from_trajectory(poses, config.rate)
    noise = config.imu
    omega = omega + np.asarray(noise.gyro_bias) + rng.normal(0.0, noise.gyro_noise * np.sqrt(config.rate), omega.shape)
    accel = accel + np.asarray(noise.accel_bias) + rng.normal(0.0, noise.accel_noise * np.sqrt(config.rate), accel.shape)
    relative_times = times - times[0]
    (out / "imu.csv").write_text(
        "t,wx,wy,wz,fx,fy,fz\n"
        + "".join(
            f"{t:.6f}," + ",".join(f"{v:.9e}" for v in (*w, *a)) + "\n"
            for t, w, a in zip(relative_times, omega, accel, strict=True)
        )
    )
    enu = poses[:, :3, 3] + rng.normal(0.0, config.gps_sigma, (n, 3)) if config.gps_sigma > 0 else poses[:, :3, 3]
    geodetic = enu_to_geodetic(origin, enu)
    (out / "gps.csv").write_text(
        "t,latitude,longitude,altitude\n"
        + "".join(f"{t:.6f},{g[0]:.10f},{g[1]:.10f},{g[2]:.4f}\n" for t, g in zip(relative_times, geodetic, strict=True))
    )
    meta = {
        "generator": "pvo sim",
        "renderer_revision": renderer_revision(poses, config.degradations.moving_vehicles, config.overcast),
        "config": recorded_config(config),
        "epoch_unix_s": float(times[0]),
        "world_T_cam0": poses[0].tolist(),
        "frames": n,
        "world_extent_m": world.extent,
        "conventions": {
            "world": "ENU at the ground under the first camera (x east, y north, z up)",
            "camera": "left optical frame, x right, y down, z forward",
            "poses.txt": "T_cam0,camk (KITTI)",
            "imu.csv": "angular rate [rad/s], specific force [m/s^2], left camera frame",
        },
    }
    (out / "sim.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
