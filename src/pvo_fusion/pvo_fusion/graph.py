"""FusionGraph: the sliding-window GTSAM smoother that fuses VO with the pseudo-sensors.

One ``Pose3`` state ``x_i = T_map,cam_i`` per VO frame, keyed by the frame's stamp, in GTSAM's
``IncrementalFixedLagSmoother`` (iSAM2; or ``BatchFixedLagSmoother``, ``solver.smoother``): states
older than the lag are marginalised and their information stays as a Gaussian prior on the oldest
remaining states (thesis §5.4.2). The factors (see :mod:`.factors`):

    prior      x_0 ~ N(T_map,cam_0, Σ_prior)                          PriorFactorPose3
    VO         x_{k-1}^-1 x_k ~ T_{k-1,k} (RelativePose, Σ_vo)          BetweenFactorPose3
    sun        f(C_map,k^T s_map(t_k)) ~ f(s_k) (SunDirection, R_s)     sun_factor (Huber)
               (+ b_k with a sun bias state: b_0 ~ N(0, Σ_b), b_k - b_k-1 ~ N(0, Q Δt)   offset_walk)
    correction x_{k-Δp}^-1 x_k ~ T_{k-Δp,k} (DPC-Net, Σ_c)             BetweenFactorPose3
    rotation   C_{j}^T C_k ~ C_{j,k} (HydraNet, Σ_hn)                   rotation_factor
               (+ o_i with a rotation offset state, one per bias_interval: C_{j,k} Exp(o_i)   offset_walk)

Measurements attach to the state with the same stamp (within ``stamp_tolerance``); those ahead of
the newest VO frame wait in a buffer, those older than the window are dropped; every outcome is
counted in :attr:`FusionGraph.counts` under ``"<input>.<outcome>"``.

The linear systems use QR: with a prior on the first pose only, the absolute uncertainty grows
without bound along a long trajectory and Cholesky declares the window indeterminate after a few
thousand frames (KITTI 05 near frame 1726); the square-root (QR) solution keeps it solvable.
"""

from __future__ import annotations

import bisect
import time
from collections import Counter, deque
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, O, X
from numpy.typing import ArrayLike, NDArray
from pvo_core.covariance import gtsam_to_ros_covariance, is_positive_definite, ros_to_gtsam_covariance
from pvo_core.lie import se3_exp, se3_inverse, se3_log, so3_exp, so3_log

from .checkpoint import FusionCheckpoint
from .config import FusionConfig
from .factors import (
    between_measurement,
    offset_walk,
    rotation_error,
    rotation_factor,
    sun_error,
    sun_factor,
    wrap_angle,
    zenith_azimuth,
)
from .measurements import RelativeMeasurement, SunMeasurement, relative_problem, sun_problem
from .sun_reference import SunReference
from .vo_bias import VOBiasTracker

Array = NDArray[np.float64]

ACCEPTED = "accepted"
BUFFERED = "buffered"
#: an input the gate has kept out this long (s of the newest state's time, every reading of it gated) is reported (the
#: fusion node's status turns WARN): the estimate and that sensor disagree for good - one of them is lost, and an input
#: the gate keeps out cannot mend it. Measured in normal running: HydraNet's readings (gate 0.65) on the 48 validation
#: drives were gated at most 3.2 s on end, the lens card's corrections on its sixteen 0.9 s; where the VO turn scale
#: that card learned ran away (one drive fed errorless corrections, docs/dpc_net.md, stop 73) 12.6 s.
GATED_WARNING_SECONDS = 10.0


@dataclass(frozen=True)
class FusedPose:
    """A fused state: ``pose`` = T_map,cam (4x4) at ``stamp`` (ns); ``covariance`` ROS order, left perturbation."""

    stamp: int
    pose: Array
    covariance: Array | None = None


@dataclass
class _Batch:
    """New factors, variables and their smoother timestamps, added in one update."""

    factors: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)
    values: gtsam.Values = field(default_factory=gtsam.Values)
    timestamps: gtsam.FixedLagSmootherKeyTimestampMap = field(default_factory=gtsam.FixedLagSmootherKeyTimestampMap)


@dataclass
class _Pending:
    kind: str
    measurement: RelativeMeasurement | SunMeasurement


class FusionGraph:
    """Fixed-lag fusion of VO relative poses with sun directions, pose corrections and relative rotations."""

    def __init__(self, config: FusionConfig | None = None, sun_reference: SunReference | None = None) -> None:
        self.config = config or FusionConfig()
        self.sun_reference = sun_reference
        self.counts: Counter[str] = Counter()
        self.factor_counts: Counter[str] = Counter()
        self.last_update_seconds = 0.0
        self.last_rejection = ""
        self.gated_in_a_row: Counter[str] = Counter()  # per input kind: the gate's rejections since its last accepted one
        # per input kind in such a streak: the newest state's stamp at its first and at its latest rejection
        self._gated_span: dict[str, tuple[int, int]] = {}
        self.longest_gated_s: dict[str, float] = {}  # per input kind: the longest such streak in this graph's life (s)
        self._initial_pose: Array | None = None
        self._resume_stamp: int | None = None
        self._initial_covariance: Array | None = None
        self._tolerance_ns = round(self.config.stamp_tolerance * 1e9)
        scale = np.sqrt(np.asarray(self.config.inputs.vo.covariance_scale, dtype=float))
        self._vo_scale = np.outer(scale, scale)
        self._vo_gain = np.asarray(self.config.inputs.vo.gain_sigma, dtype=float)
        # per input kind that teaches the VO's bias (their axes do not overlap: validated)
        self.vo_biases = {
            kind: VOBiasTracker(
                source.vo_bias_windows,
                source.vo_bias_axes,
                rotation_scale_windows=getattr(source, "vo_rotation_scale_windows", 0.0),
                rotation_scale_gain=getattr(source, "vo_rotation_scale_gain", 1.0),
                translation_scale_windows=getattr(source, "vo_translation_scale_windows", 0.0),
            )
            for kind, source in (("correction", self.config.inputs.correction), ("rotation", self.config.inputs.rotation))
            if source.vo_bias_windows > 0.0
            or getattr(source, "vo_rotation_scale_windows", 0.0) > 0.0
            or getattr(source, "vo_translation_scale_windows", 0.0) > 0.0
        }
        from scipy.stats import chi2  # 0.5 s to import: only where a graph is built, not on `pvo --help`

        gate = self.config.inputs.rotation.bridge_gate_probability
        self._bridge_gate = chi2.ppf(gate, 3) if gate > 0.0 else np.inf
        self._gates = {
            name: (chi2.ppf(p, dof) if p > 0.0 else np.inf)
            for name, p, dof in (
                ("vo", self.config.inputs.vo.gate_probability, 6),
                ("sun", self.config.inputs.sun.gate_probability, 2),
                ("correction", self.config.inputs.correction.gate_probability, 6),
                ("rotation", self.config.inputs.rotation.gate_probability, 3),
            )
        }
        self._reset_smoother()

    # ------------------------------------------------------------------ set-up
    def _reset_smoother(self) -> None:
        self.gated_in_a_row.clear()  # a restarted window has no estimate for an input to disagree with yet
        self._gated_span.clear()
        solver = self.config.solver
        self._smoother: gtsam.IncrementalFixedLagSmoother | gtsam.BatchFixedLagSmoother
        if solver.smoother == "incremental":
            isam = gtsam.ISAM2Params()
            isam.setFactorization("QR" if solver.linear_solver == "qr" else "CHOLESKY")
            # Relinearise on every pass every variable whose update exceeds the threshold (0: all of them).
            isam.relinearizeSkip = 1
            isam.setRelinearizeThreshold(solver.relinearize_threshold)
            self._smoother = gtsam.IncrementalFixedLagSmoother(self.config.window.lag, isam)
        else:
            params = gtsam.LevenbergMarquardtParams()
            params.setLinearSolverType("MULTIFRONTAL_QR" if solver.linear_solver == "qr" else "MULTIFRONTAL_CHOLESKY")
            params.setMaxIterations(solver.iterations)
            params.setRelativeErrorTol(solver.relative_error_tol)
            params.setAbsoluteErrorTol(solver.absolute_error_tol)
            self._smoother = gtsam.BatchFixedLagSmoother(self.config.window.lag, params)
        self._stamps: list[int] = []  # live states, increasing
        self._keys: dict[int, int] = {}  # stamp -> key
        self._estimates = _Estimates()  # key -> latest estimate
        self._pending: deque[_Pending] = deque()
        self._finished: list[FusedPose] = []
        self._next_index = 0
        self._first_stamp: int | None = None
        self._last_motion: tuple[Array, Array] | None = None
        self._last_velocity: tuple[Array, Array, float] | None = None  # T_k,k-1, its covariance, its interval (s)
        self._bridged_since: int | None = None  # the newest measured motion's stamp while bridges follow it (ns)
        self._sun_bias: deque[tuple[int, int]] = deque()  # live sun offset states (key, stamp), oldest first
        self._next_bias = 0
        self._rotation_bias: deque[tuple[int, int]] = deque()  # live rotation offset states (key, first stamp)
        self._next_rotation_bias = 0

    def set_initial_pose(self, pose: ArrayLike, covariance: ArrayLike | None = None) -> None:
        """Prior of the first state (T_map,cam, 4x4; optional ROS-order left covariance). Before the first VO."""
        pose = np.asarray(pose, dtype=float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError("initial pose must be a finite 4x4 transform")
        if covariance is not None and not is_positive_definite(np.asarray(covariance, dtype=float).reshape(6, 6)):
            raise ValueError("initial pose covariance must be positive definite")
        if self._stamps:
            raise ValueError("the initial pose must be set before the first VO measurement")
        self._initial_pose = pose
        self._initial_covariance = None if covariance is None else np.asarray(covariance, dtype=float).reshape(6, 6)

    def checkpoint(self, pose: ArrayLike | None = None, covariance: ArrayLike | None = None) -> FusionCheckpoint | None:
        """The newest state (stamp, pose, marginal covariance) and the last VO velocity; None before the first VO.
        ``pose``/``covariance``: the newest state's, when the caller has just computed them (saves a marginal)."""
        if not self._stamps:
            return None
        return FusionCheckpoint(
            self._stamps[-1],
            self.pose() if pose is None else np.asarray(pose, dtype=float),
            self.covariance() if covariance is None else np.asarray(covariance, dtype=float),
            self._last_velocity,
            {kind: (tracker.bias, tracker.updates) for kind, tracker in self.vo_biases.items()},
            {
                kind: tracker.scale_sums
                for kind, tracker in self.vo_biases.items()
                if tracker.rotation_scale_windows or tracker.translation_scale_windows
            },
        )

    def resume(self, checkpoint: FusionCheckpoint) -> None:
        """Start from a checkpoint (before the first VO): the first state is the checkpoint's, at its stamp, with
        its covariance; the next VO bridges the time since with the checkpoint's velocity; the VO's bias goes on
        from what each input that teaches it here had learned."""
        self.set_initial_pose(checkpoint.pose, checkpoint.covariance)
        self._resume_stamp = int(checkpoint.stamp)
        self._last_velocity = checkpoint.velocity
        for kind, (bias, updates) in checkpoint.vo_biases.items():
            if kind in self.vo_biases:
                self.vo_biases[kind].restore(bias, updates, checkpoint.vo_scales.get(kind))

    # ------------------------------------------------------------------ state look-up
    @property
    def initial_pose(self) -> Array:
        """The first state's prior mean T_map,cam (the identity unless set)."""
        return np.eye(4) if self._initial_pose is None else self._initial_pose.copy()

    @property
    def started(self) -> bool:
        return bool(self._stamps)

    @property
    def window_size(self) -> int:
        return len(self._stamps)

    @property
    def newest_stamp(self) -> int | None:
        return self._stamps[-1] if self._stamps else None

    def _find(self, stamp: int) -> int | None:
        """Key of the live state within tolerance of ``stamp``."""
        live = self._find_stamp(stamp)
        return None if live is None else self._keys[live]

    def _find_stamp(self, stamp: int) -> int | None:
        """Stamp of the live state within tolerance of ``stamp``."""
        stamps = self._stamps
        i = bisect.bisect_left(stamps, stamp - self._tolerance_ns)
        if i < len(stamps) and abs(stamps[i] - stamp) <= self._tolerance_ns:
            return stamps[i]
        return None

    def _timestamp(self, stamp: int, index: int) -> float:
        if self.config.window.lag_unit == "frames":
            return float(index)
        assert self._first_stamp is not None
        return (stamp - self._first_stamp) * 1e-9

    def count(self, name: str, outcome: str) -> str:
        """Count an input's outcome (``accepted``, ``buffered``, ``rejected.<reason>`` ...); returns it."""
        return self._count(name, outcome)

    def _count(self, name: str, outcome: str) -> str:
        self.counts[f"{name}.{outcome}"] += 1
        if outcome == "gated":
            self.gated_in_a_row[name] += 1
            now = self._stamps[-1] if self._stamps else 0
            self._gated_span[name] = (self._gated_span.get(name, (now, now))[0], now)
            self.longest_gated_s[name] = max(self.longest_gated_s.get(name, 0.0), self.gated_seconds(name))
        elif outcome == ACCEPTED:
            self.gated_in_a_row.pop(name, None)
            self._gated_span.pop(name, None)
        if outcome not in (ACCEPTED, BUFFERED):
            self.last_rejection = f"{name}: {outcome}"
        return outcome

    def gated_seconds(self, name: str) -> float:
        """Over how long (s, the newest state's time from the first to the latest) every reading of input ``name`` has
        been gated; 0 when its last one was accepted (or none was gated). A sensor gone quiet does not lengthen it."""
        first, latest = self._gated_span.get(name, (0, 0))
        return (latest - first) * 1e-9

    # ------------------------------------------------------------------ inputs
    def add_vo(self, m: RelativeMeasurement) -> str:
        """A VO relative pose T_k,k-1: creates the state at ``m.stamp`` and updates the window."""
        if not self.config.inputs.vo.enabled:
            return self._count("vo", "disabled")
        problem = relative_problem(m)
        if problem is not None or m.rotation_only:
            return self._count("vo", f"rejected.{problem or 'rotation_only'}")
        if (m.stamp - m.reference_stamp) * 1e-9 > self.config.inputs.vo.max_interval:
            return self._count("vo", "rejected.interval_too_long")
        if not self._motion_plausible(m):
            return self._count("vo", "rejected.implausible_motion")
        if not self._stamps:
            if self._resume_stamp is not None and m.reference_stamp < self._resume_stamp:
                return self._count("vo", "rejected.before_checkpoint")
            self._start(m.reference_stamp if self._resume_stamp is None else self._resume_stamp)
        newest = self._stamps[-1]
        if m.stamp <= newest + self._tolerance_ns:
            if self._find(m.stamp) is not None:
                return self._count("vo", "rejected.duplicate_stamp")
            return self._count("vo", "rejected.out_of_order")
        transform = np.asarray(m.transform, dtype=float)
        if self.vo_biases and float(np.max(np.diag(m.covariance))) < self.config.inputs.vo.lost_variance:
            raw = transform
            # keyed by the states' own stamps, so a measurement stamped within the tolerance finds the chain
            reference = self._find_stamp(m.reference_stamp) or m.reference_stamp
            for tracker in self.vo_biases.values():
                tracker.observe(reference, m.stamp, raw)
                transform = tracker.debias(transform)
        motion_covariance = self._vo_covariance(transform, np.asarray(m.covariance, dtype=float))
        covariance = motion_covariance
        reference_key = self._find(m.reference_stamp)
        lost = float(np.max(np.diag(m.covariance))) >= self.config.inputs.vo.lost_variance
        gap = reference_key is None or reference_key != self._keys[newest]
        if gap or lost:
            # A gap (frames missing, a VO restarted, a reference outside the window) or a frame the VO lost (its
            # motion carries no information): bridge from the newest state with the constant-velocity motion and a
            # covariance sized to the time since the last measured motion, so the estimate stays continuous and
            # recovers as VO resumes. A lost frame is not linked by its own huge covariance: hundreds of rad of
            # rotation variance is no distribution on SO(3), and with sun readings on both sides such a link let
            # the smoother turn the window about the sun axis without bound (stop 78's drive 03bm: 1e10 m).
            self._count("vo", "gap" if gap else "lost")
            reference_key = self._keys[newest]
            transform, covariance = self._bridge(newest, m.stamp, 1.0 if gap else self.config.inputs.vo.lost_sigma_scale)
            transform, covariance = self._bridge_with_rotations(newest, m.stamp, transform, covariance)
            if self._bridged_since is None:
                self._bridged_since = newest
        elif not self._vo_motion_consistent(m.transform, covariance):
            return self._count("vo", "gated")
        else:
            self._bridged_since = None
        if m.stamp - m.reference_stamp > 0 and not lost:
            # the velocity a later gap is bridged with: this message's own motion over its own interval
            self._last_velocity = (np.asarray(m.transform, dtype=float), motion_covariance, (m.stamp - m.reference_stamp) * 1e-9)
        self._last_motion = (transform, motion_covariance)
        measured, cov = between_measurement(transform, covariance)
        key = X(self._next_index)
        factors = gtsam.NonlinearFactorGraph()
        factors.add(gtsam.BetweenFactorPose3(reference_key, key, measured, gtsam.noiseModel.Gaussian.Covariance(cov)))
        self.factor_counts["vo"] += 1
        values = gtsam.Values()
        initial = self._estimates[reference_key].compose(measured)
        values.insert(key, initial)
        self._estimates[key] = initial
        timestamps = gtsam.FixedLagSmootherKeyTimestampMap()
        timestamps.insert((key, self._timestamp(m.stamp, self._next_index)))
        self._stamps.append(m.stamp)
        self._keys[m.stamp] = key
        self._next_index += 1
        self._update(factors, values, timestamps)
        # Buffered measurements for this frame are gated against the updated window, then added.
        late = _Batch()
        self._attach_pending(m.stamp, late)
        if late.factors.size() > 0:
            self._update(late.factors, late.values, late.timestamps)
        return self._count("vo", ACCEPTED)

    def _vo_covariance(self, transform: Array, covariance: Array) -> Array:
        """The covariance the fusion gives a VO motion T_k,k-1 (ROS order): the VO's own, scaled per axis
        (``covariance_scale``), plus the motion-proportional term of ``gain_sigma``: σ_t² t tᵀ on the translation
        block and σ_r² φ φᵀ on the rotation block (φ = Log(C_k,k-1), the same in the left and the right tangent
        space since C φ = φ)."""
        scaled = covariance * self._vo_scale
        if not self._vo_gain.any():
            return scaled
        translation = transform[:3, 3]
        rotation = so3_log(transform[:3, :3])
        gained = scaled.copy()
        gained[:3, :3] += self._vo_gain[0] ** 2 * np.outer(translation, translation)
        gained[3:, 3:] += self._vo_gain[1] ** 2 * np.outer(rotation, rotation)
        return gained

    def _bridge(self, newest: int, stamp: int, sigma_scale: float = 1.0) -> tuple[Array, Array]:
        """T_stamp,newest under constant velocity over a gap of T seconds (n frame intervals), with covariance
        diag((T sigma_scale gap_sigma)^2) + n^2 Sigma_v; without a velocity yet, the identity with σ max_speed T (m)
        and min(max_angular_rate T, 1) (rad).

        Bridges in a row (frame after lost frame) share one growth: T and n count from the newest measured motion,
        and each link gets the increment diag(gap_sigma^2) (T^2 - T_0^2) + (n^2 - n_0^2) Sigma_v over its
        predecessors' T_0, n_0, so a VO lost frame by frame is as uncertain as the same outage bridged at once."""
        vo = self.config.inputs.vo
        gap = (stamp - newest) * 1e-9
        if self._last_velocity is None:
            # no motion measured yet: standing still, as far as a vehicle can move in the interval (max_speed,
            # max_angular_rate); the rotation's σ capped at 1 rad, a distribution on SO(3) still (lost_variance·I's
            # 31 rad is none)
            sigma = np.array([vo.max_speed * gap] * 3 + [min(vo.max_angular_rate * gap, 1.0)] * 3)
            return np.eye(4), np.diag(sigma**2)
        motion, motion_cov, seconds = self._last_velocity
        before = 0.0 if self._bridged_since is None else (newest - self._bridged_since) * 1e-9
        total = before + gap
        growth = total**2 - before**2
        sigma2 = (sigma_scale * np.asarray(vo.gap_sigma, dtype=float)) ** 2 * growth
        return se3_exp(gap / seconds * se3_log(motion)), np.diag(sigma2) + growth / seconds**2 * motion_cov

    def _rotation_chain(self, start: int, end: int) -> list[_Pending] | None:
        """The buffered rotations C_k,j that link ``start`` towards ``end`` (ns) pair by pair, in order, as far as
        they reach (the last pair's reading may not have come yet: the sensor and the VO race for each image); None
        if none starts at ``start``."""
        rotations = [item for item in self._pending if item.kind == "rotation"]
        chain: list[_Pending] = []
        current = start
        while abs(current - end) > self._tolerance_ns:
            following = [
                item
                for item in rotations
                if abs(item.measurement.reference_stamp - current) <= self._tolerance_ns  # type: ignore[union-attr]
                and current + self._tolerance_ns < item.measurement.stamp <= end + self._tolerance_ns
            ]
            if not following:
                break
            step = max(following, key=lambda item: item.measurement.stamp)  # the longest link, one per frame pair
            chain.append(step)
            current = step.measurement.stamp
        return chain or None

    def _bridge_with_rotations(self, newest: int, stamp: int, transform: Array, covariance: Array) -> tuple[Array, Array]:
        """The constant-velocity bridge T_stamp,newest (and its covariance, ROS order) with its rotation replaced by
        the buffered rotations that link the gap frame pair by frame pair from ``newest`` (``inputs.rotation.bridge_gaps``;
        what they do not reach, at the end of the gap, turns at the last angular velocity), and its translation
        dead-reckoned at the last velocity along those headings; the rotations used are taken from the buffer and
        counted ``rotation.bridged``. Unchanged without such a chain, a velocity, or past the gate."""
        rotation = self.config.inputs.rotation
        if not (rotation.enabled and rotation.bridge_gaps) or self._last_velocity is None:
            return transform, covariance
        chain = self._rotation_chain(newest, stamp)
        if chain is None:
            return transform, covariance
        motion, _, seconds = self._last_velocity
        # the last motion's displacement per second, in the frame it started from (x_{k-1} = -C^T t for T_k,k-1)
        velocity = -np.asarray(motion[:3, :3]).T @ np.asarray(motion[:3, 3]) / seconds
        orientation = np.eye(3)  # of the current frame of the chain in the newest state's frame
        position = np.zeros(3)
        chained = np.eye(3)  # C_current,newest
        rotation_covariance = np.zeros((3, 3))
        previous = newest
        for item in chain:
            m = item.measurement
            assert isinstance(m, RelativeMeasurement)
            step = np.asarray(m.transform, dtype=float)[:3, :3]  # C_k,j
            position = position + orientation @ velocity * ((m.stamp - previous) * 1e-9)
            # left perturbations compose as δ_total = δ_k + C_k δ_rest: the chain's covariance carried to its end
            rotation_covariance = step @ rotation_covariance @ step.T + np.asarray(m.covariance, dtype=float)[3:, 3:]
            chained = step @ chained
            orientation = orientation @ step.T
            previous = m.stamp
        rest = (stamp - previous) * 1e-9
        if rest > 0.0:  # the end of the gap no reading reached yet: the last motion's turn rate over it
            turn = so3_exp(rest / seconds * so3_log(np.asarray(motion[:3, :3], dtype=float)))
            position = position + orientation @ velocity * rest
            rotation_covariance = turn @ rotation_covariance @ turn.T + covariance[3:, 3:] * (rest / ((stamp - newest) * 1e-9))
            chained = turn @ chained
        innovation = so3_log(chained @ np.asarray(transform, dtype=float)[:3, :3].T)
        if float(innovation @ np.linalg.solve(rotation_covariance + covariance[3:, 3:], innovation)) > self._bridge_gate:
            self.counts["rotation.bridge_gated"] += 1
            return transform, covariance
        for item in chain:  # taken, not rejected: counted without becoming the status's last rejection
            self._pending.remove(item)
            self.counts[f"rotation.{BUFFERED}"] -= 1
            self.counts["rotation.bridged"] += 1
        bridged = np.eye(4)
        bridged[:3, :3] = chained
        bridged[:3, 3] = -chained @ position  # T_stamp,newest from the pose of the new frame in the newest's
        bridged_covariance = np.array(covariance, dtype=float)
        bridged_covariance[3:, 3:] = rotation_covariance
        bridged_covariance[:3, 3:] = 0.0
        bridged_covariance[3:, :3] = 0.0
        return bridged, bridged_covariance

    def _motion_plausible(self, m: RelativeMeasurement) -> bool:
        """Speed and angular rate of T_k,k-1 over its interval within what a vehicle can do."""
        seconds = (m.stamp - m.reference_stamp) * 1e-9
        xi = se3_log(np.asarray(m.transform, dtype=float))
        vo = self.config.inputs.vo
        translation = float(np.linalg.norm(np.asarray(m.transform, dtype=float)[:3, 3]))
        return translation <= vo.max_speed * seconds and float(np.linalg.norm(xi[3:])) <= vo.max_angular_rate * seconds

    def _vo_motion_consistent(self, transform: Array, covariance: Array) -> bool:
        """Constant-velocity Mahalanobis gate on a VO motion (left errors, ROS order)."""
        threshold = self._gates["vo"]
        if not np.isfinite(threshold) or self._last_motion is None:
            return True
        previous, previous_cov = self._last_motion
        change = se3_log(np.asarray(transform, dtype=float) @ se3_inverse(previous))
        sigma = np.asarray(self.config.inputs.vo.motion_change_sigma, dtype=float)
        innovation = covariance + previous_cov + np.diag(sigma**2)
        return float(change @ np.linalg.solve(innovation, change)) <= threshold

    def add_sun(self, m: SunMeasurement) -> str:
        """A sun direction in the camera frame at ``m.stamp``."""
        if not self.config.inputs.sun.enabled:
            return self._count("sun", "disabled")
        problem = sun_problem(m)
        if problem is not None:
            return self._count("sun", f"rejected.{problem}")
        return self._route("sun", m, m.stamp)

    def add_correction(self, m: RelativeMeasurement) -> str:
        """A pose correction T_k,k-Δp (DPC-Net) between two states of the window."""
        if not self.config.inputs.correction.enabled:
            return self._count("correction", "disabled")
        problem = relative_problem(m)
        if problem is not None:
            return self._count("correction", f"rejected.{problem}")
        return self._route("correction", m, m.stamp)

    def add_rotation(self, m: RelativeMeasurement) -> str:
        """A relative rotation C_k,j (HydraNet, ``rotation_only``) between two states of the window."""
        if not self.config.inputs.rotation.enabled:
            return self._count("rotation", "disabled")
        problem = relative_problem(m)
        if problem is not None:
            return self._count("rotation", f"rejected.{problem}")
        if float(np.linalg.det(np.asarray(m.covariance, dtype=float)[3:, 3:])) > self.config.inputs.rotation.max_covariance_det:
            return self._count("rotation", "rejected.covariance_too_large")
        return self._route("rotation", m, m.stamp)

    def _route(self, kind: str, m: RelativeMeasurement | SunMeasurement, stamp: int) -> str:
        if not self._stamps or stamp > self._stamps[-1] + self._tolerance_ns:
            if len(self._pending) >= self.config.max_pending:
                dropped = self._pending.popleft()
                self._count(dropped.kind, "dropped.buffer_full")
            self._pending.append(_Pending(kind, m))
            return self._count(kind, BUFFERED)
        if stamp < self._stamps[0] - self._tolerance_ns:
            return self._count(kind, "dropped.older_than_window")
        batch = _Batch()
        outcome = self._make_factor(kind, m, batch)
        if outcome == ACCEPTED:
            self._update(batch.factors, batch.values, batch.timestamps)
        return self._count(kind, outcome)

    def _attach_pending(self, stamp: int, batch: _Batch) -> None:
        """Move buffered measurements that now have their state into ``factors``."""
        keep: deque[_Pending] = deque()
        for item in self._pending:
            m_stamp = item.measurement.stamp
            if m_stamp > stamp + self._tolerance_ns:
                keep.append(item)
                continue
            self.counts[f"{item.kind}.{BUFFERED}"] -= 1
            self._count(item.kind, self._make_factor(item.kind, item.measurement, batch))
        self._pending = keep

    # ------------------------------------------------------------------ factor construction
    def _make_factor(self, kind: str, m: RelativeMeasurement | SunMeasurement, batch: _Batch) -> str:
        key = self._find(m.stamp)
        if key is None:
            return "dropped.no_state_at_stamp"
        if kind == "sun":
            assert isinstance(m, SunMeasurement)
            return self._make_sun(key, m, batch)
        assert isinstance(m, RelativeMeasurement)
        reference_key = self._find(m.reference_stamp)
        if reference_key is None:
            return "dropped.reference_not_in_window"
        if kind == "rotation":
            return self._make_rotation(reference_key, key, m, batch)
        measured, cov = between_measurement(m.transform, m.covariance)
        factor = gtsam.BetweenFactorPose3(reference_key, key, measured, gtsam.noiseModel.Gaussian.Covariance(cov))
        predicted = self._estimates[reference_key].between(self._estimates[key])
        e = gtsam.Pose3.Logmap(measured.between(predicted))
        # First-order Jacobians of the between error at the current estimate.
        j_to = np.eye(6)
        j_from = -predicted.inverse().AdjointMap()
        if not self._gate("correction", e, [reference_key, key], np.hstack([j_from, j_to]), cov):
            return "gated"
        batch.factors.add(factor)
        self.factor_counts[kind] += 1
        self._learn_vo_bias(kind, m)
        return ACCEPTED

    def _learn_vo_bias(self, kind: str, m: RelativeMeasurement) -> None:
        # only a measurement the gate let in teaches the VO's bias: an outlier would move it for ~windows readings
        tracker = self.vo_biases.get(kind)
        if tracker is not None:
            reference, stamp = self._find_stamp(m.reference_stamp), self._find_stamp(m.stamp)
            learned = reference is not None and stamp is not None and tracker.update(reference, stamp, m.transform)
            self.counts[f"vo_bias.{kind}." + ("learned" if learned else "no_vo_chain")] += 1

    def _make_rotation(self, reference_key: int, key: int, m: RelativeMeasurement, batch: _Batch) -> str:
        """The relative-rotation factor; with an offset state, on the interval's state o_i (a new one, chained to the
        previous by its walk, once the newest is ``bias_interval`` old). Gated on the innovation with o_i predicted."""
        rotation = self.config.inputs.rotation
        covariance = np.asarray(m.covariance, dtype=float)[3:, 3:]
        e, j_from, j_to = rotation_error(
            self._estimates[reference_key].rotation().matrix(),
            self._estimates[key].rotation().matrix(),
            np.asarray(m.transform, dtype=float)[:3, :3].T,
        )
        jacobian = np.hstack([j_from, j_to])
        if not rotation.has_bias:
            if not self._gate("rotation", e, [reference_key, key], jacobian, covariance):
                return "gated"
            batch.factors.add(rotation_factor(reference_key, key, m.transform, m.covariance, rotation.huber_k))
            self.factor_counts["rotation"] += 1
            self._learn_vo_bias("rotation", m)
            return ACCEPTED
        stamp = self._find_stamp(m.stamp)
        assert stamp is not None
        latest = self._rotation_bias[-1] if self._rotation_bias else None
        shares = latest is not None and abs(stamp - latest[1]) < round(rotation.bias_interval * 1e9)
        walk_variance = np.zeros(3)
        if latest is not None and not shares:
            walk_variance = np.asarray(rotation.bias_walk_sigma, dtype=float) ** 2 * max(abs(stamp - latest[1]) * 1e-9, 1e-3)
        if latest is not None and self._estimates.has_vector(latest[0]):
            offset = self._estimates.vector(latest[0])
            joint_jacobian = np.hstack([jacobian, np.eye(3)])
            keys = [reference_key, key, latest[0]]
            ok = self._gate("rotation", e + offset, keys, joint_jacobian, covariance + np.diag(walk_variance))
        else:
            # no offset solved yet (none, or one made in this batch): the prior's N(0, Σ_o) in the innovation
            offset = np.zeros(3)
            prior = np.asarray(rotation.bias_sigma, dtype=float) ** 2
            ok = self._gate("rotation", e, [reference_key, key], jacobian, covariance + np.diag(prior + walk_variance))
        if not ok:
            return "gated"
        index = gtsam.Symbol(key).index()
        if shares:
            assert latest is not None
            bias_key = latest[0]
            # the state lives as long as its newest reading's pose: the smoother keeps it while a reading may still come
            batch.timestamps.insert((bias_key, self._timestamp(stamp, index)))
        else:
            bias_key = O(self._next_rotation_bias)
            self._next_rotation_bias += 1
            self._chain_offset("rotation", batch, bias_key, offset, stamp, index, rotation.bias_sigma, rotation.bias_walk_sigma)
        batch.factors.add(rotation_factor(reference_key, key, m.transform, m.covariance, rotation.huber_k, bias_key))
        self.factor_counts["rotation"] += 1
        self._learn_vo_bias("rotation", m)
        return ACCEPTED

    def _make_sun(self, key: int, m: SunMeasurement, batch: _Batch) -> str:
        if self.sun_reference is None:
            return "rejected.no_reference" if self.config.inputs.sun.reference != "ephemeris" else "rejected.no_gps_origin"
        sun_map = self.sun_reference.direction(m.stamp)
        if sun_map is None:
            return "rejected.no_reference_at_stamp"
        covariance = np.asarray(m.covariance, dtype=float)
        e, jacobian = sun_error(self._estimates[key].rotation().matrix(), sun_map, zenith_azimuth(np.asarray(m.direction)))
        if not self.config.inputs.sun.has_bias:
            if not self._gate("sun", e, [key], jacobian, covariance):
                return "gated"
            batch.factors.add(sun_factor(key, sun_map, m.direction, covariance, self.config.inputs.sun.huber_k))
            self.factor_counts["sun"] += 1
            return ACCEPTED
        return self._make_biased_sun(key, m, sun_map, e, jacobian, covariance, batch)

    def _make_biased_sun(
        self, key: int, m: SunMeasurement, sun_map: Array, e: Array, jacobian: Array, covariance: Array, batch: _Batch
    ) -> str:
        """The sun factor on the pose and a new offset state b_k, chained to the previous live one by its walk (a
        new chain from the prior when there is none). Gated on the innovation with b_k predicted from b_k-1."""
        sun = self.config.inputs.sun
        stamp = self._find_stamp(m.stamp)
        assert stamp is not None
        previous = self._sun_bias[-1] if self._sun_bias else None
        walk_variance = np.zeros(2)
        if previous is not None:
            walk_variance = np.asarray(sun.bias_walk_sigma, dtype=float) ** 2 * max(abs(stamp - previous[1]) * 1e-9, 1e-3)
        solved = previous is not None and self._estimates.has_vector(previous[0])
        if solved:
            assert previous is not None
            offset = self._estimates.vector(previous[0])
            e_biased = e + offset
            e_biased[1] = wrap_angle(float(e_biased[1]))
            joint_jacobian = np.hstack([jacobian, np.eye(2)])
            ok = self._gate("sun", e_biased, [key, previous[0]], joint_jacobian, covariance + np.diag(walk_variance))
        else:
            # no offset solved yet: b_k-1 (or the prior) as N(0, Σ_b), the pose's own covariance
            offset = np.zeros(2)
            ok = self._gate("sun", e, [key], jacobian, covariance + np.diag(np.asarray(sun.bias_sigma, dtype=float) ** 2))
        if not ok:
            return "gated"
        bias_key = B(self._next_bias)
        self._next_bias += 1
        index = gtsam.Symbol(key).index()
        self._chain_offset("sun", batch, bias_key, offset, stamp, index, sun.bias_sigma, sun.bias_walk_sigma)
        batch.factors.add(sun_factor(key, sun_map, m.direction, covariance, sun.huber_k, bias_key))
        self.factor_counts["sun"] += 1
        return ACCEPTED

    def _chain_offset(
        self,
        kind: str,
        batch: _Batch,
        bias_key: int,
        value: Array,
        stamp: int,
        index: int,
        prior_sigma: tuple[float, ...],
        walk_sigma: tuple[float, ...],
    ) -> None:
        """A new offset state of ``kind`` ("sun" or "rotation") at the pose ``index``: from its prior N(0, prior_sigma²)
        when that kind has no live offset state, else walked from the newest one."""
        chain = self._sun_bias if kind == "sun" else self._rotation_bias
        previous = chain[-1] if chain else None
        batch.values.insert(bias_key, value)
        batch.timestamps.insert((bias_key, self._timestamp(stamp, index)))
        if previous is None:
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.asarray(prior_sigma, dtype=float))
            batch.factors.add(gtsam.PriorFactorVector(bias_key, np.zeros(len(prior_sigma)), noise))
            self.factor_counts[f"{kind}_bias_prior"] += 1
        else:
            # a late reading (older than the previous one) walks back over the same |interval|
            seconds = abs(stamp - previous[1]) * 1e-9
            batch.factors.add(offset_walk(previous[0], bias_key, np.asarray(walk_sigma, dtype=float), seconds))
        chain.append((bias_key, stamp))

    def _gate(self, kind: str, error: Array, keys: list[int], jacobian: Array, covariance: Array) -> bool:
        """Mahalanobis test of the innovation e against S = J P J^T + R at the current estimate."""
        threshold = self._gates[kind]
        if not np.isfinite(threshold):
            return True
        joint = self._joint_covariance(keys)
        innovation = jacobian @ joint @ jacobian.T + covariance
        try:
            d2 = float(error @ np.linalg.solve(innovation, error))
        except np.linalg.LinAlgError:
            return False
        return d2 <= threshold

    # ------------------------------------------------------------------ solving
    def _start(self, stamp: int) -> None:
        self._first_stamp = stamp
        pose = gtsam.Pose3(self._initial_pose) if self._initial_pose is not None else gtsam.Pose3()
        if self._initial_covariance is not None:
            noise = gtsam.noiseModel.Gaussian.Covariance(ros_to_gtsam_covariance(self._initial_covariance, pose.matrix()))
        else:
            p = self.config.prior
            noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([p.sigma_rotation] * 3 + [p.sigma_translation] * 3))
        key = X(self._next_index)
        factors = gtsam.NonlinearFactorGraph()
        factors.add(gtsam.PriorFactorPose3(key, pose, noise))
        self.factor_counts["prior"] += 1
        values = gtsam.Values()
        values.insert(key, pose)
        timestamps = gtsam.FixedLagSmootherKeyTimestampMap()
        timestamps.insert((key, self._timestamp(stamp, self._next_index)))
        self._stamps.append(stamp)
        self._keys[stamp] = key
        self._next_index += 1
        self._update(factors, values, timestamps)

    def _update(
        self, factors: gtsam.NonlinearFactorGraph, values: gtsam.Values, timestamps: gtsam.FixedLagSmootherKeyTimestampMap
    ) -> None:
        start = time.perf_counter()
        failure = ""
        try:
            self._smoother.update(factors, values, timestamps)
            if self.config.solver.smoother == "incremental":
                for _ in range(self.config.solver.iterations - 1):
                    self._smoother.update()
            estimate = self._smoother.calculateEstimate()
            diverged = self._divergence(estimate)
            if diverged:
                failure = "diverged"
                self.last_rejection = f"solver: diverged ({diverged})"
        except RuntimeError as exc:  # GTSAM's exceptions (an indeterminate system ...) arrive as RuntimeError
            failure = "failure"
            self.last_rejection = f"solver: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}"
        if failure:
            # Keep running: restart the window at the last good estimate with no information (a lost state); the
            # states that leave keep their estimates from before this update, never the failed ones.
            self.counts[f"solver.{failure}"] += 1
            self._restart_lost()
            self.last_update_seconds = time.perf_counter() - start
            return
        # States marginalised by this update keep their estimate from before it: their final one.
        while self._stamps and not estimate.exists(self._keys[self._stamps[0]]):
            stamp = self._stamps.pop(0)
            key = self._keys.pop(stamp)
            self._finished.append(FusedPose(stamp, self._estimates[key].matrix()))
        while self._sun_bias and not estimate.exists(self._sun_bias[0][0]):
            self._sun_bias.popleft()
        while self._rotation_bias and not estimate.exists(self._rotation_bias[0][0]):
            self._rotation_bias.popleft()
        self._estimates.refresh(estimate)
        self.last_update_seconds = time.perf_counter() - start

    def _divergence(self, estimate: gtsam.Values) -> str:
        """Why the smoother's new estimate cannot be the vehicle's, or "": a non-finite pose, or the newest state moved
        by this update further than the vehicle could travel over the whole window at ``inputs.vo.max_speed``. A last
        line of defence (no run of the experiments reaches it): an ill-conditioned window must give a lost state, never
        a published path of NaN or 1e10 m."""
        poses = gtsam.utilities.extractPose3(estimate)
        if not np.all(np.isfinite(poses)):
            return "a non-finite pose"
        key = self._keys[self._stamps[-1]]
        before = self._estimates.get(key)
        if before is None or not estimate.exists(key):
            return ""
        moved = float(np.linalg.norm(estimate.atPose3(key).translation() - before.translation()))
        reach = self.config.inputs.vo.max_speed * ((self._stamps[-1] - self._stamps[0]) * 1e-9 + 1.0)
        return f"the newest state moved {moved:.3g} m in one update, more than {reach:.3g} m" if moved > reach else ""

    def _restart_lost(self) -> None:
        stamp = self._stamps[-1]
        last = self._estimates[self._keys[stamp]]
        # the window's states leave with their last good estimates (the newest one lives on as the new first state)
        finished = self._finished + [FusedPose(s, self._estimates[self._keys[s]].matrix()) for s in self._stamps[:-1]]
        kept = self._last_velocity, self._pending
        indices = self._next_index, self._next_bias, self._next_rotation_bias
        self._reset_smoother()
        self._next_index, self._next_bias, self._next_rotation_bias = indices
        self._last_velocity, self._pending = kept
        self._initial_pose = last.matrix()
        # lost: the position by lost_variance per axis, the orientation by at most 1 rad of σ per axis, as the
        # first-motion bridge does (lost_variance·I's 31 rad is no distribution on SO(3): sun readings could turn the
        # restarted window through any angle)
        lost_variance = self.config.inputs.vo.lost_variance
        self._initial_covariance = np.diag([lost_variance] * 3 + [min(lost_variance, 1.0)] * 3)
        self._start(stamp)
        self._finished = finished + self._finished

    # ------------------------------------------------------------------ outputs
    def pose(self, stamp: int | None = None) -> Array:
        """T_map,cam (4x4) of the live state at ``stamp`` (default: the newest)."""
        if not self._stamps:
            raise ValueError("the fusion graph has no state yet")
        key = self._keys[self._stamps[-1]] if stamp is None else self._find(stamp)
        if key is None:
            raise ValueError(f"no live state at stamp {stamp}")
        return self._estimates[key].matrix()

    def _joint_covariance(self, keys: list[int]) -> Array:
        """Joint marginal covariance (GTSAM order/perturbation; 6 rows per pose, 2 per sun offset, 3 per rotation
        offset) of live states.

        iSAM2: from its Bayes tree (QR-factorised, cost independent of the lag); batch: dense QR of the window.
        """
        if isinstance(self._smoother, gtsam.IncrementalFixedLagSmoother):
            try:
                joint = self._smoother.getISAM2().jointMarginalCovariance(gtsam.KeyVector(keys))
                return np.block([[joint.at(row, col) for col in keys] for row in keys])
            except RuntimeError:
                pass  # an indeterminate tree: the dense QR below still answers
        try:
            return self._dense_joint_covariance(keys)
        except (RuntimeError, np.linalg.LinAlgError):
            # a singular window: report the states as lost (the gate lets a reading in, the published covariance says so)
            self.counts["solver.singular_covariance"] += 1
            size = sum({ord("b"): 2, ord("o"): 3}.get(gtsam.Symbol(k).chr(), 6) for k in keys)
            return np.eye(size) * self.config.inputs.vo.lost_variance

    def _dense_joint_covariance(self, keys: list[int]) -> Array:
        """Joint marginal covariance of live states (poses: 6, sun offsets: 2, rotation offsets: 3) by dense QR of the
        relinearised window."""
        graph = self._smoother.getFactors()
        linear = graph.linearize(self._smoother.calculateEstimate())
        offsets = [k for k, _ in (*self._sun_bias, *self._rotation_bias) if self._estimates.has_vector(k)]
        live = [self._keys[s] for s in self._stamps] + offsets
        ordering = gtsam.Ordering()
        for key in live:
            ordering.push_back(key)
        a, _ = linear.jacobian(ordering)
        r = np.linalg.qr(a, mode="r")
        # Σ = (RᵀR)^-1; only the requested blocks are needed.
        sizes = [{ord("b"): 2, ord("o"): 3}.get(gtsam.Symbol(k).chr(), 6) for k in live]
        starts = dict(zip(live, np.concatenate([[0], np.cumsum(sizes)[:-1]]), strict=True))
        size = dict(zip(live, sizes, strict=True))
        cols = np.concatenate([np.arange(starts[k], starts[k] + size[k]) for k in keys])
        n = r.shape[1]
        rhs = np.zeros((n, len(cols)))
        rhs[cols, np.arange(len(cols))] = 1.0
        y = np.linalg.solve(r.T, rhs)
        sigma = np.linalg.solve(r, y)
        return sigma[cols]

    def covariance(self, stamp: int | None = None) -> Array:
        """Marginal covariance of the state at ``stamp`` (default newest): 6x6, ROS order, left perturbation."""
        if not self._stamps:
            raise ValueError("the fusion graph has no state yet")
        key = self._keys[self._stamps[-1]] if stamp is None else self._find(stamp)
        if key is None:
            raise ValueError(f"no live state at stamp {stamp}")
        return gtsam_to_ros_covariance(self._joint_covariance([key]), self._estimates[key].matrix())

    def window(self) -> list[FusedPose]:
        """The live states, oldest first, with their current (smoothed) estimates."""
        return [FusedPose(s, self._estimates[self._keys[s]].matrix()) for s in self._stamps]

    def drain_finished(self) -> list[FusedPose]:
        """States that left the window since the last call, with their final fixed-lag estimates."""
        out, self._finished = self._finished, []
        return out

    def trajectory(self) -> list[FusedPose]:
        """Everything not yet drained plus the live window (call at the end of a run)."""
        return self.drain_finished() + self.window()

    def pending(self) -> int:
        return len(self._pending)


class _Estimates:
    """The live states' latest estimates: the smoother's last ``Values`` (read on demand, not copied per
    update: the window may hold hundreds of states) plus initial guesses of states added since."""

    def __init__(self) -> None:
        self._values = gtsam.Values()
        self._added: dict[int, gtsam.Pose3] = {}

    def __getitem__(self, key: int) -> gtsam.Pose3:
        pose = self._added.get(key)
        return pose if pose is not None else self._values.atPose3(key)

    def get(self, key: int) -> gtsam.Pose3 | None:
        pose = self._added.get(key)
        if pose is None and self._values.exists(key):
            pose = self._values.atPose3(key)
        return pose

    def __setitem__(self, key: int, pose: gtsam.Pose3) -> None:
        self._added[key] = pose

    def refresh(self, values: gtsam.Values) -> None:
        self._values = values
        self._added.clear()

    def has_vector(self, key: int) -> bool:
        """Whether the smoother has solved the vector state ``key`` (a sun or rotation offset) yet."""
        return bool(self._values.exists(key))

    def vector(self, key: int) -> Array:
        return np.asarray(self._values.atVector(key), dtype=float)
