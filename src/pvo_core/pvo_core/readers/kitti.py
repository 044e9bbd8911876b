"""KITTI odometry sequences: calibration, times, images, ground-truth poses, sun vectors.

Layout (``SEQUENCE_DIR``): ``image_0``/``image_1`` (grey left/right) or ``image_2``/``image_3``
(colour), ``calib.txt`` (labelled ``P0: ...`` to ``P3: ...`` lines, or the two-line unlabelled
P0/P1 variant, any ``calib*.txt``), optional ``times.txt`` (seconds, one per frame) and
``poses.txt``. Frames are identified by the number in the image file name; pose, time and sun
files are indexed by that number, so a whole-sequence file serves a clip of it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from ..camera import StereoCamera
from ..errors import DataFormatError
from ..imageio import read_image
from ..sun import unit_vector
from ..trajectory import read_kitti_poses

Array = NDArray[np.float64]


def read_kitti_calibration(path: str | Path) -> dict[str, Array]:
    """Projection matrices {'P0': (3, 4), ...} from a KITTI calib file (labelled or unlabelled)."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "calibration file not found")
    matrices: dict[str, Array] = {}
    unlabelled = 0
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.strip()
        if not text:
            continue
        if ":" in text:
            key, _, rest = text.partition(":")
            key = key.strip()
        else:
            key, rest = f"P{unlabelled}", text
            unlabelled += 1
        parts = rest.split()
        try:
            values = np.array([float(p) for p in parts])
        except ValueError:
            raise DataFormatError(path, f"non-numeric value in calibration entry {key}", number) from None
        if key.startswith("P") and len(key) == 2:
            if values.size != 12:
                raise DataFormatError(path, f"{key} needs 12 numbers, got {values.size}", number)
            if not np.all(np.isfinite(values)):
                raise DataFormatError(path, f"{key} has NaN or infinite values", number)
            matrices[key] = values.reshape(3, 4)
    if "P0" not in matrices or "P1" not in matrices:
        raise DataFormatError(path, "calibration needs at least P0 and P1")
    return matrices


def read_kitti_times(path: str | Path) -> Array:
    """Frame times (N,) in seconds, one per line, strictly increasing."""
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "times file not found")
    times = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.strip()
        if not text:
            continue
        try:
            value = float(text.split()[0])
        except ValueError:
            raise DataFormatError(path, f"non-numeric time {text[:40]!r}", number) from None
        if not np.isfinite(value):
            raise DataFormatError(path, "NaN or infinite time", number)
        if times and value <= times[-1]:
            raise DataFormatError(path, f"time {value} does not increase (previous {times[-1]})", number)
        times.append(value)
    if not times:
        raise DataFormatError(path, "times file holds no data")
    return np.asarray(times)


def read_kitti_sun_csv(path: str | Path) -> Array:
    """Sun unit vectors (N, 3) from a Sun-BCNN KITTI CSV (``relpath,sx,sy,sz``); row i = frame i.

    The vectors are in the rectified colour camera (image_02) optical frame, which in KITTI's
    rectified odometry shares its orientation with every other rectified camera.
    """
    path = Path(path)
    if not path.is_file():
        raise DataFormatError(path, "sun CSV not found")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.strip()
        if not text:
            continue
        parts = text.split(",")
        if len(parts) != 4:
            raise DataFormatError(path, f"expected 'path,sx,sy,sz', got {len(parts)} fields", number)
        try:
            vector = np.array([float(p) for p in parts[1:]])
        except ValueError:
            raise DataFormatError(path, "non-numeric sun vector", number) from None
        if not np.all(np.isfinite(vector)) or abs(np.linalg.norm(vector) - 1.0) > 1e-3:
            raise DataFormatError(path, f"sun vector {vector.tolist()} is not unit length", number)
        rows.append(unit_vector(vector))
    if not rows:
        raise DataFormatError(path, "sun CSV holds no data")
    return np.asarray(rows)


def _find_calibration(root: Path) -> Path:
    for name in ("calib.txt",):
        if (root / name).is_file():
            return root / name
    candidates = sorted(root.glob("calib*.txt"))
    if not candidates:
        raise DataFormatError(root, "no calib.txt (or calib*.txt) in the sequence directory")
    return candidates[0]


def _frame_number(path: Path) -> int:
    try:
        return int(path.stem)
    except ValueError:
        raise DataFormatError(path, "image file name is not a frame number") from None


@dataclass
class KittiSequence:
    """A KITTI odometry sequence directory, read lazily image by image.

    Args:
        root: the sequence directory.
        colour: use ``image_2``/``image_3`` and P2/P3 instead of ``image_0``/``image_1`` and P0/P1.
        times_file: explicit times file (default ``root/times.txt`` when present).
        rate_hz: frame rate used when there is no times file (stamps = frame / rate).
        poses_file: ground-truth poses (default ``root/poses.txt`` when present).
        sun_file: Sun-BCNN sun-vector CSV (optional).
        start, count: select ``count`` frames starting at position ``start`` (None = all).
    """

    root: Path
    colour: bool = False
    times_file: Path | None = None
    rate_hz: float | None = None
    poses_file: Path | None = None
    sun_file: Path | None = None
    start: int = 0
    count: int | None = None
    left_paths: list[Path] = field(init=False)
    right_paths: list[Path] = field(init=False)
    frames: NDArray[np.int64] = field(init=False)
    projections: dict[str, Array] = field(init=False)
    stamps: Array = field(init=False)
    poses: Array | None = field(init=False, default=None)
    sun_vectors: Array | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        self.root = Path(self.root)
        if not self.root.is_dir():
            raise DataFormatError(self.root, "sequence directory not found")
        left_dir, right_dir = ("image_2", "image_3") if self.colour else ("image_0", "image_1")
        left = self._list_images(self.root / left_dir)
        right = self._list_images(self.root / right_dir)
        left_frames = [_frame_number(p) for p in left]
        right_frames = [_frame_number(p) for p in right]
        if left_frames != right_frames:
            missing = sorted(set(left_frames) ^ set(right_frames))[:5]
            raise DataFormatError(
                self.root,
                f"{left_dir} has {len(left)} images and {right_dir} {len(right)}; unpaired frames {missing}",
            )
        end = None if self.count is None else self.start + self.count
        if self.start < 0 or (self.count is not None and self.count <= 0):
            raise ValueError(f"invalid frame selection start={self.start} count={self.count}")
        if self.start >= len(left):
            raise ValueError(f"start {self.start} is past the last of {len(left)} frames")
        self.left_paths, self.right_paths = left[self.start : end], right[self.start : end]
        self.frames = np.asarray(left_frames[self.start : end], dtype=np.int64)
        self.projections = read_kitti_calibration(_find_calibration(self.root))
        if self.colour and ("P2" not in self.projections or "P3" not in self.projections):
            raise DataFormatError(_find_calibration(self.root), "colour images need P2 and P3")
        self.stamps = self._read_stamps()
        poses_file = self.poses_file or (self.root / "poses.txt" if (self.root / "poses.txt").is_file() else None)
        if poses_file is not None:
            self.poses = self._index_by_frame(read_kitti_poses(poses_file), Path(poses_file), "poses")
        if self.sun_file is not None:
            self.sun_vectors = self._index_by_frame(read_kitti_sun_csv(self.sun_file), Path(self.sun_file), "sun vectors")

    @staticmethod
    def _list_images(directory: Path) -> list[Path]:
        if not directory.is_dir():
            raise DataFormatError(directory, "image directory not found")
        images = sorted(p for p in directory.iterdir() if p.suffix.lower() in (".png", ".pgm", ".ppm", ".jpg"))
        if not images:
            raise DataFormatError(directory, "no images in directory")
        return images

    def _index_by_frame(self, values: np.ndarray, path: Path, what: str) -> np.ndarray:
        last = int(self.frames.max())
        if len(values) <= last:
            raise DataFormatError(path, f"{len(values)} {what} but the images go up to frame {last} ({len(self.frames)} images)")
        return values[self.frames]

    def _read_stamps(self) -> Array:
        times_file = self.times_file or (self.root / "times.txt" if (self.root / "times.txt").is_file() else None)
        if times_file is not None:
            return self._index_by_frame(read_kitti_times(times_file), Path(times_file), "times")
        if self.rate_hz is None:
            raise DataFormatError(self.root, "no times.txt in the sequence; give a times file or a frame rate")
        if not np.isfinite(self.rate_hz) or self.rate_hz <= 0.0:
            raise ValueError(f"frame rate must be positive, got {self.rate_hz}")
        return self.frames.astype(float) / self.rate_hz

    def __len__(self) -> int:
        return len(self.left_paths)

    @property
    def projection_left(self) -> Array:
        return self.projections["P2" if self.colour else "P0"]

    @property
    def projection_right(self) -> Array:
        return self.projections["P3" if self.colour else "P1"]

    def camera(self, width: int = 0, height: int = 0) -> StereoCamera:
        """The rectified stereo model of the selected camera pair."""
        return StereoCamera.from_projection_matrices(self.projection_left, self.projection_right, width, height)

    def load_pair(self, index: int) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Left and right images of the index-th selected frame; sizes are checked to agree."""
        left = read_image(self.left_paths[index])
        right = read_image(self.right_paths[index])
        if left.shape != right.shape:
            raise DataFormatError(
                self.right_paths[index],
                f"size {right.shape[1]}x{right.shape[0]} differs from the left image's {left.shape[1]}x{left.shape[0]}",
            )
        return left, right
