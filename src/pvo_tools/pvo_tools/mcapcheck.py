"""Chunk checksums of MCAP files: written into the bags pvo makes, verified when a bag is read.

rosbags writes MCAP chunks with CRC 0 (no checksum) and zstd frames without their own checksum, so a
corrupted chunk decompresses into different messages without any error. :func:`add_chunk_crcs` fills in
each chunk's CRC-32 of its uncompressed records (MCAP spec, Chunk record field ``uncompressed_crc``);
rosbags' reader then verifies it, and :func:`verify_chunks` names the chunk that is bad.
"""

from __future__ import annotations

import mmap
import struct
from binascii import crc32
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

MAGIC = b"\x89MCAP0\r\n"
OP_CHUNK = 0x06
OP_FOOTER = 0x02
CRC_OFFSET = 9 + 24  # opcode (1) + length (8), then start, end, uncompressed size (3 x 8)


@dataclass(frozen=True)
class Chunk:
    index: int
    offset: int  # of the record in the file
    start_ns: int
    end_ns: int
    uncompressed_size: int
    crc: int
    compression: str
    data_offset: int
    compressed_size: int


def _chunks(data: bytes) -> Iterator[Chunk]:
    if not data.startswith(MAGIC):
        raise ValueError("not an MCAP file (bad magic)")
    pos, index = len(MAGIC), 0
    while pos + 9 <= len(data):
        op = data[pos]
        (length,) = struct.unpack_from("<Q", data, pos + 1)
        content = pos + 9
        if content + length > len(data):
            raise ValueError(f"record at byte {pos} runs past the end of the file (truncated)")
        if op == OP_CHUNK:
            yield chunk_at(data, pos, index)
            index += 1
        elif op == OP_FOOTER:
            return
        pos = content + length


def chunk_at(data: bytes | mmap.mmap, pos: int, index: int) -> Chunk:
    """The header of the Chunk record at byte ``pos`` (the ``index``-th chunk); struct.error or
    UnicodeDecodeError where the header itself is cut off or garbled."""
    content = pos + 9
    start, end, size, crc = struct.unpack_from("<QQQI", data, content)
    (name_length,) = struct.unpack_from("<I", data, content + 28)
    compression = bytes(data[content + 32 : content + 32 + name_length]).decode()
    (compressed_size,) = struct.unpack_from("<Q", data, content + 32 + name_length)
    return Chunk(index, pos, start, end, size, crc, compression, content + 40 + name_length, compressed_size)


def decompress(compression: str, raw: bytes, partial: bool = False) -> bytes:
    """A chunk's records from its compressed bytes; ``partial``: ``raw`` is the head of a chunk cut off, and what
    its whole blocks hold is returned (zstd, lz4 frames) instead of an error."""
    if compression == "":
        return bytes(raw)
    if compression == "zstd":
        try:
            from compression import zstd  # type: ignore[import-not-found]
        except ImportError:
            from backports import zstd  # type: ignore[no-redef]
        return zstd.ZstdDecompressor().decompress(raw) if partial else zstd.decompress(raw)
    if compression == "lz4":
        import lz4.frame  # type: ignore[import-not-found]

        return lz4.frame.LZ4FrameDecompressor().decompress(raw) if partial else lz4.frame.decompress(raw)
    raise ValueError(f"unsupported compression {compression!r}")


def _uncompressed(data: bytes, chunk: Chunk) -> bytes:
    try:
        return decompress(chunk.compression, data[chunk.data_offset : chunk.data_offset + chunk.compressed_size])
    except ValueError as error:
        raise ValueError(f"chunk {chunk.index}: {error}") from None


def add_chunk_crcs(path: Path) -> int:
    """Write each chunk's CRC-32 into an MCAP file in place; returns the number of chunks."""
    data = bytearray(path.read_bytes())
    chunks = list(_chunks(bytes(data)))
    for chunk in chunks:
        struct.pack_into("<I", data, chunk.offset + CRC_OFFSET, crc32(_uncompressed(bytes(data), chunk)))
    path.write_bytes(bytes(data))
    return len(chunks)


def verify_chunks(path: Path) -> tuple[int, int, list[str]]:
    """(chunks, chunks with a checksum, one line per bad chunk naming it)."""
    data = path.read_bytes()
    problems: list[str] = []
    total = checked = 0
    try:
        for chunk in _chunks(data):
            total += 1
            span = f"bytes {chunk.offset}-{chunk.data_offset + chunk.compressed_size}"
            where = f"chunk {chunk.index} ({span}, messages {chunk.start_ns * 1e-9:.3f}-{chunk.end_ns * 1e-9:.3f} s)"
            try:
                raw = _uncompressed(data, chunk)
            except Exception as exc:  # noqa: BLE001 - every decoder error means a bad chunk
                problems.append(f"{path}: {where}: does not decompress ({type(exc).__name__})")
                continue
            if len(raw) != chunk.uncompressed_size:
                problems.append(f"{path}: {where}: {len(raw)} bytes decompressed, {chunk.uncompressed_size} recorded")
            elif chunk.crc:
                checked += 1
                if crc32(raw) != chunk.crc:
                    problems.append(f"{path}: {where}: checksum mismatch (corrupted)")
    except ValueError as exc:
        problems.append(f"{path}: {exc}")
    return total, checked, problems
