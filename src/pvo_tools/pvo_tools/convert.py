"""Dataset -> rosbag2 converters (`pvo convert kitti|devon`).

Both write the input topics of the architecture contract with stamps from the dataset and the
message definitions embedded, through :class:`~pvo_tools.bagio.SafeBagWriter` (nothing is left
behind when a conversion fails or is interrupted).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path

import numpy as np
from pvo_core.errors import DataFormatError
from pvo_core.imageio import read_image
from pvo_core.lie import quaternion_to_rotation
from pvo_core.readers import DevonDataset, KittiSequence
from pvo_core.sun import zenith_azimuth_to_vector

from . import rosmsgs
from .bagio import SafeBagWriter
from .progress import Progress

TOPIC_LEFT_IMAGE = "/stereo/left/image_rect"
TOPIC_RIGHT_IMAGE = "/stereo/right/image_rect"
TOPIC_LEFT_INFO = "/stereo/left/camera_info"
TOPIC_RIGHT_INFO = "/stereo/right/camera_info"
TOPIC_GT_ODOMETRY = "/ground_truth/odometry"
TOPIC_GT_SUN = "/ground_truth/sun_direction"
TOPIC_SUN_SENSOR = "/sun_sensor/direction"
TOPIC_IMU = "/imu/data"
TOPIC_GPS = "/gps/fix"
GPS_FRAME = "gps"
GT_FRAME = "world"  # the first left-camera frame (KITTI) / local ENU (Devon GPS)

#: Nominal ground-truth pose covariance (ROS order): small, never all-zero.
GT_POSE_COVARIANCE = np.diag([1e-6] * 6)
#: The converters write no twist: its covariance says so.
UNKNOWN_TWIST_COVARIANCE = np.diag([1e6] * 6)


@dataclass
class ConversionSummary:
    output: Path
    frames: int
    counts: dict[str, int] = field(default_factory=dict)
    seconds: float = 0.0
    bytes: int = 0

    def lines(self) -> list[str]:
        rate = self.frames / self.seconds if self.seconds > 0 else 0.0
        out = [
            f"wrote {self.output} ({self.bytes / 1e6:.1f} MB): {self.frames} frames in {self.seconds:.1f} s ({rate:.1f} frames/s)"
        ]
        out += [f"  {topic:32s} {count:6d} msgs" for topic, count in sorted(self.counts.items())]
        return out


def _bag_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _ns(seconds: float) -> int:
    return round(seconds * 1e9)


def convert_kitti(
    sequence: KittiSequence,
    out: Path,
    storage: str = "mcap",
    overwrite: bool = False,
    epoch: float = 0.0,
    show_progress: bool = True,
    imu: np.ndarray | None = None,
    gps: np.ndarray | None = None,
) -> ConversionSummary:
    """Write a KITTI sequence as a bag. ``epoch`` (UNIX s) is added to the sequence's times.

    ``imu`` (N, 7: t, angular rate, specific force in the left camera frame) and ``gps`` (N, 4: t,
    latitude, longitude, altitude), times relative to the first frame like ``times.txt``, add
    ``/imu/data`` and ``/gps/fix`` (the simulator's sidecars), interleaved in time order.
    """
    start = time.monotonic()
    width = height = 0
    with SafeBagWriter(out, storage=storage, overwrite=overwrite) as writer:
        for topic, type_name in (
            (TOPIC_LEFT_INFO, "sensor_msgs/msg/CameraInfo"),
            (TOPIC_RIGHT_INFO, "sensor_msgs/msg/CameraInfo"),
            (TOPIC_LEFT_IMAGE, "sensor_msgs/msg/Image"),
            (TOPIC_RIGHT_IMAGE, "sensor_msgs/msg/Image"),
        ):
            writer.add_topic(topic, type_name)
        if sequence.poses is not None:
            writer.add_topic(TOPIC_GT_ODOMETRY, "nav_msgs/msg/Odometry")
        if sequence.sun_vectors is not None:
            writer.add_topic(TOPIC_GT_SUN, "pvo_msgs/msg/SunDirection")
        if imu is not None:
            writer.add_topic(TOPIC_IMU, "sensor_msgs/msg/Imu")
        if gps is not None:
            writer.add_topic(TOPIC_GPS, "sensor_msgs/msg/NavSatFix")
        extras = sorted(
            [(float(row[0]), "imu", row) for row in (imu if imu is not None else [])]
            + [(float(row[0]), "gps", row) for row in (gps if gps is not None else [])],
            key=lambda item: item[0],
        )
        next_extra = 0
        progress = Progress(len(sequence), "convert kitti") if show_progress else None
        for i in range(len(sequence)):
            left, right = sequence.load_pair(i)
            if i == 0:
                height, width = left.shape[:2]
            elif left.shape[:2] != (height, width):
                raise DataFormatError(
                    sequence.left_paths[i],
                    f"image size {left.shape[1]}x{left.shape[0]} differs from the first frame's {width}x{height}",
                )
            t = _ns(epoch + sequence.stamps[i])
            while next_extra < len(extras) and _ns(epoch + extras[next_extra][0]) <= t:
                _write_extra(writer, epoch, *extras[next_extra])
                next_extra += 1
            writer.write(TOPIC_LEFT_INFO, t, rosmsgs.camera_info(t, rosmsgs.LEFT_FRAME, sequence.projection_left, width, height))
            writer.write(
                TOPIC_RIGHT_INFO, t, rosmsgs.camera_info(t, rosmsgs.RIGHT_FRAME, sequence.projection_right, width, height)
            )
            writer.write(TOPIC_LEFT_IMAGE, t, rosmsgs.image(t, rosmsgs.LEFT_FRAME, left))
            writer.write(TOPIC_RIGHT_IMAGE, t, rosmsgs.image(t, rosmsgs.RIGHT_FRAME, right))
            if sequence.poses is not None:
                writer.write(
                    TOPIC_GT_ODOMETRY,
                    t,
                    rosmsgs.odometry(
                        t, GT_FRAME, rosmsgs.LEFT_FRAME, sequence.poses[i], GT_POSE_COVARIANCE, UNKNOWN_TWIST_COVARIANCE
                    ),
                )
            if sequence.sun_vectors is not None:
                # KITTI's rectified cameras share one orientation: the image_02 vector holds for image_00.
                writer.write(TOPIC_GT_SUN, t, rosmsgs.sun_direction(t, rosmsgs.LEFT_FRAME, sequence.sun_vectors[i]))
            if progress:
                progress.update()
        for extra in extras[next_extra:]:
            _write_extra(writer, epoch, *extra)
        if progress:
            progress.close()
        counts = dict(writer.counts)
    return ConversionSummary(out, len(sequence), counts, time.monotonic() - start, _bag_size(out))


def _write_extra(writer: SafeBagWriter, epoch: float, t: float, kind: str, row: np.ndarray) -> None:
    stamp = _ns(epoch + t)
    if kind == "imu":
        writer.write(TOPIC_IMU, stamp, rosmsgs.imu(stamp, rosmsgs.LEFT_FRAME, row[1:4], row[4:7]))
    else:
        writer.write(TOPIC_GPS, stamp, rosmsgs.nav_sat_fix(stamp, GPS_FRAME, row[1], row[2], row[3]))


@dataclass(frozen=True)
class SunSensorConvention:
    """How a sun-sensor (azimuth, zenith) reading becomes a unit vector.

    The sensor frame is defined like an optical frame: the reading's zenith is measured from the
    sensor's -y axis and its azimuth (after ``sign`` and ``offset_deg``) is ``atan2(x, z)``,
    i.e. thesis eq. 5.7 inverted. ``camera_from_sensor`` (quaternion w, x, y, z), when given,
    rotates the vector into the left camera frame and the message is stamped in that frame.
    """

    azimuth_sign: float = 1.0
    azimuth_offset_deg: float = 0.0
    camera_from_sensor: tuple[float, float, float, float] | None = None
    sensor_frame: str = "sun_sensor"

    def vector(self, azimuth_deg: float, zenith_deg: float) -> tuple[np.ndarray, str]:
        azimuth = np.deg2rad(self.azimuth_sign * azimuth_deg + self.azimuth_offset_deg)
        direction = zenith_azimuth_to_vector(np.deg2rad(zenith_deg), azimuth)
        if self.camera_from_sensor is None:
            return direction, self.sensor_frame
        return quaternion_to_rotation(self.camera_from_sensor) @ direction, rosmsgs.LEFT_FRAME


def convert_devon(
    dataset: DevonDataset,
    out: Path,
    mono: bool = False,
    rate_hz: float | None = None,
    start_time: float = 0.0,
    start: int = 0,
    count: int | None = None,
    convention: SunSensorConvention = SunSensorConvention(),
    storage: str = "mcap",
    overwrite: bool = False,
    show_progress: bool = True,
) -> ConversionSummary:
    """Write a Devon Island dataset (or part of it) as a bag.

    Image stamps come from ``logs/image-times.txt``; without it from ``start_time + i / rate_hz``.
    Sun-sensor readings come from ``sun-sensor-sampled.txt`` (the reading nearest each image,
    stamped with the image time plus its offset) or, with image times, from ``sun-sensor.txt``.
    """
    if not dataset.has_right_images and not mono:
        raise DataFormatError(
            dataset.root, "no right images in the dataset: stereo needs them (pass --mono to write the left camera only)"
        )
    start_clock = time.monotonic()
    indices = dataset.indices[start : None if count is None else start + count]
    if not indices:
        raise ValueError(f"no images selected (start {start}, count {count}, {len(dataset.indices)} available)")
    times = dataset.image_times()
    if times is not None:
        missing = [i for i in indices if i not in times]
        if missing:
            raise DataFormatError(dataset.logs / "image-times.txt", f"no time for images {missing[:5]}")
        stamps = {i: times[i] for i in indices}
    else:
        if rate_hz is None or rate_hz <= 0:
            raise DataFormatError(
                dataset.logs / "image-times.txt", "not found; give --rate HZ (and --start-time) to stamp the images"
            )
        stamps = {index: start_time + k / rate_hz for k, index in enumerate(indices)}
    camera = dataset.camera()
    p_left, p_right = camera.projection_matrices()
    gps = dataset.gps_topocentric()
    with SafeBagWriter(out, storage=storage, overwrite=overwrite) as writer:
        writer.add_topic(TOPIC_LEFT_INFO, "sensor_msgs/msg/CameraInfo")
        writer.add_topic(TOPIC_LEFT_IMAGE, "sensor_msgs/msg/Image")
        if not mono:
            writer.add_topic(TOPIC_RIGHT_INFO, "sensor_msgs/msg/CameraInfo")
            writer.add_topic(TOPIC_RIGHT_IMAGE, "sensor_msgs/msg/Image")
        if gps is not None:
            writer.add_topic(TOPIC_GT_ODOMETRY, "nav_msgs/msg/Odometry")
        progress = Progress(len(indices), "convert devon") if show_progress else None
        for index in indices:
            t = _ns(stamps[index])
            left = read_image(dataset.left_images[index])
            height, width = left.shape[:2]
            writer.write(TOPIC_LEFT_INFO, t, rosmsgs.camera_info(t, rosmsgs.LEFT_FRAME, p_left, width, height))
            writer.write(TOPIC_LEFT_IMAGE, t, rosmsgs.image(t, rosmsgs.LEFT_FRAME, left))
            if not mono:
                right_path = dataset.right_images.get(index)
                if right_path is None:
                    raise DataFormatError(dataset.left_images[index], "has no matching right image")
                right = read_image(right_path)
                if right.shape != left.shape:
                    raise DataFormatError(
                        right_path, f"size {right.shape[1]}x{right.shape[0]} differs from the left image's {width}x{height}"
                    )
                writer.write(TOPIC_RIGHT_INFO, t, rosmsgs.camera_info(t, rosmsgs.RIGHT_FRAME, p_right, width, height))
                writer.write(TOPIC_RIGHT_IMAGE, t, rosmsgs.image(t, rosmsgs.RIGHT_FRAME, right))
            if gps is not None and index in gps:
                transform = np.eye(4)
                transform[:3, 3] = gps[index]
                # GPS gives position only: the orientation's covariance marks it unknown.
                covariance = np.diag([1e-4, 1e-4, 1e-4, 1e6, 1e6, 1e6])
                writer.write(
                    TOPIC_GT_ODOMETRY,
                    t,
                    rosmsgs.odometry(t, "map", "gps_antenna", transform, covariance, UNKNOWN_TWIST_COVARIANCE),
                )
            if progress:
                progress.update()
        if progress:
            progress.close()
        _write_devon_sun(writer, dataset, indices, stamps, times is not None, convention)
        counts = dict(writer.counts)
    return ConversionSummary(out, len(indices), counts, time.monotonic() - start_clock, _bag_size(out))


def _write_devon_sun(
    writer: SafeBagWriter,
    dataset: DevonDataset,
    indices: list[int],
    stamps: dict[int, float],
    absolute_times: bool,
    convention: SunSensorConvention,
) -> int:
    written = 0
    sampled = dataset.sun_sensor_sampled()
    readings: list[tuple[float, float, float]] = []
    if sampled is not None:
        selected = set(indices)
        for index, azimuth, zenith, offset in sampled:
            if int(index) in selected:
                readings.append((stamps[int(index)] + offset, azimuth, zenith))
    elif absolute_times:
        log = dataset.sun_sensor() or []
        first, last = min(stamps.values()), max(stamps.values())
        readings = [(r.stamp, r.azimuth_deg, r.zenith_deg) for r in log if first - 1.0 <= r.stamp <= last + 1.0]
    if not readings:
        return 0
    writer.add_topic(TOPIC_SUN_SENSOR, "pvo_msgs/msg/SunDirection")
    for stamp_s, azimuth, zenith in sorted(readings):
        direction, frame = convention.vector(azimuth, zenith)
        t = _ns(stamp_s)
        writer.write(TOPIC_SUN_SENSOR, t, rosmsgs.sun_direction(t, frame, direction))
        written += 1
    return written


def parse_quaternion(text: str) -> tuple[float, float, float, float]:
    """'w,x,y,z' -> tuple; ValueError with the offending text otherwise."""
    try:
        values = tuple(float(v) for v in text.replace(" ", ",").split(",") if v)
    except ValueError:
        raise ValueError(f"--sun-sensor-extrinsic expects 'w,x,y,z', got {text!r}") from None
    if len(values) != 4 or not np.isfinite(values).all() or np.linalg.norm(values) < 1e-9:
        raise ValueError(f"--sun-sensor-extrinsic expects a non-zero quaternion 'w,x,y,z', got {text!r}")
    return values  # type: ignore[return-value]


def devon_time_offset(hours: float) -> timedelta:
    return timedelta(hours=hours)
