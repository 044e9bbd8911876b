"""`pvo experiment hydranet`: HydraNet's experiments (thesis ch. 7) on the rendered corpus and real KITTI images.

1. Accuracy and consistency on the corpus's held-out test split (Table 7.3's figures), beside the stereo VO's
   own frame-to-frame rotation error on the same pairs.
2. Out of distribution (§7.5.1): a model trained on one preset only, tested on its preset and on the other.
3. The aleatoric head's form: a full Cholesky factor (the thesis) against a diagonal one (the authors' code).
4. Fusion (Table 7.2): stereo VO + HydraNet through :class:`pvo_fusion.FusionGraph` on long held-out sequences
   driven along KITTI's test drives, some with a biased VO (wrong focal length or baseline, radial
   distortion, blur); online and fixed-lag estimates separately.
5. Real images: KITTI 07 and the 06 clip with the synthetic model, then fine-tuned on 07 and tested on 06.
"""

from __future__ import annotations

import argparse
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..paths import data_directory
from .common import ExperimentRun, another_world, fusion_figures, rendered_by_this_revision, trajectory_tables

TITLE = "HydraNet (ch. 7, Tables 7.2-7.3): rotation accuracy, consistency, out of distribution, fusion, real images"
Array = NDArray[np.float64]
FIRST_STAMP_NS = 1_000_000_000  # the fusion's stamps start at 1 s (a zero stamp reads as unset in ROS)
#: the fusion section's reference row: HydraNet's covariances with the true rotations in place of its own
TRUE_ROTATIONS = "VO + true rotations"

#: The fusion sequences: name, KITTI test drive, first pose, degradations (the VO's bias).
FUSION_SEQUENCES: tuple[tuple[str, str, int, dict[str, float]], ...] = (
    ("05-clean", "05", 0, {}),
    ("05-focal+3%", "05", 1700, {"focal_scale": 1.03}),
    ("06-distorted", "06", 0, {"distortion": -0.25}),
    ("07-blur", "07", 0, {"blur_px": 4.0}),
    ("05-baseline-3%", "05", 900, {"baseline_scale": 0.97}),
)


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--corpus", type=Path, required=True, help="corpus (its test split is held out)")
    parser.add_argument(
        "--model", type=Path, required=True, help="the HydraNet model to evaluate: a directory or a shipped name (hydranet)"
    )
    parser.add_argument(
        "--other-form",
        "--diagonal",
        dest="other_form",
        type=Path,
        help="the same model trained with the other --covariance form (cholesky / diagonal; section 3)",
    )
    parser.add_argument("--fusion-sequences", type=int, default=5, help="long fusion sequences (0-5; 0 skips section 4)")
    parser.add_argument("--fusion-frames", type=int, default=1000, help="frames per fusion sequence (default 1000)")
    parser.add_argument("--fusion-dir", type=Path, help="where the fusion sequences are rendered (default OUT/fusion-sequences)")
    parser.add_argument(
        "--fusion-world",
        type=int,
        default=0,
        help="which worlds the fusion drives go through: 0 the experiment's own, K > 0 other worlds along the same "
        "drives, degradations and suns (the spread of section 4's figures; give each its own --fusion-dir)",
    )
    parser.add_argument("--finetune-epochs", type=int, default=15, help="fine-tuning epochs on KITTI 07 (0 skips it)")
    parser.add_argument("--data", type=Path, help="the shared data directory (default ../shared/data)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    parser.add_argument("--out", "-o", type=Path, default=Path("runs/experiment-hydranet"), help="output directory")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress lines")


@dataclass
class Evaluated:
    label: str
    figures: dict[str, float]


#: KITTI's cameras look level (within a degree): what a model with the pitch input is told on KITTI images.
KITTI_PITCH_DEG = 0.0


def evaluate_sequence(
    model: Any, card: Any, root: Path, label: str, cache: Path | None, pitch_deg: float | None = None
) -> tuple[Evaluated, Any]:
    from pvo_core.trajectory import read_kitti_poses
    from pvo_pseudosensors.hydranet.evaluation import evaluate_rotations, true_relative_rotations
    from pvo_pseudosensors.hydranet.infer import predict_sequence

    predictions = predict_sequence(model, card, root, cache_dir=cache, pitch_deg=pitch_deg)
    truth = true_relative_rotations(read_kitti_poses(root / "poses.txt"), predictions.earlier, predictions.frames)
    figures = evaluate_rotations(predictions.quaternions, predictions.covariance, truth)
    figures["epistemic_trace"] = float(np.trace(predictions.epistemic, axis1=1, axis2=2).mean())
    figures["aleatoric_trace"] = float(np.trace(predictions.aleatoric, axis1=1, axis2=2).mean())
    return Evaluated(label, figures), (predictions, truth)


def heads_spread(model: Any, card: Any, sequences: list[Any], presets: tuple[str, ...], cache: Path | None) -> dict[str, float]:
    """Mean tr Sigma_e (rad²) of the heads alone — no spread or shortfall widening — over the pairs of ``sequences`` of
    each preset."""
    from pvo_pseudosensors.hydranet.infer import predict_sequence

    widening, model.widening = getattr(model, "widening", None), None
    shortfall, model.shortfall_widening = getattr(model, "shortfall_widening", None), None
    try:
        return {
            preset: float(
                np.concatenate(
                    [
                        np.trace(predict_sequence(model, card, s.root, cache_dir=cache).epistemic, axis1=1, axis2=2)
                        for s in sequences
                        if s.preset == preset
                    ]
                ).mean()
            )
            for preset in presets
        }
    finally:
        model.widening, model.shortfall_widening = widening, shortfall


def pooled(label: str, parts: list[tuple[Any, Array]]) -> Evaluated:
    from pvo_pseudosensors.hydranet.evaluation import evaluate_rotations

    quaternions = np.vstack([p.quaternions for p, _ in parts])
    covariance = np.concatenate([p.covariance for p, _ in parts])
    figures = evaluate_rotations(quaternions, covariance, np.concatenate([t for _, t in parts]))
    figures["epistemic_trace"] = float(np.concatenate([np.trace(p.epistemic, axis1=1, axis2=2) for p, _ in parts]).mean())
    figures["aleatoric_trace"] = float(np.concatenate([np.trace(p.aleatoric, axis1=1, axis2=2) for p, _ in parts]).mean())
    return Evaluated(label, figures)


#: (sequence, poses file, rate) -> the VO's rotation errors and run: sections 1, 3 and 4 reuse the same runs
_VO_RUNS: dict[tuple[Path, Path | None, float | None], tuple[Array, Any]] = {}


def vo_rotation_errors(root: Path, poses_file: Path | None = None, rate_hz: float | None = None) -> tuple[Array, Any]:
    """The stereo VO's frame-to-frame rotation error (deg) per pair of a sequence (truth: ``poses_file``, default
    its poses.txt), and its run (the VO is deterministic: each sequence is run once per process)."""
    key = (Path(root), poses_file, rate_hz)
    if key not in _VO_RUNS:
        _VO_RUNS[key] = _vo_rotation_errors(Path(root), poses_file, rate_hz)
    return _VO_RUNS[key]


def _vo_rotation_errors(root: Path, poses_file: Path | None, rate_hz: float | None) -> tuple[Array, Any]:
    from pvo_core.readers import KittiSequence
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig
    from pvo_pseudosensors.hydranet.evaluation import angular_errors_deg, true_relative_rotations

    sequence = KittiSequence(root, rate_hz=rate_hz, poses_file=poses_file or root / "poses.txt")
    run = run_sequence(sequence, VOConfig())
    frames = np.arange(1, len(sequence))
    truth = true_relative_rotations(sequence.poses, frames - 1, frames)
    return angular_errors_deg(run.relative()["transforms"][:, :3, :3], truth), run


COLUMNS = (
    ("pairs", "pairs", 6, ".0f"),
    ("mean (deg)", "angle_mean_deg", 10, ".4f"),
    ("median", "angle_median_deg", 8, ".4f"),
    ("NLL", "nll", 8, ".2f"),
    ("ANEES", "anees", 7, ".2f"),
    ("tr Se", "epistemic_trace", 9, ".2e"),
    ("tr Sa", "aleatoric_trace", 9, ".2e"),
)


def model_presets(card: Any, manifest: Any) -> set[str]:
    """The presets a model was trained on: its card's (``--presets-only``; of each corpus, for a model trained on
    several), else every preset of the corpus."""
    corpus = card.corpus if isinstance(card.corpus, dict) else {}
    parts = corpus.get("corpora") or [corpus]
    if not all(part.get("presets") for part in parts):
        return {s.preset for s in manifest.split("train")}
    return {preset for part in parts for preset in part["presets"]}


def format_table(rows: list[Evaluated], extra: dict[str, float] | None = None, extra_name: str = "") -> str:
    head = "| sequence | " + " | ".join(name for name, *_ in COLUMNS) + (f" | {extra_name}" if extra else "") + " |"
    lines = [head, "|" + "---|" * (len(COLUMNS) + 1 + bool(extra))]
    for row in rows:
        cells = [format(row.figures[key], spec) for _, key, _, spec in COLUMNS]
        if extra:
            cells.append(f"{extra[row.label]:.4f}" if row.label in extra else "")
        lines.append(f"| {row.label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def validation_fusion(models: list[tuple[Any, Any]], manifest: Any, presets: set[str]) -> list[dict[str, float]]:
    """Each (model, card) fused with the stereo VO on the corpus's validation sequences of ``presets`` (short, but
    never test): the mean relative change of m-ATE (translation, rotation) against the VO alone, online. The VO's
    covariance scales are learned on the same sequences, once for all models. Sequences without right images (a
    monocular corpus) are left out; an empty record per model when none is left."""
    from pvo_core.readers import KittiSequence
    from pvo_core.trajectory import read_kitti_poses
    from pvo_pseudosensors.hydranet.infer import chained, predict_sequence

    from pvo_fusion import CalibrationSequence, FusionGraph, calibrate_vo, ordered_events, run_offline, vo_measurements
    from pvo_fusion.config import from_flat

    validation = [s for s in manifest.split("validation") if s.preset in presets and (s.root / "image_1").is_dir()]
    if not validation:
        return [{} for _ in models]
    prepared, calibration_sequences = [], []
    for item in validation:
        _, run = vo_rotation_errors(item.root)
        relative = run.relative()
        truth = read_kitti_poses(item.root / "poses.txt")
        sequence = KittiSequence(item.root, poses_file=item.root / "poses.txt")
        stamps = FIRST_STAMP_NS + (np.asarray(sequence.stamps) * 1e9).round().astype(np.int64)
        prepared.append((item, truth, run, relative, stamps))
        calibration_sequences.append(CalibrationSequence(item.name, truth, relative["transforms"], relative["covariances"]))
    calibration = calibrate_vo(calibration_sequences, 1)
    config = from_flat({"prior.source": "given"})
    out = []
    for model, card in models:
        changes: dict[str, list[float]] = {"m_ate_trans": [], "m_ate_rot_deg": []}
        for item, truth, run, relative, stamps in prepared:
            vo = vo_measurements(stamps, relative["transforms"], relative["covariances"], calibration)
            rotations = rotation_measurements(chained(predict_sequence(model, card, item.root)), stamps)
            graph = FusionGraph(config)
            graph.set_initial_pose(truth[0])
            fused = run_offline(graph, stamps, ordered_events(vo, [("rotation", m) for m in rotations]))
            alone, with_hydranet = fusion_figures(truth, truth[0] @ run.poses), fusion_figures(truth, fused.online_poses)
            for key in changes:
                changes[key].append(with_hydranet[key] / max(alone[key], 1e-12) - 1.0)
        out.append({key: float(np.mean(values)) for key, values in changes.items()} | {"sequences": float(len(validation))})
    return out


# world seeds of the fusion drives: drive i of world K is seeded FUSION_SEED + i + FUSION_WORLD_STRIDE * K
FUSION_SEED = 700
FUSION_WORLD_STRIDE = 1000


def render_fusion_sequences(data: Path, count: int, frames: int, out: Path, say: Any, world: int = 0) -> list[Path]:
    """The first ``count`` of :data:`FUSION_SEQUENCES` rendered (urban, 1x, seeded; ``world`` K > 0: other worlds
    along the same drives) into ``out``; complete ones of this renderer revision and configuration are kept (pvo
    sim moves a sequence into place only when whole); a folder holding another world's drive is one line."""
    from pvo_sim.degrade import Degradations
    from pvo_sim.render import SimConfig, simulate

    if world < 0:
        raise ValueError(f"--fusion-world must be >= 0, got {world}")

    folders = []
    for index, (name, drive, start, degradations) in enumerate(FUSION_SEQUENCES[:count]):
        folder = out / name
        folders.append(folder)
        config = SimConfig(
            preset="urban",
            frames=frames,
            poses_file=str((data / "kitti" / "poses" / f"{drive}.txt").resolve()),
            start_frame=start,
            heading_deg=float(37 * index % 360),
            seed=FUSION_SEED + index + FUSION_WORLD_STRIDE * world,
            supersample=1,
            start_time="2011-09-30T10:30:00Z",
            degradations=Degradations(**degradations),  # type: ignore[arg-type]
        )
        if rendered_by_this_revision(folder):
            if (error := another_world(folder, config.seed, "--fusion-dir")) is not None:
                raise error
            continue
        say(f"rendering fusion sequence {name} (KITTI {drive} from frame {start}, {frames} frames, world {world}) ...")
        simulate(config, folder, overwrite=True)  # an older revision's, or none
    return folders


def rotation_measurements(predictions: Any, stamps: NDArray[np.int64], rotations: Array | None = None) -> list[Any]:
    """HydraNet's predictions as the rotation-only measurements the fusion takes (what the node publishes);
    ``rotations`` (N, 3, 3): other rotations in their place, with the predictions' covariances."""
    from pvo_core.lie import quaternion_to_rotation
    from pvo_pseudosensors.hydranet.estimator import pose_covariance

    from pvo_fusion import RelativeMeasurement

    if rotations is None:
        rotations = np.stack([quaternion_to_rotation(q) for q in predictions.quaternions])
    out = []
    for a, b, rotation, covariance in zip(
        predictions.earlier, predictions.frames, rotations, predictions.covariance, strict=True
    ):
        transform = np.eye(4)
        transform[:3, :3] = rotation
        out.append(
            RelativeMeasurement(int(stamps[b]), int(stamps[a]), transform, pose_covariance(covariance), rotation_only=True)
        )
    return out


def stage_kitti(data: Path, drive: str, frames: range, poses_file: Path, out: Path) -> Path:
    """A sequence folder of KITTI left images (links, renumbered from 0) and their poses, for the datasets."""
    from pvo_core.trajectory import read_kitti_poses

    images = sorted((data / "kitti" / "sequences" / drive / "image_0").glob("*.png"))
    poses = read_kitti_poses(poses_file)
    out.mkdir(parents=True, exist_ok=True)
    (out / "image_0").mkdir(exist_ok=True)
    for new, frame in enumerate(frames):
        link = out / "image_0" / f"{new:06d}.png"
        if not link.exists():
            link.symlink_to(images[frame].resolve())
    relative = np.linalg.inv(poses[frames[0]]) @ poses[list(frames)]
    (out / "poses.txt").write_text("\n".join(" ".join(f"{v:.12e}" for v in p[:3].reshape(-1)) for p in relative) + "\n")
    return out


def run(args: argparse.Namespace) -> int:
    import torch
    from pvo_core.readers import read_corpus_manifest
    from pvo_core.results import RunResult
    from pvo_pseudosensors.hydranet.estimator import resolve_model
    from pvo_pseudosensors.hydranet.infer import load_hydranet

    args.model = resolve_model(str(args.model))  # a shipped name (hydranet) or a directory
    torch.set_num_threads(args.threads)
    session = ExperimentRun.start(args)
    say, out = session.say, session.out
    data = args.data or data_directory()
    manifest = read_corpus_manifest(args.corpus)
    test = manifest.split("test")
    if not test:
        raise ValueError(f"{manifest.path}: no sequence in the test split")
    if not 0 <= args.fusion_sequences <= len(FUSION_SEQUENCES):
        raise ValueError(f"--fusion-sequences must be in [0, {len(FUSION_SEQUENCES)}], got {args.fusion_sequences}")
    cache = Path(args.corpus) / ".cache"
    model, card = load_hydranet(args.model)
    report = ["# pvo experiment hydranet", "", f"Command: `{session.command}`", ""]
    figures: dict[str, float] = {}
    tables: dict[str, Any] = {}

    # 1. accuracy on the held-out test split, with the stereo VO's frame-to-frame error beside it
    trained_on = model_presets(card, manifest)
    rows, parts, vo_errors = [], [], {}
    by_preset: dict[str, list[Any]] = {}
    vo_by_preset: dict[str, list[Array]] = {}
    for sequence in test:
        label = f"{sequence.name} {sequence.preset}"
        say(f"test sequence {label}: HydraNet and the stereo VO ...")
        evaluated, part = evaluate_sequence(model, card, sequence.root, label, cache)
        rows.append(evaluated)
        parts.append(part)
        by_preset.setdefault(sequence.preset, []).append(part)
        if (sequence.root / "calib.txt").is_file() and (sequence.root / "image_1").is_dir():  # a stereo sequence
            errors, _ = vo_rotation_errors(sequence.root)
            vo_errors[label] = float(errors.mean())
            vo_by_preset.setdefault(sequence.preset, []).append(errors)
    groups = []
    for preset, members in sorted(by_preset.items()):
        where = "in distribution" if preset in trained_on else "out of distribution"
        group = pooled(f"{preset}: {len(members)} sequences ({where})", members)
        groups.append((preset, preset in trained_on, group))
        figures.update({f"test.{preset}.{k}": v for k, v in group.figures.items()})
        if preset in vo_by_preset:
            vo_errors[group.label] = float(np.concatenate(vo_by_preset[preset]).mean())
            figures[f"test.{preset}.vo_angle_mean_deg"] = vo_errors[group.label]
    tables["test"] = {r.label: r.figures for r in [*rows, *(g for _, _, g in groups)]}
    report += [
        "## 1. Accuracy on the held-out test split (Table 7.3's figures)",
        "",
        f"The model was trained on the {', '.join(sorted(trained_on))} preset(s) of the corpus. Per frame pair: HydraNet's",
        "angular error, the NLL of eq. 7.17 (without its constant), ANEES (1 = consistent) and the mean traces of",
        "Sigma_e and Sigma_a (rad²); the last column is this project's stereo VO's frame-to-frame rotation error on",
        "the same pairs.",
        "",
        format_table([*rows, *(g for _, _, g in groups)], vo_errors, "VO (deg)"),
        "",
    ]

    # 2. out of distribution: the presets the model never saw
    inside = [(p, g) for p, seen, g in groups if seen]
    outside = [(p, g) for p, seen, g in groups if not seen]
    if inside and outside:
        (in_preset, inner), (out_preset, outer) = inside[0], outside[0]
        ratio = outer.figures["epistemic_trace"] / inner.figures["epistemic_trace"]
        total = outer.figures["covariance_trace"] / inner.figures["covariance_trace"]
        figures["ood.epistemic_ratio"], figures["ood.covariance_ratio"] = ratio, total
        figures["ood.anees_in"], figures["ood.anees_out"] = inner.figures["anees"], outer.figures["anees"]
        report += [
            "## 2. Out of distribution (§7.5.1)",
            "",
            f"{outer.label} against {inner.label}: mean tr Sigma_e grows **{ratio:.2f}x** out of distribution,",
            f"the total covariance {total:.2f}x, while the error grows "
            f"{outer.figures['angle_mean_deg'] / inner.figures['angle_mean_deg']:.2f}x; ANEES in "
            f"{inner.figures['anees']:.2f}, out {outer.figures['anees']:.2f}.",
        ]
        if getattr(model, "widening", None) is not None:  # its added part rides in Sigma_e: the heads' own spread too
            heads = heads_spread(model, card, test, (in_preset, out_preset), cache)
            figures["ood.heads_epistemic_ratio"] = heads[out_preset] / heads[in_preset]
            report += [
                f"The card's spread widening counts its added part Sigma_a (f - 1) in Sigma_e; the heads' own spread grows "
                f"{figures['ood.heads_epistemic_ratio']:.2f}x.",
            ]
        report.append("")

    # 3. the aleatoric head's form
    if args.other_form:
        other, other_card = load_hydranet(args.other_form)
        if other_card.hyperparameters.get("covariance") == card.hyperparameters.get("covariance"):
            raise ValueError(
                f"{args.other_form}: its covariance form is {other_card.hyperparameters.get('covariance')!r}, the "
                "same as --model's; section 3 compares the two forms"
            )
        forms = []
        pair = sorted([(model, card), (other, other_card)], key=lambda mc: str(mc[1].hyperparameters.get("covariance")))
        for m, c in pair:
            label = str(c.hyperparameters.get("covariance", "cholesky"))
            form_parts = [evaluate_sequence(m, c, s.root, s.name, cache)[1] for s in test]
            evaluated = pooled(f"{label} (validation loss {c.validation.get('loss', float('nan')):.3f})", form_parts)
            evaluated.figures["validation_loss"] = float(c.validation.get("loss", float("nan")))
            forms.append(evaluated)
            figures[f"form.{label}.validation_loss"] = evaluated.figures["validation_loss"]
            figures[f"form.{label}.anees"] = evaluated.figures["anees"]
        fused = validation_fusion([(m, c) for m, c in pair], manifest, model_presets(card, manifest))
        for evaluated, change in zip(forms, fused, strict=True):
            label = evaluated.label.split()[0]
            for key, value in change.items():
                evaluated.figures[f"validation_fusion_{key}"] = value
                figures[f"form.{label}.validation_fusion.{key}"] = value
        tables["covariance_form"] = {r.label: r.figures for r in forms}
        best = min(forms, key=lambda r: r.figures["validation_loss"])
        lines = [
            "## 3. Aleatoric covariance: full Cholesky factor vs diagonal",
            "",
            "Two criteria on the validation split: the loss (the NLL of eq. 7.17, per frame pair) and what the model "
            "does in the fusion — the stereo VO fused with its rotations on the validation sequences of its presets "
            "(short, VO covariances scaled on them), the mean change of m-ATE against the VO alone. The test figures "
            "are shown for the record.",
            "",
            format_table(forms),
            "",
            f"Lower validation loss: **{best.label.split()[0]}**.",
        ]
        if fused[0]:
            helps = min(forms, key=lambda r: r.figures["validation_fusion_m_ate_rot_deg"])
            lines += [
                "",
                "| form | validation sequences | fused m-ATE trans change | fused m-ATE rot change |",
                "|---|---|---|---|",
                *(
                    f"| {r.label.split()[0]} | {r.figures['validation_fusion_sequences']:.0f} | "
                    f"{100 * r.figures['validation_fusion_m_ate_trans']:+.1f} % | "
                    f"{100 * r.figures['validation_fusion_m_ate_rot_deg']:+.1f} % |"
                    for r in forms
                ),
                "",
                f"Larger rotation gain in the fusion on validation: **{helps.label.split()[0]}**.",
            ]
        else:
            lines += ["", "No stereo validation sequence of the model's presets: the fusion criterion is not measured."]
        report += [*lines, ""]

    # 4. fusion with the stereo VO on long sequences
    if args.fusion_sequences:
        report += fusion_section(args, model, card, manifest, data, out, say, figures, tables)

    # 5. real images
    report += real_images_section(args, model, card, data, out, say, figures, tables, session.command)

    # speed: flow and network per pair on one thread
    report += speed_section(args.model, data, figures)
    (out / "report.md").write_text("\n".join(report) + "\n")
    inputs = {"corpus": str(args.corpus), "model": str(args.model)}
    RunResult("experiment", "hydranet", figures=figures, tables=tables, inputs=inputs).write(out)
    say(f"{out / 'report.md'} written in {session.seconds:.0f} s")
    print((out / "report.md").read_text())
    return 0


def fusion_section(
    args: Any, model: Any, card: Any, manifest: Any, data: Path, out: Path, say: Any, figures: dict, tables: dict
) -> list[str]:
    from pvo_core.readers import KittiSequence
    from pvo_core.trajectory import read_kitti_poses
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig
    from pvo_pseudosensors.hydranet.evaluation import true_relative_rotations
    from pvo_pseudosensors.hydranet.infer import chained, predict_sequence

    from pvo_fusion import (
        CalibrationSequence,
        FusionConfig,
        FusionGraph,
        calibrate_vo,
        ordered_events,
        run_offline,
        vo_measurements,
    )
    from pvo_fusion.config import from_flat

    folders = render_fusion_sequences(
        data, args.fusion_sequences, args.fusion_frames, args.fusion_dir or out / "fusion-sequences", say, args.fusion_world
    )
    # the VO's covariance scales are learned on the corpus's validation split, the model's presets (frame to
    # frame: HydraNet's span)
    calibration_sequences = []
    presets = model_presets(card, manifest)
    for sequence in [s for s in manifest.split("validation") if s.preset in presets]:
        _, run = vo_rotation_errors(sequence.root)
        relative = run.relative()
        truth = read_kitti_poses(sequence.root / "poses.txt")
        calibration_sequences.append(CalibrationSequence(sequence.name, truth, relative["transforms"], relative["covariances"]))
    calibration = calibrate_vo(calibration_sequences, 1)
    say(
        f"VO covariance scales (x y z rx ry rz) from {len(calibration_sequences)} validation sequences: "
        f"{np.round(calibration.scale, 2)}"
    )
    config: FusionConfig = from_flat({"prior.source": "given"})
    results: dict[str, dict[str, dict[str, float]]] = {}
    for folder in folders:
        say(f"fusion sequence {folder.name}: VO, HydraNet, fusion ...")
        sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
        truth = sequence.poses
        stamps = FIRST_STAMP_NS + (np.asarray(sequence.stamps) * 1e9).round().astype(np.int64)
        run = run_sequence(sequence, VOConfig())
        relative = run.relative()
        vo = vo_measurements(stamps, relative["transforms"], relative["covariances"], calibration)
        predictions = chained(predict_sequence(model, card, folder))  # a gap model's pairs as the fusion takes them
        rotations = rotation_measurements(predictions, stamps)
        truths = true_relative_rotations(truth, predictions.earlier, predictions.frames)
        errorless = rotation_measurements(predictions, stamps, truths)
        rows: dict[str, dict[str, float]] = {"VO": fusion_figures(truth, truth[0] @ run.poses)}
        for label, others in (
            ("VO fused alone", []),
            ("VO + HydraNet", [("rotation", m) for m in rotations]),
            (TRUE_ROTATIONS, [("rotation", m) for m in errorless]),
        ):
            graph = FusionGraph(config)
            graph.set_initial_pose(truth[0])
            fused = run_offline(graph, stamps, ordered_events(vo, others))
            rows[f"{label} online"] = fusion_figures(truth, fused.online_poses)
            rows[f"{label} smoothed"] = fusion_figures(truth, fused.poses)
        results[folder.name] = rows
        say(
            f"  {folder.name}: m-ATE rot VO {rows['VO']['m_ate_rot_deg']:.3f} deg, fused online "
            f"{rows['VO + HydraNet online']['m_ate_rot_deg']:.3f}, smoothed {rows['VO + HydraNet smoothed']['m_ate_rot_deg']:.3f}"
        )
    tables["fusion"] = results
    names = list(results)
    lines = [
        "## 4. Fusion with the stereo VO (Table 7.2)",
        "",
        f"{len(names)} sequences of {args.fusion_frames} frames rendered along KITTI's test drives (05, 06, 07: no",
        "training sequence drove them), some with a biased VO. VO covariances scaled per axis on the corpus's",
        "validation split. *online*: the newest state as the fusion node publishes it; *smoothed*: after the",
        "fixed lag. The thesis fused each frame pair alone (Appendix), so its numbers compare with the online column.",
        "",
    ]
    lines += [
        f"*{TRUE_ROTATIONS}*: HydraNet's measurements with their covariances but the true rotations — what a rotation",
        "sensor as confident as HydraNet and without error gives through the same fusion and gate (for HydraNet what",
        "the GT-Sun rows are for Sun-BCNN). HydraNet itself can do better where its errors cancel the VO's.",
        "",
    ]
    labels = ["VO + HydraNet online", "VO + HydraNet smoothed", "VO fused alone online", f"{TRUE_ROTATIONS} online"]
    return lines + trajectory_tables(results, "VO", labels, figures, lambda label: f"fusion.{label.replace(' ', '_')}")


def real_images_section(
    args: Any, model: Any, card: Any, data: Path, out: Path, say: Any, figures: dict, tables: dict, command: str
) -> list[str]:
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.flow import FlowPairs
    from pvo_pseudosensors.hydranet.infer import load_hydranet
    from pvo_pseudosensors.learning import Source, TrainConfig

    kitti = data / "kitti"
    clip06 = stage_kitti(data, "06", range(51), kitti / "sequences" / "06" / "poses_frames000-050.txt", out / "kitti06")
    count07 = len(list((kitti / "sequences" / "07" / "image_0").glob("*.png")))
    train07 = stage_kitti(data, "07", range(0, 128), kitti / "poses" / "07.txt", out / "kitti07-train")
    validation07 = stage_kitti(data, "07", range(128, count07), kitti / "poses" / "07.txt", out / "kitti07-validation")
    all07 = stage_kitti(data, "07", range(count07), kitti / "poses" / "07.txt", out / "kitti07")
    rows = []
    for label, root in (
        (f"synthetic model, KITTI 07 (frames 0-{count07 - 1})", all07),
        ("synthetic model, KITTI 06 clip", clip06),
    ):
        evaluated, _ = evaluate_sequence(model, card, root, label, None, KITTI_PITCH_DEG)
        rows.append(evaluated)
    clip = kitti / "sequences" / "06"
    vo06 = float(vo_rotation_errors(clip, clip / "poses_frames000-050.txt", rate_hz=10.0)[0].mean())
    if args.finetune_epochs:
        say(f"fine-tuning on KITTI 07 frames 0-127 for {args.finetune_epochs} epochs (validation 128-{count07 - 1}) ...")
        config = HydraNetConfig.from_card(card)
        told = {
            "texture": config.texture,
            "pitch": config.pitch,
            "pitch_deg": KITTI_PITCH_DEG,
            "flow_prior": config.flow_prior,
            "depth": config.depth,  # a depth model's inputs need the clip's right images and calib.txt too
        }
        train = FlowPairs([Source(train07, "07-train")], config.size, reverse=config.reverse, **told)
        validation = FlowPairs([Source(validation07, "07-validation")], config.size, **told)
        loop = TrainConfig(epochs=args.finetune_epochs, batch_size=16, learning_rate=1e-4, patience=0, threads=args.threads)
        tuned_dir = out / "kitti-finetuned"
        extra = {
            "corpus": card.corpus,
            "commands": {**card.commands, "finetune": f"{command}  # section 5: KITTI 07 frames 0-127, selected on 128-159"},
        }
        finetune(Path(args.model), card, (train, validation), loop, tuned_dir, extra)
        tuned, tuned_card = load_hydranet(tuned_dir)
        evaluated, _ = evaluate_sequence(tuned, tuned_card, clip06, "fine-tuned on 07, KITTI 06 clip", None, KITTI_PITCH_DEG)
        rows.append(evaluated)
        figures["kitti06.finetuned.angle_mean_deg"] = evaluated.figures["angle_mean_deg"]
        figures["kitti06.finetuned.anees"] = evaluated.figures["anees"]
    figures["kitti06.synthetic.angle_mean_deg"] = rows[1].figures["angle_mean_deg"]
    figures["kitti06.vo_angle_mean_deg"] = vo06
    tables["kitti"] = {r.label: r.figures for r in rows}
    return [
        "## 5. Real images (KITTI)",
        "",
        "The left images of `../shared/data` (07: frames 0-159; the 06 clip: 51 frames), truth from the pose files.",
        "Fine-tuning: frames 0-127 of 07, model selection on 128-159; tested on 06 only.",
        "",
        format_table(rows),
        "",
        f"This project's stereo VO on the 06 clip: mean frame-to-frame rotation error {vo06:.4f} deg.",
        "",
    ]


def finetune(model_dir: Path, card: Any, data: tuple[Any, Any], loop: Any, out: Path, card_extra: dict) -> Path:
    """``model_dir``'s network fine-tuned on ``data`` (training, validation FlowPairs) into ``out``; an ensemble
    member by member (``out``-member-<i>), then made one again in ``out`` (:func:`write_ensemble`). The tuned card
    keeps the inference mode of ``card`` (a mirrored or reversed model is tuned and judged in that mode); a feature
    density is not carried (it is of the features before tuning)."""
    from pvo_pseudosensors.hydranet.config import HydraNetConfig
    from pvo_pseudosensors.hydranet.infer import write_ensemble
    from pvo_pseudosensors.hydranet.model import HydraTask, inference_mode
    from pvo_pseudosensors.learning import fit
    from pvo_pseudosensors.learning.checkpoint import read_card, write_card
    from pvo_pseudosensors.learning.training import FineTune

    members = [model_dir, *(model_dir / m for m in (card.calibration or {}).get("members") or [])]
    tuned = [out] if len(members) == 1 else [out.with_name(f"{out.name}-member-{i}") for i in range(len(members))]
    task = HydraTask(HydraNetConfig.from_card(card))
    for member, target in zip(members, tuned, strict=True):
        fit(FineTune(task, member), *data, loop, target, say=lambda _: None, card_extra=card_extra)
    if len(members) > 1:
        shutil.rmtree(out, ignore_errors=True)  # the ensemble an earlier run wrote there
        write_ensemble(tuned, out, card_extra.get("commands", {}).get("finetune", ""))
    tuned_card = read_card(out)
    tuned_card.calibration = {**(tuned_card.calibration or {}), "mode": inference_mode(card)}
    write_card(out, tuned_card)
    return out


def speed_section(model_dir: Path, data: Path, figures: dict) -> list[str]:
    import time

    import cv2
    import torch
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig

    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    images = [
        cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((data / "kitti" / "sequences" / "06" / "image_0").glob("*.png"))
    ]
    sensor = HydraNetSensor(HydraNetSensorConfig(model=str(model_dir)))
    times = []
    for k, image in enumerate(images):
        tic = time.perf_counter()
        sensor.estimate(image, (k + 1) * 100_000_000)
        if k:
            times.append(1e3 * (time.perf_counter() - tic))
    figures["ms_per_pair_median"] = float(np.median(times))
    figures["ms_per_pair_p95"] = float(np.percentile(times, 95))
    return [
        "## Speed",
        "",
        f"Resize, Farnebäck flow and the network per frame pair on one thread (KITTI 06 clip, {images[0].shape[1]}x"
        f"{images[0].shape[0]}): median **{figures['ms_per_pair_median']:.1f} ms**, p95 {figures['ms_per_pair_p95']:.1f} ms.",
        "",
    ]
