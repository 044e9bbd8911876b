"""`pvo probe calibrate` and `pvo vo calibrate`: the VO (with a PROBE model, or the default one) over a corpus split,
its per-axis covariance scales recorded with that VO (the PROBE model's card, or a calibration file of its own), and
the learned graph (`pvo demo`, the soak, the faults) fusing the VO with them only where it runs that VO."""

from __future__ import annotations

import hashlib
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_tools.cli import main


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> Path:
    """Two rendered urban sequences in the validation split, one in training."""
    root = tmp_path_factory.mktemp("corpus")
    entries = []
    for i, split in enumerate(("validation", "validation", "train")):
        name = f"{i:04d}"
        assert main(["sim", str(root / name), "--frames", "12", "--seed", str(i), "--quiet"]) == 0
        entries.append(
            {"name": name, "split": split, "preset": "urban", "sha256": hashlib.sha256(name.encode()).hexdigest(), "config": {}}
        )
    (root / "manifest.yaml").write_text(yaml.safe_dump({"corpus": {"sequences": 3}, "sequences": entries}))
    return root


@pytest.fixture
def probe_copy(tmp_path: Path) -> Path:
    from pvo_frontend.probe.model import resolve_model

    copy = tmp_path / "probe"
    shutil.copytree(resolve_model("probe_sim"), copy)
    return copy


def independent_scales(corpus: Path, model: Path | None, names: list[str]) -> np.ndarray:
    """mean over the frame pairs of e_i^2 / Sigma_ii, e = Log(T_vo T_true^-1) (ROS order), written out here."""
    from pvo_core.lie import se3_inverse, se3_log
    from pvo_core.readers import KittiSequence
    from pvo_core.trajectory import read_kitti_poses
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import from_flat

    ratios = []
    for name in names:
        run = run_sequence(KittiSequence(corpus / name), from_flat({"probe.model": str(model)} if model else {}))
        relative = run.relative()
        truth = read_kitti_poses(corpus / name / "poses.txt")
        for k, (motion, covariance) in enumerate(zip(relative["transforms"], relative["covariances"], strict=True), 1):
            error = se3_log(motion @ se3_inverse(se3_inverse(truth[k]) @ truth[k - 1]))
            ratios.append(error**2 / np.diag(covariance))
    return np.mean(ratios, axis=0)


def test_calibrate_records_the_vos_covariance_scales_in_the_card(corpus: Path, probe_copy: Path, capsys) -> None:
    before = yaml.safe_load((probe_copy / "model.yaml").read_text())
    assert main(["probe", "calibrate", "--model", str(probe_copy), "--corpus", str(corpus)]) == 0
    out = capsys.readouterr().out
    assert "on 2 urban validation sequences" in out and "(22 frame pairs)" in out
    card = yaml.safe_load((probe_copy / "model.yaml").read_text())
    entry = card.pop("vo_calibration")
    assert card == before  # nothing else of the card changed
    np.testing.assert_allclose(entry["covariance_scale"], independent_scales(corpus, probe_copy, ["0000", "0001"]), rtol=1e-3)
    assert entry["sequences"] == 2 and entry["pairs"] == 22 and entry["corpus"]["split"] == "validation"
    assert entry["command"].startswith(f"pvo probe calibrate --model {probe_copy} --corpus {corpus}")
    assert entry["vo_settings"]["ransac.inlier_threshold"] == 4.0 and "probe.model" not in entry["vo_settings"]
    from pvo_frontend.probe.model import card_vo_covariance_scale

    assert card_vo_covariance_scale(probe_copy) == entry["covariance_scale"]


def test_the_learned_graph_fuses_the_vo_with_its_calibrated_covariance(probe_copy: Path, capsys) -> None:
    from pvo_frontend.probe.model import write_vo_calibration
    from pvo_tools.commands.demo import DemoSettings, learned_graph

    plain = learned_graph(DemoSettings(probe_model=str(probe_copy), dpc_net=False))
    assert "inputs.vo.covariance_scale" not in plain.fusion  # no calibration in the card: the VO's covariances as read
    write_vo_calibration(probe_copy, {"covariance_scale": [6.0, 3.0, 9.0, 2.0, 1.9, 1.7]})
    graph = learned_graph(DemoSettings(probe_model=str(probe_copy), dpc_net=False))
    assert graph.fusion["inputs.vo.covariance_scale"] == [6.0, 3.0, 9.0, 2.0, 1.9, 1.7]
    assert "fusion weighs the VO by its covariances scaled as" in capsys.readouterr().err
    # without PROBE the default VO's calibration speaks for it; none asked for, the covariances as read
    bare = learned_graph(DemoSettings(probe_model="", hydranet=False, dpc_net=False, vo_calibration=""))
    assert "inputs.vo.covariance_scale" not in bare.fusion
    # a calibration made with other VO settings (`pvo probe calibrate -p ...`) is not this graph's VO's: not applied
    from pvo_frontend.vo import from_flat
    from pvo_frontend.vo_calibration import recorded_settings

    other = recorded_settings(from_flat({"tracking.min_inliers": 30}))
    write_vo_calibration(probe_copy, {"covariance_scale": [6.0, 3.0, 9.0, 2.0, 1.9, 1.7], "vo_settings": other})
    capsys.readouterr()
    assert "inputs.vo.covariance_scale" not in learned_graph(DemoSettings(probe_model=str(probe_copy), dpc_net=False)).fusion
    assert "calibrated another VO (tracking.min_inliers 30 there" in capsys.readouterr().err
    # a DPC-Net card that fuses learned the scales for its own VO: its scales win
    lens = learned_graph(DemoSettings(probe_model=str(probe_copy), dpc_net_model="dpc_net"))
    assert lens.fusion["inputs.vo.covariance_scale"] != [6.0, 3.0, 9.0, 2.0, 1.9, 1.7]


def test_bad_calibration_input_is_one_line(corpus: Path, probe_copy: Path, tmp_path: Path, capsys) -> None:
    assert main(["probe", "calibrate", "--model", str(probe_copy), "--corpus", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "corpus manifest not found" in err
    assert main(["probe", "calibrate", "--model", str(probe_copy), "--corpus", str(corpus), "--preset", "planetary"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no planetary sequence in the validation split" in err
    # a shipped name resolves to the installed copy, which the next build replaces: refused before any VO runs
    assert main(["probe", "calibrate", "--model", "probe_sim", "--corpus", str(corpus)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "a shipped model's name; give its directory" in err
    from pvo_frontend.probe.model import write_vo_calibration
    from pvo_tools.commands.demo import DemoSettings, learned_graph
    from pvo_tools.errors import PvoError

    card = yaml.safe_load((probe_copy / "model.yaml").read_text())
    card["vo_calibration"] = {"covariance_scale": [1.0, -2.0]}
    (probe_copy / "model.yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(PvoError, match="vo_calibration.covariance_scale must be 6 positive numbers"):
        learned_graph(DemoSettings(probe_model=str(probe_copy), dpc_net=False))
    with pytest.raises(ValueError, match="must be 6 positive numbers"):
        write_vo_calibration(probe_copy, {"covariance_scale": [0.0] * 6})


def test_vo_calibrate_records_the_default_vos_scales_and_settings_in_a_file_of_its_own(
    corpus: Path, tmp_path: Path, capsys
) -> None:
    from pvo_frontend.vo_calibration import read_vo_calibration
    from pvo_tools.commands.demo import DemoSettings, learned_graph

    record = tmp_path / "my_vo.yaml"
    assert main(["vo", "calibrate", "--corpus", str(corpus), "-o", str(record)]) == 0
    out = capsys.readouterr().out
    assert "on 2 urban validation sequences" in out
    # then how consistent the scaled VO is by the size of its own sigma: a row per axis, its pairs in the bins
    table = out[out.index("mean e^2/sigma^2") :].splitlines()[1:8]
    assert [row.split()[0] for row in table[1:]] == ["x", "y", "z", "rx", "ry", "rz"]
    for row in table[1:]:
        assert sum(int(cell) for cell in re.findall(r"\((\d+)\)", row)) == 22
    recorded = yaml.safe_load(record.read_text())["vo_calibration"]["consistency_by_sigma"]
    assert recorded["reference_quantile"] == 0.9 and len(recorded["reference"]) == 6
    assert all(sum(recorded["pairs"][axis]) == 22 for axis in ("x", "y", "z", "rx", "ry", "rz"))
    # the record's means are the printed ones (an empty bin: null there, '-' printed)
    printed = [float(v) for v in re.findall(r"([\d.]+) \(\d+\)", table[5])]
    assert printed == pytest.approx([v for v in recorded["mean_nees"]["ry"] if v is not None], abs=0.006)
    entry = yaml.safe_load(record.read_text())["vo_calibration"]
    np.testing.assert_allclose(
        entry["covariance_scale"], independent_scales(corpus, None, ["0000", "0001"]), rtol=1e-3, atol=1e-4
    )
    assert entry["command"] == f"pvo vo calibrate --corpus {corpus} -o {record}"
    assert entry["vo_settings"]["ransac.inlier_threshold"] == 4.0 and "probe.model" not in entry["vo_settings"]
    # every graph of the default VO reads it: with hydranet or without it, the learned sun alone
    for sensors in (("sun_bcnn", "hydranet"), ("sun_bcnn",), ()):
        graph = learned_graph(DemoSettings(probe_model="", vo_calibration=str(record)), sensors)
        assert graph.fusion["inputs.vo.covariance_scale"] == entry["covariance_scale"]
    assert "scaled as" in capsys.readouterr().err
    # beside PROBE's VO the default VO's record does not apply
    assert "inputs.vo.covariance_scale" not in learned_graph(DemoSettings(vo_calibration=str(record), dpc_net=False)).fusion
    # a graph running another VO (the lens model's, RANSAC at 16 px) is told the record is not its VO's
    capsys.readouterr()
    lens_vo = learned_graph(
        DemoSettings(probe_model="", vo_calibration=str(record), vo_of_dpc_net=True, dpc_net_model="dpc_net"), ("hydranet",)
    )
    assert lens_vo.vo == {"ransac.inlier_threshold": 16.0} and "inputs.vo.covariance_scale" not in lens_vo.fusion
    assert "calibrated another VO (ransac.inlier_threshold 4.0 there, 16.0 here)" in capsys.readouterr().err
    # a record of a VO with other settings is made with them and matches the graph that runs them
    other = tmp_path / "other.yaml"
    assert main(["vo", "calibrate", "--corpus", str(corpus), "-p", "ransac.inlier_threshold=16", "-o", str(other)]) == 0
    calibration = read_vo_calibration(other)
    assert calibration is not None and calibration.vo_settings["ransac.inlier_threshold"] == 16.0
    assert calibration.covariance_scale != tuple(entry["covariance_scale"])
    matched = learned_graph(
        DemoSettings(probe_model="", vo_calibration=str(other), vo_of_dpc_net=True, dpc_net_model="dpc_net"), ("hydranet",)
    )
    assert matched.fusion["inputs.vo.covariance_scale"] == list(calibration.covariance_scale)
    # the shipped record: the scales HydraNet's experiments weigh the default VO with, made by its own command
    capsys.readouterr()
    shipped = learned_graph(DemoSettings(probe_model="", dpc_net=False)).fusion["inputs.vo.covariance_scale"]
    assert shipped == pytest.approx([1.2497, 0.249, 1.1548, 0.1342, 0.3691, 0.193])
    assert "the default_vo calibration" in capsys.readouterr().err


def test_bad_vo_calibration_input_is_one_line(corpus: Path, tmp_path: Path, capsys) -> None:
    from pvo_tools.commands.demo import DemoSettings, learned_graph
    from pvo_tools.errors import PvoError

    assert main(["vo", "calibrate", "--corpus", str(tmp_path / "none"), "-o", str(tmp_path / "x.yaml")]) == 2
    assert capsys.readouterr().err.count("\n") == 1 and not (tmp_path / "x.yaml").exists()
    assert main(["vo", "calibrate", "--corpus", str(corpus), "-p", "probe.model=probe_sim", "-o", str(tmp_path / "x.yaml")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "calibrated into its card: pvo probe calibrate --model probe_sim" in err
    assert main(["vo", "calibrate", "--corpus", str(corpus), "-p", "ransac.nonsense=1", "--dry-run"]) == 2
    assert capsys.readouterr().err.count("\n") == 1
    with pytest.raises(PvoError, match="no VO calibration file there"):
        learned_graph(DemoSettings(probe_model="", vo_calibration=str(tmp_path / "missing.yaml")))
    empty = tmp_path / "empty.yaml"
    empty.write_text("description: nothing measured\n")
    with pytest.raises(PvoError, match="no vo_calibration entry"):
        learned_graph(DemoSettings(probe_model="", vo_calibration=str(empty)))
    empty.write_text("vo_calibration:\n  covariance_scale: [1, 2, 3]\n")
    with pytest.raises(PvoError, match="covariance_scale must be 6 positive numbers"):
        learned_graph(DemoSettings(probe_model="", vo_calibration=str(empty)))
