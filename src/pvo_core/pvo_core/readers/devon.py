"""The Devon Island rover navigation dataset (Furgale et al., IJRR 2012).

Layout (``DATASET_DIR``): image folders ``<type>-sNN/{grey|color}-rectified-{left|right}-NNNNNN.{pgm|ppm}``
(index global across sections, from 1) and ``logs/`` with ``image-times.txt``,
``gps-topocentric.txt``, ``known-orientations.txt``, ``sun-sensor.txt`` and
``sun-sensor-sampled.txt``. Formats: ``shared/data/SOURCES.md``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..camera import StereoCamera
from ..errors import DataFormatError

Array = NDArray[np.float64]

#: Rectified calibration of the Bumblebee XB3 (f, cu, cv in px) per image type; baseline in metres.
DEVON_CALIBRATION = {
    "grey-rectified-512x384": (387.599884033, 253.755615234, 185.114852905, 512, 384),
    "color-rectified-1280x960": (968.999694824, 635.139038086, 463.537109375, 1280, 960),
}
DEVON_BASELINE_M = 0.239977002

_IMAGE_RE = re.compile(r"^(grey|color)-rectified-(left|right)-(\d+)\.(pgm|ppm)$")


def parse_time(text: str, default_offset: timedelta, path: Path, line: int) -> float:
    """UNIX seconds of an ISO-8601 time; a time without a zone gets ``default_offset``."""
    try:
        stamp = datetime.fromisoformat(text)
    except ValueError:
        raise DataFormatError(path, f"not an ISO-8601 time: {text!r}", line) from None
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=timezone(default_offset))
    return stamp.timestamp()


@dataclass(frozen=True)
class SunSensorReading:
    """One sun-sensor reading: UNIX time (s), azimuth and zenith in the sensor's convention (deg)."""

    stamp: float
    azimuth_deg: float
    zenith_deg: float


def read_devon_sun_sensor(path: str | Path) -> list[SunSensorReading]:
    """``sun-sensor.txt``: ``ISO8601-time-with-offset azimuth_deg zenith_deg`` per line."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "sun-sensor log not found")
    readings = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 3:
            raise DataFormatError(path, f"expected 'time azimuth zenith', got {len(parts)} fields", number)
        stamp = parse_time(parts[0], timedelta(0), path, number)
        try:
            azimuth, zenith = float(parts[1]), float(parts[2])
        except ValueError:
            raise DataFormatError(path, "non-numeric azimuth/zenith", number) from None
        if not (np.isfinite(azimuth) and np.isfinite(zenith)):
            raise DataFormatError(path, "NaN azimuth/zenith", number)
        readings.append(SunSensorReading(stamp, azimuth, zenith))
    if not readings:
        raise DataFormatError(path, "sun-sensor log holds no data")
    return readings


def read_devon_sun_sensor_sampled(path: str | Path) -> Array:
    """``sun-sensor-sampled.txt``: rows ``[image_index, azimuth_deg, zenith_deg, time_offset_s]``."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "sampled sun-sensor log not found")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        parts = line.split()
        if not parts:
            continue
        if len(parts) != 4:
            raise DataFormatError(path, f"expected 4 fields, got {len(parts)}", number)
        try:
            rows.append([float(p) for p in parts])
        except ValueError:
            raise DataFormatError(path, "non-numeric field", number) from None
    if not rows:
        raise DataFormatError(path, "sampled sun-sensor log holds no data")
    return np.asarray(rows)


def _read_table(path: Path, columns: int, what: str) -> Array:
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        parts = line.replace(",", " ").split()
        if not parts or parts[0].startswith("#"):
            continue
        if len(parts) != columns:
            raise DataFormatError(path, f"expected {columns} fields per {what} line, got {len(parts)}", number)
        try:
            rows.append([float(p) for p in parts])
        except ValueError:
            raise DataFormatError(path, f"non-numeric field in {what} line", number) from None
    if not rows:
        raise DataFormatError(path, f"{what} file holds no data")
    return np.asarray(rows)


@dataclass
class DevonDataset:
    """A Devon Island dataset directory.

    Args:
        root: the dataset directory.
        image_type: ``grey-rectified-512x384`` or ``color-rectified-1280x960``.
        image_time_offset: zone of ``image-times.txt`` times that carry none (default UTC-5, the
            zone of the sun-sensor log; the dataset documentation does not state it).
    """

    root: Path
    image_type: str = "grey-rectified-512x384"
    image_time_offset: timedelta = timedelta(hours=-5)
    left_images: dict[int, Path] = field(init=False)
    right_images: dict[int, Path] = field(init=False)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        if not self.root.is_dir():
            raise DataFormatError(self.root, "dataset directory not found")
        if self.image_type not in DEVON_CALIBRATION:
            raise ValueError(f"unknown Devon image type {self.image_type!r}; one of {sorted(DEVON_CALIBRATION)}")
        self.left_images, self.right_images = {}, {}
        folders = sorted(self.root.glob(f"{self.image_type}-s*"))
        if not folders:
            raise DataFormatError(self.root, f"no {self.image_type}-sNN image folders")
        for folder in folders:
            for path in folder.iterdir():
                match = _IMAGE_RE.match(path.name)
                if match:
                    side = self.left_images if match.group(2) == "left" else self.right_images
                    side[int(match.group(3))] = path
        if not self.left_images:
            raise DataFormatError(folders[0], "no left images")

    @property
    def logs(self) -> Path:
        return self.root / "logs"

    @property
    def has_right_images(self) -> bool:
        return bool(self.right_images)

    @property
    def indices(self) -> list[int]:
        """Image indices with a left image, ascending."""
        return sorted(self.left_images)

    def camera(self) -> StereoCamera:
        f, cu, cv, width, height = DEVON_CALIBRATION[self.image_type]
        return StereoCamera(f=f, cu=cu, cv=cv, baseline=DEVON_BASELINE_M, width=width, height=height)

    def image_times(self) -> dict[int, float] | None:
        """``image-times.txt`` as {index: UNIX seconds}, or None when the file is absent."""
        path = self.logs / "image-times.txt"
        if not path.is_file():
            return None
        times = {}
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            parts = line.split()
            if not parts:
                continue
            if len(parts) != 2:
                raise DataFormatError(path, f"expected 'index time', got {len(parts)} fields", number)
            try:
                index = int(parts[0])
            except ValueError:
                raise DataFormatError(path, "image index is not an integer", number) from None
            times[index] = parse_time(parts[1], self.image_time_offset, path, number)
        return times

    def gps_topocentric(self) -> dict[int, Array] | None:
        """``gps-topocentric.txt`` as {index: [east, north, up] metres}, or None when absent."""
        path = self.logs / "gps-topocentric.txt"
        if not path.is_file():
            return None
        table = _read_table(path, 4, "gps-topocentric")
        return {int(row[0]): row[1:] for row in table}

    def known_orientations(self) -> dict[int, Array] | None:
        """``known-orientations.txt`` as {index: axis-angle (3,) camera -> topocentric}, or None."""
        path = self.logs / "known-orientations.txt"
        if not path.is_file():
            return None
        table = _read_table(path, 5, "known-orientations")
        result = {}
        for row in table:
            axis = row[1:4]
            norm = np.linalg.norm(axis)
            if norm < 1e-9:
                raise DataFormatError(path, f"zero rotation axis for image {int(row[0])}")
            result[int(row[0])] = axis / norm * row[4]
        return result

    def sun_sensor(self) -> list[SunSensorReading] | None:
        path = self.logs / "sun-sensor.txt"
        return read_devon_sun_sensor(path) if path.is_file() else None

    def sun_sensor_sampled(self) -> Array | None:
        path = self.logs / "sun-sensor-sampled.txt"
        return read_devon_sun_sensor_sampled(path) if path.is_file() else None
