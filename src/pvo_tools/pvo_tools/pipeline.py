"""The node graph's algorithms as plain objects over a recorded bag: what ``stereo_vo`` → ``simulated_sun`` or
``sun_bcnn`` (and ``hydranet``, ``dpc_net``) → ``fusion`` compute, without ROS. The demo runs it beside the real graph to check
that both agree."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.camera import StereoCamera
from pvo_core.msgconv import image_to_array
from pvo_frontend.vo import FrameStatus, StereoVO, VOConfig
from pvo_fusion.sun_reference import SunReference
from pvo_pseudosensors.simulated_sun import SimulatedSunConfig, SimulatedSunSensor

from pvo_fusion import (
    FusionConfig,
    FusionGraph,
    OfflineResult,
    RelativeMeasurement,
    SunMeasurement,
    ordered_events,
    run_offline,
    sun_events,
)

from .samples import StereoSample

Array = NDArray[np.float64]


@dataclass
class PipelineResult:
    """Per frame stamp: VO poses T_odom,cam and their covariances; the VO and sun measurements; the fusion's."""

    stamps: NDArray[np.int64]
    vo_poses: Array
    vo_covariances: Array
    vo: list[RelativeMeasurement]
    sun: list[SunMeasurement]
    fused: OfflineResult
    rotations: list[RelativeMeasurement] = field(default_factory=list)
    corrections: list[RelativeMeasurement] = field(default_factory=list)


def run_pipeline(
    sample: StereoSample,
    vo_config: VOConfig,
    sun_config: Any,
    fusion_config: FusionConfig,
    sun_reference: SunReference | None,
    initial_pose: Array,
    sun_stamps: list[int] | None = None,
    rotation_config: Any = None,
    arrivals: dict[int, list[str]] | None = None,
    correction_config: Any = None,
    correction_windows: list[tuple[int, int]] | None = None,
) -> PipelineResult:
    """Every stereo pair through :class:`StereoVO`; the sun from every ground-truth sun vector through the
    simulated sun sensor (``sun_config``: a :class:`SimulatedSunConfig`) or from every left image through
    Sun-BCNN (a :class:`~pvo_pseudosensors.sun_bcnn.estimator.SunBCNNSensorConfig`), or none (None); both through a
    :class:`FusionGraph` in the usual arrival order (:func:`pvo_fusion.run_offline`; each sun before the next
    frame); ``sun_stamps``: the frames a ``sun_bcnn`` node estimated at (it counts the images it receives: one it
    never got shifts its choice); ``rotation_config``: a
    :class:`~pvo_pseudosensors.hydranet.estimator.HydraNetSensorConfig` adds HydraNet's rotations between
    consecutive left images, each reaching the fusion before the VO of its frame (HydraNet is the faster);
    ``correction_config``: a :class:`~pvo_pseudosensors.dpc_net.estimator.DPCNetSensorConfig` adds DPC-Net's
    corrections of the VO over Δp frames (``correction_windows``: exactly the (first, last) frame windows a
    ``dpc_net`` node published; one that missed a VO transform starts its windows elsewhere).
    ``arrivals`` (VO frame stamp -> the kinds of the measurements the fusion node took since the frame before,
    in order: its status's ``arrivals``): every measurement is taken in the order the node took it instead (the
    sensors race the VO for each image; load decides who wins)."""
    camera = StereoCamera.from_camera_infos(sample.left_info, sample.right_info)
    vo = StereoVO(camera, vo_config)
    stamps = sample.frame_stamps
    poses, covariances, measurements = [], [], []
    previous: int | None = None
    for stamp in stamps:
        left, right = sample.pairs[int(stamp)]
        result = vo.process(image_to_array(left), image_to_array(right), int(stamp) * 1e-9)
        if result.transform is not None and result.covariance is not None and previous is not None:
            measurements.append(RelativeMeasurement(int(stamp), previous, result.transform, result.covariance))
        if result.status is not FrameStatus.REJECTED:
            previous = int(stamp)
        poses.append(result.pose)
        covariances.append(result.pose_covariance)
    if sun_config is None:
        sun = []
    elif isinstance(sun_config, SimulatedSunConfig):
        sun = simulated_sun(sample, sun_config)
    else:
        sun = learned_sun(sample, sun_config, sun_stamps)
    rotations = learned_rotations(sample, rotation_config) if rotation_config is not None else []
    corrections = []
    if correction_config is not None:
        corrections = learned_corrections(sample, correction_config, measurements, correction_windows)
    graph = FusionGraph(fusion_config, sun_reference)
    graph.set_initial_pose(initial_pose)
    others = [*sun_events(sun), *(("rotation", m) for m in rotations), *(("correction", m) for m in corrections)]
    if arrivals is None:
        events = ordered_events(measurements, others, before={"rotation"})
    else:
        events = in_node_order(measurements, others, arrivals)
    fused = run_offline(graph, stamps, events, covariance_every=1)
    return PipelineResult(stamps, np.array(poses), np.array(covariances), measurements, sun, fused, rotations, corrections)


def in_node_order(vo: list[RelativeMeasurement], others: list[Any], arrivals: dict[int, list[str]]) -> list[Any]:
    """The events as the fusion node took them: before each VO frame the measurements it reported taking since
    the frame before (``arrivals``: ``kind@stamp_ns``, or a bare ``kind`` - then each kind's next in its
    sensor's order). Those it never received (published before it subscribed) and those it took after its last
    report (they reached no published estimate) are left out."""
    queues: dict[str, list[Any]] = {}
    for kind, m in others:
        queues.setdefault(kind, []).append(m)
    used: dict[str, set[int]] = {kind: set() for kind in queues}
    events: list[Any] = []

    def take(kind: str, stamp: int | None) -> Any | None:
        for position, m in enumerate(queues.get(kind, [])):
            if position not in used[kind] and (stamp is None or int(m.stamp) == stamp):
                used[kind].add(position)
                return m
        return None

    for m in vo:
        for entry in arrivals.get(int(m.stamp), []):
            kind, sep, stamp = entry.partition("@")
            taken = take(kind, int(stamp) if sep else None)
            if taken is not None:
                events.append((kind, taken))
        events.append(("vo", m))
    return events


def learned_rotations(sample: StereoSample, config: Any) -> list[RelativeMeasurement]:
    """What ``hydranet`` publishes for the sample's left images, as the fusion reads it."""
    from pvo_core.lie import quaternion_to_rotation
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor

    sensor = HydraNetSensor(config)
    rotations = []
    for stamp in sample.frame_stamps:
        estimate = sensor.estimate(image_to_array(sample.pairs[int(stamp)][0]), int(stamp))
        if estimate is not None:
            transform = np.eye(4)
            q = estimate.quaternion
            transform[:3, :3] = quaternion_to_rotation(q / np.linalg.norm(q))  # as the fusion node reads the message
            rotations.append(RelativeMeasurement(int(stamp), estimate.earlier_stamp, transform, estimate.pose_covariance, True))
    return rotations


def learned_corrections(
    sample: StereoSample, config: Any, vo: list[RelativeMeasurement], windows: list[tuple[int, int]] | None = None
) -> list[RelativeMeasurement]:
    """What ``dpc_net`` publishes for the sample's stereo pairs and the VO's transforms ``vo`` (each frame's pair
    before the VO that ends there, as on the robot), as the fusion reads it. ``windows``: only these (first, last)
    frame windows, each from its own first frame (the sensor is fed only the VO transforms inside them, so its
    windows start where a node's did whatever that node missed before)."""
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor

    sensor = DPCNetSensor(config)
    by_stamp = {int(m.stamp): m for m in vo}
    if windows is not None:
        inside = {int(m.stamp) for m in vo for first, last in windows if first < int(m.stamp) <= last}
        by_stamp = {stamp: m for stamp, m in by_stamp.items() if stamp in inside}
    corrections = []
    for stamp in sample.frame_stamps:
        left, right = sample.pairs[int(stamp)]
        sensor.add_images(int(stamp), image_to_array(left), image_to_array(right))
        m = by_stamp.get(int(stamp))
        if m is None:
            continue
        correction = sensor.add_vo(m.reference_stamp, m.stamp, m.transform, m.covariance)
        if correction is not None:
            corrections.append(
                RelativeMeasurement(correction.stamp, correction.reference_stamp, correction.transform, correction.covariance)
            )
    if windows is not None:
        wanted = set(windows)
        corrections = [m for m in corrections if (int(m.reference_stamp), int(m.stamp)) in wanted]
    return corrections


def simulated_sun(sample: StereoSample, config: SimulatedSunConfig) -> list[SunMeasurement]:
    """What ``simulated_sun`` publishes for the sample's ground-truth sun vectors."""
    sensor = SimulatedSunSensor(config)
    sun = []
    for stamp in sorted(sample.sun):
        measured = sensor.measure(sample.sun[stamp])
        if measured is not None:
            sun.append(SunMeasurement(int(stamp), measured[0], measured[1]))
    return sun


def learned_sun(sample: StereoSample, config: Any, stamps: list[int] | None = None) -> list[SunMeasurement]:
    """What ``sun_bcnn`` publishes for the sample's left images: every N-th (the first included), or the
    frames at ``stamps`` (in order: the sensor's dropout seed counts its estimates)."""
    from pvo_pseudosensors.sun_bcnn.estimator import SunBCNNSensor

    sensor = SunBCNNSensor(config)
    frames = [int(s) for k, s in enumerate(sample.frame_stamps) if not k % config.every_n] if stamps is None else stamps
    sun = []
    for stamp in frames:
        estimate = sensor.estimate(image_to_array(sample.pairs[int(stamp)][0]))
        sun.append(SunMeasurement(int(stamp), estimate.direction, estimate.covariance))
    return sun
