"""`pvo hydranet train|predict|eval` on a tiny corpus of rotation-only sequences: the commands compose the
learning harness, the prediction file has the documented columns, and bad input is one line."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_tools.cli import main

TINY = ["--height", "48", "--width", "144", "--widths", "8,16", "--feature", "16", "--heads", "4", "--head-hidden", "8"]


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    from pvo_pseudosensors.hydranet.synthetic import write_rotation_sequence

    root = tmp_path_factory.mktemp("corpus")
    entries = []
    plan = (("train", "urban"), ("train", "planetary"), ("validation", "urban"), ("test", "urban"), ("test", "planetary"))
    for i, (split, preset) in enumerate(plan):
        name = f"{i:04d}"
        write_rotation_sequence(root / name, frames=12, seed=i)
        entries.append(
            {"name": name, "split": split, "preset": preset, "sha256": hashlib.sha256(name.encode()).hexdigest(), "config": {}}
        )
    corpus = {"sequences": 5, "frames": 12, "width": 144, "height": 48, "presets": ["urban"], "seed": 0, "colour": False}
    (root / "manifest.yaml").write_text(yaml.safe_dump({"corpus": corpus, "sequences": entries}))
    return root


def test_train_predict_eval(corpus: Path, tmp_path: Path, capsys) -> None:
    model = tmp_path / "model"
    args = ["hydranet", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "2", "--batch-size", "8", "-q"]
    assert main([*args, "--threads", "1", *TINY]) == 0
    assert "44 training and 11 validation samples" in capsys.readouterr().err  # 2 x 11 pairs, reversed too; 11
    card = yaml.safe_load((model / "model.yaml").read_text())
    assert card["architecture"] == "hydranet" and card["hyperparameters"]["covariance"] == "cholesky"
    assert card["input"]["size"] == [48, 144] and "hydranet train" in card["commands"]["train"]

    predictions = tmp_path / "rotations.csv"
    assert main(["hydranet", "predict", str(corpus / "0003"), "--model", str(model), "-o", str(predictions)]) == 0
    lines = predictions.read_text().splitlines()
    assert lines[0] == "frame_prev,frame,qw,qx,qy,qz,c00,c01,c02,c10,c11,c12,c20,c21,c22" and len(lines) == 12
    values = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    np.testing.assert_array_equal(values[:, :2], np.column_stack([np.arange(11), np.arange(1, 12)]))
    np.testing.assert_allclose(np.linalg.norm(values[:, 2:6], axis=1), 1.0, atol=1e-6)
    covariances = values[:, 6:].reshape(-1, 3, 3)
    np.testing.assert_allclose(covariances, covariances.transpose(0, 2, 1), rtol=1e-6)

    capsys.readouterr()
    truth = corpus / "0003" / "poses.txt"
    assert main(["hydranet", "eval", "--pred", str(predictions), "--gt", str(truth), "--json", str(tmp_path / "m")]) == 0
    printed = capsys.readouterr().out
    assert "angular error (deg)" in printed and "ANEES" in printed and "NLL" in printed
    record = yaml.safe_load((tmp_path / "m" / "metrics.json").read_text())
    assert record["figures"]["pairs"] == 11.0


def test_calibrate_sets_the_inference_mode_that_predict_then_uses(corpus: Path, tmp_path: Path, capsys) -> None:
    model = tmp_path / "model"
    args = ["hydranet", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "1", "--batch-size", "8", "-q"]
    assert main([*args, "--threads", "1", *TINY]) == 0
    plain, mirrored = tmp_path / "plain.csv", tmp_path / "mirrored.csv"
    assert main(["hydranet", "predict", str(corpus / "0003"), "--model", str(model), "-o", str(plain)]) == 0
    capsys.readouterr()
    assert main(["hydranet", "calibrate", "--model", str(model), "--corpus", str(corpus), "--mode", "sideways"]) == 2
    assert "--mode sideways: HydraNet runs plain, mirrored or reversed" in capsys.readouterr().err
    assert main(["hydranet", "calibrate", "--model", str(model), "--corpus", str(corpus), "--mode", "mirrored"]) == 0
    printed = capsys.readouterr().out
    assert "(mirrored mode) on 1 validation sequences" in printed and "ANEES" in printed
    card = yaml.safe_load((model / "model.yaml").read_text())
    assert card["calibration"]["mode"] == "mirrored" and card["calibration"]["pairs"] == 11.0
    assert main(["hydranet", "predict", str(corpus / "0003"), "--model", str(model), "-o", str(mirrored)]) == 0
    rows = [np.loadtxt(path, delimiter=",", skiprows=1) for path in (plain, mirrored)]
    assert rows[0].shape == rows[1].shape == (11, 15) and np.abs(rows[0][:, 2:6] - rows[1][:, 2:6]).max() > 1e-7


def test_ensemble_makes_one_model_directory_that_predict_and_init_treat_as_such(corpus: Path, tmp_path: Path, capsys) -> None:
    models = []
    for seed in ("0", "1"):
        model = tmp_path / f"seed{seed}"
        args = ["hydranet", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "1", "--batch-size", "8", "-q"]
        assert main([*args, "--threads", "1", "--seed", seed, *TINY]) == 0
        models.append(model)
    ensemble = tmp_path / "ensemble"
    capsys.readouterr()
    assert main(["hydranet", "ensemble", *map(str, models), "-o", str(ensemble)]) == 0
    assert f"{ensemble}: an ensemble of 2 HydraNets, 8 heads pooled" in capsys.readouterr().out
    card = yaml.safe_load((ensemble / "model.yaml").read_text())
    assert card["calibration"]["members"] == ["members/member-1"] and card["commands"]["ensemble"].startswith("pvo hydranet")
    files = {name: tmp_path / f"{name}.csv" for name in ("seed0", "seed1", "ensemble")}
    for name, path in files.items():
        assert main(["hydranet", "predict", str(corpus / "0003"), "--model", str(tmp_path / name), "-o", str(path)]) == 0
    rows = {name: np.loadtxt(path, delimiter=",", skiprows=1) for name, path in files.items()}
    assert rows["ensemble"].shape == (11, 15)
    assert min(np.abs(rows["ensemble"][:, 2:6] - rows[n][:, 2:6]).max() for n in ("seed0", "seed1")) > 1e-7
    capsys.readouterr()
    assert main(["hydranet", "ensemble", str(models[0]), "-o", str(tmp_path / "lone")]) == 2
    assert "an ensemble needs at least two models, got 1" in capsys.readouterr().err
    args = ["hydranet", "train", "--corpus", str(corpus), "-o", str(tmp_path / "ft"), "--init", str(ensemble), "-q", *TINY]
    assert main(args) == 2
    assert "an ensemble; fine-tune each of its members instead" in capsys.readouterr().err


def test_the_experiments_finetuning_tunes_an_ensemble_member_by_member(corpus: Path, tmp_path: Path) -> None:
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.flow import FlowPairs
    from pvo_pseudosensors.hydranet.infer import load_hydranet
    from pvo_pseudosensors.hydranet.model import HydraEnsemble
    from pvo_pseudosensors.learning import Source, TrainConfig
    from pvo_tools.experiments.hydranet import finetune

    models = []
    for seed in ("0", "1"):
        args = ["hydranet", "train", "--corpus", str(corpus), "-o", str(tmp_path / seed), "--epochs", "1", "-q"]
        assert main([*args, "--batch-size", "8", "--threads", "1", "--seed", seed, *TINY]) == 0
        models.append(tmp_path / seed)
    assert main(["hydranet", "ensemble", *map(str, models), "-o", str(tmp_path / "ensemble")]) == 0
    assert (
        main(["hydranet", "calibrate", "--model", str(tmp_path / "ensemble"), "--corpus", str(corpus), "--mode", "reversed"]) == 0
    )
    _, card = load_hydranet(tmp_path / "ensemble")
    size = HydraNetConfig.from_card(card).size
    data = (FlowPairs([Source(corpus / "0000", "a")], size, reverse=True), FlowPairs([Source(corpus / "0002", "b")], size))
    loop = TrainConfig(epochs=1, batch_size=8, learning_rate=1e-4, patience=0, threads=1)
    extra = {"commands": {"finetune": "pvo experiment hydranet ..."}}
    for _ in range(2):  # a second run replaces the first's ensemble
        out = finetune(tmp_path / "ensemble", card, data, loop, tmp_path / "tuned", extra)
    tuned, tuned_card = load_hydranet(out)
    assert isinstance(tuned, HydraEnsemble) and tuned_card.calibration["members"] == ["members/member-1"]
    assert tuned_card.calibration["mode"] == "reversed"  # tuned and judged as the model runs
    assert tuned_card.commands["ensemble"] == "pvo experiment hydranet ..."
    for i, original in enumerate(models):  # each member started from its own weights and moved
        before = load_hydranet(original)[0].state_dict()
        after = load_hydranet(tmp_path / f"tuned-member-{i}")[0].state_dict()
        assert any(not np.allclose(before[k].numpy(), after[k].numpy()) for k in before)
        other = load_hydranet(models[1 - i])[0].state_dict()
        assert sum(np.abs(after[k].numpy() - before[k].numpy()).sum() for k in before) < sum(
            np.abs(after[k].numpy() - other[k].numpy()).sum() for k in before
        )


def test_presets_only_keeps_those_sequences(corpus: Path, tmp_path: Path, capsys) -> None:
    args = ["hydranet", "train", "--corpus", str(corpus), "-o", str(tmp_path / "m"), "--epochs", "1", "--presets-only", "urban"]
    assert main([*args, "-q", "--threads", "1", *TINY]) == 0
    assert "22 training and 11 validation samples" in capsys.readouterr().err
    assert yaml.safe_load((tmp_path / "m" / "model.yaml").read_text())["corpus"]["presets"] == ["urban"]


def test_the_default_model_takes_a_recording_without_sim_yaml_as_level_and_says_so(corpus: Path, tmp_path: Path, capsys) -> None:
    """The shipped default reads the camera's pitch; a sequence with no sim.yaml (a real recording) is read as a
    level camera, as the node's camera_pitch_deg default, with one line saying so; --pitch-deg overrides it."""
    sequence = corpus / "0003"
    assert not (sequence / "sim.yaml").exists()
    paths = {name: tmp_path / f"{name}.csv" for name in ("default", "level", "pitched")}
    assert main(["hydranet", "predict", str(sequence), "--model", "hydranet", "-o", str(paths["default"])]) == 0
    assert f"{sequence}: no sim.yaml, the camera's pitch taken as 0 deg" in capsys.readouterr().err
    for name, pitch in (("level", "0"), ("pitched", "20")):
        assert (
            main(["hydranet", "predict", str(sequence), "--model", "hydranet", "--pitch-deg", pitch, "-o", str(paths[name])]) == 0
        )
        assert "no sim.yaml" not in capsys.readouterr().err
    rows = {name: np.loadtxt(path, delimiter=",", skiprows=1) for name, path in paths.items()}
    np.testing.assert_array_equal(rows["default"], rows["level"])
    assert not np.allclose(rows["default"][:, 2:6], rows["pitched"][:, 2:6], atol=1e-7)


def test_bad_inputs_are_one_line(corpus: Path, tmp_path: Path, capsys) -> None:
    out = str(tmp_path / "p.csv")
    assert main(["hydranet", "predict", str(corpus / "0003"), "--model", str(tmp_path / "none"), "-o", out]) == 2
    assert "model directory not found" in capsys.readouterr().err
    assert main(["hydranet", "train", "--corpus", str(corpus), "-o", str(tmp_path / "m"), *TINY, "--covariance", "full"]) == 2
    assert "unknown covariance 'full': choose one of cholesky, diagonal" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    header = "frame_prev,frame,qw,qx,qy,qz,c00,c01,c02,c10,c11,c12,c20,c21,c22\n"
    bad.write_text(header + "0,1,1,0,0,0,1,0,0,0,1,0,0,0,1\n1,2,1,0,0,0,1,0,0,0,-1,0,0,0,1\n")
    assert main(["hydranet", "eval", "--pred", str(bad), "--gt", str(corpus / "0003" / "poses.txt")]) == 2
    assert "bad.csv:3: covariance of frame 2 is not symmetric positive definite" in capsys.readouterr().err
    bad.write_text(header + "0,1,2,0,0,0,1,0,0,0,1,0,0,0,1\n")
    assert main(["hydranet", "eval", "--pred", str(bad), "--gt", str(corpus / "0003" / "poses.txt")]) == 2
    assert "bad.csv:2: quaternion of frame 1 is not unit length" in capsys.readouterr().err
    bad.write_text(header + "0,40,1,0,0,0,1,0,0,0,1,0,0,0,1\n")
    assert main(["hydranet", "eval", "--pred", str(bad), "--gt", str(corpus / "0003" / "poses.txt")]) == 2
    assert "frame 40 is beyond the 12 poses" in capsys.readouterr().err


def test_experiment_reports_every_section(
    corpus: Path, pvo_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """`pvo experiment hydranet` on a tiny model (no fusion sequences: they take minutes to render): the
    accuracy, out-of-distribution, covariance-form, real-image and speed sections, and the record."""
    import json

    model = tmp_path / "model"
    train = ["hydranet", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "1", "--presets-only", "urban"]
    assert main([*train, "-q", *TINY]) == 0
    diagonal = tmp_path / "diagonal"
    train[train.index(str(model))] = str(diagonal)
    assert main([*train, "--covariance", "diagonal", "-q", *TINY]) == 0
    out = tmp_path / "experiment"
    options = ["--fusion-sequences", "0", "--finetune-epochs", "1", "--data", str(pvo_data), "--threads", "1", "-q"]
    same = ["experiment", "hydranet", "--corpus", str(corpus), "--model", str(model), "--other-form", str(model)]
    assert main([*same, *options, "-o", str(tmp_path / "same")]) == 2
    assert "its covariance form is 'cholesky', the same as --model's" in capsys.readouterr().err
    # the validation-selected form may be either: --model is the one evaluated, --other-form the comparison
    args = ["experiment", "hydranet", "--corpus", str(corpus), "--model", str(diagonal), "--other-form", str(model)]
    assert main([*args, *options, "-o", str(out)]) == 0
    report = (out / "report.md").read_text()
    assert "| cholesky (validation loss" in report and "| diagonal (validation loss" in report
    assert "No stereo validation sequence of the model's presets: the fusion criterion is not measured." in report
    for heading in ("## 1. Accuracy", "## 2. Out of distribution", "## 3. Aleatoric covariance", "## 5. Real images", "## Speed"):
        assert heading in report, heading
    assert "fine-tuned on 07, KITTI 06 clip" in report
    figures = json.loads((out / "metrics.json").read_text())["figures"]
    assert figures["test.urban.pairs"] == 11.0 and figures["ms_per_pair_median"] > 0.0
    assert "urban: 1 sequences (in distribution)" in report and "planetary: 1 sequences (out of distribution)" in report
    assert figures["ood.epistemic_ratio"] > 0.0 and "ood.heads_epistemic_ratio" not in figures  # no widening: one spread
    assert 0.0 < figures["kitti06.vo_angle_mean_deg"] < 0.2  # the stereo VO on the real clip, for comparison
    tuned = yaml.safe_load((out / "kitti-finetuned" / "model.yaml").read_text())
    assert "fine-tuned from" in tuned["notes"]
    staged = (out / "kitti06" / "poses.txt").read_text().splitlines()
    assert len(staged) == 51  # the clip's poses, relative to its first frame
    np.testing.assert_allclose(np.array(staged[0].split(), float).reshape(3, 4), np.eye(4)[:3], atol=1e-12)


def test_the_heads_own_spread_is_read_without_the_cards_widening(corpus: Path, tmp_path: Path) -> None:
    """Section 2 reports the heads' own Sigma_e growth beside one that carries a widening's added part."""
    import torch
    from pvo_core.readers import read_corpus_manifest
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence
    from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask
    from pvo_pseudosensors.hydranet.widening import SpreadWidening
    from pvo_pseudosensors.learning.checkpoint import save_model
    from pvo_tools.experiments.hydranet import heads_spread

    torch.manual_seed(0)
    small = HydraNetConfig(height=48, width=144, widths=(8, 16), feature=8, heads=4, head_hidden=8)
    model, card = load_hydranet(save_model(tmp_path / "model", HydraNet(small), HydraTask(small).card()))
    test = read_corpus_manifest(corpus).split("test")
    presets = tuple(sorted({s.preset for s in test}))
    plain = heads_spread(model, card, test, presets, None)
    widening = SpreadWidening(reference=1e-12, gamma=2.0)  # every pair far beyond: all widened
    model.widening = widening
    assert heads_spread(model, card, test, presets, None) == plain and model.widening is widening
    for preset in presets:
        widened = [predict_sequence(model, card, s.root).epistemic for s in test if s.preset == preset]
        assert np.trace(np.concatenate(widened), axis1=1, axis2=2).mean() > 10.0 * plain[preset]


def test_a_model_of_several_corpora_was_trained_on_their_presets() -> None:
    from types import SimpleNamespace

    from pvo_tools.experiments.hydranet import model_presets

    manifest = SimpleNamespace(split=lambda name: [SimpleNamespace(preset="urban"), SimpleNamespace(preset="planetary")])
    one = SimpleNamespace(corpus={"path": "a", "presets": ["urban"]})
    several = SimpleNamespace(corpus={"corpora": [{"path": "a", "presets": ["urban"]}, {"path": "b", "presets": ["urban"]}]})
    unrestricted = SimpleNamespace(corpus={"corpora": [{"path": "a", "presets": ["urban"]}, {"path": "b"}]})
    assert model_presets(one, manifest) == {"urban"}
    assert model_presets(several, manifest) == {"urban"}
    assert model_presets(unrestricted, manifest) == {"urban", "planetary"}
    assert model_presets(SimpleNamespace(corpus={}), manifest) == {"urban", "planetary"}


def test_the_fusion_reference_takes_the_true_rotations_with_hydranets_covariances() -> None:
    from types import SimpleNamespace

    from pvo_core.lie import quaternion_to_rotation, so3_exp
    from pvo_pseudosensors.hydranet.estimator import pose_covariance
    from pvo_pseudosensors.hydranet.evaluation import true_relative_rotations
    from pvo_tools.experiments.hydranet import rotation_measurements

    rng = np.random.default_rng(3)
    poses = np.tile(np.eye(4), (4, 1, 1))
    for k in range(1, 4):
        poses[k, :3, :3] = poses[k - 1, :3, :3] @ so3_exp(rng.normal(0.0, 0.05, 3))
        poses[k, :3, 3] = poses[k - 1, :3, 3] + [0.0, 0.0, 1.0]
    quaternions = np.array([[1.0, 0.01, 0.0, 0.0], [1.0, 0.0, -0.02, 0.0], [1.0, 0.0, 0.0, 0.03]])
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
    covariance = np.stack([np.diag([1e-6, 2e-6, 3e-6]) * (k + 1) for k in range(3)])
    predictions = SimpleNamespace(earlier=np.arange(3), frames=np.arange(1, 4), quaternions=quaternions, covariance=covariance)
    stamps = np.array([1, 2, 3, 4], dtype=np.int64) * 100_000_000

    own = rotation_measurements(predictions, stamps)
    errorless = rotation_measurements(predictions, stamps, true_relative_rotations(poses, np.arange(3), np.arange(1, 4)))
    for k, (a, b) in enumerate(zip(own, errorless, strict=True)):
        np.testing.assert_allclose(a.transform[:3, :3], quaternion_to_rotation(quaternions[k]))
        # C_k,k-1 maps the earlier camera's coordinates into the later one's: the truth's relative rotation
        np.testing.assert_allclose(b.transform[:3, :3], poses[k + 1, :3, :3].T @ poses[k, :3, :3], atol=1e-12)
        np.testing.assert_allclose(a.covariance, pose_covariance(covariance[k]))
        np.testing.assert_allclose(b.covariance, a.covariance)
        assert (a.stamp, a.reference_stamp) == (b.stamp, b.reference_stamp) == (stamps[k + 1], stamps[k])
        assert a.rotation_only and b.rotation_only


def test_density_writes_its_card_entry_and_prints_its_figures(corpus: Path, tmp_path: Path, capsys) -> None:
    import torch
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask
    from pvo_pseudosensors.learning.checkpoint import save_model

    torch.manual_seed(0)
    small = HydraNetConfig(height=48, width=144, widths=(8, 16), feature=8, heads=4, head_hidden=8)
    model = save_model(tmp_path / "model", HydraNet(small), HydraTask(small).card())
    args = ["hydranet", "density", "--model", str(model), "--corpus", str(corpus), "--shift-corpus", str(corpus)]
    assert main(args) == 0  # 11 urban training pairs over 8 features
    captured = capsys.readouterr()
    printed = captured.out
    assert "features and predictions of 1 shift sequences ..." in captured.err  # each stage as it starts
    assert "feature density over 8 units fitted on 11 pairs" in printed
    assert "validation 11 pairs" in printed and "shift      11 pairs" in printed and "ANEES" in printed
    card = yaml.safe_load((model / "model.yaml").read_text())
    assert card["calibration"]["feature_density"]["file"] == "feature_density.safetensors"
    assert card["calibration"]["feature_density"]["quantile"] == 0.95
    wide = HydraNetConfig(height=48, width=144, widths=(8, 16), feature=16, heads=4, head_hidden=8)
    other = save_model(tmp_path / "wide", HydraNet(wide), HydraTask(wide).card())
    assert main(["hydranet", "density", "--model", str(other), "--corpus", str(corpus), "--shift-corpus", str(corpus)]) == 2
    assert "a density over 16 features needs more pairs than that, got 11" in capsys.readouterr().err
    assert main([*args, "--preset", "desert"]) == 2
    assert "no desert sequence in the train split" in capsys.readouterr().err


def test_widen_writes_its_card_entry_and_prints_its_figures(corpus: Path, tmp_path: Path, capsys) -> None:
    import torch
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask
    from pvo_pseudosensors.learning.checkpoint import save_model

    torch.manual_seed(0)
    small = HydraNetConfig(height=48, width=144, widths=(8, 16), feature=8, heads=4, head_hidden=8)
    model = save_model(tmp_path / "model", HydraNet(small), HydraTask(small).card())
    args = ["hydranet", "widen", "--model", str(model), "--corpus", str(corpus), "--shift-corpus", str(corpus)]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "predictions of 1 shift sequences ..." in captured.err  # each stage as it starts
    assert "Sigma_a widened by 1 + " in captured.out and "r = tr Sigma_e / " in captured.out
    assert "validation 11 pairs" in captured.out and "shift      11 pairs" in captured.out and "ANEES" in captured.out
    entry = yaml.safe_load((model / "model.yaml").read_text())["calibration"]["spread_widening"]
    assert entry["reference"] > 0.0 and entry["gamma"] >= 0.0 and "shift_anees" in entry
    assert entry["reference_quantile"] == 0.9  # the default: only pairs beyond nine in ten of the usual spread widen
    assert main([*args, "--reference-quantile", "0.5"]) == 0
    capsys.readouterr()
    median = yaml.safe_load((model / "model.yaml").read_text())["calibration"]["spread_widening"]
    assert median["reference_quantile"] == 0.5 and median["reference"] < entry["reference"]
    assert main([*args, "--reference-quantile", "1.5"]) == 2
    assert "reference quantile must lie in (0, 1), got 1.5" in capsys.readouterr().err
    assert main([*args, "--max-gamma", "0"]) == 2
    assert "largest power must lie in (0, 1000], got 0.0" in capsys.readouterr().err
    assert main([*args, "--max-gamma", "0.01"]) == 0
    printed = capsys.readouterr().out
    bounded = yaml.safe_load((model / "model.yaml").read_text())["calibration"]["spread_widening"]
    assert bounded["gamma"] <= 0.01 and bounded["max_gamma"] == 0.01
    assert ("(at --max-gamma: the shift's pairs want more)" in printed) == (bounded["gamma"] == 0.01)
    assert main([*args, "--shift-preset", "desert"]) == 2
    assert "no desert sequence in the validation split" in capsys.readouterr().err


@pytest.mark.parametrize("extra", [{}, {"pitch": True, "texture": True}])
def test_bench_times_a_model_with_extra_input_channels(extra: dict, pvo_data: Path, tmp_path: Path, capsys) -> None:
    """The network stage is fed what the sensor feeds it: a model with the pitch (or texture) input is benched, not
    refused for a channel count its flow alone does not have."""
    import torch
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask
    from pvo_pseudosensors.learning.checkpoint import save_model

    config = HydraNetConfig(height=48, width=144, widths=(8, 16), feature=16, heads=4, head_hidden=8, **extra)
    torch.manual_seed(0)
    save_model(tmp_path / "model", HydraNet(config), HydraTask(config).card())
    assert main(["bench", "hydranet", "--model", str(tmp_path / "model"), "--data", str(pvo_data), "--repeat", "1"]) == 0
    out = capsys.readouterr().out
    assert "50 pairs of the KITTI 06 clip" in out and "network (4 heads, Sigma)" in out and "sensor total" in out


def test_fusion_drives_go_through_other_worlds_on_request(pvo_data: Path, tmp_path: Path) -> None:
    """``--fusion-world K``: the same drive, sun and degradations through another world (its own seed, other
    images); a folder of the experiment's own worlds is kept, not re-rendered; one holding another world's drive is
    one line, not overwritten."""
    import cv2
    from pvo_tools.experiments.hydranet import FUSION_SEQUENCES, render_fusion_sequences

    def seed(folder: Path) -> int:
        return yaml.safe_load((folder / "sim.yaml").read_text())["config"]["seed"]

    try:
        [own] = render_fusion_sequences(pvo_data, 1, 3, tmp_path / "own", lambda _: None)
    except Exception as error:  # noqa: BLE001 - no offscreen renderer here
        pytest.skip(f"pvo sim could not render here: {error}")
    [other] = render_fusion_sequences(pvo_data, 1, 3, tmp_path / "other", lambda _: None, world=1)
    assert own.name == other.name == FUSION_SEQUENCES[0][0]
    assert (seed(own), seed(other)) == (700, 1700)
    np.testing.assert_allclose(np.loadtxt(own / "poses.txt"), np.loadtxt(other / "poses.txt"), atol=1e-9)
    assert not np.array_equal(cv2.imread(str(own / "image_0" / "000002.png")), cv2.imread(str(other / "image_0" / "000002.png")))
    written = (own / "sim.yaml").stat().st_mtime_ns
    render_fusion_sequences(pvo_data, 1, 3, tmp_path / "own", lambda _: None)
    assert (own / "sim.yaml").stat().st_mtime_ns == written
    with pytest.raises(
        ValueError, match=r"own/05-clean: rendered through another world \(seed 700, not 1700\): give --fusion-dir"
    ):
        render_fusion_sequences(pvo_data, 1, 3, tmp_path / "own", lambda _: None, world=1)
    assert seed(own) == 700
    with pytest.raises(ValueError, match="--fusion-world must be >= 0, got -1"):
        render_fusion_sequences(pvo_data, 1, 3, tmp_path / "x", lambda _: None, world=-1)


def test_shortfall_writes_its_card_entry_and_prints_its_figures(corpus: Path, tmp_path: Path, capsys) -> None:
    import torch
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask
    from pvo_pseudosensors.learning.checkpoint import save_model

    torch.manual_seed(0)
    small = HydraNetConfig(height=48, width=144, widths=(8, 16), feature=8, heads=4, head_hidden=8)
    model = save_model(tmp_path / "model", HydraNet(small), HydraTask(small).card())
    args = ["hydranet", "shortfall", "--model", str(model), "--corpus", str(corpus), "--shift-corpus", str(corpus)]
    assert main(args) == 0
    captured = capsys.readouterr()
    assert "predictions of 1 shift sequences ..." in captured.err
    assert "Sigma_a widened by 1 + " in captured.out and "the flow's shortfall" in captured.out
    assert "validation 11 pairs" in captured.out and "shift      11 pairs" in captured.out
    entry = yaml.safe_load((model / "model.yaml").read_text())["calibration"]["flow_shortfall_widening"]
    assert entry["reference"] > 0.0 and entry["gamma"] >= 0.0 and entry["reference_quantile"] == 0.99
    assert entry["min_response"] == 0.2 and "shift_anees" in entry
    assert main([*args, "--reference-quantile", "0"]) == 2
    assert "reference quantile must lie in (0, 1), got 0.0" in capsys.readouterr().err
