"""The stereo_vo node's frame ledger: frames whose camera_info arrived but whose pair never did."""

from __future__ import annotations

from pvo_frontend.stereo_vo_node import FrameLedger


def test_a_frame_without_its_pair_is_counted_when_a_later_pair_arrives() -> None:
    ledger = FrameLedger()
    assert ledger.announce(1) == [] and ledger.arrived(1) == []
    assert ledger.announce(2) == [] and ledger.announce(3) == []
    assert ledger.arrived(3) == [2]


def test_a_late_camera_info_is_counted_until_its_pair_turns_up() -> None:
    ledger = FrameLedger()
    for stamp in (1, 2, 5):
        ledger.announce(stamp)
        ledger.arrived(stamp)
    assert ledger.announce(4) == [4]  # after the pair of 5: as things stand it can never be processed
    assert ledger.recover(3) is False
    assert ledger.recover(4) is True and ledger.recover(4) is False  # the pair of 4 came after all, once
    assert ledger.announce(2) == []  # a pair that arrived is never missing, whatever the order
