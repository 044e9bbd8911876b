"""The demo's check of the fusion node's input order: a frame reported before an earlier frame's sun message
had been handled is late; the usual order (each sun before the next frame) has none."""

from __future__ import annotations

import numpy as np
from pvo_tools.commands.demo import late_frames


def test_late_frames_from_the_handled_counts() -> None:
    stamps = np.arange(0, 60, 10)  # frames 0..5
    suns = [0, 20, 40]
    usual = {10: 1, 20: 1, 30: 2, 40: 2, 50: 3}  # each sun handled before the next frame
    assert late_frames(usual, stamps, suns) == []
    delayed = {10: 0, 20: 1, 30: 1, 40: 2, 50: 3}  # sun 0 reached the node only after frame 1; sun 20 after frame 3
    assert late_frames(delayed, stamps, suns) == [1, 3]
