"""The `pvo` command: one entry point for pvo's tools (`pvo --help`)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pvo_core.errors import DataFormatError

from .errors import PvoError

EPILOG = "Run 'pvo COMMAND --help' for the options of each command."


def _add_convert(sub: argparse._SubParsersAction) -> None:
    convert = sub.add_parser("convert", help="convert a dataset to a rosbag2 bag")
    kinds = convert.add_subparsers(dest="dataset", required=True, metavar="DATASET")

    kitti = kinds.add_parser("kitti", help="a KITTI odometry sequence directory")
    kitti.add_argument("sequence_dir", type=Path, help="directory with image_0/1 (or image_2/3) and calib.txt")
    kitti.add_argument("--out", "-o", type=Path, required=True, help="bag directory to write")
    kitti.add_argument("--poses", type=Path, help="ground-truth pose file (KITTI format; default SEQUENCE_DIR/poses.txt)")
    timing = kitti.add_mutually_exclusive_group()
    timing.add_argument("--times", type=Path, help="frame times file (default SEQUENCE_DIR/times.txt)")
    timing.add_argument("--rate", type=float, help="frame rate (Hz) when there is no times file")
    kitti.add_argument("--epoch", type=float, default=0.0, help="UNIX seconds added to every frame time (default 0)")
    kitti.add_argument("--sun", type=Path, help="Sun-BCNN sun-vector CSV -> /ground_truth/sun_direction")
    kitti.add_argument("--imu", type=Path, help="imu.csv of `pvo sim` (t,wx,wy,wz,fx,fy,fz) -> /imu/data")
    kitti.add_argument("--gps", type=Path, help="gps.csv of `pvo sim` (t,latitude,longitude,altitude) -> /gps/fix")
    kitti.add_argument("--colour", action="store_true", help="use image_2/image_3 (rgb8) and P2/P3")
    kitti.add_argument("--start", type=int, default=0, help="first frame (position in the sequence)")
    kitti.add_argument("--count", type=int, help="number of frames (default: all)")
    _add_storage(kitti)

    devon = kinds.add_parser("devon", help="a Devon Island rover navigation dataset directory")
    devon.add_argument("dataset_dir", type=Path, help="directory with <type>-sNN image folders and logs/")
    devon.add_argument("--out", "-o", type=Path, required=True, help="bag directory to write")
    devon.add_argument("--mono", action="store_true", help="write the left camera only (when right images are absent)")
    devon.add_argument(
        "--image-type", default="grey-rectified-512x384", choices=["grey-rectified-512x384", "color-rectified-1280x960"]
    )
    devon.add_argument("--rate", type=float, help="frame rate (Hz) to stamp images when logs/image-times.txt is absent")
    devon.add_argument("--start-time", type=float, default=0.0, help="UNIX time of the first image with --rate")
    devon.add_argument(
        "--image-time-zone", type=float, default=-5.0, help="UTC offset (h) of image-times.txt entries without a zone"
    )
    devon.add_argument("--start", type=int, default=0, help="first image (position among the images)")
    devon.add_argument("--count", type=int, help="number of images (default: all)")
    devon.add_argument(
        "--sun-azimuth-sign", type=float, default=1.0, choices=[1.0, -1.0], help="sign applied to the logged azimuth"
    )
    devon.add_argument("--sun-azimuth-offset-deg", type=float, default=0.0, help="added to the signed azimuth (deg)")
    devon.add_argument(
        "--sun-sensor-extrinsic",
        help="rotation camera<-sun sensor as a quaternion 'w,x,y,z'; without it vectors stay in frame 'sun_sensor'",
    )
    _add_storage(devon)


def _add_storage(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--storage", choices=["mcap", "sqlite3"], default="mcap", help="rosbag2 storage (default mcap, zstd chunks)"
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")


def _add_bag(sub: argparse._SubParsersAction) -> None:
    bag = sub.add_parser("bag", help="inspect, play and record rosbag2 bags")
    verbs = bag.add_subparsers(dest="verb", required=True, metavar="VERB")
    info = verbs.add_parser("info", help="topics, types, counts, duration and size of a bag")
    info.add_argument("bag", type=Path)

    play = verbs.add_parser("play", help="publish a bag's messages with the recorded timing and /clock")
    play.add_argument("bag", type=Path)
    play.add_argument("--rate", "-r", type=float, default=1.0, help="playback speed factor (default 1)")
    play.add_argument("--start-offset", type=float, default=0.0, help="skip the first S seconds")
    play.add_argument("--topics", nargs="+", help="play only these topics")
    play.add_argument("--loop", "-l", action="store_true", help="play again and again")
    play.add_argument("--no-clock", action="store_true", help="do not publish /clock")
    play.add_argument(
        "--wait-for-subscribers", type=int, default=0, metavar="N", help="wait (up to 10 s) for N subscribers per topic"
    )
    play.add_argument("--delay", type=float, default=0.0, help="seconds to wait before playing (discovery)")

    rec = verbs.add_parser("record", help="record topics to a bag (raw bytes, definitions preserved)")
    rec.add_argument("topics", nargs="*", help="topics to record")
    rec.add_argument("--all", "-a", action="store_true", help="record every topic that appears")
    rec.add_argument("--output", "-o", type=Path, required=True, help="bag directory to write")
    rec.add_argument("--duration", "-d", type=float, help="stop after S seconds (default: on Ctrl-C)")
    rec.add_argument("--stamp", choices=["receive", "header"], default="receive", help="bag time: receive time or header.stamp")
    rec.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    rec.add_argument("--overwrite", action="store_true", help="replace an existing output")

    traj = verbs.add_parser("trajectory", help="summary (and export) of a pose topic, e.g. the ground truth")
    traj.add_argument("bag", type=Path)
    traj.add_argument("--topic", default="/ground_truth/odometry")
    traj.add_argument("--output", "-o", type=Path, help="write the trajectory to this file")
    traj.add_argument("--format", choices=["kitti", "tum"], default="kitti")


def _add_graph(sub: argparse._SubParsersAction) -> None:
    run = sub.add_parser("run", help="run an executable of a package (like `ros2 run`)")
    run.add_argument("package")
    run.add_argument("executable")
    run.add_argument("args", nargs=argparse.REMAINDER, help="arguments for the executable (e.g. --ros-args ...)")

    topic = sub.add_parser("topic", help="inspect topics on the live graph")
    verbs = topic.add_subparsers(dest="verb", required=True, metavar="VERB")
    lst = verbs.add_parser("list", help="list topics")
    lst.add_argument("--show-types", "-t", action="store_true")
    lst.add_argument("--wait", type=float, default=2.5, help="discovery time (s)")
    info = verbs.add_parser("info", help="type and publisher/subscription counts")
    info.add_argument("topic")
    info.add_argument("--wait", type=float, default=2.0)
    echo = verbs.add_parser("echo", help="print messages as YAML")
    echo.add_argument("topic")
    echo.add_argument("--once", action="store_true", help="print one message and exit")
    echo.add_argument("--count", "-n", type=int, help="print N messages and exit")
    echo.add_argument("--timeout", type=float, help="give up after S seconds")
    echo.add_argument("--full", action="store_true", help="do not truncate long arrays")
    echo.add_argument("--wait", type=float, default=5.0, help="time to wait for the topic to appear")
    hz = verbs.add_parser("hz", help="print the publishing rate")
    hz.add_argument("topic")
    hz.add_argument("--window", "-w", type=int, default=100)
    hz.add_argument("--duration", type=float, help="stop after S seconds")
    hz.add_argument("--header", action="store_true", help="rate from header stamps instead of receive times")
    hz.add_argument("--wait", type=float, default=5.0)

    node = sub.add_parser("node", help="inspect nodes on the live graph")
    nverbs = node.add_subparsers(dest="verb", required=True, metavar="VERB")
    nlist = nverbs.add_parser("list", help="list nodes")
    nlist.add_argument("--wait", type=float, default=2.5, help="discovery time (s)")

    iface = sub.add_parser("interface", help="show message definitions")
    iverbs = iface.add_subparsers(dest="verb", required=True, metavar="VERB")
    show = iverbs.add_parser("show", help="print a .msg definition")
    show.add_argument("type", help="e.g. pvo_msgs/msg/RelativePose")


def _add_sequence_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("sequence_dir", type=Path, help="KITTI odometry sequence directory (image_0/1, calib.txt)")
    parser.add_argument("--poses", type=Path, help="ground-truth poses for the summary (default SEQUENCE_DIR/poses.txt)")
    parser.add_argument("--rate", type=float, help="frame rate (Hz) when there is no times.txt (default 10)")


def _add_vo(sub: argparse._SubParsersAction) -> None:
    vo = sub.add_parser("vo", help="run the stereo VO on a KITTI sequence directory (no ROS)")
    _add_sequence_args(vo)
    vo.add_argument("--out", "-o", type=Path, required=True, help="trajectory file to write (KITTI pose format)")
    vo.add_argument("--times", type=Path, help="frame times file (default SEQUENCE_DIR/times.txt)")
    vo.add_argument("--colour", action="store_true", help="use image_2/image_3 and P2/P3")
    vo.add_argument("--start", type=int, default=0, help="first frame (position in the sequence)")
    vo.add_argument("--count", type=int, help="number of frames (default: all)")
    vo.add_argument(
        "--param", "-p", action="append", metavar="NAME=VALUE", help="VO parameter, e.g. -p solver.loss=huber (repeatable)"
    )
    vo.add_argument("--params-file", type=Path, help="ROS-style YAML with stereo_vo parameters (e.g. config/stereo_vo.yaml)")
    vo.add_argument("--relative", type=Path, help="also write per-frame motions and covariances (.npz) for `pvo eval --relative`")
    vo.add_argument("--quiet", "-q", action="store_true", help="no progress output")

    ev = sub.add_parser("eval", help="evaluate a trajectory against ground truth (table, plots, metrics.json)")
    ev.add_argument("--gt", type=Path, required=True, help="ground-truth poses (KITTI format)")
    ev.add_argument(
        "--est", type=Path, required=True, help="estimated poses (KITTI format, optionally with a frame-number column)"
    )
    ev.add_argument(
        "--align", choices=["none", "se3", "sim3"], default="none", help="align the estimate first (Umeyama on positions)"
    )
    ev.add_argument("--gt-start", type=int, default=0, help="ground-truth frame of the estimate's first pose (default 0)")
    ev.add_argument("--relative", type=Path, help="per-frame motions and covariances from `pvo vo --relative` -> NEES/ANEES")
    ev.add_argument("--out", "-o", type=Path, help="directory for metrics.json and the PNG plots")

    bench = sub.add_parser("bench", help="benchmarks")
    kinds = bench.add_subparsers(dest="bench", required=True, metavar="WHAT")
    bvo = kinds.add_parser("vo", help="stereo VO per-stage timings and accuracy on a KITTI clip")
    _add_sequence_args(bvo)
    bvo.add_argument("--count", type=int, help="number of frames (default: all)")
    bvo.add_argument("--repeat", type=int, default=3, help="runs per variant; the fastest is reported (default 3)")
    bvo.add_argument("--threads", type=int, default=1, help="OpenCV threads (default 1: one core)")
    bvo.add_argument("--compare", action="store_true", help="also run the alternative detector/tracker/solver variants")
    bvo.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="VO parameter for every variant")
    bvo.add_argument("--json", type=Path, help="write the figures as YAML/JSON to this file")


def _add_experiment(sub: argparse._SubParsersAction, bench_kinds: argparse._SubParsersAction) -> None:
    exp = sub.add_parser("experiment", help="thesis experiments on real data")
    kinds = exp.add_subparsers(dest="experiment", required=True, metavar="WHICH")
    sim = kinds.add_parser("sun-sim", help="Table 5.2: viso2-s VO on KITTI 00-10 fused with simulated sun (GT-Sun-0/10/20/30)")
    sim.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    sim.add_argument("--sequences", nargs="+", default=None, help="sequences (default: 00 01 02 04 05 06 07 08 09 10)")
    sim.add_argument("--levels", nargs="+", type=float, default=None, help="mean sun errors in degrees (default 0 10 20 30)")
    sim.add_argument("--seed", type=int, default=0, help="seed of the simulated sun noise (default 0)")
    sim.add_argument("--trials", type=int, default=1, help="noise realisations averaged per level (seeds SEED..SEED+N-1)")
    sim.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="fusion parameter, e.g. -p window.lag=20")
    sim.add_argument("--no-anees", action="store_true", help="skip the marginal covariances (faster)")
    sim.add_argument("--out", "-o", type=Path, default=Path("runs/sun-sim"), help="output directory (default runs/sun-sim)")
    sim.add_argument("--quiet", "-q", action="store_true", help="no per-run lines")
    sim.add_argument(
        "--through-nodes",
        metavar="SEQ",
        help="instead: run SEQ with GT-Sun-10 as a bag through the fusion node over DDS and compare with the ROS-free run",
    )
    sim.add_argument("--frames", type=int, help="with --through-nodes: only the first N frames")
    sim.add_argument("--rate", type=float, default=20.0, help="with --through-nodes: playback rate (default 20x real time)")

    bs = bench_kinds.add_parser(
        "sim", help="synthetic world: stereo frames/s at 620x188 and 1241x376, world generation vs length"
    )
    bs.add_argument("--preset", default="urban", help="urban | planetary")
    bs.add_argument("--frames", type=int, default=30, help="frames rendered per size (default 30)")

    bf = bench_kinds.add_parser(
        "fusion", help="FusionGraph over a whole KITTI sequence (viso2-s VO + GT-Sun-10): time and memory"
    )
    bf.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    bf.add_argument("--sequence", default="00", help="KITTI sequence (default 00: 4541 frames)")
    bf.add_argument("--repeat", type=int, default=3, help="runs; the fastest is reported (default 3)")
    bf.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="fusion parameter")


def _add_sim(sub: argparse._SubParsersAction) -> None:
    sim = sub.add_parser("sim", help="render a synthetic stereo sequence (MuJoCo) under the real sun, with IMU, GPS and truth")
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
    sim.add_argument("--speed", type=float, default=8.0, help="procedural path speed in m/s (default 8)")
    sim.add_argument("--heading", type=float, default=0.0, help="initial heading, degrees clockwise from north")
    sim.add_argument("--lat", type=float, default=49.011, help="latitude of the world origin (default Karlsruhe)")
    sim.add_argument("--lon", type=float, default=8.4245, help="longitude of the world origin")
    sim.add_argument("--alt", type=float, default=115.0, help="altitude of the world origin (m)")
    sim.add_argument("--start-time", default="2011-09-30T11:30:00Z", help="UTC time of the first frame (ISO 8601)")
    sim.add_argument("--overcast", action="store_true", help="diffuse light, no cast shadows")
    sim.add_argument("--night", action="store_true", help="render even when the sun is below the horizon")
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
    deg.add_argument("--distortion", type=float, default=0.0, help="radial distortion kappa, then crop (e.g. -0.3, 0.2, 0.01)")
    deg.add_argument("--blur", type=float, default=0.0, help="horizontal motion blur length in px")
    deg.add_argument("--exposure", type=float, default=0.0, help="exposure change amplitude (relative gain, e.g. 0.3)")
    deg.add_argument("--noise", type=float, default=0.0, help="sensor noise std in grey levels")
    deg.add_argument("--focal-scale", type=float, default=1.0, help="write calib.txt with the focal length times this")
    deg.add_argument("--baseline-scale", type=float, default=1.0, help="write calib.txt with the baseline times this")
    deg.add_argument("--texture-poor", type=float, default=0.0, help="urban: fraction of buildings with plain walls")
    deg.add_argument("--moving", type=int, default=3, help="urban: number of independently moving vehicles")
    sim.add_argument("--quiet", "-q", action="store_true", help="no progress output")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pvo", description="pvo: pseudo-sensor visual odometry tools.", epilog=EPILOG)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_convert(sub)
    _add_bag(sub)
    _add_graph(sub)
    _add_vo(sub)
    bench_kinds = next(a for a in sub.choices["bench"]._actions if isinstance(a, argparse._SubParsersAction))
    _add_experiment(sub, bench_kinds)
    _add_sim(sub)
    return parser


def _cmd_convert(args: argparse.Namespace) -> int:
    from pvo_core.readers import DevonDataset, KittiSequence

    from .bagio import check_output_path
    from .convert import SunSensorConvention, convert_devon, convert_kitti, devon_time_offset, parse_quaternion

    check_output_path(args.out, args.overwrite)
    if args.dataset == "kitti":
        sequence = KittiSequence(
            args.sequence_dir,
            colour=args.colour,
            times_file=args.times,
            rate_hz=args.rate,
            poses_file=args.poses,
            sun_file=args.sun,
            start=args.start,
            count=args.count,
        )
        from pvo_core.readers import read_gps_csv, read_imu_csv

        summary = convert_kitti(
            sequence,
            args.out,
            storage=args.storage,
            overwrite=args.overwrite,
            epoch=args.epoch,
            show_progress=not args.quiet,
            imu=read_imu_csv(args.imu) if args.imu else None,
            gps=read_gps_csv(args.gps) if args.gps else None,
        )
    else:
        dataset = DevonDataset(
            args.dataset_dir, image_type=args.image_type, image_time_offset=devon_time_offset(args.image_time_zone)
        )
        convention = SunSensorConvention(
            azimuth_sign=args.sun_azimuth_sign,
            azimuth_offset_deg=args.sun_azimuth_offset_deg,
            camera_from_sensor=parse_quaternion(args.sun_sensor_extrinsic) if args.sun_sensor_extrinsic else None,
        )
        summary = convert_devon(
            dataset,
            args.out,
            mono=args.mono,
            rate_hz=args.rate,
            start_time=args.start_time,
            start=args.start,
            count=args.count,
            convention=convention,
            storage=args.storage,
            overwrite=args.overwrite,
            show_progress=not args.quiet,
        )
    print("\n".join(summary.lines()))
    return 0


def _cmd_bag(args: argparse.Namespace) -> int:
    if args.verb == "info":
        from .baginfo import bag_info

        print("\n".join(bag_info(args.bag).lines()))
    elif args.verb == "play":
        from .player import PlayOptions, play

        options = PlayOptions(
            rate=args.rate,
            start_offset=args.start_offset,
            topics=args.topics,
            loop=args.loop,
            clock=not args.no_clock,
            wait_for_subscribers=args.wait_for_subscribers,
            delay=args.delay,
        )
        stats = play(args.bag, options)
        print(f"played {stats.messages} messages in {stats.seconds:.2f} s", file=sys.stderr)
    elif args.verb == "record":
        from .recorder import RecordOptions, record

        if not args.all and not args.topics:
            raise PvoError("bag record needs topics or --all")
        counts = record(
            args.output,
            RecordOptions(
                topics=args.topics,
                record_all=args.all,
                duration=args.duration,
                stamp=args.stamp,
                storage=args.storage,
                overwrite=args.overwrite,
            ),
        )
        print(f"recorded {sum(counts.values())} messages on {len(counts)} topics to {args.output}", file=sys.stderr)
    elif args.verb == "trajectory":
        from pvo_core.trajectory import write_kitti_poses, write_tum_trajectory

        from .baginfo import bag_trajectory

        trajectory = bag_trajectory(args.bag, args.topic)
        summary = trajectory.summary()
        print(f"Trajectory {args.topic} in {args.bag}:")
        print(f"  frames:            {int(summary['frames'])}")
        print(f"  duration:          {summary['duration_s']:.3f} s")
        print(f"  path length:       {summary['path_length_m']:.3f} m")
        print(f"  mean speed:        {summary['mean_speed_mps']:.3f} m/s")
        print(f"  net displacement:  {summary['net_displacement_m']:.3f} m")
        print(f"  extent x/y/z:      {summary['extent_x_m']:.3f} / {summary['extent_y_m']:.3f} / {summary['extent_z_m']:.3f} m")
        if args.output:
            if args.format == "kitti":
                write_kitti_poses(args.output, trajectory.poses)
            else:
                write_tum_trajectory(args.output, trajectory)
            print(f"  written to {args.output} ({args.format})")
    return 0


def _cmd_graph(args: argparse.Namespace) -> int:
    from . import graph

    if args.command == "run":
        graph.run(args.package, args.executable, args.args)
        return 0
    if args.command == "interface":
        print(graph.interface_show(args.type))
        return 0
    node = graph.make_node("pvo_cli")
    try:
        if args.command == "node":
            print("\n".join(graph.node_list(node, args.wait)))
        elif args.verb == "list":
            print("\n".join(graph.topic_list(node, args.show_types, args.wait)))
        elif args.verb == "info":
            print("\n".join(graph.topic_info(node, args.topic, args.wait)))
        elif args.verb == "echo":
            count = 1 if args.once else args.count
            received = graph.topic_echo(node, args.topic, count, args.wait, args.full, args.timeout)
            if count is not None and received < count:
                raise PvoError(f"received {received} of {count} messages on '{args.topic}' before the timeout")
        elif args.verb == "hz":
            graph.topic_hz(node, args.topic, args.window, args.duration, args.wait, args.header)
    finally:
        graph.shutdown(node)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "convert":
            return _cmd_convert(args)
        if args.command == "bag":
            return _cmd_bag(args)
        if args.command == "vo":
            from .vo_offline import cmd_vo

            return cmd_vo(args)
        if args.command == "eval":
            from .evaluation import run_eval

            run_eval(args.gt, args.est, args.align, args.out, args.gt_start, args.relative)
            return 0
        if args.command == "bench" and args.bench == "sim":
            from .sim_cli import cmd_bench_sim

            return cmd_bench_sim(args)
        if args.command == "bench" and args.bench == "fusion":
            from .fusion_tools import cmd_bench_fusion

            return cmd_bench_fusion(args)
        if args.command == "bench":
            from .vo_offline import cmd_bench_vo

            return cmd_bench_vo(args)
        if args.command == "sim":
            from .sim_cli import cmd_sim

            return cmd_sim(args)
        if args.command == "experiment":
            from .fusion_tools import cmd_sun_sim

            return cmd_sun_sim(args)
        return _cmd_graph(args)
    except (PvoError, DataFormatError, ValueError) as error:
        print(f"pvo: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("pvo: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
