"""The VO's slowly varying bias as the pose corrections reveal it, removed from later VO motions.

A miscalibrated rig (a focal length or baseline off, a lens processed as if undistorted) makes a stereo VO read every
motion a little wrong in the same way: its per-frame covariance carries none of it, so a fusion that treats the VO's
errors as independent keeps most of it — the per-frame error is small beside a correction's, but it never averages
out. A correction (DPC-Net, T_k,k-Δp) re-measures the VO's chain over its Δp frames; their disagreement
``Log(T_corrected T_vo⁻¹) / Δp`` is, on average over many windows, the VO's bias per frame. Its running mean
(exponentially weighted over ``windows`` corrections; the plain mean until that many have come) is that estimate,
and each new VO motion is taken as ``Exp(β) T_k,k-1`` — the left perturbation the correction itself has (thesis eq.
6.1). Only the disagreement of corrections already received is used (causal): the fusion node's online estimate and
the offline one agree. ``axes`` (ROS order x y z rotX rotY rotZ, 1 = tracked) limits it to the axes whose bias the
corrections know better than the VO: on the long validation drives of both DPC-Net rigs, the translation.

A rig's error also scales what the VO reads: a lens processed as if undistorted makes this VO read every turn about
8 % too large, a focal length 3 % long 2 % too small — an error proportional to the turn, of either sign as the
vehicle turns left or right, which an additive bias cannot carry (its mean over a drive is near zero). With
``rotation_scale_windows`` the tracker also learns that scale: per correction, the least-squares
``k = Σ dᵣ·φ / (Σ φ·φ + ε)`` of its rotation disagreement ``dᵣ`` on the VO chain's own rotation vector φ (sums
exponentially weighted over about that many corrections; ε, a turn of about 1°, keeps straight driving from teaching
it), and each new VO motion's rotation vector is taken ``(1 + gain·k)`` times as long. ``gain`` ≤ 1 shrinks the
estimate toward none: a scale a drive's turns teach imperfectly, applied in full, can unmask errors it was hiding.
``translation_scale_windows`` learns the same for the distance the VO reads (a focal length off scales the depth
and so every step, ``k_t = Σ (t_C − t_W)·t_W / (Σ t_W·t_W + ε_t)``), each VO step then ``1 + k_t`` times as long.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pvo_core.lie import se3_exp, se3_inverse, se3_log, so3_exp, so3_log

Array = NDArray[np.float64]

#: the axes (ROS order) whose bias is tracked by default: the translation (see the module docstring)
TRANSLATION_AXES = (1.0, 1.0, 1.0, 0.0, 0.0, 0.0)
#: ε of the rotation scale's least squares (rad²): about 1° of turning before a scale is believed
ROTATION_SCALE_PRIOR = 3e-4
#: ε of the translation scale's (m²): a metre of travel
TRANSLATION_SCALE_PRIOR = 1.0


class VOBiasTracker:
    """The running per-frame bias β (6,) of a VO's relative motions T_k,k-1 (ROS-order tangent, left perturbation:
    m and rad per frame), learned from corrections spanning several of its motions.

    ``windows``: the exponential mean's time constant, in corrections (> 0; 0: no additive bias, a scale
    alone); ``axes``: 6 weights, 1 to track an axis, 0 to leave it alone; ``history``: how many raw VO motions are kept
    to chain under a correction (the oldest go); ``rotation_scale_windows``: the rotation scale's time constant, in
    corrections (0: none; ``inf``: every correction alike), ``rotation_scale_gain`` the part of it applied (0, 1];
    ``translation_scale_windows``: the translation scale's (0: none)."""

    def __init__(
        self,
        windows: float,
        axes: ArrayLike = TRANSLATION_AXES,
        history: int = 1000,
        rotation_scale_windows: float = 0.0,
        rotation_scale_gain: float = 1.0,
        translation_scale_windows: float = 0.0,
    ) -> None:
        axes = np.asarray(axes, dtype=float)
        if not (np.isfinite(windows) and windows >= 0.0):
            raise ValueError(f"the VO bias's time constant must be a number of corrections >= 0, got {windows}")
        if not (rotation_scale_windows >= 0.0 and not np.isnan(rotation_scale_windows)):
            raise ValueError(
                f"the VO rotation scale's time constant must be a number of corrections >= 0, got {rotation_scale_windows}"
            )
        if not (translation_scale_windows >= 0.0 and not np.isnan(translation_scale_windows)):
            raise ValueError(
                f"the VO translation scale's time constant must be a number of corrections >= 0, got {translation_scale_windows}"
            )
        if windows == 0.0 and rotation_scale_windows == 0.0 and translation_scale_windows == 0.0:
            raise ValueError("a VO bias tracker needs a time constant > 0 for the bias or for a scale")
        if not (np.isfinite(rotation_scale_gain) and 0.0 < rotation_scale_gain <= 1.0):
            raise ValueError(f"the VO rotation scale's gain must be in (0, 1], got {rotation_scale_gain}")
        if axes.shape != (6,) or not np.all((axes == 0.0) | (axes == 1.0)):
            raise ValueError(f"the VO bias's axes must be 6 weights of 0 or 1 (x y z rotX rotY rotZ), got {axes.tolist()}")
        self.windows = float(windows)
        self.axes = axes if windows > 0.0 else np.zeros(6)
        self.rotation_scale_windows = float(rotation_scale_windows)
        self.rotation_scale_gain = float(rotation_scale_gain)
        self.translation_scale_windows = float(translation_scale_windows)
        self.updates = 0
        self._bias = np.zeros(6)
        self._scale_sums = np.zeros(4)  # Σ dᵣ·φ, Σ φ·φ, Σ (t_C − t_W)·t_W, Σ t_W·t_W (exponentially weighted)
        self._history = history
        self._motions: OrderedDict[int, tuple[int, Array]] = OrderedDict()

    @property
    def bias(self) -> Array:
        """β (6,), ROS order: the bias per VO motion removed from each new one."""
        return self._bias.copy()

    @property
    def rotation_scale(self) -> float:
        """``gain·k``: the VO's rotation vectors are taken ``1 + rotation_scale`` times as long (0 without one)."""
        if self.rotation_scale_windows == 0.0:
            return 0.0
        return self.rotation_scale_gain * float(self._scale_sums[0] / (self._scale_sums[1] + ROTATION_SCALE_PRIOR))

    @property
    def translation_scale(self) -> float:
        """``k_t``: the VO's steps are taken ``1 + translation_scale`` times as long (0 without one)."""
        if self.translation_scale_windows == 0.0:
            return 0.0
        return float(self._scale_sums[2] / (self._scale_sums[3] + TRANSLATION_SCALE_PRIOR))

    @property
    def scale_sums(self) -> Array:
        """(4,): the scales' weighted sums Σ dᵣ·φ, Σ φ·φ (rad²), Σ (t_C − t_W)·t_W, Σ t_W·t_W (m²) — what a
        checkpoint keeps."""
        return self._scale_sums.copy()

    def restore(self, bias: ArrayLike, updates: int, scale_sums: ArrayLike | None = None) -> None:
        """Go on from a bias learned before (a checkpoint): β (6,), ROS order, masked to this tracker's axes, the
        number of corrections it was learned from (the exponential mean's weight goes on from there) and the
        scales' sums (:attr:`scale_sums`; None: none learned)."""
        bias = np.asarray(bias, dtype=float)
        if bias.shape != (6,) or not np.all(np.isfinite(bias)) or updates < 0:
            raise ValueError(f"a VO bias to restore must be 6 finite numbers and a count >= 0, got {bias.tolist()}, {updates}")
        sums = np.zeros(4) if scale_sums is None else np.asarray(scale_sums, dtype=float)
        if sums.shape != (4,) or not np.all(np.isfinite(sums)) or sums[1] < 0.0 or sums[3] < 0.0:
            raise ValueError(f"VO scale sums to restore must be 4 finite numbers, the 2nd and 4th >= 0, got {sums.tolist()}")
        self._bias = self.axes * bias
        self.updates = int(updates)
        self._scale_sums = sums * np.repeat([self.rotation_scale_windows > 0.0, self.translation_scale_windows > 0.0], 2)

    def debias(self, transform: ArrayLike) -> Array:
        """``Exp(β) T'_k,k-1`` (4, 4): a VO motion with the current bias estimate removed, T' its rotation vector
        taken ``1 + rotation_scale`` times as long and its translation ``1 + translation_scale``."""
        transform = np.asarray(transform, dtype=float)
        scale, step = self.rotation_scale, self.translation_scale
        if scale or step:
            transform = transform.copy()
            if scale:
                transform[:3, :3] = so3_exp((1.0 + scale) * so3_log(transform[:3, :3]))
            transform[:3, 3] *= 1.0 + step
        if not self._bias.any():
            return transform.copy()
        return se3_exp(self._bias) @ transform

    def observe(self, reference_stamp: int, stamp: int, transform: ArrayLike) -> None:
        """Keep the VO's own motion T_stamp,reference (4, 4), as the VO read it (before :meth:`debias`)."""
        self._motions[int(stamp)] = (int(reference_stamp), np.array(transform, dtype=float))
        self._motions.move_to_end(int(stamp))
        while len(self._motions) > self._history:
            self._motions.popitem(last=False)

    def update(self, reference_stamp: int, stamp: int, corrected: ArrayLike) -> bool:
        """Learn from a correction T_stamp,reference (4, 4) — True when the VO's motions chain from ``reference_stamp``
        to ``stamp`` (False, nothing learned, across a gap or beyond the kept history)."""
        chain = np.eye(4)
        motions = 0
        at = int(stamp)
        while at != int(reference_stamp):
            if at not in self._motions or motions > len(self._motions):
                return False
            previous, transform = self._motions[at]
            chain = chain @ transform  # T_stamp,at T_at,previous
            at = previous
            motions += 1
            if at < int(reference_stamp):
                return False
        if motions == 0:
            return False
        disagreement = se3_log(np.asarray(corrected, dtype=float) @ se3_inverse(chain))
        if not np.all(np.isfinite(disagreement)):
            return False
        self.updates += 1
        if self.windows > 0.0:
            weight = max(1.0 / self.updates, 1.0 / self.windows)
            self._bias = (1.0 - weight) * self._bias + weight * self.axes * disagreement / motions
        if self.rotation_scale_windows > 0.0:
            turn = so3_log(chain[:3, :3])  # the chain's rotation vector as the VO read it
            keep = 1.0 - 1.0 / self.rotation_scale_windows  # inf: 1, every correction alike
            self._scale_sums[:2] = keep * self._scale_sums[:2] + np.array([disagreement[3:] @ turn, turn @ turn])
        if self.translation_scale_windows > 0.0:
            step = chain[:3, 3]  # the chain's translation as the VO read it
            keep = 1.0 - 1.0 / self.translation_scale_windows
            offset = np.asarray(corrected, dtype=float)[:3, 3] - step
            self._scale_sums[2:] = keep * self._scale_sums[2:] + np.array([offset @ step, step @ step])
        return True


def debiased_motions(
    transforms: ArrayLike,
    first: ArrayLike,
    last: ArrayLike,
    corrected: ArrayLike,
    windows: float,
    axes: ArrayLike = TRANSLATION_AXES,
    rotation_scale_windows: float = 0.0,
    rotation_scale_gain: float = 1.0,
    translation_scale_windows: float = 0.0,
) -> Array:
    """The VO's motions T_k,k-1 (frames k = 1..N; (N, 4, 4)) as a fusion with :class:`VOBiasTracker` takes them, given
    the corrections T_last,first (M, 4, 4) over frames ``first`` → ``last`` (M,): motion k debiased with what the
    corrections ending at frame k-1 or before taught (a correction ending at k is received after motion k). Every
    correction teaches here; the fusion learns only from those its gate lets in (on the validation drives nearly all)."""
    transforms = np.asarray(transforms, dtype=float)
    tracker = VOBiasTracker(
        windows, axes, len(transforms) + 1, rotation_scale_windows, rotation_scale_gain, translation_scale_windows
    )
    ending: dict[int, list[tuple[int, Array]]] = {}
    for a, b, t in zip(np.asarray(first), np.asarray(last), np.asarray(corrected, dtype=float), strict=True):
        ending.setdefault(int(b), []).append((int(a), t))
    out = np.empty_like(transforms)
    for k in range(1, len(transforms) + 1):
        tracker.observe(k - 1, k, transforms[k - 1])
        out[k - 1] = tracker.debias(transforms[k - 1])
        for a, t in ending.get(k, []):
            tracker.update(a, k, t)
    return out
