"""`pvo bag recover`: a cut-off or corrupted MCAP recording gives back every message that can still be read, byte for
byte, and names what is lost; the damaged bag is left as it was."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
from pvo_tools.bagio import open_bag
from pvo_tools.bagrecover import recover_bag
from pvo_tools.errors import BagError
from pvo_tools.mcapcheck import _chunks
from rosbags.rosbag2 import Reader


def messages(bag: Path) -> list[tuple[str, str, str, int, bytes]]:
    """(topic, type, type hash, stamp, CDR bytes) of every message, in the reader's order."""
    with Reader(bag) as reader:
        return [(c.topic, c.msgtype, c.digest, t, bytes(raw)) for c, t, raw in reader.messages()]


def damaged_copy(bag: Path, target: Path, data: bytes) -> Path:
    target.mkdir()
    shutil.copy(bag / "metadata.yaml", target)
    (target / "kitti06_sample.mcap").write_bytes(data)
    return target


def test_a_truncated_recording_gives_back_every_complete_message(sample_bag: Path, tmp_path: Path) -> None:
    original = messages(sample_bag)
    data = (sample_bag / "kitti06_sample.mcap").read_bytes()
    cut = len(data) // 3
    truncated = damaged_copy(sample_bag, tmp_path / "truncated", data[:cut])
    before = (truncated / "kitti06_sample.mcap").read_bytes()
    with pytest.raises(BagError, match=r"pvo bag recover"):  # the reader refuses it, and says what to do
        with open_bag(truncated):
            pass
    recovery = recover_bag(truncated, tmp_path / "recovered")
    saved = messages(tmp_path / "recovered")
    # a prefix of the recording, byte for byte, with the recorded types and their hashes
    assert saved == original[: len(saved)]
    whole = [c for c in _chunks(data) if c.data_offset + c.compressed_size <= cut]
    in_whole_chunks = sum(1 for m in original if m[3] <= whole[-1].end_ns)  # at most this many
    assert len(saved) > in_whole_chunks, "the complete messages at the head of the chunk cut off are kept too"
    assert recovery.chunks_read == len(whole) and recovery.chunks_partial == 1
    assert sum(recovery.messages.values()) == len(saved)
    assert recovery.start_ns == original[0][3] and recovery.end_ns == saved[-1][3]
    assert len(recovery.problems) == 1 and f"truncated at byte {cut}, inside chunk {len(whole)}" in recovery.problems[0]
    assert (truncated / "kitti06_sample.mcap").read_bytes() == before  # the damaged bag is left alone


def test_a_corrupted_chunk_is_named_and_dropped_and_the_rest_kept(sample_bag: Path, tmp_path: Path) -> None:
    # the sample predates chunk CRCs; a copy through the recovery has them (as every bag pvo writes)
    with_crcs = tmp_path / "with_crcs"
    recover_bag(sample_bag, with_crcs)
    original = messages(with_crcs)
    assert original == messages(sample_bag)
    data = bytearray(next(with_crcs.glob("*.mcap")).read_bytes())
    chunk = list(_chunks(bytes(data)))[5]
    middle = chunk.data_offset + chunk.compressed_size // 2
    data[middle : middle + 64] = bytes(64)  # zeroed inside its compressed payload
    corrupt = damaged_copy(with_crcs, tmp_path / "corrupt", bytes(data))
    recovery = recover_bag(corrupt, tmp_path / "recovered")
    saved = messages(tmp_path / "recovered")
    assert recovery.chunks_read == 34 and recovery.chunks_partial == 0
    assert len(recovery.problems) == 1 and "chunk 5 " in recovery.problems[0]
    assert "checksum mismatch" in recovery.problems[0] or "does not decompress" in recovery.problems[0]
    kept = set(saved)
    lost = [m for m in original if m not in kept]
    assert kept <= set(original) and 0 < len(lost) < 20
    assert all(chunk.start_ns <= m[3] <= chunk.end_ns for m in lost)  # only that chunk's messages


def test_a_recording_without_metadata_and_split_files_are_recovered_in_order(sample_bag: Path, tmp_path: Path) -> None:
    """A recorder killed before it wrote metadata.yaml leaves bare .mcap files; split ones are all read."""
    data = (sample_bag / "kitti06_sample.mcap").read_bytes()
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "rec_1.mcap").write_bytes(data[: len(data) // 2])
    (bare / "rec_0.mcap").write_bytes(data)
    with pytest.raises(BagError, match=r"no metadata.yaml beside its .mcap .*pvo bag recover"):
        with open_bag(bare):
            pass
    recovery = recover_bag(bare, tmp_path / "recovered")
    saved = messages(tmp_path / "recovered")
    original = messages(sample_bag)
    assert len(saved) > len(original) and set(saved) == set(original)  # rec_0 whole, the head of rec_1 again
    assert recovery.problems and "rec_1.mcap: truncated" in recovery.problems[0]


def test_nothing_readable_is_one_line_and_leaves_no_output(sample_bag: Path, tmp_path: Path) -> None:
    garbage = damaged_copy(sample_bag, tmp_path / "garbage", b"not an mcap file at all")
    out = tmp_path / "recovered"
    with pytest.raises(BagError, match="no message could be recovered .*not an MCAP file"):
        recover_bag(garbage, out)
    assert not out.exists() and not list(tmp_path.glob(".recovered.partial-*"))
    with pytest.raises(BagError, match="not replace it or inside it"):
        recover_bag(sample_bag, sample_bag / "inside")
    with pytest.raises(BagError, match="no such bag or MCAP file"):
        recover_bag(tmp_path / "missing", out)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BagError, match="no .mcap file"):
        recover_bag(empty, out)


def test_the_command_recovers_and_reports(sample_bag: Path, tmp_path: Path) -> None:
    data = (sample_bag / "kitti06_sample.mcap").read_bytes()
    truncated = damaged_copy(sample_bag, tmp_path / "truncated", data[: len(data) // 2])
    result = subprocess.run(["pvo", "bag", "info", str(truncated)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2 and result.stderr.count("\n") == 1
    assert f"`pvo bag recover {truncated} -o NEW` saves what can be read" in result.stderr
    out = tmp_path / "recovered"
    result = subprocess.run(["pvo", "bag", "recover", str(truncated), "-o", str(out)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("recovered ") and "lost: " in result.stdout
    info = subprocess.run(["pvo", "bag", "info", str(out)], capture_output=True, text=True, timeout=60)
    assert info.returncode == 0 and "chunks verified" in info.stdout
    again = subprocess.run(["pvo", "bag", "recover", str(truncated), "-o", str(out)], capture_output=True, text=True, timeout=60)
    assert again.returncode == 2 and "output exists" in again.stderr


def test_a_type_no_package_here_defines_keeps_its_definition_and_hash(tmp_path: Path) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.rosbag2.enums import StoragePlugin
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    definition = "float64 x\nstring label\n"
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(definition, "elsewhere_msgs/msg/Thing"))
    type_hash = store.hash_rihs01("elsewhere_msgs/msg/Thing")
    bag = tmp_path / "foreign"
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection("/thing", "elsewhere_msgs/msg/Thing", msgdef=definition, rihs01=type_hash)
        message = store.types["elsewhere_msgs/msg/Thing"](x=1.5, label="a")
        for k in range(5):
            writer.write(connection, 1_000 + k, store.serialize_cdr(message, "elsewhere_msgs/msg/Thing"))
    recovery = recover_bag(bag, tmp_path / "recovered")
    assert recovery.messages == {"/thing": 5} and not recovery.problems
    with Reader(tmp_path / "recovered") as reader:
        (connection,) = reader.connections
        assert connection.msgtype == "elsewhere_msgs/msg/Thing" and connection.digest == type_hash
        assert [store.deserialize_cdr(raw, connection.msgtype).x for _, _, raw in reader.messages()] == [1.5] * 5
