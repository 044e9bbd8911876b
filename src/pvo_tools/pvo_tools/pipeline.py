"""The node graph's algorithms as plain objects over a recorded bag: what ``stereo_vo`` → ``simulated_sun`` →
``fusion`` compute, without ROS. The demo runs it beside the real graph to check that both agree."""

from __future__ import annotations

from dataclasses import dataclass

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


def run_pipeline(
    sample: StereoSample,
    vo_config: VOConfig,
    sun_config: SimulatedSunConfig,
    fusion_config: FusionConfig,
    sun_reference: SunReference | None,
    initial_pose: Array,
) -> PipelineResult:
    """Every stereo pair through :class:`StereoVO`, every ground-truth sun vector through the simulated sun
    sensor, and both through a :class:`FusionGraph` in arrival order (:func:`pvo_fusion.run_offline`)."""
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
    sensor = SimulatedSunSensor(sun_config)
    sun = []
    for stamp in sorted(sample.sun):
        measured = sensor.measure(sample.sun[stamp])
        if measured is not None:
            sun.append(SunMeasurement(int(stamp), measured[0], measured[1]))
    graph = FusionGraph(fusion_config, sun_reference)
    graph.set_initial_pose(initial_pose)
    fused = run_offline(graph, stamps, ordered_events(measurements, sun_events(sun)), covariance_every=1)
    return PipelineResult(stamps, np.array(poses), np.array(covariances), measurements, sun, fused)
