"""`pvo probe train|eval`, `pvo vo --probe` and `pvo experiment probe` on the real KITTI data: the commands
compose PROBE's library, write what they say, and bad input is one line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_tools.cli import main


def test_train_on_tracks_then_eval_and_vo_with_the_model(tmp_path: Path, pvo_data: Path, capsys) -> None:
    kitti = pvo_data / "kitti"
    model = tmp_path / "model"
    tracks = kitti / "raw-derived" / "2011_09_30_drive_0027_sync_KLT.mat"
    args = [str(tracks), "--track-images", str(kitti / "sequences/07/image_0"), "--frames", "1:40", "-o", str(model), "-q"]
    assert main(["probe", "train", *args]) == 0
    card = yaml.safe_load((model / "model.yaml").read_text())
    assert card["kind"] == "gk" and card["training"]["pairs"] == 39 and card["samples"] == card["training"]["features"]
    assert "pvo probe train" in card["training"]["command"]
    clip = kitti / "sequences" / "06"
    poses = clip / "poses_frames000-050.txt"
    assert (
        main(
            [
                "probe",
                "eval",
                str(clip),
                "--poses",
                str(poses),
                "--model",
                str(model),
                "--count",
                "20",
                "-o",
                str(tmp_path / "eval"),
            ]
        )
        == 0
    )
    figures = json.loads((tmp_path / "eval" / "metrics.json").read_text())["figures"]
    assert figures["VO.end_drift_percent"] > 0 and figures["VO + PROBE.end_drift_percent"] > 0
    assert figures["VO.end_drift_percent"] != figures["VO + PROBE.end_drift_percent"]
    out = tmp_path / "traj.txt"
    assert main(["vo", str(clip), "--poses", str(poses), "--count", "10", "--probe", str(model), "-o", str(out), "-q"]) == 0
    assert len(out.read_text().splitlines()) == 10
    capsys.readouterr()


def test_bad_probe_input_is_one_line(tmp_path: Path, pvo_data: Path, capsys) -> None:
    clip = pvo_data / "kitti" / "sequences" / "06"
    assert main(["vo", str(clip), "--probe", str(tmp_path / "missing"), "-o", str(tmp_path / "t.txt"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "PROBE model" in err and "no such directory" in err
    assert main(["probe", "train", str(clip), "-o", str(tmp_path / "m"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no poses.txt" in err
    tracks = pvo_data / "kitti" / "raw-derived" / "2011_09_30_drive_0027_sync_KLT.mat"
    assert main(["probe", "train", str(tracks), "-o", str(tmp_path / "m"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--track-images" in err
    assert main(["probe", "train", str(tracks), "--no-image", "--kind", "knn", "--em", "-o", str(tmp_path / "m"), "-q"]) == 2
    assert "k-NN trains with ground truth only" in capsys.readouterr().err
    # --prior-samples weighs the nominal prior only: with the fitted one it would be ignored, so it is refused
    assert main(["probe", "train", str(clip), "--prior-samples", "5", "-o", str(tmp_path / "m"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "give --prior nominal with it" in err


def test_experiment_probe_writes_its_report(tmp_path: Path, capsys) -> None:
    out = tmp_path / "exp"
    args = ["experiment", "probe", "--train-seconds", "8", "--test-seconds", "12", "--seeds", "0", "--em-iterations", "2"]
    assert main([*args, "--skip-kitti", "-o", str(out), "-q"]) == 0
    report = (out / "report.md").read_text()
    assert "Table 4.1" in report and "PROBE-GK-GT" in report and (out / "synthetic_rmse.png").is_file()
    figures = json.loads((out / "metrics.json").read_text())["figures"]
    assert figures["synthetic.PROBE-GK-GT.trans_m"] < figures["synthetic.Fixed covariance.trans_m"]
    capsys.readouterr()


@pytest.mark.parametrize("drive", ["01"])
def test_experiment_refuses_to_train_on_sequence_01(tmp_path: Path, capsys, drive: str) -> None:
    args = ["experiment", "probe", "--train-seconds", "2", "--test-seconds", "2", "--seeds", "0", "--em-iterations", "1"]
    assert main([*args, "--train-drive", drive, "-o", str(tmp_path), "-q"]) == 2
    assert "kept for testing" in capsys.readouterr().err


def test_train_with_the_imu_of_a_rendered_sequence_and_run_with_it(tmp_path: Path, capsys) -> None:
    """`pvo sim` writes imu.csv: `pvo probe train --imu` reads it into the model's IMU predictors and `pvo vo
    --probe` feeds the same readings to the VO; without imu.csv --imu is one clear line."""
    seq = tmp_path / "seq"
    assert main(["sim", str(seq), "--frames", "14", "--seed", "3"]) == 0
    model = tmp_path / "model"
    assert main(["probe", "train", str(seq), "--imu", "-o", str(model), "-q"]) == 0
    card = yaml.safe_load((model / "model.yaml").read_text())
    assert card["predictors"][-4:] == ["specific_force", "angular_rate", "disparity", "row"]
    assert main(["vo", str(seq), "--probe", str(model), "-o", str(tmp_path / "t.txt"), "-q"]) == 0
    assert len((tmp_path / "t.txt").read_text().splitlines()) == 14
    (seq / "imu.csv").unlink()
    capsys.readouterr()
    assert main(["probe", "train", str(seq), "--imu", "-o", str(tmp_path / "m2"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--imu needs an imu.csv" in err


def test_experiment_hydranet_1d_writes_its_report(tmp_path: Path, capsys) -> None:
    out = tmp_path / "h1d"
    args = ["experiment", "hydranet-1d", "--repetitions", "1", "--steps", "30", "--heads", "3", "--bags", "2", "--threads", "1"]
    assert main([*args, "-o", str(out), "-q"]) == 0
    report = (out / "report.md").read_text()
    assert "hydranet_no_aleatoric" in report and (out / "nll_boxplot.png").is_file() and (out / "bands.png").is_file()
    figures = json.loads((out / "metrics.json").read_text())["figures"]
    assert np.isfinite(figures["bagging.nll_out_median"])
    assert main([*args[:2], "--repetitions", "0", "-o", str(out), "-q"]) == 2
    capsys.readouterr()
