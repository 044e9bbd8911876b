"""DPC-Net on a sequence: corrections of the VO's Δp-frame transforms, and the VO and the corrections fused
through :class:`pvo_fusion.FusionGraph` — the thesis's pose-graph relaxation (§6.4.5) done by the fixed-lag
smoother, instead of the authors' shipped code that overwrote every Δp-th pose."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.lie import se3_exp

from ..learning.checkpoint import ModelCard, load_model
from ..learning.data import Source, cached_images
from .config import ARCHITECTURE, DPCNetConfig
from .model import DPCNet, estimate_input

Array = NDArray[np.float64]
CORRECTIONS_HEADER = (
    "frame_first,frame_last,"
    + ",".join(f"t{i}{j}" for i in range(3) for j in range(4))
    + ","
    + ",".join(f"c{i}{j}" for i in range(6) for j in range(6))
)


def load_dpc_net(directory: Path) -> tuple[DPCNet, ModelCard]:
    """The trained network of ``directory`` in eval mode (one clear line for every bad model file)."""
    model, card = load_model(Path(directory), ARCHITECTURE, lambda card: DPCNet(DPCNetConfig.from_card(card)))
    model.eval()
    return model, card


@dataclass
class Corrections:
    """Per window: first and last frame (N,), the corrected transform T_last,first = exp(ξ^) T̂ (N, 4, 4) and its
    covariance (N, 6, 6) in ROS order (x y z rotX rotY rotZ), left perturbation."""

    first: NDArray[np.int64]
    last: NDArray[np.int64]
    transforms: Array
    covariances: Array

    def write_csv(self, path: Path) -> Path:
        rows = [CORRECTIONS_HEADER]
        for a, b, t, c in zip(self.first, self.last, self.transforms, self.covariances, strict=True):
            rows.append(f"{int(a)},{int(b)}," + ",".join(f"{v:.9g}" for v in [*t[:3].reshape(-1), *c.reshape(-1)]))
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text("\n".join(rows) + "\n")
        return path


AXES = ("x", "y", "z", "rx", "ry", "rz")  # ROS order
#: the variance of an axis a variant does not correct (rad², m²): the fusion then takes the VO's alone there
UNMEASURED = 9999.0


def correction_vectors(config: DPCNetConfig, output: Array) -> Array:
    """The network's output (N, 6 | 3 | 1) as left corrections ξ = [ρ; φ] (N, 6): the rotation variant's φ with
    no translation, the yaw variant's angle about the camera's y axis (down in the optical frame)."""
    output = np.asarray(output, dtype=float).reshape(len(output), -1)
    xi = np.zeros((len(output), 6))
    if config.variant == "pose":
        xi[:] = output
    elif config.variant == "rotation":
        xi[:, 3:] = output
    else:
        xi[:, 4] = output[:, 0]
    return xi


def residual_mean(calibration: dict) -> Array:
    """The mean left error (6,) ROS order, g = log(T* exp(-ξ^)), the corrected transforms kept on the validation
    split (``residual.bias_*_after``, `pvo dpc-net calibrate`) when the card's drive calibration chose to remove it
    (``remove_mean: true``), else zeros. A correction that learned a constant the validation split does not share
    (a yaw offset from training drives that turn one way more than the other) adds it to every window, and over a
    drive of hundreds of windows that offset is the drift."""
    if not calibration.get("remove_mean"):
        return np.zeros(6)
    residual = calibration.get("residual") or {}
    missing = [axis for axis in AXES if f"bias_{axis}_after" not in residual]
    if missing:
        raise ValueError(
            "the model card's calibration says remove_mean but its residual has no bias_"
            f"{'/'.join(missing)}_after figures: run `pvo dpc-net calibrate` on it again"
        )
    mean = np.asarray([float(residual[f"bias_{axis}_after"]) for axis in AXES])
    if not np.all(np.isfinite(mean)):
        raise ValueError(f"the model card's residual mean must be finite, got {mean.tolist()}")
    return mean


def remove_residual_mean(transforms: Array, calibration: dict) -> Array:
    """Corrected transforms (N, 4, 4) with the card's validation mean error removed: exp(b^) T (:func:`residual_mean`;
    unchanged without it)."""
    mean = residual_mean(calibration)
    if not np.any(mean) or not len(transforms):
        return transforms
    return se3_exp(mean) @ transforms


def corrected_covariance(calibration: dict) -> Array:
    """The corrected transform's covariance (6, 6), ROS order, on every axis: the residual covariance on the validation
    split about its mean when the card has it (the spread left once the mean is removed), else the training targets'
    (eq. 6.6). :func:`measurement_covariance` is this on the measured axes."""
    covariance = np.asarray(calibration.get("residual_covariance", calibration["target_covariance"]), dtype=float)
    if "residual_covariance" in calibration:
        mean = residual_mean(calibration)  # removed from the corrections: the spread about it is what is left
        covariance = covariance - np.outer(mean, mean)
    return covariance


def measurement_covariance(config: DPCNetConfig, calibration: dict) -> Array:
    """The corrected transform's covariance (6, 6), ROS order, on the axes the variant corrects (:data:`UNMEASURED`
    on the others, uncorrelated): the corrected transforms' own residual covariance on the validation split when
    the card has it (`pvo dpc-net calibrate`, in the card's inference mode), else the training targets' (eq. 6.6,
    the thesis's; an upper bound: the error of the VO the model corrects). Only the axes the calibration validated
    are measured: those its long validation drives chose (``fused_axes``, `calibrate --drives`; none when no choice
    lowered the mean m-ATE within its harm tolerance on every drive), else those whose error the correction lowered
    on the validation windows (``residual.corrected_*``). With ``correction_scale`` (`calibrate --drives
    --consistent-corrections`: per-axis variance scales, ROS order, that make the chained corrections consistent over
    the card's VO span) the measured axes' covariance is scaled by them."""
    covariance = corrected_covariance(calibration)
    axes = {"pose": range(6), "rotation": range(3, 6), "yaw": [4]}[config.variant]
    if calibration.get("fused_axes") is not None:
        axes = [a for a in axes if AXES[a] in calibration["fused_axes"]]
    else:
        residual = calibration.get("residual") or {}
        # an axis the correction made worse on validation is not measured (the VO alone there)
        axes = [a for a in axes if residual.get(f"corrected_{AXES[a]}", 1.0)]
    if calibration.get("correction_scale") is not None:
        scale = np.asarray(calibration["correction_scale"], dtype=float)
        if scale.shape != (6,) or not np.all(np.isfinite(scale)) or np.any(scale <= 0.0):
            raise ValueError(
                f"the model card's correction_scale must be 6 positive numbers, got {calibration['correction_scale']}"
            )
        covariance = covariance * np.outer(np.sqrt(scale), np.sqrt(scale))
    kept = np.zeros((6, 6), dtype=bool)
    kept[np.ix_(list(axes), list(axes))] = True
    return np.where(kept, covariance, np.diag(np.full(6, UNMEASURED)))


#: the mirror of the camera frame (x right, y down, z forward): every right turn a left turn
MIRROR = np.diag([-1.0, 1.0, 1.0, 1.0])


def mirror_baseline(card: ModelCard) -> float:
    """The stereo baseline (m) through which a window is mirrored: the middle of the card's trained range (the rig
    check refuses a sequence outside it); 0 for a model without a card rig or of the left image alone."""
    config = DPCNetConfig.from_card(card)
    rig = card.input.get("rig") or {}
    if not config.stereo or not rig.get("baseline_m"):
        return 0.0
    return float(np.mean(rig["baseline_m"]))


def _mirror_conjugation(baseline_m: float) -> Array:
    """M = S E^-1 (4, 4): a transform T between two poses of the left camera becomes M T M^-1 between the mirrored
    rig's left camera's (the old right one through the mirror; E the shift by the baseline along x)."""
    shift = np.eye(4)
    shift[0, 3] = -baseline_m
    return MIRROR @ shift


def correction_outputs(
    model: DPCNet,
    config: DPCNetConfig,
    first: torch.Tensor,
    last: torch.Tensor,
    estimates: Array,
    mirrored: bool,
    baseline_m: float,
    estimate_logs: torch.Tensor | None = None,
) -> Array:
    """The left corrections ξ (N, 6) of the VO's window transforms ``estimates`` (N, 4, 4) T̂_last,first from the
    frames ``first``, ``last`` (N, C, H, W) in [0, 1] (:func:`correction_vectors`). ``mirrored``: also predicted on
    the window through the mirror (images flipped left-right, a stereo pair's left and right swapped, T̂ -> M T̂ M^-1
    with :func:`_mirror_conjugation` of ``baseline_m``), that correction taken back through the mirror (C = M^-1 C' M)
    and the two averaged on the tangent space — what the network does differently to the two views, which a model
    trained on a corpus and its mirror should not, cancels. ``estimate_logs``: the network's input for
    ``estimates`` if already made (:func:`.model.estimate_input`)."""
    from pvo_core.lie import se3_log

    estimates = np.asarray(estimates, dtype=float).reshape(-1, 4, 4)
    if not len(estimates):
        return np.zeros((0, 6))
    with torch.no_grad():
        logs = estimate_input(estimates) if estimate_logs is None else estimate_logs
        xi = correction_vectors(config, model(first, last, logs).double().numpy())
        if not mirrored:
            return xi
        conjugation = _mirror_conjugation(baseline_m if config.stereo else 0.0)
        back = np.linalg.inv(conjugation)
        order = [1, 0] if config.stereo else [0]

        def flipped(frames: torch.Tensor) -> torch.Tensor:
            return torch.flip(frames[:, order], dims=[-1])

        mirrored_estimates = conjugation @ estimates @ back
        output = model(flipped(first), flipped(last), estimate_input(mirrored_estimates)).double().numpy()
    xi_mirrored = correction_vectors(config, output)
    unmirrored = np.array([se3_log(back @ se3_exp(x) @ conjugation) for x in xi_mirrored])
    if config.variant == "yaw":  # the mirror of a yaw is a yaw; keep the variant's one axis
        unmirrored[:, [0, 1, 2, 3, 5]] = 0.0
    return 0.5 * (xi + unmirrored)


def predict_corrections(model: DPCNet, card: ModelCard, sequence: Path, vo: Array, cache_dir: Path | None = None) -> Corrections:
    """Corrections of the VO's transforms (camera-to-odom poses ``vo`` (N, 4, 4)) over consecutive windows of
    the card's ``test_delta`` frames (0 → Δp, Δp → 2Δp, ...), any variant (:func:`correction_vectors`), with
    :func:`measurement_covariance`; the validation mean error removed where the card says so
    (:func:`remove_residual_mean`)."""
    config = DPCNetConfig.from_card(card)
    source = Source(Path(sequence), Path(sequence).name)
    size = (config.height, config.width)
    left = cached_images(source.images("left", False), size, False, cache_dir)
    right = cached_images(source.images("right", False), size, False, cache_dir) if config.stereo else None
    if len(vo) != len(left):
        raise ValueError(f"the VO has {len(vo)} poses for the {len(left)} images of {sequence}")
    delta = config.test_delta
    last = np.arange(delta, len(left), delta)
    first = last - delta

    def frames(index: NDArray[np.int64]) -> torch.Tensor:
        stacked = np.concatenate([left[index], right[index]], axis=1) if right is not None else np.asarray(left[index])
        return torch.from_numpy(stacked.astype(np.float32) / 255.0)

    estimate = np.linalg.inv(vo[last]) @ vo[first]
    mirrored = bool(card.calibration.get("mirrored", False))
    xi = correction_outputs(model, config, frames(first), frames(last), estimate, mirrored, mirror_baseline(card))
    transforms = np.stack([se3_exp(x) @ t for x, t in zip(xi, estimate, strict=True)]) if len(last) else np.zeros((0, 4, 4))
    transforms = remove_residual_mean(transforms, card.calibration)
    covariance = measurement_covariance(config, card.calibration)
    return Corrections(first, last, transforms, np.broadcast_to(covariance, (len(last), 6, 6)).copy())


def overwrite_trajectory(vo: Array, corrections: Corrections) -> Array:
    """The authors' shipped use of the corrections (thesis code facts §5): every window's last pose overwritten
    by its first pose times the corrected transform, the VO's own transforms chained in between. ``vo``: camera-
    to-odom poses (N, 4, 4); the windows must be consecutive (each starts where the last ended). Returns (N, 4, 4)."""
    poses = np.array(vo, dtype=float)
    anchor, anchored = np.eye(4), 0  # poses[k] = anchor @ vo[k] for k after the last overwritten frame
    for a, b, transform in zip(corrections.first, corrections.last, corrections.transforms, strict=True):
        if int(a) != anchored:
            raise ValueError(
                f"the corrections' windows are not consecutive: one starts at frame {a}, the last ends at {anchored}"
            )
        poses[a : b + 1] = anchor @ vo[a : b + 1]
        poses[b] = poses[a] @ np.linalg.inv(transform)
        anchor, anchored = poses[b] @ np.linalg.inv(vo[b]), int(b)
    poses[anchored:] = anchor @ vo[anchored:]
    return poses


#: windows over which an axis's correction is judged (100 x Δp frames, 30 s at Δp = 3 and 10 Hz): a bias the
#: correction removes adds up over them, its noise only as their square root
DRIFT_WINDOWS = 100


def lowers_drift(before: Array, after: Array, windows: int = DRIFT_WINDOWS) -> NDArray[np.bool_]:
    """Per axis, whether the errors ``after`` (M, 6) a correction, summed over ``windows`` consecutive windows, are
    smaller in mean square than ``before`` (M, 6): n² bias² + n variance, each window's error independent around
    the axis's bias."""
    n = float(windows)

    def drift(errors: Array) -> Array:
        return n**2 * errors.mean(axis=0) ** 2 + n * errors.var(axis=0)

    return np.asarray(drift(np.asarray(after)) < drift(np.asarray(before)))


def residual_covariance(
    model: DPCNet, card: ModelCard, windows: Any, batch_size: int = 64, drift_windows: int = DRIFT_WINDOWS
) -> tuple[Array, dict[str, float]]:
    """The covariance (6, 6), ROS order, of the corrected transforms' left errors g = log(T_gt (exp(ξ^) T̂)^-1)
    = log(T* exp(-ξ^)) over ``windows`` (a :class:`.data.DPCWindows` of validation sequences at the test span),
    eq. 6.6's estimator applied to what is left after the correction; and figures: the windows, the mean
    translation and rotation error (m, deg) before and after the correction, per axis the mean (bias) before and
    after (``bias_x_before`` ...), and whether the correction lowers the error accumulated over ``drift_windows``
    consecutive windows, n² bias² + n variance (``corrected_x`` ... ``corrected_rz``: 1 or 0). Judged per window
    (n = 1) a correction that removes the VO's bias but adds a little noise looks useless; over a drive the bias
    is what the VO's drift is made of."""
    from pvo_core.lie import se3_log

    config = DPCNetConfig.from_card(card)
    mirrored, baseline = bool(card.calibration.get("mirrored", False)), mirror_baseline(card)
    residuals, before = [], []
    for start in range(0, len(windows), batch_size):
        batch = [windows[i] for i in range(start, min(start + batch_size, len(windows)))]
        first, last, logs = (torch.stack([b[key] for b in batch]) for key in ("first", "last", "estimate"))
        estimates = np.array([se3_exp(log) for log in logs.double().numpy()])
        xi_batch = correction_outputs(model, config, first, last, estimates, mirrored, baseline, logs)
        for xi, sample in zip(xi_batch, batch, strict=True):
            target = sample["target"].double().numpy()
            residuals.append(se3_log(target @ se3_exp(-xi)))
            before.append(se3_log(target))
    if not residuals:
        raise ValueError("no validation window to calibrate on")
    g, b = np.asarray(residuals), np.asarray(before)
    covariance = g.T @ g / len(g)
    corrected = lowers_drift(b, g, drift_windows)  # only these axes are fused
    figures = {
        "windows": float(len(g)),
        "translation_error_m_before": float(np.linalg.norm(b[:, :3], axis=1).mean()),
        "translation_error_m_after": float(np.linalg.norm(g[:, :3], axis=1).mean()),
        "rotation_error_deg_before": float(np.degrees(np.linalg.norm(b[:, 3:], axis=1)).mean()),
        "rotation_error_deg_after": float(np.degrees(np.linalg.norm(g[:, 3:], axis=1)).mean()),
        "drift_windows": float(drift_windows),
        **{f"corrected_{axis}": float(c) for axis, c in zip(AXES, corrected, strict=True)},
        **{f"bias_{axis}_before": float(v) for axis, v in zip(AXES, b.mean(axis=0), strict=True)},
        **{f"bias_{axis}_after": float(v) for axis, v in zip(AXES, g.mean(axis=0), strict=True)},
    }
    return covariance, figures
