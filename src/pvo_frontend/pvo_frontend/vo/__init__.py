"""ROS-free stereo visual odometry (thesis ch. 3, app. B)."""

from .config import DetectorConfig, RansacConfig, SolverConfig, TrackerConfig, TrackingConfig, VOConfig, flatten, from_flat
from .pipeline import FrameResult, FrameStatus, StereoVO
from .solver import RobustLoss, SolveResult, solve_motion

__all__ = [
    "DetectorConfig",
    "FrameResult",
    "FrameStatus",
    "RansacConfig",
    "RobustLoss",
    "SolveResult",
    "SolverConfig",
    "StereoVO",
    "TrackerConfig",
    "TrackingConfig",
    "VOConfig",
    "flatten",
    "from_flat",
    "solve_motion",
]
