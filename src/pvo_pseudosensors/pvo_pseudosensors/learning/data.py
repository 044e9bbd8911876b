"""Datasets over KITTI-layout sequences (rendered corpora, real KITTI clips, Devon Island images).

Images are decoded and resized once to the model's input, stored as one ``(N, C, H, W)`` uint8 ``.npy``
per sequence, camera and size under a cache directory, and memory-mapped afterwards: decoding and
resizing PNGs every epoch would dominate a CPU epoch (``pvo bench learning`` measures both). Truth comes
from the sequence's sidecars through :mod:`pvo_core.readers`: poses (``poses.txt``), sun vectors
(``sun.csv``, left camera optical frame) and IMU (``imu.csv``).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.errors import DataFormatError
from pvo_core.readers import read_corpus_manifest, read_imu_csv, read_kitti_calibration, read_kitti_sun_csv
from pvo_core.trajectory import read_kitti_poses

from .spec import DataSpec

IMAGE_SUFFIXES = (".png", ".pgm", ".ppm", ".jpg")


@dataclass(frozen=True)
class Source:
    """One sequence directory and where it came from: the KITTI layout (``image_0``/``image_1`` or
    ``image_2``/``image_3``), or a flat folder of left images (the Devon Island release), found by itself."""

    root: Path
    name: str
    split: str = ""

    def images(self, side: str, colour: bool) -> list[Path]:
        names = ("image_2", "image_3") if colour else ("image_0", "image_1")
        folder = self.root / names[0 if side == "left" else 1]
        if not folder.is_dir() and self.root.is_dir():
            flat = sorted(p for p in self.root.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if flat and side != "left":
                raise DataFormatError(self.root, "a flat folder of images holds left images only (no right camera)")
            if flat:
                return flat
        if not folder.is_dir():
            raise DataFormatError(folder, "image directory not found")
        paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not paths:
            raise DataFormatError(folder, "no images in directory")
        return paths


def corpus_sources(corpus: str | Path, split: str) -> list[Source]:
    """The sequences of one split of a `pvo sim corpus` corpus."""
    manifest = read_corpus_manifest(corpus)
    sources = [Source(s.root, s.name, s.split) for s in manifest.split(split)]
    if not sources:
        raise ValueError(f"{manifest.path}: no sequence in the {split} split")
    return sources


def _cache_key(paths: Sequence[Path], size: tuple[int, int], colour: bool) -> str:
    """Changes whenever the images, the size or the colour mode do (paths, sizes and mtimes of the files)."""
    digest = hashlib.sha256(f"{size}:{colour}:{len(paths)}".encode())
    for path in paths:
        stat = path.stat()
        digest.update(f"{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}".encode())
    return digest.hexdigest()[:24]


def load_resized(path: Path, size: tuple[int, int], colour: bool) -> NDArray[np.uint8]:
    """One image as (C, H, W) uint8 at ``size`` (area-averaged when shrinking); one line naming a bad file."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_COLOR if colour else cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise DataFormatError(path, "not a readable image")
    height, width = size
    if image.shape[:2] != (height, width):
        shrinking = image.shape[0] > height
        image = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    if colour:
        return np.ascontiguousarray(image[:, :, ::-1].transpose(2, 0, 1))  # BGR -> RGB, channels first
    return image[None]


def cached_images(
    paths: Sequence[Path], size: tuple[int, int], colour: bool, cache_dir: Path | None, progress: Callable[[], None] | None = None
) -> NDArray[np.uint8]:
    """(N, C, H, W) uint8 of ``paths`` at ``size``: from the cache when present, else decoded once and stored
    (written to a temporary name and renamed: an interrupted run never leaves a half-written cache)."""
    if cache_dir is None:
        return np.stack([load_resized(p, size, colour) for p in paths])
    file = Path(cache_dir) / f"{_cache_key(paths, size, colour)}.npy"
    shape = (len(paths), 3 if colour else 1, *size)
    return cached_array(file, shape, np.dtype(np.uint8), lambda i: load_resized(paths[i], size, colour), progress)


def cached_array(
    file: Path,
    shape: tuple[int, ...],
    dtype: np.dtype,
    item: Callable[[int], NDArray],
    progress: Callable[[], None] | None = None,
) -> NDArray:
    """``file`` memory-mapped when it holds a readable array, else made from ``item(i)`` for each of shape[0]
    entries: written to a temporary name and renamed, so an interrupted run never leaves a half-written cache,
    and a damaged one is rebuilt."""
    if file.is_file():
        try:
            return np.load(file, mmap_mode="r")
        except (ValueError, OSError):
            file.unlink()
    file.parent.mkdir(parents=True, exist_ok=True)
    temporary = file.with_suffix(f".{os.getpid()}.tmp.npy")
    array = np.lib.format.open_memmap(temporary, mode="w+", dtype=dtype, shape=shape)
    for i in range(shape[0]):
        array[i] = item(i)
        if progress:
            progress()
    array.flush()
    del array
    os.replace(temporary, file)
    return np.load(file, mmap_mode="r")


@dataclass
class _Sequence:
    source: Source
    left: NDArray[np.uint8]
    right: NDArray[np.uint8] | None
    poses: NDArray[np.float64] | None
    sun: NDArray[np.float64] | None
    imu: NDArray[np.float64] | None
    camera: NDArray[np.float64] | None = None


@dataclass
class FrameDataset(torch.utils.data.Dataset):
    """Samples (one per frame k >= delta of every sequence) as dicts of tensors:

    ``left`` (C, H, W) float32 in [0, 1]; ``right``, ``previous`` (the left image at k - delta) likewise;
    ``relative`` (4, 4) T_k,k-delta (maps points from the earlier camera frame to the later one); ``sun``
    (3,) unit vector towards the sun in the left camera optical frame; ``imu`` (6,) angular rate (rad/s)
    and specific force (m/s²); ``camera`` (4,) the left camera's fx, fy, cx, cy in pixels of the resized image
    (from ``calib.txt``); ``sequence``, ``frame`` (ints)."""

    sources: Sequence[Source]
    spec: DataSpec
    cache_dir: Path | None = None
    progress: Callable[[], None] | None = None
    sequences: list[_Sequence] = field(init=False, default_factory=list)
    index: NDArray[np.int64] = field(init=False)

    def __post_init__(self) -> None:
        spec = self.spec
        rows = []
        for number, source in enumerate(self.sources):
            left_paths = source.images("left", spec.colour)
            left = cached_images(left_paths, spec.size, spec.colour, self.cache_dir, self.progress)
            right = None
            if spec.right:
                right_paths = source.images("right", spec.colour)
                if len(right_paths) != len(left_paths):
                    raise DataFormatError(source.root, f"{len(left_paths)} left images but {len(right_paths)} right")
                right = cached_images(right_paths, spec.size, spec.colour, self.cache_dir, self.progress)
            poses = self._truth(source, "poses.txt", read_kitti_poses, len(left_paths)) if spec.delta else None
            sun = self._truth(source, "sun.csv", read_kitti_sun_csv, len(left_paths)) if spec.sun else None
            imu = self._truth(source, "imu.csv", lambda p: read_imu_csv(p)[:, 1:], len(left_paths)) if spec.imu else None
            camera = _camera_at_size(source, left_paths[0], spec) if spec.camera else None
            self.sequences.append(_Sequence(source, left, right, poses, sun, imu, camera))
            frames = np.arange(spec.delta, len(left_paths))
            rows.append(np.column_stack([np.full(len(frames), number), frames]))
        self.index = np.vstack(rows) if rows else np.zeros((0, 2), np.int64)
        if len(self.index) == 0:
            raise ValueError("the dataset holds no sample (no sequence, or every sequence shorter than delta + 1)")

    @staticmethod
    def _truth(source: Source, name: str, reader: Callable[[Path], NDArray], frames: int) -> NDArray[np.float64]:
        path = source.root / name
        if not path.is_file():
            raise DataFormatError(path, f"needed by the dataset but missing ({source.name})")
        values = np.asarray(reader(path), dtype=np.float64)
        if len(values) != frames:
            raise DataFormatError(path, f"{len(values)} rows for {frames} images")
        return values

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, item: int) -> dict[str, torch.Tensor]:
        number, k = (int(v) for v in self.index[item])
        sequence = self.sequences[number]
        sample = {"left": _float(sequence.left[k]), "sequence": torch.tensor(number), "frame": torch.tensor(k)}
        if sequence.right is not None:
            sample["right"] = _float(sequence.right[k])
        if self.spec.delta:
            earlier = k - self.spec.delta
            sample["previous"] = _float(sequence.left[earlier])
            assert sequence.poses is not None
            relative = np.linalg.inv(sequence.poses[k]) @ sequence.poses[earlier]
            sample["relative"] = torch.from_numpy(relative.astype(np.float32))
        if sequence.sun is not None:
            sample["sun"] = torch.from_numpy(sequence.sun[k].astype(np.float32))
        if sequence.imu is not None:
            sample["imu"] = torch.from_numpy(sequence.imu[k].astype(np.float32))
        if sequence.camera is not None:
            sample["camera"] = torch.from_numpy(sequence.camera.astype(np.float32))
        return sample


def _camera_at_size(source: Source, first_image: Path, spec: DataSpec) -> NDArray[np.float64]:
    """The left camera's (fx, fy, cx, cy) from ``calib.txt`` (P0, or P2 for colour), scaled from the image's own
    size to ``spec.size`` (pixel centres map as resizing maps them: x' = (x + 0.5) s - 0.5)."""
    import cv2

    path = source.root / "calib.txt"
    if not path.is_file():
        raise DataFormatError(path, f"needed by the dataset (camera intrinsics) but missing ({source.name})")
    key = "P2" if spec.colour else "P0"
    matrices = read_kitti_calibration(path)
    if key not in matrices:
        raise DataFormatError(path, f"no {key} entry (the left camera's projection)")
    projection = matrices[key]
    image = cv2.imread(str(first_image), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise DataFormatError(first_image, "not a readable image")
    scale_y, scale_x = spec.size[0] / image.shape[0], spec.size[1] / image.shape[1]
    fx, fy, cx, cy = projection[0, 0], projection[1, 1], projection[0, 2], projection[1, 2]
    return np.array([fx * scale_x, fy * scale_y, (cx + 0.5) * scale_x - 0.5, (cy + 0.5) * scale_y - 0.5])


def _float(image: NDArray[np.uint8]) -> torch.Tensor:
    return torch.from_numpy(np.asarray(image, dtype=np.float32) / 255.0)
