"""`pvo sim OUT`: render a synthetic stereo sequence with :mod:`pvo_sim` (and convert it to a bag with --bag)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from pvo_sim import KITTI_FOCAL_PER_PIXEL_WIDTH, CameraModel, Degradations, ImuNoise, SimConfig, simulate

from ..progress import Progress


def register(sub: Any) -> None:
    sim = sub.add_parser("sim", help="render a synthetic stereo sequence (MuJoCo) under the real sun, with IMU, GPS and truth")
    sim.set_defaults(handler=run)
    sim.add_argument("out", type=Path, help="output directory (KITTI odometry layout plus sidecars)")
    sim.add_argument("--preset", default="urban", help="urban | planetary (default urban)")
    sim.add_argument("--frames", type=int, default=100, help="number of stereo frames (default 100)")
    sim.add_argument("--size", default="620x188", help="image size WxH (default 620x188)")
    sim.add_argument("--focal", type=float, help="focal length in px (default: KITTI's 718.856 scaled to the width)")
    sim.add_argument("--baseline", type=float, default=0.54, help="stereo baseline in m (default 0.54)")
    sim.add_argument("--rate", type=float, default=10.0, help="frame rate in Hz (default 10)")
    sim.add_argument("--colour", action="store_true", help="colour images (image_2/image_3) instead of grey")
    sim.add_argument("--path", default="loop", help="procedural path: loop | straight | s-curve (default loop)")
    sim.add_argument("--poses", type=Path, help="replay a KITTI ground-truth pose file instead of a procedural path")
    sim.add_argument("--start", type=int, default=0, help="with --poses: first pose")
    sim.add_argument(
        "--level-frames",
        type=int,
        default=0,
        metavar="N",
        help="with --poses: level the drive onto the flat ground over N of its frames around the window (default 0: "
        "over the window itself)",
    )
    sim.add_argument(
        "--speed-scale",
        type=float,
        default=1.0,
        metavar="S",
        help="with --poses: replay the drive S times faster (frame k at the drive's pose start + k*S; default 1)",
    )
    sim.add_argument("--speed", type=float, default=8.0, help="procedural path speed in m/s (default 8)")
    sim.add_argument("--heading", type=float, default=0.0, help="heading, degrees clockwise from north (turns the path)")
    sim.add_argument("--pitch", type=float, default=0.0, help="cameras pitched down by this many degrees (default 0)")
    sim.add_argument("--lat", type=float, default=49.011, help="latitude of the world origin (default Karlsruhe)")
    sim.add_argument("--lon", type=float, default=8.4245, help="longitude of the world origin")
    sim.add_argument("--alt", type=float, default=115.0, help="altitude of the world origin (m)")
    sim.add_argument("--start-time", default="2011-09-30T11:30:00Z", help="UTC time of the first frame (ISO 8601)")
    sim.add_argument("--overcast", action="store_true", help="diffuse light, no cast shadows")
    sim.add_argument(
        "--sky",
        choices=("gradient", "sun"),
        default="gradient",
        help="gradient: one sky for every sun (default); sun: the CIE standard clear sky, brightest about the sun and "
        "towards the horizon (with --overcast, the CIE overcast sky)",
    )
    sim.add_argument("--night", action="store_true", help="render even when the sun is below the horizon")
    sim.add_argument(
        "--supersample",
        type=int,
        default=0,
        help="render N times larger, average down (1-4; default 0: 2 for both presets)",
    )
    sim.add_argument("--depth", action="store_true", help="also write depth_0/*.png (16-bit, metres x 256)")
    sim.add_argument("--seed", type=int, default=0, help="world and noise seed (default 0)")
    sim.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    sim.add_argument("--bag", type=Path, help="also convert the result to this rosbag2 (images, truth, sun, IMU, GPS)")
    sensors = sim.add_argument_group("IMU and GPS noise")
    sensors.add_argument("--gyro-noise", type=float, default=0.0, help="gyro white noise density, rad/s/sqrt(Hz)")
    sensors.add_argument("--accel-noise", type=float, default=0.0, help="accelerometer white noise density, m/s^2/sqrt(Hz)")
    sensors.add_argument("--gyro-bias", type=float, nargs=3, default=[0.0, 0.0, 0.0], metavar="B", help="gyro bias, rad/s")
    sensors.add_argument("--accel-bias", type=float, nargs=3, default=[0.0, 0.0, 0.0], metavar="B", help="accel bias, m/s^2")
    sensors.add_argument("--gps-sigma", type=float, default=0.0, help="GPS position noise std, m")
    deg = sim.add_argument_group("degradations")
    deg.add_argument(
        "--distortion",
        type=float,
        nargs="+",
        default=[0.0],
        metavar="K",
        help="plumb-bob radial distortion k1 [k2 k3], then crop (the thesis's ch. 6: -0.3 0.2 0.01)",
    )
    deg.add_argument("--blur", type=float, default=0.0, help="horizontal motion blur length in px")
    deg.add_argument("--exposure", type=float, default=0.0, help="exposure change amplitude (relative gain, e.g. 0.3)")
    deg.add_argument("--noise", type=float, default=0.0, help="sensor noise std in grey levels")
    deg.add_argument("--focal-scale", type=float, default=1.0, help="write calib.txt with the focal length times this")
    deg.add_argument("--baseline-scale", type=float, default=1.0, help="write calib.txt with the baseline times this")
    deg.add_argument("--texture-poor", type=float, default=0.0, help="urban: fraction of buildings with plain walls")
    deg.add_argument("--moving", type=int, default=3, help="urban: number of independently moving vehicles")
    deg.add_argument(
        "--vehicle-speed",
        type=float,
        default=0.0,
        help="urban: the moving vehicles' own speed in m/s, each within +-30 %% (default 0: each replays the camera's "
        "path in the oncoming lane, at the camera's speed of another moment)",
    )
    cam = sim.add_argument_group("camera model (applied to every image; --linear-camera keeps the raw render)")
    cam.add_argument("--linear-camera", action="store_true", help="no auto-exposure, vignetting, noise, gamma or JPEG")
    cam.add_argument("--exposure-target", type=float, default=0.42, help="auto-exposure mean brightness, 0-1 (default 0.42)")
    cam.add_argument("--fixed-gain", type=float, help="a fixed exposure gain instead of auto-exposure")
    cam.add_argument("--gamma", type=float, default=2.2, help="encoding gamma (default 2.2)")
    cam.add_argument("--vignetting", type=float, default=0.25, help="relative fall-off at the corners (default 0.25)")
    cam.add_argument("--full-well", type=float, default=6000.0, help="electrons at saturation, for shot noise (0: none)")
    cam.add_argument("--read-noise", type=float, default=1.0, help="read noise std, grey levels (default 1)")
    cam.add_argument("--sharpening", type=float, default=1.0, help="in-camera unsharp mask amount, 0-3 (default 1)")
    cam.add_argument("--jpeg", type=int, default=0, help="JPEG quality 1-100 (default 0: lossless PNG only)")
    sim.add_argument("--quiet", "-q", action="store_true", help="no progress output")


def parse_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {text!r} must be WIDTHxHEIGHT, e.g. 620x188") from None
    return width, height


def camera_model(args: argparse.Namespace) -> CameraModel:
    if args.linear_camera:
        return CameraModel.linear()
    return CameraModel(
        auto_exposure=args.fixed_gain is None,
        target=args.exposure_target,
        gain=args.fixed_gain or 1.0,
        gamma=args.gamma,
        vignetting=args.vignetting,
        full_well=args.full_well,
        read_noise=args.read_noise,
        sharpening=args.sharpening,
        jpeg_quality=args.jpeg,
    )


def run(args: argparse.Namespace) -> int:
    width, height = parse_size(args.size)
    config = SimConfig(
        preset=args.preset,
        frames=args.frames,
        width=width,
        height=height,
        focal=args.focal or KITTI_FOCAL_PER_PIXEL_WIDTH * width,
        baseline=args.baseline,
        rate=args.rate,
        colour=args.colour,
        path=args.path,
        poses_file=str(args.poses) if args.poses else "",
        start_frame=args.start,
        level_frames=args.level_frames,
        speed_scale=args.speed_scale,
        speed=args.speed,
        heading_deg=args.heading,
        pitch_deg=args.pitch,
        latitude=args.lat,
        longitude=args.lon,
        altitude=args.alt,
        start_time=args.start_time,
        overcast=args.overcast,
        sky=args.sky,
        night=args.night,
        depth=args.depth,
        supersample=args.supersample,
        seed=args.seed,
        imu=ImuNoise(args.gyro_noise, args.accel_noise, tuple(args.gyro_bias), tuple(args.accel_bias)),
        gps_sigma=args.gps_sigma,
        degradations=Degradations(
            distortion=args.distortion[0] if len(args.distortion) == 1 else tuple(args.distortion),
            blur_px=args.blur,
            exposure=args.exposure,
            noise=args.noise,
            focal_scale=args.focal_scale,
            baseline_scale=args.baseline_scale,
            texture_poor=args.texture_poor,
            moving_vehicles=args.moving,
            vehicle_speed=args.vehicle_speed,
        ),
        camera=camera_model(args),
    )
    if args.bag is not None and args.bag.exists() and not args.overwrite:
        raise ValueError(f"{args.bag} exists: refusing to overwrite it (use --overwrite)")
    bar = None if args.quiet else Progress(config.frames, "pvo sim")
    result = simulate(config, args.out, overwrite=args.overwrite, progress=(lambda done, total: bar.update()) if bar else None)
    if bar:
        bar.close()
    fps = result.frames / max(result.seconds_render, 1e-9)
    print(
        f"{result.out}: {result.frames} stereo frames {width}x{height} ({config.preset}), "
        f"sun elevation {result.sun_elevation_deg[0]:.1f}-{result.sun_elevation_deg[1]:.1f} deg, "
        f"world {result.seconds_world:.2f} s, rendering {fps:.2f} stereo frames/s"
    )
    if args.bag is not None:
        from pvo_core.readers import KittiSequence

        from ..convert import convert_kitti

        out = Path(args.out)
        sequence = KittiSequence(out, colour=config.colour, poses_file=out / "poses.txt", sun_file=out / "sun.csv")
        from pvo_core.readers import read_gps_csv, read_imu_csv

        summary = convert_kitti(
            sequence,
            args.bag,
            overwrite=args.overwrite,
            epoch=config.epoch,
            show_progress=not args.quiet,
            imu=read_imu_csv(out / "imu.csv"),
            gps=read_gps_csv(out / "gps.csv"),
        )
        total = sum(summary.counts.values())
        print(f"{args.bag}: {total} messages on {len(summary.counts)} topics, {summary.bytes / 1e6:.1f} MB", file=sys.stderr)
    return 0
