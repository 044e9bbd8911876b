"""`pvo bag info|play|record|trajectory|recover`: rosbag2 bags without a ROS 2 install."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ..errors import PvoError


def register(sub: Any) -> None:
    bag = sub.add_parser("bag", help="inspect, play and record rosbag2 bags")
    bag.set_defaults(handler=run)
    verbs = bag.add_subparsers(dest="verb", required=True, metavar="VERB")
    info = verbs.add_parser("info", help="topics, types, counts, duration and size of a bag")
    info.add_argument("bag", type=Path)

    play = verbs.add_parser("play", help="publish a bag's messages with the recorded timing and /clock")
    play.add_argument("bag", type=Path)
    play.add_argument("--rate", "-r", type=float, default=1.0, help="playback speed factor (default 1)")
    play.add_argument("--start-offset", type=float, default=0.0, help="skip the first S seconds")
    play.add_argument("--topics", nargs="+", help="play only these topics")
    play.add_argument("--loop", "-l", action="store_true", help="play again and again, stamps increasing across passes")
    play.add_argument("--loops", type=int, default=0, metavar="N", help="with --loop: stop after N passes (default: never)")
    play.add_argument("--no-clock", action="store_true", help="do not publish /clock")
    play.add_argument(
        "--wait-for-subscribers",
        type=int,
        default=1,
        metavar="N",
        help="before playing, wait until every topic that has subscribers has N of them (default 1; 0: play at once)",
    )
    play.add_argument("--wait-timeout", type=float, default=10.0, help="give up waiting after S seconds (default 10)")
    play.add_argument("--delay", type=float, default=0.0, help="seconds to wait before playing (discovery)")

    rec = verbs.add_parser("record", help="record topics to a bag (raw bytes, definitions preserved)")
    rec.add_argument("topics", nargs="*", help="topics to record")
    rec.add_argument("--all", "-a", action="store_true", help="record every topic that appears")
    rec.add_argument("--output", "-o", type=Path, required=True, help="bag directory to write")
    rec.add_argument("--duration", "-d", type=float, help="stop after S seconds (default: on Ctrl-C)")
    rec.add_argument("--stamp", choices=["receive", "header"], default="receive", help="bag time: receive time or header.stamp")
    rec.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    rec.add_argument("--overwrite", action="store_true", help="replace an existing output")

    recover = verbs.add_parser(
        "recover",
        help="save what can be read of a truncated or corrupted MCAP recording into a new bag",
        description="Read every MCAP file of BAG (a bag directory, with or without metadata.yaml, or one .mcap file) "
        "in file order and write every message that can still be read into a new bag: whole chunks that pass their "
        "checksum, and the complete messages at the head of a chunk cut off. Each loss is named; BAG is not changed.",
    )
    recover.add_argument("bag", type=Path)
    recover.add_argument("--output", "-o", type=Path, required=True, help="the new bag directory")
    recover.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    recover.add_argument("--overwrite", action="store_true", help="replace an existing output bag")

    traj = verbs.add_parser("trajectory", help="summary (and export) of a pose topic, e.g. the ground truth")
    traj.add_argument("bag", type=Path)
    traj.add_argument("--topic", default="/ground_truth/odometry")
    traj.add_argument("--output", "-o", type=Path, help="write the trajectory to this file")
    traj.add_argument("--format", choices=["kitti", "tum"], default="kitti")


def run(args: argparse.Namespace) -> int:
    if args.verb == "info":
        from ..baginfo import bag_info

        print("\n".join(bag_info(args.bag).lines()))
    elif args.verb == "play":
        from ..player import PlayOptions, play

        options = PlayOptions(
            rate=args.rate,
            start_offset=args.start_offset,
            topics=args.topics,
            loop=args.loop or args.loops > 0,
            passes=args.loops,
            clock=not args.no_clock,
            wait_for_subscribers=args.wait_for_subscribers,
            wait_timeout=args.wait_timeout,
            delay=args.delay,
        )
        stats = play(args.bag, options)
        print(stats.report(), file=sys.stderr)
    elif args.verb == "record":
        from ..recorder import RecordOptions, record

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
    elif args.verb == "recover":
        from ..bagrecover import recover_bag

        recovery = recover_bag(args.bag, args.output, overwrite=args.overwrite, storage=args.storage)
        print("\n".join(recovery.lines()))
    elif args.verb == "trajectory":
        from pvo_core.trajectory import write_kitti_poses, write_tum_trajectory

        from ..baginfo import bag_trajectory

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
