"""The demo's replay of the fusion node's input order: before each VO frame the measurements the node reported
taking since the frame before, by kind and stamp (or, for a bare kind, each kind in its sensor's order); what it
never received and what it took after its last report are left out."""

from __future__ import annotations

import itertools

import numpy as np
from pvo_tools.pipeline import in_node_order

from pvo_fusion import RelativeMeasurement, SunMeasurement


def replayed(arrivals: dict[int, list[str]]) -> list[tuple[str, int]]:
    """(kind, stamp) of the events replayed for VO frames 10, 20, 30, suns at 0 and 20 and a rotation per frame."""
    vo = [RelativeMeasurement(s, s - 10, np.eye(4), np.eye(6)) for s in (10, 20, 30)]
    suns = [SunMeasurement(s, np.array([0.0, 0.0, 1.0]), np.eye(2)) for s in (0, 20)]
    rotations = [RelativeMeasurement(s, s - 10, np.eye(4), np.eye(6), True) for s in (10, 20, 30)]
    others = [("sun", m) for m in suns] + [("rotation", m) for m in rotations]
    return [(kind, int(m.stamp)) for kind, m in in_node_order(vo, others, arrivals)]


def test_events_follow_the_reported_arrivals() -> None:
    # rotation 10 came before frame 10 and sun 0 after it; sun 20 only after frame 30, with rotation 30 before it
    assert replayed({10: ["rotation"], 20: ["sun", "rotation"], 30: ["rotation"]}) == [
        ("rotation", 10),
        ("vo", 10),
        ("sun", 0),
        ("rotation", 20),
        ("vo", 20),
        ("rotation", 30),
        ("vo", 30),
    ]  # sun 20, taken after the last report, reached no published estimate: left out
    # the same reported with stamps
    assert replayed({10: ["rotation@10"], 20: ["sun@0", "rotation@20"], 30: ["rotation@30"]}) == replayed(
        {10: ["rotation"], 20: ["sun", "rotation"], 30: ["rotation"]}
    )


def test_a_measurement_the_node_never_received_is_left_out() -> None:
    """The sun node's first estimate was published before the fusion node subscribed: the node took sun 20 first.
    Matched by stamp, the replay skips sun 0 (by kind alone it would have fed sun 0 in sun 20's place)."""
    assert replayed({10: ["rotation@10", "sun@20"], 20: ["rotation@20"], 30: ["rotation@30", "sun@99"]}) == [
        ("rotation", 10),
        ("sun", 20),
        ("vo", 10),
        ("rotation", 20),
        ("vo", 20),
        ("rotation", 30),
        ("vo", 30),
    ]  # sun 99 is no measurement the objects made: nothing to replay


def test_corrections_replay_the_windows_a_node_published() -> None:
    """A ``dpc_net`` node that missed the VO's first transform starts its Δp windows one frame later than the
    objects would from the first frame: given the node's windows, the objects compute exactly those, each equal to
    a sensor fed only that window."""
    from types import SimpleNamespace

    from pvo_pseudosensors.dpc_net.estimator import DPCNetSensor, DPCNetSensorConfig
    from pvo_tools.pipeline import learned_corrections
    from pvo_tools.samples import StereoSample

    rng = np.random.default_rng(3)

    def image(seed: int) -> SimpleNamespace:
        pixels = np.random.default_rng(seed).integers(0, 256, (188, 620), dtype=np.uint8)
        return SimpleNamespace(encoding="mono8", height=188, width=620, step=620, data=pixels.tobytes())

    stamps = [100 * (k + 1) for k in range(12)]
    sample = StereoSample(None, {s: (image(s), image(s + 1)) for s in stamps}, None, None)  # type: ignore[arg-type]
    vo = []
    for earlier, later in itertools.pairwise(stamps):
        transform = np.eye(4)
        transform[:3, 3] = [0.01 * rng.standard_normal(), 0.0, -1.0]
        vo.append(RelativeMeasurement(later, earlier, transform, 1e-4 * np.eye(6)))
    config = DPCNetSensorConfig()
    delta = DPCNetSensor(config).delta
    from_first = learned_corrections(sample, config, vo)
    assert [(m.reference_stamp, m.stamp) for m in from_first][:2] == [
        (stamps[0], stamps[delta]),
        (stamps[delta], stamps[2 * delta]),
    ]
    node_windows = [(stamps[1], stamps[1 + delta]), (stamps[1 + delta], stamps[1 + 2 * delta])]
    replayed = learned_corrections(sample, config, vo, node_windows)
    assert [(m.reference_stamp, m.stamp) for m in replayed] == node_windows
    for m, (first, last) in zip(replayed, node_windows, strict=True):
        alone = DPCNetSensor(config)
        for stamp in (first, last):
            alone.add_images(stamp, *(np.frombuffer(side.data, np.uint8).reshape(188, 620) for side in sample.pairs[stamp]))
        correction = None
        for step in vo:
            if first < step.stamp <= last:
                correction = alone.add_vo(step.reference_stamp, step.stamp, step.transform, step.covariance)
        assert correction is not None
        np.testing.assert_allclose(m.transform, correction.transform, atol=1e-12)
        assert not np.allclose(m.transform, from_first[0].transform)  # another window, another correction
