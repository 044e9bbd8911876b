"""`pvo bag info` and `pvo bag trajectory`: what a bag holds, without ROS running."""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from pvo_core.msgconv import pose_to_matrix
from pvo_core.trajectory import Trajectory

from .bagio import iter_messages, open_bag
from .errors import BagError
from .mcapcheck import verify_chunks
from .typesys import ensure_type, project_typestore


@dataclass
class BagInfo:
    path: Path
    storage: str
    size_bytes: int
    start_ns: int
    end_ns: int
    message_count: int
    compression: str
    topics: list[tuple[str, str, int, str]]  # name, type, count, serialization
    integrity: str = ""

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) / 1e9 if self.message_count else 0.0

    def lines(self) -> list[str]:
        def fmt_time(ns: int) -> str:
            when = datetime.fromtimestamp(ns / 1e9, tz=UTC).strftime("%b %d %Y %H:%M:%S.%f")[:-3]
            return f"{when} UTC ({ns / 1e9:.9f})"

        out = [
            f"Files:             {self.path}",
            f"Bag size:          {self.size_bytes / 1e6:.1f} MB",
            f"Storage id:        {self.storage}",
            f"Compression:       {self.compression}",
            f"Duration:          {self.duration_s:.9f} s",
            f"Start:             {fmt_time(self.start_ns) if self.message_count else '-'}",
            f"End:               {fmt_time(self.end_ns) if self.message_count else '-'}",
            f"Messages:          {self.message_count}",
            *([f"Chunk checksums:   {self.integrity}"] if self.integrity else []),
            "Topic information:",
        ]
        width = max((len(t[0]) for t in self.topics), default=0)
        for name, type_name, count, fmt in self.topics:
            out.append(f"  Topic: {name:{width}s} | Type: {type_name} | Count: {count} | Serialization Format: {fmt}")
        return out


def bag_info(path: str | Path) -> BagInfo:
    path = Path(path)
    with open_bag(path) as reader:
        counts: dict[str, int] = {}
        for connection in reader.connections:
            counts[connection.topic] = counts.get(connection.topic, 0) + connection.msgcount
        topics = sorted({(c.topic, c.msgtype, counts[c.topic], c.ext.serialization_format) for c in reader.connections})
        storage = _storage_identifier(path)
        compression = reader.compression_format or ""
        if compression:
            compression = f"{compression} ({reader.compression_mode})"
        else:
            compression = "zstd (chunks)" if storage == "mcap" and _mcap_is_compressed(path) else "none"
        size = sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
        end = reader.end_time - 1 if reader.message_count else 0  # rosbags' end_time is exclusive
        integrity = ""
        if storage == "mcap":
            total = checked = 0
            for mcap in sorted(path.glob("*.mcap")):
                chunks, with_crc, problems = verify_chunks(mcap)
                if problems:
                    raise BagError(problems[0] + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""))
                total, checked = total + chunks, checked + with_crc
            integrity = (
                f"{checked} of {total} chunks verified"
                if checked
                else f"none recorded in {total} chunks (corruption cannot be detected)"
            )
        return BagInfo(path, storage, size, reader.start_time, end, reader.message_count, compression, list(topics), integrity)


def _storage_identifier(path: Path) -> str:
    for line in (path / "metadata.yaml").read_text().splitlines():
        key, _, value = line.strip().partition(":")
        if key == "storage_identifier":
            return value.strip().strip("'\"")
    return "?"


def _mcap_is_compressed(path: Path) -> bool:
    for file in path.glob("*.mcap"):
        with file.open("rb") as handle:
            head = handle.read(1 << 16)
        return b"zstd" in head or b"lz4" in head
    return False


def bag_trajectory(path: str | Path, topic: str = "/ground_truth/odometry") -> Trajectory:
    """The poses of an Odometry / PoseStamped / PoseWithCovarianceStamped topic, as a Trajectory."""
    path = Path(path)
    store = project_typestore()
    stamps, poses = [], []
    with open_bag(path) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            raise BagError(f"{path}: no topic {topic} in the bag")
        for connection, _, raw in iter_messages(reader, connections):
            ensure_type(store, connection.msgtype)
            msg = store.deserialize_cdr(raw, connection.msgtype)
            pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
            try:
                transform = pose_to_matrix(pose)
            except ValueError as exc:
                raise BagError(f"{path}: {topic} at {msg.header.stamp.sec}.{msg.header.stamp.nanosec:09d}: {exc}") from None
            stamps.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
            poses.append(transform)
    if not poses:
        raise BagError(f"{path}: topic {topic} holds no messages")
    return Trajectory(poses=np.asarray(poses), stamps=np.asarray(stamps))
