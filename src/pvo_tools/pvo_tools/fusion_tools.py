"""CLI glue for the fusion experiments and benchmarks (`pvo experiment sun-sim`, `pvo bench fusion`)."""

from __future__ import annotations

import os
import resource
import sys
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np

from .vo_offline import parse_overrides


def data_directory(explicit: Path | None) -> Path:
    """``--data``, else ``$PVO_DATA_DIR``, else ``../shared/data`` (the layout of a checkout)."""
    path = explicit or Path(os.environ.get("PVO_DATA_DIR", "../shared/data"))
    if not (path / "kitti").is_dir():
        raise ValueError(f"data directory {path} has no kitti/ folder (set --data or PVO_DATA_DIR)")
    return path


def cmd_sun_sim(args: Any) -> int:
    from .sun_experiment import NOISE_LEVELS, SEQUENCE_DRIVES, format_table, run_experiment, summary, write_outputs

    data = data_directory(args.data)
    if args.through_nodes:
        return _through_nodes(args, data)
    sequences = args.sequences or list(SEQUENCE_DRIVES)
    levels = args.levels if args.levels is not None else list(NOISE_LEVELS)
    overrides = parse_overrides(args.param)
    say = None if args.quiet else (lambda line: print(line, file=sys.stderr, flush=True))
    start = time.perf_counter()
    anees_every = 0 if args.no_anees else 10
    reports = run_experiment(data, sequences, levels, args.seed, overrides, anees_every, progress=say, trials=args.trials)
    table = format_table(reports, levels)
    if args.trials > 1:
        seeds = f"{args.seed}..{args.seed + args.trials - 1}"
        table += f"\nEach GT-Sun row is the mean over {args.trials} noise realisations (seeds {seeds})."
    print(table)
    means = summary(reports, levels)
    for label, change in means.items():
        print(
            f"{label}: mean change trans {100 * change['trans']:+.1f} %, "
            f"EN {100 * change['trans_en']:+.1f} %, rot {100 * change['rot']:+.1f} %"
        )
    write_outputs(args.out, reports, table, levels)
    print(f"wrote {args.out}/results.json and report.md ({time.perf_counter() - start:.1f} s)")
    return 0


def _through_nodes(args: Any, data: Path) -> int:
    from .sun_experiment import armse, experiment_config, prepare_sequence, run_fusion
    from .sun_experiment_nodes import run_through_nodes

    name = args.through_nodes
    seq, vo, sun = prepare_sequence(data, name, 10.0, args.seed, args.frames)
    overrides = parse_overrides(args.param)
    ros_free = run_fusion(seq, vo, sun, experiment_config(overrides))
    print(f"sequence {name}: {len(seq.stamps)} frames, {len(sun)} GT-Sun-10 measurements; playing at {args.rate:g}x", flush=True)
    nodes = run_through_nodes(seq, vo, sun, args.out / f"nodes_{name}", overrides, rate=args.rate)
    a, b = armse(seq.ground_truth, ros_free.poses), armse(seq.ground_truth, nodes.poses)
    print(f"{'':<12}{'trans [m]':>12}{'EN [m]':>12}{'rot [1e-3]':>12}")
    for label, m in (("ROS-free", a), ("nodes", b)):
        print(f"{label:<12}{m['trans']:>12.6f}{m['trans_en']:>12.6f}{1e3 * m['rot']:>12.6f}")
    diff = float(np.nanmax(np.abs(nodes.poses - ros_free.poses)))
    # Online (newest-state) estimates match where no sun measurement shares the frame: when a frame's sun
    # message reaches the node before its VO, the node publishes after fusing both (the ROS-free run before).
    sun_frames = {int(m.stamp) for m in sun}
    plain = [k for k in range(1, len(seq.stamps)) if int(seq.stamps[k]) not in sun_frames]
    online = float(np.nanmax(np.abs(nodes.online_poses[plain] - ros_free.online_poses[plain])))
    lat = np.asarray(nodes.latencies_ms)
    print(
        f"max |pose difference|: final {diff:.2e}, online (frames without sun) {online:.2e}; "
        f"odometry messages {nodes.odometry_messages}/{len(vo)}"
    )
    if len(lat):
        print(
            f"node latency VO in -> odometry out: median {np.median(lat):.2f} ms, "
            f"p95 {np.percentile(lat, 95):.2f} ms, max {lat.max():.2f} ms"
        )
    print(f"wall time {nodes.wall_seconds:.1f} s; bags in {args.out / f'nodes_{name}'}")
    return 0 if nodes.odometry_messages == len(vo) and diff < 1e-6 else 1


def cmd_bench_fusion(args: Any) -> int:
    """Whole-sequence FusionGraph throughput and memory (VO + GT-Sun-10, no covariance queries)."""
    from .sun_experiment import experiment_config, prepare_sequence, run_fusion

    data = data_directory(args.data)
    seq, vo, sun = prepare_sequence(data, args.sequence, 10.0, seed=0)
    config = experiment_config(parse_overrides(args.param))
    times = []
    for _ in range(max(args.repeat, 1)):
        result = run_fusion(seq, vo, sun, config)
        times.append(result.seconds)
    frames = len(seq.stamps)
    best = min(times)
    print(
        f"sequence {args.sequence}: {frames} frames, {len(sun)} sun measurements, "
        f"smoother {config.solver.smoother}/{config.solver.linear_solver}, lag {config.window.lag:g} {config.window.lag_unit}"
    )
    print(
        f"  whole sequence: best {best:.2f} s of {len(times)} ({1e3 * best / frames:.3f} ms/frame), "
        f"runs: {', '.join(f'{t:.2f}' for t in times)}"
    )
    print(f"  factors: {result.factors}")
    # Memory over the sequence: Python-heap peak per quarter of the run must stay flat.
    tracemalloc.start()
    marks = []
    quarter = frames // 4
    from pvo_fusion.sun_reference import TabulatedSunReference

    from pvo_fusion import FusionGraph

    from .sun_experiment import ordered_events

    graph = FusionGraph(config, TabulatedSunReference(seq.stamps, seq.sun_map()))
    graph.set_initial_pose(seq.ground_truth[0])
    rss_start = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    frames_done = 0
    for kind, m in ordered_events(vo, sun):
        (graph.add_vo if kind == "vo" else graph.add_sun)(m)
        graph.drain_finished()
        if kind == "vo":
            frames_done += 1
            if frames_done % max(quarter, 1) == 0:
                marks.append((frames_done, tracemalloc.get_traced_memory()[0] / 1e6, graph.window_size))
    current, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    rss_end = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    print("  memory (live Python heap, MB) by frame: " + ", ".join(f"{i}: {mb:.3f} (window {w})" for i, mb, w in marks))
    print(
        f"  end: {current / 1e6:.2f} MB live, peak {peak / 1e6:.2f} MB; max RSS {rss_start / 1024:.0f} -> {rss_end / 1024:.0f} MB"
    )
    return 0
