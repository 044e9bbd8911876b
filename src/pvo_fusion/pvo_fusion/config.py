"""Typed configuration of the fusion graph; the ``fusion`` node's parameters are its dotted fields.

``config/fusion.yaml`` holds the same defaults (a test checks they agree).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from pvo_core.config import flatten as _flatten
from pvo_core.config import from_flat as _from_flat

LAG_UNITS = ("frames", "seconds")
LINEAR_SOLVERS = ("qr", "cholesky")
SMOOTHERS = ("incremental", "batch")
PRIOR_SOURCES = ("identity", "given")
SUN_REFERENCES = ("ephemeris", "fixed", "table")


@dataclass(frozen=True)
class WindowConfig:
    """Fixed-lag window: states older than ``lag`` (frames or seconds) behind the newest are marginalised.

    100 frames (10 s at 10 Hz, ten sun measurements) smooths each pose with the sun measurements of the
    next 10 s: on the KITTI sun experiment the rotational gain grows with the lag (GT-Sun-10: -30 % at 10,
    -31 % at 30, -35.5 % at 100, -39 % at 200 frames) while the cost per frame grows too (seq 00:
    2.6 s at 10, 6-8 s at 100, 17 s at 200 frames)."""

    lag: float = 100.0
    lag_unit: str = "frames"


@dataclass(frozen=True)
class SolverConfig:
    """The smoother: ``incremental`` (iSAM2, ``iterations`` Gauss-Newton passes per update) or ``batch``
    (Levenberg-Marquardt over the window, at most ``iterations`` iterations). QR keeps long drifting chains
    solvable (see the module notes in :mod:`pvo_fusion.graph`). Three iSAM2 passes let a sun correction's
    relinearisation of the window finish in the sun's own update, off the VO -> odometry path (with two,
    the next VO update paid it: 6 ms instead of 1.5 ms); the estimates are the same."""

    smoother: str = "incremental"
    linear_solver: str = "qr"
    iterations: int = 3
    relinearize_threshold: float = 1e-3
    relative_error_tol: float = 1e-9
    absolute_error_tol: float = 1e-12


@dataclass(frozen=True)
class PriorConfig:
    """Prior on the first state: the identity, or a pose given by the caller (ground truth, GPS/heading)."""

    source: str = "identity"
    sigma_rotation: float = 1e-4
    sigma_translation: float = 1e-3


@dataclass(frozen=True)
class VOInputConfig:
    """``/pvo/vo/relative``. ``covariance_scale`` multiplies each ROS-order variance (x y z rotX rotY rotZ).

    The VO creates the states, so its gate tests each motion against the previous one (constant
    velocity): innovation ``Log(T_k,k-1 T_k-1,k-2^-1)`` against ``Σ_k + Σ_k-1 + diag(motion_change_sigma²)``
    (m, m, m, rad, rad, rad per frame). A gated motion is dropped; the next frame bridges the gap.
    Whatever the gate, a motion faster than ``max_speed`` (m/s) or ``max_angular_rate`` (rad/s) over its
    interval is physically impossible for a vehicle and rejected (``implausible_motion``); one spanning more
    than ``max_interval`` seconds is no frame-to-frame motion (a far-future or corrupt stamp:
    ``interval_too_long``). A gap (missing frames, a restarted VO) is bridged from the newest state with the
    last motion extrapolated over it (constant velocity) and the covariance of a velocity that may have
    changed by ``gap_sigma`` (m/s and rad/s, ROS order, per second of gap) plus the last motion's own
    covariance scaled to the gap. A motion with a variance of ``lost_variance`` or more is a frame the VO lost: bridged
    the same way, its motion not used (bridges in a row grow as one outage of their summed length), with ``gap_sigma``
    times ``lost_sigma_scale``: the VO often loses its frames where the vehicle's motion changes, and its last measured
    motion before them may be wrong already.

    ``gain_sigma`` = (translation, rotation), dimensionless: errors that grow with the motion. A calibration error
    (focal length, baseline, lens) makes a stereo VO read distances and turns a few per cent long or short, which
    its per-frame covariance does not carry; each motion's covariance gets ``σ_t² t tᵀ`` (t its translation, m) and
    ``σ_r² φ φᵀ`` (φ its rotation vector, rad) added — nothing on a straight road, most in a turn, where a rotation
    sensor's reading would otherwise be gated out against an overconfident VO. (0, 0): no such term.
    """

    enabled: bool = True
    covariance_scale: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    lost_variance: float = 1000.0
    gate_probability: float = 0.0
    motion_change_sigma: tuple[float, ...] = (0.5, 0.5, 1.0, 0.05, 0.1, 0.05)
    max_speed: float = 100.0
    max_angular_rate: float = 10.0
    max_interval: float = 10.0
    gap_sigma: tuple[float, ...] = (1.0, 1.0, 2.0, 0.05, 0.1, 0.05)
    lost_sigma_scale: float = 1.0
    gain_sigma: tuple[float, ...] = (0.0, 0.0)


@dataclass(frozen=True)
class SunInputConfig:
    """``/pvo/sun/direction``: zenith/azimuth factor with a Huber loss (k on the whitened residual).

    ``bias_sigma`` (rad, zenith and azimuth) > 0 gives the readings a shared offset state b: each reading is
    ``f(s_meas) = f(C_map,k^T s_map) + b + noise``, b starts as N(0, bias_sigma²) and walks by
    ``bias_walk_sigma`` (rad/√s) between readings. For a learned sun (Sun-BCNN), whose errors are mostly an offset
    shared by a drive's readings: fused as independent they rotate a good VO towards the offset; with the state the
    offset is learned from the readings and only the heading drift faster than its walk is corrected. (0, 0): no
    state, every reading independent (a sun sensor with white noise, GT-Sun-N)."""

    enabled: bool = True
    huber_k: float = 1.345
    gate_probability: float = 0.9999
    reference: str = "ephemeris"
    reference_direction: tuple[float, ...] = (0.0, 0.0, 1.0)
    reference_table: str = ""
    ephemeris_time_offset: float = 0.0
    bias_sigma: tuple[float, ...] = (0.0, 0.0)
    bias_walk_sigma: tuple[float, ...] = (0.0, 0.0)

    @property
    def has_bias(self) -> bool:
        return max(self.bias_sigma, default=0.0) > 0.0


@dataclass(frozen=True)
class CorrectionInputConfig:
    """``/pvo/dpc/correction``: a between factor over the Δp frames it spans.

    ``vo_bias_windows`` > 0: the corrections also teach the VO's bias (:class:`pvo_fusion.vo_bias.VOBiasTracker`):
    the running mean of their disagreement with the VO's chain under them, per frame, over about this many
    corrections, is removed from each later VO motion on the ``vo_bias_axes`` (ROS order, 1 = tracked). A
    systematic VO error (a miscalibrated rig) that the VO's per-frame covariance does not carry then stops
    accumulating between the corrections. 0: the VO's motions as it reads them.

    ``vo_rotation_scale_windows`` > 0: the corrections also teach how much too long or short the VO reads its turns
    (the rotation vector's scale, least squares over about this many corrections; ``inf``: all alike), and each later
    VO rotation is stretched by ``vo_rotation_scale_gain`` (0 < gain ≤ 1) of that — a lens or focal-length error
    scales every turn, which the additive bias cannot carry. 0: none. ``vo_translation_scale_windows`` > 0: the same
    for the length of the VO's steps (a focal length off scales the depth it reads, so every step), no gain."""

    enabled: bool = True
    gate_probability: float = 0.9999
    vo_bias_windows: float = 0.0
    vo_bias_axes: tuple[float, ...] = (1.0, 1.0, 1.0, 0.0, 0.0, 0.0)
    vo_rotation_scale_windows: float = 0.0
    vo_rotation_scale_gain: float = 1.0
    vo_translation_scale_windows: float = 0.0


@dataclass(frozen=True)
class RotationInputConfig:
    """``/pvo/hydranet/rotation``: rotation-only factor; skipped when det(Σ_rot) exceeds ``max_covariance_det``;
    ``huber_k`` > 0 puts a Huber loss on its whitened residual (0: plain L2, eq. 7.22).

    The gate is tighter than the other inputs': HydraNet is overconfident where the flow is an interpolation
    (a turn across an empty square). On the long validation drives (nine, 271-1000 frames) the model shipped then
    fused rotation m-ATE changed +5.4 % at 0.9999, -1.7 % at 0.99, -5.4 % at 0.95, -7.9 % at 0.9, -10.2 % at 0.8,
    -8.3 % at 0.65 (the two-corpus model's: +9.3, +2.8, -4.4, -6.6, -7.8, -7.5 %; `scripts/hydranet_validation_drives.py`).
    Chosen again with the model on 48 drives (the sixteen drives and their mirrors, clean, through the thesis's lens
    and with the focal length 3 % off): the shipped model's mean m-ATE change (translation / rotation) -10.9 / +1.1 % at
    0.9, -13.6 / -7.7 % at 0.8, -12.9 / -12.5 % at 0.65, -9.6 / -11.3 % at 0.5 (the model it replaced: -5.1 / +11.6,
    -10.1 / -1.1, -11.6 / -9.7, -9.1 / -10.5 %).

    ``bias_sigma`` (rad, about the camera's x y z) > 0 gives the rotations an offset state b shared by the readings of
    ``bias_interval`` seconds: each reading is ``C_from,to_meas = C_from,to Exp(b + noise)``; b starts as N(0, bias_sigma²)
    and walks by ``bias_walk_sigma`` (rad/√s) from one interval's state to the next. A learned rotation sensor's errors
    are partly an offset shared by a drive's pairs (HydraNet's yaw 0.02–0.05° per pair on a clean KITTI 10 drive, a third
    to a half of its per-pair sigma): fused as white noise, it turns a good VO by the drive's sum of it. (0 0 0): no
    state, every reading independent (eq. 7.22).

    ``vo_bias_windows`` > 0: the other way round — the rotations teach the *VO's* rotation bias, as the corrections
    can its translation (``CorrectionInputConfig``; :class:`pvo_fusion.vo_bias.VOBiasTracker`): the running mean of
    their disagreement with the VO's motions under them, over about this many readings, removed from each later VO
    motion on the ``vo_bias_axes`` (rotation axes only). 0: none. ``vo_rotation_scale_windows`` and
    ``vo_rotation_scale_gain``: the scale of the VO's turns learned from the rotations, as ``CorrectionInputConfig``'s
    (the two inputs' trackers each apply their own).

    ``bridge_gaps``: a VO gap (frames missing, the VO restarted) is bridged with the rotations received over it where
    they link its two ends frame pair by frame pair: the heading follows them instead of the last angular velocity,
    and the position moves at the last velocity along those headings (dead reckoning), the rotation's covariance
    theirs, composed. A chain that disagrees with the constant-velocity bridge beyond ``bridge_gate_probability``
    (χ², 3 dof, against both covariances) is not used. False: the constant-velocity bridge alone."""

    enabled: bool = True
    gate_probability: float = 0.65
    bridge_gaps: bool = True
    bridge_gate_probability: float = 0.9999
    max_covariance_det: float = 1e-4
    huber_k: float = 0.0
    bias_sigma: tuple[float, ...] = (0.0, 0.0, 0.0)
    bias_walk_sigma: tuple[float, ...] = (0.0, 0.0, 0.0)
    bias_interval: float = 1.0
    vo_bias_windows: float = 0.0
    vo_bias_axes: tuple[float, ...] = (0.0, 0.0, 0.0, 1.0, 1.0, 1.0)
    vo_rotation_scale_windows: float = 0.0
    vo_rotation_scale_gain: float = 1.0

    @property
    def has_bias(self) -> bool:
        return max(self.bias_sigma, default=0.0) > 0.0


@dataclass(frozen=True)
class InputsConfig:
    vo: VOInputConfig = field(default_factory=VOInputConfig)
    sun: SunInputConfig = field(default_factory=SunInputConfig)
    correction: CorrectionInputConfig = field(default_factory=CorrectionInputConfig)
    rotation: RotationInputConfig = field(default_factory=RotationInputConfig)


@dataclass(frozen=True)
class OutputConfig:
    """The published online pose (:mod:`pvo_fusion.output`): per frame it follows the smoother's motion and moves
    at most ``max_correction_sigma`` motion-model sigmas (``inputs.vo.gap_sigma`` over the frame interval, as
    lengths of the translation and the rotation) towards the newest estimate, so a correction after a VO gap
    is spread over frames instead of a jump; what is not caught up yet is added to the published covariance.
    0: publish the newest estimate as it is. 2.5 is half the 5-sigma jump a continuity check flags; runs
    without gaps never reach it."""

    max_correction_sigma: float = 2.5


@dataclass(frozen=True)
class FusionConfig:
    window: WindowConfig = field(default_factory=WindowConfig)
    solver: SolverConfig = field(default_factory=SolverConfig)
    prior: PriorConfig = field(default_factory=PriorConfig)
    inputs: InputsConfig = field(default_factory=InputsConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    #: Measurements attach to the state whose stamp is within this many seconds.
    stamp_tolerance: float = 0.001
    #: Measurements ahead of the newest VO state wait in a buffer of at most this many.
    max_pending: int = 1000

    def __post_init__(self) -> None:
        validate(self)


def validate(config: FusionConfig) -> None:
    """Raise ``ValueError`` naming the parameter for any out-of-range value."""
    gates = {
        "inputs.vo.gate_probability": config.inputs.vo.gate_probability,
        "inputs.sun.gate_probability": config.inputs.sun.gate_probability,
        "inputs.correction.gate_probability": config.inputs.correction.gate_probability,
        "inputs.rotation.gate_probability": config.inputs.rotation.gate_probability,
    }
    sun_bias = (*config.inputs.sun.bias_sigma, *config.inputs.sun.bias_walk_sigma)
    rotation_bias = (*config.inputs.rotation.bias_sigma, *config.inputs.rotation.bias_walk_sigma)
    checks: list[tuple[bool, str]] = [
        (config.window.lag > 0.0, "window.lag must be positive"),
        (config.window.lag_unit in LAG_UNITS, f"window.lag_unit must be one of {', '.join(LAG_UNITS)}"),
        (config.solver.linear_solver in LINEAR_SOLVERS, f"solver.linear_solver must be one of {', '.join(LINEAR_SOLVERS)}"),
        (config.solver.smoother in SMOOTHERS, f"solver.smoother must be one of {', '.join(SMOOTHERS)}"),
        (config.solver.iterations >= 1, "solver.iterations must be >= 1"),
        (config.solver.relinearize_threshold >= 0.0, "solver.relinearize_threshold must be >= 0"),
        (config.solver.relative_error_tol >= 0.0, "solver.relative_error_tol must be >= 0"),
        (config.solver.absolute_error_tol >= 0.0, "solver.absolute_error_tol must be >= 0"),
        (config.prior.source in PRIOR_SOURCES, f"prior.source must be one of {', '.join(PRIOR_SOURCES)}"),
        (config.prior.sigma_rotation > 0.0, "prior.sigma_rotation must be positive"),
        (config.prior.sigma_translation > 0.0, "prior.sigma_translation must be positive"),
        (
            len(config.inputs.vo.covariance_scale) == 6 and min(config.inputs.vo.covariance_scale) > 0.0,
            "inputs.vo.covariance_scale needs 6 positive values",
        ),
        (config.inputs.vo.lost_variance > 0.0, "inputs.vo.lost_variance must be positive"),
        (config.inputs.vo.lost_sigma_scale > 0.0, "inputs.vo.lost_sigma_scale must be positive"),
        (config.inputs.vo.max_speed > 0.0, "inputs.vo.max_speed must be positive (m/s)"),
        (config.inputs.vo.max_angular_rate > 0.0, "inputs.vo.max_angular_rate must be positive (rad/s)"),
        (config.inputs.vo.max_interval > 0.0, "inputs.vo.max_interval must be positive (s)"),
        (
            len(config.inputs.vo.gap_sigma) == 6 and min(config.inputs.vo.gap_sigma) > 0.0,
            "inputs.vo.gap_sigma needs 6 positive values (m/s, rad/s)",
        ),
        (
            len(config.inputs.vo.gain_sigma) == 2 and min(config.inputs.vo.gain_sigma) >= 0.0,
            "inputs.vo.gain_sigma needs 2 values >= 0 (translation, rotation; a share of the motion, 0 0 = none)",
        ),
        (
            len(config.inputs.vo.motion_change_sigma) == 6 and min(config.inputs.vo.motion_change_sigma) > 0.0,
            "inputs.vo.motion_change_sigma needs 6 positive values",
        ),
        (config.inputs.sun.huber_k >= 0.0, "inputs.sun.huber_k must be >= 0 (0 = no Huber loss)"),
        (config.inputs.rotation.huber_k >= 0.0, "inputs.rotation.huber_k must be >= 0 (0 = no Huber loss)"),
        (config.output.max_correction_sigma >= 0.0, "output.max_correction_sigma must be >= 0 (0 = off)"),
        (config.inputs.sun.reference in SUN_REFERENCES, f"inputs.sun.reference must be one of {', '.join(SUN_REFERENCES)}"),
        (len(config.inputs.sun.reference_direction) == 3, "inputs.sun.reference_direction needs 3 values"),
        (
            len(config.inputs.sun.bias_sigma) == 2 and min(config.inputs.sun.bias_sigma) >= 0.0,
            "inputs.sun.bias_sigma needs 2 values >= 0 (rad, zenith and azimuth; 0 0 = no bias state)",
        ),
        (
            len(config.inputs.sun.bias_walk_sigma) == 2 and min(config.inputs.sun.bias_walk_sigma) >= 0.0,
            "inputs.sun.bias_walk_sigma needs 2 values >= 0 (rad/√s)",
        ),
        (
            not config.inputs.sun.has_bias or min(sun_bias, default=0.0) > 0.0,
            "inputs.sun.bias_sigma and inputs.sun.bias_walk_sigma: all four > 0 for a bias state (bias_sigma 0 0: none)",
        ),
        (
            math.isfinite(config.inputs.correction.vo_bias_windows) and config.inputs.correction.vo_bias_windows >= 0.0,
            "inputs.correction.vo_bias_windows must be >= 0 (corrections; 0 = the VO's motions as read)",
        ),
        (
            len(config.inputs.correction.vo_bias_axes) == 6 and set(config.inputs.correction.vo_bias_axes) <= {0.0, 1.0},
            "inputs.correction.vo_bias_axes needs 6 values of 0 or 1 (x y z rotX rotY rotZ; 1 = tracked)",
        ),
        (
            config.inputs.correction.vo_rotation_scale_windows >= 0.0,  # NaN fails too
            "inputs.correction.vo_rotation_scale_windows must be >= 0 (corrections; inf = all alike; 0 = none)",
        ),
        (
            config.inputs.correction.vo_translation_scale_windows >= 0.0,
            "inputs.correction.vo_translation_scale_windows must be >= 0 (corrections; inf = all alike; 0 = none)",
        ),
        (
            math.isfinite(config.inputs.correction.vo_rotation_scale_gain)
            and 0.0 < config.inputs.correction.vo_rotation_scale_gain <= 1.0,
            "inputs.correction.vo_rotation_scale_gain must be in (0, 1] (the part of the learned scale applied)",
        ),
        (
            config.inputs.rotation.vo_rotation_scale_windows >= 0.0,
            "inputs.rotation.vo_rotation_scale_windows must be >= 0 (readings; inf = all alike; 0 = none)",
        ),
        (
            math.isfinite(config.inputs.rotation.vo_rotation_scale_gain)
            and 0.0 < config.inputs.rotation.vo_rotation_scale_gain <= 1.0,
            "inputs.rotation.vo_rotation_scale_gain must be in (0, 1] (the part of the learned scale applied)",
        ),
        (
            not (
                config.inputs.correction.vo_rotation_scale_windows > 0.0
                and config.inputs.rotation.vo_rotation_scale_windows > 0.0
            ),
            "inputs.correction.vo_rotation_scale_windows and inputs.rotation.vo_rotation_scale_windows: one input learns "
            "the scale of the VO's turns",
        ),
        (
            math.isfinite(config.inputs.rotation.vo_bias_windows) and config.inputs.rotation.vo_bias_windows >= 0.0,
            "inputs.rotation.vo_bias_windows must be >= 0 (readings; 0 = the VO's motions as read)",
        ),
        (
            len(config.inputs.rotation.vo_bias_axes) == 6
            and set(config.inputs.rotation.vo_bias_axes) <= {0.0, 1.0}
            and not any(config.inputs.rotation.vo_bias_axes[:3]),
            "inputs.rotation.vo_bias_axes needs 6 values of 0 or 1, the first three (translation) 0: a rotation measures none",
        ),
        (
            not (config.inputs.correction.vo_bias_windows > 0.0 and config.inputs.rotation.vo_bias_windows > 0.0)
            or not any(
                a and b for a, b in zip(config.inputs.correction.vo_bias_axes, config.inputs.rotation.vo_bias_axes, strict=False)
            ),
            "inputs.correction.vo_bias_axes and inputs.rotation.vo_bias_axes overlap: one input learns each axis's VO bias",
        ),
        (config.inputs.rotation.max_covariance_det > 0.0, "inputs.rotation.max_covariance_det must be positive"),
        (
            len(config.inputs.rotation.bias_sigma) == 3 and min(config.inputs.rotation.bias_sigma) >= 0.0,
            "inputs.rotation.bias_sigma needs 3 values >= 0 (rad, about x y z; 0 0 0 = no bias state)",
        ),
        (
            len(config.inputs.rotation.bias_walk_sigma) == 3 and min(config.inputs.rotation.bias_walk_sigma) >= 0.0,
            "inputs.rotation.bias_walk_sigma needs 3 values >= 0 (rad/√s)",
        ),
        (
            not config.inputs.rotation.has_bias or min(rotation_bias, default=0.0) > 0.0,
            "inputs.rotation.bias_sigma and inputs.rotation.bias_walk_sigma: all six > 0 for a bias state "
            "(bias_sigma 0 0 0: none)",
        ),
        (config.inputs.rotation.bias_interval > 0.0, "inputs.rotation.bias_interval must be positive (s)"),
        (config.stamp_tolerance >= 0.0, "stamp_tolerance must be >= 0"),
        (config.max_pending >= 0, "max_pending must be >= 0"),
    ]
    checks += [(0.0 <= p < 1.0, f"{name} must be in [0, 1) (0 disables the gate)") for name, p in gates.items()]
    for ok, message in checks:
        if not ok:
            raise ValueError(f"invalid fusion configuration: {message}")


flatten = _flatten  # {"section.leaf": value, ...} of a config; tuples become lists


def from_flat(values: Mapping[str, Any], base: FusionConfig | None = None) -> FusionConfig:
    """A :class:`FusionConfig` from dotted names over ``base`` (defaults); unknown names and bad values are errors."""
    return _from_flat(values, base or FusionConfig(), what="fusion")
