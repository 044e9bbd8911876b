"""Bags that pvo writes are safe (issue 18, defects 4, 6 and 10): chunk checksums catch corruption and name
the chunk; --overwrite never deletes what is not a bag; a killed conversion leaves nothing behind, and what
an earlier killed run left is removed."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pvo_tools.baginfo import bag_info
from pvo_tools.bagio import SafeBagWriter, check_output_path, iter_messages, open_bag
from pvo_tools.errors import BagError
from pvo_tools.typesys import project_typestore


def write_images(path: Path, frames: int = 120) -> None:
    types = project_typestore().types
    rng = np.random.default_rng(0)
    with SafeBagWriter(path) as writer:
        writer.add_topic("/camera", "sensor_msgs/msg/Image")
        for k in range(frames):
            stamp = 1_000_000_000 + k * 100_000_000
            header = types["std_msgs/msg/Header"](
                stamp=types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id="c"
            )
            pixels = rng.integers(0, 255, 64 * 1024, dtype=np.uint8)
            image = types["sensor_msgs/msg/Image"](
                header=header, height=256, width=256, encoding="mono8", is_bigendian=0, step=256, data=pixels
            )
            writer.write("/camera", stamp, image)


def test_a_corrupted_chunk_is_found_and_named(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    write_images(bag)
    info = bag_info(bag)
    assert info.integrity.endswith("chunks verified") and not info.integrity.startswith("0 ")
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4096] = bytes(4096)
    mcap.write_bytes(bytes(data))
    with pytest.raises(
        BagError, match=r"chunk \d+ \(bytes \d+-\d+, messages [\d.]+-[\d.]+ s\): (checksum mismatch|does not decompress)"
    ):
        bag_info(bag)
    with pytest.raises(BagError, match=r"chunk \d+"), open_bag(bag) as reader:
        for _ in iter_messages(reader):
            pass


def test_overwrite_replaces_a_bag_or_an_empty_directory_and_nothing_else(tmp_path: Path) -> None:
    precious = tmp_path / "thesis"
    precious.mkdir()
    (precious / "chapter1.tex").write_text("years of work")
    with pytest.raises(BagError, match="not a rosbag2 bag .* refusing to replace it, even with --overwrite"):
        check_output_path(precious, overwrite=True)
    with pytest.raises(BagError, match="not a rosbag2 bag"):
        SafeBagWriter(precious, overwrite=True)
    assert (precious / "chapter1.tex").read_text() == "years of work"
    (tmp_path / "empty").mkdir()
    check_output_path(tmp_path / "empty", overwrite=True)
    write_images(tmp_path / "bag", frames=3)
    check_output_path(tmp_path / "bag", overwrite=True)
    with pytest.raises(BagError, match="output exists; pass --overwrite"):
        check_output_path(tmp_path / "bag", overwrite=False)


def test_sigterm_during_a_conversion_leaves_nothing_and_a_later_run_removes_stale_partials(
    pvo_data: Path, tmp_path: Path
) -> None:
    out = tmp_path / "bag"
    stale = tmp_path / ".bag.partial-999999999-deadbeef"  # a pid that cannot exist
    (stale / "bag").mkdir(parents=True)
    command = [sys.executable, "-m", "pvo_tools.cli", "convert", "kitti", str(pvo_data / "kitti/sequences/06"), "--out", str(out)]
    proc = subprocess.Popen([*command, "--rate", "10", "-q"], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not list(tmp_path.glob(f".bag.partial-{proc.pid}-*")):
        time.sleep(0.05)
    assert list(tmp_path.glob(f".bag.partial-{proc.pid}-*")), "the conversion never started writing"
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "pvo: interrupted" in err, err[-3000:]
    assert f"removed {stale}" in err  # the earlier run's leftover, reported
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no bag, no partial, nothing stale
