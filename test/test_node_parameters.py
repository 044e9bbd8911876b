"""Every node declares exactly its configs' fields, and its YAML defaults file lists the same names and values."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml

pytestmark = pytest.mark.ros
ROOT = Path(__file__).resolve().parents[1]


def _nodes():
    from pvo_frontend.stereo_vo_node import StereoVONode, StereoVONodeConfig
    from pvo_frontend.vo import VOConfig
    from pvo_fusion.fusion_node import FusionNode, FusionNodeConfig
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensorConfig
    from pvo_pseudosensors.dpc_net_node import DPCNetNode
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensorConfig
    from pvo_pseudosensors.hydranet_node import HydraNetNode
    from pvo_pseudosensors.simulated_sun import SimulatedSunConfig
    from pvo_pseudosensors.simulated_sun_node import SimulatedSunNode
    from pvo_pseudosensors.sun_bcnn.estimator import SunBCNNSensorConfig
    from pvo_pseudosensors.sun_bcnn_node import SunBCNNNode

    from pvo_fusion.config import FusionConfig

    return {
        "stereo_vo": (StereoVONode, (VOConfig(), StereoVONodeConfig()), ROOT / "src/pvo_frontend/config/stereo_vo.yaml"),
        "fusion": (FusionNode, (FusionConfig(), FusionNodeConfig()), ROOT / "src/pvo_fusion/config/fusion.yaml"),
        "simulated_sun": (SimulatedSunNode, (SimulatedSunConfig(),), ROOT / "src/pvo_pseudosensors/config/simulated_sun.yaml"),
        "sun_bcnn": (SunBCNNNode, (SunBCNNSensorConfig(),), ROOT / "src/pvo_pseudosensors/config/sun_bcnn.yaml"),
        "hydranet": (HydraNetNode, (HydraNetSensorConfig(),), ROOT / "src/pvo_pseudosensors/config/hydranet.yaml"),
        "dpc_net": (DPCNetNode, (DPCNetSensorConfig(),), ROOT / "src/pvo_pseudosensors/config/dpc_net.yaml"),
    }


def _plain(value):
    return list(value) if hasattr(value, "__len__") and not isinstance(value, str) else value


@pytest.mark.parametrize("name", ["stereo_vo", "fusion", "simulated_sun", "sun_bcnn", "hydranet", "dpc_net"])
def test_declared_parameters_equal_the_config_fields_and_the_yaml(name: str, ros_context) -> None:
    from pvo_core.config import flatten

    from pvo_ros import config_fields, declared_parameter_names

    cls, configs, yaml_path = _nodes()[name]
    node = cls(context=ros_context)
    try:
        declared = declared_parameter_names(node)
        assert declared == config_fields(*configs)
        defaults = {k: v for c in configs for k, v in flatten(c).items()}
        assert {n: _plain(node.get_parameter(n).value) for n in declared} == defaults
        params = yaml.safe_load(yaml_path.read_text())[name]["ros__parameters"]
        assert set(params) == declared
        for key, value in params.items():
            assert value == defaults[key], key
    finally:
        node.destroy_node()


@pytest.mark.parametrize("name", ["stereo_vo", "fusion", "simulated_sun", "sun_bcnn", "hydranet", "dpc_net"])
def test_runtime_change_of_an_algorithm_parameter_is_refused_with_the_reason(name: str, ros_context) -> None:
    from pvo_core.config import flatten
    from rclpy.parameter import Parameter

    cls, configs, _ = _nodes()[name]
    node = cls(context=ros_context)
    try:
        first = next(iter(flatten(configs[0]).items()))
        result = node.set_parameters([Parameter(first[0], value=first[1])])[0]
        assert not result.successful
        assert result.reason == f"{name}: {first[0]} is read at start-up; restart the node to change it"
    finally:
        node.destroy_node()


def test_fusion_applies_path_period_at_run_time_and_validates_it(ros_context) -> None:
    from pvo_fusion.fusion_node import FusionNode
    from rclpy.parameter import Parameter

    node = FusionNode(context=ros_context)
    try:
        assert node.set_parameters([Parameter("path_period", value=0.25)])[0].successful
        assert node.settings.path_period == 0.25
        bad = node.set_parameters([Parameter("path_period", value=-1.0)])[0]
        assert not bad.successful and "path_period must be >= 0 s, got -1.0" in bad.reason
        assert node.settings.path_period == 0.25
    finally:
        node.destroy_node()


@pytest.mark.parametrize(
    ("package", "node", "parameter", "message"),
    [
        (
            "pvo_frontend",
            "stereo_vo",
            "solver.loss:=tukey",
            "invalid VO configuration: solver.loss must be one of l2, huber, cauchy, geman_mcclure, student_t",
        ),
        ("pvo_frontend", "stereo_vo", "max_pending_frames:=0", "max_pending_frames must be >= 1, got 0"),
        (
            "pvo_fusion",
            "fusion",
            "window.lag_unit:=hours",
            "invalid fusion configuration: window.lag_unit must be one of frames, seconds",
        ),
        ("pvo_fusion", "fusion", "path_period:=-1.0", "path_period must be >= 0 s, got -1.0"),
        ("pvo_fusion", "fusion", "initial_pose:=[0.0,0.0]", "initial_pose: a pose needs 7 finite numbers"),
        ("pvo_pseudosensors", "simulated_sun", "every_n:=0", "invalid simulated sun configuration: every_n must be >= 1, got 0"),
        ("pvo_pseudosensors", "sun_bcnn", "mode:=sideways", "unknown mode 'sideways': choose one of full, head"),
        ("pvo_pseudosensors", "hydranet", "max_gap:=0.0", "max_gap must be > 0 s, got 0.0"),
        ("pvo_pseudosensors", "hydranet", "camera_pitch_deg:=95.0", "camera_pitch_deg must be in [-90, 90] deg, got 95.0"),
        ("pvo_pseudosensors", "dpc_net", "threads:=0", "threads must be >= 1, got 0"),
        ("pvo_fusion", "fusion", "inputs.vo.lost_variance:=abc", "parameter inputs.vo.lost_variance must be a number, got 'abc'"),
        ("pvo_frontend", "stereo_vo", "max_pending_frames:=2.5", "parameter max_pending_frames must be an integer, got 2.5"),
        ("pvo_pseudosensors", "hydranet", "max_gap:=[1.0]", "parameter max_gap must be a number, got [1.0]"),
    ],
)
def test_a_wrong_parameter_is_one_clear_line_and_exit_2(ros_env, package: str, node: str, parameter: str, message: str) -> None:
    result = subprocess.run(
        ["pvo", "run", package, node, "--ros-args", "-p", parameter], env=ros_env, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{node}: error: {message}"), lines


def test_an_integer_for_a_float_parameter_is_the_number_meant(ros_context) -> None:
    """`-p inputs.vo.lost_variance:=1000` (no decimal point) used to stop the node with rclpy's type error."""
    from pvo_fusion.fusion_node import FusionNode
    from rclpy.parameter import Parameter

    overrides = [
        Parameter("inputs.vo.lost_variance", value=1000),
        Parameter("inputs.vo.covariance_scale", value=[1, 1, 1, 2, 2, 2]),
    ]
    node = FusionNode(context=ros_context, parameter_overrides=overrides)
    try:
        assert node.get_parameter("inputs.vo.lost_variance").value == 1000.0
        assert node.config.inputs.vo.lost_variance == 1000.0 and isinstance(node.config.inputs.vo.lost_variance, float)
        assert list(node.config.inputs.vo.covariance_scale) == [1.0, 1.0, 1.0, 2.0, 2.0, 2.0]
    finally:
        node.destroy_node()


def test_arguments_rcl_cannot_parse_are_one_error_line_and_exit_2(ros_env) -> None:
    result = subprocess.run(
        ["pvo", "run", "pvo_fusion", "fusion", "--ros-args", "-p", "inputs.vo.covariance_scale:=[1,1,x]"],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr
    (line,) = [line for line in result.stderr.splitlines() if line.startswith("fusion: error: ")]
    assert "Couldn't parse parameter override rule: '-p inputs.vo.covariance_scale:=[1,1,x]'" in line and "/project/" not in line


def test_a_misspelt_parameter_is_named_with_the_one_meant(ros_env) -> None:
    """ROS ignores a start-up value no parameter takes; the node says so, with the closest name it has."""
    import signal
    import time

    proc = subprocess.Popen(
        ["pvo", "run", "pvo_frontend", "stereo_vo", "--ros-args", "-p", "solver.los:=huber", "-p", "nosuch:=1"],
        env=ros_env,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(4.0)
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == 0
    assert "parameter solver.los is not one of stereo_vo's and is ignored; did you mean solver.loss?" in stderr
    assert "parameter nosuch is not one of stereo_vo's and is ignored\n" in stderr
