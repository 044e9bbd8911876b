"""The VO's covariance calibration record: per-axis variance scales (ROS order x y z rx ry rz) that make one VO's
frame-to-frame covariances consistent on a corpus split, with the VO settings it was measured with and how.

A calibration belongs to the VO it measured, so it lives with that VO: in a PROBE model's card (``vo_calibration``
of ``model.yaml``: the VO with that model) or, for the VO with its default noise, in a file of its own
(``calibration/default_vo.yaml`` of this package, `DEFAULT_VO_CALIBRATION`). Both hold the same ``vo_calibration``
entry. The fusion takes the scales as ``inputs.vo.covariance_scale``; a graph running another VO (other settings
than the recorded ones) can tell, with `differing_settings`, that the record is not its VO's."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from .vo import VOConfig, flatten, from_flat

#: The shipped calibration of the VO with its default noise (no PROBE model), by name.
DEFAULT_VO_CALIBRATION = "default_vo"
#: A VO setting a calibration record does not compare: the PROBE model is the record's home (its card) or absent.
MODEL_SETTING = "probe.model"


@dataclass(frozen=True)
class VOCalibration:
    """``covariance_scale`` (6,): variance scales x y z rx ry rz (ROS order) for the VO's frame-to-frame covariances;
    ``vo_settings``: every VO setting (dotted names, as `pvo_frontend.vo.flatten` gives them) of the VO it measured,
    empty where the record predates them; ``source``: the file it was read from."""

    covariance_scale: tuple[float, ...]
    source: Path
    vo_settings: dict[str, Any] = field(default_factory=dict)


def shipped_calibration_path(name: str = DEFAULT_VO_CALIBRATION) -> Path:
    """The installed record ``name`` (share/pvo_frontend/calibration/NAME.yaml), or the source tree's."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        return Path(get_package_share_directory("pvo_frontend")) / "calibration" / f"{name}.yaml"
    except (PackageNotFoundError, ValueError):
        return Path(__file__).resolve().parents[1] / "calibration" / f"{name}.yaml"


def resolve_calibration(name: str) -> Path:
    """A record file: the shipped ``default_vo`` (unless a local path of that name exists), or a path."""
    if name == DEFAULT_VO_CALIBRATION and not Path(name).exists():
        return shipped_calibration_path(name)
    return Path(name).expanduser()


def read_vo_calibration(path: Path) -> VOCalibration | None:
    """The ``vo_calibration`` entry of the YAML file ``path`` (a PROBE card or a record of its own); None when the
    file has none. A missing or unreadable file or a malformed entry is a ValueError naming the file."""
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a readable VO calibration ({exc})") from None
    entry = document.get("vo_calibration") if isinstance(document, dict) else None
    if entry is None:
        return None
    scale = entry.get("covariance_scale") if isinstance(entry, dict) else None
    try:
        values = tuple(float(v) for v in scale)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        values = ()
    if len(values) != 6 or not all(np.isfinite(values)) or min(values) <= 0.0:
        raise ValueError(f"{path}: vo_calibration.covariance_scale must be 6 positive numbers, got {scale!r}")
    settings = entry.get("vo_settings") or {}
    if not isinstance(settings, dict):
        raise ValueError(f"{path}: vo_calibration.vo_settings must be a mapping of VO settings, got {settings!r}")
    return VOCalibration(values, path, dict(settings))


def write_vo_calibration(path: Path, entry: dict[str, Any]) -> Path:
    """Record ``entry`` (``covariance_scale``, the VO's settings, how it was measured) as the ``vo_calibration`` of
    the YAML file ``path``, created if missing, every other field of it kept; what was written must read back."""
    path = Path(path)
    document: dict[str, Any] = {}
    if path.exists():
        loaded = yaml.safe_load(path.read_text()) or {}
        if not isinstance(loaded, dict):
            raise ValueError(f"{path}: not a YAML mapping; not overwritten")
        document = loaded
    previous = document.get("vo_calibration")
    document["vo_calibration"] = entry
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(yaml.safe_dump(document, sort_keys=False, width=120, allow_unicode=True))
    try:
        read_vo_calibration(path)
    except ValueError:
        if previous is None:
            document.pop("vo_calibration")
        else:
            document["vo_calibration"] = previous
        path.write_text(yaml.safe_dump(document, sort_keys=False, width=120, allow_unicode=True))
        raise
    return path


def recorded_settings(config: VOConfig) -> dict[str, Any]:
    """Every setting of the VO ``config`` as a record keeps it (dotted names, lists for tuples), the PROBE model
    left out (`MODEL_SETTING`: the record's home says which model, if any)."""
    return {name: value for name, value in flatten(config).items() if name != MODEL_SETTING}


def differing_settings(calibration: VOCalibration, vo: dict[str, Any]) -> dict[str, tuple[Any, Any]]:
    """The settings (dotted name → (recorded, the graph's)) where the VO a graph runs — ``vo``, its settings over
    the defaults, as a node's parameters — is not the one ``calibration`` measured; empty when it is (or when the
    record predates recorded settings). A recorded name this VO does not have differs too (graph's value None)."""
    if not calibration.vo_settings:
        return {}
    running = recorded_settings(from_flat({k: v for k, v in vo.items() if k != MODEL_SETTING}))
    differ = {}
    for name, recorded in calibration.vo_settings.items():
        if name == MODEL_SETTING:
            continue
        value = running.get(name)
        if _normalised(recorded) != _normalised(value):
            differ[name] = (recorded, value)
    return differ


def _normalised(value: Any) -> Any:
    """Lists and tuples alike, numbers compared as floats (YAML reads 1 and 1.0 differently)."""
    if isinstance(value, (list, tuple)):
        return [_normalised(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, str):
        return value
    if isinstance(value, (int, float)):
        return float(value)
    return value
