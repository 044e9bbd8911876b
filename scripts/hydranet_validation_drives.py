"""HydraNet models fused with the stereo VO on the long *validation* drives, for choosing a model and the fusion's
rotation gate without touching the test split.

The drives are DPC-Net's validation drives (KITTI 10 frames 0-999 and 201-1200, KITTI 04's 271 frames; urban,
renderer revision 7), each clean, through the thesis's lens and with a focal length 3 % off in calib.txt:

    pvo dpc-net drives runs/dpc/vlong --split validation
    python scripts/hydranet_validation_drives.py --models src/pvo_pseudosensors/models/hydranet runs/hydranet7/urban2-20 \
        --gates 0.9999,0.99,0.95,0.9,0.8,0.65,0.5,0.3 --huber 0,1.345

`--vo-gains` adds the fusion's motion-proportional VO noise (``inputs.vo.gain_sigma``), `--rotation-biases` its
rotation offset state (``inputs.rotation.bias_sigma``, ``bias_walk_sigma``); `--part K/N` runs every N-th
drive from the K-th (processes side by side) and `--json` keeps the per-drive changes, which `--merge` averages.

The VO's covariance scales are learned on the corpus's urban validation sequences (as `pvo experiment hydranet`
does). Per drive: HydraNet's mean angular error and ANEES, and the change of m-ATE (translation / rotation) of
the online fused estimate against the VO alone; then the mean over drives per model and gate.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from pvo_core.lie import so3_exp
from pvo_core.readers import KittiSequence, read_corpus_manifest
from pvo_core.trajectory import read_kitti_poses
from pvo_frontend.offline import run_sequence
from pvo_frontend.vo import VOConfig
from pvo_frontend.vo import flatten as flatten_vo
from pvo_frontend.vo import from_flat as from_flat_vo
from pvo_pseudosensors.hydranet.evaluation import evaluate_rotations, rotation_errors, true_relative_rotations
from pvo_pseudosensors.hydranet.infer import chained, load_hydranet, predict_sequence
from pvo_pseudosensors.learning.checkpoint import ModelFileError
from pvo_tools.experiments.common import TRAJECTORY_METRICS, fusion_figures
from pvo_tools.experiments.hydranet import FIRST_STAMP_NS, rotation_measurements, vo_rotation_errors
from scipy.spatial.transform import Rotation

from pvo_fusion import CalibrationSequence, FusionGraph, calibrate_vo, ordered_events, run_offline, vo_measurements
from pvo_fusion.config import from_flat

# gate, huber, span, gain, scale, offset, VO bias windows, VO turn-scale gain
Setting = tuple[float, float, int, tuple[float, ...], float, tuple[float, ...], float, float]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", type=Path, help="HydraNet model directories (required unless --merge)")
    parser.add_argument("--gates", default="0.9999", help="inputs.rotation.gate_probability values, comma-separated")
    parser.add_argument("--huber", default="0", help="inputs.rotation.huber_k values, comma-separated (each with each gate)")
    parser.add_argument("--drives", type=Path, default=Path("runs/dpc/vlong"), help="OUT of `pvo dpc-net drives`")
    parser.add_argument("--corpus", type=Path, default=Path("data/corpus-hydra7"), help="for the VO's covariance scales")
    parser.add_argument(
        "--vo-spans",
        default="",
        help="learn the VO's covariance scales on the other drives (leave one drive out, every rig) over these spans, "
        "comma-separated, instead of on the corpus's short validation sequences (frame to frame)",
    )
    parser.add_argument(
        "--vo-gains",
        default="0",
        help="inputs.vo.gain_sigma values, comma-separated: R (rotation only) or T:R (each with each gate)",
    )
    parser.add_argument(
        "--covariance-scales",
        default="1",
        help="HydraNet's covariances times each of these before the fusion, comma-separated (each with each gate)",
    )
    parser.add_argument(
        "--rotation-biases",
        default="0",
        help="the fusion's rotation offset state (inputs.rotation.bias_sigma and bias_walk_sigma, the same on each "
        "axis), comma-separated S:W in degrees and degrees/sqrt(s); 0: no state (each with each gate)",
    )
    parser.add_argument(
        "--vo-bias-windows",
        default="0",
        help="the VO's rotation bias learned from HydraNet's rotations over about this many readings and removed from "
        "its motions (inputs.rotation.vo_bias_windows), comma-separated; 0: none (each with each gate)",
    )
    parser.add_argument(
        "--vo-rotation-scales",
        default="0",
        help="the scale of the VO's turns learned from HydraNet's rotations (over ~1000 readings) and applied with this "
        "gain (inputs.rotation.vo_rotation_scale_gain), comma-separated; 0: none (each with each gate)",
    )
    parser.add_argument(
        "--readings",
        default="as-read",
        help="which readings are fused, comma-separated: as-read (the model's), debiased (an oracle: each drive's own "
        "mean error per pair, from the truth, taken off its readings - the slow part removed, the rest kept), true (an "
        "oracle: the true rotations at the model's covariances), sampled (an oracle: an honest, unbiased model - the true "
        "rotations each perturbed by an error drawn from its reading's own covariance, independently pair by pair, seeded "
        "by the drive's name), turn-scaled (each reading's rotation vector divided by "
        "1 + --turn-gain per axis); each is reported as MODEL@READINGS",
    )
    parser.add_argument(
        "--turn-gain",
        default="",
        help="x,y,z: how much too long the model reads each axis's rotation (the least-squares slope of its error, "
        "estimate minus truth, on the true rotation vector; measured on validation data), for --readings turn-scaled",
    )
    parser.add_argument(
        "--vo-param",
        "-p",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a VO setting (VOConfig's dotted name) for every drive's VO run instead of its default, e.g. "
        "-p ransac.inlier_threshold=4 (the VO's covariance scales are then learned with it too)",
    )
    parser.add_argument(
        "--vo-as-read",
        action="store_true",
        help="fuse the VO's covariances as it reports them instead of scaled by the corpus's calibration (span 0)",
    )
    parser.add_argument(
        "--fusion-param",
        "-f",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a fusion setting (FusionConfig's dotted name, a YAML value) for every fused graph, e.g. "
        "-f inputs.vo.lost_sigma_scale=3",
    )
    parser.add_argument("--part", default="1/1", help="K/N: every N-th drive from the K-th (default 1/1: all)")
    parser.add_argument("--json", type=Path, help="write the per-drive changes here (for --merge)")
    parser.add_argument("--merge", nargs="+", type=Path, help="only average the per-drive changes of these --json files")
    parser.add_argument("--cache", type=Path, default=Path("runs/hydranet-validation-drives/cache"), help="flow cache")
    parser.add_argument(
        "--vo-cache",
        type=Path,
        default=Path("runs/hydranet-validation-drives/vo"),
        help="the VO's run of each drive, kept between runs (keyed by the drive's calib.txt and sim.yaml and the VO's code)",
    )
    args = parser.parse_args()
    if args.merge:
        merged: dict[str, list[list[float]]] = {}
        for path in args.merge:
            if not path.is_file():
                parser.error(f"--merge {path}: no such file (written by a run with --json)")
            for key, rows in json.loads(path.read_text()).items():
                merged.setdefault(key, []).extend(rows)
        print_means(merged)
        return
    torch.set_num_threads(1)
    if not args.models:
        parser.error("--models is required (unless --merge)")
    vo_settings = named_values(parser, "-p", args.vo_param)
    fusion_params = named_values(parser, "-f", args.fusion_param)
    try:
        vo_config = from_flat_vo(vo_settings)
        from_flat({"prior.source": "given", **fusion_params})
    except ValueError as error:
        parser.error(str(error))

    corpus_sequences = []
    for item in [s for s in read_corpus_manifest(args.corpus).split("validation") if s.preset == "urban"]:
        if vo_settings:
            run = run_sequence(KittiSequence(item.root, poses_file=item.root / "poses.txt"), vo_config)
        else:
            _, run = vo_rotation_errors(item.root)
        relative = run.relative()
        truth = read_kitti_poses(item.root / "poses.txt")
        corpus_sequences.append(CalibrationSequence(item.name, truth, relative["transforms"], relative["covariances"]))
    corpus_calibration = calibrate_vo(corpus_sequences, 1)
    print(f"VO covariance scales (x y z rx ry rz) on the corpus: {np.round(corpus_calibration.scale, 2)}", flush=True)
    if args.vo_as_read:
        corpus_calibration = None
        print("  not applied (--vo-as-read): the VO's covariances as it reports them", flush=True)
    spans = [int(v) for v in args.vo_spans.split(",")] if args.vo_spans else [0]  # 0: the corpus's frame-to-frame scales

    gains = [tuple(float(v) for v in (g if ":" in g else f"0:{g}").split(":")) for g in args.vo_gains.split(",")]
    try:
        biases = [tuple(float(v) for v in (b if ":" in b else "0:0").split(":")) for b in args.rotation_biases.split(",")]
        assert all(len(b) == 2 and min(b) >= 0.0 and (min(b) > 0.0 or max(b) == 0.0) for b in biases)
    except (ValueError, AssertionError):
        parser.error(f"--rotation-biases {args.rotation_biases!r}: give S:W (degrees, both > 0) or 0, comma-separated")
    settings = [
        (float(g), float(k), span, gain, scale, bias, vo_bias, turn)
        for g in args.gates.split(",")
        for k in args.huber.split(",")
        for span in spans
        for gain in gains
        for scale in (float(v) for v in args.covariance_scales.split(","))
        for bias in biases
        for vo_bias in (float(v) for v in args.vo_bias_windows.split(","))
        for turn in (float(v) for v in args.vo_rotation_scales.split(","))
    ]
    try:
        models = [(path, *load_hydranet(path)) for path in args.models]
    except ModelFileError as error:
        raise SystemExit(str(error)) from None
    readings = [r.strip() for r in args.readings.split(",") if r.strip()]
    turn_gain = None
    if args.turn_gain:
        try:
            turn_gain = np.array([float(v) for v in args.turn_gain.split(",")])
            assert turn_gain.shape == (3,) and np.all(turn_gain > -1.0)
        except (ValueError, AssertionError):
            parser.error(f"--turn-gain {args.turn_gain!r}: give three gains x,y,z (each > -1)")
    if "turn-scaled" in readings and turn_gain is None:
        parser.error("--readings turn-scaled needs --turn-gain")
    if not readings or any(r not in READINGS for r in readings):
        parser.error(f"--readings {args.readings!r}: choose among {', '.join(READINGS)}")
    labels = [(p, r, str(p) if r == "as-read" else f"{p}@{r}") for p in args.models for r in readings]
    changes: dict[tuple[str, Setting], list[list[float]]] = {(label, s): [] for _, _, label in labels for s in settings}
    drives = sorted(p for p in args.drives.glob("*/*") if (p / "poses.txt").is_file())
    if not drives:
        raise SystemExit(f"{args.drives}: no drive (render them with `pvo dpc-net drives {args.drives} --split validation`)")
    try:
        part, parts = (int(v) for v in args.part.split("/"))
        assert 1 <= part <= parts
    except (ValueError, AssertionError):
        parser.error(f"--part {args.part!r}: give K/N with 1 <= K <= N")
    if parts > 1 and any(spans):
        raise SystemExit("--vo-spans learns from the other drives: run it on all of them (no --part)")
    drives = drives[part - 1 :: parts]
    runs = {}
    for folder in drives:
        sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
        runs[folder] = (sequence, *vo_of(folder, sequence, args.vo_cache, vo_config))
    for folder in drives:
        started = time.perf_counter()
        sequence, vo_poses, relative = runs[folder]
        truth = sequence.poses
        stamps = FIRST_STAMP_NS + (np.asarray(sequence.stamps) * 1e9).round().astype(np.int64)
        calibrations = {0: corpus_calibration}
        others = [
            CalibrationSequence(
                f"{f.parent.name}/{f.name}", runs[f][0].poses, runs[f][2]["transforms"], runs[f][2]["covariances"]
            )
            for f in drives
            if f.name != folder.name
        ]
        for span in spans:
            if span:
                calibrations[span] = calibrate_vo(others, span)
        alone = fusion_figures(truth, truth[0] @ vo_poses)
        line = f"{folder.parent.name}/{folder.name}: VO {alone['m_ate_trans']:.2f} m {alone['m_ate_rot_deg']:.2f} deg"
        for (path, model, card), (_, reading, label) in zip([m for m in models for _ in readings], labels, strict=True):
            predictions = chained(predict_sequence(model, card, folder, cache_dir=args.cache))
            true = true_relative_rotations(truth, predictions.earlier, predictions.frames)
            seed = zlib.crc32(f"{folder.parent.name}/{folder.name}".encode())
            predictions = oracle_readings(predictions, true, reading, turn_gain, np.random.default_rng(seed))
            accuracy = evaluate_rotations(predictions.quaternions, predictions.covariance, true)
            name = path.name if reading == "as-read" else f"{path.name}@{reading}"
            line += f" | {name}: {accuracy['angle_mean_deg']:.3f} deg, ANEES {accuracy['anees']:.2f}"
            for setting in settings:
                gate, huber, span, gain, scale, bias, vo_bias, turn = setting
                scaled = dataclasses.replace(
                    predictions, epistemic=predictions.epistemic * scale, aleatoric=predictions.aleatoric * scale
                )
                rotations = [("rotation", m) for m in rotation_measurements(scaled, stamps)]
                vo = vo_measurements(stamps, relative["transforms"], relative["covariances"], calibrations[span])
                flat = {
                    "prior.source": "given",
                    "inputs.rotation.gate_probability": gate,
                    "inputs.rotation.huber_k": huber,
                    "inputs.vo.gain_sigma": list(gain),
                    "inputs.rotation.bias_sigma": [np.radians(bias[0])] * 3,
                    "inputs.rotation.bias_walk_sigma": [np.radians(bias[1])] * 3,
                    "inputs.rotation.vo_bias_windows": vo_bias,
                    "inputs.rotation.vo_rotation_scale_windows": 1000.0 if turn else 0.0,
                    "inputs.rotation.vo_rotation_scale_gain": turn or 1.0,
                    **fusion_params,
                }
                graph = FusionGraph(from_flat(flat))
                graph.set_initial_pose(truth[0])
                fused = fusion_figures(truth, run_offline(graph, stamps, ordered_events(vo, rotations)).online_poses)
                change = [fused[k] / max(alone[k], 1e-12) - 1.0 for k in TRAJECTORY_METRICS]
                changes[(label, setting)].append(change)
                line += f"; gate {gate:g} huber {huber:g} span {span} gain {gain[0]:g}:{gain[1]:g} x{scale:g}"
                line += f" offset {bias[0]:g}:{bias[1]:g}" if max(bias) > 0 else ""
                line += f" VO bias over {vo_bias:g}" if vo_bias else ""
                line += f" turns x{turn:g}: " if turn else ": "
                line += f"{100 * change[0]:+.1f} / {100 * change[1]:+.1f} %"
        print(f"{line} ({time.perf_counter() - started:.0f} s)", flush=True)
    named = {setting_name(path, setting): rows for (path, setting), rows in changes.items()}
    if args.vo_as_read:
        named = {name.replace("VO scales from the corpus", "VO covariances as read"): rows for name, rows in named.items()}
    if args.json:
        args.json.write_text(json.dumps(named, indent=1))
    print_means(named)


def named_values(parser: argparse.ArgumentParser, flag: str, items: list[str]) -> dict[str, Any]:
    """``NAME=VALUE`` options as a dict of YAML values; a malformed one stops the command naming it."""
    values = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep:
            parser.error(f"{flag} {item!r}: expected NAME=VALUE")
        values[name] = yaml.safe_load(text)
    return values


READINGS = ("as-read", "debiased", "true", "sampled", "turn-scaled")


def oracle_readings(
    predictions: Any,
    true: np.ndarray,
    reading: str,
    turn_gain: np.ndarray | None = None,
    rng: np.random.Generator | None = None,
) -> Any:
    """The model's readings (``as-read``), the same with the drive's mean error per pair taken off each (``debiased``:
    C = Exp(mean Log(C_true C_est^T)) C_est), the true rotations (``true``), the true rotations each with an error
    drawn from its reading's covariance (``sampled``: C = Exp(L z) C_true, L L^T = Sigma, z ~ N(0, I) from ``rng``; the
    covariance is in the left tangent space), or each reading's rotation vector divided per axis by 1 + ``turn_gain``
    (``turn-scaled``: a model that reads every turn g short has g < 0), their covariances kept."""
    if reading == "as-read":
        return predictions
    estimates = Rotation.from_quat(np.asarray(predictions.quaternions)[:, [1, 2, 3, 0]]).as_matrix()
    if reading == "turn-scaled":
        if turn_gain is None:
            raise ValueError("turn-scaled readings need the model's turn gain (--turn-gain)")
        rotations = Rotation.from_rotvec(Rotation.from_matrix(estimates).as_rotvec() / (1.0 + turn_gain)).as_matrix()
    elif reading == "true":
        rotations = true
    elif reading == "sampled":
        rng = rng or np.random.default_rng(0)
        factors = np.linalg.cholesky(np.asarray(predictions.covariance))
        errors = np.einsum("nij,nj->ni", factors, rng.standard_normal((len(true), 3)))
        rotations = np.stack([so3_exp(e) for e in errors]) @ true
    else:
        mean = rotation_errors(estimates, true).mean(axis=0)
        rotations = so3_exp(mean) @ estimates
    xyzw = Rotation.from_matrix(rotations).as_quat()
    return dataclasses.replace(predictions, quaternions=xyzw[:, [3, 0, 1, 2]])


def setting_name(path: str, setting: Setting) -> str:
    gate, huber, span, gain, scale, bias, vo_bias, turn = setting
    vo = f"VO scales over {span} frames on the other drives" if span else "VO scales from the corpus"
    covariance = "" if scale == 1.0 else f" HydraNet covariance x{scale:g}"
    offset = f" offset state {bias[0]:g} deg, walk {bias[1]:g} deg/sqrt(s)" if max(bias) > 0 else ""
    learned = f" VO rotation bias learned over {vo_bias:g}" if vo_bias else ""
    learned += f" VO turns rescaled x{turn:g} (scale learned over 1000)" if turn else ""
    return f"{path} gate {gate:g} huber {huber:g} VO gain {gain[0]:g}:{gain[1]:g}{covariance}{offset}{learned}, {vo}"


def print_means(changes: dict[str, list[list[float]]]) -> None:
    for name, rows in changes.items():
        mean = 100 * np.mean(rows, axis=0)
        figures = f"{mean[0]:+.1f} / {mean[1]:+.1f} %, segments {mean[2]:+.1f} / {mean[3]:+.1f} %"
        print(f"  {name}: over {len(rows)} drives m-ATE {figures}; m-ATE mean {(mean[0] + mean[1]) / 2:+.2f} %")


def vo_of(
    folder: Path, sequence: KittiSequence, cache: Path, config: VOConfig | None = None
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The VO's poses (N, 4, 4) and relative motions (transforms, covariances) on ``folder``: from ``cache`` when
    this drive (calib.txt, sim.yaml, frame count), the VO's settings and its code are unchanged, else run and kept
    there."""
    import pvo_frontend

    config = config or VOConfig()
    key = hashlib.sha256(str(len(sequence.stamps)).encode())
    if config != VOConfig():  # the default's key stays what it was, so existing caches keep answering
        key.update(repr(sorted(flatten_vo(config).items())).encode())
    for name in ("calib.txt", "sim.yaml"):
        if (folder / name).is_file():
            key.update((folder / name).read_bytes())
    for source in sorted(Path(pvo_frontend.__file__).parent.rglob("*.py")):
        key.update(source.read_bytes())
    path = cache / f"{folder.parent.name}-{folder.name}-{key.hexdigest()[:16]}.npz"
    if path.is_file():
        with np.load(path) as stored:
            return stored["poses"], {"transforms": stored["transforms"], "covariances": stored["covariances"]}
    run = run_sequence(sequence, config)
    relative = run.relative()
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, poses=run.poses, transforms=relative["transforms"], covariances=relative["covariances"])
    return run.poses, {"transforms": relative["transforms"], "covariances": relative["covariances"]}


if __name__ == "__main__":
    main()
