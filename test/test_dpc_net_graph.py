"""The dpc_net node over DDS: stereo images and VO transforms in, a correction of every Δp-frame window out,
exactly what the ROS-free sensor computes; a VO gap, a lost VO frame and a size change inside a window give
no correction and say why; a camera of another rig than the model card's is refused; a bad stereo pair and a
missing model are reported and the node keeps running."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from pvo_core.lie import se3_exp
from pvo_core.msgconv import fill_pose, fill_stamp, pose_to_matrix
from pvo_tools.testing import Spinner, wait_for
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from test_sun_bcnn_graph import image_message

from pvo_msgs.msg import RelativePose

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
STEP = 100_000_000


@pytest.fixture()
def tiny_model(tmp_path: Path) -> Path:
    import torch
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig
    from pvo_pseudosensors.dpc_net.model import DPCNet, DPCTask
    from pvo_pseudosensors.learning.checkpoint import save_model

    config = DPCNetConfig(height=32, width=104, stem=(4, 4, 8), body=(8, 16), test_delta=3)
    torch.manual_seed(0)
    network = DPCNet(config)
    with torch.no_grad():
        network.head.weight.normal_(0.0, 0.01)  # a non-zero correction, so the test sees it applied
    return save_model(tmp_path / "model", network, DPCTask(config, np.diag([0.01] * 3 + [0.001] * 3)).card())


def vo_message(stamp: int, reference: int, transform: np.ndarray) -> RelativePose:
    msg = RelativePose()
    fill_stamp(msg.header.stamp, stamp)
    fill_stamp(msg.reference_stamp, reference)
    msg.header.frame_id = "camera_left_optical"
    fill_pose(msg.pose.pose, transform)
    msg.pose.covariance = [float(v) for v in np.eye(6).reshape(-1) * 1e-4]
    return msg


def run_graph(ros_context, parameters: dict, script) -> tuple[list[RelativePose], list[DiagnosticArray]]:
    from pvo_pseudosensors.dpc_net_node import DPCNetNode

    node = DPCNetNode(context=ros_context, parameter_overrides=[Parameter(k, value=v) for k, v in parameters.items()])
    source = Node("source", context=ros_context)
    left = source.create_publisher(Image, "/stereo/left/image_rect", RELIABLE)
    right = source.create_publisher(Image, "/stereo/right/image_rect", RELIABLE)
    vo = source.create_publisher(RelativePose, "/pvo/vo/relative", RELIABLE)
    received: list[RelativePose] = []
    statuses: list[DiagnosticArray] = []
    source.create_subscription(RelativePose, "/pvo/dpc/correction", received.append, RELIABLE)
    source.create_subscription(DiagnosticArray, "/pvo/dpc_net/status", statuses.append, RELIABLE)
    try:
        with Spinner(ros_context, node), Spinner(ros_context, source):
            wait_for(lambda: vo.get_subscription_count() > 0 and right.get_subscription_count() > 0, 10)
            wait_for(lambda: node.publisher.get_subscription_count() > 0, 10)
            script(left, right, vo, received, statuses, node)
    finally:
        node.destroy_node()
        source.destroy_node()
    return received, statuses


def test_windows_of_vo_in_corrections_out(ros_context, tiny_model: Path) -> None:
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig

    rng = np.random.default_rng(0)
    frames = [(rng.integers(0, 256, (64, 208), np.uint8), rng.integers(0, 256, (64, 208), np.uint8)) for _ in range(8)]
    motions = [
        se3_exp(np.r_[0.02 * rng.normal(size=3), 0.01 * rng.normal(size=3)]) @ se3_exp([0, 0, 0.8, 0, 0, 0]) for _ in range(8)
    ]

    def script(left, right, vo, received, statuses, node) -> None:
        for k, (a, b) in enumerate(frames):
            left.publish(image_message(a, (k + 1) * STEP))
            right.publish(image_message(b, (k + 1) * STEP))
        wait_for(lambda: len(node.sensor.images) == len(frames), 20)  # the pairs before their VO, as on a robot
        for k in range(1, 8):
            vo.publish(vo_message((k + 1) * STEP, k * STEP, motions[k]))
        wait_for(lambda: len(received) >= 2, 20)

    received, _ = run_graph(ros_context, {"model": str(tiny_model)}, script)
    reference = DPCNetSensor(DPCNetSensorConfig(model=str(tiny_model)))
    expected = []
    for k, (a, b) in enumerate(frames):
        reference.add_images((k + 1) * STEP, a, b)
    for k in range(1, 8):
        correction = reference.add_vo(k * STEP, (k + 1) * STEP, motions[k])
        if correction is not None:
            expected.append(correction)
    assert len(received) == len(expected) == 2  # windows 1-4 and 4-7 (frames at 0.1 s steps)
    for msg, correction in zip(received, expected, strict=True):
        assert msg.reference_stamp.nanosec == correction.reference_stamp % 1_000_000_000
        np.testing.assert_allclose(pose_to_matrix(msg.pose.pose), correction.transform, atol=1e-9)
        np.testing.assert_allclose(np.reshape(msg.pose.covariance, (6, 6)), np.diag([0.01] * 3 + [0.001] * 3))
    vo_only = np.eye(4)
    for k in (1, 2, 3):
        vo_only = motions[k] @ vo_only
    assert not np.allclose(expected[0].transform, vo_only)  # the correction was applied


def test_a_card_that_fuses_no_axis_publishes_unmeasured_corrections_and_says_so(ros_context, tiny_model: Path) -> None:
    import yaml
    from pvo_pseudosensors.dpc_net.infer import UNMEASURED

    card = yaml.safe_load((tiny_model / "model.yaml").read_text())
    card["calibration"]["fused_axes"] = []  # what `calibrate --drives` writes when no weighing lowered every drive
    (tiny_model / "model.yaml").write_text(yaml.safe_dump(card))
    rng = np.random.default_rng(1)

    def script(left, right, vo, received, statuses, node) -> None:
        for k in range(4):
            left.publish(image_message(rng.integers(0, 256, (64, 208), np.uint8), (k + 1) * STEP))
            right.publish(image_message(rng.integers(0, 256, (64, 208), np.uint8), (k + 1) * STEP))
        wait_for(lambda: len(node.sensor.images) == 4, 20)
        for k in range(1, 4):
            vo.publish(vo_message((k + 1) * STEP, k * STEP, se3_exp([0, 0, 0.8, 0, 0, 0])))
        wait_for(lambda: len(received) >= 1 and len(statuses) >= 1, 20)

    received, statuses = run_graph(ros_context, {"model": str(tiny_model)}, script)
    np.testing.assert_array_equal(np.diag(np.reshape(received[0].pose.covariance, (6, 6))), [UNMEASURED] * 6)
    assert statuses[-1].status[0].level == DiagnosticStatus.WARN
    assert "calibration measures no axis; the corrections carry no weight" in statuses[-1].status[0].message


def test_a_broken_chain_starts_a_new_window_and_a_bad_pair_is_reported(ros_context, tiny_model: Path) -> None:
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig

    sensor = DPCNetSensor(DPCNetSensorConfig(model=str(tiny_model)))
    image = np.zeros((64, 208), np.uint8)
    for k in range(1, 8):
        sensor.add_images(k * STEP, image, image)
    assert sensor.add_vo(1 * STEP, 2 * STEP, np.eye(4)) is None
    assert sensor.add_vo(2 * STEP, 3 * STEP, np.eye(4)) is None and sensor.dropped is None
    assert sensor.add_vo(4 * STEP, 5 * STEP, np.eye(4)) is None  # frame 3 -> 4 missing: a new window from 4
    assert sensor.dropped is not None and "VO gap: the transform to 0.500 s starts at 0.400 s" in sensor.dropped
    assert sensor.add_vo(5 * STEP, 6 * STEP, np.eye(4)) is None
    correction = sensor.add_vo(6 * STEP, 7 * STEP, np.eye(4))
    assert correction is not None and correction.reference_stamp == 4 * STEP
    # a lost VO frame inside the next window: no correction for it, and why
    lost = np.eye(6) * 9999.0
    for k in range(8, 12):
        sensor.add_images(k * STEP, image, image)
    assert sensor.add_vo(7 * STEP, 8 * STEP, np.eye(4)) is None
    assert sensor.add_vo(8 * STEP, 9 * STEP, np.eye(4), lost) is None
    assert sensor.add_vo(9 * STEP, 10 * STEP, np.eye(4)) is None
    assert sensor.dropped == "the window 0.700-1.000 s is dropped: the VO was lost at 0.900 s (variance >= 1000)"
    # the images change size inside the following one
    sensor.add_images(13 * STEP, np.zeros((70, 230), np.uint8), np.zeros((70, 230), np.uint8))
    for k in (11, 12, 13):
        result = sensor.add_vo((k - 1) * STEP, k * STEP, np.eye(4))
    assert (
        result is None and sensor.dropped == "the window 1.000-1.300 s is dropped: the images changed size from 208x64 to 230x70"
    )
    with pytest.raises(ValueError, match="left and right images differ in size"):
        sensor.add_images(9 * STEP, image, image[:, :100])

    def script(left, right, vo, received, statuses, node) -> None:
        left.publish(image_message(image, STEP))
        right.publish(image_message(image[:, :100].copy(), STEP))
        wait_for(lambda: any(s.status[0].level == DiagnosticStatus.WARN for s in statuses), 20)

    _, statuses = run_graph(ros_context, {"model": str(tiny_model)}, script)
    assert "left and right images differ in size" in statuses[-1].status[0].message


def test_the_sensor_takes_the_cards_validation_mean_off_every_correction(tiny_model: Path, tmp_path: Path) -> None:
    import shutil

    import yaml
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig

    mean = np.array([0.01, -0.02, 0.03, 1e-4, -4.5e-4, 2e-4])
    removing = tmp_path / "removing"
    shutil.copytree(tiny_model, removing)
    card = yaml.safe_load((removing / "model.yaml").read_text())
    axes = ("x", "y", "z", "rx", "ry", "rz")
    card["calibration"]["residual"] = {f"bias_{a}_after": float(v) for a, v in zip(axes, mean, strict=True)}
    card["calibration"]["remove_mean"] = True
    (removing / "model.yaml").write_text(yaml.safe_dump(card))
    image = np.random.default_rng(0).integers(0, 255, (64, 208), dtype=np.uint8)
    step = se3_exp(np.array([0.01, 0.0, 0.8, 0.0, 0.01, 0.0]))
    corrections = []
    for model in (tiny_model, removing):
        sensor = DPCNetSensor(DPCNetSensorConfig(model=str(model)))
        for k in range(1, 5):
            sensor.add_images(k * STEP, image, image)
        results = [sensor.add_vo(k * STEP, (k + 1) * STEP, step) for k in range(1, 4)]
        corrections.append(results[-1])
    assert corrections[0] is not None and corrections[1] is not None
    np.testing.assert_allclose(corrections[1].transform, se3_exp(mean) @ corrections[0].transform, atol=1e-12)
    # asking for the removal without the figures stops the sensor at start-up, in one line
    del card["calibration"]["residual"]["bias_ry_after"]
    (removing / "model.yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(ValueError, match="remove_mean but its residual has no bias_ry_after figures"):
        DPCNetSensor(DPCNetSensorConfig(model=str(removing)))


def test_a_mirrored_card_makes_the_sensor_mirror_equivariant(tiny_model: Path, tmp_path: Path) -> None:
    """A card calibrated with mirrored inference: the sensor corrects a window seen through a left-right mirror
    (each image flipped, left and right swapped, every VO step conjugated) by the mirror of its correction of the
    window; the card without it does not."""
    import shutil

    import yaml
    from pvo_core.lie import se3_log
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig
    from pvo_pseudosensors.dpc_net.infer import _mirror_conjugation

    mirrored = tmp_path / "mirrored"
    shutil.copytree(tiny_model, mirrored)
    card = yaml.safe_load((mirrored / "model.yaml").read_text())
    card["calibration"]["mirrored"] = True
    card["input"]["rig"] = {"size": [208, 64], "focal_px": [200.0, 200.0], "baseline_m": [0.54, 0.54]}
    (mirrored / "model.yaml").write_text(yaml.safe_dump(card))
    rng = np.random.default_rng(1)
    pairs = [(rng.integers(0, 255, (64, 208), dtype=np.uint8), rng.integers(0, 255, (64, 208), dtype=np.uint8)) for _ in range(4)]
    steps = [se3_exp(np.array([0.05, 0.0, 0.8, 0.0, 0.03, 0.01])) for _ in range(3)]
    conjugation = _mirror_conjugation(0.54)

    def correct(model: Path, through_mirror: bool) -> np.ndarray:
        sensor = DPCNetSensor(DPCNetSensorConfig(model=str(model)))
        for k, (left, right) in enumerate(pairs, start=1):
            if through_mirror:
                left, right = np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1])
            sensor.add_images(k * STEP, left, right)
        results = [
            sensor.add_vo(k * STEP, (k + 1) * STEP, conjugation @ step @ conjugation if through_mirror else step)
            for k, step in enumerate(steps, start=1)
        ]
        assert results[-1] is not None
        estimate = np.eye(4)
        for step in steps:
            estimate = (conjugation @ step @ conjugation if through_mirror else step) @ estimate
        return results[-1].transform @ np.linalg.inv(estimate)  # the correction

    for model, equivariant in ((mirrored, True), (tiny_model, False)):
        seen, through = correct(model, False), correct(model, True)
        difference = np.abs(se3_log(through) - se3_log(conjugation @ seen @ conjugation)).max()
        assert (difference < 1e-6) if equivariant else (difference > 1e-4), (model.name, difference)


def test_a_camera_of_another_rig_is_refused(ros_context, tmp_path: Path) -> None:
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig
    from pvo_pseudosensors.dpc_net.model import DPCNet, DPCTask
    from pvo_pseudosensors.learning.checkpoint import save_model
    from sensor_msgs.msg import CameraInfo

    config = DPCNetConfig(height=32, width=104, stem=(4, 4, 8), body=(8, 16), test_delta=3)
    rig = {"size": [620, 188], "focal_px": [300.0, 400.0], "baseline_m": [0.54, 0.54], "lens": [], "focal_scale": 1.0}
    model = save_model(
        tmp_path / "model", DPCNet(config), DPCTask(config, np.eye(6) * 1e-3, rig | {"baseline_scale": 1.0}).card()
    )

    def info(width: int, focal: float) -> CameraInfo:
        msg = CameraInfo()
        fill_stamp(msg.header.stamp, STEP)
        msg.width, msg.height = width, 188
        msg.p = [focal, 0.0, width / 2, -focal * 0.54, 0.0, focal, 94.0, 0.0, 0.0, 0.0, 1.0, 0.0]
        return msg

    def script(left, right, vo, received, statuses, node) -> None:
        cameras = node.create_publisher(CameraInfo, "/stereo/right/camera_info", RELIABLE)
        wait_for(lambda: cameras.get_subscription_count() > 0, 10)
        cameras.publish(info(620, 350.0))  # the model's rig: only what cannot be checked is said
        wait_for(lambda: node.camera is not None, 10)
        cameras.publish(info(1226, 718.9))  # KITTI's own camera
        wait_for(lambda: node.refusal is not None, 10)
        vo.publish(vo_message(2 * STEP, STEP, np.eye(4)))
        wait_for(lambda: node.rejected >= 1, 10)
        wait_for(lambda: len(statuses) >= 3, 10)

    received, statuses = run_graph(ros_context, {"model": str(model)}, script)
    messages = [s.status[0].message for s in statuses]
    assert received == []
    assert messages[0].startswith("rig check: the lens cannot be checked: the model corrects no lens distortion")
    refused = "not this DPC-Net model's rig: images are 1226x188, the model's rig 620x188; calib.txt's focal 718.9 px"
    assert messages[1].startswith(refused) and statuses[1].status[0].level == DiagnosticStatus.ERROR
    assert messages[-1].startswith(refused)  # and the VO of that camera gets no correction


def test_a_missing_model_is_reported_and_the_node_keeps_running(ros_context, tmp_path: Path) -> None:
    def script(left, right, vo, received, statuses, node) -> None:
        vo.publish(vo_message(2 * STEP, STEP, np.eye(4)))
        vo.publish(vo_message(3 * STEP, 2 * STEP, np.eye(4)))
        wait_for(lambda: len(statuses) >= 2, 20)

    received, statuses = run_graph(ros_context, {"model": str(tmp_path / "none")}, script)
    assert received == [] and all(s.status[0].level == DiagnosticStatus.ERROR for s in statuses)
    assert "model directory not found" in statuses[0].status[0].message


def test_a_window_waits_for_images_that_come_after_its_vo(ros_context, tiny_model: Path) -> None:
    """In a graph the VO can finish a window before this sensor has its stereo pair: the window waits and the
    pair's arrival gives the same correction as images-first; a pair that never comes is given up, with why."""
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig

    rng = np.random.default_rng(4)
    images = {k: rng.integers(0, 255, (64, 208), dtype=np.uint8) for k in range(1, 12)}
    motions = {k: se3_exp(np.r_[0.0, 0.0, 0.5, 0.0, 0.002 * k, 0.0]) for k in range(2, 12)}
    first = DPCNetSensor(DPCNetSensorConfig(model=str(tiny_model)))
    for k in range(1, 5):
        first.add_images(k * STEP, images[k], images[k])
    for k in (2, 3):
        assert first.add_vo((k - 1) * STEP, k * STEP, motions[k]) is None
    expected = first.add_vo(3 * STEP, 4 * STEP, motions[4])
    assert expected is not None

    late = DPCNetSensor(DPCNetSensorConfig(model=str(tiny_model)))
    for k in (1, 2, 3):
        late.add_images(k * STEP, images[k], images[k])
    for k in (2, 3, 4):
        assert late.add_vo((k - 1) * STEP, k * STEP, motions[k]) is None
    assert late.dropped is None  # waiting, not dropped
    waited = late.add_images(4 * STEP, images[4], images[4])
    assert waited is not None and (waited.reference_stamp, waited.stamp) == (STEP, 4 * STEP)
    np.testing.assert_allclose(waited.transform, expected.transform, atol=1e-12)
    # the pair at 7 never comes: the next completed window gives that one up and says why
    for k in (5, 6):
        late.add_images(k * STEP, images[k], images[k])
    for k in (5, 6, 7):
        assert late.add_vo((k - 1) * STEP, k * STEP, motions[k]) is None
    assert late.dropped is None and late.pending is not None
    for k in (8, 9, 10):
        late.add_images(k * STEP, images[k], images[k])
        assert late.add_vo((k - 1) * STEP, k * STEP, motions[k]) is None
    assert late.dropped == "the window 0.400-0.700 s is dropped: no stereo pair at 0.700 s"
