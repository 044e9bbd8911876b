"""pvo_fusion: the sliding-window GTSAM smoother (ROS-free :class:`FusionGraph`), its offline runner, the
VO-covariance calibration, and the ``fusion`` node."""

from .calibration import CalibrationSequence, VOCalibration, calibrate_vo, vo_measurements
from .config import FusionConfig
from .graph import FusedPose, FusionGraph
from .measurements import RelativeMeasurement, SunMeasurement
from .offline import OfflineResult, ordered_events, run_offline, sun_events
from .vo_bias import VOBiasTracker, debiased_motions

__all__ = [
    "CalibrationSequence",
    "FusedPose",
    "FusionConfig",
    "FusionGraph",
    "OfflineResult",
    "RelativeMeasurement",
    "SunMeasurement",
    "VOBiasTracker",
    "VOCalibration",
    "calibrate_vo",
    "debiased_motions",
    "ordered_events",
    "run_offline",
    "sun_events",
    "vo_measurements",
]
