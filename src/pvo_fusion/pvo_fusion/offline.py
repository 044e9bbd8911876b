"""The offline runner: recorded measurements through a :class:`FusionGraph` in arrival order, no ROS.

The same events give the same estimates as the ``fusion`` node fed the same messages in the same order
(tested through DDS), so experiments, benchmarks and the demo's ROS-free check all call :func:`run_offline`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Collection, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from .graph import FusionGraph
from .measurements import RelativeMeasurement, SunMeasurement
from .output import ContinuousOutput

Array = NDArray[np.float64]
Measurement = RelativeMeasurement | SunMeasurement
Event = tuple[str, Measurement]  # kind: vo | sun | correction | rotation


def ordered_events(
    vo: Sequence[RelativeMeasurement], others: Iterable[tuple[str, Measurement]] = (), before: Collection[str] = ()
) -> list[Event]:
    """Measurements in arrival order: each frame's VO, then the other measurements stamped at that frame
    (those at the first VO's reference frame first of all); others at no VO frame come at the end. Kinds in
    ``before`` come just before the VO of their frame instead (a sensor faster than the VO: HydraNet's
    rotation ending at frame k reaches the fusion before the VO of frame k does, and waits for its state)."""
    by_stamp: dict[int, list[Event]] = {}
    early: dict[int, list[Event]] = {}
    for kind, m in others:
        (early if kind in before else by_stamp).setdefault(int(m.stamp), []).append((kind, m))
    events: list[Event] = []
    if vo:
        events.extend(early.pop(int(vo[0].reference_stamp), []))
        events.extend(by_stamp.pop(int(vo[0].reference_stamp), []))
    for m in vo:
        events.extend(early.pop(int(m.stamp), []))
        events.append(("vo", m))
        events.extend(by_stamp.pop(int(m.stamp), []))
    for stamp in sorted(set(by_stamp) | set(early)):
        events.extend(early.get(stamp, []) + by_stamp.get(stamp, []))
    return events


def sun_events(sun: Iterable[SunMeasurement]) -> list[Event]:
    return [("sun", m) for m in sun]


@dataclass
class OfflineResult:
    """Estimates per frame of ``stamps``: final fixed-lag ``poses`` and ``online_poses`` (the newest state
    right after its VO, as the fusion node publishes it: continuous, :mod:`pvo_fusion.output`), (N, 4, 4), NaN
    where none; their ``covariances`` (N, 6, 6, ROS order, left) when asked; the time spent in the graph
    (covariance queries excluded); counts and factors; ``gated_for_s``: per input the longest time (s of the newest
    state's time) over which every reading of it was gated (:attr:`FusionGraph.longest_gated_s`: buffered readings
    gated when their state came count too), inputs never gated left out."""

    poses: Array
    online_poses: Array
    covariances: Array | None
    seconds: float
    counts: dict[str, int] = field(default_factory=dict)
    factors: dict[str, int] = field(default_factory=dict)
    gated_for_s: dict[str, float] = field(default_factory=dict)


def run_offline(
    graph: FusionGraph,
    stamps: NDArray[np.int64],
    events: Iterable[Event],
    covariance_every: int = 0,
    on_vo: Callable[[int, FusionGraph], None] | None = None,
) -> OfflineResult:
    """Feed ``events`` to a started ``graph`` (its first pose set) and collect the estimates at ``stamps``.

    covariance_every: query the newest state's marginal covariance at every N-th frame (0: never).
    on_vo: called after each VO event with (frames so far, graph), e.g. to sample memory.
    """
    add: dict[str, Callable[[Measurement], str]] = {
        "vo": graph.add_vo,  # type: ignore[dict-item]
        "sun": graph.add_sun,  # type: ignore[dict-item]
        "correction": graph.add_correction,  # type: ignore[dict-item]
        "rotation": graph.add_rotation,  # type: ignore[dict-item]
    }
    output = ContinuousOutput.from_config(graph.config)
    n = len(stamps)
    index = {int(s): i for i, s in enumerate(stamps)}
    final = np.full((n, 4, 4), np.nan)
    online = np.full((n, 4, 4), np.nan)
    covariances = np.full((n, 6, 6), np.nan) if covariance_every > 0 else None
    if graph.newest_stamp is None:
        online[0] = graph.initial_pose
    cov_seconds = 0.0
    frames = 0
    start = time.perf_counter()
    for kind, m in events:
        add[kind](m)
        if kind == "vo":
            frames += 1
            if graph.newest_stamp == m.stamp and m.stamp in index:
                k = index[m.stamp]
                published = output.publish_newest(graph)
                online[k] = published.pose
                if covariances is not None and k % covariance_every == 0:
                    t0 = time.perf_counter()
                    covariances[k] = published.covariance(graph.covariance())
                    cov_seconds += time.perf_counter() - t0
            if on_vo is not None:
                on_vo(frames, graph)
        for p in graph.drain_finished():
            if p.stamp in index:
                final[index[p.stamp]] = p.pose
    for p in graph.trajectory():
        if p.stamp in index:
            final[index[p.stamp]] = p.pose
    seconds = time.perf_counter() - start - cov_seconds
    return OfflineResult(
        final, online, covariances, seconds, dict(graph.counts), dict(graph.factor_counts), dict(graph.longest_gated_s)
    )
