"""`pvo demo`'s node plan (which sun, which learned sensors, PROBE) and its ablation: the distinct sensor sets on
one VO, and the table of what each adds against the same run's VO alone."""

from __future__ import annotations

import pytest
from pvo_tools.commands.demo import (
    DemoSettings,
    ablation_variants,
    describe_nodes,
    format_ablation_table,
    learned_graph,
    plan_nodes,
)


def test_the_learned_graph_runs_where_the_bag_has_gps() -> None:
    learned = plan_nodes(DemoSettings(), gps_fixes=300)
    assert learned.sun_node == "sun_bcnn" and learned.learned and learned.probe
    assert learned.sensors == ("sun_bcnn", "hydranet", "dpc_net")
    assert learned.names == ("stereo_vo", "sun_bcnn", "hydranet", "dpc_net", "fusion")
    kitti = plan_nodes(DemoSettings(), gps_fixes=2)  # too few fixes for the ephemeris: GT-Sun, no learned sensors
    assert (kitti.sun_node, kitti.learned, kitti.sensors, kitti.probe) == ("simulated_sun", False, (), False)
    assert kitti.names == ("stereo_vo", "simulated_sun", "fusion")


def test_no_sun_leaves_the_other_learned_sensors_where_they_run() -> None:
    none = plan_nodes(DemoSettings(sun="none"), gps_fixes=300)
    assert none.sun_node is None and none.sensors == ("hydranet", "dpc_net") and none.probe
    assert describe_nodes(none) == "stereo_vo(PROBE) hydranet dpc_net fusion"
    bare = plan_nodes(DemoSettings(sun="none"), gps_fixes=0)
    assert bare.names == ("stereo_vo", "fusion") and not bare.learned
    # Sun-BCNN asked for on a bag without GPS still brings the learned sensors (the demo then says GPS is missing)
    assert plan_nodes(DemoSettings(sun="sun-bcnn", dpc_net=False), gps_fixes=0).sensors == ("sun_bcnn", "hydranet")


def test_an_ablation_runs_each_distinct_graph_once_on_the_same_vo() -> None:
    variants = ablation_variants(DemoSettings(), gps_fixes=300)
    graphs = [describe_nodes(v.nodes) for v in variants]
    assert graphs == [
        "stereo_vo(PROBE) sun_bcnn hydranet dpc_net fusion",
        "stereo_vo sun_bcnn hydranet dpc_net fusion",
        "stereo_vo(PROBE) hydranet dpc_net fusion",
        "stereo_vo(PROBE) sun_bcnn dpc_net fusion",
        "stereo_vo(PROBE) sun_bcnn hydranet fusion",
        "stereo_vo(PROBE) fusion",
        "stereo_vo(PROBE) sun_bcnn fusion",
        "stereo_vo(PROBE) hydranet fusion",
        "stereo_vo(PROBE) dpc_net fusion",
    ]
    assert len({v.slug for v in variants}) == len(variants)
    # where dpc_net runs in the full graph every variant keeps the VO its model corrects, dpc_net running or not
    assert all(v.settings.vo_of_dpc_net for v in variants)
    lens = ablation_variants(DemoSettings(dpc_net_model="dpc_net"), gps_fixes=300)
    without = next(v for v in lens if v.label == "without dpc_net")
    assert learned_graph(without.settings, without.nodes.sensors).vo == {
        "ransac.inlier_threshold": 16.0,  # the shipped lens model's VO (its card)
        "probe.model": "probe_sim",
    }
    # a bag without GPS runs GT-Sun and nothing learned: only the sun can be taken away
    kitti = ablation_variants(DemoSettings(), gps_fixes=0)
    assert [(v.label, describe_nodes(v.nodes)) for v in kitti] == [
        ("every sensor", "stereo_vo simulated_sun fusion"),
        ("without the sun", "stereo_vo fusion"),
    ]
    assert not any(v.settings.vo_of_dpc_net for v in kitti)
    # without dpc_net asked for, the variants run the plain VO and no dpc_net
    no_dpc = ablation_variants(DemoSettings(dpc_net=False), gps_fixes=300)
    assert len(no_dpc) == 5 and not any("dpc_net" in v.nodes.sensors or v.settings.vo_of_dpc_net for v in no_dpc)


def _figures(drift: float, ate: float, m_t: float, m_r: float) -> dict[str, float]:
    return {
        "frames": 300,
        "path_length_m": 239.2,
        "end_drift_percent": drift,
        "ate_rmse_m": ate,
        "m_ate_translation_m": m_t,
        "m_ate_rotation_deg": m_r,
        "rpe_rotation_mean_deg": 0.04,
    }


def test_the_ablation_table_gives_each_graph_against_its_own_vo() -> None:
    vo = _figures(1.5, 1.2, 1.0, 0.50)
    plain_vo = _figures(2.0, 1.9, 1.6, 0.80)
    rows = [
        ("every sensor", "stereo_vo(PROBE) sun_bcnn fusion", {"vo": vo, "fused_online": _figures(1.2, 1.0, 0.75, 0.40)}),
        ("without PROBE", "stereo_vo sun_bcnn fusion", {"vo": plain_vo, "fused_online": _figures(1.8, 1.7, 1.2, 0.88)}),
    ]
    lines = format_ablation_table("sample", rows).splitlines()
    assert lines[0].startswith("sample: 300 frames, 239.2 m")
    body = {line.split("  ")[0]: line.split() for line in lines[3:]}
    assert len(lines) == 7  # header (3), the two VOs alone, the two graphs
    vo_rows = [line.split() for line in lines[3:5]]
    assert vo_rows[0][:3] == ["VO", "alone", "stereo_vo(PROBE)"] and vo_rows[0][-2:] == ["-", "-"]
    assert vo_rows[1][:3] == ["VO", "alone", "stereo_vo"] and vo_rows[1][3] == "2.000"
    every = body["every sensor"]
    assert every[-2:] == ["-25.0", "-20.0"]  # m-ATE 1.0 -> 0.75 m, 0.50 -> 0.40 deg
    assert body["without PROBE"][-2:] == ["-25.0", "+10.0"]  # against the plain VO of its own run


@pytest.mark.parametrize("sun", ["none", "simulated", "sun-bcnn", "auto"])
def test_every_sun_choice_plans_a_graph_with_stereo_vo_and_fusion(sun: str) -> None:
    names = plan_nodes(DemoSettings(sun=sun), gps_fixes=300).names
    assert names[0] == "stereo_vo" and names[-1] == "fusion"
    assert ("simulated_sun" in names) == (sun == "simulated") and ("sun_bcnn" in names) == (sun in ("sun-bcnn", "auto"))


def test_an_unchanged_figure_reads_zero_without_a_sign() -> None:
    vo = _figures(1.5, 1.2, 1.0, 0.50)
    rows = [("every sensor", "stereo_vo fusion", {"vo": vo, "fused_online": _figures(1.5, 1.2, 1.0 - 1e-9, 0.50 + 1e-9)})]
    assert format_ablation_table("sample", rows).splitlines()[-1].split()[-2:] == ["0.0", "0.0"]
