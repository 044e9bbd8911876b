"""Reading and writing rosbag2 (MCAP or sqlite3) with rosbags, safely.

- :class:`SafeBagWriter` writes into a hidden temporary directory beside the target and renames it
  into place only when writing finished: an interrupted conversion leaves no half-written bag.
- :func:`open_bag` turns every way a bag can be broken into one :class:`BagError` line.
"""

from __future__ import annotations

import os
import shutil
import sys
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode, StoragePlugin

from .errors import BagError
from .mcapcheck import add_chunk_crcs, verify_chunks
from .typesys import ensure_type, project_typestore

STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}


def check_output_path(path: Path, overwrite: bool) -> None:
    """Refuse to replace an existing path unless ``overwrite``, and even then anything but a bag or an empty
    directory (``--overwrite`` must never delete a user's directory recursively)."""
    if not path.exists():
        return
    if not overwrite:
        raise BagError(f"{path}: output exists; pass --overwrite to replace it")
    if path.is_dir() and not any(path.iterdir()):
        return
    if not (path.is_dir() and (path / "metadata.yaml").is_file()):
        raise BagError(
            f"{path}: exists and is not a rosbag2 bag (no metadata.yaml); refusing to replace it, even with --overwrite"
        )


PARTIAL = ".{name}.partial-"


def stale_partials(path: Path) -> list[Path]:
    """The hidden ``.<name>.partial-<pid>-*`` directories that earlier runs for ``path`` left when they were killed
    (their process is gone)."""
    stale = []
    for candidate in sorted(path.parent.glob(PARTIAL.format(name=path.name) + "*")):
        pid_text = candidate.name.rsplit(".partial-", 1)[1].split("-", 1)[0]
        alive = pid_text.isdigit() and _process_alive(int(pid_text))
        if candidate.is_dir() and not alive:
            stale.append(candidate)
    return stale


def _process_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class SafeBagWriter:
    """A rosbag2 writer that only makes ``path`` appear once :meth:`close` succeeds.

    Args:
        path: the bag directory to create.
        storage: ``mcap`` (zstd-compressed chunks) or ``sqlite3``.
        overwrite: replace an existing ``path``.
        compress: zstd chunk compression (MCAP) / per-storage compression.
        keep_interrupted: what a killed earlier run for ``path`` left is kept and named, not removed: a recording
            cannot be made again (a conversion can), and `pvo bag recover` saves what it holds.
    """

    def __init__(
        self,
        path: str | Path,
        storage: str = "mcap",
        overwrite: bool = False,
        compress: bool = True,
        keep_interrupted: bool = False,
    ):
        self.path = Path(path)
        if storage not in STORAGES:
            raise BagError(f"unknown storage '{storage}'; use one of {sorted(STORAGES)}")
        check_output_path(self.path, overwrite)
        self.overwrite = overwrite
        self.typestore = project_typestore()
        for stale in stale_partials(self.path):
            if keep_interrupted:
                left = stale / self.path.name
                saves = (
                    f"`pvo bag recover {left} -o NEW` saves what it holds"
                    if any(left.glob("*.mcap"))
                    else "its storage file holds what was written"
                )
                print(f"pvo: an earlier recording to {self.path} was cut off and left {left}: {saves}", file=sys.stderr)
            else:
                shutil.rmtree(stale, ignore_errors=True)
                print(f"pvo: removed {stale}, left by an interrupted earlier run", file=sys.stderr)
        # The bag is written as <hidden dir>/<name> so its storage file gets its final name; the pid in the
        # name tells a later run whether the writer is still alive.
        self._tmp_parent = self.path.parent / (PARTIAL.format(name=self.path.name) + f"{os.getpid()}-{uuid.uuid4().hex[:8]}")
        self._tmp_parent.mkdir(parents=True)
        self._tmp = self._tmp_parent / self.path.name
        try:
            self._writer = Writer(self._tmp, version=9, storage_plugin=STORAGES[storage])
            if compress and storage == "mcap":
                self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._writer.open()
        except BaseException:  # an interrupt before the with-block is entered must not leave the partial behind
            shutil.rmtree(self._tmp_parent, ignore_errors=True)
            raise
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}
        self._closed = False

    def add_topic(self, topic: str, type_name: str) -> Connection:
        """Register a topic; the type definition is embedded in the bag."""
        if topic in self._connections:
            return self._connections[topic]
        ensure_type(self.typestore, type_name)
        connection = self._writer.add_connection(topic, type_name, typestore=self.typestore)
        self._connections[topic] = connection
        self.counts[topic] = 0
        return connection

    def add_recorded_topic(
        self,
        topic: str,
        type_name: str,
        definition: str,
        type_hash: str,
        qos: list[Any],
        serialization_format: str = "cdr",
    ) -> Connection:
        """Register a topic with the definition and type hash a recording carried, so types no package here defines
        keep theirs (`pvo bag recover`)."""
        if topic in self._connections:
            return self._connections[topic]
        connection = self._writer.add_connection(
            topic,
            type_name,
            msgdef=definition,
            rihs01=type_hash,
            serialization_format=serialization_format,
            offered_qos_profiles=qos,
        )
        self._connections[topic] = connection
        self.counts[topic] = 0
        return connection

    def write(self, topic: str, stamp_ns: int, message: Any) -> None:
        """Serialise a rosbags message object to CDR and write it."""
        connection = self._connections[topic]
        data = self.typestore.serialize_cdr(message, connection.msgtype)
        self.write_raw(topic, stamp_ns, data)

    def write_raw(self, topic: str, stamp_ns: int, data: bytes | memoryview) -> None:
        self._writer.write(self._connections[topic], int(stamp_ns), data)
        self.counts[topic] += 1

    def close(self) -> None:
        """Finish the bag and move it into place."""
        if self._closed:
            return
        self._writer.close()
        self._closed = True
        for mcap in self._tmp.glob("*.mcap"):
            add_chunk_crcs(mcap)  # readers can then tell a corrupted chunk from a good one
        if self.path.exists():
            if not self.overwrite:
                shutil.rmtree(self._tmp_parent, ignore_errors=True)
                raise BagError(f"{self.path}: output appeared while writing; not replaced")
            shutil.rmtree(self.path) if self.path.is_dir() else self.path.unlink()
        self._tmp.rename(self.path)
        shutil.rmtree(self._tmp_parent, ignore_errors=True)

    def abort(self) -> None:
        """Drop everything written so far."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
        except Exception:  # noqa: BLE001 - the writer may be half-open; the directory goes anyway
            pass
        shutil.rmtree(self._tmp_parent, ignore_errors=True)

    def __enter__(self) -> SafeBagWriter:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


@contextmanager
def open_bag(path: str | Path) -> Iterator[Reader]:
    """Open a rosbag2 directory for reading; every failure becomes one BagError line."""
    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such bag")
    if path.is_file():
        raise BagError(f"{path}: a rosbag2 bag is a directory with metadata.yaml; got a file")
    if not (path / "metadata.yaml").is_file():
        if any(path.glob("*.mcap")):
            raise BagError(f"{path}: no metadata.yaml beside its .mcap (a recording cut off?){_recover_hint(path)}")
        raise BagError(f"{path}: not a rosbag2 bag (no metadata.yaml)")
    reader = Reader(path)
    try:
        reader.open()
    except Exception as error:  # noqa: BLE001 - rosbags raises several types for broken bags
        raise BagError(f"{path}: cannot open bag: {_one_line(error)}{_recover_hint(path)}") from None
    try:
        yield reader
    finally:
        try:
            reader.close()
        except Exception:  # noqa: BLE001
            pass


def iter_messages(reader: Reader, connections: list[Connection] | None = None, start_ns: int | None = None):
    """Messages in time order, turning storage errors part-way into a BagError (naming a corrupted chunk)."""
    try:
        yield from reader.messages(connections=connections or (), start=start_ns)
    except BagError:
        raise
    except Exception as error:  # noqa: BLE001
        bad = [line for mcap in Path(reader.path).glob("*.mcap") for line in verify_chunks(mcap)[2]]
        hint = _recover_hint(Path(reader.path))
        if bad:
            raise BagError(bad[0] + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else "") + hint) from None
        raise BagError(f"{reader.path}: corrupt or truncated bag: {_one_line(error)}{hint}") from None


def _recover_hint(path: Path) -> str:
    """What to do about a damaged MCAP bag, for its error line ("" for other storages)."""
    return f" (`pvo bag recover {path} -o NEW` saves what can be read)" if any(path.glob("*.mcap")) else ""


def _one_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return text[0] if text else type(error).__name__
