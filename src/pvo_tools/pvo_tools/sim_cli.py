"""`pvo sim`: argument handling and the optional conversion to a bag."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from pvo_sim import KITTI_FOCAL_PER_PIXEL_WIDTH, Degradations, ImuNoise, SimConfig, simulate

from .progress import Progress


def parse_size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {text!r} must be WIDTHxHEIGHT, e.g. 620x188") from None
    return width, height


def cmd_sim(args: Any) -> int:
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
        speed=args.speed,
        heading_deg=args.heading,
        latitude=args.lat,
        longitude=args.lon,
        altitude=args.alt,
        start_time=args.start_time,
        overcast=args.overcast,
        night=args.night,
        depth=args.depth,
        seed=args.seed,
        imu=ImuNoise(args.gyro_noise, args.accel_noise, tuple(args.gyro_bias), tuple(args.accel_bias)),
        gps_sigma=args.gps_sigma,
        degradations=Degradations(
            distortion=args.distortion,
            blur_px=args.blur,
            exposure=args.exposure,
            noise=args.noise,
            focal_scale=args.focal_scale,
            baseline_scale=args.baseline_scale,
            texture_poor=args.texture_poor,
            moving_vehicles=args.moving,
        ),
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

        from .convert import convert_kitti

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


def cmd_bench_sim(args: Any) -> int:
    """Rendering throughput at two sizes and world-generation time against path length."""
    import tempfile
    import time

    from pvo_sim import WorldSpec, build_world, procedural_path

    with tempfile.TemporaryDirectory() as tmp:
        for width, height in ((620, 188), (1241, 376)):
            config = SimConfig(
                frames=args.frames, width=width, height=height, focal=KITTI_FOCAL_PER_PIXEL_WIDTH * width, preset=args.preset
            )
            result = simulate(config, Path(tmp) / f"{width}", overwrite=True)
            print(
                f"{args.preset} {width}x{height}: {result.frames / result.seconds_render:.2f} stereo frames/s "
                f"({1e3 * result.seconds_render / result.frames:.1f} ms per stereo pair incl. PNG writing)"
            )
    for frames in (250, 500, 1000, 2000):
        poses = procedural_path("s-curve", frames, 10.0, 8.0, 1.65)
        start = time.perf_counter()
        world = build_world(WorldSpec(args.preset), poses, 1.65)
        seconds = time.perf_counter() - start
        print(f"world generation, {frames} frames ({frames * 0.8:.0f} m): {seconds:.3f} s, {world.xml.count('<geom')} geoms")
    return 0
