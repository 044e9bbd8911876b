"""`pvo convert kitti|devon`: a dataset to a rosbag2 bag."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any


def register(sub: Any) -> None:
    convert = sub.add_parser("convert", help="convert a dataset to a rosbag2 bag")
    convert.set_defaults(handler=run)
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


def run(args: argparse.Namespace) -> int:
    from pvo_core.readers import DevonDataset, KittiSequence

    from ..bagio import check_output_path
    from ..convert import SunSensorConvention, convert_devon, convert_kitti, devon_time_offset, parse_quaternion

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
