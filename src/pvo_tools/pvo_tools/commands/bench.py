"""`pvo bench vo|probe|sun-bcnn|sim|realism|fusion|soak|faults`: benchmarks that print figures (speed, memory, accuracy)."""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
import tracemalloc
from pathlib import Path
from typing import Any

import yaml
from pvo_frontend.offline import STAGES, run_sequence, summarise
from pvo_frontend.vo import from_flat

from ..errors import PvoError
from ..overrides import parse_overrides
from ..paths import data_directory
from .vo import add_sequence_arguments, open_sequence


def register(sub: Any) -> None:
    bench = sub.add_parser(
        "bench", help="benchmarks: vo | probe | sun-bcnn | hydranet | dpc-net | sim | realism | fusion | soak | faults"
    )
    kinds = bench.add_subparsers(dest="bench", required=True, metavar="WHAT")
    bvo = kinds.add_parser("vo", help="stereo VO per-stage timings and accuracy on a KITTI clip")
    bvo.set_defaults(handler=bench_vo)
    add_sequence_arguments(bvo)
    bvo.add_argument("--count", type=int, help="number of frames (default: all)")
    bvo.add_argument("--repeat", type=int, default=3, help="runs per variant; the fastest is reported (default 3)")
    bvo.add_argument("--threads", type=int, default=1, help="OpenCV threads (default 1: one core)")
    bvo.add_argument("--compare", action="store_true", help="also run the alternative detector/tracker/solver variants")
    bvo.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="VO parameter for every variant")
    bvo.add_argument("--json", type=Path, help="write the figures as YAML/JSON to this file")

    bp = kinds.add_parser("probe", help="PROBE: predictors and noise inference per frame for N features on one core")
    bp.set_defaults(handler=bench_probe)
    bp.add_argument("--model", default="probe_kitti", help="PROBE model (default probe_kitti, the shipped one)")
    bp.add_argument("--features", type=int, default=500, help="features per frame (default 500)")
    bp.add_argument("--image", type=Path, help="left image (default KITTI 06 frame 10 of the data directory)")
    bp.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    bp.add_argument("--repeat", type=int, default=50, help="frames timed (default 50)")

    bsun = kinds.add_parser("sun-bcnn", help="Sun-BCNN: one estimate per KITTI 06 image in every MC mode on one core")
    bsun.set_defaults(handler=bench_sun_bcnn)
    bsun.add_argument("--model", default="", help="Sun-BCNN model (default: the shipped one)")
    bsun.add_argument("--samples", type=int, default=25, help="MC-dropout passes per estimate (default 25)")
    bsun.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")

    bh = kinds.add_parser("hydranet", help="HydraNet: resize, Farneback flow and the network per frame pair on one core")
    bh.set_defaults(handler=bench_hydranet)
    bh.add_argument("--model", default="", help="HydraNet model (default: the shipped one)")
    bh.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    bh.add_argument("--repeat", type=int, default=3, help="passes over the KITTI 06 clip; the fastest is reported (default 3)")

    bd = kinds.add_parser("dpc-net", help="DPC-Net: the stereo pair resized per frame and one correction per window on one core")
    bd.set_defaults(handler=bench_dpc_net)
    bd.add_argument("--model", default="", help="DPC-Net model (default: the shipped one)")
    bd.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    bd.add_argument("--repeat", type=int, default=3, help="passes over the KITTI 06 clip; the fastest is reported (default 3)")

    bs = kinds.add_parser("sim", help="synthetic world: stereo frames/s at 620x188 and 1241x376, world generation vs length")
    bs.set_defaults(handler=bench_sim)
    bs.add_argument("--preset", default="urban", help="urban | planetary")
    bs.add_argument("--frames", type=int, default=30, help="frames rendered per size (default 30)")

    breal = kinds.add_parser(
        "realism", help="rendered worlds against the real KITTI and Devon images: statistics, tracking, drift"
    )
    breal.set_defaults(handler=bench_realism)
    breal.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    breal.add_argument(
        "--out", "-o", type=Path, default=Path("runs/bench-realism"), help="renders, metrics.json, contact_sheet.png"
    )
    breal.add_argument("--reuse", action="store_true", help="keep earlier renders of the same configurations")
    breal.add_argument(
        "--compare", action="append", default=[], metavar="LABEL=DIR", help="also measure this rendered folder (repeatable)"
    )

    blearn = kinds.add_parser("learning", help="learning harness: data-loader samples/s cold and cached, training-step time")
    blearn.set_defaults(handler=bench_learning)
    blearn.add_argument("--corpus", type=Path, default=Path("data/corpus"), help="corpus (default data/corpus)")
    blearn.add_argument("--sequences", type=int, default=2, help="sequences to load (default 2)")
    blearn.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")

    bsoak = kinds.add_parser("soak", help="a sample bag looped through the real node graph: memory, lost frames, latency drift")
    bsoak.set_defaults(handler=bench_soak)
    bsoak.add_argument("--bag", type=Path, help="bag to loop (default bags/sim_urban_sample)")
    bsoak.add_argument("--frames", type=int, default=10_000, help="stereo frames to play (default 10000)")
    bsoak.add_argument("--rate", type=float, default=2.0, help="playback speed factor (default 2x real time)")
    bsoak.add_argument(
        "--out", "-o", type=Path, default=Path("runs/bench-soak"), help="logs and metrics.json (default runs/bench-soak)"
    )
    bsoak.add_argument(
        "--param", "-p", action="append", metavar="NODE:NAME=VALUE", help="node parameter, e.g. -p fusion:path_max_poses=100"
    )
    bsoak.add_argument(
        "--sensors",
        default="sun_bcnn,hydranet,dpc_net",
        help="pseudo-sensor nodes beside stereo_vo and fusion, comma-separated among simulated_sun, sun_bcnn, hydranet, "
        "dpc_net (default sun_bcnn,hydranet,dpc_net: the main job's graph, as `pvo demo` runs it on the synthetic sample)",
    )
    bsoak.add_argument("--sun-model", default="", help="Sun-BCNN model (default: the shipped one)")
    bsoak.add_argument("--hydranet-model", default="", help="HydraNet model (default: the shipped one)")
    bsoak.add_argument("--dpc-net-model", default="dpc_net_clean", help="DPC-Net model (default dpc_net_clean, as pvo demo)")
    bsoak.add_argument(
        "--probe-model", default="probe_sim", help="stereo_vo's PROBE model (default probe_sim, as pvo demo; '' for none)"
    )

    bfault = kinds.add_parser("faults", help="nodes killed and restarted, images dropped, a clock jump: what each costs")
    bfault.set_defaults(handler=bench_faults)
    bfault.add_argument("--bag", type=Path, help="sample bag (default bags/sim_urban_sample)")
    bfault.add_argument("--rate", type=float, default=1.0, help="playback speed factor (default 1)")
    bfault.add_argument("--out", "-o", type=Path, default=Path("runs/bench-faults"), help="logs and metrics.json")
    bfault.add_argument(
        "--sensors",
        default="sun_bcnn,hydranet,dpc_net",
        help="pseudo-sensor nodes beside stereo_vo and fusion, comma-separated among simulated_sun, sun_bcnn, hydranet, "
        "dpc_net (default sun_bcnn,hydranet,dpc_net: the main job's graph); each node of the graph is killed in turn",
    )
    bfault.add_argument(
        "--probe-model", default="probe_sim", help="stereo_vo's PROBE model (default probe_sim, as pvo demo; '' for none)"
    )

    bf = kinds.add_parser("fusion", help="FusionGraph over a whole KITTI sequence (viso2-s VO + GT-Sun-10): time and memory")
    bf.set_defaults(handler=bench_fusion)
    bf.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    bf.add_argument("--sequence", default="00", help="KITTI sequence (default 00: 4541 frames)")
    bf.add_argument("--repeat", type=int, default=3, help="runs; the fastest is reported (default 3)")
    bf.add_argument("--param", "-p", action="append", metavar="NAME=VALUE", help="fusion parameter")
    bf.add_argument(
        "--rotations",
        type=float,
        metavar="SIGMA_DEG",
        help="also a relative rotation every frame, as HydraNet's: the true one with this much noise per axis (deg), "
        "fused by the rotation factor (the sun stays)",
    )


BENCH_VARIANTS: dict[str, dict[str, Any]] = {
    "default": {},
    "gftt detector": {"detector.method": "gftt"},
    "forward-backward check": {"tracker.forward_backward": True},
    "KLT 21x21, 3 levels": {"tracker.window": 21, "tracker.levels": 3, "tracker.iterations": 30},
    "L2 loss": {"solver.loss": "l2"},
    "no reference-noise propagation": {"solver.propagate_reference_noise": False},
    "pixel sigma 2, 2, 4 (calibrated)": {"solver.pixel_sigma": [2.0, 2.0, 4.0]},
    "stereo noise model": {"solver.noise_model": "stereo"},
}


def bench_probe(args: argparse.Namespace) -> int:
    """Issue 17's budget: PROBE's predictors and its noise inference for N features of one frame, one core."""
    import time

    import cv2
    import numpy as np
    from pvo_core.imageio import read_image
    from pvo_frontend.probe.model import ProbeModel, resolve_model
    from pvo_frontend.probe.predictors import (
        blur_metric,
        flow_variance_score,
        frequency_composition,
        gather_patches,
        patch_entropy,
    )

    from ..paths import data_directory

    cv2.setNumThreads(1)
    model = ProbeModel.load(resolve_model(args.model))
    image = read_image(args.image or data_directory(args.data) / "kitti" / "sequences" / "06" / "image_0" / "000010.png")
    image = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)
    rng = np.random.default_rng(0)
    height, width = image.shape
    current = rng.uniform([0, 0], [width, height], (args.features, 2))
    reference = current + rng.normal(0, 2.0, current.shape)
    disparity = rng.uniform(2.0, 80.0, args.features)
    cfg = model.predictors
    stages = {
        "patches + entropy": lambda: patch_entropy(gather_patches(image, current, cfg.patch), cfg.entropy_bins),
        "blur": lambda: blur_metric(image, current, cfg.patch, cfg.blur_taps),
        "fft low/high": lambda: frequency_composition(gather_patches(image, current, cfg.patch), cfg.block),
        "flow variance": lambda: flow_variance_score(reference, current, cfg.flow_small, cfg.flow_large),
        "predictors + noise (total)": lambda: model.without_imu().noise(reference, current, image, disparity=disparity),
    }
    if cfg.imu:  # the total above is a frame without an IMU reading (the images alone); this one has one
        imu = np.array([9.81, 0.05])  # |specific force| m/s^2, |angular rate| rad/s
        stages["... with an IMU reading"] = lambda: model.noise(reference, current, image, imu, disparity)
    print(
        f"pvo bench probe: model {args.model} ({model.kind}, {len(model.estimator.errors)} stored samples, "
        f"predictors {', '.join(cfg.names)}), {args.features} features on a {width}x{height} image, one core"
    )
    for name, stage in stages.items():
        if not cfg.image and name in ("patches + entropy", "blur", "fft low/high"):
            continue
        stage()
        times = []
        for _ in range(args.repeat):
            tic = time.perf_counter()
            stage()
            times.append(1e3 * (time.perf_counter() - tic))
        print(f"  {name:<28} median {np.median(times):6.2f} ms, p95 {np.percentile(times, 95):6.2f} ms")
    return 0


def bench_sun_bcnn(args: argparse.Namespace) -> int:
    """Issue 14's budget: one estimate (resize, N passes, Method I/II) <= 30 ms per image on one core, in every
    MC mode, over the KITTI 06 clip's full-size left images (what the node receives)."""
    import time

    import numpy as np
    from pvo_core.imageio import read_image
    from pvo_pseudosensors.sun_bcnn.estimator import SunBCNNSensor, SunBCNNSensorConfig
    from pvo_pseudosensors.sun_bcnn.infer import MODES

    from ..paths import data_directory

    folder = data_directory(args.data) / "kitti" / "sequences" / "06" / "image_0"
    paths = sorted(folder.glob("*.png"))
    if not paths:
        raise PvoError(f"{folder}: no KITTI 06 left images to time Sun-BCNN on")
    images = [read_image(p) for p in paths]
    own = SunBCNNSensor(SunBCNNSensorConfig(model=args.model, samples=args.samples, threads=1)).mode
    print(
        f"pvo bench sun-bcnn: model {args.model or 'sun_bcnn (shipped)'}, {args.samples} passes, {len(images)} KITTI 06 "
        f"images of {images[0].shape[1]}x{images[0].shape[0]}, one thread (the node's mode for this model: {own})"
    )
    for mode in MODES:
        sensor = SunBCNNSensor(SunBCNNSensorConfig(model=args.model, samples=args.samples, mode=mode, threads=1))
        sensor.estimate(images[0])  # warm-up
        times = []
        for image in images:
            tic = time.perf_counter()
            sensor.estimate(image)
            times.append(1e3 * (time.perf_counter() - tic))
        print(f"  {mode:<14} median {np.median(times):6.1f} ms, p95 {np.percentile(times, 95):6.1f} ms per image")
    return 0


def bench_hydranet(args: argparse.Namespace) -> int:
    """Issue 15's budget: flow + inference <= 25 ms per frame pair on one core, stage by stage, over the KITTI
    06 clip's full-size left images (what the node receives)."""
    import time

    import cv2
    import numpy as np
    import torch
    from pvo_core.imageio import read_image
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.flow import dense_flow, network_input
    from pvo_pseudosensors.hydranet.model import predict_rotations
    from pvo_pseudosensors.hydranet.shortfall import flow_shortfall

    from ..paths import data_directory

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    sensor = HydraNetSensor(HydraNetSensorConfig(model=args.model, threads=1))
    paths = sorted((data_directory(args.data) / "kitti" / "sequences" / "06" / "image_0").glob("*.png"))
    images = [read_image(p) for p in paths]
    size = (sensor.width, sensor.height)
    small = [cv2.resize(i, size, interpolation=cv2.INTER_AREA) for i in images]
    # the network reads what the sensor gives it: the flow, and the texture and pitch channels its card asks for
    flow = torch.from_numpy(
        network_input(small[0], dense_flow(small[0], small[1], sensor.flow_prior), sensor.texture, sensor.pitch_deg)
    )[None]
    mirrored, reversed_flow = sensor.mode == "mirrored", None
    if sensor.mode == "reversed":
        backward = dense_flow(small[1], small[0], sensor.flow_prior)
        reversed_flow = torch.from_numpy(network_input(small[1], backward, sensor.texture, sensor.pitch_deg))[None]
    heads = sensor.model.head_count * (1 if sensor.mode == "plain" else 2)  # the pair and its mirror image or reverse
    stages = {
        "resize": lambda k: cv2.resize(images[k], size, interpolation=cv2.INTER_AREA),
        f"Farneback flow{' x2' if reversed_flow is not None else ''}": lambda k: (
            dense_flow(small[k - 1], small[k], sensor.flow_prior),
            reversed_flow is not None and dense_flow(small[k], small[k - 1], sensor.flow_prior),
        ),
        f"network ({heads} heads, Sigma)": lambda k: predict_rotations(sensor.model, flow, mirrored, reversed_flow),
    }
    shortfall = getattr(sensor.model, "shortfall_widening", None)
    if shortfall is not None:  # the card's flow-shortfall widening: a phase correlation per pair
        moved = dense_flow(small[0], small[1], sensor.flow_prior)
        stages["flow shortfall"] = lambda k: flow_shortfall(small[k - 1], small[k], moved, shortfall.min_response)
    stages["sensor total"] = lambda k: sensor.estimate(images[k], (k + 1) * 100_000_000)
    print(
        f"pvo bench hydranet: {sensor.height}x{sensor.width} flow from {images[0].shape[1]}x{images[0].shape[0]} images, "
        f"{len(images) - 1} pairs of the KITTI 06 clip, one core, {sensor.mode} inference"
    )
    for name, stage in stages.items():
        best: list[float] = []
        for _ in range(args.repeat):
            sensor.reset()
            sensor.estimate(images[0], 100_000_000)
            times = []
            for k in range(1, len(images)):
                tic = time.perf_counter()
                stage(k)
                times.append(1e3 * (time.perf_counter() - tic))
            best = times if not best or np.median(times) < np.median(best) else best
        print(f"  {name:<28} median {np.median(best):6.2f} ms, p95 {np.percentile(best, 95):6.2f} ms")
    return 0


def bench_dpc_net(args: argparse.Namespace) -> int:
    """Issue 16's budget: one correction <= 30 ms on one core; what the node does per frame (both images resized)
    and per window (the network over its two ends), over the KITTI 06 clip's full-size stereo pairs."""
    import time

    import cv2
    import numpy as np
    import torch
    from pvo_core.imageio import read_image
    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig

    from ..paths import data_directory

    cv2.setNumThreads(1)
    torch.set_num_threads(1)
    sensor = DPCNetSensor(DPCNetSensorConfig(model=args.model, threads=1))
    clip = data_directory(args.data) / "kitti" / "sequences" / "06"
    pairs = [
        (read_image(a), read_image(b))
        for a, b in zip(sorted((clip / "image_0").glob("*.png")), sorted((clip / "image_1").glob("*.png")), strict=True)
    ]
    step = np.eye(4)
    step[2, 3] = 0.8
    print(
        f"pvo bench dpc-net: {sensor.settings.height}x{sensor.settings.width} input from {pairs[0][0].shape[1]}x"
        f"{pairs[0][0].shape[0]} stereo pairs, Δp = {sensor.delta}, {len(pairs)} frames of the KITTI 06 clip, one core"
        + (", each window also through the mirror (the card's mode)" if sensor.mirrored else "")
    )
    best: dict[str, list[float]] = {}
    for _ in range(args.repeat):
        sensor.images.clear()
        sensor.sizes.clear()
        sensor.first, sensor.chain = None, type(sensor.chain)()
        times: dict[str, list[float]] = {"stereo pair resized (every frame)": [], "correction (every window)": []}
        for k, (left, right) in enumerate(pairs):
            tic = time.perf_counter()
            sensor.add_images((k + 1) * 100_000_000, left, right)
            times["stereo pair resized (every frame)"].append(1e3 * (time.perf_counter() - tic))
            if k == 0:
                continue
            tic = time.perf_counter()
            correction = sensor.add_vo(k * 100_000_000, (k + 1) * 100_000_000, step)
            if correction is not None:
                times["correction (every window)"].append(1e3 * (time.perf_counter() - tic))
        for name, values in times.items():
            if name not in best or np.median(values) < np.median(best[name]):
                best[name] = values
    for name, values in best.items():
        print(f"  {name:<36} median {np.median(values):6.2f} ms, p95 {np.percentile(values, 95):6.2f} ms ({len(values)} timed)")
    per_frame = np.median(best["stereo pair resized (every frame)"]) + np.median(best["correction (every window)"]) / sensor.delta
    print(f"  {'per frame on average':<36} {per_frame:6.2f} ms (100 ms between frames at 10 Hz)")
    return 0


def bench_vo(args: argparse.Namespace) -> int:
    """Per-stage timings and accuracy of the stereo VO (and its variants) on a KITTI clip."""
    import cv2

    cv2.setNumThreads(args.threads)
    sequence = open_sequence(args.sequence_dir, args.rate, None, False, 0, args.count, args.poses)
    images = [sequence.load_pair(i) for i in range(len(sequence))]
    base = parse_overrides(args.param, None, node="stereo_vo")
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
            vo_run = run_sequence(sequence, from_flat({**base, **overrides}), images=images)
            s = summarise(vo_run, sequence.poses)
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


def bench_sim(args: argparse.Namespace) -> int:
    """Rendering throughput at two sizes and world-generation time against path length."""
    from pvo_sim import KITTI_FOCAL_PER_PIXEL_WIDTH, SimConfig, WorldSpec, build_world, procedural_path, simulate

    with tempfile.TemporaryDirectory() as tmp:
        for width, height in ((620, 188), (1241, 376)):
            config = SimConfig(
                frames=args.frames, width=width, height=height, focal=KITTI_FOCAL_PER_PIXEL_WIDTH * width, preset=args.preset
            )
            result = simulate(config, Path(tmp) / f"{width}", overwrite=True)
            print(
                f"{args.preset} {width}x{height}: {result.frames / result.seconds_render:.2f} stereo frames/s "
                f"({1e3 * result.seconds_render / result.frames:.1f} ms per stereo pair incl. PNG writing)"
            )
    for frames in (250, 500, 1000, 2000):
        poses = procedural_path("s-curve", frames, 10.0, 8.0, 1.65)
        start = time.perf_counter()
        world = build_world(WorldSpec(args.preset), poses, 1.65)
        seconds = time.perf_counter() - start
        print(f"world generation, {frames} frames ({frames * 0.8:.0f} m): {seconds:.3f} s, {world.xml.count('<geom')} geoms")
    return 0


def bench_learning(args: argparse.Namespace) -> int:
    """Samples/s of the dataset decoding PNGs (cold), building the cache, and reading the cache (warm); the
    time of one Sun-BCNN training step (batch 32) at two input sizes."""
    import shutil

    import torch
    from pvo_core.readers import read_corpus_manifest
    from pvo_pseudosensors.learning import DataSpec, FrameDataset, Source
    from pvo_pseudosensors.sun_bcnn import SunBCNNConfig
    from pvo_pseudosensors.sun_bcnn.model import SunTask

    torch.set_num_threads(args.threads)
    sequences = read_corpus_manifest(args.corpus).sequences[: args.sequences]
    sources = [Source(s.root, s.name, s.split) for s in sequences]
    spec = DataSpec((94, 310), sun=True)

    def sweep(data: FrameDataset) -> float:
        start = time.perf_counter()
        for i in range(len(data)):
            data[i]
        return len(data) / (time.perf_counter() - start)

    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        uncached = FrameDataset(sources, spec, None)  # decodes and resizes every PNG into memory
        cold = len(uncached) / (time.perf_counter() - start)
        start = time.perf_counter()
        FrameDataset(sources, spec, Path(tmp))
        build = len(uncached) / (time.perf_counter() - start)
        start = time.perf_counter()
        cached = FrameDataset(sources, spec, Path(tmp))
        opening = time.perf_counter() - start
        warm = sweep(cached)
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"dataset over {len(sources)} corpus sequences ({len(uncached)} samples at 94x310, grey):")
    print(f"  decoding the PNGs (what every epoch would cost without a cache): {cold:8.1f} samples/s")
    print(f"  building the cache (decode, resize, write .npy once):            {build:8.1f} samples/s")
    print(f"  from the cache (memory-mapped; opening took {opening * 1e3:.0f} ms):          {warm:8.1f} samples/s")
    for height, width in ((94, 310), (120, 400)):
        task = SunTask(SunBCNNConfig(height=height, width=width))
        model = task.build()
        optimizer = torch.optim.AdamW(model.parameters(), lr=1e-3)
        batch = {"left": torch.rand(32, 1, height, width), "sun": torch.nn.functional.normalize(torch.randn(32, 3), dim=1)}
        times = []
        for _ in range(6):
            start = time.perf_counter()
            optimizer.zero_grad()
            task.loss(model, batch).backward()
            optimizer.step()
            times.append(time.perf_counter() - start)
        parameters = sum(p.numel() for p in model.parameters())
        median = sorted(times[1:])[2]
        print(
            f"Sun-BCNN training step, batch 32 at {height}x{width} ({parameters / 1e3:.0f} k parameters, "
            f"{args.threads} threads): median {1e3 * median:.0f} ms ({32 / median:.0f} samples/s)"
        )
    return 0


def bench_realism(args: argparse.Namespace) -> int:
    import sys

    import cv2

    from ..realism import RealismOptions, contact_sheet, run_realism

    extra = []
    for item in args.compare:
        label, sep, folder = item.partition("=")
        if not sep or not Path(folder).is_dir():
            raise PvoError(f"--compare {item!r}: expected LABEL=DIR with an existing rendered folder")
        extra.append((label, Path(folder)))
    out = Path(args.out)
    options = RealismOptions(data_directory(args.data), out / "renders", tuple(extra), args.reuse)
    result, sets = run_realism(options, say=lambda text: print(text, file=sys.stderr, flush=True))
    columns = (
        "tracked",
        "inlier_ratio",
        "spectrum_slope",
        "mean_intensity",
        "slope_gap",
        "intensity_distance",
        "gradient_distance",
    )
    print(f"{'image set':<24} {'kind':<10} " + " ".join(f"{c:>18}" for c in columns))
    for label, row in result.tables["image_sets"].items():
        values = " ".join(f"{row[c]:>18.3f}" for c in columns)
        print(f"{label:<24} {row['kind']:<10} {values}")
    print("(slope_gap and distances against the real set of the same kind: KITTI 06 for urban, Devon for planetary)")
    for label, row in result.tables["vo_runs"].items():
        print(f"stereo VO end drift, {label}: {row['end_drift_percent']:.2f} % of {row['path_m']:.1f} m")
    out.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out / "contact_sheet.png"), contact_sheet(sets))
    print(f"wrote {result.write(out)} and {out / 'contact_sheet.png'}")
    return 0


def bench_fusion(args: argparse.Namespace) -> int:
    """Whole-sequence FusionGraph throughput and memory (VO + GT-Sun-10, no covariance queries)."""
    from ..experiments.sun_sim import experiment_config, prepare_sequence, run_fusion

    if args.rotations is not None:
        check_rotation_noise(args.rotations)  # before the VO runs
    data = data_directory(args.data)
    seq, vo, sun = prepare_sequence(data, args.sequence, 10.0, seed=0)
    config = experiment_config(parse_overrides(args.param))
    rotations = [] if args.rotations is None else noisy_relative_rotations(seq.stamps, seq.ground_truth, args.rotations)
    times = []
    for _ in range(max(args.repeat, 1)):
        result = run_fusion(seq, vo, sun, config, rotations=rotations)
        times.append(result.seconds)
    frames = len(seq.stamps)
    best = min(times)
    read = f", {len(rotations)} relative rotations ({args.rotations:g} deg per axis)" if rotations else ""
    print(
        f"sequence {args.sequence}: {frames} frames, {len(sun)} sun measurements{read}, "
        f"smoother {config.solver.smoother}/{config.solver.linear_solver}, lag {config.window.lag:g} {config.window.lag_unit}"
    )
    print(
        f"  whole sequence: best {best:.2f} s of {len(times)} ({1e3 * best / frames:.3f} ms/frame), "
        f"runs: {', '.join(f'{t:.2f}' for t in times)}"
    )
    print(f"  factors: {result.factors}")
    # Memory over the sequence: the live Python heap at each quarter of the run must stay flat.
    quarter = max(frames // 4, 1)
    marks: list[tuple[int, float, int]] = []

    def sample(done: int, graph: Any) -> None:
        graph.drain_finished()
        if done % quarter == 0:
            marks.append((done, tracemalloc.get_traced_memory()[0] / 1e6, graph.window_size))

    tracemalloc.start()
    rss_start = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    run_fusion(seq, vo, sun, config, on_vo=sample, rotations=rotations)
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss_end = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print("  memory (live Python heap, MB) by frame: " + ", ".join(f"{i}: {mb:.3f} (window {w})" for i, mb, w in marks))
    print(
        f"  end: {current / 1e6:.2f} MB live, peak {peak / 1e6:.2f} MB; max RSS {rss_start / 1024:.0f} -> {rss_end / 1024:.0f} MB"
    )
    return 0


def check_rotation_noise(sigma_deg: float) -> None:
    """ValueError unless ``sigma_deg`` is a finite positive number of degrees."""
    if not (sigma_deg > 0.0 and sigma_deg != float("inf")):  # NaN fails the first test
        raise ValueError(f"--rotations: the noise must be a positive number of degrees, got {sigma_deg}")


def noisy_relative_rotations(stamps: Any, ground_truth: Any, sigma_deg: float, seed: int = 0) -> list[Any]:
    """A rotation reading per frame k >= 1, as HydraNet's: C_k,k-1 of ``ground_truth`` (N, 4, 4, T_map,cam) times
    Exp(noise), the noise N(0, sigma_deg² I) per axis (deg), published with that covariance (rotation block)."""
    import numpy as np
    from pvo_core.lie import so3_exp
    from pvo_fusion.measurements import RelativeMeasurement

    check_rotation_noise(sigma_deg)
    rng = np.random.default_rng(seed)
    sigma = np.radians(sigma_deg)
    covariance = np.diag([1e4, 1e4, 1e4] + [sigma**2] * 3)
    readings = []
    for k in range(1, len(stamps)):
        reading = np.eye(4)
        c_to_from = ground_truth[k][:3, :3].T @ ground_truth[k - 1][:3, :3]
        reading[:3, :3] = c_to_from @ so3_exp(rng.normal(0.0, sigma, 3))
        readings.append(RelativeMeasurement(int(stamps[k]), int(stamps[k - 1]), reading, covariance, rotation_only=True))
    return readings


def bench_soak(args: argparse.Namespace) -> int:
    """Issue 18's soak, on the main job's graph by default: RSS growth after warm-up and CPU share per node, every
    frame and every sensor's output accounted for, end-to-end latency p95 start vs end."""
    import os
    import random

    import numpy as np
    from pvo_core.results import RunResult
    from pvo_fusion.sun_reference import TabulatedSunReference

    from pvo_core import metrics

    from ..graphbench import cpu_share, run_soak, soak_nodes
    from ..paths import repository_root
    from ..samples import read_stereo_sample
    from .demo import DemoSettings, learned_graph

    sensors = tuple(name.strip() for name in args.sensors.split(",") if name.strip())
    nodes = [name for _, name in soak_nodes(sensors)]
    bag = args.bag or (repository_root() or Path.cwd()) / "bags" / "sim_urban_sample"
    sample = read_stereo_sample(bag)
    first = int(sample.frame_stamps[0])
    if first not in sample.sun:
        raise PvoError(f"{bag}: no /ground_truth/sun_direction at the first frame: the fusion's sun reference needs it")
    # the bag loops (its stamps shifted on each pass), so the fusion's sun reference is the map-frame direction at
    # the first frame, fixed: a 30 s sample's sun does not move
    sun_map = TabulatedSunReference.from_ground_truth(
        [first], sample.ground_truth_at(sample.frame_stamps[:1]), [sample.sun[first]]
    )
    overrides: dict[str, dict] = {}
    for item in args.param or []:
        node, sep, assignment = item.partition(":")
        if not sep:
            raise PvoError(f"--param {item!r} must be NODE:NAME=VALUE, e.g. fusion:path_max_poses=100")
        if node not in nodes:
            raise PvoError(f"--param {item!r}: no node {node!r} in this soak (its nodes: {', '.join(nodes)})")
        overrides.setdefault(node, {}).update(parse_overrides([assignment]))
    settings = DemoSettings(
        sun_model=args.sun_model,
        hydranet_model=args.hydranet_model,
        dpc_net_model=args.dpc_net_model,
        probe_model=args.probe_model,
    )
    graph = learned_graph(settings, tuple(name for name in sensors if name != "simulated_sun"), who="pvo bench soak")
    parameters: dict[str, dict] = {
        "stereo_vo": graph.vo | overrides.get("stereo_vo", {}),
        **{name: graph.sensors.get(name, {}) | overrides.get(name, {}) for name in sensors},
        "fusion": {
            "inputs.sun.reference": "fixed",
            "inputs.sun.reference_direction": [float(v) for v in sun_map.directions[0]],
            **graph.fusion,
            **overrides.get("fusion", {}),
        },
    }
    domain = int(os.environ.get("ROS_DOMAIN_ID") or random.Random().randint(40, 89))
    print(f"soak: {args.frames} frames of {bag} at {args.rate:g}x through {' + '.join(nodes)}", flush=True)
    result = run_soak(bag, args.frames, args.rate, args.out, domain, parameters, sensors)
    print(
        f"  played {result.frames_played} stereo frames in {result.seconds:.0f} s; received {result.vo_messages} VO motions "
        f"and {result.fused_messages} fused poses (every frame after the first: {result.frames_played - 1}); "
        f"node exit codes {result.exit_codes}"
    )
    figures: dict[str, float] = {
        "frames": result.frames_played,
        "vo_messages": result.vo_messages,
        "fused": result.fused_messages,
    }
    expected = sensor_outputs_due(result.frames_played, result.vo_messages, parameters)
    for name in sensors:
        counters = result.sensors.get(name)
        if counters is None:
            continue
        due = expected.get(name)
        print(
            f"  {name:<14} published {counters.get('published', 0)}"
            + (f" of {counters['images']} images received" if "images" in counters else "")
            + (f" ({due})" if due else "")
            + f", {counters.get('rejected', 0)} rejected"
        )
        figures.update({f"{name}.{key}": value for key, value in counters.items()})
    taken = {key.removeprefix("factors."): value for key, value in result.fusion.items() if key.startswith("factors.")}
    if taken:
        print("  fusion factors added: " + ", ".join(f"{kind} {count}" for kind, count in sorted(taken.items())))
        figures.update({f"fusion.factors.{kind}": float(count) for kind, count in taken.items()})
    # what the fusion did not take as it came: gated, rejected (with the reason), dropped, gaps in the VO's chain
    rejected = {
        key: value
        for key, value in result.fusion.items()
        if key.startswith("count.") and not key.endswith((".accepted", ".buffered"))
    }
    if rejected:
        print(
            "  fusion, not taken as it came: "
            + ", ".join(f"{key.removeprefix('count.')} {value}" for key, value in sorted(rejected.items()))
        )
    warm = 0.1 * result.seconds
    total_cpu = 0.0
    for name, samples in result.rss.items():
        after = [mb for t, mb in samples if t >= warm]
        share = cpu_share(result.cpu.get(name, []), warm)
        if len(after) >= 2:
            growth = after[-1] - after[0]
            figures[f"{name}.rss_start_mb"], figures[f"{name}.rss_end_mb"], figures[f"{name}.rss_growth_mb"] = (
                after[0],
                after[-1],
                growth,
            )
            cpu_text = "" if share != share else f"; CPU {100 * share:5.1f} % of one core"
            print(
                f"  {name:<14} RSS {after[0]:7.1f} MB after warm-up -> {after[-1]:7.1f} MB at the end ({growth:+.1f} MB)"
                + cpu_text
            )
        if share == share:
            figures[f"{name}.cpu_share"] = share
            total_cpu += share
    if total_cpu:
        cores = os.cpu_count() or 1
        figures["cpu_share_total"] = total_cpu
        print(
            f"  the graph's nodes together: {total_cpu:.2f} cores' worth of CPU at {args.rate:g}x real time "
            f"({100 * total_cpu / cores:.0f} % of this machine's {cores}; the player and listener, this process, not counted)"
        )
    # the start of the latency comparison is after the same warm-up as the memory's (the first 10 % of the
    # frames: the smoother's window and the bounded paths fill, caches warm)
    latencies = [ms for _, ms in result.latencies_ms]
    warm_frames = len(latencies) // 10
    window = min(1000, max((len(latencies) - warm_frames) // 4, 1))
    if len(latencies) - warm_frames >= 2 * window:
        start = metrics.latency_summary(latencies[warm_frames : warm_frames + window])
        end = metrics.latency_summary(latencies[-window:])
        figures.update({f"latency_start.{k}": v for k, v in start.items()})
        figures.update({f"latency_end.{k}": v for k, v in end.items()})
        figures["latency_p95_change"] = end["p95_ms"] / start["p95_ms"] - 1.0
        print(
            f"  latency image -> fused pose, frames {warm_frames}-{warm_frames + window} (after warm-up): "
            f"median {start['median_ms']:.1f} ms, p95 {start['p95_ms']:.1f} ms; "
            f"last {window}: median {end['median_ms']:.1f} ms, p95 {end['p95_ms']:.1f} ms "
            f"(p95 {100 * figures['latency_p95_change']:+.0f} %)"
        )
    if len(latencies) >= 20:  # the trend over the run, a tenth at a time: a slow growth shows here, a burst does not
        tenths = [metrics.latency_summary(part) for part in np.array_split(np.asarray(latencies), 10)]
        print("  latency by tenth of the run, median: " + " ".join(f"{t['median_ms']:.0f}" for t in tenths) + " ms")
        print("  latency by tenth of the run, p95:    " + " ".join(f"{t['p95_ms']:.0f}" for t in tenths) + " ms")
        figures.update({f"latency_tenth{k}.p95_ms": t["p95_ms"] for k, t in enumerate(tenths)})
        figures.update({f"latency_tenth{k}.median_ms": t["median_ms"] for k, t in enumerate(tenths)})
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "latency.csv").open("w") as handle:  # every frame's image -> fused pose latency
        handle.write("fused_index,latency_ms\n")
        handle.writelines(f"{index},{ms:.3f}\n" for index, ms in result.latencies_ms)
    inputs = {"bag": str(bag), "rate": str(args.rate), "sensors": ",".join(sensors), "probe_model": args.probe_model}
    path = RunResult("bench/soak", bag.name, figures=figures, inputs=inputs).write(args.out)
    print(f"  wrote {path}")
    return 0


def sensor_outputs_due(frames: int, vo_messages: int, parameters: dict[str, dict[str, Any]]) -> dict[str, str]:
    """What each sensor node should have published had it kept up, in words: sun_bcnn one direction per
    ``every_n`` images, hydranet one rotation per image but the first, dpc_net one correction per Δp VO motions
    (frames are the stereo frames played, ``vo_messages`` the VO motions received)."""
    from pvo_pseudosensors.sun_bcnn.estimator import SunBCNNSensorConfig

    every_n = int(parameters.get("sun_bcnn", {}).get("every_n", SunBCNNSensorConfig().every_n))
    due = {"sun_bcnn": f"one in {every_n}: {-(-frames // every_n)} due", "hydranet": f"one per pair: {frames - 1} due"}
    if "dpc_net" in parameters:
        from pvo_pseudosensors.dpc_net.config import DPCNetConfig
        from pvo_pseudosensors.dpc_net.estimator import resolve_model
        from pvo_pseudosensors.learning.checkpoint import ModelFileError, read_card

        try:
            delta = DPCNetConfig.from_card(read_card(resolve_model(str(parameters["dpc_net"].get("model", ""))))).test_delta
        except (ModelFileError, ValueError):
            return due  # the node said why in its log and status; nothing is due from it
        due["dpc_net"] = f"one per {delta} VO motions: {vo_messages // delta} due"
    return due


FAULT_AT, RESTART_AT, JUMP_AT = 100, 120, 150  # frames of the sample
CLOCK_JUMP_NS = 5_000_000_000


def bench_faults(args: argparse.Namespace) -> int:
    """Issue 18's faults: each node killed (SIGKILL) at frame 100 and restarted at 120, 10 % of the images dropped
    at random, the stamps jumping 5 s forward at frame 150; the fused online pose against the ground truth."""
    import os
    import random

    from pvo_core.msgconv import pose_to_xyz_xyzw
    from pvo_core.results import RunResult
    from pvo_fusion.sun_reference import TabulatedSunReference

    from pvo_core import metrics
    from pvo_fusion.config import FusionConfig

    from ..graphbench import run_fault, soak_nodes
    from ..paths import repository_root
    from ..recorder import with_header_stamp
    from ..samples import read_stereo_sample
    from .demo import DemoSettings, learned_graph

    sensors = tuple(name.strip() for name in args.sensors.split(",") if name.strip())
    nodes = [name for _, name in soak_nodes(sensors)]
    graph = learned_graph(
        DemoSettings(probe_model=args.probe_model), tuple(n for n in sensors if n != "simulated_sun"), who="pvo bench faults"
    )
    bag = args.bag or (repository_root() or Path.cwd()) / "bags" / "sim_urban_sample"
    sample = read_stereo_sample(bag)
    stamps = [int(s) for s in sample.frame_stamps]
    gt = sample.ground_truth_at(sample.frame_stamps)
    args.out.mkdir(parents=True, exist_ok=True)
    table = args.out / "sun_reference.csv"
    sun_stamps = [s for s in stamps if s in sample.sun]
    reference = TabulatedSunReference.from_ground_truth(
        sun_stamps, sample.ground_truth_at(sun_stamps), [sample.sun[s] for s in sun_stamps]
    )
    TabulatedSunReference.write(table, sun_stamps, reference.directions)
    params = {
        "stereo_vo": graph.vo,
        **{name: graph.sensors.get(name, {}) for name in sensors},
        "fusion": {
            "prior.source": "given",
            "initial_pose": pose_to_xyz_xyzw(gt[0]),
            "inputs.sun.reference": "table",
            "inputs.sun.reference_table": str(table.resolve()),
            **graph.fusion,
        },
    }
    domain = int(os.environ.get("ROS_DOMAIN_ID") or random.Random().randint(40, 89))
    gap = FusionConfig().inputs.vo.gap_sigma
    sigma = float(sum(v * v for v in gap[:3]) ** 0.5)  # m/s: the motion model's translational sigma per second

    def restart(node: str):
        def factory(group, params_file, log_dir, env):
            def hook(topic: str, stamp: int | None, raw: bytes) -> bytes:
                if topic == "/stereo/left/image_rect" and stamp == stamps[FAULT_AT]:
                    group.kill(node)
                if topic == "/stereo/left/image_rect" and stamp == stamps[RESTART_AT]:
                    group.restart(node, params_file, log_dir, env)
                return raw

            return hook

        return factory

    def drop_images(group, params_file, log_dir, env):
        rng = random.Random(0)
        return lambda topic, stamp, raw: None if topic.endswith("image_rect") and rng.random() < 0.1 else raw

    def clock_jump(group, params_file, log_dir, env):
        return lambda topic, stamp, raw: (
            with_header_stamp(raw, stamp + CLOCK_JUMP_NS) if stamp and stamp >= stamps[JUMP_AT] else raw
        )

    scenarios = [
        ("clean", None),
        *((f"{node} killed and restarted", restart(node)) for node in nodes),
        ("10 % of images dropped", drop_images),
        ("stamps jump 5 s forward", clock_jump),
    ]
    print(
        f"faults on {bag} ({len(stamps)} frames at {args.rate:g}x) through {' + '.join(nodes)}; node faults at frame "
        f"{FAULT_AT}, restarts at {RESTART_AT}"
    )
    print(f"{'scenario':<36}{'fused':>7}{'RMSE m':>9}{'vs clean':>10}{'jump m':>8}{'5 sigma m':>11}{'ratio':>7}  exits")
    figures: dict[str, float] = {}
    clean_rmse = None
    for index, (name, factory) in enumerate(scenarios):
        run = run_fault(name, bag, args.out / f"scenario{index}", domain, params, args.rate, factory, sensors)
        shift = CLOCK_JUMP_NS if factory is clock_jump else 0
        by_frame = {}
        for stamp, pose in run.poses.items():
            original = stamp - shift if shift and stamp >= stamps[JUMP_AT] + shift else stamp
            by_frame[original] = (pose, run.covariances[stamp])
        est = [by_frame[s][0] if s in by_frame else [[float("nan")] * 4] * 4 for s in stamps]
        f = metrics.fault_figures(gt, est, [s * 1e-9 for s in stamps], sigma)
        clean_rmse = f["rmse_m"] if clean_rmse is None else clean_rmse
        figures.update({f"{name}.{k}": v for k, v in f.items()})
        exits = ", ".join(f"{n} {c}" for n, c in run.exit_codes.items())
        print(
            f"{name:<36}{int(f['frames']):>7}{f['rmse_m']:>9.3f}{f['rmse_m'] - clean_rmse:>+10.3f}"
            f"{f['max_step_excess_m']:>8.3f}{f['five_sigma_m']:>11.3f}{f['jump_ratio']:>7.2f}  {exits}"
        )
    inputs = {"bag": str(bag), "rate": str(args.rate), "sensors": ",".join(sensors), "probe_model": args.probe_model}
    path = RunResult("bench/faults", bag.name, figures=figures, inputs=inputs).write(args.out)
    print("fused = frames with a fused pose; jump = the step of the fused pose that most exceeds the true step, against")
    print(
        f"5 sigma of the motion model over it (inputs.vo.gap_sigma, {sigma:.2f} m/s); ratio > 1 is a discontinuity. Wrote {path}"
    )
    return 0
