"""`pvo sim`: geometry of the rendered images against the scene, truth files, IMU, determinism, bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pvo_core.ephemeris import GeodeticOrigin, sun_direction_enu
from pvo_core.lie import so3_exp
from pvo_core.trajectory import read_kitti_poses
from pvo_sim.paths import procedural_path
from pvo_sim.render import SimConfig, camera_trajectory, imu_from_trajectory, simulate

SMALL = {"width": 320, "height": 120, "focal": 185.4, "path": "straight", "speed": 6.0}


def render(out: Path, **overrides) -> SimConfig:
    config = SimConfig(**{**SMALL, **overrides})  # type: ignore[arg-type]
    try:
        simulate(config, out, overwrite=True)
    except ValueError as exc:
        if "no offscreen renderer" in str(exc):
            pytest.skip(str(exc))
        raise
    return config


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> tuple[Path, SimConfig]:
    out = tmp_path_factory.mktemp("sim") / "urban"
    return out, render(out, frames=8, depth=True)


def test_depth_of_the_road_plane_matches_the_camera_height(sequence) -> None:
    import cv2

    out, config = sequence
    depth = cv2.imread(str(out / "depth_0" / "000000.png"), cv2.IMREAD_UNCHANGED).astype(float) / 256.0
    cv = (config.height - 1) / 2.0
    height_above_road = config.camera_height - 0.01  # the road boxes are 1 cm thick on the ground
    rows = np.arange(int(cv) + 15, config.height)
    centre = depth[rows, config.width // 2 - 5 : config.width // 2 + 5].mean(axis=1)
    expected = config.focal * height_above_road / (rows - cv)
    np.testing.assert_allclose(centre, expected, rtol=0.01)


def test_disparity_of_matched_features_is_f_b_over_z(sequence) -> None:
    import cv2

    out, config = sequence
    left = cv2.imread(str(out / "image_0" / "000004.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(out / "image_1" / "000004.png"), cv2.IMREAD_GRAYSCALE)
    depth = cv2.imread(str(out / "depth_0" / "000004.png"), cv2.IMREAD_UNCHANGED).astype(float) / 256.0
    corners = cv2.goodFeaturesToTrack(left, 300, 0.01, 5)
    assert corners is not None and len(corners) > 50
    tracked, status, _ = cv2.calcOpticalFlowPyrLK(left, right, corners, None, winSize=(21, 21), maxLevel=3)
    back, status_back, _ = cv2.calcOpticalFlowPyrLK(right, left, tracked, None, winSize=(21, 21), maxLevel=3)
    # keep left-right consistent matches on the epipolar line, away from depth discontinuities
    ok = (status.ravel() == 1) & (status_back.ravel() == 1) & (np.linalg.norm(back - corners, axis=2).ravel() < 0.3)
    pl, pr = corners[ok, 0], tracked[ok, 0]
    u, v = np.round(pl[:, 0]).astype(int), np.round(pl[:, 1]).astype(int)
    inside = (u >= 3) & (u < config.width - 3) & (v >= 3) & (v < config.height - 3)
    pl, pr, u, v = pl[inside], pr[inside], u[inside], v[inside]
    z = depth[v, u]
    patch = np.stack([depth[v + dv, u + du] for dv in (-3, 0, 3) for du in (-3, 0, 3)], axis=1)
    smooth = (patch.max(axis=1) - patch.min(axis=1)) < 0.1 * z
    good = (z > 2.0) & (z < 60.0) & (np.abs(pl[:, 1] - pr[:, 1]) < 0.5) & smooth
    assert good.sum() > 20
    disparity = pl[good, 0] - pr[good, 0]
    expected = config.focal * config.baseline / z[good]
    assert np.median(np.abs(disparity - expected)) < 0.3


def test_truth_files_agree_with_the_trajectory_and_the_ephemeris(sequence) -> None:
    import yaml

    out, config = sequence
    meta = yaml.safe_load((out / "sim.yaml").read_text())
    world_from_cam0 = np.array(meta["world_T_cam0"])
    poses = world_from_cam0 @ read_kitti_poses(out / "poses.txt")
    np.testing.assert_allclose(poses, camera_trajectory(config), atol=1e-9)
    sun = np.array([[float(v) for v in line.split(",")[1:]] for line in (out / "sun.csv").read_text().splitlines()])
    times = meta["epoch_unix_s"] + np.loadtxt(out / "times.txt")
    truth = sun_direction_enu(GeodeticOrigin(config.latitude, config.longitude, config.altitude), times)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", poses[:, :3, :3], sun), truth, atol=1e-8)
    calib = (out / "calib.txt").read_text().splitlines()
    p1 = np.array([float(v) for v in calib[1].split()[1:]])
    assert p1[3] == pytest.approx(-config.focal * config.baseline)


def test_same_seed_same_bytes(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    render(a, frames=3, seed=5)
    render(b, frames=3, seed=5)
    for name in ("image_0/000002.png", "image_1/000001.png", "imu.csv", "gps.csv", "poses.txt"):
        assert (a / name).read_bytes() == (b / name).read_bytes(), name
    render(b, frames=3, seed=6)
    assert (a / "image_0/000002.png").read_bytes() != (b / "image_0/000002.png").read_bytes()


def test_noise_free_imu_integrates_back_to_the_trajectory() -> None:
    rate = 10.0
    poses = procedural_path("s-curve", 101, rate, 8.0, 1.65, seed=2)
    omega, force = imu_from_trajectory(poses, rate)
    dt = 1.0 / rate
    gravity = np.array([0.0, 0.0, -9.80665])
    rotation = poses[0, :3, :3].copy()
    position = poses[0, :3, 3].copy()
    velocity = (poses[1, :3, 3] - poses[0, :3, 3]) / dt
    for k in range(100):
        accel = rotation @ force[k] + gravity
        position = position + velocity * dt + 0.5 * accel * dt**2
        velocity = velocity + accel * dt
        rotation = rotation @ so3_exp(0.5 * (omega[k] + omega[k + 1]) * dt)
    path_length = np.sum(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1))
    assert np.linalg.norm(position - poses[100, :3, 3]) < 0.01 * path_length
    assert np.degrees(np.linalg.norm(so3_exp(np.zeros(3)) @ (rotation.T @ poses[100, :3, :3]) - np.eye(3))) < 1.0


def test_bad_input_is_one_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown preset 'lunar'"):
        SimConfig(preset="lunar")
    bad = tmp_path / "poses.txt"
    bad.write_text("1 2 3\n")
    with pytest.raises(ValueError, match="not a KITTI pose file"):
        camera_trajectory(SimConfig(poses_file=str(bad)))
    with pytest.raises(ValueError, match="below the horizon"):
        simulate(SimConfig(**SMALL, frames=2, start_time="2011-09-30T22:00:00Z"), tmp_path / "night")
    (tmp_path / "exists").mkdir()
    with pytest.raises(ValueError, match="exists: refusing"):
        simulate(SimConfig(**SMALL, frames=2), tmp_path / "exists")
    with pytest.raises(ValueError, match="not ISO 8601"):
        _ = SimConfig(start_time="yesterday").epoch


def test_degradations_are_what_they_say(tmp_path: Path) -> None:
    import cv2
    from pvo_sim.degrade import Degradations, ImageDegrader, distortion_maps, exposure_gains

    mx, my = distortion_maps(320, 120, 185.4, 0.0)
    v, u = np.mgrid[0:120, 0:320]
    np.testing.assert_allclose(mx, u, atol=1e-4)
    np.testing.assert_allclose(my, v, atol=1e-4)
    for kappa in (-0.3, 0.2, 0.01):
        mx, my = distortion_maps(320, 120, 185.4, kappa)
        assert mx.min() >= -0.5 and mx.max() <= 319.5 and my.min() >= -0.5 and my.max() <= 119.5  # cropped to valid
        assert abs(mx[60, 160] - 160) < 1.0 and abs(my[60, 160] - 60) < 1.0  # the centre stays
    gains = exposure_gains(200, 0.3, seed=1)
    assert 0.7 <= gains.min() < 0.95 and 1.05 < gains.max() <= 1.3 and np.max(np.abs(np.diff(gains))) < 0.05
    flat = np.full((120, 320), 100, dtype=np.uint8)
    noisy = ImageDegrader(Degradations(noise=4.0), 320, 120, 185.4, 1, seed=0)(flat, 0)
    assert abs(float(noisy.std()) - 4.0) < 0.2
    with pytest.raises(ValueError, match="--distortion"):
        Degradations(distortion=2.0)
    out = tmp_path / "miscal"
    config = render(out, frames=2, degradations=Degradations(focal_scale=1.1, baseline_scale=0.9, blur_px=5))
    p1 = np.array([float(v) for v in (out / "calib.txt").read_text().splitlines()[1].split()[1:]])
    assert p1[0] == pytest.approx(1.1 * config.focal)
    assert p1[3] == pytest.approx(-1.1 * config.focal * 0.9 * config.baseline)
    blurred = cv2.imread(str(out / "image_0" / "000001.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    sharp_dir = tmp_path / "sharp"
    render(sharp_dir, frames=2)
    sharp = cv2.imread(str(sharp_dir / "image_0" / "000001.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    assert np.abs(np.diff(blurred, axis=1)).mean() < 0.8 * np.abs(np.diff(sharp, axis=1)).mean()


def test_the_thesis_plumb_bob_distortion_matches_opencv() -> None:
    """(k1, k2, k3) = (-0.3, 0.2, 0.01), the thesis's ch. 6: each output pixel samples the render where OpenCV's
    plumb-bob model (cv2.projectPoints with those coefficients) puts the same ray; one number is k1 alone;
    a folding model and too many coefficients are one-line errors."""
    import cv2
    from pvo_sim.degrade import Degradations, distortion_maps

    width, height, focal = 320, 120, 185.4
    mx, my = distortion_maps(width, height, focal, (-0.3, 0.2, 0.01))
    cu, cv = (width - 1) / 2.0, (height - 1) / 2.0
    v, u = np.mgrid[0:height:7, 0:width:11].astype(np.float64)
    rays = np.column_stack([(u.ravel() - cu) / focal, (v.ravel() - cv) / focal, np.ones(u.size)])  # barrel: no crop
    camera = np.array([[focal, 0.0, cu], [0.0, focal, cv], [0.0, 0.0, 1.0]])
    projected, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), camera, np.array([-0.3, 0.2, 0.0, 0.0, 0.01]))
    sampled = np.column_stack([mx[0:height:7, 0:width:11].ravel(), my[0:height:7, 0:width:11].ravel()])
    np.testing.assert_allclose(sampled, projected[:, 0, :], atol=1e-3)
    np.testing.assert_array_equal(distortion_maps(width, height, focal, 0.2)[0], distortion_maps(width, height, focal, (0.2,))[0])
    assert Degradations(distortion=[-0.3, 0.2, 0.01]).radial == (-0.3, 0.2, 0.01)  # a YAML list from a manifest
    with pytest.raises(ValueError, match="folds the image"):
        distortion_maps(width, height, focal, (-0.5, 0.0, 0.0))
    with pytest.raises(ValueError, match="one to three coefficients"):
        Degradations(distortion=(0.1, 0.1, 0.1, 0.1))


def test_a_pole_casts_its_shadow_away_from_the_sun_azimuth() -> None:
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    mujoco = pytest.importorskip("mujoco")
    from pvo_sim.render import open_renderer, place_rig, place_sun

    origin = GeodeticOrigin(49.011, 8.4245, 115.0)
    when = SimConfig(start_time="2011-09-30T14:00:00Z").epoch  # afternoon: sun in the south-west
    sun = sun_direction_enu(origin, when)
    xml = """<mujoco><visual><global offwidth="400" offheight="400"/><quality shadowsize="2048"/>
      <map znear="0.01" zfar="50" shadowclip="0.5"/></visual>
      <statistic extent="20" center="0 0 0"/>
      <worldbody>
        <light name="sun" directional="true" castshadow="true" dir="0 0 -1" ambient="0.3 0.3 0.3" diffuse="0.9 0.9 0.9"/>
        <geom type="plane" size="20 20 0.1" rgba="0.8 0.8 0.8 1"/>
        <geom type="cylinder" pos="0 0 1.5" size="0.15 1.5" rgba="0.8 0.8 0.8 1"/>
        <body name="rig" mocap="true"><camera name="left" fovy="60"/></body>
      </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    # a camera 12 m above the pole looking straight down, image x = east, image y = south
    pose = np.eye(4)
    pose[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    pose[:3, 3] = [0.0, 0.0, 12.0]
    place_rig(data, model.body("rig").mocapid[0], pose)
    place_sun(model, model.light("sun").id, sun, pose[:3, 3])
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    try:
        renderer = open_renderer(model, 400, 400)
    except ValueError as exc:
        pytest.skip(str(exc))
    try:
        renderer.update_scene(data, camera="left")
        grey = renderer.render().mean(axis=2)
    finally:
        renderer.close()
    import cv2

    # the shadow is the largest dark blob; a morphological opening removes isolated shadow-map acne
    mask = (grey < 0.75 * np.median(grey)).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    count, labels, stats, _ = cv2.connectedComponentsWithStats(mask)
    assert count > 1
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    rows, cols = np.nonzero(labels == largest)
    centre = (400 - 1) / 2.0
    east, north = cols - centre, -(rows - centre)
    far = np.hypot(east, north) > 15  # away from the pole itself
    assert far.sum() > 100
    shadow_azimuth = np.degrees(np.arctan2(east[far].mean(), north[far].mean())) % 360
    sun_azimuth = np.degrees(np.arctan2(sun[0], sun[1])) % 360
    difference = (shadow_azimuth - (sun_azimuth + 180.0) + 180.0) % 360 - 180.0
    print(f"shadow azimuth {shadow_azimuth:.2f} deg, sun azimuth {sun_azimuth:.2f} deg, off by {difference:+.2f} deg")
    assert abs(difference) < 3.0, (shadow_azimuth, sun_azimuth)


def test_a_wall_between_the_sun_and_the_camera_shades_the_ground_the_camera_sees() -> None:
    """Revision 9: MuJoCo culls a directional light's shadow casters behind the light's position, so a sun light
    placed at the camera (revisions up to 8) let nothing on the sun's side of the camera cast a shadow. A 12 m wall
    5 m to the east of a camera looking north, the sun in the east 30 deg up: the ground ahead lies in the wall's
    shadow (it reaches 21 m west of the wall) and renders dark; with the light at the camera it rendered lit."""
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    mujoco = pytest.importorskip("mujoco")
    from pvo_sim.render import open_renderer, place_rig, place_sun

    xml = """<mujoco><visual><global offwidth="160" offheight="120"/><quality shadowsize="2048"/>
      <map znear="0.005" zfar="10" shadowclip="1.5"/></visual>
      <statistic extent="40" center="0 0 0"/>
      <worldbody>
        <light name="sun" directional="true" castshadow="true" dir="0 0 -1" ambient="0.2 0.2 0.2" diffuse="0.8 0.8 0.8"/>
        <geom type="plane" size="100 100 0.1" rgba="0.8 0.8 0.8 1"/>
        <geom name="wall" type="box" pos="5.25 20 6" size="0.25 20 6" rgba="0.8 0.8 0.8 1"/>
        <body name="rig" mocap="true"><camera name="left" fovy="60"/></body>
      </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    sun = np.array([np.cos(np.radians(30.0)), 0.0, np.sin(np.radians(30.0))])  # east, 30 deg up
    pose = np.eye(4)  # optical x east, y down, z north
    pose[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    pose[:3, 3] = [0.0, 0.0, 1.65]
    place_rig(data, model.body("rig").mocapid[0], pose)
    try:
        renderer = open_renderer(model, 120, 160)
    except ValueError as exc:
        pytest.skip(str(exc))

    def ground_ahead(light_at_camera: bool, wall: bool) -> float:
        place_sun(model, model.light("sun").id, sun, pose[:3, 3], **({"distance": 0.0} if light_at_camera else {}))
        model.geom_rgba[model.geom("wall").id, 3] = 1.0
        model.geom_group[model.geom("wall").id] = 0 if wall else 5
        mujoco.mj_kinematics(model, data)
        mujoco.mj_camlight(model, data)
        option = mujoco.MjvOption()
        option.geomgroup[5] = 0
        renderer.update_scene(data, camera="left", scene_option=option)
        grey = renderer.render().mean(axis=2)
        return float(np.median(grey[90:120, 50:110]))  # the ground 2-6 m ahead, left of the wall

    try:
        open_ground = ground_ahead(False, wall=False)
        shaded, cut = ground_ahead(False, wall=True), ground_ahead(True, wall=True)
    finally:
        renderer.close()
    print(f"ground ahead: no wall {open_ground:.1f}, wall {shaded:.1f}, wall with the light at the camera {cut:.1f}")
    assert shaded < 0.5 * open_ground  # sunlight gone: only the ambient term is left
    assert cut > 0.9 * open_ground  # what revisions up to 8 drew


def test_the_culler_keeps_what_may_shade_the_view_from_behind() -> None:
    """RangeCuller hides geoms out of range, and those behind the camera beyond 25 m — unless they stand up-sun of
    it (revision 9), where a low sun throws their shadows forward into view."""
    mujoco = pytest.importorskip("mujoco")
    from pvo_sim.render import HIDDEN_GROUP, RangeCuller

    xml = """<mujoco><worldbody>
        <geom type="plane" size="100 100 0.1"/>
        <geom name="ahead" type="box" pos="0 40 2" size="1 1 2"/>
        <geom name="near_behind" type="box" pos="0 -10 2" size="1 1 2"/>
        <geom name="behind_east" type="box" pos="20 -40 2" size="1 1 2"/>
        <geom name="behind_west" type="box" pos="-20 -40 2" size="1 1 2"/>
        <geom name="far" type="box" pos="0 300 2" size="1 1 2"/>
      </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    pose = np.eye(4)  # at the origin looking north (optical z)
    pose[:3, :3] = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
    pose[:3, 3] = [0.0, 0.0, 1.65]
    cull = RangeCuller(model)
    names = ("ahead", "near_behind", "behind_east", "behind_west", "far")

    def hidden() -> dict[str, bool]:
        return {name: bool(model.geom_group[model.geom(name).id] == HIDDEN_GROUP) for name in names}

    cull(data, pose)  # overcast: no shadows to keep
    assert hidden() == {"ahead": False, "near_behind": False, "behind_east": True, "behind_west": True, "far": True}
    low_sun_behind_east = np.array([0.95, -0.1, 0.3])
    cull(data, pose, low_sun_behind_east / np.linalg.norm(low_sun_behind_east))
    assert hidden() == {"ahead": False, "near_behind": False, "behind_east": False, "behind_west": True, "far": True}
    assert model.geom_group[0] != HIDDEN_GROUP  # the unbounded ground plane always drawn


def test_rig_and_light_placement_match_the_truth() -> None:
    import os

    os.environ.setdefault("MUJOCO_GL", "egl")
    mujoco = pytest.importorskip("mujoco")
    from pvo_sim.render import place_rig, place_sun
    from pvo_sim.world import WorldSpec, build_world

    poses = camera_trajectory(SimConfig(**SMALL, frames=30))
    model = build_world(WorldSpec(), poses, 1.65).compile()
    data = mujoco.MjData(model)
    sun = np.array([0.3, -0.5, 0.81])
    sun /= np.linalg.norm(sun)
    for k in (0, 17, 29):
        place_rig(data, model.body("rig").mocapid[0], poses[k])
        place_sun(model, model.light("sun").id, sun, poses[k, :3, 3])
        mujoco.mj_kinematics(model, data)
        mujoco.mj_camlight(model, data)
        left, right = model.camera("left").id, model.camera("right").id
        np.testing.assert_allclose(data.cam_xpos[left], poses[k, :3, 3], atol=1e-9)
        # MuJoCo camera axes: x right, y up, z backwards = optical (x, -y, -z)
        np.testing.assert_allclose(data.cam_xmat[left].reshape(3, 3), poses[k, :3, :3] @ np.diag([1.0, -1.0, -1.0]), atol=1e-9)
        np.testing.assert_allclose(data.cam_xpos[right], poses[k, :3, 3] + 0.54 * poses[k, :3, 0], atol=1e-9)
        np.testing.assert_allclose(data.light_xdir[model.light("sun").id], -sun, atol=1e-12)


def test_vehicles_at_their_own_speed_pass_a_stopped_camera() -> None:
    """``vehicle_speed``: beside a camera that stands still each moving vehicle still drives, 3.5 m to the path's
    left and against its direction, every step its own speed (within +-30 % of the asked one) times the frame
    interval, but where it comes round again; without it the vehicles replay the camera's path (here: stand still),
    and the recorded configuration names the option only when it is set (earlier content hashes stay)."""
    from dataclasses import replace

    from pvo_sim.degrade import Degradations
    from pvo_sim.render import recorded_config
    from pvo_sim.world import WorldSpec, build_world

    stopped = np.tile(camera_trajectory(SimConfig(**SMALL, frames=2))[:1], (30, 1, 1))
    forward = stopped[0, :2, 2] / np.linalg.norm(stopped[0, :2, 2])  # the optical axis, horizontal: the path's way
    stopped[:, :2, 3] += 1e-4 * np.arange(30)[:, None] * forward  # creeping 1 mm/s: the road runs its way
    spec = WorldSpec(moving_vehicles=4, vehicle_speed=10.0, frame_interval=0.1)
    world = build_world(spec, stopped, 1.65)
    assert len(world.moving_paths) == 4
    for path, heading in zip(world.moving_paths, world.moving_headings, strict=True):
        steps = np.diff(path[:, :2], axis=0)
        lengths = np.linalg.norm(steps, axis=1)
        driving = lengths < 5.0  # a wrap round the 160 m path is one jump
        assert driving.sum() >= 28 and 0.7 - 1e-9 <= lengths[driving].mean() <= 1.3 + 1e-9
        np.testing.assert_allclose(lengths[driving], lengths[driving][0], rtol=1e-6)
        np.testing.assert_allclose(steps[driving] @ forward, -lengths[driving], rtol=1e-6)  # oncoming
        offsets = (path[:, :2] - stopped[0, :2, 3]) @ np.array([forward[1], -forward[0]])  # to the path's right
        np.testing.assert_allclose(offsets, -3.5, atol=1e-6)
        np.testing.assert_allclose(np.cos(heading), -forward[0], atol=1e-9)
    replaying = build_world(replace(spec, vehicle_speed=0.0), stopped, 1.65)
    for path in replaying.moving_paths:
        assert np.abs(np.diff(path, axis=0)).max() < 5e-3  # creeping with the camera (3 mm where one comes round)
    plain = SimConfig(**SMALL)
    assert "vehicle_speed" not in recorded_config(plain)["degradations"]
    fast = replace(plain, degradations=Degradations(moving_vehicles=2, vehicle_speed=8.0))
    assert recorded_config(fast)["degradations"]["vehicle_speed"] == 8.0
    with pytest.raises(ValueError, match=r"--vehicle-speed must be in \[0, 40\] m/s, got -1.0"):
        Degradations(vehicle_speed=-1.0)


def _driven_then_stopped(stop: bool, frames: int = 40) -> np.ndarray:
    """Camera poses (N, 4, 4) looking along +x: 0.5 m per frame that way, then (``stop``) the second half at a
    standstill whose positions jitter by up to 8 mm, as KITTI's do (07 from frame 660)."""
    rng = np.random.default_rng(4)
    x = 0.5 * np.arange(frames, dtype=float)
    y = np.zeros(frames)
    if stop:
        x[frames // 2 :] = x[frames // 2]
        x[frames // 2 :] += rng.uniform(-0.004, 0.004, frames - frames // 2)
        y[frames // 2 :] += rng.uniform(-0.004, 0.004, frames - frames // 2)
    poses = np.tile(np.eye(4), (frames, 1, 1))
    poses[:, :3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # optical x, y, z in ENU
    poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3] = x, y, 1.65
    return poses


def test_a_stopped_cameras_jitter_steers_neither_the_vehicles_nor_the_road(tmp_path: Path) -> None:
    """At a standstill the direction of one jittering step points anywhere; there the camera's heading is the
    path's. Vehicles replaying the path keep the way it drove — 3.5 m to its left, facing against it — where before
    revision 8 they circled the stopped camera 3.5 m away; the road beyond its end runs on the way the camera faces.
    A path that never stops keeps np.gradient's directions to the bit (its worlds are revision 7's, recorded so)."""
    import yaml
    from pvo_sim.render import (
        RENDERER_REVISION,
        STEADIED_REVISION,
        UNCHANGED_SINCE_REVISION,
        rendered_by_this_renderer,
        renderer_revision,
    )
    from pvo_sim.world import WorldSpec, build_world, end_direction, horizontal_headings, steady_directions

    stopped, moving = _driven_then_stopped(True), _driven_then_stopped(False)
    world = build_world(WorldSpec(moving_vehicles=4, image_size=(64, 48)), stopped, 1.65)
    for path, heading in zip(world.moving_paths, world.moving_headings, strict=True):
        np.testing.assert_allclose(path[:, 1], 3.5, atol=0.01)  # the path's y jitters by 4 mm at most
        np.testing.assert_allclose(np.abs(np.angle(np.exp(1j * (heading - np.pi)))), 0.0, atol=0.02)
    headings = horizontal_headings(stopped)
    np.testing.assert_allclose(headings, np.tile([1.0, 0.0], (len(stopped), 1)), atol=1e-12)
    down = np.eye(4)[None].copy()
    down[0, :3, :3] = np.diag([1.0, -1.0, -1.0])  # the optical axis straight down: no heading, north by convention
    np.testing.assert_allclose(horizontal_headings(down), [[0.0, 1.0]])
    np.testing.assert_allclose(end_direction(stopped[:, :2, 3], headings[-1], -1), [1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(end_direction(stopped[:, :2, 3], headings[0], 0), [-1.0, 0.0], atol=1e-12)
    turned = np.array([0.0, 1.0])  # a stopped end follows the camera; a moving one its own last step
    np.testing.assert_allclose(end_direction(stopped[:, :2, 3], turned, -1), turned, atol=1e-12)
    np.testing.assert_allclose(end_direction(stopped[:, :2, 3], turned, 0), [-1.0, 0.0], atol=1e-12)
    gradient = np.gradient(moving[:, :2, 3], axis=0)
    expected = gradient / np.maximum(np.linalg.norm(gradient, axis=1, keepdims=True), 1e-9)
    assert np.array_equal(steady_directions(moving[:, :2, 3], horizontal_headings(moving)), expected)
    # revision 9 (shadows from the sun's side of the camera) changes every sequence with sunshine; without it
    # (overcast) a sequence keeps the revision that last changed it
    assert renderer_revision(stopped, 4) == renderer_revision(moving, 0) == RENDERER_REVISION == 9
    assert renderer_revision(stopped, 4, overcast=True) == STEADIED_REVISION == 8
    assert renderer_revision(stopped, 0, overcast=True) == 8  # the road beyond a stopped end, vehicles or none
    assert renderer_revision(moving, 4, overcast=True) == UNCHANGED_SINCE_REVISION == 7
    middle = np.concatenate([stopped[:30], moving[30:] + np.array([[0, 0, 0, -5.0]] + [[0, 0, 0, 0]] * 3)])
    assert renderer_revision(middle, 0, True) == 7 and renderer_revision(middle, 2, True) == 8  # only vehicles replay a stop
    # a folder is this renderer's when it records the revision its own path and sky give
    cases = (
        ("a", stopped, 7, True, False),
        ("b", stopped, 8, True, True),
        ("c", moving, 7, True, True),
        ("d", moving, 7, False, False),  # sunshine rendered before revision 9: its shadows were cut
        ("e", moving, 9, False, True),
    )
    for name, poses, revision, overcast, expected_current in cases:
        folder = tmp_path / name
        folder.mkdir()
        first = poses[0].copy()
        relative = np.linalg.inv(first) @ poses
        np.savetxt(folder / "poses.txt", relative[:, :3, :].reshape(-1, 12))
        config = {"overcast": overcast, "degradations": {"moving_vehicles": 3}}
        meta = {"renderer_revision": revision, "world_T_cam0": first.tolist(), "config": config}
        (folder / "sim.yaml").write_text(yaml.safe_dump(meta))
        assert rendered_by_this_renderer(folder) is expected_current, name
    assert not rendered_by_this_renderer(tmp_path / "missing")


def test_kitti_ground_truth_replay(pvo_data: Path, tmp_path: Path) -> None:
    poses_file = pvo_data / "kitti" / "poses" / "06.txt"
    config = render(tmp_path / "kitti", frames=4, poses_file=str(poses_file), start_frame=100)
    written = read_kitti_poses(tmp_path / "kitti" / "poses.txt")
    kitti = read_kitti_poses(poses_file)[100:104]
    # KITTI's turns exactly; each step's horizontal motion kept, its climb lost (the world is flat)
    steps, true_steps = np.linalg.inv(written[:-1]) @ written[1:], np.linalg.inv(kitti[:-1]) @ kitti[1:]
    np.testing.assert_allclose(steps[:, :3, :3], true_steps[:, :3, :3], atol=1e-9)
    lengths, true_lengths = np.linalg.norm(steps[:, :3, 3], axis=1), np.linalg.norm(true_steps[:, :3, 3], axis=1)
    np.testing.assert_allclose(lengths, true_lengths, rtol=0.01)
    assert config.frames == 4


def test_a_long_kitti_drive_stays_on_the_ground(pvo_data: Path) -> None:
    from pvo_sim.paths import kitti_path

    poses = kitti_path(pvo_data / "kitti" / "poses" / "05.txt", 1000, 0, 1.65, heading_deg=30.0)
    np.testing.assert_allclose(poses[:, 2, 3], 1.65)  # replayed as recorded, this window climbs 12 m
    up = -poses[:, :3, 1]  # the cameras' up (optical y is down) in ENU
    assert np.degrees(np.arccos(up[:, 2])).max() < 5.0  # a car's pitch and roll, not a tilted world
    true = read_kitti_poses(pvo_data / "kitti" / "poses" / "05.txt")[:1000]
    true_steps = np.linalg.inv(true[:-1]) @ true[1:]
    np.testing.assert_allclose((np.linalg.inv(poses[:-1]) @ poses[1:])[:, :3, :3], true_steps[:, :3, :3], atol=1e-9)


def test_a_short_window_levelled_over_its_drive_pitches_as_the_long_drive_does(pvo_data: Path) -> None:
    """KITTI 10's frames 500-600 go down a slope: levelled on itself, a 60-frame window there stays within a few
    degrees of level; levelled over the 1000 frames around it (``level_frames``), each camera's pitch against the
    flat ground is the 1000-frame drive's at the same frame."""
    from pvo_sim.paths import kitti_path

    drive = pvo_data / "kitti" / "poses" / "10.txt"

    def pitch(poses: np.ndarray) -> np.ndarray:  # the optical axis above the horizon (ENU: z up), degrees
        return np.degrees(np.arcsin(poses[:, 2, 2]))

    long = kitti_path(drive, 1000, 40, 1.65)  # frames 40-1039: centred on the window below
    alone = kitti_path(drive, 60, 510, 1.65)
    levelled = kitti_path(drive, 60, 510, 1.65, level_frames=1000)
    assert np.abs(pitch(alone)).max() < 3.0 and pitch(long)[470:530].min() < -6.0
    np.testing.assert_allclose(pitch(levelled), pitch(long)[470:530], atol=1e-4)  # poses to 12 digits
    np.testing.assert_allclose(levelled[:, 2, 3], 1.65)
    steps = np.linalg.inv(levelled[:-1]) @ levelled[1:]  # the motion itself is KITTI's either way
    np.testing.assert_allclose(steps[:, :3, :3], (np.linalg.inv(alone[:-1]) @ alone[1:])[:, :3, :3], atol=1e-9)
    # near the drive's end the stretch is clipped to the drive, never shorter than asked
    end = kitti_path(drive, 60, 1140, 1.65, level_frames=1000)  # frames 1140-1199 of 1201, levelled over 201-1200
    np.testing.assert_allclose(pitch(end), pitch(kitti_path(drive, 1000, 201, 1.65))[939:999], atol=1e-4)
    with pytest.raises(ValueError, match="level_frames must be >= 0"):
        kitti_path(drive, 60, 510, 1.65, level_frames=-1)


def test_a_drive_replayed_faster_covers_more_road_at_the_same_frame_rate(pvo_data: Path) -> None:
    """``speed_scale`` 2 is every second pose of the drive exactly; 1.5 puts every other camera halfway between two
    poses (position the mean, rotation the slerp midpoint); the speed scales with it; bad factors are one line."""
    from pvo_core.lie import so3_log
    from pvo_sim.paths import kitti_path, resample_poses

    drive = pvo_data / "kitti" / "poses" / "04.txt"
    true = read_kitti_poses(drive)
    as_driven = kitti_path(drive, 121, 20, 1.65)
    doubled = kitti_path(drive, 61, 20, 1.65, speed_scale=2.0)
    assert len(doubled) == 61
    np.testing.assert_allclose(doubled, as_driven[::2], atol=1e-9)  # whole indices: the drive's own poses
    faster = kitti_path(drive, 41, 20, 1.65, speed_scale=1.5)
    stretch = kitti_path(drive, 61, 20, 1.65)  # the same 61 poses of road, levelled alike
    np.testing.assert_allclose(faster[::2], stretch[::3], atol=1e-9)
    middle = faster[1]  # the drive's frame 21.5 (start 20): between its poses 1 and 2 of the window
    np.testing.assert_allclose(middle[:3, 3], (stretch[1, :3, 3] + stretch[2, :3, 3]) / 2, atol=1e-9)
    half = so3_log(stretch[1, :3, :3].T @ middle[:3, :3])
    np.testing.assert_allclose(half, so3_log(stretch[1, :3, :3].T @ stretch[2, :3, :3]) / 2, atol=1e-9)
    speed = np.linalg.norm(np.diff(faster[:, :3, 3], axis=0), axis=1).mean() * 10.0
    driven = np.linalg.norm(np.diff(true[20:81, :3, 3], axis=0), axis=1).mean() * 10.0
    assert speed == pytest.approx(1.5 * driven, rel=0.01)  # 04 at about 14 m/s becomes about 21 m/s
    end = kitti_path(drive, 200, len(true) - 31, 1.65, speed_scale=3.0)  # clipped at the drive's end, as before
    assert len(end) == 11
    with pytest.raises(ValueError, match="speed_scale must be positive"):
        kitti_path(drive, 60, 20, 1.65, speed_scale=0.0)
    with pytest.raises(ValueError, match="resample times must lie in"):
        resample_poses(true[:5], np.array([0.0, 4.5]))
    with pytest.raises(ValueError, match="--speed-scale must be positive"):
        SimConfig(speed_scale=-1.0)


def test_a_drive_replayed_at_a_crawl_nearly_stands_still(pvo_data: Path) -> None:
    """``speed_scale`` 0.02 (the corpus's floor): 50 cameras between the drive's first two poses of the window,
    each step a fiftieth of the drive's, the turn between them slerped in fifty equal parts."""
    from pvo_core.lie import so3_log
    from pvo_sim.paths import kitti_path

    drive = pvo_data / "kitti" / "poses" / "07.txt"
    crawl = kitti_path(drive, 50, 100, 1.65, speed_scale=0.02)
    driven = kitti_path(drive, 2, 100, 1.65)
    assert len(crawl) == 50
    np.testing.assert_allclose(crawl[0], driven[0], atol=1e-9)
    steps = np.linalg.norm(np.diff(crawl[:, :3, 3], axis=0), axis=1)
    np.testing.assert_allclose(steps, 0.02 * np.linalg.norm(driven[1, :3, 3] - driven[0, :3, 3]), rtol=1e-6)
    turn = so3_log(driven[0, :3, :3].T @ driven[1, :3, :3])
    np.testing.assert_allclose(so3_log(crawl[0, :3, :3].T @ crawl[1, :3, :3]), 0.02 * turn, atol=1e-12)


def test_a_failed_render_keeps_the_previous_output(tmp_path: Path, monkeypatch) -> None:
    import pvo_sim.render as sim

    out = tmp_path / "keep"
    render(out, frames=2)
    before = (out / "image_0" / "000001.png").read_bytes()

    def broken(*args, **kwargs):
        raise RuntimeError("renderer crashed")

    monkeypatch.setattr(sim, "_render", broken)
    with pytest.raises(RuntimeError, match="renderer crashed"):
        simulate(SimConfig(**SMALL, frames=2, seed=9), out, overwrite=True)
    assert (out / "image_0" / "000001.png").read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["keep"]  # no partial directory left behind


def test_a_drive_file_is_read_once_per_version(tmp_path: Path) -> None:
    """drive_poses: the same array for the same file (a corpus plans hundreds of windows of one drive), read
    again once the file is rewritten, and never writable (it is shared)."""
    import os

    from pvo_sim.paths import drive_poses

    drive = tmp_path / "00.txt"
    drive.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3)
    first = drive_poses(drive)
    assert drive_poses(drive) is first and first.shape == (3, 4, 4)
    with pytest.raises(ValueError):
        first[0, 0, 3] = 1.0
    drive.write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * 3 + "1 0 0 2 0 1 0 0 0 0 1 0\n")
    os.utime(drive, ns=(drive.stat().st_atime_ns, drive.stat().st_mtime_ns + 1_000_000))
    again = drive_poses(drive)
    assert again.shape == (4, 4, 4) and again[3, 0, 3] == 2.0
