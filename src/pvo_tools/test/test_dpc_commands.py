"""`pvo dpc-net train|predict|correct|eval` on a tiny corpus cut from the real KITTI 06 clip with a 5 % wrong
focal length in calib.txt: the commands compose; the corrected trajectory is the fused VO + corrections."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_tools.cli import main

TINY = ["--height", "32", "--width", "104", "--stem", "4,4,8", "--body", "8,16", "--deltas", "2,3", "--test-delta", "3"]


def write_clip(clip: Path, root: Path, frames: range) -> None:
    for side in ("image_0", "image_1"):
        (root / side).mkdir(parents=True)
        images = sorted((clip / side).glob("*.png"))
        for new, frame in enumerate(frames):
            (root / side / f"{new:06d}.png").symlink_to(images[frame])
    rows = []
    for name, line in zip(("P0", "P1"), (clip / "calib_P0_P1_unlabelled.txt").read_text().splitlines(), strict=True):
        p = np.array(line.split()[-12:], float).reshape(3, 4)
        p[0, 0] *= 1.05
        p[1, 1] *= 1.05
        p[0, 3] *= 1.05
        rows.append(f"{name}: " + " ".join(f"{v:.12e}" for v in p.reshape(-1)))
    (root / "calib.txt").write_text("\n".join(rows) + "\n")
    poses = np.array([np.array(line.split(), float) for line in (clip / "poses_frames000-050.txt").read_text().splitlines()])
    first = np.vstack([poses[frames[0]].reshape(3, 4), [0, 0, 0, 1]])
    relative = [np.linalg.inv(first) @ np.vstack([poses[k].reshape(3, 4), [0, 0, 0, 1]]) for k in frames]
    (root / "poses.txt").write_text("\n".join(" ".join(f"{v:.12e}" for v in r[:3].reshape(-1)) for r in relative) + "\n")


@pytest.fixture(scope="module")
def corpus(pvo_data: Path, tmp_path_factory) -> Path:
    clip = pvo_data / "kitti" / "sequences" / "06"
    root = tmp_path_factory.mktemp("dpc-corpus")
    entries = []
    for i, (split, frames) in enumerate((("train", range(0, 20)), ("validation", range(20, 34)), ("test", range(34, 51)))):
        name = f"{i:04d}"
        write_clip(clip, root / name, frames)
        entries.append(
            {"name": name, "split": split, "preset": "urban", "sha256": hashlib.sha256(name.encode()).hexdigest(), "config": {}}
        )
    corpus = {"sequences": 3, "frames": 17, "width": 1226, "height": 370, "presets": ["urban"], "seed": 0, "colour": False}
    (root / "manifest.yaml").write_text(yaml.safe_dump({"corpus": corpus, "sequences": entries}))
    return root


def test_train_predict_correct_eval(corpus: Path, tmp_path: Path, capsys) -> None:
    model = tmp_path / "model"
    train = ["dpc-net", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "2", "--batch-size", "8", "-q"]
    assert main([*train, "--threads", "1", *TINY]) == 0
    assert "35 training and 11 validation samples" in capsys.readouterr().err  # spans 2, 3 of 20 frames; span 3 of 14
    card = yaml.safe_load((model / "model.yaml").read_text())
    covariance = np.array(card["calibration"]["target_covariance"])
    assert card["architecture"] == "dpc-net" and covariance.shape == (6, 6) and np.all(np.linalg.eigvalsh(covariance) > 0)

    out = tmp_path / "corrected.txt"
    assert main(["dpc-net", "correct", str(corpus / "0002"), "--model", str(model), "-o", str(out)]) == 0
    assert "of 5 corrections fused" in capsys.readouterr().out  # windows 0-3, 3-6, ..., 12-15 of 17 frames
    corrected = np.loadtxt(out)
    assert corrected.shape == (17, 12) and np.all(np.isfinite(corrected))

    corrections = tmp_path / "corrections.csv"
    vo = tmp_path / "corrected_vo.txt"
    assert main(["dpc-net", "predict", str(corpus / "0002"), "--vo", str(vo), "--model", str(model), "-o", str(corrections)]) == 0
    lines = corrections.read_text().splitlines()
    assert lines[0].startswith("frame_first,frame_last,t00") and len(lines) == 6 and lines[1].startswith("0,3,")

    capsys.readouterr()
    evaluate = ["dpc-net", "eval", "--gt", str(corpus / "0002" / "poses.txt"), "--est", str(out), "--vo", str(vo)]
    assert main([*evaluate, "--json", str(tmp_path / "m")]) == 0
    printed = capsys.readouterr().out
    assert "corrected" in printed and "VO" in printed and "m-ATE" in printed
    figures = yaml.safe_load((tmp_path / "m" / "metrics.json").read_text())["figures"]
    assert figures["VO.m_ate_trans"] > 0.0 and np.isfinite(figures["corrected.m_ate_trans"])


def test_bad_inputs_are_one_line(corpus: Path, tmp_path: Path, capsys) -> None:
    missing = ["dpc-net", "correct", str(corpus / "0002"), "--model", str(tmp_path / "none"), "-o", str(tmp_path / "x.txt")]
    assert main(missing) == 2
    assert "model directory not found" in capsys.readouterr().err
    assert main(["dpc-net", "train", "--corpus", str(corpus), "-o", str(tmp_path / "m"), *TINY, "--variant", "scale"]) == 2
    assert "unknown variant 'scale'" in capsys.readouterr().err
