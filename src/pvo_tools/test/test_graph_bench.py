"""The soak's graph (`pvo bench soak`): the main job's nodes and parameters — the same as `pvo demo` runs, from the
same model cards — every edge it waits for, and the CPU figures it reads from /proc."""

from __future__ import annotations

import math
import os
import time

import pytest
from pvo_tools.commands.bench import sensor_outputs_due
from pvo_tools.commands.demo import DemoSettings, learned_graph
from pvo_tools.errors import PvoError
from pvo_tools.graphbench import cpu_seconds, cpu_share, parse_cpu_seconds, soak_edges, soak_nodes


def test_the_main_job_graph_is_stereo_vo_the_learned_sensors_and_fusion() -> None:
    assert soak_nodes(("sun_bcnn", "hydranet", "dpc_net")) == (
        ("pvo_frontend", "stereo_vo"),
        ("pvo_pseudosensors", "sun_bcnn"),
        ("pvo_pseudosensors", "hydranet"),
        ("pvo_pseudosensors", "dpc_net"),
        ("pvo_fusion", "fusion"),
    )


@pytest.mark.parametrize("sensors", [("sun_bcnn", "gyroscope"), ()])
def test_an_unknown_or_empty_sensor_list_is_one_line(sensors: tuple[str, ...]) -> None:
    with pytest.raises(PvoError, match="choose among simulated_sun, sun_bcnn, hydranet, dpc_net"):
        soak_nodes(sensors)


def test_the_soak_waits_for_every_edge_of_its_graph() -> None:
    edges = soak_edges(("sun_bcnn", "hydranet", "dpc_net"), listeners=1)
    # the left images: stereo_vo, sun_bcnn, hydranet, dpc_net and the benchmark's listener
    assert edges["/stereo/left/image_rect"] == (0, 5)
    assert edges["/stereo/right/image_rect"] == (0, 2)  # stereo_vo and dpc_net
    assert edges["/pvo/vo/relative"] == (1, 3)  # fusion, dpc_net, the listener
    assert edges["/pvo/hydranet/rotation"] == (1, 1) and edges["/pvo/dpc/correction"] == (1, 1)
    assert edges["/pvo/sun/direction"] == (1, 1)
    assert "/ground_truth/sun_direction" not in edges
    # the soak of issue 18: both suns publish on one topic; simulated_sun reads the ground truth
    old = soak_edges(("simulated_sun", "sun_bcnn"), listeners=1)
    assert old["/pvo/sun/direction"] == (2, 1) and old["/ground_truth/sun_direction"] == (0, 1)
    assert old["/stereo/left/image_rect"] == (0, 3) and old["/pvo/vo/relative"] == (1, 2)
    assert "/pvo/hydranet/rotation" not in old and "/pvo/dpc/correction" not in old


def test_the_soak_and_the_demo_read_the_same_cards() -> None:
    graph = learned_graph(DemoSettings(), who="pvo bench soak")
    assert list(graph.sensors) == ["sun_bcnn", "hydranet", "dpc_net"]
    assert graph.sensors["dpc_net"] == {"model": "dpc_net_clean"} and graph.sensors["hydranet"] == {"model": ""}
    assert graph.vo["probe.model"] == "probe_sim"
    # the learned sun is fused with the offset state its card names
    assert graph.fusion["inputs.sun.bias_sigma"] == [0.1, 0.1]
    without = learned_graph(DemoSettings(hydranet=False, dpc_net=False, probe_model=""))
    assert list(without.sensors) == ["sun_bcnn"] and without.vo == {}
    assert learned_graph(DemoSettings(), ("hydranet",)).fusion == {}
    with pytest.raises(PvoError, match="unknown learned sensor"):
        learned_graph(DemoSettings(), ("simulated_sun",))


def test_outputs_due_follow_each_sensors_rate() -> None:
    due = sensor_outputs_due(600, 599, {"sun_bcnn": {"every_n": 10}, "dpc_net": {"model": "dpc_net_clean"}})
    assert due["sun_bcnn"] == "one in 10: 60 due"
    assert due["hydranet"] == "one per pair: 599 due"
    assert due["dpc_net"] == "one per 4 VO motions: 149 due"
    # a model the node cannot load: it says why itself, nothing is due from it
    assert "dpc_net" not in sensor_outputs_due(600, 599, {"dpc_net": {"model": "/no/such/model"}})


def test_cpu_time_is_read_after_a_command_name_with_spaces_and_parentheses() -> None:
    line = "4242 (python3 (x) y) S 1 2 3 4 5 6 7 8 9 10 250 50 0 0 20 0 1 0 100 0 0"
    assert parse_cpu_seconds(line, 100.0) == pytest.approx(3.0)  # utime 250 + stime 50 ticks


def test_a_busy_process_uses_one_core_and_a_gone_one_none() -> None:
    before = cpu_seconds(os.getpid())
    end = time.process_time() + 0.3
    while time.process_time() < end:
        pass
    assert cpu_seconds(os.getpid()) - before >= 0.25
    assert math.isnan(cpu_seconds(2**22 + 12345))  # beyond pid_max's default: no such process


def test_the_cpu_share_is_taken_after_the_warm_up() -> None:
    samples = [(0.0, 0.0), (5.0, 4.0), (10.0, 6.5), (15.0, 9.0)]
    assert cpu_share(samples, 5.0) == pytest.approx(0.5)  # 5 s of CPU in 10 s after the warm-up
    assert math.isnan(cpu_share(samples, 14.0))
    assert math.isnan(cpu_share([(6.0, float("nan")), (7.0, 1.0)], 5.0))


def test_a_node_stopped_by_the_sigterm_after_a_hung_teardown_is_a_warning_not_a_failure() -> None:
    import signal

    from pvo_tools.commands.demo import failed_nodes

    codes = {"stereo_vo": 0, "dpc_net": -signal.SIGTERM, "fusion": -signal.SIGKILL, "hydranet": 1, "sun_bcnn": -15}
    # dpc_net ignored SIGINT (its teardown hung) and SIGTERM stopped it; fusion needed SIGKILL; hydranet failed on
    # its own; sun_bcnn was never escalated, so a SIGTERM from elsewhere is a failure
    assert failed_nodes(codes, ["dpc_net", "fusion"], ["fusion"]) == {"fusion": -9, "hydranet": 1, "sun_bcnn": -15}
