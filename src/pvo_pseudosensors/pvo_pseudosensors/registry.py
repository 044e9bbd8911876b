"""The learned pseudo-sensors, one entry each: how to build a model's training task from its settings, and
how to predict and evaluate with a trained one. `pvo <model> train|predict|eval` is generated from this
table; a new model plugs in with a config, a network, a loss (its :class:`~.learning.training.Task`) and
an entry here."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .learning.spec import DataSpec


@dataclass(frozen=True)
class ModelEntry:
    """name: the command (`pvo NAME ...`); config: the model's settings dataclass (its fields become
    `train` options); task: settings -> Task; spec: settings -> what the dataset must carry;
    dataset: (settings, sources, cache directory, progress) -> a torch Dataset, when the model reads
    something else than :class:`~.learning.data.FrameDataset`'s samples; predict: the library call behind
    `predict` (an object with ``frames`` and ``write_csv``); evaluate: (prediction file, truth file) ->
    figures, behind `eval`, and summary: figures -> the lines it prints; truth: what `eval --gt` takes;
    fit_task: the task from the settings and the training set (DPC-Net weighs its loss by the training
    targets' covariance); work: how many progress steps a dataset of those sequences reports, when its
    dataset does more than decode images (HydraNet computes flows);
    mc_sampling: `predict` takes MC-dropout options (--samples, --seed, --mode); off_rig: corpus conditions that
    make a sequence another camera's (a drawn calibration error or lens), left out of training when the model
    is one rig's (DPC-Net's correction is for one camera and one VO)."""

    name: str
    description: str
    config: type
    task: Callable[[Any], Any]
    spec: Callable[[Any], DataSpec]
    predict: Callable[..., Any] | None = None  # None: the command module adds its own predict / eval
    evaluate: Callable[[Path, Path], dict[str, float]] | None = None
    summary: Callable[[dict[str, float]], list[str]] | None = None
    truth: str = ""
    calibrate: Callable[..., dict[str, float]] | None = None  # model dir, validation sequences -> card figures
    dataset: Callable[..., Any] | None = None
    fit_task: Callable[[Any, Any], Any] | None = None  # (settings, training set) -> Task, for a loss that needs the data
    work: Callable[[Any, list[int], bool], int] | None = None  # (settings, frames per sequence, training) -> progress steps
    mc_sampling: bool = True
    prediction_header: str = ""
    options: dict[str, str] = field(default_factory=dict)  # option help per config field
    off_rig: tuple[str, ...] = ()
    shipped: tuple[str, ...] = ()  # models installed with the package: `predict --model NAME` takes these names


def _sun_bcnn() -> ModelEntry:
    from pvo_core.readers import SUN_PREDICTIONS_HEADER

    from .sun_bcnn.config import SHIPPED, SunBCNNConfig

    def task(config: SunBCNNConfig):
        from .sun_bcnn.model import SunTask

        return SunTask(config)

    def predict(model_dir, sequence, samples=25, seed=0, cache_dir=None, mode=None, equalize=False):
        from .sun_bcnn.infer import equalize_input, load_sun_bcnn, predict_sequence

        model, card = load_sun_bcnn(model_dir)
        if equalize:
            equalize_input(model)
        return predict_sequence(model, card, sequence, samples=samples, seed=seed, cache_dir=cache_dir, mode=mode)

    def calibrate(model_dir, sequences, samples=25, mode=None, cache_dir=None):
        from .learning.checkpoint import write_card
        from .sun_bcnn.infer import DEFAULT_MODE, calibrate, load_sun_bcnn

        model, card = load_sun_bcnn(model_dir)
        mode = mode or DEFAULT_MODE
        figures = calibrate(model, card, sequences, samples=samples, mode=mode, cache_dir=cache_dir)
        card.calibration = {**figures, "mode": mode}
        write_card(model_dir, card)
        return figures

    def evaluate(prediction_file: Path, truth_file: Path) -> dict[str, float]:
        from pvo_core.readers import read_kitti_sun_csv, read_sun_predictions_csv

        from .sun_bcnn.evaluation import evaluate_predictions

        predictions = read_sun_predictions_csv(prediction_file)
        truth = read_kitti_sun_csv(truth_file)
        frames = predictions[:, 0].astype(int)
        if frames.max() >= len(truth):
            raise ValueError(f"{prediction_file}: frame {frames.max()} is beyond the {len(truth)} rows of {truth_file}")
        return evaluate_predictions(predictions, truth[frames])

    def summary(figures: dict[str, float]) -> list[str]:
        lines = [f"{'images':<22} {int(figures['images'])}"]
        for name in ("vector", "zenith", "azimuth"):
            lines.append(
                f"{name + ' error (deg)':<22} mean {figures[f'{name}_mean_deg']:7.2f}   "
                f"median {figures[f'{name}_median_deg']:7.2f}"
            )
        return [*lines, f"{'ANEES (zenith, azimuth)':<22} {figures['anees']:.3f}"]

    return ModelEntry(
        name="sun-bcnn",
        description="Sun-BCNN: the sun direction with covariance from one image (thesis ch. 5)",
        config=SunBCNNConfig,
        task=task,
        spec=lambda config: config.spec,
        predict=predict,
        evaluate=evaluate,
        summary=summary,
        truth="true sun vectors (sun.csv of the sequence)",
        calibrate=calibrate,
        prediction_header=SUN_PREDICTIONS_HEADER,
        shipped=SHIPPED,
        options={
            "height": "input height (px)",
            "width": "input width (px)",
            "colour": "RGB input (image_2) instead of grey (image_0)",
            "widths": "channels of the convolutional blocks, comma-separated",
            "hidden": "units of the fully connected layer",
            "dropout": "dropout probability (kept on for MC sampling)",
            "grid": "rows,columns of the region pooling before the head (1,1: global)",
            "mirror": "mirror training images left-right at random (the sun's x negated)",
            "rotate": "warp training images as if the camera turned: yaw within +-ROTATE deg, pitch and roll "
            "+-ROTATE/4, the sun turned with it (0: off)",
            "aleatoric": "a von Mises-Fisher concentration per image (heteroscedastic covariance)",
            "augment": "photometric jitter in training (gain, gamma, noise)",
            "batch_norm": "batch normalisation after every convolution (running statistics in the MC passes)",
            "bins": "0: regress the sun vector (the thesis); N: classify it into N directions over the sphere",
            "decode_radius": "with bins: the answer is the mean within this many bin spacings of the most probable "
            "bin (inf: the whole sphere)",
            "equalize": "histogram-equalise every image the network reads (training and prediction alike)",
        },
    )


def _hydranet() -> ModelEntry:
    from pvo_core.readers import ROTATION_PREDICTIONS_HEADER

    from .hydranet.config import SHIPPED, HydraNetConfig

    def task(config: HydraNetConfig):
        from .hydranet.model import HydraTask

        return HydraTask(config)

    def dataset(config: HydraNetConfig, sources, cache_dir, progress=None, training: bool = True):
        from .hydranet.flow import FlowPairs

        return FlowPairs(
            sources,
            config.size,
            reverse=config.reverse and training,
            cache_dir=cache_dir,
            progress=progress,
            texture=config.texture,
            pitch=config.pitch,
            flow_prior=config.flow_prior,
            depth=config.depth,
            gap=config.gap,
        )

    def predict(model_dir, sequence, cache_dir=None, pitch_deg=None, **_mc):
        from .hydranet.infer import load_hydranet, predict_sequence

        model, card = load_hydranet(model_dir)
        return predict_sequence(model, card, sequence, cache_dir=cache_dir, pitch_deg=pitch_deg)

    def evaluate(prediction_file: Path, truth_file: Path) -> dict[str, float]:
        from pvo_core.readers import read_rotation_predictions_csv
        from pvo_core.trajectory import read_kitti_poses

        from .hydranet.evaluation import evaluate_rotations, true_relative_rotations

        rows = read_rotation_predictions_csv(prediction_file)
        poses = read_kitti_poses(truth_file)
        frames = rows[:, :2].astype(int)
        if frames.max() >= len(poses):
            raise ValueError(f"{prediction_file}: frame {frames.max()} is beyond the {len(poses)} poses of {truth_file}")
        truth = true_relative_rotations(poses, frames[:, 0], frames[:, 1])
        return evaluate_rotations(rows[:, 2:6], rows[:, 6:].reshape(-1, 3, 3), truth)

    def calibrate(model_dir, sequences, samples=None, mode=None, cache_dir=None):
        """The inference mode (plain | mirrored | reversed, default plain) written into the card, with its figures on the
        validation ``sequences`` pooled over their pairs (MC sampling does not apply: ``samples`` is unused)."""
        from pvo_core.trajectory import read_kitti_poses

        from .hydranet.evaluation import evaluate_rotations, true_relative_rotations
        from .hydranet.infer import load_hydranet, predict_sequence
        from .hydranet.model import MODES
        from .learning.checkpoint import write_card

        mode = mode or "plain"
        if mode not in MODES:
            raise ValueError(f"--mode {mode}: HydraNet runs {', '.join(MODES[:-1])} or {MODES[-1]}")
        model, card = load_hydranet(model_dir)
        widening = (card.calibration or {}).get("spread_widening")  # `pvo hydranet widen`'s: kept in its own mode
        dropped = bool(widening) and widening.get("mode", "plain") != mode
        if dropped:  # its reference is another mode's spread (stop 67: plain's read in mirrored mode gave ANEES 0.33)
            model.widening = None
            widening = None
        card.calibration = {**(card.calibration or {}), "mode": mode}
        quaternions, covariances, truth = [], [], []
        for sequence in sequences:
            predictions = predict_sequence(model, card, sequence, cache_dir=cache_dir)
            poses = read_kitti_poses(Path(sequence) / "poses.txt")
            quaternions.append(predictions.quaternions)
            covariances.append(predictions.covariance)
            truth.append(true_relative_rotations(poses, predictions.earlier, predictions.frames))
        figures = evaluate_rotations(np.vstack(quaternions), np.concatenate(covariances), np.concatenate(truth))
        members = (card.calibration or {}).get("members")  # an ensemble stays one
        density = (card.calibration or {}).get("feature_density")  # `pvo hydranet density`'s, kept
        shortfall = (card.calibration or {}).get("flow_shortfall_widening")  # `pvo hydranet shortfall`'s, kept
        card.calibration = {
            **figures,
            "sequences": float(len(sequences)),
            "mode": mode,
            **({"members": members} if members else {}),
            **({"feature_density": density} if density else {}),
            **({"spread_widening": widening} if widening else {}),
            **({"flow_shortfall_widening": shortfall} if shortfall else {}),
        }
        write_card(model_dir, card)
        return {**figures, "spread_widening_dropped": 1.0} if dropped else figures

    def summary(figures: dict[str, float]) -> list[str]:
        dropped = [f"{'spread widening':<24} dropped: fitted in another inference mode (run pvo hydranet widen again)"]
        return (dropped if figures.get("spread_widening_dropped") else []) + [
            f"{'frame pairs':<24} {int(figures['pairs'])}",
            f"{'angular error (deg)':<24} mean {figures['angle_mean_deg']:.4f}   median {figures['angle_median_deg']:.4f}"
            f"   rms {figures['angle_rms_deg']:.4f}",
            f"{'NLL (eq. 7.17)':<24} {figures['nll']:.3f}",
            f"{'ANEES':<24} {figures['anees']:.3f}",
        ]

    return ModelEntry(
        name="hydranet",
        description="HydraNet: relative rotations with epistemic and aleatoric covariance (thesis ch. 7)",
        config=HydraNetConfig,
        task=task,
        spec=lambda config: config.spec,
        predict=predict,
        evaluate=evaluate,
        summary=summary,
        truth="true camera poses (poses.txt, KITTI format)",
        calibrate=calibrate,
        dataset=dataset,
        # each image decoded, then the flow of each consecutive pair (and of each reversed pair in training)
        work=lambda config, frames, training: sum(n + (n - 1) * (2 if config.reverse and training else 1) for n in frames),
        mc_sampling=False,
        shipped=SHIPPED,
        prediction_header=ROTATION_PREDICTIONS_HEADER,
        options={
            "height": "height (px) of the images the flow is computed at",
            "width": "width (px) of the images the flow is computed at",
            "widths": "channels of the body's stride-2 convolutions, comma-separated",
            "feature": "units of the body's output",
            "heads": "number of quaternion heads H (epistemic covariance from their spread)",
            "head_hidden": "units of each head's hidden layer",
            "head_dropout": "dropout in each head (training only)",
            "covariance": "aleatoric covariance: cholesky (full, the thesis) | diagonal (the authors' code)",
            "reverse": "add every training pair reversed (images swapped, target C_k-1,k)",
            "bootstrap": "each head trains on its own fixed half of the samples (bootstrapped heads)",
            "mirror": "mirror training pairs left-right at random (flow flipped, the rotation's y and z negated)",
            "texture": "a third input channel: the texture (log gradient magnitude) of the image the flow starts from",
            "pitch": "one more input channel: the camera's pitch below the horizon (from each sequence's sim.yaml)",
            "depth": "one more input channel: the inverse depth of the image the flow starts from, by stereo matching "
            "(the right images and calib.txt needed; predict reads such a model, the node does not; stop 74's pilot: "
            "6 %% lower error, not adopted)",
            "coordinates": "the network adds two channels of its own: each pixel's normalised image coordinates "
            "(CoordConv), so its convolutions can read a turn's flow, a function of where the pixel is",
            "flow_prior": "where Farneback starts: none (zero, the thesis; loses turns beyond ~3 deg per frame at 64 px "
            "high) | shift (the images' global shift: 98-99 %% of a turn's flow up to 6 deg per frame)",
        },
    )


def _dpc_net() -> ModelEntry:
    from .dpc_net.config import DPCNetConfig

    def task(config: DPCNetConfig):
        from .dpc_net.model import DPCTask

        return DPCTask(config)

    def fit_task(config: DPCNetConfig, train: Any):
        from pvo_frontend.vo import flatten

        from .dpc_net.data import vo_config, vo_signature
        from .dpc_net.loss import target_covariance
        from .dpc_net.model import DPCTask
        from .dpc_net.rig import training_rig

        parts = getattr(train, "datasets", [train])  # a ConcatDataset of several corpora, or one
        targets = np.concatenate([part.targets for part in parts])
        vo = vo_config(config.vo_settings)
        rig = training_rig(r for part in parts for r in part.rigs) | {
            "vo": vo_signature(vo),
            "vo_settings": flatten(vo),  # every setting, lists for tuples
        }
        return DPCTask(config, target_covariance(targets), rig)

    def dataset(config: DPCNetConfig, sources, cache_dir, progress=None, training: bool = True):
        from .dpc_net.data import DPCWindows

        return DPCWindows(sources, config, cache_dir, None if training else (config.test_delta,), progress)

    return ModelEntry(
        name="dpc-net",
        description="DPC-Net: learned SE(3) corrections to the stereo VO over Δp frames (thesis ch. 6)",
        config=DPCNetConfig,
        task=task,
        spec=lambda config: DataSpec((config.height, config.width), right=config.stereo),
        dataset=dataset,
        fit_task=fit_task,
        off_rig=("wrong calibration", "radial distortion"),
        options={
            "height": "input height (px)",
            "width": "input width (px)",
            "stem": "channels of the siamese stem's three convolutions, comma-separated",
            "body": "channels of the stride-2 convolutions after the stems, comma-separated",
            "dropout": "dropout after every convolution",
            "variant": "pose (SE(3) from stereo) | rotation (SO(3) from the left images) | yaw",
            "deltas": "frame spans of the training windows, comma-separated (thesis 3,4,5; 2,3,4 for distorted images)",
            "test_delta": "frame span at prediction and validation",
            "vo_input": "also feed the VO's estimate of the window, log(T̂), through a linear map (beyond the thesis)",
            "vo_settings": "the stereo VO whose errors the model learns: its settings that differ from the defaults, "
            "'NAME=VALUE ...' as `pvo vo -p` (the card records every setting; its tools run that VO)",
        },
    )


def models() -> dict[str, ModelEntry]:
    """Every learned pseudo-sensor, by command name."""
    entries = [_sun_bcnn(), _hydranet(), _dpc_net()]
    return {entry.name: entry for entry in entries}
