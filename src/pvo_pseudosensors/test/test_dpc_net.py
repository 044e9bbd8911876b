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
from pvo_pseudosensors.dpc_net.model import DPCNet, DPCTask, estimate_input
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


def _copy_with(root: Path, out: Path, focal_scale: float = 1.0, sim: dict | None = None) -> Path:
    """``root``'s sequence linked, calib.txt's focal length times ``focal_scale``, a sim.yaml if given."""
    import yaml

    shutil.copytree(root, out, symlinks=True)
    lines = []
    for line in (root / "calib.txt").read_text().splitlines():
        key, values = line.split(":")
        p = np.array(values.split(), float).reshape(3, 4)
        p[0, 0], p[1, 1], p[0, 3] = p[0, 0] * focal_scale, p[1, 1] * focal_scale, p[0, 3] * focal_scale
        lines.append(f"{key}: " + " ".join(f"{v:.12e}" for v in p.reshape(-1)))
    (out / "calib.txt").write_text("\n".join(lines) + "\n")
    if sim is not None:
        (out / "sim.yaml").write_text(yaml.safe_dump({"config": {"degradations": sim}}))
    return out


def test_the_card_records_the_rig_and_a_model_is_refused_on_another(miscalibrated: Path, tmp_path: Path) -> None:
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net
    from pvo_pseudosensors.dpc_net.rig import check_rig, rig_problems, sequence_rig, training_rig

    data = DPCWindows([Source(miscalibrated, "06")], TINY, cache_dir=tmp_path)
    rig = training_rig(data.rigs)
    assert rig["size"] == [1226, 370] and rig["lens"] is None  # real images: the lens is unknown
    fit(DPCTask(TINY, target_covariance(data.targets), rig), data, data, TrainConfig(epochs=1, threads=1), tmp_path / "m")
    _, card = load_dpc_net(tmp_path / "m")
    assert card.input["rig"] == rig
    # the training camera itself: used, flagged for what cannot be known
    warnings = check_rig(card.input["rig"], miscalibrated)
    assert any("the lens cannot be checked" in w for w in warnings)
    # another focal length: refused in one line naming both
    longer = _copy_with(miscalibrated, tmp_path / "longer", focal_scale=1.2)
    with pytest.raises(
        ValueError, match=r"longer: not this DPC-Net model's rig: calib.txt's focal 890.9 px is outside the trained 742.4-742.4"
    ):
        check_rig(card.input["rig"], longer)
    assert check_rig(card.input["rig"], longer, allow_any=True)  # forced: the refusal becomes a warning
    # a model of another VO's errors is flagged
    _, flagged = rig_problems(rig | {"vo": "0123"}, sequence_rig(miscalibrated), "4567")
    assert "the model learned the errors of VO 0123, this VO is 4567" in flagged[0]
    # a known lens against a model of known clean images: refused; sequences of two lenses do not make one rig
    clean = sequence_rig(_copy_with(miscalibrated, tmp_path / "clean", sim={"distortion": 0.0}))
    lens = sequence_rig(_copy_with(miscalibrated, tmp_path / "lens", sim={"distortion": [-0.3, 0.2, 0.01]}))
    assert lens.lens == (-0.3, 0.2, 0.01) and clean.lens == () and clean.focal_scale == 1.0
    with pytest.raises(ValueError, match="the training sequences mix rigs: lens"):
        training_rig([clean, lens])
    with pytest.raises(
        ValueError, match=r"not this DPC-Net model's rig: the images' lens \[-0.3, 0.2, 0.01\] is not the model's none"
    ):
        check_rig(training_rig([clean]), tmp_path / "lens")


def test_perfect_corrections_overwrite_the_window_ends_with_the_truth(miscalibrated: Path, tmp_path: Path) -> None:
    from pvo_core.trajectory import read_kitti_poses
    from pvo_pseudosensors.dpc_net.infer import Corrections, overwrite_trajectory

    truth = read_kitti_poses(miscalibrated / "poses.txt")
    truth = np.linalg.inv(truth[0]) @ truth
    vo = vo_poses(Source(miscalibrated, "06"), tmp_path)
    last = np.arange(4, len(vo), 4)
    first = last - 4
    perfect = np.linalg.inv(truth[last]) @ truth[first]
    corrected = overwrite_trajectory(vo, Corrections(first, last, perfect, np.zeros((len(last), 6, 6))))
    np.testing.assert_allclose(corrected[last], truth[last], atol=1e-9)
    # in between, the VO's own transforms from the window's corrected first pose
    k = 6
    np.testing.assert_allclose(corrected[k], truth[4] @ np.linalg.inv(vo[4]) @ vo[k], atol=1e-9)
    assert np.abs(vo[last] - truth[last]).max() > 1e-3  # the miscalibrated VO itself is off
    with pytest.raises(ValueError, match="not consecutive: one starts at frame 8, the last ends at 4"):
        overwrite_trajectory(vo, Corrections(first[[0, 2]], last[[0, 2]], perfect[[0, 2]], np.zeros((2, 6, 6))))


def test_every_variant_becomes_a_left_correction_with_unmeasured_axes() -> None:
    from pvo_pseudosensors.dpc_net.infer import UNMEASURED, correction_vectors, measurement_covariance

    covariance = np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    calibration = {"target_covariance": covariance}
    pose, rotation, yaw = TINY, replace(TINY, variant="rotation"), replace(TINY, variant="yaw")
    np.testing.assert_array_equal(correction_vectors(rotation, np.array([[0.1, 0.2, 0.3]])), [[0, 0, 0, 0.1, 0.2, 0.3]])
    np.testing.assert_array_equal(correction_vectors(yaw, np.array([[0.4]])), [[0, 0, 0, 0, 0.4, 0]])
    np.testing.assert_array_equal(measurement_covariance(pose, calibration), covariance)
    assert np.diag(measurement_covariance(rotation, calibration)).tolist() == [UNMEASURED] * 3 + [4.0, 5.0, 6.0]
    assert np.diag(measurement_covariance(yaw, calibration)).tolist() == [UNMEASURED] * 4 + [5.0, UNMEASURED]
    residual = {"target_covariance": covariance, "residual_covariance": 0.5 * covariance}
    np.testing.assert_array_equal(measurement_covariance(pose, residual), 0.5 * covariance)
    # the axes the correction made worse on validation are not fused
    worse = residual | {
        "residual": {"corrected_x": 1.0, "corrected_y": 1.0, "corrected_z": 1.0}
        | dict.fromkeys(("corrected_rx", "corrected_ry", "corrected_rz"), 0.0)
    }
    assert np.diag(measurement_covariance(pose, worse)).tolist() == [0.5, 1.0, 1.5] + [UNMEASURED] * 3
    # axes chosen on validation drives override the per-window verdicts; none chosen: nothing measured
    drives = worse | {"fused_axes": ["z", "ry"]}
    assert np.diag(measurement_covariance(pose, drives)).tolist() == [UNMEASURED] * 2 + [1.5, UNMEASURED, 2.5, UNMEASURED]
    assert np.diag(measurement_covariance(rotation, drives)).tolist() == [UNMEASURED] * 4 + [2.5, UNMEASURED]
    assert np.diag(measurement_covariance(pose, worse | {"fused_axes": []})).tolist() == [UNMEASURED] * 6
    # corrections made consistent over a longer span: the measured axes scaled, the unmeasured left unmeasured
    scaled = drives | {"correction_scale": [4.0, 4.0, 9.0, 1.0, 0.25, 1e-6]}
    assert np.diag(measurement_covariance(pose, scaled)).tolist() == pytest.approx(
        [UNMEASURED] * 2 + [13.5, UNMEASURED, 0.625, UNMEASURED]
    )
    for bad in ([1.0] * 5, [1.0, 1.0, 1.0, 1.0, 1.0, 0.0], [1.0, 1.0, 1.0, 1.0, 1.0, float("nan")]):
        with pytest.raises(ValueError, match="correction_scale must be 6 positive numbers"):
            measurement_covariance(pose, drives | {"correction_scale": bad})


def test_the_validation_mean_error_is_removed_only_where_the_card_chose_it() -> None:
    from pvo_core.lie import se3_exp, se3_log
    from pvo_pseudosensors.dpc_net.infer import AXES, measurement_covariance, remove_residual_mean, residual_mean

    mean = np.array([0.01, -0.02, 0.03, 1e-4, -4.5e-4, 2e-4])  # a constant yaw offset the network learned, and more
    second_moment = np.diag([0.02, 0.03, 0.04, 1e-6, 2e-6, 3e-6]) + np.outer(mean, mean)
    calibration = {
        "target_covariance": np.eye(6),
        "residual_covariance": second_moment,
        "residual": {f"bias_{axis}_after": float(v) for axis, v in zip(AXES, mean, strict=True)},
    }
    rng = np.random.default_rng(3)
    transforms = np.stack([se3_exp(rng.normal(scale=0.1, size=6)) for _ in range(4)])
    # not chosen (the shipped cards before the choice existed): the corrections and their covariance as they were
    np.testing.assert_array_equal(residual_mean(calibration), np.zeros(6))
    assert remove_residual_mean(transforms, calibration) is transforms
    np.testing.assert_array_equal(measurement_covariance(TINY, calibration), second_moment)
    chosen = calibration | {"remove_mean": True}
    np.testing.assert_array_equal(residual_mean(chosen), mean)
    removed = remove_residual_mean(transforms, chosen)
    for before, after in zip(transforms, removed, strict=True):  # exp(b^) T: the left error's mean taken off
        np.testing.assert_allclose(se3_log(after @ np.linalg.inv(before)), mean, atol=1e-12)
    # the covariance left is the spread about that mean, not the second moment
    np.testing.assert_allclose(measurement_covariance(TINY, chosen), second_moment - np.outer(mean, mean), atol=1e-15)
    assert remove_residual_mean(np.zeros((0, 4, 4)), chosen).shape == (0, 4, 4)
    # a card that asks for the removal without the figures is one clear line, not zeros or a KeyError
    partial = chosen | {"residual": {k: v for k, v in chosen["residual"].items() if k != "bias_ry_after"}}
    with pytest.raises(ValueError, match="remove_mean but its residual has no bias_ry_after figures"):
        remove_residual_mean(transforms, partial)
    with pytest.raises(ValueError, match="has no bias_x/y/z/rx/ry/rz_after figures"):
        measurement_covariance(TINY, chosen | {"residual": None})
    with pytest.raises(ValueError, match="residual mean must be finite"):
        residual_mean(chosen | {"residual": chosen["residual"] | {"bias_x_after": float("nan")}})


def test_the_residual_covariance_of_no_correction_is_the_targets_second_moment(miscalibrated: Path, tmp_path: Path) -> None:
    from pvo_core.lie import se3_log
    from pvo_pseudosensors.dpc_net.infer import residual_covariance

    windows = DPCWindows([Source(miscalibrated, "06")], TINY, cache_dir=tmp_path, deltas=(3,))
    card = DPCTask(TINY).card()
    covariance, figures = residual_covariance(DPCNet(TINY).eval(), card, windows, batch_size=7)
    logs = np.stack([se3_log(t) for t in windows.targets])
    np.testing.assert_allclose(covariance, logs.T @ logs / len(logs), rtol=1e-5, atol=1e-10)
    assert figures["windows"] == len(windows) == 24 - 3
    assert figures["translation_error_m_after"] == pytest.approx(figures["translation_error_m_before"], rel=1e-5)
    assert figures["corrected_z"] == 0.0  # no correction lowers no error


class ConstantCorrection(torch.utils.data.Dataset):
    """Random stereo frames, every window's target the same T* = exp(ξ*^): a rig whose VO is always off the same way."""

    def __init__(self, xi: np.ndarray, count: int = 64) -> None:
        from pvo_core.lie import se3_exp

        generator = torch.Generator().manual_seed(1)
        self.frames = torch.rand(count, 2, 2, 32, 104, generator=generator)
        self.target = torch.from_numpy(se3_exp(xi).astype(np.float32))

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, item: int) -> dict[str, torch.Tensor]:
        return {"first": self.frames[item, 0], "last": self.frames[item, 1], "target": self.target}


def test_a_tiny_model_learns_a_constant_correction(tmp_path: Path) -> None:
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net

    xi = np.array([0.02, -0.01, -0.12, 0.002, -0.004, 0.001])  # the lens's kind: forward motion overestimated
    data = ConstantCorrection(xi)
    covariance = np.diag([0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4])
    config = TrainConfig(epochs=60, batch_size=16, learning_rate=3e-3, patience=0, threads=1)
    fit(DPCTask(replace(TINY, dropout=0.0), covariance), data, data, config, tmp_path / "m", say=lambda _: None)
    model, _ = load_dpc_net(tmp_path / "m")
    with torch.no_grad():
        predicted = model(data.frames[:8, 0], data.frames[:8, 1]).double().numpy()
    np.testing.assert_allclose(predicted, np.broadcast_to(xi, (8, 6)), atol=0.1 * np.abs(xi).max())


class ScaleBias(torch.utils.data.Dataset):
    """Uninformative random frames; the VO's window motions random, each 3 % too long in translation and 3 % too
    short in rotation (a focal length written 3 % long does that): T* = T T̂^-1 depends on the VO's estimate."""

    def __init__(self, count: int = 96, seed: int = 2) -> None:
        from pvo_core.lie import se3_exp

        rng = np.random.default_rng(seed)
        self.frames = torch.rand(count, 2, 2, 32, 104, generator=torch.Generator().manual_seed(seed))
        truth_logs = np.column_stack(
            [rng.normal(0, 0.3, (count, 2)), rng.uniform(1.0, 4.0, count), rng.normal(0, 0.05, (count, 3))]
        )
        estimates = np.array([se3_exp(np.concatenate([1.03 * x[:3], x[3:] / 1.03])) for x in truth_logs])
        self.truth = np.array([se3_exp(x) for x in truth_logs])
        self.estimates = estimates
        self.logs = estimate_input(estimates)
        self.targets = torch.from_numpy((self.truth @ np.linalg.inv(estimates)).astype(np.float32))

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, item: int) -> dict[str, torch.Tensor]:
        return {
            "first": self.frames[item, 0],
            "last": self.frames[item, 1],
            "target": self.targets[item],
            "estimate": self.logs[item],
        }


def test_a_model_fed_the_vo_estimate_learns_a_scale_bias_that_images_cannot_show(tmp_path: Path) -> None:
    """With ``vo_input`` the correction of a calibration-like bias (proportional to the VO's motion) is learned
    from the estimate; on held-out windows the corrected translation error falls tenfold. The image-only network
    on the same windows can at best learn the mean correction. An estimate missing at inference is one line."""
    from pvo_core.lie import se3_exp, se3_log
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net

    train, test = ScaleBias(seed=2), ScaleBias(seed=3)
    covariance = np.diag([0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4])
    config = TrainConfig(epochs=80, batch_size=16, learning_rate=3e-3, patience=0, threads=1)
    errors = {}
    for name, vo_input in (("vo", True), ("images", False)):
        fit(
            DPCTask(replace(TINY, dropout=0.0, vo_input=vo_input), covariance),
            train,
            train,
            config,
            tmp_path / name,
            say=lambda _: None,
        )
        model, card = load_dpc_net(tmp_path / name)
        assert card.hyperparameters["vo_input"] is vo_input
        with torch.no_grad():
            xi = model(test.frames[:, 0], test.frames[:, 1], test.logs).double().numpy()
        corrected = np.array([se3_exp(x) @ e for x, e in zip(xi, test.estimates, strict=True)])
        errors[name] = np.mean(
            [np.linalg.norm(se3_log(t @ np.linalg.inv(c))[:3]) for t, c in zip(test.truth, corrected, strict=True)]
        )
    before = np.mean([np.linalg.norm(se3_log(t @ np.linalg.inv(e))[:3]) for t, e in zip(test.truth, test.estimates, strict=True)])
    assert errors["vo"] < 0.1 * before
    assert errors["images"] > 0.3 * before
    model_vo, _ = load_dpc_net(tmp_path / "vo")
    with pytest.raises(ValueError, match="VO's estimate"):
        model_vo(test.frames[:1, 0], test.frames[:1, 1])


def test_an_axis_is_fused_when_the_correction_lowers_the_drift_not_the_window_error() -> None:
    from pvo_pseudosensors.dpc_net.infer import lowers_drift

    rng = np.random.default_rng(0)
    noise = rng.normal(size=(5000, 6))
    before = 1e-3 * noise + 2e-4  # a bias a tenth of the noise on every axis
    after = before.copy()
    after[:, 4] = 1.03e-3 * noise[:, 4] + 0.2e-4  # the bias mostly removed, 3 % more noise
    after[:, 5] = 1.10e-3 * noise[:, 5] + 2e-4  # noisier, the bias left
    per_window = lowers_drift(before, after, windows=1)
    over_a_drive = lowers_drift(before, after, windows=100)
    assert not per_window[4] and over_a_drive[4]  # per window it looks useless; over 100 windows it is not
    assert not per_window[5] and not over_a_drive[5]
    assert not over_a_drive[:4].any()  # unchanged axes are not "lowered"


def test_mirrored_inference_is_exactly_mirror_equivariant_and_off_changes_nothing() -> None:
    """A window through the mirror (images flipped, left and right swapped, T̂ -> M T̂ M^-1) gets the mirror of the
    window's averaged correction; without the mirror the network's own output."""
    from pvo_core.lie import se3_exp, se3_log
    from pvo_pseudosensors.dpc_net.infer import _mirror_conjugation, correction_outputs, correction_vectors

    config = replace(TINY, vo_input=True)
    torch.manual_seed(3)
    model = DPCNet(config).eval()
    torch.nn.init.normal_(model.head.weight, std=0.02)
    torch.nn.init.normal_(model.vo_head.weight, std=0.2)
    first, last = torch.rand(5, 2, 32, 104), torch.rand(5, 2, 32, 104)
    rng = np.random.default_rng(0)
    estimates = np.array([se3_exp(np.r_[rng.normal(0, 0.3, 2), 1.2, rng.normal(0, 0.02, 3)]) for _ in range(5)])
    plain = correction_outputs(model, config, first, last, estimates, False, 0.54)
    with torch.no_grad():
        direct = correction_vectors(config, model(first, last, estimate_input(estimates)).double().numpy())
    assert np.array_equal(plain, direct)

    averaged = correction_outputs(model, config, first, last, estimates, True, 0.54)
    conjugation = _mirror_conjugation(0.54)
    assert np.allclose(conjugation @ conjugation, np.eye(4))  # the mirror of the mirrored rig is the rig
    flipped = [torch.flip(f[:, [1, 0]], dims=[-1]) for f in (first, last)]
    through = correction_outputs(model, config, *flipped, conjugation @ estimates @ conjugation, True, 0.54)
    expected = np.array([se3_log(conjugation @ se3_exp(x) @ conjugation) for x in averaged])
    assert through == pytest.approx(expected, abs=1e-6)
    assert np.abs(averaged - plain).max() > 1e-4  # the untrained network is not symmetric: the average moved it


def test_the_shipped_corrections_name_the_vo_they_learned_and_every_tool_runs_it() -> None:
    """A card records every setting of its VO, so it stays bound to that VO when the defaults change: the
    settings agree with the signature, and the model's config (which training, calibration and evaluation run)
    rebuilds exactly that VO. A VO setting added since (at the value that keeps the VO as it was) leaves the
    signature alone; set to another value it names another VO."""
    from pvo_frontend.vo import VOConfig, flatten
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig, settings_against_defaults, vo_differences
    from pvo_pseudosensors.dpc_net.data import card_vo_config, settings_text, vo_config, vo_signature
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_pseudosensors.learning.checkpoint import read_card

    for name in ("dpc_net", "dpc_net_clean"):
        card = read_card(resolve_model(name))
        rig = card.input["rig"]
        assert vo_signature(card_vo_config(rig)) == rig["vo"], name
        assert vo_signature(vo_config(DPCNetConfig.from_card(card).vo_settings)) == rig["vo"], name
    # the lens model learned the VO of the 4-sigma RANSAC gate and keeps it; the clean one, retrained, the default VO
    assert card_vo_config(read_card(resolve_model("dpc_net")).input["rig"]).ransac.inlier_threshold == 16.0
    assert card_vo_config(read_card(resolve_model("dpc_net_clean")).input["rig"]) == VOConfig()
    default = VOConfig()
    stereo = replace(default, solver=replace(default.solver, noise_model="stereo"))
    assert "noise_model='stereo'" in settings_text(stereo)
    other = replace(default, solver=replace(default.solver, noise_model="uvd", pixel_sigma=(2.0, 2.0, 4.0)))
    other = replace(other, ransac=replace(other.ransac, inlier_threshold=9.0), probe=replace(other.probe, model="a b/c"))
    assert "noise_model='uvd'" not in settings_text(other)
    record = flatten(other)
    text = settings_against_defaults(record)
    assert "ransac.inlier_threshold=9.0" in text and "'probe.model=\"a b/c\"'" in text
    assert vo_config(text) == other and vo_config(record) == other
    assert vo_signature(other) != vo_signature(default)
    with pytest.raises(ValueError, match="not the VO 0123"):
        card_vo_config({"vo": "0123", "vo_settings": record})
    with pytest.raises(ValueError, match="ransac.sneaky"):
        vo_differences(record | {"ransac.sneaky": 1})
    with pytest.raises(ValueError, match="'inlier_threshold' must be NAME=VALUE"):
        vo_config("inlier_threshold")
    assert card_vo_config(None) == card_vo_config({"vo": "0123"}) == default  # named by signature only: the defaults
