"""`pvo experiment dpc-net`: DPC-Net's experiments (thesis ch. 6) on long rendered sequences.

The sequences drive windows of KITTI's test drives (05, 06, 07: no training sequence drove them), rendered
twice: through a clean lens and through the thesis's radial distortion. From them:

1. Table 6.1: a systematic VO bias from a wrong calibration (calib.txt's focal length x1.03; the clean images,
   so only the calibration differs) — S-VO against S-VO + DPC-Net, pose / rotation / yaw models.
2. Table 6.2: the distorted images processed as if undistorted — S-VO against S-VO + DPC-Net (pose).
   Both tables also give the clean rig's VO on the same drives: what removing the rig's error entirely is worth.
3. No harm: a model trained on the clean rig, on the clean sequences where the VO is already good; and the
   model card's rig check refusing a model on a rig it was not trained for.
4. Applying the corrections: the fixed-lag smoother (§6.4.5's pose-graph relaxation; online and smoothed)
   against the authors' every-Δp overwrite — in every table.
5. Speed: one correction on one core at the model's input size; the training time from the cards.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..dpc import RIGS, TEST_DRIVES, card_vo_fusion, describe_vo_fusion, in_world, render_drives
from ..paths import data_directory
from .common import TRAJECTORY_METRICS, ExperimentRun, fusion_figures, trajectory_tables

TITLE = "DPC-Net (ch. 6, Tables 6.1-6.2): corrections for a miscalibrated and a distorted rig, no harm, fusion vs overwrite"
Array = NDArray[np.float64]

#: the long sequences: name, KITTI test drive, first pose (:data:`pvo_tools.dpc.TEST_DRIVES`)
SEQUENCES: tuple[tuple[str, str, int], ...] = tuple((d.name, d.drive, d.start) for d in TEST_DRIVES)
#: the reference row of a biased rig: the VO on the same drive through the clean rig (calib.txt's true focal
#: length; the drive rendered without the lens) — what a correction that removed the rig's error entirely would
#: reach, so a target can be read against what the rig's error is worth
CLEAN_REFERENCE = "S-VO on the clean rig"
_VALIDATION_RUNS: dict[tuple[Path, ...], list[Any]] = {}  # per corpora: the VO over their validation splits, run once
#: per drive folder and VO: its run, once (a clean drive serves as both tables' reference)
_VO_RUNS: dict[tuple[Path, str], Any] = {}


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--calib-model", type=Path, help="pose model trained on the miscalibrated rig (Table 6.1)")
    parser.add_argument("--calib-rotation", type=Path, help="rotation-variant model of that rig (Table 6.1)")
    parser.add_argument("--calib-yaw", type=Path, help="yaw-variant model of that rig (Table 6.1)")
    parser.add_argument("--lens-model", type=Path, help="pose model trained on the distorted rig (Table 6.2; default shipped)")
    parser.add_argument("--clean-model", type=Path, help="pose model trained on the clean rig (no harm; e.g. dpc_net_clean)")
    parser.add_argument("--sequences", type=int, default=5, help=f"long sequences per rig (1-{len(SEQUENCES)}, default 5)")
    parser.add_argument("--frames", type=int, default=1000, help="frames per sequence (default 1000)")
    parser.add_argument("--sequence-dir", type=Path, help="where the sequences are rendered (default OUT/sequences)")
    parser.add_argument(
        "--world",
        type=int,
        default=0,
        help="the test drives through another world (their motion kept, the scenery drawn with another seed; 0: their "
        "own, default): a fresh test set for a rule chosen after the first was seen (give it its own --sequence-dir)",
    )
    parser.add_argument("--jobs", "-j", type=int, default=2, help="sequences rendered in parallel (default 2)")
    parser.add_argument("--data", type=Path, help="the shared data directory (default ../shared/data)")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    parser.add_argument(
        "--vo-span",
        type=int,
        help="frames over which the VO's covariances are made consistent on validation (default: each model's card's "
        "vo_span from `pvo dpc-net calibrate --vo-spans`, else its Δp)",
    )
    parser.add_argument("--out", "-o", type=Path, default=Path("runs/experiment-dpc-net"), help="output directory")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress lines")


def harm_rule(drive_calibration: dict[str, Any]) -> str:
    """Why a card calibrated on drives fuses nothing, by the harm tolerance it was chosen with (cards before stop
    63 have none: every drive had to be lowered)."""
    tolerance = float(drive_calibration.get("harm_tolerance", 0.0))
    if tolerance == 0.0:
        return "no choice lowered every drive's m-ATE"
    return f"no choice lowered the mean m-ATE and kept every drive within +{100 * tolerance:g} %"


def fusion_summary(card: Any) -> str:
    """How a card weighs its corrections against the VO, in words (for the report)."""
    calibration = card.calibration or {}
    drives = calibration.get("drive_calibration")
    if drives is not None:
        names = ", ".join(Path(d).name for d in drives.get("drives", []))
        if not calibration.get("fused_axes"):
            return f"chosen on the validation drives {names}: nothing fused ({harm_rule(drives)})"
        return (
            f"chosen on the validation drives {names}: axes {' '.join(calibration['fused_axes'])}, VO span "
            f"{calibration.get('vo_span')} frames"
            + ("; the validation split's mean residual removed from the corrections" if calibration.get("remove_mean") else "")
            + (f"; {debiasing}" if (debiasing := describe_vo_fusion(card_vo_fusion(card))) else "")
        )
    residual = calibration.get("residual") or {}
    axes = " ".join(a for a in ("x", "y", "z", "rx", "ry", "rz") if residual.get(f"corrected_{a}", 1.0))
    span = calibration.get("vo_span") or "the model's Δp"
    return f"calibrated on validation windows: axes {axes}, VO span {span}"


def render_sequences(
    data: Path, count: int, frames: int, out: Path, jobs: int, say: Any, rigs: tuple[str, ...] = RIGS, world: int = 0
) -> dict[str, list[Path]]:
    """The first ``count`` of :data:`pvo_tools.dpc.TEST_DRIVES` through world ``world`` (:func:`pvo_tools.dpc.in_world`),
    ``frames`` each, rendered clean, through the thesis's lens and with a miscalibrated calib.txt — those of ``rigs``
    (:func:`pvo_tools.dpc.render_drives`)."""
    return render_drives(in_world(TEST_DRIVES[:count], world), data, out, frames, jobs, say, rigs)


def vo_calibration(card: Any, say: Any, span: int | None = None) -> Any:
    """Per-axis scales of the VO's covariances over ``span`` frames — the motions the corrections are weighed
    against: a VO bias adds up over a span faster than independent frame errors do. Without ``span``, the scales
    the card carries (`pvo dpc-net calibrate --vo-spans`: at the span it chose on its validation split), else
    learned over the card's span (or the model's Δp) on the validation split the corrections were calibrated on
    (recorded in the card; else the model's own corpus: its rig), so both sides of the weighing are measured on
    the same windows; None (the VO's own covariances) when that corpus is not here."""
    from pvo_core.readers import read_corpus_manifest
    from pvo_core.trajectory import read_kitti_poses

    from pvo_fusion import CalibrationSequence, calibrate_vo

    from ..dpc import card_vo_calibration, model_vo, rig_sequences, vo_run

    carried = card_vo_calibration(card) if span is None else None
    if carried is not None:
        say(
            f"  VO covariance scales (x y z rx ry rz) from the model card, over {card.calibration.get('vo_span')}-frame "
            f"motions: {np.round(carried.scale, 2)}"
        )
        return carried
    calibrated_on = ((card.calibration or {}).get("residual") or {}).get("corpus")
    paths = calibrated_on if isinstance(calibrated_on, list) else [calibrated_on or card.corpus.get("path")]
    corpora = tuple(Path(p) for p in paths if p)
    missing = [c for c in corpora if not (c / "manifest.yaml").is_file()]
    if not corpora or missing:
        say(f"  the model's corpus {(missing or [None])[0]} is not here: the VO keeps its own covariances")
        return None
    if corpora not in _VALIDATION_RUNS:
        sequences = []
        for corpus in corpora:
            for sequence in rig_sequences(read_corpus_manifest(corpus), card):
                run, _ = vo_run(sequence.root, config=model_vo(card))
                relative = run.relative()
                truth = read_kitti_poses(sequence.root / "poses.txt")
                sequences.append(CalibrationSequence(sequence.name, truth, relative["transforms"], relative["covariances"]))
        _VALIDATION_RUNS[corpora] = sequences
    sequences = _VALIDATION_RUNS[corpora]
    corpus = ", ".join(str(c) for c in corpora)
    span = span or int((card.calibration or {}).get("vo_span") or card.hyperparameters["test_delta"])
    calibration = calibrate_vo(sequences, span)
    say(
        f"  VO covariance scales (x y z rx ry rz) over {span}-frame motions of {len(sequences)} validation sequences "
        f"of {corpus}: {np.round(calibration.scale, 2)}"
    )
    return calibration


def vo_of(folder: Path, config: Any = None) -> Any:
    """The run of the VO ``config`` (the defaults when None) over the drive at ``folder``
    (:func:`pvo_tools.dpc.vo_run`), made once per process."""
    from pvo_pseudosensors.dpc_net.data import vo_signature

    from ..dpc import vo_run

    key = (folder, vo_signature(config))
    if key not in _VO_RUNS:
        _VO_RUNS[key] = vo_run(folder, config=config)[0]
    return _VO_RUNS[key]


def models_vo(models: dict[str, tuple[Any, Any]]) -> Any:
    """The one VO the ``models`` (name: (model, card)) all learned — the S-VO their rows are measured against;
    ``ValueError`` when their cards name different VOs."""
    from pvo_pseudosensors.dpc_net.data import vo_signature

    from ..dpc import model_vo

    configs = {name: model_vo(card) for name, (_, card) in models.items()}
    signatures = {vo_signature(config) for config in configs.values()}
    if len(signatures) > 1:
        named = ", ".join(f"{name} VO {vo_signature(config)}" for name, config in configs.items())
        raise ValueError(f"the models learned different VOs ({named}): compare them one rig at a time")
    return next(iter(configs.values()), None)


def evaluate_rig(
    label: str,
    folders: list[Path],
    models: dict[str, tuple[Any, Any]],
    say: Any,
    methods: dict[str, tuple[str, ...]],
    vo_span: int | None = None,
    clean_folders: list[Path] | None = None,
) -> tuple[dict[str, dict[str, dict[str, float]]], dict[str, dict[str, Array]]]:
    """Per sequence: the VO's figures, the clean rig's VO on the same drive (:data:`CLEAN_REFERENCE`; with
    ``clean_folders``, matched by name) and, per model and method, the corrected trajectory's (``online`` and
    ``smoothed`` for the fusion); and the trajectories themselves (camera-to-world, per sequence and row)."""
    from pvo_core.trajectory import read_kitti_poses

    from ..dpc import correct_sequence

    calibrations = {name: vo_calibration(card, say, vo_span) for name, (_, card) in models.items()}
    clean = {folder.name: folder for folder in clean_folders or []}
    vo = models_vo(models)
    results: dict[str, dict[str, dict[str, float]]] = {}
    trajectories: dict[str, dict[str, Array]] = {}
    for folder in folders:
        truth = read_kitti_poses(folder / "poses.txt")
        say(f"{label} {folder.name}: VO ...")
        run = vo_of(folder, vo)
        estimates = {"S-VO": truth[0] @ run.poses}
        if folder.name in clean:
            if not np.allclose(read_kitti_poses(clean[folder.name] / "poses.txt"), truth):
                raise ValueError(f"{clean[folder.name]} drives another path than {folder}: no clean-rig reference for it")
            say(f"{label} {folder.name}: the clean rig's VO ...")
            estimates[CLEAN_REFERENCE] = truth[0] @ vo_of(clean[folder.name], vo).poses
        for name, (model, card) in models.items():
            for method in methods.get(name, ("fusion",)):
                corrected = correct_sequence(folder, model, card, method, calibrations[name], run=run)
                if method == "fusion":
                    estimates[f"+ {name} fusion online"] = truth[0] @ corrected.corrected_online
                    estimates[f"+ {name} fusion smoothed"] = truth[0] @ corrected.corrected
                else:
                    estimates[f"+ {name} {method}"] = truth[0] @ corrected.corrected
        rows = {row: fusion_figures(truth, poses) for row, poses in estimates.items()}
        results[folder.name], trajectories[folder.name] = rows, estimates
        say("  " + ", ".join(f"{row}: {m['m_ate_trans']:.1f} m / {m['m_ate_rot_deg']:.2f} deg" for row, m in rows.items()))
    return results, trajectories


def table(results: dict[str, dict[str, dict[str, float]]], figures: dict[str, float], prefix: str) -> list[str]:
    """Per sequence and estimate, then the mean relative change of each estimate against the S-VO."""
    labels = [row for row in next(iter(results.values())) if row != "S-VO"]
    return trajectory_tables(
        results, "S-VO", labels, figures, lambda label: f"{prefix}.{label.removeprefix('+ ').replace(' ', '_')}"
    )


def plot_rig(out: Path, name: str, folders: list[Path], trajectories: dict[str, dict[str, Array]]) -> str:
    """Figs 6.5-6.8's kind: c-ATE against distance travelled (translation and rotation), per sequence; the
    smoothed fusion rows are left out (they lie on the online ones at this scale). Returns the file name."""
    from pvo_core.trajectory import read_kitti_poses

    from pvo_core import metrics

    from ..plots import pyplot

    plt = pyplot()
    fig, axes = plt.subplots(2, len(folders), figsize=(4 * len(folders), 6), squeeze=False)
    for column, folder in enumerate(folders):
        truth = read_kitti_poses(folder / "poses.txt")
        distance = metrics.path_distances(truth)
        for label, poses in trajectories.get(folder.name, {}).items():
            if label.endswith("smoothed"):
                continue
            errors = metrics.mean_trajectory_errors(truth, poses)
            axes[0, column].plot(distance, errors.cumulative_translation, label=label)
            axes[1, column].plot(distance, np.degrees(errors.cumulative_rotation), label=label)
        axes[0, column].set_title(folder.name)
        axes[1, column].set_xlabel("distance travelled (m)")
    axes[0, 0].set_ylabel("c-ATE translation (m)")
    axes[1, 0].set_ylabel("c-ATE rotation (deg)")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / f"c-ate-{name}.png", dpi=90)
    plt.close(fig)
    return f"c-ate-{name}.png"


def speed(model_dir: Path, data: Path, figures: dict[str, float]) -> list[str]:
    """One correction on one core: the four images resized from the camera's size (KITTI 06, 1226x370) and one
    forward pass at the model's input size."""
    import time

    import cv2
    import torch
    from pvo_pseudosensors.dpc_net.config import DPCNetConfig
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net

    torch.set_num_threads(1)
    model, card = load_dpc_net(model_dir)
    config = DPCNetConfig.from_card(card)
    clip = data / "kitti" / "sequences" / "06"
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((clip / "image_0").glob("*.png"))[:8]]
    times = []
    with torch.no_grad():
        for repeat in range(30):
            tic = time.perf_counter()
            planes = [
                cv2.resize(images[(repeat + i) % len(images)], (config.width, config.height), interpolation=cv2.INTER_AREA)
                for i in range(4)
            ]
            first = torch.from_numpy(np.stack(planes[:2])[None].astype(np.float32) / 255.0)
            last = torch.from_numpy(np.stack(planes[2:])[None].astype(np.float32) / 255.0)
            model(first, last, torch.zeros(1, 6) if config.vo_input else None)
            times.append(1e3 * (time.perf_counter() - tic))
    times = np.asarray(times[5:])
    figures["speed.correction_ms"], figures["speed.correction_p95_ms"] = float(np.median(times)), float(np.percentile(times, 95))
    seconds = (card.training or {}).get("seconds_to_best")
    lines = [
        "## 5. Speed",
        "",
        f"One correction on one core ({config.height}x{config.width}, 4 images resized from 1226x370 and one forward pass): "
        f"median **{figures['speed.correction_ms']:.2f} ms**, p95 {figures['speed.correction_p95_ms']:.2f} ms (budget 30 ms; one "
        f"every {config.test_delta} frames at 10 Hz).",
    ]
    if seconds:
        figures["speed.training_seconds_to_best"] = float(seconds)
        lines.append(f"Training of {model_dir} until its best epoch: {seconds:.0f} s ({card.training.get('threads')} threads).")
    return [*lines, ""]


def run(args: argparse.Namespace) -> int:
    import torch
    from pvo_core.results import RunResult
    from pvo_core.trajectory import write_kitti_poses
    from pvo_pseudosensors.dpc_net.data import vo_signature
    from pvo_pseudosensors.dpc_net.estimator import resolve_model
    from pvo_pseudosensors.dpc_net.infer import load_dpc_net
    from pvo_pseudosensors.dpc_net.rig import rig_problems, sequence_rig

    from ..dpc import model_vo

    if not 1 <= args.sequences <= len(SEQUENCES):
        raise ValueError(f"--sequences must be in [1, {len(SEQUENCES)}], got {args.sequences}")
    if args.frames < 100:
        raise ValueError(f"--frames must be >= 100 (segment errors need 100 m and more), got {args.frames}")
    in_world((), args.world)  # a negative world fails here, before any model is loaded
    torch.set_num_threads(args.threads)
    session = ExperimentRun.start(args)
    say, out = session.say, session.out
    data = args.data or data_directory()
    # a model argument may name a shipped model (dpc_net, dpc_net_clean) as the node's parameter does
    for name in ("lens_model", "calib_model", "calib_rotation", "calib_yaw", "clean_model"):
        if getattr(args, name):
            setattr(args, name, resolve_model(str(getattr(args, name))))
    lens_dir = args.lens_model or resolve_model("")
    loaded = {"lens": load_dpc_net(lens_dir)}
    for key, path in (("calib", args.calib_model), ("calib rotation", args.calib_rotation), ("calib yaw", args.calib_yaw)):
        if path:
            loaded[key] = load_dpc_net(path)
    if args.clean_model:
        loaded["clean"] = load_dpc_net(args.clean_model)
    # only the rigs some model is tested on are rendered (the calib rig is the clean renders with another calib.txt)
    # and the clean one, whose VO is the biased rigs' reference
    tested = tuple(rig for rig in RIGS if rig == "clean" or any(name.split()[0] == rig for name in loaded))
    folders = render_sequences(
        data, args.sequences, args.frames, args.sequence_dir or out / "sequences", args.jobs, say, tested, args.world
    )
    report = ["# pvo experiment dpc-net", "", f"Command: `{session.command}`", ""]
    report += [
        f"{args.sequences} sequences of {args.frames} frames (620x188, KITTI geometry) driven along KITTI's test drives "
        f"({', '.join(f'{d} from {s}' for _, d, s in SEQUENCES[: args.sequences])}"
        + (f"; through world {args.world}, not the drives' own" if args.world else "")
        + "); the VO is this project's stereo VO "
        "with its defaults. Each model's corrections are weighed against the VO as its card's calibration says: "
        "chosen on long validation drives of its rig rendered like these (along KITTI 03, 04 and 10, `pvo dpc-net drives`; "
        "`pvo dpc-net calibrate --drives`: the VO span, the fused axes and whether the VO's translation bias is learned "
        "from the corrections, those that lowered the mean m-ATE most and raised "
        "no drive's by the card's harm tolerance, else nothing fused) when it has that, else the VO's covariances "
        "scaled on the validation split its corrections were calibrated on over "
        + (f"{args.vo_span} frames" if args.vo_span else "the span its card chose on that split (else Δp)")
        + " and the axes whose error over 100 windows the correction lowers there. The corrections' covariance is "
        "their residual covariance on that split (`pvo dpc-net calibrate`; the training targets' of eq. 6.6 without it). "
        "*fusion online*: the newest state as the fusion "
        "node publishes it; *fusion smoothed*: after the fixed lag; *overwrite*: every Δp-th pose overwritten "
        "(the authors' shipped code). m-ATE and segment errors as §6.5 (eqs. 6.31-6.32; segments of 100-800 m). "
        f"*{CLEAN_REFERENCE}* (Tables 6.1 and 6.2): the VO on the same drive with the rig's error removed "
        "(calib.txt's true focal length; the drive rendered without the lens) — not a correction but what one that "
        "removed the rig's error entirely would reach: the VO's own drift stays.",
        "",
    ]
    figures: dict[str, float] = {}
    tables: dict[str, Any] = {}
    rigs = (
        (
            "table_6_1",
            "calib",
            "## 1. Table 6.1: a miscalibrated rig (calib.txt's focal length x1.03)",
            ("calib", "calib rotation", "calib yaw"),
        ),
        (
            "table_6_2",
            "lens",
            "## 2. Table 6.2: radially distorted images (k = -0.3, 0.2, 0.01) processed as undistorted",
            ("lens",),
        ),
        ("no_harm", "clean", "## 3. No harm: the clean rig, where the VO is already good", ("clean",)),
    )
    for key, rig, heading, names in rigs:
        models = {name: loaded[name] for name in names if name in loaded}
        if not models:
            report += [heading, "", "Not run: no model for this rig was given.", ""]
            continue
        report += [heading, "", *(f"- {name}: {fusion_summary(card)}" for name, (_, card) in models.items()), ""]
        methods = {name: ("fusion", "overwrite") for name in models if loaded[name][1].hyperparameters["variant"] == "pose"}
        clean_folders = folders["clean"] if rig != "clean" else None
        results, trajectories = evaluate_rig(key, folders[rig], models, say, methods, args.vo_span, clean_folders)
        tables[key] = results
        for sequence, estimates in trajectories.items():
            for row, poses in estimates.items():
                file = out / "trajectories" / key / sequence / (row.removeprefix("+ ").replace(" ", "_") + ".txt")
                file.parent.mkdir(parents=True, exist_ok=True)
                write_kitti_poses(file, poses)
        figure = plot_rig(out, key, folders[rig], trajectories)
        report += [*table(results, figures, key), f"![c-ATE]({figure})", ""]
    if "clean" in loaded and "no_harm" in tables:
        changes = [figures[f"no_harm.clean_fusion_online.{k}_change"] for k in TRAJECTORY_METRICS]
        figures["no_harm.worst_change"] = max(changes)
        verdict = "holds" if max(changes) <= 0.05 else "does not hold"
        report += [
            f"No harm (every figure within +5 % of the S-VO's, fusion online): **{verdict}** "
            f"(worst {100 * max(changes):+.1f} %).",
            "",
        ]
    # the rig check: each model against each rendered rig's first sequence
    report += ["### The model card's rig check", "", "| model | sequence | verdict |", "|---|---|---|"]
    for name, (_, card) in loaded.items():
        for rig in (rig for rig in ("clean", "calib", "lens") if folders.get(rig)):
            refusals, warnings = rig_problems(card.input.get("rig"), sequence_rig(folders[rig][0]), vo_signature(model_vo(card)))
            verdict = (
                "refused: " + "; ".join(refusals)
                if refusals
                else ("used" + (f" (flagged: {'; '.join(warnings)})" if warnings else ""))
            )
            report.append(f"| {name} | {rig}/{folders[rig][0].name} | {verdict} |")
            figures[f"rig_check.{name.replace(' ', '_')}.{rig}.refused"] = float(bool(refusals))
    report.append("")
    report += speed(lens_dir, data, figures)
    (out / "report.md").write_text("\n".join(report) + "\n")
    inputs = {
        name: str(path) for name, path in (("lens", lens_dir), ("calib", args.calib_model), ("clean", args.clean_model)) if path
    }
    RunResult("experiment", "dpc-net", figures=figures, tables=tables, inputs=inputs).write(out)
    say(f"{out / 'report.md'} written in {session.seconds:.0f} s")
    print((out / "report.md").read_text())
    return 0
