"""Experiment 4 of `pvo experiment sun-bcnn` on a tiny rendered corpus: the test sequences rendered longer
(the same draws, a longer world), the project's VO and a Sun-BCNN fused with GT-Sun rows beside them."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before anything imports mujoco


def test_test_sequences_rendered_longer_and_fused(tmp_path: Path) -> None:
    from pvo_core.readers import read_corpus_manifest
    from pvo_pseudosensors.learning.checkpoint import save_model
    from pvo_pseudosensors.sun_bcnn.config import SunBCNNConfig
    from pvo_pseudosensors.sun_bcnn.model import SunBCNN, SunTask
    from pvo_sim.corpus import CorpusConfig, render_corpus
    from pvo_tools.experiments.sun_bcnn import (
        FUSION_ROWS,
        fusion_changes,
        fusion_experiment,
        fusion_inputs,
        render_fusion_sequences,
        with_rig_error,
    )

    corpus = CorpusConfig(sequences=6, frames=3, width=320, height=120, seed=7)  # test split: 0000 and 0005
    try:
        render_corpus(corpus, tmp_path / "corpus", jobs=1)
    except ValueError as exc:
        if "no offscreen renderer" in str(exc):
            pytest.skip(str(exc))
        raise
    folders = render_fusion_sequences(tmp_path / "corpus", 2, 30, tmp_path / "long", jobs=2, say=lambda _: None)
    assert [f.name for f in folders] == ["0000", "0005"]
    import yaml

    presets = {
        e["name"]: e["config"]["preset"] for e in yaml.safe_load((tmp_path / "corpus" / "manifest.yaml").read_text())["sequences"]
    }
    for preset in set(presets[f.name] for f in folders):  # --fusion-preset: the first test sequences of one preset
        picked = render_fusion_sequences(tmp_path / "corpus", 1, 30, tmp_path / preset, jobs=1, say=lambda _: None, preset=preset)
        assert [presets[f.name] for f in picked] == [preset] and picked[0].name in [f.name for f in folders]
    validation = [s.name for s in read_corpus_manifest(tmp_path / "corpus").split("validation")]
    picked = render_fusion_sequences(tmp_path / "corpus", 1, 30, tmp_path / "validation", 1, lambda _: None, split="validation")
    assert [f.name for f in picked] == validation[:1] and (picked[0] / "sun.csv").is_file()
    with pytest.raises(ValueError, match="test sequences of the nowhere preset, 1 asked for"):
        render_fusion_sequences(tmp_path / "corpus", 1, 30, tmp_path / "long", jobs=1, say=lambda _: None, preset="nowhere")

    short = {e["name"]: e["config"] for e in yaml.safe_load((tmp_path / "corpus" / "manifest.yaml").read_text())["sequences"]}
    long = {e["name"]: e["config"] for e in yaml.safe_load((tmp_path / "long" / "manifest.yaml").read_text())["sequences"]}
    for folder in folders:  # the same draws (place, time, path, preset, camera, degradations), only longer
        assert {**short[folder.name], "frames": 30} == long[folder.name]
        assert len(list((folder / "image_0").glob("*.png"))) == 30

    torch = pytest.importorskip("torch")
    torch.manual_seed(0)
    config = SunBCNNConfig(height=24, width=64, widths=(4, 8), hidden=8, dropout=0.1, grid=(1, 1), bins=0, rotate=0.0)
    save_model(tmp_path / "model", SunBCNN(config), SunTask(config).card())
    from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn

    model, card = load_sun_bcnn(tmp_path / "model")
    inputs = [fusion_inputs(folder, model, card, samples=4) for folder in folders]
    for seq, learned in inputs:
        assert len(seq.ground_truth) == len(seq.vo_poses) == 30 and [m.stamp for m in learned] == list(seq.stamps[::10])
    table = fusion_experiment([seq for seq, _ in inputs], [learned for _, learned in inputs])
    assert set(table) == {"0000", "0005"} and all(set(rows) == set(FUSION_ROWS) for rows in table.values())
    for rows in table.values():
        for row in rows.values():
            assert all(np.isfinite(row[e][k]) for e in ("online", "smoothed") for k in ("trans", "rot"))
        assert rows["GT-Sun-10"]["smoothed"]["rot"] != rows["Without Sun"]["smoothed"]["rot"]  # the sun was fused
    changes = fusion_changes(table)
    assert set(changes) == set(FUSION_ROWS[1:])
    some = fusion_experiment([seq for seq, _ in inputs], [learned for _, learned in inputs], rows=("Without Sun", "Sun-BCNN"))
    assert some["0000"] == {row: table["0000"][row] for row in ("Without Sun", "Sun-BCNN")}  # the same fusion, fewer rows
    assert set(fusion_changes(some)) == {"Sun-BCNN"} and fusion_changes(some)["Sun-BCNN"] == changes["Sun-BCNN"]
    offset = {"inputs.sun.bias_sigma": (0.2, 0.2), "inputs.sun.bias_walk_sigma": (0.01, 0.01)}  # the learned sun's only
    biased_table = fusion_experiment([seq for seq, _ in inputs], [learned for _, learned in inputs], learned_fusion=offset)
    for name, rows in biased_table.items():
        assert {r: v for r, v in rows.items() if r != "Sun-BCNN"} == {r: v for r, v in table[name].items() if r != "Sun-BCNN"}
    assert any(biased_table[n]["Sun-BCNN"] != table[n]["Sun-BCNN"] for n in table)

    # --fusion-rig-error: the same images, the VO on a calib.txt with the focal length 5 % too long, so every
    # depth and hence every step it measures is 5 % too long; the camera's file and the truth untouched
    from pvo_core.readers import KittiSequence

    sequence = KittiSequence(folders[0], poses_file=folders[0] / "poses.txt")
    camera, wrong = sequence.camera(), with_rig_error(sequence, 1.05, 0.9).camera()
    assert wrong.f == pytest.approx(1.05 * camera.f) and wrong.baseline == pytest.approx(0.9 * camera.baseline)
    assert (wrong.cu, wrong.cv) == (camera.cu, camera.cv) and sequence.camera() == camera
    biased, _ = fusion_inputs(folders[0], model, card, samples=4, rig_error=(1.05, 1.0))
    clean = inputs[0][0]

    def path_length(poses: np.ndarray) -> float:
        return float(np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1).sum())

    np.testing.assert_array_equal(biased.ground_truth, clean.ground_truth)
    assert path_length(biased.vo_poses) / path_length(clean.vo_poses) == pytest.approx(1.05, abs=0.02)

    # --fusion-lens: the same drive rendered through the thesis's lens; the truth, the sun and calib.txt as without it,
    # the images bent (barrel distortion pulls the border towards the centre)
    import cv2
    from pvo_tools.experiments.sun_bcnn import fusion_rigs

    bent = render_fusion_sequences(
        tmp_path / "corpus", 1, 30, tmp_path / "lens", jobs=1, say=lambda _: None, lens=(-0.3, 0.2, 0.01)
    )
    assert [f.name for f in bent] == ["0000"]
    for name in ("poses.txt", "sun.csv", "calib.txt"):
        assert (bent[0] / name).read_text() == (folders[0] / name).read_text()
    straight = cv2.imread(str(folders[0] / "image_0" / "000010.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    through_lens = cv2.imread(str(bent[0] / "image_0" / "000010.png"), cv2.IMREAD_GRAYSCALE).astype(float)
    assert straight.shape == through_lens.shape and np.abs(straight - through_lens).mean() > 5.0
    rigs = fusion_rigs(folders, (1.03, 1.0), (-0.3, 0.2, 0.01), bent)
    assert [(r.key, r.folders, r.rig_error) for r in rigs] == [
        ("fusion", folders, None),
        ("fusion_rig", folders, (1.03, 1.0)),
        ("fusion_lens", bent, None),
    ]
    assert "k = -0.3, 0.2, 0.01" in rigs[2].vo


def test_rig_error_option_is_two_scales() -> None:
    from pvo_tools.experiments.sun_bcnn import parse_rig_error

    assert parse_rig_error(None) is None and parse_rig_error("1.03,1") == (1.03, 1.0)
    with pytest.raises(ValueError, match="give two scales, FOCAL,BASELINE"):
        parse_rig_error("1.03")
    with pytest.raises(ValueError, match="each scale must be in \\[0.5, 2\\]"):
        parse_rig_error("3,1")


def test_lens_option_is_up_to_three_finite_coefficients() -> None:
    from pvo_tools.experiments.sun_bcnn import fusion_rigs, parse_lens

    assert parse_lens(None) == () and parse_lens([-0.3, 0.2, 0.01]) == (-0.3, 0.2, 0.01) and parse_lens([-0.1]) == (-0.1,)
    with pytest.raises(ValueError, match="give k1 \\[k2 k3\\], finite"):
        parse_lens([-0.3, 0.2, 0.01, 0.0])
    with pytest.raises(ValueError, match="give k1 \\[k2 k3\\], finite"):
        parse_lens([float("nan")])
    with pytest.raises(ValueError, match="a lens that distorts nothing is the calibrated rig"):
        parse_lens([0.0, 0.0])
    with pytest.raises(ValueError, match="needs its sequences rendered through the lens"):
        fusion_rigs([Path("a")], None, (-0.3,), None)


def test_a_staged_kitti_clip_carries_its_camera_for_turned_camera_fine_tuning(tmp_path: Path) -> None:
    """The experiment fine-tunes on staged KITTI frames; a model trained with --rotate needs their intrinsics."""
    import cv2
    from pvo_pseudosensors.learning import FrameDataset, Source
    from pvo_pseudosensors.sun_bcnn import SunBCNNConfig
    from pvo_tools.experiments.sun_bcnn import stage_kitti

    clip = tmp_path / "data" / "kitti" / "sequences" / "07"
    (clip / "image_0").mkdir(parents=True)
    for k in range(4):
        cv2.imwrite(str(clip / "image_0" / f"{k:06d}.png"), np.full((40, 120), 60 * k, np.uint8))
    (clip / "calib.txt").write_text("P0: 80 0 59.5 0 0 80 19.5 0 0 0 1 0\nP1: 80 0 59.5 -43 0 80 19.5 0 0 0 1 0\n")
    (tmp_path / "data" / "kitti" / "sun").mkdir()
    (tmp_path / "data" / "kitti" / "sun" / "kitti_sun_test_07.csv").write_text(
        "".join(f"{k:06d},0.6,-0.6,0.52915026\n" for k in range(4))
    )
    staged = stage_kitti(tmp_path / "data", "07", range(1, 4), tmp_path / "staged")
    config = SunBCNNConfig(height=20, width=60, rotate=10.0)
    sample = FrameDataset([Source(staged, "07")], config.spec)[0]
    np.testing.assert_allclose(sample["camera"].numpy(), [40.0, 40.0, 29.5, 9.5])
    assert float(sample["left"].mean()) == pytest.approx(60 / 255, abs=1e-6)  # frame 1, renumbered 0
