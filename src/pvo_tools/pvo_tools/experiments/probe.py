"""PROBE (thesis ch. 4, Table 4.1): translational and rotational ARMSE of stereo VO with a fixed covariance, the
static Student-t M-estimator (nu = 5), PROBE-GK trained with ground truth and by EM, and the isotropic k-NN
PROBE of app. A.

1. Synthetic (Table 4.1, first row): the thesis's point world - 2000 landmarks, a circle at 3 m/s, 30 s to
   train and 60 s to test, pixel noise whose variance grows down the image plus 5 % uniform outliers
   (:mod:`pvo_frontend.probe.synthetic`); the one predictor is the feature's image row.
2. Real KITTI tracks: ``kitti/raw-derived/*.mat`` (500 frames of stereo KLT tracks, IMU and ground truth per
   drive); models trained on one drive, tested on another (07 -> 06 by default), with the predictors every
   frame has (flow variance of the tracks, disparity and row, |specific force|, |angular rate|), without the
   IMU, with the image predictors on the frames whose left images ``../shared/data`` holds (07: 0-159,
   06: 0-50), and with each test frame's own (the image models on 06's frames 1-50, the tracks + IMU models on
   the rest). Sequence 01's frames are never trained on.
3. Rendered sequences (``--corpus``): PROBE-GK trained with ground truth on the corpus's training split (this
   project's VO's own tracks, image predictors), against the default robust VO on every test sequence,
   grouped by condition (moving vehicles, motion blur, texture-poor walls, ... and clean).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from .common import ExperimentRun

TITLE = "PROBE (ch. 4, Table 4.1): fixed / M-estimator / PROBE-GK-GT / PROBE-GK-EM / k-NN, synthetic world and KITTI tracks"
#: PROBE-GK's prior for KITTI's KLT tracks, chosen by three-fold cross-validation on 07's frames 1-499 (never 06):
#: PROBE-GK-GT against the static M-estimator, mean of the folds, tracks + IMU / tracks only: the nominal prior
#: -16.4 / -3.9 %, the fitted static Student-t with 1 dof -2.2 / +2.7 %, with 3 dof -0.7 / +3.8 % (the single
#: split 1-349 / 350-499 had favoured 1 dof, -15.2 % against -11.4 %; its folds disagree by 40 points, so one
#: split decides nothing; scripts/probe_kitti_prior_cv.py). The rendered corpus's VO tracks were validated the other way
#: (GKConfig's default).
KITTI_PRIOR = "nominal"

#: odometry sequence -> raw-derived file and the frames with left images in ../shared/data
DRIVES = {
    "06": ("2011_09_30_drive_0020_sync_KLT.mat", 51),
    "07": ("2011_09_30_drive_0027_sync_KLT.mat", 160),
    "01": ("2011_10_03_drive_0042_sync_KLT.mat", 0),
}


def register(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--train-seconds", type=float, default=30.0, help="synthetic training traverse (default 30 s)")
    parser.add_argument("--test-seconds", type=float, default=60.0, help="synthetic test traverse (default 60 s)")
    parser.add_argument("--em-iterations", type=int, default=5, help="EM iterations (default 5)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="world seeds (default 0 1 2)")
    parser.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    parser.add_argument("--train-drive", default="07", choices=sorted(DRIVES), help="KITTI tracks to train on (default 07)")
    parser.add_argument("--test-drive", default="06", choices=sorted(DRIVES), help="KITTI tracks to test on (default 06)")
    parser.add_argument("--skip-kitti", action="store_true", help="skip experiment 2 (KITTI tracks)")
    parser.add_argument(
        "--kitti-prior",
        choices=("nominal", "fitted"),
        default=KITTI_PRIOR,
        help=f"experiment 2: PROBE-GK's prior on the KITTI tracks (default {KITTI_PRIOR}, chosen by cross-validation on 07)",
    )
    parser.add_argument("--kitti-prior-dof", type=float, default=3.0, help="experiment 2: the fitted prior's dof (default 3)")
    parser.add_argument("--corpus", type=Path, help="experiment 3: a `pvo sim corpus` directory (skipped without)")
    parser.add_argument(
        "--train-sequences", type=int, default=60, help="experiment 3: training-split sequences used (default 60)"
    )
    parser.add_argument("--corpus-imu", action="store_true", help="experiment 3: IMU predictors too (the corpus's imu.csv)")
    parser.add_argument(
        "--vo-seeds",
        type=int,
        nargs="+",
        default=[0, 1, 2, 3, 4],
        help="experiment 3: RANSAC seeds each test sequence is run with, ARMSE averaged over them (default 0 1 2 3 4)",
    )
    parser.add_argument("--out", "-o", type=Path, default=Path("runs/probe-experiment"), help="output directory")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress lines")


def run(args: argparse.Namespace) -> int:
    from pvo_core.results import RunResult
    from pvo_frontend.probe.evaluation import ESTIMATORS, KNN_ROW, synthetic_experiment

    from ..plots import pyplot

    session = ExperimentRun.start(args)
    say, command, out = session.say, session.command, session.out
    rows = (*ESTIMATORS, KNN_ROW)
    tables: dict[str, Any] = {"synthetic": {}}
    figures: dict[str, float] = {}
    per_seed = []
    for seed in args.seeds:
        say(f"synthetic world, seed {seed} ...")
        table = synthetic_experiment(
            train_seconds=args.train_seconds, test_seconds=args.test_seconds, seed=seed, em_iterations=args.em_iterations, say=say
        )
        per_seed.append(table)
        tables["synthetic"][str(seed)] = {"armse": table.armse, "em_log_likelihood": table.em_log_likelihood}
    mean = {row: {k: sum(t.armse[row][k] for t in per_seed) / len(per_seed) for k in ("trans", "rot")} for row in rows}
    for row in rows:
        figures[f"synthetic.{row}.trans_m"] = mean[row]["trans"]
        figures[f"synthetic.{row}.rot_rad"] = mean[row]["rot"]
    fixed = mean["Fixed covariance"]["trans"]
    figures["synthetic.gk_gt_change_vs_fixed"] = mean["PROBE-GK-GT"]["trans"] / fixed - 1.0
    figures["synthetic.gk_em_vs_gk_gt"] = mean["PROBE-GK-EM"]["trans"] / mean["PROBE-GK-GT"]["trans"] - 1.0

    em_lines = "; ".join(
        f"seed {s}: " + ", ".join(f"{v:.0f}" for v in t.em_log_likelihood) for s, t in zip(args.seeds, per_seed, strict=True)
    )
    report = ["# pvo experiment probe", "", f"Command: `{command}`", ""]
    report += [
        "## 1. Synthetic point world (Table 4.1, first row)",
        "",
        f"{args.train_seconds:g} s to train, {args.test_seconds:g} s to test, 2000 landmarks, circle at 3 m/s; pixel noise "
        "sigma 0.5 px at the top row to 4 px at the bottom (variance linear in the row), 5 % uniform outliers within "
        "20 px. Predictor: the feature's image row. ARMSE over the test traverse, mean over the world seeds "
        f"{', '.join(str(s) for s in args.seeds)} (thesis: 3.87 / 2.49 / 1.59 / 1.66 m).",
        "",
        "| estimator | trans ARMSE (m) | rot ARMSE (rad) | " + " | ".join(f"seed {s} trans" for s in args.seeds) + " |",
        "|---|---|---|" + "---|" * len(args.seeds),
    ]
    for row in rows:
        seeds = " | ".join(f"{t.armse[row]['trans']:.3f}" for t in per_seed)
        report.append(f"| {row} | {mean[row]['trans']:.3f} | {mean[row]['rot']:.4f} | {seeds} |")
    report += [
        "",
        f"PROBE-GK-GT against the fixed covariance: {100 * figures['synthetic.gk_gt_change_vs_fixed']:+.1f} % "
        f"(target <= -50 %); PROBE-GK-EM against PROBE-GK-GT: {100 * figures['synthetic.gk_em_vs_gk_gt']:+.1f} % "
        "(target within 15 %).",
        "",
        "EM log-likelihood per iteration (leave-one-out Student-t density of the stored errors): " + em_lines,
        "",
    ]
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    first = per_seed[0]
    assert first.truth is not None
    from pvo_core import metrics

    for row in rows:
        curve = metrics.crmse(metrics.map_frame_errors(first.truth, first.trajectories[row])["trans"])
        ax.plot([k / 10.0 for k in range(len(curve))], curve, label=row)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("translational RMSE (m)")
    ax.set_title(f"synthetic test traverse, seed {args.seeds[0]} (Fig. 4.10)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "synthetic_rmse.png", dpi=110)
    report += ["![RMSE over the synthetic test traverse](synthetic_rmse.png)", ""]
    if not args.skip_kitti:
        if args.train_drive == "01":
            raise ValueError("sequence 01's frames are kept for testing: train on 06 or 07")
        report += kitti_section(args, figures, tables, say)
    if args.corpus is not None:
        report += corpus_section(args, figures, tables, say)
    report.append(f"Wall time {session.seconds:.0f} s.")
    (out / "report.md").write_text("\n".join(report) + "\n")
    RunResult("experiment", "probe", figures=figures, tables=tables, inputs={"seeds": " ".join(map(str, args.seeds))}).write(out)
    print("\n".join(report))
    print(f"wrote {out}/report.md, synthetic_rmse.png and metrics.json")
    return 0


def kitti_section(args: argparse.Namespace, figures: dict[str, float], tables: dict[str, Any], say: Any) -> list[str]:
    """Experiment 2: Table 4.1 on real KITTI tracks, without and with the image predictors, and with the predictors
    each test frame has (the image ones only where ../shared/data holds its image)."""
    from pvo_core.imageio import read_image
    from pvo_core.readers import read_klt_tracks
    from pvo_frontend.probe.evaluation import (
        ESTIMATORS,
        KNN_ROW,
        per_frame_table,
        track_pairs,
        tracks_experiment,
        tracks_solvers,
    )
    from pvo_frontend.probe.gk import GKConfig
    from pvo_frontend.probe.predictors import PredictorConfig

    from ..paths import data_directory

    data = data_directory(args.data)
    train_file, train_images = DRIVES[args.train_drive]
    test_file, test_images = DRIVES[args.test_drive]
    train = read_klt_tracks(data / "kitti" / "raw-derived" / train_file)
    test = read_klt_tracks(data / "kitti" / "raw-derived" / test_file)

    def images(sequence: str) -> Any:
        def image_of(k: int) -> Any:
            return read_image(data / "kitti" / "sequences" / sequence / "image_0" / f"{k:06d}.png")

        return image_of

    variants = [("tracks + IMU", PredictorConfig(image=False, imu=True), range(1, len(train)), range(1, len(test)))]
    variants.append(("tracks (no IMU)", PredictorConfig(image=False), range(1, len(train)), range(1, len(test))))
    if train_images > 1 and test_images > 1:
        variants.append(("images + tracks + IMU", PredictorConfig(imu=True), range(1, train_images), range(1, test_images)))
    lines = [
        f"## 2. Real KITTI tracks: trained on {args.train_drive}, tested on {args.test_drive} (Table 4.1's KITTI rows)",
        "",
        "Raw-derived stereo KLT tracks (their own tracker's, with its outliers) and the drives' ground truth. Each "
        "estimator solves every frame-to-frame motion from the tracks alone (no RANSAC); ARMSE of the composed "
        "trajectory. PROBE-GK's prior: "
        + (
            "the nominal one, 3 virtual samples of (1, 1, 2) px (chosen by three-fold cross-validation on 07)"
            if args.kitti_prior == "nominal"
            else f"the training errors' static Student-t with {args.kitti_prior_dof:g} dof"
        )
        + ". Target: PROBE-GK-GT at least 30 % below the static M-estimator (thesis on KITTI: -43 % to -79 %).",
        "",
        "| predictors | frames (train / test) | "
        + " | ".join(f"{r} trans (m)" for r in (*ESTIMATORS, KNN_ROW))
        + " | GK-GT vs M-est. |",
        "|---|---|" + "---|" * (len(ESTIMATORS) + 2),
    ]
    rows = (*ESTIMATORS, KNN_ROW)
    for label, predictors, train_frames, test_frames in variants:
        say(f"KITTI tracks, {label} ...")
        table = tracks_experiment(
            train,
            test,
            predictors,
            train_frames,
            test_frames,
            images(args.train_drive),
            images(args.test_drive),
            gk=GKConfig(prior=args.kitti_prior, prior_dof=args.kitti_prior_dof),
            em_iterations=args.em_iterations,
            say=say,
        )
        change = table.change("PROBE-GK-GT", against="Static M-estimator")
        tables.setdefault("kitti", {})[label] = {"armse": table.armse, "em_log_likelihood": table.em_log_likelihood}
        for row in rows:
            figures[f"kitti.{label}.{row}.trans_m"] = table.armse[row]["trans"]
            figures[f"kitti.{label}.{row}.rot_rad"] = table.armse[row]["rot"]
        figures[f"kitti.{label}.gk_gt_vs_static"] = change
        cells = " | ".join(f"{table.armse[r]['trans']:.3f}" for r in rows)
        lines.append(f"| {label} | {len(train_frames)} / {len(test_frames)} | {cells} | {100 * change:+.1f} % |")
    if train_images > 1 and 1 < test_images < len(test):
        # the predictors each test frame has: the image ones where ../shared/data holds the images, the tracks and
        # IMU alone on the rest of the drive — each model trained on the training frames that have its predictors
        label = "each frame's predictors (images where held)"
        say(f"KITTI tracks, {label} ...")
        gk = GKConfig(prior=args.kitti_prior, prior_dof=args.kitti_prior_dof)
        segments: list[Any] = []
        em_log: list[Any] = []
        for predictors, train_frames, test_frames, with_images in (
            (PredictorConfig(imu=True), range(1, train_images), range(1, test_images), True),
            (PredictorConfig(image=False, imu=True), range(1, len(train)), range(test_images, len(test)), False),
        ):
            solvers, log_likelihood = tracks_solvers(
                train, test, predictors, train_frames, images(args.train_drive) if with_images else None, gk,
                args.em_iterations, say=say,
            )  # fmt: skip
            pairs, _, _ = track_pairs(test, predictors, test_frames, images(args.test_drive) if with_images else None)
            segments.append((pairs, solvers))
            em_log.append(log_likelihood)
        table = per_frame_table(segments, test.poses[: len(test)], say=say)
        change = table.change("PROBE-GK-GT", against="Static M-estimator")
        tables["kitti"][label] = {"armse": table.armse, "em_log_likelihood": em_log}
        for row in rows:
            figures[f"kitti.per-frame.{row}.trans_m"] = table.armse[row]["trans"]
            figures[f"kitti.per-frame.{row}.rot_rad"] = table.armse[row]["rot"]
        figures["kitti.per-frame.gk_gt_vs_static"] = change
        cells = " | ".join(f"{table.armse[r]['trans']:.3f}" for r in rows)
        lines.append(
            f"| {label} | {train_images - 1} + {len(train) - 1} / {test_images - 1} + {len(test) - test_images} | "
            f"{cells} | {100 * change:+.1f} % |"
        )
    lines.append("")
    return lines


HARD_CONDITIONS = ("moving vehicles", "motion blur", "texture-poor walls")


def corpus_section(args: argparse.Namespace, figures: dict[str, float], tables: dict[str, Any], say: Any) -> list[str]:
    """Experiment 3: PROBE-GK on the VO's own tracks in rendered sequences, against the default VO."""
    from pvo_core.readers import KittiSequence, read_corpus_manifest
    from pvo_frontend.probe.evaluation import compare_on_sequences
    from pvo_frontend.probe.predictors import PredictorConfig
    from pvo_frontend.probe.sequences import collect, train_on_sequences
    from pvo_frontend.vo import VOConfig

    from ..commands.vo import frame_imu

    manifest = read_corpus_manifest(args.corpus)
    train = manifest.split("train")[: args.train_sequences]
    test = manifest.split("test")
    if not train or not test:
        raise ValueError(f"{manifest.path}: needs sequences in its train and test splits")
    predictors, config = PredictorConfig(imu=args.corpus_imu), VOConfig()

    def open_sequence(root: Path) -> KittiSequence:
        return KittiSequence(root, poses_file=root / "poses.txt")

    def imu_of(root: Path, sequence: KittiSequence) -> Any:
        return frame_imu(root, sequence) if args.corpus_imu else None

    say(f"collecting the VO's tracks from {len(train)} training sequences ...")
    data, cameras = [], {}
    for item in train:
        sequence = open_sequence(item.root)
        collected = collect(sequence, config, predictors, name=item.root.name, imu=imu_of(item.root, sequence))
        cameras[collected.name] = sequence.camera()
        data.append(collected)
    model = train_on_sequences(data, lambda d: cameras[d.name], predictors, say=say)
    model.save(args.out / "probe-corpus-model")
    opened = [(s.root.name, open_sequence(s.root)) for s in test]
    results = compare_on_sequences([(n, q, imu_of(q.root, q)) for n, q in opened], config, model, say, args.vo_seeds)
    conditions = {r.name: s.conditions for r, s in zip(results, test, strict=True)}
    groups: dict[str, list[Any]] = {"all": results, "clean": [r for r in results if not conditions[r.name]]}
    for condition in sorted({c for s in test for c in s.conditions}):
        groups[condition] = [r for r in results if condition in conditions[r.name]]
    groups["hard (" + ", ".join(HARD_CONDITIONS) + ")"] = [r for r in results if set(conditions[r.name]) & set(HARD_CONDITIONS)]
    lines = [
        f"## 3. Rendered sequences: PROBE-GK trained on {len(train)} sequences of the corpus's training split",
        "",
        f"Corpus `{args.corpus}` (hash {manifest.sha256[:12]}); this project's VO with its defaults (RANSAC, Cauchy loss) "
        "against the same VO with the PROBE-GK model's per-feature Student-t noise (images, tracks, disparity/row). "
        f"Each sequence's ARMSE is the mean over {len(args.vo_seeds)} RANSAC seed(s) ({' '.join(map(str, args.vo_seeds))}) "
        "for both VOs. Change = mean over the group's sequences of each sequence's relative change of translational "
        "ARMSE. Targets: -25 % where tracking is hard; never worse than +5 % on clean sequences.",
        "",
        "| group | sequences | default ARMSE (m) | PROBE ARMSE (m) | mean change | worst sequence | default seed spread > 5 % |",
        "|---|---|---|---|---|---|---|",
    ]
    tables["corpus"] = {
        r.name: {
            "default": r.default,
            "probe": r.probe,
            "default_runs": r.default_runs,
            "probe_runs": r.probe_runs,
            "conditions": list(conditions[r.name]),
        }
        for r in results
    }
    for label, members in groups.items():
        if not members:
            continue
        change = sum(r.change for r in members) / len(members)
        default = sum(r.default["trans"] for r in members) / len(members)
        probe = sum(r.probe["trans"] for r in members) / len(members)
        figures[f"corpus.{label}.change"] = change
        worst = max(members, key=lambda r: r.change)
        figures[f"corpus.{label}.worst_change"] = worst.change
        noisy = sum(r.default_spread > 0.05 for r in members)
        lines.append(
            f"| {label} | {len(members)} | {default:.3f} | {probe:.3f} | {100 * change:+.1f} % | "
            f"{worst.name} {100 * worst.change:+.1f} % | {noisy} |"
        )
    lines += ["", *seed_by_seed(results, groups["clean"], args.vo_seeds, figures), ""]
    return lines


def seed_by_seed(results: list[Any], clean: list[Any], seeds: list[int], figures: dict[str, float]) -> list[str]:
    """What one RANSAC seed alone would have said about the clean sequences: the worst change per seed, and how
    far the default VO's own ARMSE moves between seeds."""
    if len(seeds) < 2 or not clean:
        return []
    lines = ["Clean sequences, one seed at a time (what a single run per sequence would report):", ""]
    for i, seed in enumerate(seeds):
        worst = max(clean, key=lambda r: r.probe_runs[i] / r.default_runs[i])
        change = worst.probe_runs[i] / worst.default_runs[i] - 1.0
        figures[f"corpus.clean.seed{seed}.worst_change"] = change
        lines.append(f"- seed {seed}: worst {worst.name} {100 * change:+.1f} %")
    spreads = sorted(r.default_spread for r in clean)
    figures["corpus.clean.default_spread_median"] = spreads[len(spreads) // 2]
    lines += [
        "",
        f"The default VO's translational ARMSE moves by a median {100 * spreads[len(spreads) // 2]:.0f} % (max "
        f"{100 * spreads[-1]:.0f} %) between seeds on these sequences.",
    ]
    return lines
