"""What can be saved of a damaged MCAP recording (`pvo bag recover`).

A recording cut off (power lost, the recorder killed, the disk full) ends inside a chunk and has neither the MCAP
summary section nor rosbag2's ``metadata.yaml``; a corrupted chunk fails its checksum. A reader that starts from the
summary refuses the whole file, though every chunk written before the damage is intact: the MCAP data section carries
each Schema and Channel record before the first Message that uses it. :func:`scan_mcap` walks the data section in
file order, keeps every record of every good chunk, the complete records at the head of a chunk cut off (zstd
decompresses a truncated frame up to its last whole block), skips a chunk that does not decompress or fails its
CRC, and names each loss; :func:`recover_bag` writes what it kept into a new bag (its own ``metadata.yaml``, chunk
CRCs), leaving the damaged one untouched.

Record layouts: the MCAP specification (https://mcap.dev/spec), all integers little-endian.
"""

from __future__ import annotations

import mmap
import re
import struct
from binascii import crc32
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from .errors import BagError
from .mcapcheck import MAGIC, OP_CHUNK, OP_FOOTER, chunk_at, decompress

OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_DATA_END = 0x0F
RECORD_HEADER = 9  # opcode (1) + content length (8)


@dataclass(frozen=True)
class Schema:
    name: str  # the message type, e.g. sensor_msgs/msg/Image
    encoding: str  # ros2msg or ros2idl
    data: str  # the definition, its dependencies appended


@dataclass(frozen=True)
class Channel:
    topic: str
    schema_id: int
    message_encoding: str  # cdr
    metadata: dict[str, str]  # rosbag2: offered_qos_profiles, topic_type_hash when the recorder wrote it


@dataclass(frozen=True)
class Message:
    channel_id: int
    log_time_ns: int
    data: bytes


@dataclass
class McapScan:
    """What :func:`scan_mcap` found; ``problems`` names every loss, one line each."""

    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    chunks_read: int = 0
    chunks_partial: int = 0
    problems: list[str] = field(default_factory=list)


class _Reader:
    """Little-endian fields from a buffer, raising ValueError where a field runs past its end."""

    def __init__(self, buffer: bytes | memoryview, pos: int = 0, end: int | None = None) -> None:
        self.buffer = buffer
        self.pos = pos
        self.end = len(buffer) if end is None else end

    def take(self, size: int) -> bytes:
        if self.pos + size > self.end:
            raise ValueError(f"a field of {size} bytes at offset {self.pos} runs past its record")
        value = bytes(self.buffer[self.pos : self.pos + size])
        self.pos += size
        return value

    def uint(self, fmt: str) -> int:
        return struct.unpack(fmt, self.take(struct.calcsize(fmt)))[0]

    def string(self) -> str:
        return self.take(self.uint("<I")).decode("utf-8")

    def string_map(self) -> dict[str, str]:
        inner = _Reader(self.buffer, self.pos + 4, self.pos + 4 + self.uint("<I"))
        self.pos = inner.end
        values = {}
        while inner.pos < inner.end:
            key = inner.string()
            values[key] = inner.string()
        return values


def _records(buffer: bytes | memoryview, start: int = 0) -> Iterator[tuple[int, int, int]]:
    """(opcode, content offset, content length) of each complete record from ``start``; stops at the footer. A
    record that runs past the end raises ValueError naming its offset."""
    pos = start
    while pos + RECORD_HEADER <= len(buffer):
        op = buffer[pos]
        (length,) = struct.unpack_from("<Q", buffer, pos + 1)
        content = pos + RECORD_HEADER
        if content + length > len(buffer):
            raise ValueError(f"record at byte {pos} (opcode 0x{op:02x}, {length} bytes) runs past the end")
        yield op, content, length
        if op == OP_FOOTER:
            return
        pos = content + length
    if pos != len(buffer):
        raise ValueError(f"{len(buffer) - pos} stray bytes at byte {pos}")


def _data_records(buffer: bytes | memoryview, scan: McapScan, where: str, partial: bool) -> Iterator[Message]:
    """Schema, Channel and Message records of a chunk's records (or the file's unchunked ones); ``partial``: the
    buffer is the head of a chunk cut off, so a record running past its end is the cut, not damage."""
    count = 0
    try:
        for op, content, length in _records(buffer):
            fields = _Reader(buffer, content, content + length)
            if op == OP_SCHEMA:
                schema_id = fields.uint("<H")
                scan.schemas[schema_id] = Schema(fields.string(), fields.string(), fields.take(fields.uint("<I")).decode())
            elif op == OP_CHANNEL:
                channel_id = fields.uint("<H")
                schema_id = fields.uint("<H")
                topic = fields.string()
                scan.channels[channel_id] = Channel(topic, schema_id, fields.string(), fields.string_map())
            elif op == OP_MESSAGE:
                channel_id = fields.uint("<H")
                fields.uint("<I")  # sequence
                log_time = fields.uint("<Q")
                fields.uint("<Q")  # publish time
                count += 1
                yield Message(channel_id, log_time, bytes(buffer[fields.pos : content + length]))
    except (ValueError, UnicodeDecodeError) as error:
        if not partial:
            scan.problems.append(f"{where}: {error}; its messages after the {count} read are dropped")


def scan_mcap(path: Path) -> tuple[McapScan, Iterator[Message]]:
    """The records of one MCAP file that can be read, in file order. The scan's schemas and channels grow as the
    iterator runs (each comes before the messages that use it); its problems are complete once it is exhausted."""
    scan = McapScan()
    return scan, _scan_messages(path, scan)


def _scan_messages(path: Path, scan: McapScan) -> Iterator[Message]:
    with path.open("rb") as handle:
        size = path.stat().st_size
        if size < len(MAGIC):
            scan.problems.append(f"{path}: {size} bytes, not an MCAP file")
            return
        data = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
        try:
            if data[: len(MAGIC)] != MAGIC:
                scan.problems.append(f"{path}: not an MCAP file (bad magic)")
                return
            pos = len(MAGIC)
            ended = False
            chunk_index = -1
            while pos + RECORD_HEADER <= size and not ended:
                op = data[pos]
                (length,) = struct.unpack_from("<Q", data, pos + 1)
                content = pos + RECORD_HEADER
                cut = content + length > size
                if op in (OP_DATA_END, OP_FOOTER):
                    ended = True
                elif op == OP_CHUNK:
                    chunk_index += 1
                    yield from _chunk_messages(path, data, scan, chunk_index, pos, cut)
                elif op in (OP_SCHEMA, OP_CHANNEL, OP_MESSAGE) and not cut:
                    yield from _data_records(data[pos : content + length], scan, f"{path}: byte {pos}", partial=False)
                if cut:
                    record = f"chunk {chunk_index}" if op == OP_CHUNK else f"a record (opcode 0x{op:02x})"
                    scan.problems.append(
                        f"{path}: truncated at byte {size}, inside {record} of bytes {pos}-{content + length}: "
                        "the rest of it is lost"
                    )
                    return
                pos = content + length
            if not ended:
                scan.problems.append(f"{path}: ends at byte {size} without its data-end record (truncated)")
        finally:
            data.close()


def _chunk_messages(path: Path, data: mmap.mmap, scan: McapScan, index: int, pos: int, cut: bool) -> Iterator[Message]:
    try:
        chunk = chunk_at(data, pos, index)
    except (struct.error, UnicodeDecodeError):
        scan.problems.append(f"{path}: chunk {index} at byte {pos}: its header is cut off")
        return
    where = f"{path}: chunk {index} (byte {pos}, messages {chunk.start_ns * 1e-9:.3f}-{chunk.end_ns * 1e-9:.3f} s)"
    raw = bytes(data[chunk.data_offset : chunk.data_offset + chunk.compressed_size])
    try:
        records = decompress(chunk.compression, raw, partial=cut)
    except Exception as error:  # noqa: BLE001 - every decoder error means a chunk that cannot be read
        scan.problems.append(f"{where}: does not decompress ({type(error).__name__}); its messages are dropped")
        return
    if cut:
        scan.chunks_partial += 1
        yield from _data_records(records, scan, where, partial=True)
        return
    if len(records) != chunk.uncompressed_size:
        scan.problems.append(f"{where}: {len(records)} bytes decompressed, {chunk.uncompressed_size} recorded; dropped")
        return
    if chunk.crc and crc32(records) != chunk.crc:
        scan.problems.append(f"{where}: checksum mismatch (corrupted); its messages are dropped")
        return
    scan.chunks_read += 1
    yield from _data_records(records, scan, where, partial=False)


def mcap_files(source: Path) -> list[Path]:
    """The MCAP files of a bag directory in recording order (``name_0.mcap``, ``name_1.mcap``, …), or the one file."""
    if source.is_file():
        return [source]
    if not source.is_dir():
        raise BagError(f"{source}: no such bag or MCAP file")

    def order(path: Path) -> tuple[int, str]:
        match = re.search(r"_(\d+)\.mcap$", path.name)
        return (int(match.group(1)) if match else -1, path.name)

    files = sorted(source.glob("*.mcap"), key=order)
    if not files:
        raise BagError(f"{source}: no .mcap file to recover (a sqlite3 bag is recovered by sqlite3's own .recover)")
    return files


@dataclass(frozen=True)
class Recovery:
    """What :func:`recover_bag` wrote: messages per topic, their time span, the chunks read whole and in part, and
    one line per loss."""

    out: Path
    messages: dict[str, int]
    start_ns: int | None
    end_ns: int | None
    chunks_read: int
    chunks_partial: int
    problems: list[str]

    def lines(self) -> list[str]:
        total = sum(self.messages.values())
        span = (
            f", {self.start_ns * 1e-9:.3f}-{self.end_ns * 1e-9:.3f} s"
            if self.start_ns is not None and self.end_ns is not None
            else ""
        )
        partial = f" and the complete messages of {self.chunks_partial} cut off" if self.chunks_partial else ""
        lines = [f"recovered {total} messages on {len(self.messages)} topics{span} into {self.out}"]
        lines.append(f"  from {self.chunks_read} whole chunks{partial}")
        lines += [f"  {topic}: {count}" for topic, count in sorted(self.messages.items())]
        lines += [f"  lost: {problem}" for problem in self.problems]
        return lines


def _rihs01(channel: Channel, schema: Schema) -> str:
    """The type hash rosbag2 keeps per topic: the recorder's own where it wrote one, else computed from the definition
    the file carries."""
    recorded = channel.metadata.get("topic_type_hash", "")
    if recorded.startswith("RIHS01_"):
        return recorded
    from rosbags.typesys import Stores, get_types_from_idl, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    parse = get_types_from_idl if schema.encoding == "ros2idl" else get_types_from_msg
    store.register(parse(schema.data, schema.name))
    return store.hash_rihs01(schema.name)


def recover_bag(source: Path, out: Path, overwrite: bool = False, storage: str = "mcap") -> Recovery:
    """Every message of ``source`` (a bag directory, with or without metadata.yaml, or one .mcap file) that can still
    be read, written into a new bag ``out``; ``source`` is left as it is. Raises BagError when nothing can be saved."""
    from rosbags.rosbag2.metadata import parse_qos

    from .bagio import SafeBagWriter

    files = mcap_files(source)
    if out.resolve() == source.resolve() or source.resolve() in out.resolve().parents:
        raise BagError(f"{out}: the recovered bag must go beside {source}, not replace it or inside it")
    counts: dict[str, int] = {}
    problems: list[str] = []
    chunks_read = chunks_partial = 0
    first: int | None = None
    last: int | None = None
    writer = SafeBagWriter(out, storage=storage, overwrite=overwrite)
    try:
        for path in files:
            scan, messages = scan_mcap(path)
            topics: dict[int, str] = {}  # channel ids are the file's own
            unusable: set[int] = set()
            for message in messages:
                topic = topics.get(message.channel_id)
                if topic is None:
                    if message.channel_id in unusable:
                        continue
                    channel = scan.channels.get(message.channel_id)
                    schema = None if channel is None else scan.schemas.get(channel.schema_id)
                    if channel is None or schema is None:
                        unusable.add(message.channel_id)
                        missing = "channel" if channel is None else f"schema {channel.schema_id} of {channel.topic}"
                        problems.append(f"{path}: messages of channel {message.channel_id}: its {missing} was never read")
                        continue
                    try:
                        writer.add_recorded_topic(
                            channel.topic,
                            schema.name,
                            schema.data,
                            _rihs01(channel, schema),
                            parse_qos(channel.metadata.get("offered_qos_profiles", "") or "[]"),
                            channel.message_encoding,
                        )
                    except Exception as error:  # noqa: BLE001 - a definition rosbags cannot parse: that topic only
                        unusable.add(message.channel_id)
                        problems.append(f"{path}: {channel.topic} ({schema.name}): definition unreadable: {error}")
                        continue
                    topic = topics[message.channel_id] = channel.topic
                writer.write_raw(topic, message.log_time_ns, message.data)
                counts[topic] = counts.get(topic, 0) + 1
                first = message.log_time_ns if first is None else min(first, message.log_time_ns)
                last = message.log_time_ns if last is None else max(last, message.log_time_ns)
            chunks_read += scan.chunks_read
            chunks_partial += scan.chunks_partial
            problems += scan.problems
        if not counts:
            raise BagError(f"{source}: no message could be recovered" + (f" ({problems[0]})" if problems else ""))
        writer.close()
    except BaseException:
        writer.abort()
        raise
    return Recovery(out, counts, first, last, chunks_read, chunks_partial, problems)
