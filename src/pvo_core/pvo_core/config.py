"""Typed configuration helpers shared by every node: frozen dataclasses <-> dotted ROS parameter names.

A node declares one ROS parameter per leaf field of its config dataclass, named by the dotted path
(``detector.bucket_size``, ``inputs.sun.huber_k`` ...); :func:`flatten` lists them with their defaults
and :func:`from_flat` builds the typed config back, checking names and types.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

C = TypeVar("C")


def flatten(config: Any, prefix: str = "") -> dict[str, Any]:
    """``{"section.leaf": value, ...}`` for a (nested) config dataclass; tuples become lists."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        name = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(value):
            out.update(flatten(value, name + "."))
        else:
            out[name] = list(value) if isinstance(value, tuple) else value
    return out


def parse_assignments(items: Iterable[str]) -> dict[str, Any]:
    """``{"name": value}`` from ``NAME=VALUE`` items (command-line overrides), each value read as YAML (``3`` an
    int, ``[1, 2]`` a list, ``''`` the empty string); ``ValueError`` naming an item that is not ``NAME=VALUE``."""
    import yaml

    values: dict[str, Any] = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"{item!r} must be NAME=VALUE, e.g. solver.loss=huber")
        values[name.strip()] = yaml.safe_load(text)
    return values


def _coerce(name: str, value: Any, default: Any, what: str) -> Any:
    if isinstance(default, list):
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            raise ValueError(f"{what} parameter {name} must be a list, got {value!r}")
        items = list(value)
        if default and isinstance(default[0], str):
            return tuple(str(v) for v in items)
        try:
            return tuple(float(v) for v in items)
        except (TypeError, ValueError):
            raise ValueError(f"{what} parameter {name} must be a list of numbers, got {value!r}") from None
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{what} parameter {name} must be a boolean, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or int(value) != value:
            raise ValueError(f"{what} parameter {name} must be an integer, got {value!r}")
        return int(value)
    if isinstance(default, float):
        # YAML 1.1 reads "1e-5" (no dot) as a string: accept any text that is a number.
        if isinstance(value, str):
            try:
                return float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{what} parameter {name} must be a number, got {value!r}")
        return float(value)
    if isinstance(default, str):
        if not isinstance(value, str):
            raise ValueError(f"{what} parameter {name} must be a string, got {value!r}")
    return value


def from_flat(values: Mapping[str, Any], base: C, what: str = "configuration") -> C:
    """``base`` with the dotted ``values`` applied; unknown names and wrong types raise ``ValueError``.

    Validation in the dataclasses' ``__post_init__`` runs on the result, so an out-of-range value also
    raises ``ValueError`` naming the parameter.
    """
    known = flatten(base)
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ValueError(f"unknown {what} parameter(s): {', '.join(unknown)}")
    # Leaves are applied innermost-first through plain replace, then the whole tree is rebuilt once
    # so that cross-field validation sees the final values only.
    fields: dict[str, Any] = {name: _coerce(name, value, known[name], what) for name, value in values.items()}
    raw = _unvalidated_tree(base)
    for name, value in fields.items():
        _set_path(raw, name.split("."), value)
    return _build(type(base), raw)


def _unvalidated_tree(config: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in dataclasses.fields(config):
        value = getattr(config, f.name)
        out[f.name] = (type(value), _unvalidated_tree(value)) if dataclasses.is_dataclass(value) else value
    return out


def _set_path(tree: dict[str, Any], path: list[str], value: Any) -> None:
    node = tree
    for part in path[:-1]:
        node = node[part][1]
    node[path[-1]] = value


def _build(cls: type, tree: dict[str, Any]) -> Any:
    kwargs = {
        k: _build(v[0], v[1]) if isinstance(v, tuple) and len(v) == 2 and isinstance(v[0], type) else v for k, v in tree.items()
    }
    return cls(**kwargs)
