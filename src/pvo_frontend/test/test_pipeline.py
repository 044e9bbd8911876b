"""StereoVO on the real KITTI 06 clip (regression against ground truth) and on bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_core.readers import KittiSequence
from pvo_frontend.vo import FrameStatus, StereoVO, VOConfig, flatten

from pvo_core import metrics

PACKAGE = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def clip(pvo_data: Path) -> tuple[KittiSequence, list]:
    root = pvo_data / "kitti/sequences/06"
    sequence = KittiSequence(root, rate_hz=10.0, poses_file=root / "poses_frames000-050.txt")
    return sequence, [sequence.load_pair(i) for i in range(len(sequence))]


@pytest.fixture(scope="module")
def clip_run(clip):
    sequence, images = clip
    vo = StereoVO(sequence.camera(), VOConfig())
    return [vo.process(left, right, float(t)) for (left, right), t in zip(images, sequence.stamps, strict=True)]


def test_kitti06_clip_accuracy(clip, clip_run) -> None:
    """Measured: end drift 1.021 % of 59.86 m, mean ATE 0.323 m, no lost frame (thresholds ~10 % above)."""
    sequence, _ = clip
    assert clip_run[0].status is FrameStatus.FIRST
    assert all(r.status is FrameStatus.TRACKING for r in clip_run[1:])
    gt = sequence.poses
    poses = np.array([r.pose for r in clip_run])
    err = metrics.absolute_trajectory_error(gt, poses)
    length = metrics.path_distances(gt)[-1]
    assert 100 * err[-1] / length < 1.15
    assert err.mean() < 0.36
    assert min(r.inliers for r in clip_run[1:]) > 150


def test_kitti06_covariances_are_valid_and_informative(clip, clip_run) -> None:
    sequence, _ = clip
    transforms = np.array([r.transform for r in clip_run[1:]])
    covariances = np.array([r.covariance for r in clip_run[1:]])
    assert np.allclose(covariances, np.swapaxes(covariances, 1, 2))
    assert np.all(np.linalg.eigvalsh(covariances) > 0)
    errors = metrics.relative_motion_errors(sequence.poses, transforms)
    nees = metrics.nees(errors, covariances) / 6
    # measured: median 4.2 per dof (thesis R); KITTI's ground truth itself is noisy frame to frame
    assert 0.5 < np.median(nees) < 8.0


def test_same_input_same_output(clip) -> None:
    sequence, images = clip
    runs = []
    for _ in range(2):
        vo = StereoVO(sequence.camera())
        runs.append(
            [vo.process(left, right, float(t)).pose for (left, right), t in zip(images[:6], sequence.stamps[:6], strict=True)]
        )
    assert np.array_equal(np.array(runs[0]), np.array(runs[1]))


def test_bad_input_is_reported_and_not_fatal(clip) -> None:
    sequence, images = clip
    vo = StereoVO(sequence.camera())
    stamps = sequence.stamps
    assert vo.process(*images[0], float(stamps[0])).status is FrameStatus.FIRST
    good = vo.process(*images[1], float(stamps[1]))
    assert good.ok

    mismatched = vo.process(images[2][0], images[2][1][:, :-10], float(stamps[2]))
    assert mismatched.status is FrameStatus.REJECTED and "differ in size" in mismatched.message

    repeated = vo.process(*images[1], float(stamps[1]))
    assert repeated.status is FrameStatus.REJECTED and "repeated frame" in repeated.message
    backwards = vo.process(*images[2], float(stamps[0]))
    assert backwards.status is FrameStatus.REJECTED and "backwards" in backwards.message
    assert np.array_equal(backwards.pose, good.pose)  # nothing that was good is lost

    black = np.zeros_like(images[2][0])
    lost = vo.process(black, black, float(stamps[2]))
    assert lost.status is FrameStatus.LOST and lost.covariance is not None
    assert np.allclose(lost.covariance, 9999.0 * np.eye(6))
    # the next good frame starts tracking again from freshly detected features
    statuses = [vo.process(*images[i], float(stamps[i])).status for i in range(3, 6)]
    assert statuses[-1] is FrameStatus.TRACKING

    wrong_type = vo.process(images[4][0].astype(np.float32), images[4][1], float(stamps[6]))
    assert wrong_type.status is FrameStatus.REJECTED and "8-bit" in wrong_type.message


def test_config_yaml_mirrors_dataclass() -> None:
    data = yaml.safe_load((PACKAGE / "config/stereo_vo.yaml").read_text())["stereo_vo"]["ros__parameters"]
    dotted = {k: v for k, v in data.items() if "." in k}
    assert dotted == flatten(VOConfig())


def test_dropped_frame_is_bridged(clip) -> None:
    """A missing frame (0.2 s gap) is tracked through: the motion is about twice a normal step."""
    sequence, images = clip
    vo = StereoVO(sequence.camera())
    steps = [vo.process(*images[i], float(sequence.stamps[i])) for i in (0, 1, 2, 4)]
    assert [s.status for s in steps] == [FrameStatus.FIRST, FrameStatus.TRACKING, FrameStatus.TRACKING, FrameStatus.TRACKING]
    single = np.linalg.norm(steps[2].transform[:3, 3])
    double = np.linalg.norm(steps[3].transform[:3, 3])
    assert 1.7 < double / single < 2.3
