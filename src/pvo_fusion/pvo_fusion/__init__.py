"""pvo_fusion: the sliding-window GTSAM smoother (ROS-free :class:`FusionGraph`) and the ``fusion`` node."""

from .config import FusionConfig
from .graph import FusedPose, FusionGraph, run_measurements
from .measurements import RelativeMeasurement, SunMeasurement

__all__ = ["FusedPose", "FusionConfig", "FusionGraph", "RelativeMeasurement", "SunMeasurement", "run_measurements"]
