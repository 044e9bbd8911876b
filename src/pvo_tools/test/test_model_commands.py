"""`pvo sun-bcnn train|predict|eval` on a tiny corpus: the commands compose the learning harness."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_tools.cli import main

TINY = "--height 24 --width 64 --widths 4,8 --hidden 8 --no-augment --bins 0 --rotate 0 --threads 1 -q".split()


def write_sequence(root: Path, frames: int, seed: int) -> None:
    import cv2

    rng = np.random.default_rng(seed)
    (root / "image_0").mkdir(parents=True)
    v, u = np.mgrid[0:48, 0:128].astype(float)
    u, v = (u - 64) / 128, (v - 24) / 48
    rows = []
    for k in range(frames):
        sun = rng.normal(size=3)
        sun[2] = abs(sun[2])
        sun /= np.linalg.norm(sun)
        image = np.clip(128 + 200 * (sun[0] * u + sun[1] * v), 0, 255).astype(np.uint8)
        cv2.imwrite(str(root / "image_0" / f"{k:06d}.png"), image)
        rows.append(f"image_0/{k:06d}.png,{sun[0]:.9f},{sun[1]:.9f},{sun[2]:.9f}\n")
    (root / "sun.csv").write_text("".join(rows))


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("corpus")
    entries = []
    for i, split in enumerate(("train", "train", "validation", "test")):
        name = f"{i:04d}"
        write_sequence(root / name, 16, i)
        entries.append({"name": name, "split": split, "sha256": hashlib.sha256(name.encode()).hexdigest(), "config": {}})
    corpus = {"sequences": 4, "frames": 16, "width": 128, "height": 48, "presets": ["urban"], "seed": 0, "colour": False}
    (root / "manifest.yaml").write_text(yaml.safe_dump({"corpus": corpus, "sequences": entries}))
    return root


def test_train_predict_eval(corpus: Path, tmp_path: Path, capsys) -> None:
    model = tmp_path / "model"
    args = ["sun-bcnn", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "3", "--batch-size", "16"]
    assert main([*args, "--learning-rate", "0.01", *TINY]) == 0
    assert "best validation loss" in capsys.readouterr().out
    card = yaml.safe_load((model / "model.yaml").read_text())
    assert card["architecture"] == "sun-bcnn" and card["input"]["size"] == [24, 64]
    assert card["corpus"]["sequences"] == 4 and len(card["corpus"]["sha256"]) == 64
    assert card["commands"]["corpus"].startswith("pvo sim corpus") and "sun-bcnn train" in card["commands"]["train"]
    assert card["training"]["best_epoch"] >= 1 and "loss" in card["validation"]

    predictions = tmp_path / "pred.csv"
    predict = ["sun-bcnn", "predict", str(corpus / "0003"), "--model", str(model), "--samples", "5"]
    assert main([*predict, "-o", str(predictions)]) == 0
    lines = predictions.read_text().splitlines()
    assert lines[0] == "frame,sx,sy,sz,zenith,azimuth,c_zz,c_za,c_az,c_aa" and len(lines) == 17
    values = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    np.testing.assert_allclose(np.linalg.norm(values[:, 1:4], axis=1), 1.0, atol=1e-6)
    np.testing.assert_allclose(values[:, 7], values[:, 8])  # the covariance is symmetric
    assert np.all(values[:, 6] > 0) and np.all(values[:, 9] > 0)
    again = tmp_path / "again.csv"
    main([*predict, "-o", str(again)])
    assert again.read_text() == predictions.read_text()  # seeded MC samples
    equalised = tmp_path / "equalised.csv"
    assert main([*predict, "--equalize", "-o", str(equalised)]) == 0  # the images equalised before the network
    assert equalised.read_text() != predictions.read_text()

    capsys.readouterr()
    assert (
        main(
            [
                "sun-bcnn",
                "eval",
                "--pred",
                str(predictions),
                "--gt",
                str(corpus / "0003" / "sun.csv"),
                "--json",
                str(tmp_path / "m"),
            ]
        )
        == 0
    )
    printed = capsys.readouterr().out
    assert "vector error (deg)" in printed and "ANEES" in printed
    record = yaml.safe_load((tmp_path / "m" / "metrics.json").read_text())
    assert record["figures"]["images"] == 16.0


def test_calibrate_writes_the_covariance_calibration(corpus: Path, tmp_path: Path, capsys) -> None:
    """`pvo sun-bcnn calibrate` fits tau (an overconfident model) or a scale below 1 (one too wide) on the
    validation split and writes both to the card; `predict` then states covariances with that ANEES."""
    from pvo_core.readers import read_kitti_sun_csv
    from pvo_core.sun import anees, zenith_azimuth_residuals

    def train(model: Path, epochs: int) -> None:
        args = ["sun-bcnn", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", str(epochs), "--batch-size", "16"]
        assert main([*args, "--learning-rate", "0.01", *TINY]) == 0

    train(tmp_path / "untrained", 1)  # no prediction near the truth: nothing to calibrate on
    capsys.readouterr()
    assert main(["sun-bcnn", "calibrate", "--model", str(tmp_path / "untrained"), "--corpus", str(corpus)]) == 2
    assert "none of the 16 validation predictions is within cosine distance 0.3" in capsys.readouterr().err

    model = tmp_path / "model"
    train(model, 8)
    capsys.readouterr()
    assert main(["sun-bcnn", "calibrate", "--model", str(model), "--corpus", str(corpus), "--mode", "head"]) == 0
    printed = capsys.readouterr().out
    assert "covariance scale" in printed and "ANEES over the" in printed and "over all" in printed
    calibration = yaml.safe_load((model / "model.yaml").read_text())["calibration"]
    assert calibration["mode"] == "head" and calibration["images"] == 16.0
    assert calibration["scale"] <= 1.0 and (calibration["scale"] == 1.0 or calibration["tau"] == float("inf"))

    predictions = tmp_path / "validation.csv"
    assert main(["sun-bcnn", "predict", str(corpus / "0002"), "--model", str(model), "-o", str(predictions)]) == 0
    rows = np.loadtxt(predictions, delimiter=",", skiprows=1)
    truth = read_kitti_sun_csv(corpus / "0002" / "sun.csv")[rows[:, 0].astype(int)]
    residuals, covariances = zenith_azimuth_residuals(rows[:, 1:4], truth), rows[:, 6:10].reshape(-1, 2, 2)
    keep = 1.0 - np.sum(rows[:, 1:4] * truth, axis=1) < 0.3
    assert anees(residuals, covariances) == pytest.approx(calibration["anees_all"], rel=1e-6)
    if calibration["tau"] != float("inf"):
        assert anees(residuals[keep], covariances[keep]) == pytest.approx(1.0, rel=1e-6)
    elif calibration["scale"] < 1.0:
        assert np.sqrt(anees(residuals[keep], covariances[keep]) * calibration["anees_all"]) == pytest.approx(1.0, rel=1e-6)


def test_predict_takes_a_shipped_models_name(corpus: Path, tmp_path: Path) -> None:
    from pvo_pseudosensors.learning.checkpoint import shipped_model

    by_name, by_path = tmp_path / "name.csv", tmp_path / "path.csv"
    predict = ["sun-bcnn", "predict", str(corpus / "0003"), "--samples", "2"]
    assert main([*predict, "--model", "sun_bcnn", "-o", str(by_name)]) == 0
    assert main([*predict, "--model", str(shipped_model("sun_bcnn")), "-o", str(by_path)]) == 0
    assert len(by_name.read_text().splitlines()) == 17 and by_name.read_text() == by_path.read_text()


@pytest.mark.parametrize(
    ("calibration", "message"),
    [({"scale": -1.0}, "scale must be positive and finite, got -1.0"), ({"tau": "wide"}, "tau must be a number, got 'wide'")],
)
def test_a_bad_covariance_calibration_in_the_card_is_one_line(
    corpus: Path, tmp_path: Path, capsys, calibration: dict, message: str
) -> None:
    from pvo_pseudosensors.learning.checkpoint import save_model
    from pvo_pseudosensors.sun_bcnn.config import SunBCNNConfig
    from pvo_pseudosensors.sun_bcnn.model import SunBCNN, SunTask

    config = SunBCNNConfig(height=24, width=64, widths=(4, 8), hidden=8, bins=0, rotate=0.0)
    card = SunTask(config).card()
    card.calibration = calibration
    save_model(tmp_path / "model", SunBCNN(config), card)
    predict = ["sun-bcnn", "predict", str(corpus / "0003"), "--model", str(tmp_path / "model"), "-o", str(tmp_path / "p.csv")]
    assert main(predict) == 2
    error = capsys.readouterr().err
    assert f"{tmp_path / 'model' / 'model.yaml'}: covariance calibration: {message}" in error
    assert "Traceback" not in error and not (tmp_path / "p.csv").exists()


def test_bad_inputs_are_one_line(corpus: Path, tmp_path: Path, capsys) -> None:
    assert (
        main(["sun-bcnn", "predict", str(corpus / "0003"), "--model", str(tmp_path / "none"), "-o", str(tmp_path / "p.csv")]) == 2
    )
    assert "model directory not found" in capsys.readouterr().err
    assert main(["sun-bcnn", "train", "--corpus", str(tmp_path), "-o", str(tmp_path / "m"), *TINY]) == 2
    assert "corpus manifest not found" in capsys.readouterr().err
    assert main(["sun-bcnn", "train", "--corpus", str(corpus), "-o", str(tmp_path / "m"), *TINY, "--widths", "4,x"]) == 2
    assert "--widths '4,x' must be comma-separated integers" in capsys.readouterr().err
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,sx,sy,sz,zenith,azimuth,c_zz,c_za,c_az,c_aa\n0,1,1,0,0,0,1,0,0,1\n")
    assert main(["sun-bcnn", "eval", "--pred", str(bad), "--gt", str(corpus / "0003" / "sun.csv")]) == 2
    assert "bad.csv:2: sun vector of frame 0 is not unit length" in capsys.readouterr().err


def test_experiment_reports_every_table(corpus: Path, pvo_data: Path, tmp_path: Path, capsys) -> None:
    """`pvo experiment sun-bcnn` on a tiny model: every table of the report, the calibration plot, and the
    KITTI models fine-tuned and trained on 07 frames 0-127 (calibrated on 128-159), tested on 06."""
    import json

    model = tmp_path / "model"
    train = ["sun-bcnn", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "2", "--batch-size", "16", *TINY]
    assert main(train) == 0
    out = tmp_path / "experiment"
    args = ["experiment", "sun-bcnn", "--corpus", str(corpus), "--model", str(model), "--homoscedastic", str(model)]
    options = [
        "--samples",
        "4",
        "--finetune-epochs",
        "1",
        "--fusion-sequences",
        "0",
        "--data",
        str(pvo_data),
        "-o",
        str(out),
        "-q",
    ]
    assert main([*args, *options]) == 0
    report = (out / "report.md").read_text()
    for heading in ("## 1. Accuracy", "## 2. Cloud cover", "## 3. Method I vs Method II", "## 5. Real images"):
        assert heading in report, heading
    assert "fine-tuned on 07, KITTI 06" in report and "trained on 07 alone, KITTI 06" in report
    assert (out / "calibration.png").stat().st_size > 10_000
    figures = json.loads((out / "metrics.json").read_text())["figures"]
    assert 0.0 <= figures["aleatoric.vector_median_deg"] <= 180.0
    for mode in ("full", "head", "full-mirrored", "head-mirrored"):  # every MC mode timed and in the table
        assert figures[f"ms_per_image_{mode}"] > 0 and f"\n{mode} " in report, mode
    tuned = yaml.safe_load((out / "kitti-finetuned" / "model.yaml").read_text())
    assert "fine-tuned from" in tuned["notes"] and tuned["calibration"]["on"] == "KITTI 07 frames 128-159"
    staged = (out / "kitti07-validation" / "sun.csv").read_text().splitlines()
    truth = (pvo_data / "kitti" / "sun" / "kitti_sun_test_07.csv").read_text().splitlines()
    assert staged == truth[128:160]  # the validation rows are frames 128-159, renumbered from 0
    rows = (out / "kitti06_kitti-finetuned.csv").read_text().splitlines()
    assert len(rows) == 52  # header + the 51 frames of the 06 clip


def test_experiment_can_skip_the_kitti_scratch_baseline(corpus: Path, pvo_data: Path, tmp_path: Path, capsys) -> None:
    """`--scratch-epochs 0`: the fine-tuned KITTI model only, no model trained on 07 alone; a negative count (or a
    fine-tune of no epoch) is one line before anything is written."""
    model = tmp_path / "model"
    train = ["sun-bcnn", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "1", "--batch-size", "16", *TINY]
    assert main(train) == 0
    out = tmp_path / "experiment"
    args = ["experiment", "sun-bcnn", "--corpus", str(corpus), "--model", str(model), "--samples", "2"]
    options = ["--finetune-epochs", "1", "--fusion-sequences", "0", "--data", str(pvo_data), "-o", str(out), "-q"]
    assert main([*args, *options, "--scratch-epochs", "-1"]) == 2
    assert "--scratch-epochs -1: must be 0 (skip) or a number of epochs" in capsys.readouterr().err
    assert main([*args, *options, "--finetune-epochs", "0"]) == 2
    assert "--finetune-epochs 0: the KITTI fine-tune needs at least one epoch" in capsys.readouterr().err
    assert main([*args, *options, "--fusion-sequences", "1", "--fusion-preset", "nowhere"]) == 2
    assert "--fusion-preset nowhere: 0 test sequences of it in" in capsys.readouterr().err
    assert main([*args, *options, "--fusion-lens", "0"]) == 2
    assert "--fusion-lens 0: a lens that distorts nothing is the calibrated rig" in capsys.readouterr().err
    card = yaml.safe_load((model / "model.yaml").read_text())
    card["calibration"]["fusion"] = {"inputs.sun.bias_sigma": [0.5, 0.5]}  # an offset state with no walk
    (model / "model.yaml").write_text(yaml.safe_dump(card, sort_keys=False))
    assert main([*args, *options]) == 2
    assert f"{model}: the card's calibration.fusion: invalid fusion configuration" in capsys.readouterr().err
    card["calibration"].pop("fusion")
    (model / "model.yaml").write_text(yaml.safe_dump(card, sort_keys=False))
    assert not out.exists()
    assert main([*args, *options, "--scratch-epochs", "0"]) == 0
    report = (out / "report.md").read_text()
    assert "fine-tuned on 07, KITTI 06" in report and "trained on 07 alone" not in report
    assert (out / "kitti-finetuned" / "model.yaml").exists() and not (out / "kitti07-only").exists()


def test_the_kitti_fine_tune_can_keep_synthetic_images_in_view(corpus: Path, pvo_data: Path, tmp_path: Path, capsys) -> None:
    """`--finetune-synthetic N`: N of the corpus's training images join every fine-tune epoch (the card says which
    and counts them); more than the training split holds, or a negative count, is one line."""
    model = tmp_path / "model"
    train = ["sun-bcnn", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "1", "--batch-size", "16", *TINY]
    assert main(train) == 0
    out = tmp_path / "experiment"
    args = ["experiment", "sun-bcnn", "--corpus", str(corpus), "--model", str(model), "--samples", "2", "--scratch-epochs", "0"]
    options = ["--finetune-epochs", "1", "--fusion-sequences", "0", "--data", str(pvo_data), "-o", str(out), "-q"]
    assert main([*args, *options, "--finetune-synthetic", "-1"]) == 2
    assert "--finetune-synthetic -1: a number of images, 0 for none" in capsys.readouterr().err
    assert main([*args, *options, "--finetune-synthetic", "33"]) == 2  # two training sequences of 16 frames
    assert f"{corpus}: 33 synthetic images asked for, its training split has 32" in capsys.readouterr().err
    assert main([*args, *options, "--finetune-synthetic", "8"]) == 0
    tuned = yaml.safe_load((out / "kitti-finetuned" / "model.yaml").read_text())
    assert tuned["corpus"]["synthetic"] == f"8 images of {corpus}'s training split"
    assert tuned["training"]["train_samples"] == 128 + 8  # 07 frames 0-127 and the synthetic eight


def test_experiment_five_alone_fine_tunes_the_features_and_keeps_the_head(
    corpus: Path, pvo_data: Path, tmp_path: Path, capsys
) -> None:
    """`--kitti-only`: the real-image experiment without a synthetic corpus; by default the fine-tune trains the
    convolutional features and keeps the synthetic head (`--finetune-trainable all` trains everything); a wrong
    selection or a contradictory pair of flags is one line before anything is written."""
    from safetensors.torch import load_file

    model = tmp_path / "model"
    train = ["sun-bcnn", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "1", "--batch-size", "16", *TINY]
    assert main(train) == 0
    out = tmp_path / "experiment"
    args = ["experiment", "sun-bcnn", "--model", str(model), "--samples", "2", "--scratch-epochs", "0"]
    options = ["--finetune-epochs", "2", "--data", str(pvo_data), "-o", str(out), "-q"]
    assert main([*args, *options]) == 2
    assert "--corpus is needed (or --kitti-only)" in capsys.readouterr().err
    assert main([*args, *options, "--kitti-only", "--skip-kitti"]) == 2
    assert "--kitti-only and --skip-kitti leave nothing to run" in capsys.readouterr().err
    assert main([*args, *options, "--kitti-only", "--finetune-trainable", "blocks:9"]) == 2
    assert "--finetune-trainable blocks:9: trainable entry 'blocks:9': K must be 1 to 2" in capsys.readouterr().err
    assert not out.exists()
    assert main([*args, *options, "--kitti-only"]) == 0
    report = (out / "report.md").read_text()
    assert "## 5. Real images" in report and "## 1. Accuracy" not in report and "fine-tuned on 07, KITTI 06" in report
    start, tuned = load_file(str(model / "weights.safetensors")), load_file(str(out / "kitti-finetuned" / "weights.safetensors"))
    assert all(start[k].equal(tuned[k]) for k in start if k.startswith("head."))
    assert not all(start[k].equal(tuned[k]) for k in start if k.startswith("features.") and k.endswith("weight"))
    assert "(trained: features; the rest kept)" in yaml.safe_load((out / "kitti-finetuned" / "model.yaml").read_text())["notes"]
    assert main([*args, *options, "--kitti-only", "--finetune-trainable", "all", "-o", str(tmp_path / "all")]) == 0
    tuned = load_file(str(tmp_path / "all" / "kitti-finetuned" / "weights.safetensors"))
    assert not all(start[k].equal(tuned[k]) for k in start if k.startswith("head."))


def test_synthetic_mix_spreads_evenly_over_the_training_split(corpus: Path) -> None:
    """The same images every time, spread over both training sequences (frames 0 and 10 of the first, 5 and 15
    of the second: from the split's first image to its last)."""
    from pvo_pseudosensors.learning import DataSpec
    from pvo_tools.experiments.sun_bcnn import synthetic_mix

    spec = DataSpec((24, 64), sun=True)
    mix = synthetic_mix(corpus, 4, spec)
    assert list(mix.indices) == [0, 10, 21, 31] == list(synthetic_mix(corpus, 4, spec).indices)
    assert [int(mix[i]["sequence"]) for i in range(4)] == [0, 0, 1, 1]


def test_a_bearing_balanced_epoch_repeats_rare_suns_and_keeps_its_length() -> None:
    """Three suns at one bearing and one at another (mirrored: the sign of the azimuth does not count): the lone
    one appears as often as the three together; the epoch keeps its length; the same list every time."""
    from pvo_tools.experiments.sun_bcnn import bearing_balanced_indices

    def sun(azimuth_deg: float) -> list[float]:
        a = np.radians(azimuth_deg)
        return [np.sin(a) * 0.8, -0.6, np.cos(a) * 0.8]

    suns = np.array([sun(160), sun(-158), sun(162), sun(70)])
    indices = bearing_balanced_indices(suns)
    assert len(indices) == 4 and indices == bearing_balanced_indices(suns) == sorted(indices)
    assert np.bincount(indices, minlength=4)[3] == 2  # half the epoch: the rare bearing weighs as much as the rest
    many = np.array([sun(155 + 0.1 * k) for k in range(90)] + [sun(60 + 2 * k) for k in range(30)])
    counts = np.bincount(bearing_balanced_indices(many), minlength=120)
    assert counts.sum() == 120 and counts[90:].sum() > 60
    kept = np.flatnonzero(counts[:90])  # the crowded bearing thinned evenly along the drive, not dropped in a block
    assert kept.size > 5 and np.diff(kept).max() <= 4


def test_training_on_two_corpora_joins_their_splits(corpus: Path, tmp_path: Path, capsys) -> None:
    import shutil

    other = tmp_path / "other"
    shutil.copytree(corpus, other, ignore=shutil.ignore_patterns(".cache"))
    model = tmp_path / "model"
    args = ["sun-bcnn", "train", "--corpus", str(corpus), "--corpus", str(other), "-o", str(model), "--epochs", "1"]
    assert main([*args, "--batch-size", "16", *TINY]) == 0
    assert "64 training and 32 validation samples" in capsys.readouterr().err  # 2 x (2 train + 1 validation) x 16
    card = yaml.safe_load((model / "model.yaml").read_text())
    assert [c["path"] for c in card["corpus"]["corpora"]] == [str(corpus), str(other)]
    assert card["commands"]["corpus"].count("pvo sim corpus") == 2


def test_init_fine_tunes_from_a_trained_model(corpus: Path, tmp_path: Path, capsys) -> None:
    import torch
    from safetensors.torch import load_file

    first, tuned = tmp_path / "first", tmp_path / "tuned"
    args = ["sun-bcnn", "train", "--corpus", str(corpus), "--epochs", "1", "--batch-size", "16", *TINY]
    assert main([*args, "-o", str(first), "--learning-rate", "0.01"]) == 0
    # a vanishing learning rate: the fine-tuned weights are the initial ones, not a fresh initialisation
    assert main([*args, "-o", str(tuned), "--learning-rate", "1e-12", "--init", str(first)]) == 0
    start, end = load_file(first / "weights.safetensors"), load_file(tuned / "weights.safetensors")
    learned = [k for k in start if "running_" not in k and start[k].is_floating_point()]  # batch norm's statistics move
    assert learned and all(torch.allclose(start[k], end[k], atol=1e-8) for k in learned)
    card = yaml.safe_load((tuned / "model.yaml").read_text())
    assert f"fine-tuned from {first}" in card["notes"]
    # the card remakes the weights from nothing: the initial model's commands, then the fine-tuning's
    made = yaml.safe_load((first / "model.yaml").read_text())["commands"]
    assert card["commands"]["initial_train"] == made["train"] and card["commands"]["initial_corpus"] == made["corpus"]
    assert f"--init {first}" in card["commands"]["train"]
    capsys.readouterr()
    assert main([*args, "-o", str(tmp_path / "x"), "--init", str(tmp_path / "nowhere")]) == 2
    assert "--init" in capsys.readouterr().err.strip().splitlines()[-1]


def test_an_extra_corpus_without_validation_sequences_adds_training_samples_only(corpus: Path, tmp_path: Path, capsys) -> None:
    import shutil

    extra = tmp_path / "extra"  # rendered with --split 1,0,0: training sequences only
    shutil.copytree(corpus, extra, ignore=shutil.ignore_patterns(".cache"))
    manifest = yaml.safe_load((extra / "manifest.yaml").read_text())
    for entry in manifest["sequences"]:
        entry["split"] = "train"
    manifest["corpus"]["split"] = [1.0, 0.0, 0.0]
    (extra / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    args = ["sun-bcnn", "train", "--corpus", str(corpus), "--corpus", str(extra), "-o", str(tmp_path / "m"), "--epochs", "1"]
    assert main([*args, "--batch-size", "16", *TINY]) == 0
    err = capsys.readouterr().err
    assert f"{extra} has no validation sequence" in err
    assert "96 training and 16 validation samples" in err  # (2 + 4) train x 16, the first corpus's 1 validation x 16
    # the card's corpus commands remake both corpora, the extra one with its shares
    commands = yaml.safe_load((tmp_path / "m" / "model.yaml").read_text())["commands"]["corpus"].split(" && ")
    assert "--split" not in commands[0] and commands[1].endswith("--split 1,0,0")
    # no validation sequence anywhere: one line naming the corpora
    args = ["sun-bcnn", "train", "--corpus", str(extra), "--corpus", str(extra), "-o", str(tmp_path / "n"), "--epochs", "1"]
    assert main([*args, "--batch-size", "16", *TINY]) == 2
    assert "no sequence in the validation split of" in capsys.readouterr().err.strip().splitlines()[-1]


def test_a_card_names_the_command_that_mirrored_its_corpus(corpus: Path, tmp_path: Path) -> None:
    from pvo_core.readers import read_corpus_manifest
    from pvo_tools.commands.models import _corpus_command

    mirrored = tmp_path / "mirrored"
    mirrored.mkdir()
    data = yaml.safe_load((corpus / "manifest.yaml").read_text())
    data |= {"generator": "pvo sim mirror", "mirrored_from": str(corpus)}
    (mirrored / "manifest.yaml").write_text(yaml.safe_dump(data))
    assert _corpus_command(read_corpus_manifest(mirrored)) == f"pvo sim mirror {corpus} {mirrored}"
    assert _corpus_command(read_corpus_manifest(corpus)).startswith(f"pvo sim corpus {corpus} --sequences 4")
    assert "--sky" not in _corpus_command(read_corpus_manifest(corpus))
    sky = tmp_path / "sky"
    sky.mkdir()
    data = yaml.safe_load((corpus / "manifest.yaml").read_text())
    data["corpus"]["sky"] = "sun"
    (sky / "manifest.yaml").write_text(yaml.safe_dump(data))
    assert " --sky sun" in _corpus_command(read_corpus_manifest(sky))
    assert "--urban-pitch" not in _corpus_command(read_corpus_manifest(corpus))
    data["corpus"]["urban_pitch"] = [0.0, 25.0]
    (sky / "manifest.yaml").write_text(yaml.safe_dump(data))
    assert " --urban-pitch 0 25" in _corpus_command(read_corpus_manifest(sky))
