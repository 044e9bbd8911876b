"""HydraNet's input: dense optical flow between consecutive left images, and the training pairs over sequences.

The flow is OpenCV's Farnebäck with the parameters of the thesis's code (pyramid scale 0.5, 3 levels,
window 15, 3 iterations, poly_n 5, poly_sigma 1.2) between the two grey images resized to the model's
input: (2, H, W) float32, pixels at that size, flow[:, v, u] = where pixel (u, v) of the earlier image went
in the later one. Per sequence, the flows of every consecutive pair, forward and reversed, are computed once
and kept as float16 ``.npy`` beside the decoded-image cache (memory-mapped afterwards): Farnebäck on every
sample every epoch would dominate a CPU epoch. With ``texture`` a third channel carries the texture of the image
the flow starts from (:func:`texture_map`): where it is flat (sky, an empty square) Farnebäck's flow is an
interpolation, not a measurement, and the channel shows the network where (measured: it did not teach the shipped
data's network to distrust such flow, see the README).

Farnebäck's pyramid stops where a level would be under 32 px (OpenCV's minimum), so at a 64-px-high input it has
two levels whatever ``levels`` says, and it cannot follow a displacement beyond a few pixels: a pure yaw of the
camera reads 99 % of its flow at 2°, 94 % at 3°, 63 % at 4° and 25 % at 5° per frame (KITTI's sharp turns reach
3-4.8° per frame). ``prior="shift"`` starts Farnebäck from the image's global shift (phase correlation with a Hann
window, +0.26 ms): the same yaws then read 98-99 % up to 6° (97.5 % at 8°). A per-model setting (``flow_prior`` on the card): a
network reads the flow it was trained on.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.errors import DataFormatError
from pvo_core.lie import rotation_to_quaternion
from pvo_core.trajectory import read_kitti_poses

from ..learning.data import Source, cached_array, cached_images
from .config import FLOW_PRIORS

FARNEBACK = (0.5, 3, 15, 3, 5, 1.2, 0)  # pyr_scale, levels, winsize, iterations, poly_n, poly_sigma, flags
FLOW_REVISION = 1  # bump when the flow computation changes: the caches are rebuilt


def dense_flow(earlier: NDArray[np.uint8], later: NDArray[np.uint8], prior: str = "none") -> NDArray[np.float32]:
    """Farnebäck flow (2, H, W) in pixels from ``earlier`` to ``later``, both grey (H, W) uint8 of one size;
    ``prior="shift"``: started from their global shift (:func:`global_shift`) instead of zero."""
    import cv2

    if earlier.shape != later.shape or earlier.ndim != 2:
        raise ValueError(f"flow needs two grey images of one size, got {earlier.shape} and {later.shape}")
    if prior == "none":
        flow = cv2.calcOpticalFlowFarneback(earlier, later, None, *FARNEBACK)
    elif prior == "shift":
        initial = np.empty((*earlier.shape, 2), np.float32)
        initial[...] = global_shift(earlier, later)
        flow = cv2.calcOpticalFlowFarneback(earlier, later, initial, *FARNEBACK[:-1], cv2.OPTFLOW_USE_INITIAL_FLOW)
    else:
        raise ValueError(f"unknown flow prior {prior!r}: choose one of {', '.join(FLOW_PRIORS)}")
    return np.ascontiguousarray(flow.transpose(2, 0, 1))


def global_shift(earlier: NDArray[np.uint8], later: NDArray[np.uint8]) -> tuple[float, float]:
    """(du, dv) pixels: where ``earlier``'s content moved in ``later`` as a whole (phase correlation with a Hann
    window; sub-pixel). A camera's turn moves the whole image; a forward motion's flow, radial, cancels out."""
    import cv2

    window = cv2.createHanningWindow((earlier.shape[1], earlier.shape[0]), cv2.CV_32F)
    (du, dv), _ = cv2.phaseCorrelate(earlier.astype(np.float32), later.astype(np.float32), window)
    return float(du), float(dv)


def texture_map(image: NDArray[np.uint8]) -> NDArray[np.float32]:
    """(H, W) float32 log(1 + |grad I|) of a grey (H, W) uint8 image, the gradient by 3x3 Sobel normalised to grey
    levels per pixel (a ramp of slope g gives log(1 + g) inside the image)."""
    import cv2

    grey = image.astype(np.float32)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE) / 8.0
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE) / 8.0
    return np.log1p(np.sqrt(gx * gx + gy * gy))


def network_input(
    source: NDArray[np.uint8],
    flow: NDArray[np.floating],
    texture: bool,
    pitch_deg: float | None = None,
    inverse_depth: NDArray[np.floating] | None = None,
) -> NDArray[np.float32]:
    """The network's input (2-5, H, W) float32: the flow (2, H, W) from grey ``source`` (H, W); with ``texture``
    the source's :func:`texture_map` as a channel; with ``pitch_deg`` (the camera's pitch below the horizon, deg)
    a constant channel of pitch_deg / 10; with ``inverse_depth`` (1, H, W) the source's
    :func:`stereo_inverse_depth`."""
    channels = [np.asarray(flow, dtype=np.float32)]
    if texture:
        channels.append(texture_map(np.asarray(source))[None])
    if pitch_deg is not None:
        channels.append(np.full((1, *channels[0].shape[1:]), pitch_deg / 10.0, np.float32))
    if inverse_depth is not None:
        channels.append(np.asarray(inverse_depth, dtype=np.float32).reshape(1, *channels[0].shape[1:]))
    return channels[0] if len(channels) == 1 else np.concatenate(channels, axis=0)


DEPTH_SCALE = 10.0  # the depth channel carries DEPTH_SCALE / Z: 5 at 2 m, 0.5 at 20 m, 0 where nothing matched
DEPTH_REVISION = 1  # bump when the depth computation changes: the caches are rebuilt


def stereo_inverse_depth(
    left: NDArray[np.uint8], right: NDArray[np.uint8], focal_px: float, baseline_m: float, size: tuple[int, int]
) -> NDArray[np.float32]:
    """(H, W) float32 DEPTH_SCALE / Z of the left image's pixels (Z in m along the optical axis) at ``size``
    (height, width), from semi-global block matching on the rectified grey pair ``left``, ``right`` at their own
    size (``focal_px`` at that size), resized by averaging the matched pixels of each output pixel's area: where
    nothing matched (flat regions, occlusions, the sky, the left border the matcher cannot search) 0, as at
    infinity."""
    import cv2

    if left.shape != right.shape or left.ndim != 2:
        raise ValueError(f"stereo depth needs two grey images of one size, got {left.shape} and {right.shape}")
    disparities = 16 * max(1, -(-int(0.15 * left.shape[1]) // 16))  # nearest depth about f b / (0.15 width)
    block = 7
    matcher = cv2.StereoSGBM_create(
        minDisparity=0, numDisparities=disparities, blockSize=block, P1=8 * block * block, P2=32 * block * block,
        uniquenessRatio=10, speckleWindowSize=50, speckleRange=2, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY,
    )  # fmt: skip
    disparity = matcher.compute(left, right).astype(np.float32) / 16.0
    matched = (disparity > 0.0).astype(np.float32)
    inverse = (disparity * matched * (DEPTH_SCALE / (focal_px * baseline_m))).astype(np.float32)
    shrink = lambda image: cv2.resize(image, (size[1], size[0]), interpolation=cv2.INTER_AREA)  # noqa: E731
    share = shrink(matched)  # the mean over the matched pixels of each output pixel's area, not over the holes
    return np.where(share > 0.0, shrink(inverse) / np.maximum(share, 1e-6), 0.0).astype(np.float32)


def sequence_inverse_depths(
    source: Source, size: tuple[int, int], cache_dir: Path | None, progress: Callable[[], None] | None = None
) -> NDArray[np.float16]:
    """(N, 1, H, W) float16 :func:`stereo_inverse_depth` of every frame of ``source`` (its grey pair and
    calib.txt's P0, P1), from the cache when present."""
    import cv2
    from pvo_core.camera import StereoCamera
    from pvo_core.readers import read_kitti_calibration

    lefts, rights = source.images("left", False), source.images("right", False)
    if len(lefts) != len(rights):
        raise DataFormatError(source.root, f"{len(lefts)} left and {len(rights)} right images: the depth input needs pairs")
    matrices = read_kitti_calibration(source.root / "calib.txt")
    camera = StereoCamera.from_projection_matrices(matrices["P0"], matrices["P1"])

    def item(i: int) -> NDArray[np.float32]:
        left = cv2.imread(str(lefts[i]), cv2.IMREAD_GRAYSCALE)
        right = cv2.imread(str(rights[i]), cv2.IMREAD_GRAYSCALE)
        if left is None or right is None:
            raise DataFormatError(lefts[i] if left is None else rights[i], "unreadable image")
        return stereo_inverse_depth(left, right, camera.f, camera.baseline, size)[None]

    if cache_dir is None:
        return np.stack([item(i) for i in range(len(lefts))]).astype(np.float16)
    key = f"{_images_key(lefts + rights, size)}:depth:{DEPTH_REVISION}:{DEPTH_SCALE}"
    file = Path(cache_dir) / f"depth-{hashlib.sha256(key.encode()).hexdigest()[:24]}.npy"
    return cached_array(file, (len(lefts), 1, *size), np.dtype(np.float16), item, progress)


def camera_pitch(source: Source) -> float:
    """The camera's pitch below the horizon (deg) that ``source``'s sim.yaml records (``config.pitch_deg``)."""
    import yaml

    path = source.root / "sim.yaml"
    if not path.is_file():
        raise DataFormatError(
            path, f"the pitch input needs the camera's pitch, but {source.name} has no sim.yaml (give it: --pitch-deg)"
        )
    try:
        return float(yaml.safe_load(path.read_text())["config"]["pitch_deg"])
    except (KeyError, TypeError, ValueError, yaml.YAMLError) as error:
        raise DataFormatError(path, f"no readable config.pitch_deg ({error})") from None


def relative_rotations(poses: NDArray[np.float64], gap: int = 1) -> NDArray[np.float64]:
    """(N-gap, 4) quaternions (w >= 0) of C_k,k-gap for camera-to-world poses (N, 4, 4): the rotation that maps
    directions in the earlier camera frame into the later one."""
    relative = np.linalg.inv(poses[gap:])[:, :3, :3] @ poses[:-gap, :3, :3]
    return np.stack([rotation_to_quaternion(r) for r in relative])


def _flow_file(images_key: str, cache_dir: Path, reverse: bool, prior: str = "none", gap: int = 1) -> Path:
    prior_key = "" if prior == "none" else f":{prior}"  # the flows cached before the prior keep their files
    gap_key = "" if gap == 1 else f":gap{gap}"  # and those cached before the gap
    digest = hashlib.sha256(f"{images_key}:{FARNEBACK}:{FLOW_REVISION}:{reverse}{prior_key}{gap_key}".encode()).hexdigest()[:24]
    return Path(cache_dir) / f"flow-{digest}.npy"


def sequence_flows(
    images: NDArray[np.uint8],
    cache_dir: Path | None,
    key: str,
    reverse: bool,
    progress: Callable[[], None] | None = None,
    prior: str = "none",
    gap: int = 1,
) -> NDArray[np.float16]:
    """(N-gap, 2, H, W) float16 flows of the images (N, 1, H, W) ``gap`` frames apart: k-gap -> k, or k -> k-gap
    with ``reverse`` (row i: the pair ending at frame i + gap); from the cache when present (written under a
    temporary name and renamed)."""
    count = len(images) - gap
    if cache_dir is None:
        return np.stack([_pair_flow(images, k, reverse, prior, gap) for k in range(gap, count + gap)]).astype(np.float16)
    shape = (count, 2, *images.shape[2:])
    item = lambda i: _pair_flow(images, i + gap, reverse, prior, gap)  # noqa: E731 - the pair ending at frame i + gap
    return cached_array(_flow_file(key, cache_dir, reverse, prior, gap), shape, np.dtype(np.float16), item, progress)


def _pair_flow(images: NDArray[np.uint8], k: int, reverse: bool, prior: str, gap: int = 1) -> NDArray[np.float32]:
    earlier, later = np.asarray(images[k - gap, 0]), np.asarray(images[k, 0])
    return dense_flow(later, earlier, prior) if reverse else dense_flow(earlier, later, prior)


@dataclass
class _Pairs:
    source: Source
    forward: NDArray[np.float16]
    backward: NDArray[np.float16] | None
    rotations: NDArray[np.float64] | None
    images: NDArray[np.uint8]  # (N, 1, H, W) at the flow's size
    pitch_deg: float | None = None  # the camera's pitch with the pitch input
    inverse_depths: NDArray[np.float16] | None = None  # (N, 1, H, W) with the depth input


@dataclass
class FlowPairs(torch.utils.data.Dataset):
    """Samples, one per pair of left images ``gap`` frames apart (1: consecutive) of every sequence (and one more
    per pair reversed with ``reverse``), as dicts: ``flow`` (2, H, W) float32 pixels; ``rotation`` (4,) the unit
    quaternion (w, x, y, z) of C_k,k-gap (C_k-gap,k for a reversed pair); ``sequence``, ``frame`` (the later frame k),
    ``reversed`` (0 or 1). targets: read each sequence's ``poses.txt`` for the rotations (False: flows only,
    for prediction on sequences without truth; samples then carry no ``rotation``); texture: ``flow`` carries
    the texture of the image it starts from as a third channel (:func:`network_input`); pitch: and the camera's
    pitch as a constant channel: ``pitch_deg`` for every sequence, else each sequence's sim.yaml; depth: and the
    inverse depth of the image it starts from, by stereo matching (:func:`stereo_inverse_depth`)."""

    sources: Sequence[Source]
    size: tuple[int, int]
    reverse: bool = False
    cache_dir: Path | None = None
    progress: Callable[[], None] | None = None
    targets: bool = True
    texture: bool = False
    pitch: bool = False
    pitch_deg: float | None = None
    flow_prior: str = "none"
    depth: bool = False
    gap: int = 1
    pairs: list[_Pairs] = field(init=False, default_factory=list)
    index: NDArray[np.int64] = field(init=False)

    def __post_init__(self) -> None:
        if self.gap < 1:
            raise ValueError(f"gap must be >= 1 frame, got {self.gap}")
        rows = []
        for number, source in enumerate(self.sources):
            paths = source.images("left", False)
            if len(paths) < self.gap + 1:
                needed = "two images" if self.gap == 1 else f"{self.gap + 1} images (pairs {self.gap} frames apart)"
                raise DataFormatError(source.root, f"HydraNet needs at least {needed} per sequence")
            rotations = self._rotations(source, len(paths)) if self.targets else None
            images = cached_images(paths, self.size, False, self.cache_dir, self.progress)
            key = _images_key(paths, self.size)
            forward = sequence_flows(images, self.cache_dir, key, False, self.progress, self.flow_prior, self.gap)
            backward = (
                sequence_flows(images, self.cache_dir, key, True, self.progress, self.flow_prior, self.gap)
                if self.reverse
                else None
            )
            pitch = (camera_pitch(source) if self.pitch_deg is None else self.pitch_deg) if self.pitch else None
            depths = sequence_inverse_depths(source, self.size, self.cache_dir, self.progress) if self.depth else None
            self.pairs.append(_Pairs(source, forward, backward, rotations, images, pitch, depths))
            frames = np.arange(self.gap, len(paths))
            rows.append(np.column_stack([np.full(len(frames), number), frames, np.zeros(len(frames), np.int64)]))
            if self.reverse:
                rows.append(np.column_stack([np.full(len(frames), number), frames, np.ones(len(frames), np.int64)]))
        self.index = np.vstack(rows) if rows else np.zeros((0, 3), np.int64)
        if len(self.index) == 0:
            raise ValueError("the dataset holds no image pair")

    def _rotations(self, source: Source, images: int) -> NDArray[np.float64]:
        poses_file = source.root / "poses.txt"
        if not poses_file.is_file():
            raise DataFormatError(poses_file, f"needed for HydraNet's targets but missing ({source.name})")
        poses = read_kitti_poses(poses_file)
        if len(poses) != images:
            raise DataFormatError(poses_file, f"{len(poses)} poses for {images} images")
        return relative_rotations(poses, self.gap)

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, item: int) -> dict[str, torch.Tensor]:
        number, k, backwards = (int(v) for v in self.index[item])
        pairs = self.pairs[number]
        flows = pairs.backward if backwards else pairs.forward
        assert flows is not None
        first = k if backwards else k - self.gap  # the image the flow starts from
        depth = None if pairs.inverse_depths is None else pairs.inverse_depths[first]
        flow = flows[k - self.gap]
        sample = {
            "flow": torch.from_numpy(network_input(pairs.images[first, 0], flow, self.texture, pairs.pitch_deg, depth)),
            "sequence": torch.tensor(number),
            "frame": torch.tensor(k),
            "reversed": torch.tensor(backwards),
        }
        if pairs.rotations is not None:
            rotation = pairs.rotations[k - self.gap] * (np.array([1.0, -1.0, -1.0, -1.0]) if backwards else 1.0)
            sample["rotation"] = torch.from_numpy(rotation.astype(np.float32))
        return sample


def _images_key(paths: Sequence[Path], size: tuple[int, int]) -> str:
    digest = hashlib.sha256(f"{size}:{len(paths)}".encode())
    for path in paths:
        stat = path.stat()
        digest.update(f"{path.resolve()}:{stat.st_size}:{stat.st_mtime_ns}".encode())
    return digest.hexdigest()
