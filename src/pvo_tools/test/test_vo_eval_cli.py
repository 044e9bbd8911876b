"""`pvo vo` and `pvo eval` end to end on real data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pvo_core.readers import KittiSequence
from pvo_core.trajectory import read_kitti_poses
from pvo_frontend.vo import StereoVO
from pvo_tools.cli import main


def test_pvo_vo_writes_the_trajectory_of_the_pipeline(pvo_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    root = pvo_data / "kitti/sequences/06"
    out = tmp_path / "traj.txt"
    code = main(["vo", str(root), "--poses", str(pvo_data / "kitti/poses/06.txt"), "-o", str(out), "--count", "8", "-q"])
    assert code == 0
    assert "end drift" in capsys.readouterr().out
    sequence = KittiSequence(root, rate_hz=10.0, count=8)
    vo = StereoVO(sequence.camera())
    expected = [vo.process(*sequence.load_pair(i), 0.1 * i).pose for i in range(8)]
    assert np.allclose(read_kitti_poses(out), expected, atol=1e-8)


def test_pvo_vo_bad_parameter_is_one_line(pvo_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code = main(["vo", str(pvo_data / "kitti/sequences/06"), "-o", str(tmp_path / "t.txt"), "-p", "solver.loss=tukey"])
    assert code == 2
    assert capsys.readouterr().err.strip() == (
        "pvo: error: invalid VO configuration: solver.loss must be one of l2, huber, cauchy, geman_mcclure, student_t"
    )


def test_pvo_vo_takes_the_nodes_params_file(pvo_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """The shipped params files carry the node's own settings too (frames, path publishing); offline they are left
    out, the VO's are read, and -p still wins; any other unknown name is still an error."""
    from pvo_tools.commands.vo import vo_config

    config_dir = Path(__file__).resolve().parents[2] / "pvo_frontend" / "config"
    calibrated = vo_config(None, config_dir / "stereo_vo_kitti_calibrated.yaml")
    assert calibrated.solver.pixel_sigma == (2.0, 2.0, 4.0)
    assert vo_config(["solver.noise_model=stereo"], config_dir / "stereo_vo.yaml").solver.noise_model == "stereo"
    wrong = tmp_path / "params.yaml"
    wrong.write_text("stereo_vo:\n  ros__parameters:\n    odom_frame: odom\n    solver.nonsense: 1\n")
    args = ["vo", str(pvo_data / "kitti/sequences/06"), "-o", str(tmp_path / "t.txt"), "--params-file", str(wrong)]
    assert main(args) == 2
    assert "unknown VO parameter(s): solver.nonsense" in capsys.readouterr().err
    wrong.write_text("stereo_vo:\n  ros__parameters:\n    odom_frame: odom\n    solverloss: huber\n")  # a typo, not the node's
    assert main(args) == 2
    assert "unknown VO parameter(s): solverloss" in capsys.readouterr().err


def test_pvo_eval_matches_the_devkit_and_writes_plots(pvo_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    gt = pvo_data / "kitti/poses/07.txt"
    est = pvo_data / "kitti/reference-results/IMLS/07.txt"
    reference = np.loadtxt(pvo_data / "kitti/reference-results/IMLS/errors/07.txt")
    code = main(["eval", "--gt", str(gt), "--est", str(est), "-o", str(tmp_path / "eval")])
    assert code == 0
    assert "KITTI devkit segments" in capsys.readouterr().out
    record = json.loads((tmp_path / "eval/metrics.json").read_text())
    assert record["kind"] == "eval" and record["schema"] == "pvo.run-result/1"
    figures = record["figures"]
    assert figures["devkit_translation_percent"] == pytest.approx(100 * reference[:, 2].mean(), rel=1e-9)
    assert figures["devkit_segments"] == len(reference)
    for name in ("trajectory.png", "errors_per_frame.png", "errors_vs_length.png"):
        assert (tmp_path / "eval" / name).stat().st_size > 1000


def test_pvo_eval_refuses_an_estimate_longer_than_the_ground_truth(
    pvo_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    code = main(
        [
            "eval",
            "--gt",
            str(pvo_data / "kitti/sequences/06/poses_frames000-050.txt"),
            "--est",
            str(pvo_data / "kitti/poses/06.txt"),
        ]
    )
    assert code == 2
    assert "has only 51 poses" in capsys.readouterr().err


def test_pvo_eval_of_a_shorter_estimate_says_which_frames_it_evaluates(
    pvo_data: Path, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    clip = pvo_data / "kitti/sequences/06/poses_frames000-050.txt"
    code = main(["eval", "--gt", str(pvo_data / "kitti/poses/06.txt"), "--est", str(clip)])
    assert code == 0
    err = capsys.readouterr().err
    assert f"pvo: warning: {clip} has 51 poses (frames 0-50) of the 1101 in" in err and "evaluating those frames only" in err
