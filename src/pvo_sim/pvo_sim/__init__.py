"""The synthetic world, ROS-free: ``simulate(SimConfig(...), out_dir)`` renders a stereo sequence in the KITTI
layout (images, poses, times, calib, sun/IMU/GPS sidecars, optional depth) under the ephemeris sun."""

from .degrade import CameraModel, Degradations
from .paths import kitti_path, procedural_path
from .render import KITTI_FOCAL_PER_PIXEL_WIDTH, ImuNoise, SimConfig, SimResult, camera_trajectory, simulate
from .world import PRESETS, World, WorldSpec, build_world

__all__ = [
    "KITTI_FOCAL_PER_PIXEL_WIDTH",
    "PRESETS",
    "CameraModel",
    "Degradations",
    "ImuNoise",
    "SimConfig",
    "SimResult",
    "World",
    "WorldSpec",
    "build_world",
    "camera_trajectory",
    "kitti_path",
    "procedural_path",
    "simulate",
]
