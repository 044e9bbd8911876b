"""`pvo vo` and `pvo bench vo`: the stereo VO object run on a KITTI sequence directory without ROS."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from pvo_core.readers import KittiSequence
from pvo_core.trajectory import write_kitti_poses
from pvo_frontend.vo import FrameResult, FrameStatus, StereoVO, VOConfig, from_flat

from pvo_core import metrics

from .errors import PvoError
from .progress import Progress

Array = NDArray[np.float64]
STAGES = ("tracking", "ransac", "gauss_newton", "detection", "stereo_matching", "total")


def parse_overrides(items: list[str] | None, params_file: Path | None = None) -> dict[str, Any]:
    """Dotted VO parameters from a ROS-style YAML file and ``name=value`` strings (YAML values)."""
    values: dict[str, Any] = {}
    if params_file is not None:
        if not params_file.is_file():
            raise PvoError(f"{params_file}: parameter file not found")
        try:
            data = yaml.safe_load(params_file.read_text()) or {}
        except yaml.YAMLError as exc:
            raise PvoError(f"{params_file}: not valid YAML: {exc}") from None
        node = data.get("stereo_vo", data)
        params = node.get("ros__parameters", node) if isinstance(node, dict) else None
        if not isinstance(params, dict):
            raise PvoError(f"{params_file}: expected 'stereo_vo: ros__parameters: {{...}}'")
        values.update({k: v for k, v in params.items() if "." in k})
    for item in items or []:
        name, sep, text = item.partition("=")
        if not sep:
            raise PvoError(f"parameter {item!r} must be NAME=VALUE, e.g. solver.loss=huber")
        values[name.strip()] = yaml.safe_load(text)
    return values


@dataclass
class VORun:
    results: list[FrameResult]
    poses: Array  # (N, 4, 4) T_odom,cam
    seconds: Array  # (N,) process() wall time

    def relative(self) -> dict[str, Array]:
        """Per-frame motions after the first: transforms, covariances, ok flags, stamps."""
        later = self.results[1:]
        return {
            "transforms": np.array([r.transform if r.transform is not None else np.eye(4) for r in later]),
            "covariances": np.array([r.covariance if r.covariance is not None else np.eye(6) * 9999.0 for r in later]),
            "ok": np.array([r.status is FrameStatus.TRACKING for r in later]),
            "stamps": np.array([r.stamp for r in later]),
        }


def run_sequence(sequence: KittiSequence, config: VOConfig, progress: bool = True, images: list | None = None) -> VORun:
    vo = StereoVO(sequence.camera(), config)
    bar = Progress(len(sequence), "vo") if progress else None
    results, poses, seconds = [], [], []
    for i in range(len(sequence)):
        left, right = images[i] if images is not None else sequence.load_pair(i)
        tic = time.perf_counter()
        result = vo.process(left, right, float(sequence.stamps[i]))
        seconds.append(time.perf_counter() - tic)
        if result.status is FrameStatus.REJECTED:
            raise PvoError(f"{sequence.left_paths[i]}: frame rejected: {result.message}")
        results.append(result)
        poses.append(result.pose)
        if bar:
            bar.update()
    if bar:
        bar.close()
    return VORun(results, np.array(poses), np.array(seconds))


def open_sequence(
    sequence_dir: Path,
    rate: float | None,
    times: Path | None,
    colour: bool,
    start: int,
    count: int | None,
    poses: Path | None = None,
) -> KittiSequence:
    rate_hz = rate if (rate is not None or times is not None or (sequence_dir / "times.txt").is_file()) else 10.0
    return KittiSequence(
        sequence_dir, colour=colour, times_file=times, rate_hz=rate_hz, poses_file=poses, start=start, count=count
    )


def summarise(run: VORun, gt: Array | None) -> dict[str, Any]:
    """Accuracy and timing figures of a run (accuracy only with ground truth)."""
    out: dict[str, Any] = {
        "frames": len(run.results),
        "lost": sum(r.status is FrameStatus.LOST for r in run.results),
        "median_ms": 1e3 * float(np.median(run.seconds[1:])),
        "p95_ms": 1e3 * float(np.percentile(run.seconds[1:], 95)),
        "tracked": float(np.mean([r.tracked for r in run.results[1:]])),
        "inliers": float(np.mean([r.inliers for r in run.results[1:]])),
        "stages_ms": {s: 1e3 * float(np.median([r.timings.get(s, 0.0) for r in run.results[1:]])) for s in STAGES},
    }
    if gt is not None:
        g = np.linalg.inv(gt[0]) @ gt
        dist = metrics.path_distances(g)
        err = metrics.absolute_trajectory_error(g, run.poses)
        out["path_m"] = float(dist[-1])
        out["end_drift_percent"] = 100.0 * float(err[-1]) / float(dist[-1])
        out["ate_mean_m"] = float(err.mean())
        out["ate_rmse_m"] = float(np.sqrt(np.mean(err**2)))
        rel = run.relative()
        ok = rel["ok"]
        e = metrics.relative_motion_errors(g, rel["transforms"])
        nees = metrics.nees(e[ok], rel["covariances"][ok]) / 6.0
        out["anees"] = float(nees.mean())
        out["nees_median"] = float(np.median(nees))
    return out


def cmd_vo(args: Any) -> int:
    overrides = parse_overrides(args.param, args.params_file)
    config = from_flat(overrides)
    sequence = open_sequence(args.sequence_dir, args.rate, args.times, args.colour, args.start, args.count, args.poses)
    run = run_sequence(sequence, config, progress=not args.quiet)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_kitti_poses(args.out, run.poses)
    if args.relative is not None:
        np.savez(args.relative, **run.relative())
    summary = summarise(run, sequence.poses)
    lost = summary["lost"]
    print(f"wrote {args.out}: {len(run.poses)} poses, {lost} lost frame(s), median {summary['median_ms']:.1f} ms/frame")
    if sequence.poses is not None:
        print(
            f"against {args.poses or 'poses.txt'}: end drift {summary['end_drift_percent']:.3f} % of {summary['path_m']:.1f} m, "
            f"ATE mean {summary['ate_mean_m']:.3f} m, ANEES {summary['anees']:.2f}"
        )
    return 0


BENCH_VARIANTS: dict[str, dict[str, Any]] = {
    "default": {},
    "gftt detector": {"detector.method": "gftt"},
    "forward-backward check": {"tracker.forward_backward": True},
    "KLT 21x21, 3 levels": {"tracker.window": 21, "tracker.levels": 3, "tracker.iterations": 30},
    "L2 loss": {"solver.loss": "l2"},
    "no reference-noise propagation": {"solver.propagate_reference_noise": False},
    "pixel sigma 2, 2, 4 (calibrated)": {"solver.pixel_sigma": [2.0, 2.0, 4.0]},
}


def cmd_bench_vo(args: Any) -> int:
    import cv2

    cv2.setNumThreads(args.threads)
    sequence = open_sequence(args.sequence_dir, args.rate, None, False, 0, args.count, args.poses)
    images = [sequence.load_pair(i) for i in range(len(sequence))]
    base = parse_overrides(args.param, None)
    variants = BENCH_VARIANTS if args.compare else {"default": {}}
    print(
        f"pvo bench vo: {sequence.root} frames {len(sequence)}, "
        f"{images[0][0].shape[1]}x{images[0][0].shape[0]}, OpenCV threads {args.threads}"
    )
    header = (
        f"{'variant':<34} {'median':>7} {'p95':>7} "
        + " ".join(f"{s[:8]:>8}" for s in STAGES[:-1])
        + f" {'drift%':>7} {'ATE m':>6} {'ANEES':>6} {'inl':>5} lost"
    )
    print(header)
    summaries = {}
    for name, overrides in variants.items():
        best: dict[str, Any] | None = None
        for _ in range(args.repeat):
            run = run_sequence(sequence, from_flat({**base, **overrides}), progress=False, images=images)
            s = summarise(run, sequence.poses)
            if best is None or s["median_ms"] < best["median_ms"]:
                best = s
        assert best is not None
        summaries[name] = best
        st = best["stages_ms"]
        acc = (
            f"{best['end_drift_percent']:7.3f} {best['ate_mean_m']:6.3f} {best['anees']:6.2f}"
            if "anees" in best
            else f"{'-':>7} {'-':>6} {'-':>6}"
        )
        print(
            f"{name:<34} {best['median_ms']:7.2f} {best['p95_ms']:7.2f} "
            + " ".join(f"{st[s]:8.2f}" for s in STAGES[:-1])
            + f" {acc} {best['inliers']:5.0f} {best['lost']}"
        )
    print("times in ms per stereo frame (median over frames, best of repeats); drift = end-point error / path length;")
    print("ATE = mean position error, no alignment; ANEES = mean NEES / 6 of the per-frame motions against ground truth")
    if args.json is not None:
        args.json.write_text(yaml.safe_dump(summaries, sort_keys=False))
    return 0
