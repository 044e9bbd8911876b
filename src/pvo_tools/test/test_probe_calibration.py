"""`pvo probe calibrate` and `pvo hydranet vo-scale`: the VO (with a PROBE model, or the default one) over a corpus
split, its per-axis covariance scales recorded in a model card, and the learned graph (`pvo demo`, the soak, the
faults) fusing the VO with them."""

from __future__ import annotations

import hashlib
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
    # without PROBE (and without hydranet, whose card speaks for the default VO) no card speaks for the VO
    assert "inputs.vo.covariance_scale" not in learned_graph(DemoSettings(probe_model="", hydranet=False, dpc_net=False)).fusion
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


def test_vo_scale_records_the_default_vos_scales_in_the_hydranet_card(corpus: Path, tmp_path: Path, capsys) -> None:
    from pvo_pseudosensors.hydranet.estimator import resolve_model
    from pvo_tools.commands.demo import DemoSettings, learned_graph

    model = tmp_path / "hydranet"
    shutil.copytree(resolve_model(""), model)
    del_entry = yaml.safe_load((model / "model.yaml").read_text())
    del_entry["calibration"].pop("default_vo_fusion", None)
    (model / "model.yaml").write_text(yaml.safe_dump(del_entry, sort_keys=False))
    no_scale = learned_graph(DemoSettings(probe_model="", hydranet_model=str(model), dpc_net=False))
    assert "inputs.vo.covariance_scale" not in no_scale.fusion
    assert main(["hydranet", "vo-scale", "--model", str(model), "--corpus", str(corpus)]) == 0
    assert "the default VO's covariance scales" in capsys.readouterr().out
    entry = yaml.safe_load((model / "model.yaml").read_text())["calibration"]["default_vo_fusion"]
    expected = independent_scales(corpus, None, ["0000", "0001"])
    np.testing.assert_allclose(entry["inputs.vo.covariance_scale"], expected, rtol=1e-3, atol=1e-4)
    graph = learned_graph(DemoSettings(probe_model="", hydranet_model=str(model), dpc_net=False))
    assert graph.fusion["inputs.vo.covariance_scale"] == entry["inputs.vo.covariance_scale"]
    assert "scaled as" in capsys.readouterr().err
    # beside PROBE's VO the HydraNet card's scales for the default VO do not apply; without hydranet neither
    assert "inputs.vo.covariance_scale" not in learned_graph(DemoSettings(hydranet_model=str(model), dpc_net=False)).fusion
    assert "inputs.vo.covariance_scale" not in learned_graph(DemoSettings(probe_model="", hydranet=False, dpc_net=False)).fusion
    # the shipped card carries the scales its experiments weighed the default VO with
    shipped = learned_graph(DemoSettings(probe_model="", dpc_net=False)).fusion["inputs.vo.covariance_scale"]
    assert shipped == pytest.approx([1.2497, 0.249, 1.1548, 0.1342, 0.3691, 0.193])
    capsys.readouterr()
    assert main(["hydranet", "vo-scale", "--model", str(tmp_path / "none"), "--corpus", str(corpus)]) == 2
    assert capsys.readouterr().err.count("\n") == 1
