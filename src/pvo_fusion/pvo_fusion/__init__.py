"""pvo_fusion: the sliding-window GTSAM smoother (ROS-free :class:`FusionGraph`), its offline runner, the
VO-covariance calibration, and the ``fusion`` node."""

from .calibration import CalibrationSequence, VOCalibration, calibrate_vo, vo_measurements
from .config import FusionConfig
from .graph import FusedPose, FusionGraph
from .measurements import RelativeMeasurement, SunMeasurement
from .offline import OfflineResult, ordered_events, run_offline, sun_events

__all__ = [
    "CalibrationSequence",
    "FusedPose",
    "FusionConfig",
    "FusionGraph",
    "OfflineResult",
    "RelativeMeasurement",
    "SunMeasurement",
    "VOCalibration",
    "calibrate_vo",
    "ordered_events",
    "run_offline",
    "sun_events",
    "vo_measurements",
]
