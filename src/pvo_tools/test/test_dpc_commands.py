"""`pvo dpc-net train|calibrate|predict|correct|eval` on a tiny corpus cut from the real KITTI 06 clip with a 5 %
wrong focal length in calib.txt: the commands compose; the corrected trajectory is the fused VO + corrections or
the overwritten VO; another rig's sequence is left out of training and refused at use; the experiment's pieces."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_tools.cli import main
from pvo_tools.dpc import describe_nearest, nearest_fusion, select_fusion, worst_change

TINY = ["--height", "32", "--width", "104", "--stem", "4,4,8", "--body", "8,16", "--deltas", "2,3", "--test-delta", "3"]


def write_clip(clip: Path, root: Path, frames: range, focal_scale: float = 1.05) -> None:
    for side in ("image_0", "image_1"):
        (root / side).mkdir(parents=True)
        images = sorted((clip / side).glob("*.png"))
        for new, frame in enumerate(frames):
            (root / side / f"{new:06d}.png").symlink_to(images[frame])
    rows = []
    for name, line in zip(("P0", "P1"), (clip / "calib_P0_P1_unlabelled.txt").read_text().splitlines(), strict=True):
        p = np.array(line.split()[-12:], float).reshape(3, 4)
        p[0, 0] *= focal_scale
        p[1, 1] *= focal_scale
        p[0, 3] *= focal_scale
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
    # a sequence of another rig (a drawn calibration error): DPC-Net's training leaves it out
    write_clip(clip, root / "0003", range(0, 20), focal_scale=1.3)
    entries.append(
        {
            "name": "0003",
            "split": "train",
            "preset": "urban",
            "sha256": "0" * 64,
            "config": {},
            "conditions": ["wrong calibration"],
        }
    )
    corpus = {"sequences": 3, "frames": 17, "width": 1226, "height": 370, "presets": ["urban"], "seed": 0, "colour": False}
    (root / "manifest.yaml").write_text(yaml.safe_dump({"corpus": corpus, "sequences": entries}))
    return root


def test_train_predict_correct_eval(corpus: Path, tmp_path: Path, capsys) -> None:
    model = tmp_path / "model"
    train = ["dpc-net", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "2", "--batch-size", "8", "-q"]
    assert main([*train, "--threads", "1", *TINY]) == 0
    err = capsys.readouterr().err
    assert "35 training and 11 validation samples" in err  # spans 2, 3 of 20 frames; span 3 of 14
    assert "1 train sequence(s) of" in err and "left out, another rig's (wrong calibration or radial distortion): 0003" in err
    card = yaml.safe_load((model / "model.yaml").read_text())
    covariance = np.array(card["calibration"]["target_covariance"])
    assert card["architecture"] == "dpc-net" and covariance.shape == (6, 6) and np.all(np.linalg.eigvalsh(covariance) > 0)
    assert card["input"]["rig"]["size"] == [1226, 370] and card["input"]["rig"]["lens"] is None

    assert main(["dpc-net", "calibrate", "--model", str(model), "--corpus", str(corpus), "--vo-spans", "3,6"]) == 0
    out = capsys.readouterr().out
    assert "11 validation windows of 1 sequences" in out
    calibration = yaml.safe_load((model / "model.yaml").read_text())["calibration"]
    residual = np.array(calibration["residual_covariance"])
    assert residual.shape == (6, 6) and np.all(np.linalg.eigvalsh(residual) > 0)
    # the span whose fusion lowered the m-ATE most on validation, each candidate's figures kept in the card
    changes = {int(k): v for k, v in calibration["vo_span_changes"].items()}
    assert set(changes) == {3, 6} and calibration["vo_span"] == min(changes, key=lambda s: sum(changes[s]))
    assert f"VO span {calibration['vo_span']} frames (1 validation sequences, in sample: one sequence)" in out
    assert len(calibration["vo_scale"]) == 6 and min(calibration["vo_scale"]) > 0.0  # the VO's scales at that span
    for bad, message in (
        ("0,3", "VO spans must be positive frame counts, got '0,3'"),
        ("3,x", "expected frame counts separated by commas (e.g. 3,9,30), got '3,x'"),
    ):
        with pytest.raises(SystemExit) as exit_status:
            main(["dpc-net", "calibrate", "--model", str(model), "--corpus", str(corpus), "--vo-spans", bad])
        assert exit_status.value.code == 2 and f"argument --vo-spans: {message}" in capsys.readouterr().err
    for flag in (
        ["--consistent-corrections"],
        ["--harm-tolerance", "5"],
        ["--vo-bias-windows", "30"],
        ["--vo-rotation-scales", "1"],
    ):
        assert main(["dpc-net", "calibrate", "--model", str(model), "--corpus", str(corpus), *flag]) == 2
        assert f"{flag[0]} weighs the corrections on long validation drives: give them with --drives" in (capsys.readouterr().err)
    for bad in ("-1", "x", "inf", "nan"):
        for option in ("--harm-tolerance", "--vo-bias-windows"):
            with pytest.raises(SystemExit) as exit_status:
                main(["dpc-net", "calibrate", "--model", str(model), "--corpus", str(corpus), option, bad])
            assert exit_status.value.code == 2 and f"argument {option}: " in capsys.readouterr().err
    for bad in ("1.5", "x", "-1", "nan"):
        with pytest.raises(SystemExit) as exit_status:
            main(["dpc-net", "calibrate", "--model", str(model), "--corpus", str(corpus), "--vo-rotation-scales", bad])
        assert exit_status.value.code == 2 and "argument --vo-rotation-scales: " in capsys.readouterr().err

    # the fusion chosen on long drives (here the validation and test clips): every candidate's per-drive figures kept,
    # the choice the one select_fusion makes of them (none: nothing fused, and `correct` says so)
    drove = tmp_path / "drove"
    shutil.copytree(model, drove)
    calibrate = ["dpc-net", "calibrate", "--model", str(drove), "--corpus", str(corpus), "--vo-spans", "3,6"]
    drives = ["--drives", str(corpus / "0001"), str(corpus / "0002")]
    scales = ["--vo-rotation-scales", "0.5", "--vo-translation-scales", "50"]
    assert main([*calibrate, *drives, "--vo-bias-windows", "10,30", *scales]) == 0
    drive_card = yaml.safe_load((drove / "model.yaml").read_text())["calibration"]
    candidates = drive_card["drive_calibration"]["candidates"]
    assert {c["span"] for c in candidates.values()} == {3, 6} and all(len(c["per_drive"]) == 2 for c in candidates.values())
    # each weighing tried with the corrections as predicted and with the validation split's mean error taken off
    assert sum(c["remove_mean"] for c in candidates.values()) == sum(not c["remove_mean"] for c in candidates.values()) > 0
    chosen = select_fusion({label: list(c["per_drive"].values()) for label, c in candidates.items()}, harm_tolerance=0.05)
    assert drive_card["drive_calibration"]["harm_tolerance"] == 0.05  # the default: the no-harm bound
    for c in candidates.values():
        assert c["worst"] == pytest.approx(max(max(v) for v in c["per_drive"].values()), abs=1e-4)
        assert c["accepted"] == (c["worst"] < 0.05 and max(c["mean"]) < 0.0)
    if chosen is None:
        assert drive_card["fused_axes"] == [] and drive_card["drive_calibration"]["chosen"] is None
        out = capsys.readouterr().out
        assert "nothing is fused" in out and str(describe_nearest(candidates)) in out
        assert main(["dpc-net", "correct", str(corpus / "0002"), "--model", str(drove), "-o", str(tmp_path / "d.txt")]) == 0
        assert "fuses no axis" in capsys.readouterr().err
    else:
        assert drive_card["fused_axes"] == candidates[chosen]["axes"] and drive_card["vo_span"] == candidates[chosen]["span"]
        assert drive_card["remove_mean"] == candidates[chosen]["remove_mean"]
        assert drive_card.get("vo_bias_windows", 0.0) == candidates[chosen].get("vo_bias_windows", 0.0)
        gain = candidates[chosen].get("vo_rotation_scale_gain")
        assert drive_card.get("vo_rotation_scale") == ({"windows": 1000.0, "gain": gain} if gain else None)
        steps = candidates[chosen].get("vo_translation_scale_windows")
        assert drive_card.get("vo_translation_scale_windows") == steps
        assert f"VO span {drive_card['vo_span']} frames (2 validation drives" in capsys.readouterr().out
    # every weighing that fuses the translation is tried again with the VO's translation bias learned from the
    # corrections, once per number of them asked for (10 and 30; 10, 30 and 100 by default), named so; one without the
    # translation not
    # and each such weighing that fuses rotation too, with the VO's turns rescaled by the gain asked for (0.5)
    plain = {
        label: c for label, c in candidates.items() if not c.get("vo_bias_windows") and not c.get("vo_translation_scale_windows")
    }
    translating = {label for label, c in plain.items() if {"x", "y", "z"} <= set(c["axes"])}
    turning = {label for label in translating if {"rx", "ry", "rz"} & set(plain[label]["axes"])}
    for windows in (10, 30):
        debiased = {label: c for label, c in candidates.items() if c.get("vo_bias_windows") == windows}
        rescaled = {label for label, c in debiased.items() if c.get("vo_rotation_scale_gain")}
        assert translating and {label.removesuffix(f", VO debiased over {windows}") for label in debiased.keys() - rescaled} == (
            translating
        )
        assert turning and {label.removesuffix(f", VO debiased over {windows}, turns rescaled x0.5") for label in rescaled} == (
            turning
        )
        assert all(debiased[label]["vo_rotation_scale_gain"] == 0.5 for label in rescaled)
    # and each weighing that fuses the translation with the VO's steps rescaled instead (over 50 corrections)
    stepped = {label for label, c in candidates.items() if c.get("vo_translation_scale_windows") == 50}
    assert {label.removesuffix(", steps rescaled over 50") for label in stepped} == translating
    assert len(candidates) == len(plain) + 2 * len(translating) + 2 * len(turning) + len(translating)
    # the corrections made consistent over the span too: tried for the spans longer than Δp, each named so
    consistent = tmp_path / "consistent"
    shutil.copytree(model, consistent)
    calibrate[calibrate.index(str(drove))] = str(consistent)
    assert (
        main(
            [
                *calibrate,
                "--drives",
                str(corpus / "0001"),
                str(corpus / "0002"),
                "--consistent-corrections",
                "--vo-bias-windows",
                "0",
                "--vo-translation-scales",
                "0",
            ]
        )
        == 0
    )
    capsys.readouterr()
    consistent_card = yaml.safe_load((consistent / "model.yaml").read_text())["calibration"]
    tried = consistent_card["drive_calibration"]["candidates"]
    delta = yaml.safe_load((consistent / "model.yaml").read_text())["hyperparameters"]["test_delta"]
    over = {label: c for label, c in tried.items() if c.get("corrections_over_span")}
    assert {c["span"] for c in over.values()} == {s for s in (3, 6) if s > delta}
    assert all(label.endswith(", corrections over the span") for label in over)
    assert len(tried) == len(plain) + len(over)  # the others as without the flags (0: no debiased nor rescaled ones)
    assert not any(c.get("vo_bias_windows") for c in tried.values())
    chosen = select_fusion({label: list(c["per_drive"].values()) for label, c in tried.items()}, harm_tolerance=0.05)
    if chosen is not None and tried[chosen].get("corrections_over_span"):
        assert len(consistent_card["correction_scale"]) == 6 and min(consistent_card["correction_scale"]) > 0.0
    else:
        assert "correction_scale" not in consistent_card
    # a new residual without drives: what the drives chose with the old one (axes, mean removal) goes with it
    stale = yaml.safe_load((drove / "model.yaml").read_text())
    stale["calibration"]["remove_mean"] = True
    (drove / "model.yaml").write_text(yaml.safe_dump(stale))
    assert main(["dpc-net", "calibrate", "--model", str(drove), "--corpus", str(corpus)]) == 0
    capsys.readouterr()
    recalibrated = yaml.safe_load((drove / "model.yaml").read_text())["calibration"]
    stale_keys = {"remove_mean", "fused_axes", "drive_calibration", "vo_scale", "correction_scale", "vo_bias_windows"}
    assert not (stale_keys | {"vo_rotation_scale"}) & set(recalibrated)
    assert recalibrated["mirrored"] is False
    # mirrored inference: calibrated in that mode, and the corrections follow the card
    from pvo_core.trajectory import read_kitti_poses
    from pvo_pseudosensors.dpc_net.data import vo_poses
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net, predict_corrections
    from pvo_pseudosensors.learning import Source

    mirrored = tmp_path / "mirrored"
    shutil.copytree(drove, mirrored)
    assert main(["dpc-net", "calibrate", "--model", str(mirrored), "--corpus", str(corpus), "--mirrored"]) == 0
    assert "11 validation windows of 1 sequences, each also predicted through the mirror" in capsys.readouterr().out
    # validation splits joined (a corpus and its mirror): every corpus's windows, each corpus named in the card
    other = tmp_path / "other-corpus"
    shutil.copytree(corpus, other, ignore=shutil.ignore_patterns(".cache"))
    joined = ["dpc-net", "calibrate", "--model", str(drove), "--corpus", str(corpus), "--corpus", str(other)]
    assert main(joined) == 0
    assert "22 validation windows of 2 sequences" in capsys.readouterr().out
    assert yaml.safe_load((drove / "model.yaml").read_text())["calibration"]["residual"]["corpus"] == [str(corpus), str(other)]
    mirrored_card = yaml.safe_load((mirrored / "model.yaml").read_text())["calibration"]
    assert mirrored_card["mirrored"] is True and mirrored_card["residual_covariance"] != recalibrated["residual_covariance"]
    vo = vo_poses(Source(corpus / "0002", "0002"), None)
    assert len(vo) == len(read_kitti_poses(corpus / "0002" / "poses.txt"))
    as_is, through = (predict_corrections(*load_dpc_net(m), corpus / "0002", vo) for m in (drove, mirrored))
    assert np.array_equal(as_is.last, through.last) and 1e-9 < np.abs(as_is.transforms - through.transforms).max() < 0.1
    assert main([*calibrate, "--drives", str(tmp_path / "nowhere")]) == 2
    assert "nowhere: not a sequence with poses.txt nor a folder of them" in capsys.readouterr().err
    assert main([*calibrate, "--drives", str(corpus / "0001"), str(corpus / "0001")]) == 2
    assert "two validation drives are named '0001'" in capsys.readouterr().err

    out = tmp_path / "corrected.txt"
    assert main(["dpc-net", "correct", str(corpus / "0002"), "--model", str(model), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "of 5 corrections fused" in printed  # windows 0-3, 3-6, ..., 12-15 of 17 frames
    assert f"VO covariances scaled by the card's calibration over {calibration['vo_span']} frames" in printed
    broken = tmp_path / "broken"
    shutil.copytree(model, broken)
    card = yaml.safe_load((broken / "model.yaml").read_text())
    card["calibration"]["vo_scale"] = [1.0, -2.0]
    (broken / "model.yaml").write_text(yaml.safe_dump(card))
    assert main(["dpc-net", "correct", str(corpus / "0002"), "--model", str(broken), "-o", str(tmp_path / "b.txt")]) == 2
    assert "the model card's vo_scale must be 6 positive numbers (x y z rx ry rz), got [1.0, -2.0]" in capsys.readouterr().err
    corrected = np.loadtxt(out)
    assert corrected.shape == (17, 12) and np.all(np.isfinite(corrected))

    corrections = tmp_path / "corrections.csv"
    vo = tmp_path / "corrected_vo.txt"
    assert main(["dpc-net", "predict", str(corpus / "0002"), "--vo", str(vo), "--model", str(model), "-o", str(corrections)]) == 0
    lines = corrections.read_text().splitlines()
    assert lines[0].startswith("frame_first,frame_last,t00") and len(lines) == 6 and lines[1].startswith("0,3,")

    overwritten = tmp_path / "overwritten.txt"
    assert (
        main(["dpc-net", "correct", str(corpus / "0002"), "--model", str(model), "-o", str(overwritten), "--method", "overwrite"])
        == 0
    )
    assert "5 poses overwritten" in capsys.readouterr().out
    np.testing.assert_allclose(np.loadtxt(overwritten)[:3], np.loadtxt(vo)[:3], atol=1e-9)  # the VO inside the first window
    assert not np.allclose(np.loadtxt(overwritten)[3], np.loadtxt(vo)[3])

    # the model's rig is 5 % off KITTI's focal length; the training clip of another rig is refused, or flagged when forced
    other = ["dpc-net", "correct", str(corpus / "0003"), "--model", str(model), "-o", str(tmp_path / "other.txt")]
    assert main(other) == 2
    assert "0003: not this DPC-Net model's rig: calib.txt's focal" in capsys.readouterr().err
    assert main([*other, "--any-rig"]) == 0
    assert "warning:" in capsys.readouterr().err

    capsys.readouterr()
    evaluate = ["dpc-net", "eval", "--gt", str(corpus / "0002" / "poses.txt"), "--est", str(out), "--vo", str(vo)]
    assert main([*evaluate, "--json", str(tmp_path / "m")]) == 0
    printed = capsys.readouterr().out
    assert "corrected" in printed and "VO" in printed and "m-ATE" in printed
    figures = yaml.safe_load((tmp_path / "m" / "metrics.json").read_text())["figures"]
    assert figures["VO.m_ate_trans"] > 0.0 and np.isfinite(figures["corrected.m_ate_trans"])


def test_a_model_for_another_vo_is_corrected_on_that_vo(corpus: Path, tmp_path: Path, capsys) -> None:
    """`train --vo-settings` learns another VO's errors; the card records that VO's every setting, and the tools run
    it (not the defaults): the trajectory `correct` starts from is that VO's."""
    from pvo_core.readers import KittiSequence
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig, from_flat
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net
    from pvo_tools.dpc import correct_sequence, model_vo

    model = tmp_path / "model"
    train = ["dpc-net", "train", "--corpus", str(corpus), "-o", str(model), "--epochs", "1", "--batch-size", "8", "-q"]
    assert main([*train, "--threads", "1", *TINY, "--vo-settings", "ransac.inlier_threshold=9 tracker.window=11"]) == 0
    capsys.readouterr()
    network, card = load_dpc_net(model)
    settings = card.input["rig"]["vo_settings"]
    assert settings["ransac.inlier_threshold"] == 9.0 and settings["tracker.window"] == 11
    assert settings["solver.loss"] == VOConfig().solver.loss  # every setting, not only the changed ones
    other = from_flat({"ransac.inlier_threshold": 9.0, "tracker.window": 11})
    assert model_vo(card) == other
    assert sorted(DPCNetConfig.from_card(card).vo_settings.split()) == ["ransac.inlier_threshold=9.0", "tracker.window=11"]
    sequence = corpus / "0002"
    corrected = correct_sequence(sequence, network, card, "overwrite")
    on_other = run_sequence(KittiSequence(sequence, rate_hz=10.0), other).poses
    on_default = run_sequence(KittiSequence(sequence, rate_hz=10.0), VOConfig()).poses
    assert np.allclose(corrected.vo, on_other) and not np.allclose(corrected.vo, on_default)
    assert not any("VO" in warning for warning in corrected.warnings)  # the card's own VO: nothing to flag
    assert main([*train, "--vo-settings", "ransac.no_such=1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "vo_settings 'ransac.no_such=1'" in err and "ransac.no_such" in err
    assert "left out" not in err  # refused before any data is read


def test_the_demo_runs_the_vo_a_dpc_net_model_learned(tmp_path: Path, capsys) -> None:
    """`pvo demo` gives stereo_vo the settings in which the DPC-Net model's VO differs from the defaults, says so,
    and a card naming a setting the VO does not have is one line naming the model."""
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_tools.commands.demo import dpc_net_vo
    from pvo_tools.errors import PvoError

    model = tmp_path / "model"
    shutil.copytree(resolve_model("dpc_net_clean"), model)
    card = yaml.safe_load((model / "model.yaml").read_text())
    card["input"]["rig"]["vo_settings"] |= {"ransac.inlier_threshold": 9.0, "tracker.window": 13}
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    assert dpc_net_vo(str(model)) == {"ransac.inlier_threshold": 9.0, "tracker.window": 13}
    assert "stereo_vo runs the VO that" in capsys.readouterr().err
    card["input"]["rig"]["vo_settings"]["tracker.no_such"] = 1
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(PvoError, match="tracker.no_such"):
        dpc_net_vo(str(model))


def test_the_demo_weighs_the_corrections_as_the_card_does(tmp_path: Path, capsys) -> None:
    """With a card that fuses some axis, `pvo demo` gives the fusion node the card's VO covariance scales (what
    `pvo dpc-net correct` weighs with) and, where the card chose it, the VO's bias learned from the corrections; the
    fusion config accepts them; a card that fuses nothing changes nothing; a broken scale is one line naming the model."""
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_tools.commands.demo import dpc_net_fusion
    from pvo_tools.errors import PvoError

    from pvo_fusion.config import from_flat as fusion_from_flat

    # a card of its own (the shipped ones' weighings may change): one that fuses two axes at known VO scales
    model = tmp_path / "model"
    shutil.copytree(resolve_model("dpc_net_clean"), model)
    card = yaml.safe_load((model / "model.yaml").read_text())
    scales = [2.0, 0.5, 3.0, 0.25, 4.0, 1.5]
    card["calibration"] |= {"fused_axes": ["z", "ry"], "vo_scale": scales, "vo_static_covariance": np.eye(6).tolist()}
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    parameters = dpc_net_fusion(str(model))
    assert parameters == {"inputs.vo.covariance_scale": pytest.approx(scales)}
    assert "scaled by its card (2 0.5 3 0.25 4 1.5)" in capsys.readouterr().err
    config = fusion_from_flat(parameters)
    assert config.inputs.vo.covariance_scale == pytest.approx(tuple(scales))
    # the VO's translation bias learned from the corrections, where the card chose that
    card["calibration"]["vo_bias_windows"] = 30.0
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    parameters = dpc_net_fusion(str(model))
    assert parameters == {"inputs.vo.covariance_scale": pytest.approx(scales), "inputs.correction.vo_bias_windows": 30.0}
    assert "the VO's translation bias learned from the corrections (over ~30)" in capsys.readouterr().err
    assert fusion_from_flat(parameters).inputs.correction.vo_bias_windows == 30.0
    # and the scale of its turns
    card["calibration"]["vo_rotation_scale"] = {"windows": 1000.0, "gain": 0.75}
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    parameters = dpc_net_fusion(str(model))
    assert parameters["inputs.correction.vo_rotation_scale_windows"] == 1000.0
    assert parameters["inputs.correction.vo_rotation_scale_gain"] == 0.75
    assert "its turns rescaled by 0.75 of the scale they teach (over ~1000)" in capsys.readouterr().err
    assert fusion_from_flat(parameters).inputs.correction.vo_rotation_scale_gain == 0.75
    card["calibration"]["vo_rotation_scale"] = {"windows": 1000.0, "gain": 2.0}
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(PvoError, match="vo_rotation_scale needs windows > 0 and a gain in \\(0, 1\\], got"):
        dpc_net_fusion(str(model))
    card["calibration"].pop("vo_rotation_scale")
    card["calibration"]["vo_translation_scale_windows"] = 100.0  # and the length of its steps
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    parameters = dpc_net_fusion(str(model))
    assert parameters["inputs.correction.vo_translation_scale_windows"] == 100.0
    assert "the VO's steps rescaled by the scale the corrections teach (over ~100)" in capsys.readouterr().err
    card["calibration"]["vo_translation_scale_windows"] = float("nan")
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(PvoError, match="vo_translation_scale_windows must be a number of corrections > 0, got nan"):
        dpc_net_fusion(str(model))
    card["calibration"].pop("vo_translation_scale_windows")
    card["calibration"]["vo_bias_windows"] = -1.0
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(PvoError, match="vo_bias_windows must be a number of corrections >= 0, got -1.0"):
        dpc_net_fusion(str(model))
    card["calibration"].pop("vo_bias_windows")
    card["calibration"]["fused_axes"] = []  # fuses nothing: the VO keeps its own covariances, scales or not
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    assert dpc_net_fusion(str(model)) == {} and capsys.readouterr().err == ""

    card["calibration"] |= {"fused_axes": ["z"], "vo_scale": [1.0, -2.0]}
    (model / "model.yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(PvoError, match="vo_scale must be 6 positive numbers"):
        dpc_net_fusion(str(model))


def test_bad_inputs_are_one_line(corpus: Path, tmp_path: Path, capsys) -> None:
    missing = ["dpc-net", "correct", str(corpus / "0002"), "--model", str(tmp_path / "none"), "-o", str(tmp_path / "x.txt")]
    assert main(missing) == 2
    assert "model directory not found" in capsys.readouterr().err
    assert main(["dpc-net", "train", "--corpus", str(corpus), "-o", str(tmp_path / "m"), *TINY, "--variant", "scale"]) == 2
    assert "unknown variant 'scale'" in capsys.readouterr().err


def test_the_experiment_miscalibrates_a_copy_and_tabulates_changes(corpus: Path, tmp_path: Path) -> None:
    from pvo_core.readers.kitti import read_kitti_calibration
    from pvo_pseudosensors.dpc_net.rig import sequence_rig
    from pvo_tools.dpc import miscalibrate
    from pvo_tools.experiments.dpc_net import table

    source = tmp_path / "source"
    source.mkdir()
    for name in ("image_0", "image_1", "poses.txt", "calib.txt"):
        (source / name).symlink_to((corpus / "0002" / name).resolve())
    (source / "times.txt").write_text("".join(f"{0.1 * k:.1f}\n" for k in range(17)))
    (source / "sim.yaml").write_text(yaml.safe_dump({"config": {"degradations": {"distortion": 0.0, "focal_scale": 1.0}}}))
    copy = miscalibrate(source, tmp_path / "copy", 1.03)
    before, after = read_kitti_calibration(source / "calib.txt"), read_kitti_calibration(copy / "calib.txt")
    np.testing.assert_allclose(after["P1"][0, [0, 3]], 1.03 * before["P1"][0, [0, 3]])
    assert after["P0"][1, 1] == pytest.approx(1.03 * before["P0"][1, 1]) and after["P0"][0, 2] == before["P0"][0, 2]
    rig = sequence_rig(copy)
    assert rig.focal_scale == 1.03 and rig.lens == () and (copy / "image_0").resolve() == (corpus / "0002" / "image_0").resolve()

    row = {"m_ate_trans": 10.0, "m_ate_rot_deg": 2.0, "seg_trans_percent": 5.0, "seg_rot_deg_per_m": 0.01}
    results = {
        "a": {"S-VO": row, "+ lens fusion online": {k: v / 2 for k, v in row.items()}},
        "b": {"S-VO": row, "+ lens fusion online": {k: v * 1.5 for k, v in row.items()}},
    }
    figures: dict[str, float] = {}
    lines = table(results, figures, "t")
    assert figures["t.lens_fusion_online.m_ate_trans_change"] == pytest.approx(0.0)  # -50 % and +50 %: mean 0
    assert "| + lens fusion online | +0.0 % |" in "\n".join(lines)


def test_a_biased_rig_is_read_beside_the_clean_rigs_vo_on_the_same_drive(pvo_data: Path, tmp_path: Path) -> None:
    from pvo_core.trajectory import read_kitti_poses
    from pvo_tools.dpc import vo_run
    from pvo_tools.experiments.dpc_net import CLEAN_REFERENCE, evaluate_rig

    clip = pvo_data / "kitti" / "sequences" / "06"
    write_clip(clip, tmp_path / "clean" / "06", range(0, 30), focal_scale=1.0)
    write_clip(clip, tmp_path / "calib" / "06", range(0, 30), focal_scale=1.05)
    results, trajectories = evaluate_rig(
        "t", [tmp_path / "calib" / "06"], {}, lambda _: None, {}, clean_folders=[tmp_path / "clean" / "06"]
    )
    assert list(results["06"]) == ["S-VO", CLEAN_REFERENCE]
    truth = read_kitti_poses(tmp_path / "calib" / "06" / "poses.txt")
    np.testing.assert_allclose(trajectories["06"][CLEAN_REFERENCE], truth[0] @ vo_run(tmp_path / "clean" / "06")[0].poses)
    # the focal-length error stretches the calib rig's path: the reference is the true calibration's, not a copy
    assert results["06"]["S-VO"]["m_ate_trans"] > 1.5 * results["06"][CLEAN_REFERENCE]["m_ate_trans"]

    write_clip(clip, tmp_path / "other" / "06", range(10, 40), focal_scale=1.0)
    with pytest.raises(ValueError, match="drives another path than .*calib/06: no clean-rig reference for it"):
        evaluate_rig("t", [tmp_path / "calib" / "06"], {}, lambda _: None, {}, clean_folders=[tmp_path / "other" / "06"])


def test_a_fusion_is_chosen_only_where_it_harmed_no_drive_beyond_the_tolerance() -> None:
    changes = {
        "both lower everywhere": [[-0.2, -0.1], [-0.1, -0.05]],
        "lower on average, 1 % worse on one drive": [[-0.9, -0.9], [0.01, -0.2]],
        "lower on average, 6 % worse on one drive": [[-0.95, -0.95], [-0.2, 0.06]],
        "lower everywhere, less": [[-0.05, -0.01], [-0.02, -0.01]],
    }
    # the default: no drive 5 % worse or more (the no-harm bound), then the lowest mean sum
    assert select_fusion(changes) == "lower on average, 1 % worse on one drive"
    # tolerance 0: every drive lowered on both m-ATEs (unchanged is not lowered)
    strict = {k: v for k, v in changes.items() if k != "both lower everywhere"}
    assert select_fusion(changes, harm_tolerance=0.0) == "both lower everywhere"
    assert select_fusion(strict, harm_tolerance=0.0) == "lower everywhere, less"
    assert select_fusion({"worse on one drive": [[-0.5, -0.5], [-0.5, 0.0]]}, harm_tolerance=0.0) is None
    assert select_fusion({"worse on one drive": [[-0.5, -0.5], [-0.5, 0.0]]}) == "worse on one drive"
    # within the tolerance on every drive but not lower on average: nothing to gain, nothing fused
    assert select_fusion({"slightly worse": [[0.01, -0.01], [0.02, 0.0]]}) is None
    assert select_fusion({"6 % worse": changes["lower on average, 6 % worse on one drive"]}) is None
    assert select_fusion({}) is None
    assert worst_change(changes["lower on average, 6 % worse on one drive"]) == 0.06
    with pytest.raises(ValueError, match="the harm tolerance must be a finite fraction >= 0, got -0.1"):
        select_fusion(changes, harm_tolerance=-0.1)


def test_the_nearest_fusion_lowered_the_most_drives_and_names_the_others() -> None:
    def candidate(*per_drive: list[float]) -> dict:
        changes = np.asarray(per_drive)
        return {"per_drive": {f"d{i}": list(c) for i, c in enumerate(per_drive)}, "mean": list(changes.mean(axis=0))}

    candidates = {
        "large mean, two drives worse": candidate([-0.9, -0.9], [0.1, -0.2], [-0.5, 0.3]),
        "one drive worse": candidate([-0.1, -0.1], [-0.1, -0.1], [-0.2, 0.05]),
        "one drive worse, lower on average": candidate([-0.3, -0.2], [-0.2, -0.1], [-0.2, 0.0]),
    }
    assert nearest_fusion(candidates) == ("one drive worse, lower on average", {"d2": [-0.2, 0.0]})  # unchanged: not lowered
    assert describe_nearest(candidates) == (
        "nearest: one drive worse, lower on average, 2 of 3 drives lowered; "
        "not lowered (m-ATE translation / rotation): d2 -20.0 / +0.0 %"
    )
    assert nearest_fusion({}) is None and describe_nearest({}) is None


def test_the_report_says_how_a_card_weighs_its_corrections() -> None:
    from types import SimpleNamespace

    from pvo_tools.experiments.dpc_net import fusion_summary

    chosen = {"drive_calibration": {"drives": ["v/03", "v/04"]}, "fused_axes": ["x", "rz"], "vo_span": 250}
    assert fusion_summary(SimpleNamespace(calibration=chosen)) == (
        "chosen on the validation drives 03, 04: axes x rz, VO span 250 frames"
    )
    assert fusion_summary(SimpleNamespace(calibration=chosen | {"remove_mean": True})).endswith(
        "VO span 250 frames; the validation split's mean residual removed from the corrections"
    )
    assert fusion_summary(SimpleNamespace(calibration=chosen | {"vo_bias_windows": 30.0})).endswith(
        "VO span 250 frames; the VO's translation bias learned from the corrections (over ~30)"
    )
    stepped = chosen | {"vo_translation_scale_windows": 100.0}
    assert fusion_summary(SimpleNamespace(calibration=stepped)).endswith(
        "VO span 250 frames; the VO's steps rescaled by the scale the corrections teach (over ~100)"
    )
    rescaled = chosen | {"vo_bias_windows": 10.0, "vo_rotation_scale": {"windows": 1000.0, "gain": 0.5}}
    assert fusion_summary(SimpleNamespace(calibration=rescaled)).endswith(
        "(over ~10); its turns rescaled by 0.5 of the scale they teach (over ~1000)"
    )
    refused = chosen | {"fused_axes": []}
    # a card from before the harm tolerance had every drive lowered; a newer one says its tolerance
    assert fusion_summary(SimpleNamespace(calibration=refused)).endswith("nothing fused (no choice lowered every drive's m-ATE)")
    tolerant = refused | {"drive_calibration": {"drives": ["v/03"], "harm_tolerance": 0.05}}
    assert fusion_summary(SimpleNamespace(calibration=tolerant)).endswith(
        "nothing fused (no choice lowered the mean m-ATE and kept every drive within +5 %)"
    )


def test_a_miscalibrated_drive_links_what_the_calibration_does_not_change(tmp_path: Path) -> None:
    """The focal-length rig shares the clean drive's images, truth and sensors (the sun, for Sun-BCNN's fusion on it)
    and scales calib.txt's focal length, the -f b term with it."""
    from pvo_core.readers.kitti import read_kitti_calibration

    from pvo_tools import dpc

    source = tmp_path / "clean"
    (source / "image_0").mkdir(parents=True)
    (source / "image_1").mkdir()
    for name in ("poses.txt", "times.txt", "sun.csv", "gps.csv"):
        (source / name).write_text(f"{name}\n")
    p0 = "7.0e+02 0 3.1e+02 0 0 7.0e+02 9.4e+01 0 0 0 1 0"
    p1 = "7.0e+02 0 3.1e+02 -3.78e+02 0 7.0e+02 9.4e+01 0 0 0 1 0"
    (source / "calib.txt").write_text(f"P0: {p0}\nP1: {p1}\n")
    (source / "sim.yaml").write_text("config:\n  degradations:\n    focal_scale: 1.0\n")
    out = dpc.miscalibrate(source, tmp_path / "calib", 1.03)
    for name in ("image_0", "image_1", "poses.txt", "times.txt", "sun.csv", "gps.csv"):
        assert (out / name).is_symlink() and (out / name).resolve() == (source / name).resolve()
    assert not (out / "imu.csv").exists()  # the clean drive has none
    calibration = read_kitti_calibration(out / "calib.txt")
    assert calibration["P0"].reshape(3, 4)[0, 0] == pytest.approx(721.0)
    assert calibration["P1"].reshape(3, 4)[0, 3] == pytest.approx(-378.0 * 1.03)


def test_drives_refuses_a_short_test_drive(tmp_path: Path, capsys) -> None:
    assert main(["dpc-net", "drives", str(tmp_path / "d"), "--split", "test", "--frames", "50"]) == 2
    assert "--frames must be >= 100 (segment errors need 100 m and more), got 50" in capsys.readouterr().err


def test_drives_render_only_the_rigs_asked_for(tmp_path: Path, monkeypatch) -> None:
    import subprocess

    from pvo_tools import dpc

    commands: list[list[str]] = []

    def fake_render(command: list[str], **_: object) -> subprocess.CompletedProcess:
        commands.append(command)
        return subprocess.CompletedProcess(command, 0, "", "")

    monkeypatch.setattr(dpc.subprocess, "run", fake_render)
    drives = dpc.VALIDATION_DRIVES[:2]
    folders = dpc.render_drives(drives, Path("data"), tmp_path, jobs=1, say=lambda _: None, rigs=("lens",))
    assert folders == {"lens": [tmp_path / "lens" / d.name for d in drives]}
    assert len(commands) == 2 and all("--distortion" in c for c in commands)
    assert [c[c.index("sim") + 1] for c in commands] == [str(tmp_path / "lens" / d.name) for d in drives]
    with pytest.raises(ValueError, match="rigs must be some of clean, lens, calib, got fisheye"):
        dpc.render_drives(drives, Path("data"), tmp_path, rigs=("fisheye",))


def test_drives_through_another_world_keep_their_motion_and_never_mix_worlds(tmp_path: Path, monkeypatch) -> None:
    """``--world K``: every drive's seed K strides up, its motion, frames and mirrors kept; a folder rendered
    through another world is one line, not kept as this world's and not overwritten."""
    import subprocess

    from pvo_tools import dpc

    commands: list[list[str]] = []

    def fake_render(command: list[str], **_: object) -> subprocess.CompletedProcess:
        commands.append(command)
        folder = Path(command[command.index("sim") + 1])
        _fake_sequence(folder)
        meta = yaml.safe_load((folder / "sim.yaml").read_text())
        meta["config"]["seed"] = int(command[command.index("--seed") + 1])
        (folder / "sim.yaml").write_text(yaml.safe_dump(meta))
        return subprocess.CompletedProcess(command, 0, "", "")

    monkeypatch.setattr(dpc.subprocess, "run", fake_render)
    own, other = dpc.VALIDATION_DRIVES[:1], dpc.in_world(dpc.VALIDATION_DRIVES[:1], 2)
    assert other[0].seed == own[0].seed + 2 * dpc.WORLD_SEED_STRIDE
    assert [(d.drive, d.start, d.frames, d.heading, d.mirror_of) for d in dpc.in_world(dpc.VALIDATION_DRIVES, 1)] == [
        (d.drive, d.start, d.frames, d.heading, d.mirror_of) for d in dpc.VALIDATION_DRIVES
    ]
    dpc.render_drives(own, Path("data"), tmp_path / "w0", jobs=1, say=lambda _: None, rigs=("lens",))
    dpc.render_drives(own, Path("data"), tmp_path / "w0", jobs=1, say=lambda _: None, rigs=("lens",))
    assert len(commands) == 1  # kept the second time
    seeds = f"seed {own[0].seed}, not {other[0].seed}"
    with pytest.raises(ValueError, match=rf"w0/lens/{own[0].name}: rendered through another world \({seeds}\)"):
        dpc.render_drives(other, Path("data"), tmp_path / "w0", jobs=1, say=lambda _: None, rigs=("lens",))
    assert len(commands) == 1
    with pytest.raises(ValueError, match="--world must be >= 0, got -1"):
        dpc.in_world(own, -1)


def test_drives_refuses_an_unknown_rig(tmp_path: Path, capsys) -> None:
    with pytest.raises(SystemExit):
        main(["dpc-net", "drives", str(tmp_path / "d"), "--rigs", "lens,fisheye"])
    assert "unknown rig(s) fisheye: choose from clean, lens, calib" in capsys.readouterr().err


def _fake_sequence(folder: Path, frames: int = 3, width: int = 40, height: int = 20) -> None:
    """What `pvo sim` leaves: images (noise), a centred calib.txt, poses moving forward and right, times."""
    import cv2

    rng = np.random.default_rng(len(folder.name))
    for side in ("image_0", "image_1"):
        (folder / side).mkdir(parents=True)
        for k in range(frames):
            cv2.imwrite(str(folder / side / f"{k:06d}.png"), rng.integers(0, 255, (height, width), dtype=np.uint8))
    f, cx, cy = 30.0, (width - 1) / 2, (height - 1) / 2
    rows = [[f, 0, cx, 0, 0, f, cy, 0, 0, 0, 1, 0], [f, 0, cx, -f * 0.54, 0, f, cy, 0, 0, 0, 1, 0]]
    (folder / "calib.txt").write_text("".join(f"P{i}: " + " ".join(f"{v:.12e}" for v in r) + "\n" for i, r in enumerate(rows)))
    poses = np.tile(np.eye(4)[:3].reshape(12), (frames, 1))
    poses[:, 3], poses[:, 11] = 0.2 * np.arange(frames), np.arange(frames)
    np.savetxt(folder / "poses.txt", poses)
    (folder / "times.txt").write_text("".join(f"{0.1 * k:e}\n" for k in range(frames)))
    from pvo_sim.render import RENDERER_REVISION

    meta = {  # a sunny drive (the default sky): drawn by this renderer's revision
        "renderer_revision": RENDERER_REVISION,
        "world_T_cam0": np.eye(4).tolist(),
        "config": {"baseline": 0.54, "degradations": {"moving_vehicles": 0}},
    }
    (folder / "sim.yaml").write_text(yaml.safe_dump(meta))


def test_mirrored_validation_drives_are_their_drives_through_a_mirror(tmp_path: Path, monkeypatch) -> None:
    import subprocess

    import cv2

    from pvo_tools import dpc

    rendered: list[str] = []

    def fake_render(command: list[str], **_: object) -> subprocess.CompletedProcess:
        folder = Path(command[command.index("sim") + 1])
        rendered.append(folder.name)
        if folder.exists():
            shutil.rmtree(folder)
        _fake_sequence(folder)
        return subprocess.CompletedProcess(command, 0, "", "")

    monkeypatch.setattr(dpc.subprocess, "run", fake_render)
    # every validation drive turns right on the whole; each has its mirror, made from it and not rendered
    mirrored = [d for d in dpc.VALIDATION_DRIVES if d.mirror_of]
    assert sorted(d.mirror_of for d in mirrored) == sorted(d.name for d in dpc.VALIDATION_DRIVES if not d.mirror_of)
    drives = (dpc.VALIDATION_DRIVES[0], next(d for d in mirrored if d.mirror_of == dpc.VALIDATION_DRIVES[0].name))
    folders = dpc.render_drives(drives, Path("data"), tmp_path, jobs=1, say=lambda _: None, rigs=("calib",))
    assert rendered == ["10a"]
    assert folders == {"calib": [tmp_path / "calib" / "10a", tmp_path / "calib" / "10am"]}
    source, mirror = tmp_path / "clean" / "10a", tmp_path / "calib" / "10am"
    left = cv2.imread(str(source / "image_1" / "000001.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(cv2.imread(str(mirror / "image_0" / "000001.png"), cv2.IMREAD_UNCHANGED), left[:, ::-1])
    assert np.loadtxt(mirror / "poses.txt")[2, 3] == pytest.approx(-0.4)  # drifting right becomes drifting left
    assert "3.09" in (mirror / "calib.txt").read_text().split()[1]  # the calib rig's focal length, 30 x 1.03
    # an unchanged source: its mirror is kept; a source rendered again is mirrored again
    made = tmp_path / "clean" / "10am" / "poses.txt"
    before = made.stat().st_mtime_ns
    dpc.render_drives(drives, Path("data"), tmp_path, jobs=1, say=lambda _: None, rigs=("calib",))
    assert rendered == ["10a"] and made.stat().st_mtime_ns == before
    os.utime(source / "poses.txt", ns=(before + 10**9, before + 10**9))
    dpc.render_drives(drives, Path("data"), tmp_path, jobs=1, say=lambda _: None, rigs=("calib",))
    assert made.stat().st_mtime_ns > before
    with pytest.raises(ValueError, match="drive 10am mirrors 10a, which is not among the drives rendered"):
        dpc.render_drives(drives[1:], Path("data"), tmp_path, say=lambda _: None, rigs=("calib",))


def test_the_experiment_renders_its_test_drives_through_another_world(tmp_path: Path, monkeypatch, capsys) -> None:
    """``--world K``: the same test drives (motion, start, frames) with the scenery drawn from another seed, a fresh
    test set; a negative world is refused in one line before anything is loaded or rendered."""
    from pvo_tools.dpc import TEST_DRIVES, WORLD_SEED_STRIDE
    from pvo_tools.experiments import dpc_net as experiment

    asked: list = []
    monkeypatch.setattr(experiment, "render_drives", lambda drives, *rest: asked.append(drives) or {})
    experiment.render_sequences(tmp_path, 2, 1000, tmp_path / "out", 1, print, ("clean",), 3)
    experiment.render_sequences(tmp_path, 2, 1000, tmp_path / "out", 1, print, ("clean",))
    world3, own = asked
    assert [d.seed for d in own] == [d.seed for d in TEST_DRIVES[:2]]
    assert [d.seed for d in world3] == [d.seed + 3 * WORLD_SEED_STRIDE for d in TEST_DRIVES[:2]]
    assert [(d.drive, d.start, d.heading) for d in world3] == [(d.drive, d.start, d.heading) for d in TEST_DRIVES[:2]]

    assert main(["experiment", "dpc-net", "--world", "-1", "-o", str(tmp_path / "x")]) != 0
    assert "--world must be >= 0, got -1" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


def test_corrections_drifting_together_are_made_consistent_over_the_span() -> None:
    """The corrected chain's scales over a span (:func:`pvo_tools.dpc.correction_calibration`): corrections whose
    error is white noise at their covariance stay near 1 at any span; the same noise plus a bias shared by every
    window grows with the span, as the VO's does."""
    from types import SimpleNamespace

    from pvo_core.lie import se3_exp
    from pvo_tools.dpc import correction_calibration, correction_sequence

    rng = np.random.default_rng(0)
    delta, windows = 3, 600
    sigma = np.array([0.02, 0.01, 0.05, 1e-3, 2e-3, 1e-3])
    covariance = np.diag(sigma**2)
    step = np.eye(4)
    step[:3, 3] = [0.0, 0.0, 3.0]  # 3 m forward per window
    truth = np.stack([np.linalg.matrix_power(np.linalg.inv(step), k) for k in range(windows + 1)])  # T_map,k
    predicted = SimpleNamespace(first=np.arange(windows) * delta, last=np.arange(1, windows + 1) * delta)
    frames = np.zeros((windows * delta + 1, 4, 4))
    frames[::delta] = truth  # the truth per frame, only the windows' boundaries read

    def chain(bias: np.ndarray) -> object:
        noise = rng.normal(size=(windows, 6)) * sigma + bias
        transforms = np.stack([se3_exp(e) @ step for e in noise])
        return correction_sequence("d", frames, predicted, transforms, covariance)

    white = [chain(np.zeros(6)) for _ in range(2)]
    one, long = correction_calibration(white, 3, delta), correction_calibration(white, 120, delta)
    assert np.allclose(one, 1.0, atol=0.2) and np.allclose(long, 1.0, atol=0.5)
    biased = [chain(np.array([0.0, 0.0, 0.05, 0.0, 2e-3, 0.0])) for _ in range(2)]
    over_40 = correction_calibration(biased, 120, delta)  # 40 windows: the bias adds ~40 sigma^2 on z and ry
    # a yaw bias also swings the forward motion sideways (x); nothing moves the chain up or down (y)
    assert over_40[2] > 20.0 and over_40[4] > 20.0 and over_40[0] > 20.0 and over_40[1] < 3.0


def test_correct_warns_when_the_gate_kept_the_corrections_out(tmp_path: Path, capsys, monkeypatch) -> None:
    """`pvo dpc-net correct` says so when the fusion's gate took none of the corrections for 10 s or more on end (a
    VO and corrections that disagree for good: the estimate is the VO's there), and not when it did not."""
    import pvo_tools.dpc as dpc
    from pvo_fusion.graph import GATED_WARNING_SECONDS

    poses = np.tile(np.eye(4), (5, 1, 1))
    for gated, warned in ((GATED_WARNING_SECONDS + 2.6, True), (GATED_WARNING_SECONDS - 0.1, False)):
        result = dpc.CorrectedSequence(poses, poses, poses, dpc_corrections(), 1, [], gated)
        monkeypatch.setattr(dpc, "correct_sequence", lambda *args, result=result, **kwargs: result)
        out = tmp_path / "corrected.txt"
        assert main(["dpc-net", "correct", str(tmp_path), "--model", "dpc_net", "-o", str(out)]) == 0
        err = capsys.readouterr().err
        assert (f"took none of the corrections for {gated:.1f} s on end" in err) == warned, err
        assert out.is_file()  # the estimate is written either way


def dpc_corrections():
    from pvo_pseudosensors.dpc_net.infer import Corrections

    return Corrections(np.array([0]), np.array([4]), np.eye(4)[None], np.eye(6)[None])
