"""DPC-Net's network, windows and task on the real KITTI 06 clip with a wrong focal length in its calib.txt
(the VO is then systematically wrong, as ch. 6 studies): targets turn the VO into the truth exactly, an
untrained network corrects nothing, training lowers the loss, and a missing pose file is one line."""

from __future__ import annotations

import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from pvo_pseudosensors.dpc_net.config import DPCNetConfig
from pvo_pseudosensors.dpc_net.data import DPCWindows, vo_poses, window_targets
from pvo_pseudosensors.dpc_net.loss import target_covariance
from pvo_pseudosensors.dpc_net.model import DPCNet, DPCTask
from pvo_pseudosensors.learning import Source, TrainConfig, fit

TINY = DPCNetConfig(height=32, width=104, stem=(4, 4, 8), body=(8, 16), dropout=0.1, deltas=(2, 3))


@pytest.fixture(scope="module")
def miscalibrated(pvo_data: Path, tmp_path_factory) -> Path:
    """The 06 clip with its focal length written 5 % too long (images unchanged)."""
    clip = pvo_data / "kitti" / "sequences" / "06"
    root = tmp_path_factory.mktemp("miscalibrated")
    for side in ("image_0", "image_1"):
        (root / side).mkdir()
        for path in sorted((clip / side).glob("*.png"))[:24]:
            (root / side / path.name).symlink_to(path)
    rows = [
        np.array(line.split()[-12:], float).reshape(3, 4)
        for line in (clip / "calib_P0_P1_unlabelled.txt").read_text().splitlines()
    ]
    lines = []
    for name, p in zip(("P0", "P1"), rows, strict=True):
        wrong = p.copy()
        wrong[0, 0] *= 1.05
        wrong[1, 1] *= 1.05
        wrong[0, 3] *= 1.05
        lines.append(f"{name}: " + " ".join(f"{v:.12e}" for v in wrong.reshape(-1)))
    (root / "calib.txt").write_text("\n".join(lines) + "\n")
    poses = (clip / "poses_frames000-050.txt").read_text().splitlines()[:24]
    (root / "poses.txt").write_text("\n".join(poses) + "\n")
    return root


def test_targets_turn_the_vo_into_the_truth(miscalibrated: Path, tmp_path: Path) -> None:
    from pvo_core.trajectory import read_kitti_poses

    data = DPCWindows([Source(miscalibrated, "06")], TINY, cache_dir=tmp_path)
    assert len(data) == (24 - 2) + (24 - 3)
    truth = read_kitti_poses(miscalibrated / "poses.txt")
    estimates = vo_poses(Source(miscalibrated, "06"), tmp_path)  # from the cache now
    assert len(list(tmp_path.glob("vo-*.npy"))) == 1
    sample = data[5]
    k, delta = int(sample["frame"]), int(sample["delta"])
    vo = np.linalg.inv(estimates[k]) @ estimates[k - delta]
    true = np.linalg.inv(truth[k]) @ truth[k - delta]
    np.testing.assert_allclose(sample["target"].numpy() @ vo, true, atol=1e-5)
    assert sample["first"].shape == (2, 32, 104)  # left and right stacked
    # the wrong focal length makes the VO's windows systematically wrong: the targets are not the identity
    targets = window_targets(truth, estimates, np.arange(0, 20), np.arange(3, 23))
    assert np.mean(np.linalg.norm(targets[:, :3, 3], axis=1)) > 0.02
    assert target_covariance(data.targets).shape == (6, 6)


def test_an_untrained_network_corrects_nothing_and_training_lowers_the_loss(miscalibrated: Path, tmp_path: Path) -> None:
    torch.manual_seed(0)
    network = DPCNet(TINY)
    frames = torch.rand(3, 2, 32, 104)
    assert torch.all(network(frames, frames) == 0.0)
    rotation = DPCNet(replace(TINY, variant="rotation"))
    assert rotation(frames[:, :1], frames[:, :1]).shape == (3, 3)
    data = DPCWindows([Source(miscalibrated, "06")], TINY, cache_dir=tmp_path)
    task = DPCTask(TINY, target_covariance(data.targets))
    config = TrainConfig(epochs=8, batch_size=8, learning_rate=1e-3, patience=0, threads=1)
    result = fit(task, data, data, config, tmp_path / "model", say=lambda _: None)
    assert result.history[-1]["train_loss"] < result.history[0]["train_loss"]
    assert result.best_validation < result.history[0]["validation_loss"]


def test_a_missing_pose_file_is_one_line(miscalibrated: Path, tmp_path: Path) -> None:
    copy = tmp_path / "copy"
    shutil.copytree(miscalibrated, copy, symlinks=True)
    (copy / "poses.txt").unlink()
    with pytest.raises(ValueError, match=r"poses.txt: needed for DPC-Net's targets but missing"):
        DPCWindows([Source(copy, "copy")], TINY)
    with pytest.raises(ValueError, match="unknown variant 'scale'"):
        DPCNetConfig(variant="scale")
