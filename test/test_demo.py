"""`pvo demo` (the main job) on the real KITTI sample: the graph over DDS equals the ROS-free objects."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest

pytestmark = pytest.mark.ros


def test_demo_on_the_kitti_sample_matches_the_ros_free_objects(sample_bag: Path, tmp_path: Path, ros_env) -> None:
    out = tmp_path / "demo"
    result = subprocess.run(
        ["pvo", "demo", str(sample_bag), "-o", str(out)], env=ros_env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr[-2000:]
    assert "VO (stereo_vo)" in result.stdout and "fused smoothed (/pvo/fusion/path)" in result.stdout
    sample = out / "kitti06_sample"
    record = json.loads((sample / "metrics.json").read_text())
    assert record["schema"] == "pvo.run-result/1" and record["kind"] == "demo"
    agreement = record["figures"]
    for key in ("vo", "fused_smoothed", "fused_online"):
        assert agreement[f"agreement_with_ros_free.{key}_max_position_difference_m"] < 1e-6
    estimates = record["tables"]["estimates"]
    assert estimates["vo"]["frames"] == estimates["fused_smoothed"]["frames"] == 51
    # the stereo VO's figure on the 06 clip, through the nodes
    assert estimates["vo"]["end_drift_percent"] == pytest.approx(1.022, abs=5e-4)
    assert 0.0 < estimates["fused_online"]["pose_anees"]
    for name in ("report.md", "trajectory.png", "errors.png", "params.yaml", "sun_reference.csv"):
        assert (sample / name).stat().st_size > 100, name
    assert (out / "report.md").read_text().count("kitti06_sample") >= 2
    bag_info = subprocess.run(["pvo", "bag", "info", str(sample / "recorded")], capture_output=True, text=True, timeout=60)
    assert "Topic: /pvo/vo/relative" in bag_info.stdout and "Count: 50" in bag_info.stdout


def test_demo_runs_sun_bcnn_where_the_bag_has_gps(tmp_path: Path, ros_env) -> None:
    """The synthetic sample (it has /gps/fix) goes through stereo_vo -> sun_bcnn, hydranet and dpc_net (the
    shipped models; DPC-Net's for the clean rig) -> fusion, the reference from the ephemeris; the graph equals the
    same objects run without ROS."""
    from conftest import REPO_ROOT

    out = tmp_path / "demo"
    bag = REPO_ROOT / "bags" / "sim_urban_sample"
    result = subprocess.run(["pvo", "demo", str(bag), "-o", str(out)], env=ros_env, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    sample = out / "sim_urban_sample"
    params = (sample / "params.yaml").read_text()
    assert "sun_bcnn:" in params and "hydranet:" in params and "dpc_net:" in params and "simulated_sun" not in params
    assert "probe.model: probe_sim" in params  # stereo_vo with the shipped PROBE model of this rig
    import yaml
    from pvo_pseudosensors.dpc_net.config import vo_differences
    from pvo_pseudosensors.dpc_net.estimator import resolve_model as resolve_dpc_net
    from pvo_pseudosensors.learning.checkpoint import read_card
    from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
    from pvo_pseudosensors.sun_bcnn.infer import card_fusion

    # stereo_vo runs the VO whose errors DPC-Net's model learned (its card names every setting)
    dpc_vo = vo_differences(read_card(resolve_dpc_net("dpc_net_clean")).input["rig"]["vo_settings"])
    vo_parameters = yaml.safe_load(params)["stereo_vo"]["ros__parameters"]
    assert all(vo_parameters[name] == value for name, value in dpc_vo.items())
    fusion_parameters = yaml.safe_load(params)["fusion"]["ros__parameters"]
    asked = card_fusion(read_card(resolve_model("sun_bcnn")))  # how the shipped model's card says to fuse it
    assert asked and all(fusion_parameters[name] == list(value) for name, value in asked.items())
    record = json.loads((sample / "metrics.json").read_text())
    for key in ("vo", "fused_smoothed", "fused_online"):
        assert record["figures"][f"agreement_with_ros_free.{key}_max_position_difference_m"] < 1e-6
    assert record["figures"]["agreement_with_ros_free.hydranet_max_rotation_difference"] < 1e-6
    assert record["figures"]["agreement_with_ros_free.dpc_net_max_position_difference_m"] < 1e-6
    bag_info = subprocess.run(["pvo", "bag", "info", str(sample / "recorded")], capture_output=True, text=True, timeout=60)
    assert "Topic: /pvo/sun/direction" in bag_info.stdout and "Count: 30 " in bag_info.stdout  # every 10th of 300
    assert "Topic: /pvo/hydranet/rotation" in bag_info.stdout and "Count: 299 " in bag_info.stdout  # every pair
    # one correction every Δp = 4 of 299 pairs: 74; on a loaded machine a window can still lose a VO transform or a
    # stereo pair in transit, and the node then reports it instead of correcting (the objects take the same ones)
    corrections = re.search(r"Topic: /pvo/dpc/correction +\| Type: [^|]+\| Count: (\d+) ", bag_info.stdout)
    assert corrections is not None and 70 <= int(corrections.group(1)) <= 74, bag_info.stdout
    assert "stereo_vo -> sun_bcnn + hydranet + dpc_net -> fusion" in (sample / "report.md").read_text()


def test_demo_ablation_runs_each_graph_through_the_nodes(sample_bag: Path, tmp_path: Path, ros_env) -> None:
    """`pvo demo --ablation` on the KITTI sample (no GPS: GT-Sun-10 and nothing learned): the graph with the sun and
    the graph without any sun sensor, each through the real nodes and checked against the ROS-free objects, then
    tabulated against the VO alone."""
    out = tmp_path / "demo"
    result = subprocess.run(
        ["pvo", "demo", "--ablation", str(sample_bag), "-o", str(out)], env=ros_env, capture_output=True, text=True, timeout=400
    )
    assert result.returncode == 0, result.stderr[-2000:]
    ablation = out / "ablation" / "kitti06_sample"
    record = json.loads((ablation / "metrics.json").read_text())
    assert record["kind"] == "demo-ablation"
    assert record["inputs"]["graphs"] == {
        "every-sensor": "stereo_vo simulated_sun fusion",
        "without-the-sun": "stereo_vo fusion",
    }
    without = ablation / "without-the-sun"
    params = (without / "params.yaml").read_text()
    assert "simulated_sun" not in params and "inputs.sun.enabled: false" in params
    assert not (without / "sun_reference.csv").exists()
    figures = json.loads((without / "metrics.json").read_text())["figures"]
    for key in ("vo", "fused_smoothed", "fused_online"):
        assert figures[f"agreement_with_ros_free.{key}_max_position_difference_m"] < 1e-6
    # with no other measurement the fused chain is the VO's own: the same end point to the millimetre
    tables = record["tables"]
    assert tables["without-the-sun"]["fused_online"]["end_drift_percent"] == pytest.approx(
        tables["without-the-sun"]["vo"]["end_drift_percent"], abs=1e-3
    )
    assert tables["every-sensor"]["vo"]["end_drift_percent"] == pytest.approx(1.022, abs=5e-4)
    bag_info = subprocess.run(["pvo", "bag", "info", str(without / "recorded")], capture_output=True, text=True, timeout=60)
    assert "/pvo/sun/direction" not in bag_info.stdout and "Topic: /pvo/fusion/odometry" in bag_info.stdout
    table = (ablation / "ablation.md").read_text()
    assert "VO alone" in table and "without the sun" in table and "stereo_vo simulated_sun fusion" in table
    assert "stereo_vo -> fusion over DDS" in (without / "report.md").read_text()
    assert "kitti06_sample" in (out / "ablation" / "report.md").read_text()


@pytest.mark.parametrize(
    ("case", "extra"),
    [("bag", []), ("bag", ["--ablation"]), ("vo-calibration", ["--probe-model", "", "--vo-calibration", "{missing}"])],
)
def test_demo_on_missing_input_is_one_clear_line(tmp_path: Path, ros_env, case: str, extra: list[str]) -> None:
    """A missing bag, or a missing `--vo-calibration` (the record the learned graph weighs the plain VO with): one
    line naming it, before any node starts."""
    from conftest import REPO_ROOT

    missing = tmp_path / "none"
    bag = missing if case == "bag" else REPO_ROOT / "bags" / "sim_urban_sample"
    result = subprocess.run(
        ["pvo", "demo", *(e.format(missing=missing) for e in extra), str(bag), "-o", str(tmp_path / "out")],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    said = "no such bag" if case == "bag" else f"no VO calibration file there ({missing})"
    assert result.stderr.strip().splitlines()[-1] == f"pvo: error: {missing}: {said}"
    assert not (tmp_path / "out" / "sim_urban_sample" / "recorded").exists()
