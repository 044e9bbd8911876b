"""Sun-BCNN, thesis ch. 5 on the project's corpus and on real KITTI images.

1. Accuracy (Table 5.1) per test sequence of the corpus and overall, with and without the aleatoric output,
   every MC mode (full / head, each also mirrored) with its time per image; a calibration plot (predicted sigma against the
   actual error).
2. Cloud cover (§5.10.1): sunny against overcast test sequences.
3. Method I against Method II (Tables 5.7, 5.8): the mean and the covariance of the MC samples.
4. Fusion (Table 5.2 on synthetic): the first test sequences rendered longer, this project's VO fused with
   GT-Sun-10/20/30 and with Sun-BCNN at every 10th frame; online and smoothed ARMSE against VO alone; with
   --fusion-rig-error, again with the VO run on a wrong calibration (a systematically biased VO); with --fusion-lens,
   again on the same drives rendered through a lens calib.txt does not model (a VO that drifts, as viso2 on KITTI).
5. Real images: the synthetic model on the KITTI 06 clip and the 07 left images; the synthetic model
   fine-tuned on 07 and a model trained on 07 alone, both tested on 06. 07 is split by frame (0-127 train,
   128-159 validation: model selection and covariance calibration); 06 is never trained on.
"""

from __future__ import annotations

import argparse
import copy
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..paths import data_directory
from .common import ExperimentRun

TITLE = "Sun-BCNN (ch. 5): accuracy, cloud cover, Method I/II, fusion on the corpus's test sequences; KITTI transfer"
Array = NDArray[np.float64]
KITTI_TRAIN_FRAMES = range(0, 128)  # of the 07 clip (frames 0-159)
KITTI_VALIDATION_FRAMES = range(128, 160)
#: the KITTI fine-tune's learning rate and epochs (stop 49: the best of four settings on 07 frames 128-159 by
#: scripts/sun_bcnn_kitti_finetune.py; 3e-4 for 20 epochs before)
FINETUNE_LEARNING_RATE = 3e-3
FINETUNE_EPOCHS = 40
#: synthetic training images mixed into every epoch of the KITTI fine-tune (0: the real frames alone)
FINETUNE_SYNTHETIC = 0
# stop 74, rule 1: the convolutional features adapt to the real camera, the head keeps where the synthetic world
# taught the sun to be (07 held out by the sun's azimuth: 54.1 deg against 63.6 for a full fine-tune)
FINETUNE_TRAINABLE = "features"


@dataclass
class Evaluated:
    """One model on one image set: the prediction rows (N, 10) and Table 5.1's figures."""

    label: str
    rows: Array
    truth: Array
    figures: dict[str, float] = field(default_factory=dict)


def evaluate(label: str, rows: Array, truth: Array) -> Evaluated:
    from pvo_pseudosensors.sun_bcnn.evaluation import evaluate_predictions

    return Evaluated(label, rows, truth, evaluate_predictions(rows, truth))


def stage_kitti(data: Path, sequence: str, frames: Sequence[int], out: Path) -> Path:
    """A sequence folder (links to the clip's left images, renumbered from 0, their rows of the sun CSV and the
    clip's calibration as ``calib.txt``) that the learning datasets read like a corpus sequence."""
    clip = data / "kitti" / "sequences" / sequence / "image_0"
    rows = (data / "kitti" / "sun" / f"kitti_sun_test_{sequence}.csv").read_text().splitlines()
    images = sorted(clip.glob("*.png"))
    out.mkdir(parents=True, exist_ok=True)
    (out / "image_0").mkdir(exist_ok=True)
    lines = []
    for new, frame in enumerate(frames):
        link = out / "image_0" / f"{new:06d}.png"
        if not link.exists():
            link.symlink_to(images[frame].resolve())
        lines.append(rows[frame])
    (out / "sun.csv").write_text("\n".join(lines) + "\n")
    for calibration in ("calib.txt", "calib_P0_P1_unlabelled.txt"):  # the camera, for --rotate's fine-tuning
        if (clip.parent / calibration).is_file():
            (out / "calib.txt").write_text((clip.parent / calibration).read_text())
            break
    return out


def kitti_truth(data: Path, sequence: str, frames: NDArray[np.int64]) -> Array:
    from pvo_core.readers import read_kitti_sun_csv

    return read_kitti_sun_csv(data / "kitti" / "sun" / f"kitti_sun_test_{sequence}.csv")[frames]


def kitti_figures(model_name: str, staged: Path, data: Path, sequence: str, frames: range, cache: Path) -> dict[str, float]:
    """Table 5.1's figures of one model (a directory or shipped name, in the MC mode its card names, N = 25) on
    ``frames`` of a KITTI clip staged by :func:`stage_kitti` into ``staged``."""
    from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
    from pvo_pseudosensors.sun_bcnn.evaluation import evaluate_predictions
    from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn, predict_sequence

    model, card = load_sun_bcnn(resolve_model(model_name))
    predictions = predict_sequence(model, card, staged, cache_dir=cache)
    truth = kitti_truth(data, sequence, np.asarray(list(frames))[predictions.frames])
    return evaluate_predictions(predictions.rows(), truth)


def synthetic_mix(corpus: Path, count: int, spec: Any) -> Any:
    """``count`` images of ``corpus``'s training split for a fine-tune to keep seeing: evenly spread over the split's
    frames in corpus order (a fixed subset: the same every run), read through the corpus's decoded-image cache."""
    import torch
    from pvo_pseudosensors.learning import FrameDataset, corpus_sources

    everything = FrameDataset(corpus_sources(corpus, "train"), spec, Path(corpus) / ".cache")
    if not 0 < count <= len(everything):
        raise ValueError(f"{corpus}: {count} synthetic images asked for, its training split has {len(everything)}")
    chosen = np.unique(np.linspace(0, len(everything) - 1, count).round().astype(np.int64))
    return torch.utils.data.Subset(everything, chosen.tolist())


BEARING_WINDOW_DEG = 15.0  # sun bearings this close count as the same for bearing_balanced_indices


def bearing_balanced_indices(suns: Array, window_deg: float = BEARING_WINDOW_DEG) -> list[int]:
    """Indices into ``suns`` (N, 3 unit vectors, camera optical frame) for an epoch of the same length N in which
    each frame appears in proportion to 1 / (the frames whose sun's |azimuth| atan2(x, z) lies within
    ``window_deg`` of its own): a drive that mostly kept the sun at one bearing no longer teaches that bearing as
    the answer. The sign of the azimuth is ignored because training mirrors images (and suns) at random. Counts by
    systematic rounding of the running share (a frame kept less than once in a while is kept every so often along
    the drive, not dropped in a block), so the result is deterministic and sums to N; frames in ascending order."""
    azimuth = np.abs(np.degrees(np.arctan2(suns[:, 0], suns[:, 2])))
    neighbours = (np.abs(azimuth[:, None] - azimuth[None, :]) <= window_deg).sum(axis=1)
    share = (1.0 / neighbours) / np.sum(1.0 / neighbours) * len(suns)
    edges = np.floor(np.round(np.concatenate([[0.0], np.cumsum(share)]), 9) + 0.5).astype(int)
    return np.repeat(np.arange(len(suns)), np.diff(edges)).tolist()


def train_on_kitti(
    task: Any,
    spec: Any,
    train: Path,
    validation: Path,
    out: Path,
    epochs: int,
    learning_rate: float,
    say: Any,
    commands: dict[str, str],
    synthetic: Any = None,
    frames: str = "KITTI 07 frames 0-127 (validation 128-159)",
    balance_bearing: bool = False,
    seed: int = 0,
) -> Path:
    """Fine-tune (or train) ``task`` on the staged real frames ``train``, selecting on ``validation``; with
    ``synthetic`` (a dataset, :func:`synthetic_mix`) those images join every epoch; ``balance_bearing``: the real
    frames repeated by :func:`bearing_balanced_indices`; seed: the training's (shuffles, dropout, augmentation)."""
    import torch
    from pvo_pseudosensors.learning import FrameDataset, Source, TrainConfig, fit

    cache = out.parent / ".cache"
    train_set = FrameDataset([Source(train, "07-train", "train")], spec, cache)
    if balance_bearing:
        from pvo_core.readers import read_kitti_sun_csv

        suns = read_kitti_sun_csv(train / "sun.csv")
        if len(suns) != len(train_set):
            raise ValueError(f"{train}: {len(suns)} suns for {len(train_set)} images")
        train_set = torch.utils.data.Subset(train_set, bearing_balanced_indices(suns))
    validation_set = FrameDataset([Source(validation, "07-validation", "validation")], spec, cache)
    config = TrainConfig(epochs=epochs, batch_size=16, learning_rate=learning_rate, patience=6, seed=seed)
    corpus: dict[str, Any] = {"path": frames}
    if balance_bearing:
        corpus["balanced"] = f"frames repeated by the inverse density of their sun's |azimuth| within {BEARING_WINDOW_DEG:g} deg"
    if synthetic is not None:
        corpus["synthetic"] = f"{len(synthetic)} images of {Path(synthetic.dataset.sources[0].root).parent}'s training split"
        train_set = torch.utils.data.ConcatDataset([train_set, synthetic])
    extra = {"corpus": corpus, "commands": commands}
    fit(task, train_set, validation_set, config, out, say=say, card_extra=extra)
    return out


FUSION_ROWS = ("Without Sun", "GT-Sun-10", "GT-Sun-20", "GT-Sun-30", "Sun-BCNN")


def render_fusion_sequences(
    corpus: Path,
    count: int,
    frames: int,
    out: Path,
    jobs: int,
    say: Any,
    lens: Sequence[float] = (),
    preset: str | None = None,
    split: str = "test",
) -> list[Path]:
    """The first ``count`` test sequences of ``corpus`` rendered again with ``frames`` frames each into ``out``
    (the same draws — place, time, path, speed, preset, camera, degradations: plans depend on (seed, index)
    only — in a world generated along the longer path); resumes like `pvo sim corpus`. lens: plumb-bob k1 [k2
    k3] on every sequence (`pvo sim corpus --lens-distortion`): the same drives seen through an uncalibrated lens,
    calib.txt and the sun as without it. preset: the first ``count`` of that preset only (None: of any). split:
    another split's sequences instead (``validation``: drives a choice may be made on)."""
    import yaml
    from pvo_core.readers import read_corpus_manifest
    from pvo_sim.corpus import CorpusConfig, render_corpus

    manifest = read_corpus_manifest(corpus)
    values = dict(yaml.safe_load(manifest.path.read_text())["corpus"])
    values.update(presets=tuple(values["presets"]), split=tuple(values["split"]), frames=frames, lens_distortion=tuple(lens))
    indices = [int(s.name) for s in manifest.split(split) if preset is None or s.preset == preset][:count]
    if len(indices) < count:
        which = "" if preset is None else f" of the {preset} preset"
        raise ValueError(f"{manifest.path}: {len(indices)} {split} sequences{which}, {count} asked for")
    through = f" through the lens {tuple(lens)}" if lens else ""
    say(f"rendering {split} sequences {', '.join(f'{i:04d}' for i in indices)} with {frames} frames{through} into {out} ...")
    render_corpus(CorpusConfig(**values), out, jobs=jobs, indices=indices)
    return [out / f"{i:04d}" for i in indices]


def with_rig_error(sequence: Any, focal_scale: float, baseline_scale: float) -> Any:
    """``sequence`` (a :class:`pvo_core.readers.KittiSequence`) as a VO with a wrong calibration sees it: its
    calib.txt's focal length times ``focal_scale`` and baseline times ``baseline_scale`` (the images as they
    are) — what `pvo sim corpus --calib-focal-scale/--calib-baseline-scale` writes, without rendering again."""
    wrong = copy.copy(sequence)
    wrong.projections = {}
    for name, projection in sequence.projections.items():
        scaled = np.array(projection, dtype=float)
        scaled[0, 0] *= focal_scale
        scaled[1, 1] *= focal_scale
        scaled[0, 3] *= focal_scale * baseline_scale  # -f b for a right camera
        wrong.projections[name] = scaled
    return wrong


def fusion_inputs(
    folder: Path, model: Any, card: Any, samples: int, rig_error: tuple[float, float] | None = None
) -> tuple[Any, list[Any]]:
    """A rendered sequence as the sun experiment reads KITTI: ground truth, this project's stereo VO (poses
    and motion covariances) and the camera-frame sun; and Sun-BCNN's measurements at every 10th frame.
    rig_error: (focal, baseline) scales of a wrong calibration the VO runs with (:func:`with_rig_error`)."""
    from pvo_core.readers import KittiSequence, KittiSunSequence, read_kitti_sun_csv
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig
    from pvo_pseudosensors.sun_bcnn.infer import predict_sequence

    from pvo_fusion import SunMeasurement

    from .sun_sim import SUN_EVERY

    sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
    run = run_sequence(sequence if rig_error is None else with_rig_error(sequence, *rig_error), VOConfig())
    sun_camera = read_kitti_sun_csv(folder / "sun.csv")
    seq = KittiSunSequence(folder.name, "pvo sim", sequence.poses, run.poses, run.relative()["covariances"], sun_camera)
    predictions = predict_sequence(model, card, folder, samples)
    stamps = seq.stamps
    learned = [
        SunMeasurement(int(stamps[k]), predictions.vectors[k], predictions.covariance[k])
        for k in range(0, len(stamps), SUN_EVERY)
    ]
    return seq, learned


def fusion_experiment(
    sequences: list[Any],
    learned: list[list[Any]],
    seed: int = 0,
    say: Any = None,
    rows: Sequence[str] = FUSION_ROWS,
    learned_fusion: dict[str, Any] | None = None,
) -> dict[str, dict[str, dict[str, dict[str, float]]]]:
    """Table 5.2 on the rendered sequences: per sequence and row (``rows``, a subset of FUSION_ROWS; "Without Sun"
    first when given), ARMSE/CRMSE of the online (newest-state) and the fixed-lag smoothed estimates. VO covariances calibrated on
    the other sequences. ``learned_fusion``: fusion settings (dotted names) for the Sun-BCNN row only, e.g. its
    offset state (``inputs.sun.bias_sigma``); the GT-Sun-N rows' readings have none."""
    from pvo_core import metrics
    from pvo_fusion import calibrate_vo

    from .sun_sim import SUN_EVERY, calibration_input, experiment_config, run_fusion, sequence_vo, sun_measurements, sun_seed

    config = experiment_config()
    config_learned = experiment_config(learned_fusion)
    table: dict[str, dict[str, dict[str, dict[str, float]]]] = {}
    for i, seq in enumerate(sequences):
        calibration = calibrate_vo((calibration_input(s) for j, s in enumerate(sequences) if j != i), SUN_EVERY)
        vo = sequence_vo(seq, calibration)
        fused: dict[str, dict[str, dict[str, float]]] = {}
        for row in rows:
            if row == "Without Sun":
                sun = None
            elif row == "Sun-BCNN":
                sun = learned[i]
            else:
                level = float(row.split("-")[-1])
                sun = sun_measurements(seq, level, sun_seed(seed, seq.name, level))
            result = run_fusion(seq, vo, sun, config_learned if row == "Sun-BCNN" else config)
            fused[row] = {
                "online": metrics.armse(seq.ground_truth, result.online_poses),
                "smoothed": metrics.armse(seq.ground_truth, result.poses),
            }
            if say:
                m = fused[row]
                say(
                    f"{seq.name} {row:>11}: online trans {m['online']['trans']:7.3f} m rot {1e3 * m['online']['rot']:6.2f} e-3, "
                    f"smoothed trans {m['smoothed']['trans']:7.3f} m rot {1e3 * m['smoothed']['rot']:6.2f} e-3"
                )
        table[seq.name] = fused
    return table


def fusion_changes(table: dict[str, dict[str, dict[str, dict[str, float]]]]) -> dict[str, dict[str, dict[str, float]]]:
    """Mean relative change against VO alone (negative = better) per row, estimate and metric."""
    from pvo_core import metrics

    names = list(table)
    out: dict[str, dict[str, dict[str, float]]] = {}
    for row in [r for r in next(iter(table.values()), {}) if r != "Without Sun"]:
        out[row] = {}
        for estimate in ("online", "smoothed"):
            out[row][estimate] = {
                key: metrics.mean_relative_change(
                    [table[n][row][estimate][key] for n in names], [table[n]["Without Sun"][estimate][key] for n in names]
                )
                for key in ("trans", "rot")
            }
    return out


COLUMNS = (
    ("N", "images", 5, "d"),
    ("vec mean", "vector_mean_deg", 8, ".2f"),
    ("median", "vector_median_deg", 7, ".2f"),
    ("std", "vector_std_deg", 6, ".2f"),
    ("zen mean", "zenith_mean_deg", 8, ".2f"),
    ("median", "zenith_median_deg", 7, ".2f"),
    ("azi mean", "azimuth_mean_deg", 8, ".2f"),
    ("median", "azimuth_median_deg", 7, ".2f"),
    ("ANEES", "anees", 7, ".2f"),
    ("filt.", "anees_filtered", 6, ".2f"),
)


def format_table(results: list[Evaluated]) -> str:
    """Table 5.1's columns (degrees; ANEES without and with the cosine-distance filter), one row per result."""
    lines = [f"{'':<40}" + " ".join(f"{title:>{width}}" for title, _, width, _ in COLUMNS)]
    for r in results:
        cells = [
            format(int(r.figures[key]) if kind == "d" else r.figures[key], f">{width}{kind}") for _, key, width, kind in COLUMNS
        ]
        lines.append(f"{r.label:<40}" + " ".join(cells))
    return "\n".join(lines)


@dataclass(frozen=True)
class FusionRig:
    """One rig of experiment 4: its key in metrics.json, the report's heading, what the VO runs on (the report's
    words), the rendered sequences and the calibration error the VO runs with (None: calib.txt as written)."""

    key: str
    title: str
    vo: str
    folders: list[Path]
    rig_error: tuple[float, float] | None = None


def fusion_rigs(
    folders: list[Path],
    rig_error: tuple[float, float] | None = None,
    lens: Sequence[float] = (),
    lens_folders: list[Path] | None = None,
) -> list[FusionRig]:
    """The calibrated rig, then (``--fusion-rig-error``) the VO on a wrong calib.txt, then (``--fusion-lens``) the
    same drives rendered through an uncalibrated lens."""
    rigs = [FusionRig("fusion", "The calibrated rig", "this project's stereo VO", folders)]
    if rig_error is not None:
        rigs.append(
            FusionRig(
                "fusion_rig",
                "VO with a rig calibration error",
                f"this project's stereo VO run with a wrong calibration (calib.txt's focal length x{rig_error[0]:g}, "
                f"baseline x{rig_error[1]:g}; the images as rendered)",
                folders,
                rig_error,
            )
        )
    if lens:
        if lens_folders is None:
            raise ValueError("a lens rig needs its sequences rendered through the lens")
        coefficients = ", ".join(f"{k:g}" for k in lens)
        rigs.append(
            FusionRig(
                "fusion_lens",
                "VO through an uncalibrated lens",
                f"this project's stereo VO on the same drives rendered through a lens (plumb-bob k = {coefficients}) that "
                "calib.txt does not model, so its images are processed as if undistorted and the VO drifts; Sun-BCNN reads "
                "the same distorted images",
                lens_folders,
            )
        )
    return rigs


def fusion_section(
    fused: dict[str, dict[str, dict[str, dict[str, float]]]],
    changes: dict[str, dict[str, dict[str, float]]],
    count: int,
    frames: int,
    title: str = "The calibrated rig",
    vo: str = "this project's stereo VO",
    preset: str | None = None,
) -> list[str]:
    """Table 5.2's report lines for one rig: ARMSE per sequence and row, then the mean changes against VO alone."""
    lines = [
        f"### {title}",
        "",
        f"{count} {preset + ' ' if preset else ''}test sequences of the corpus rendered with {frames} frames, {vo} "
        "(covariances calibrated on the other "
        "sequences), fused with a sun measurement at every 10th frame. ARMSE: translation (m) and rotation (rad) over "
        "the whole run; the change is the mean over sequences of each sequence's relative change against VO alone "
        "(negative = better).",
        "",
        "| sequence | row | online trans | online rot | smoothed trans | smoothed rot |",
        "|---|---|---|---|---|---|",
    ]
    for name, rows in fused.items():
        for row, m in rows.items():
            lines.append(
                f"| {name} | {row} | {m['online']['trans']:.3f} | {m['online']['rot']:.5f} | "
                f"{m['smoothed']['trans']:.3f} | {m['smoothed']['rot']:.5f} |"
            )
    lines += ["", "| row | online trans | online rot | smoothed trans | smoothed rot |", "|---|---|---|---|---|"]
    for row, c in changes.items():
        lines.append(
            f"| {row} | {100 * c['online']['trans']:+.1f} % | {100 * c['online']['rot']:+.1f} % | "
            f"{100 * c['smoothed']['trans']:+.1f} % | {100 * c['smoothed']['rot']:+.1f} % |"
        )
    return [*lines, ""]


def parse_rig_error(text: str | None) -> tuple[float, float] | None:
    """``--fusion-rig-error FOCAL,BASELINE`` as two scales in [0.5, 2] (``ValueError``, one line, otherwise)."""
    if text is None:
        return None
    try:
        focal, baseline = (float(v) for v in text.split(","))
    except ValueError:
        raise ValueError(f"--fusion-rig-error {text!r}: give two scales, FOCAL,BASELINE (e.g. 1.03,1)") from None
    if not (0.5 <= focal <= 2.0 and 0.5 <= baseline <= 2.0):
        raise ValueError(f"--fusion-rig-error {text!r}: each scale must be in [0.5, 2] (a calibration error)")
    return focal, baseline


def parse_lens(coefficients: Sequence[float] | None) -> tuple[float, ...]:
    """``--fusion-lens K1 [K2 K3]`` as plumb-bob coefficients (``ValueError``, one line, otherwise)."""
    lens = tuple(coefficients or ())
    if len(lens) > 3 or not all(np.isfinite(lens)):
        raise ValueError(f"--fusion-lens {' '.join(f'{k:g}' for k in lens)}: give k1 [k2 k3], finite (e.g. -0.3 0.2 0.01)")
    if lens and not any(lens):
        raise ValueError("--fusion-lens 0: a lens that distorts nothing is the calibrated rig")
    return lens


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--corpus", type=Path, help="the corpus the models were trained on (its test split); not needed with --kitti-only"
    )
    parser.add_argument(
        "--model",
        type=Path,
        required=True,
        help="the Sun-BCNN model (calibrated), with the aleatoric output: a directory or a shipped name (sun_bcnn)",
    )
    parser.add_argument("--homoscedastic", type=Path, help="the same model trained without the aleatoric output (calibrated)")
    parser.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    parser.add_argument("--samples", type=int, default=25, help="MC-dropout passes (default 25)")
    parser.add_argument(
        "--finetune-epochs", type=int, default=FINETUNE_EPOCHS, help=f"epochs on KITTI 07 (default {FINETUNE_EPOCHS})"
    )
    parser.add_argument(
        "--finetune-learning-rate",
        type=float,
        default=FINETUNE_LEARNING_RATE,
        help=f"the KITTI fine-tune's learning rate (default {FINETUNE_LEARNING_RATE:g})",
    )
    parser.add_argument(
        "--finetune-synthetic",
        type=int,
        default=FINETUNE_SYNTHETIC,
        metavar="N",
        help="synthetic training images of --corpus mixed into each fine-tune epoch, so the model keeps the world it "
        f"learned (default {FINETUNE_SYNTHETIC}: the real frames alone)",
    )
    parser.add_argument(
        "--scratch-epochs",
        type=int,
        help="epochs of the baseline trained on KITTI 07 alone, from scratch (default twice --finetune-epochs; 0 skips it)",
    )
    parser.add_argument(
        "--finetune-trainable",
        default=FINETUNE_TRAINABLE,
        help="what the KITTI fine-tune changes: 'all', or comma-separated parts (features, head, concentration, norm, "
        f"blocks:K, the first K convolutional blocks), the rest kept as the synthetic world trained it (default "
        f"{FINETUNE_TRAINABLE})",
    )
    parser.add_argument("--skip-kitti", action="store_true", help="skip experiment 5 (no training)")
    parser.add_argument("--kitti-only", action="store_true", help="experiment 5 alone (real images; no synthetic corpus needed)")
    parser.add_argument(
        "--fusion-sequences", type=int, default=5, help="experiment 4: test sequences rendered longer and fused (0: skip)"
    )
    parser.add_argument("--fusion-frames", type=int, default=1000, help="experiment 4: frames per sequence (default 1000)")
    parser.add_argument(
        "--fusion-rig-error",
        metavar="FOCAL,BASELINE",
        help="experiment 4 again with the VO run on a wrong calibration: calib.txt's focal length and baseline times "
        "these (e.g. 1.03,1: a systematically biased VO, as on a badly calibrated camera; default: the calibrated rig only)",
    )
    parser.add_argument(
        "--fusion-preset",
        help="experiment 4: the first test sequences of this preset (urban, planetary; default: the first of any)",
    )
    parser.add_argument(
        "--fusion-lens",
        type=float,
        nargs="+",
        default=(),
        metavar="K",
        help="experiment 4 again on the same drives rendered through an uncalibrated lens, plumb-bob k1 [k2 k3] (e.g. "
        "-0.3 0.2 0.01, the thesis's lens of ch. 6: the VO drifts, as on a camera nobody calibrated; default: none)",
    )
    parser.add_argument(
        "--independent-sun",
        action="store_true",
        help="experiment 4: fuse Sun-BCNN's readings as independent, without the offset state its card's "
        "calibration.fusion sets (the experiment before stop 52)",
    )
    parser.add_argument("--jobs", "-j", type=int, default=2, help="experiment 4: rendering processes (default 2)")
    parser.add_argument("--out", "-o", type=Path, default=Path("runs/sun-bcnn-experiment"), help="output directory")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress lines")


def finetune_selection(args: argparse.Namespace) -> tuple[str, ...]:
    """The KITTI fine-tune's trainable entries from ``--finetune-trainable`` (empty: all), checked against
    ``args.model``'s network (ValueError naming what is wrong)."""
    from pvo_pseudosensors.learning.training import trainable_parameters
    from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn
    from pvo_pseudosensors.sun_bcnn.model import trainable_selection

    if args.finetune_trainable == "all":
        return ()
    model = load_sun_bcnn(args.model)[0]
    try:
        selection = trainable_selection(args.finetune_trainable, model.config)
        trainable_parameters(model, selection)
    except ValueError as exc:
        raise ValueError(f"--finetune-trainable {args.finetune_trainable}: {exc}") from None
    return selection


def kitti_experiment(
    args: argparse.Namespace, config: Any, out: Path, say: Any, command: str, synthetic: Any
) -> tuple[list[str], dict[str, float]]:
    """Experiment 5: the synthetic model on KITTI 06 and 07, fine-tuned on 07 (what ``args.finetune_trainable``
    picks of it), trained on 07 alone; each calibrated on 07 frames 128-159 and read on 06. Returns the report's
    lines and the figures."""
    from pvo_pseudosensors.learning.checkpoint import write_card
    from pvo_pseudosensors.learning.training import FineTune
    from pvo_pseudosensors.sun_bcnn.infer import DEFAULT_MODE, calibrate, equalize_input, load_sun_bcnn, predict_sequence
    from pvo_pseudosensors.sun_bcnn.model import SunTask

    trainable = finetune_selection(args)
    report: list[str] = []
    figures: dict[str, float] = {}
    data = data_directory(args.data)
    report += ["## 5. Real images (KITTI)", ""]
    kitti_results: list[Evaluated] = []

    def on_kitti(label: str, directory: Path, sequence: str, equalize: bool = False) -> Evaluated:
        m, c = load_sun_bcnn(directory)
        if equalize:
            equalize_input(m)
        p = predict_sequence(m, c, data / "kitti" / "sequences" / sequence, args.samples, cache_dir=out / ".cache")
        result = evaluate(label, p.rows(), kitti_truth(data, sequence, p.frames))
        p.write_csv(out / f"kitti{sequence}_{directory.name}{'-equalised' if equalize else ''}.csv")
        return result

    kitti_results.append(on_kitti("synthetic model, KITTI 06 (51)", args.model, "06"))
    kitti_results.append(on_kitti("synthetic model, KITTI 07 (160)", args.model, "07"))
    # stop 74, rule 3: the renders' grey levels spread more evenly than a real exposure's (07: 31.4 against 37.6 deg)
    kitti_results.append(on_kitti("synthetic model, equalised, KITTI 06", args.model, "06", equalize=True))
    kitti_results.append(on_kitti("synthetic model, equalised, KITTI 07", args.model, "07", equalize=True))
    train = stage_kitti(data, "07", KITTI_TRAIN_FRAMES, out / "kitti07-train")
    validation = stage_kitti(data, "07", KITTI_VALIDATION_FRAMES, out / "kitti07-validation")
    say("fine-tuning the synthetic model on KITTI 07 ...")
    tuned = train_on_kitti(
        FineTune(SunTask(config), args.model, trainable),
        config.spec,
        train,
        validation,
        out / "kitti-finetuned",
        args.finetune_epochs,
        args.finetune_learning_rate,
        say,
        {"train": command},
        synthetic,
    )
    scratch_epochs = 2 * args.finetune_epochs if args.scratch_epochs is None else args.scratch_epochs
    kitti_models = [tuned]
    if scratch_epochs:
        say("training on KITTI 07 alone ...")
        kitti_models.append(
            train_on_kitti(
                SunTask(config),
                config.spec,
                train,
                validation,
                out / "kitti07-only",
                scratch_epochs,
                1e-3,
                say,
                {"train": command},
            )
        )
    for directory in kitti_models:
        m, c = load_sun_bcnn(directory)
        c.calibration = {  # the mode calibrated in is the mode the card names: the one it then runs in
            **calibrate(m, c, [validation], samples=args.samples, mode=DEFAULT_MODE, cache_dir=out / ".cache"),
            "mode": DEFAULT_MODE,
            "on": "KITTI 07 frames 128-159",
        }
        write_card(directory, c)
    kitti_results.append(on_kitti("fine-tuned on 07, KITTI 06", tuned, "06"))
    if scratch_epochs:
        kitti_results.append(on_kitti("trained on 07 alone, KITTI 06", kitti_models[1], "06"))
    report += ["```", format_table(kitti_results), "```", ""]
    for r in kitti_results:
        figures[f"kitti.{r.label}.vector_median_deg"] = r.figures["vector_median_deg"]
        figures[f"kitti.{r.label}.anees"] = r.figures["anees"]

    return report, figures


def run_kitti_only(args: argparse.Namespace) -> int:
    """``--kitti-only``: experiment 5 alone, its report and metrics.json."""
    from pvo_core.results import RunResult
    from pvo_pseudosensors.sun_bcnn.infer import load_sun_bcnn

    config = load_sun_bcnn(args.model)[0].config
    synthetic = synthetic_mix(args.corpus, args.finetune_synthetic, config.spec) if args.finetune_synthetic else None
    session = ExperimentRun.start(args)
    report = ["# pvo experiment sun-bcnn (experiment 5 only)", "", f"Command: `{session.command}`", ""]
    lines, figures = kitti_experiment(args, config, session.out, session.say, session.command, synthetic)
    report += [*lines, f"Wall time {session.seconds:.0f} s."]
    (session.out / "report.md").write_text("\n".join(report) + "\n")
    inputs = {"model": str(args.model), "corpus": str(args.corpus or "")}
    RunResult("experiment", "sun-bcnn", figures=figures, tables={}, inputs=inputs).write(session.out)
    print("\n".join(report))
    print(f"wrote {session.out}/report.md and metrics.json")
    return 0


def run(args: argparse.Namespace) -> int:
    from pvo_core.readers import read_corpus_manifest, read_kitti_sun_csv
    from pvo_core.results import RunResult
    from pvo_pseudosensors.learning.checkpoint import read_card
    from pvo_pseudosensors.sun_bcnn.estimator import resolve_model
    from pvo_pseudosensors.sun_bcnn.evaluation import calibration_curve, method_comparison, time_per_image
    from pvo_pseudosensors.sun_bcnn.infer import (
        MODES,
        Draws,
        card_calibration,
        card_fusion,
        load_sun_bcnn,
        model_mode,
        predict_sequence,
        predictions_from_draws,
        sample_sequence,
    )

    from ..plots import pyplot
    from .sun_sim import experiment_config

    if not args.finetune_learning_rate > 0.0:
        raise ValueError(f"--finetune-learning-rate {args.finetune_learning_rate}: must be positive")
    rig_error = parse_rig_error(args.fusion_rig_error)
    lens = parse_lens(args.fusion_lens)
    if args.finetune_epochs < 1:
        raise ValueError(f"--finetune-epochs {args.finetune_epochs}: the KITTI fine-tune needs at least one epoch")
    if args.finetune_synthetic < 0:
        raise ValueError(f"--finetune-synthetic {args.finetune_synthetic}: a number of images, 0 for none")
    if args.scratch_epochs is not None and args.scratch_epochs < 0:
        raise ValueError(f"--scratch-epochs {args.scratch_epochs}: must be 0 (skip) or a number of epochs")
    if args.kitti_only and args.skip_kitti:
        raise ValueError("--kitti-only and --skip-kitti leave nothing to run")
    if args.corpus is None and (not args.kitti_only or args.finetune_synthetic):
        raise ValueError("--corpus is needed" + (" for --finetune-synthetic" if args.kitti_only else " (or --kitti-only)"))
    args.model = resolve_model(str(args.model))  # a shipped name (sun_bcnn) or a directory
    if not args.skip_kitti:
        finetune_selection(args)  # a wrong --finetune-trainable is said before any long work
    if args.kitti_only:
        return run_kitti_only(args)
    manifest = read_corpus_manifest(args.corpus)
    test = manifest.split("test")
    if not test:
        raise ValueError(f"{manifest.path}: no sequence in the test split")
    if args.fusion_sequences and args.fusion_preset:  # before anything is written
        of_preset = sum(s.preset == args.fusion_preset for s in test)
        if of_preset < args.fusion_sequences:
            presets = ", ".join(sorted({s.preset for s in test}))
            raise ValueError(
                f"--fusion-preset {args.fusion_preset}: {of_preset} test sequences of it in {manifest.path}, "
                f"{args.fusion_sequences} asked for (its test split's presets: {presets})"
            )
    card = read_card(args.model)  # how experiment 4 fuses the learned sun: its card's calibration.fusion
    try:
        learned_fusion = {} if args.independent_sun else card_fusion(card)
        experiment_config(learned_fusion)
    except ValueError as exc:
        raise ValueError(f"{args.model}: the card's calibration.fusion: {exc}") from None
    session = ExperimentRun.start(args)
    say, command, out = session.say, session.command, session.out
    cache = Path(args.corpus) / ".cache"
    models = {"aleatoric": args.model} | ({"homoscedastic": args.homoscedastic} if args.homoscedastic else {})
    loaded = {name: load_sun_bcnn(path) for name, path in models.items()}
    synthetic = None  # the fine-tune's synthetic images, checked before the long work
    if args.finetune_synthetic and not args.skip_kitti:
        synthetic = synthetic_mix(args.corpus, args.finetune_synthetic, loaded["aleatoric"][0].config.spec)
    report = ["# pvo experiment sun-bcnn", "", f"Command: `{command}`", ""]
    figures: dict[str, float] = {}
    tables: dict[str, Any] = {}

    # 1-3: the corpus's test split
    per_model: dict[str, dict[str, Any]] = {}
    for name, (model, card) in loaded.items():
        calibration = card_calibration(card)
        per_sequence, all_rows, all_truth, all_draws_vectors, all_inverse = [], [], [], [], []
        for sequence in test:
            say(f"{name}: predicting test sequence {sequence.name} ...")
            frames, draws = sample_sequence(model, card, sequence.root, args.samples, cache_dir=cache)
            predictions = predictions_from_draws(frames, draws, calibration)
            truth = read_kitti_sun_csv(sequence.root / "sun.csv")[frames]
            rows = predictions.rows()
            per_sequence.append(
                (
                    sequence,
                    evaluate(
                        f"{sequence.name} {sequence.preset}{' overcast' if 'overcast' in sequence.conditions else ''}",
                        rows,
                        truth,
                    ),
                )
            )
            all_rows.append(rows)
            all_truth.append(truth)
            all_draws_vectors.append(draws.vectors)
            all_inverse.append(draws.inverse_concentration)
        rows, truth = np.vstack(all_rows), np.vstack(all_truth)
        overall = evaluate(f"all {len(test)} test sequences", rows, truth)
        overcast = [r for s, r in per_sequence if "overcast" in s.conditions]
        sunny = [r for s, r in per_sequence if "overcast" not in s.conditions]
        groups = {}
        for label, members in (("sunny", sunny), ("overcast", overcast)):
            if members:
                groups[label] = evaluate(
                    f"{label} ({len(members)} sequences)",
                    np.vstack([m.rows for m in members]),
                    np.vstack([m.truth for m in members]),
                )
        draws_all = Draws(
            np.concatenate(all_draws_vectors, axis=1), None if all_inverse[0] is None else np.concatenate(all_inverse, axis=1)
        )
        per_model[name] = {
            "per_sequence": per_sequence,
            "overall": overall,
            "groups": groups,
            "draws": draws_all,
            "truth": truth,
            "calibration": calibration,
            "card": card,
            "model": model,
        }
        for key, value in overall.figures.items():
            figures[f"{name}.{key}"] = value
        for label, group in groups.items():
            figures[f"{name}.{label}.vector_median_deg"] = group.figures["vector_median_deg"]
            figures[f"{name}.{label}.anees"] = group.figures["anees"]

    default = per_model["aleatoric"]
    model, card = loaded["aleatoric"]
    say("the other MC modes and timing ...")
    other_modes: dict[str, Any] = {}
    own_mode = model_mode(card)  # the mode the rows above ran in: the one its tau was calibrated in
    for mode in (m for m in MODES if m != own_mode):
        mode_rows, mode_truth = [], []
        for sequence in test:
            p = predict_sequence(model, card, sequence.root, args.samples, cache_dir=cache, mode=mode)
            mode_rows.append(p.rows())
            mode_truth.append(read_kitti_sun_csv(sequence.root / "sun.csv")[p.frames])
        other_modes[mode] = evaluate(f"aleatoric, {mode}", np.vstack(mode_rows), np.vstack(mode_truth))
        figures.update({f"{mode}.{k}": v for k, v in other_modes[mode].figures.items()})
    timing = {mode: time_per_image(model, card, 40, mode, args.samples) for mode in MODES}
    figures.update({f"ms_per_image_{mode}": ms for mode, ms in timing.items()})

    report += ["## 1. Accuracy on the corpus's test split (Table 5.1's columns; degrees)", ""]
    for name, result in per_model.items():
        report += [
            f"### {name} model (`{models[name]}`, covariance scale {result['calibration'].scale:.3g}, tau^-1 = "
            f"{0.0 if np.isinf(result['calibration'].tau) else 1 / result['calibration'].tau:.4g} rad²)",
            "",
            "```",
        ]
        report.append(format_table([r for _, r in result["per_sequence"]] + [result["overall"]]))
        report += ["```", ""]
    report += [
        f"MC modes of the aleatoric model (N = {args.samples}; full: dropout everywhere, head: the backbone once, "
        "-mirrored: half the passes over the mirrored image; the rows above ran in the model's calibrated mode, "
        f"{own_mode}):",
        "",
        "```",
    ]
    mode_results = {own_mode: default["overall"], **other_modes}
    report.append(format_table([replace(mode_results[m], label=m) for m in MODES]))
    report += ["```", "", "Time per image, one thread, batch 1: " + ", ".join(f"{m} {timing[m]:.1f} ms" for m in MODES) + ".", ""]

    fig, axes = pyplot().subplots(1, 2, figsize=(11, 4.5))
    for name, result in per_model.items():
        predicted, actual = calibration_curve(np.vstack([r.rows for _, r in result["per_sequence"]]), result["truth"])
        axes[0].plot(predicted, actual, "o-", label=name)
        anees = [r.figures["anees"] for _, r in result["per_sequence"]]
        axes[1].plot(range(len(anees)), anees, "o", label=name)
    top = max(axes[0].get_xlim()[1], axes[0].get_ylim()[1])
    axes[0].plot([0, top], [0, top], "k--", lw=1, label="ideal")
    axes[0].set_xlabel("predicted sigma per axis (deg)")
    axes[0].set_ylabel("actual RMS error per axis (deg)")
    axes[0].set_title("calibration (test split, 8 equal-count bins)")
    axes[0].legend()
    axes[1].axhspan(0.7, 1.5, color="0.9")
    axes[1].set_yscale("log")
    axes[1].set_xlabel("test sequence")
    axes[1].set_ylabel("ANEES")
    axes[1].set_title("ANEES per test sequence")
    axes[1].legend()
    fig.tight_layout()
    fig.savefig(out / "calibration.png", dpi=110)
    report += ["![calibration](calibration.png)", ""]

    report += ["## 2. Cloud cover (§5.10.1)", "", "```"]
    report.append(
        format_table([replace(g, label=f"{name}: {g.label}") for name, r in per_model.items() for g in r["groups"].values()])
    )
    report += ["```", ""]

    report += ["## 3. Method I vs Method II (Tables 5.7, 5.8), aleatoric model, test split", ""]
    methods = method_comparison(default["draws"], default["truth"], default["calibration"])
    tables["methods"] = methods
    report += [
        "| mean | vector mean | median | std | zenith mean | azimuth mean | ANEES, cov. Method I | ANEES, cov. Method II |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for mean_name, row in methods.items():
        report.append(
            f"| {mean_name} | {row['vector_mean_deg']:.2f} | {row['vector_median_deg']:.2f} | {row['vector_std_deg']:.2f} | "
            f"{row['zenith_mean_deg']:.2f} | {row['azimuth_mean_deg']:.2f} | "
            f"{row['anees_cov_Method I']:.2f} | {row['anees_cov_Method II']:.2f} |"
        )
    report += ["", "## 4. Fusion on long synthetic sequences (Table 5.2)", ""]
    if args.fusion_sequences:
        # a folder per preset: a render's manifest lists the sequences of its last call only
        preset_suffix = f"-{args.fusion_preset}" if args.fusion_preset else ""
        folders = render_fusion_sequences(
            args.corpus,
            args.fusion_sequences,
            args.fusion_frames,
            out / f"fusion-sequences{preset_suffix}",
            args.jobs,
            say,
            (),
            args.fusion_preset,
        )
        lens_folders = (
            render_fusion_sequences(
                args.corpus,
                args.fusion_sequences,
                args.fusion_frames,
                out / f"fusion-sequences-lens{preset_suffix}",
                args.jobs,
                say,
                lens,
                args.fusion_preset,
            )
            if lens
            else None
        )
        if learned_fusion:
            settings = ", ".join(f"`{name}: {value}`" for name, value in learned_fusion.items())
            how = (
                f"with the settings of the model's card (`calibration.fusion`): {settings} — a (zenith, azimuth) offset "
                "shared by a drive's readings; the GT-Sun rows' readings have none."
            )
        else:
            why = "`--independent-sun`" if args.independent_sun else "the card has no `calibration.fusion`"
            how = f"as independent ({why})."
        report += [f"The Sun-BCNN row fuses the readings {how}", ""]
        for rig in fusion_rigs(folders, rig_error, lens, lens_folders):
            key = rig.key
            inputs = [fusion_inputs(folder, model, card, args.samples, rig.rig_error) for folder in rig.folders]
            fused = fusion_experiment(
                [seq for seq, _ in inputs], [learned for _, learned in inputs], say=say, learned_fusion=learned_fusion
            )
            changes = fusion_changes(fused)
            tables[key], tables[f"{key}_changes"] = fused, changes
            for row, c in changes.items():
                for estimate in ("online", "smoothed"):
                    for metric in ("trans", "rot"):
                        figures[f"{key}.{row}.{estimate}.{metric}_change"] = c[estimate][metric]
            report += fusion_section(fused, changes, len(rig.folders), args.fusion_frames, rig.title, rig.vo, args.fusion_preset)
        report += [
            "The thesis's sliding window held two poses (thesis-code-facts §4): each pose of its trajectory is the "
            "estimate one frame after it was newest — the online estimate here is the closer match.",
            "",
        ]
    else:
        report += ["Skipped (--fusion-sequences 0).", ""]

    if not args.skip_kitti:
        kitti_report, kitti_figures_ = kitti_experiment(args, loaded["aleatoric"][0].config, out, say, command, synthetic)
        report += kitti_report
        figures.update(kitti_figures_)

    report.append(f"Wall time {session.seconds:.0f} s.")
    (out / "report.md").write_text("\n".join(report) + "\n")
    inputs = {
        "corpus": str(args.corpus),
        "corpus_sha256": manifest.sha256,
        "model": str(args.model),
        "homoscedastic": str(args.homoscedastic or ""),
    }
    RunResult("experiment", "sun-bcnn", figures=figures, tables=tables, inputs=inputs).write(out)
    print("\n".join(report))
    print(f"wrote {out}/report.md, calibration.png and metrics.json")
    return 0
