"""Message types for bags (rosbags typestore) and for rclpy (generated Python classes).

Types come from rosbags' built-in ROS 2 Jazzy store plus any ``share/<pkg>/msg/<Type>.msg`` found
along ``AMENT_PREFIX_PATH`` (the project's ``pvo_msgs`` among them), so converters and the recorder
embed full definitions in the bags they write and any rosbag2 reader can decode them.
"""

from __future__ import annotations

import importlib
import os
from functools import lru_cache
from pathlib import Path
from typing import Any

from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from .errors import UnknownMessageType

#: Where the .msg files of this checkout live, used when the workspace is not built/sourced.
SOURCE_MSG_DIRS = {"pvo_msgs": Path(__file__).resolve().parents[2] / "pvo_msgs" / "msg"}


def _ament_prefixes() -> list[Path]:
    return [Path(p) for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]


def find_interface_file(type_name: str) -> Path | None:
    """The ``.msg`` file defining ``pkg/msg/Type`` (or ``pkg/Type``), or None."""
    pkg, kind, name = split_type_name(type_name)
    for prefix in _ament_prefixes():
        candidate = prefix / "share" / pkg / kind / f"{name}.{kind}"
        if candidate.is_file():
            return candidate
    source_dir = SOURCE_MSG_DIRS.get(pkg)
    if kind == "msg" and source_dir is not None and (source_dir / f"{name}.msg").is_file():
        return source_dir / f"{name}.msg"
    return None


def split_type_name(type_name: str) -> tuple[str, str, str]:
    """``('pkg', 'msg', 'Type')`` from ``pkg/msg/Type`` or ``pkg/Type``."""
    parts = type_name.strip("/").split("/")
    if len(parts) == 2:
        return parts[0], "msg", parts[1]
    if len(parts) == 3 and parts[1] in ("msg", "srv", "action"):
        return parts[0], parts[1], parts[2]
    raise UnknownMessageType(f"'{type_name}' is not a message type name (expected pkg/msg/Type)")


def normalise_type_name(type_name: str) -> str:
    pkg, kind, name = split_type_name(type_name)
    return f"{pkg}/{kind}/{name}"


@lru_cache(maxsize=1)
def project_typestore() -> Typestore:
    """The ROS 2 Jazzy typestore with the project's interfaces registered."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for type_name in ("pvo_msgs/msg/RelativePose", "pvo_msgs/msg/SunDirection"):
        ensure_type(store, type_name)
    return store


def ensure_type(store: Typestore, type_name: str) -> None:
    """Register ``type_name`` (and the types it uses) from its .msg file when the store lacks it."""
    type_name = normalise_type_name(type_name)
    if type_name in store.fielddefs:
        return
    path = find_interface_file(type_name)
    if path is None:
        raise UnknownMessageType(
            f"unknown message type '{type_name}': no installed package defines it "
            "(is the workspace built and install/setup.bash sourced?)"
        )
    types = get_types_from_msg(path.read_text(), type_name)
    store.register(types)
    for _, fielddesc in types[type_name][1]:
        for nested in _nested_type_names(fielddesc):
            ensure_type(store, nested)


def _nested_type_names(fielddesc: Any) -> list[str]:
    names: list[str] = []
    if isinstance(fielddesc, tuple):
        for item in fielddesc:
            if isinstance(item, str) and item.count("/") == 2:
                names.append(item)
            elif isinstance(item, tuple):
                names.extend(_nested_type_names(item))
    return names


def message_class(type_name: str) -> type:
    """The rclpy message class for ``pkg/msg/Type``; UnknownMessageType when not importable."""
    pkg, kind, name = split_type_name(type_name)
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
        return getattr(module, name)
    except (ImportError, AttributeError):
        raise UnknownMessageType(
            f"unknown message type '{pkg}/{kind}/{name}': its Python package is not installed "
            "(is the workspace built and install/setup.bash sourced?)"
        ) from None


def type_name_of(message_or_class: Any) -> str:
    """``pkg/msg/Type`` of an rclpy message instance or class."""
    cls = message_or_class if isinstance(message_or_class, type) else type(message_or_class)
    module = cls.__module__.split(".")
    return f"{module[0]}/{module[1]}/{cls.__name__}"
