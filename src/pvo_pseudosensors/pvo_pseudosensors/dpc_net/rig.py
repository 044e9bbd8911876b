"""The camera a DPC-Net model corrects (its rig), and the check that a sequence comes from it.

A correction is learned for one camera and one VO (thesis §6.5): applied to another lens or another calibration
it corrects an error that is not there. Training records its sequences' rig in the model card; a sequence whose
rig is known to differ is refused, one whose lens or calibration error cannot be known (no ``sim.yaml``: a real
camera) is flagged. No torch here.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

#: how far a sequence's focal length and baseline may lie outside the training range (relative)
RANGE_SLACK = 0.02
#: lens coefficients and calibration scales equal within this
VALUE_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Rig:
    """size: the images' (width, height) in px; focal_px, baseline_m: as ``calib.txt`` states them (the VO's
    belief); lens: the images' plumb-bob (k1, k2, k3), () for none; focal_scale, baseline_scale: ``calib.txt``'s
    values over the true ones (a calibration error). lens and the scales are None when unknown (a real camera:
    only a rendered sequence's ``sim.yaml`` knows them)."""

    size: tuple[int, int]
    focal_px: float
    baseline_m: float
    lens: tuple[float, ...] | None
    focal_scale: float | None
    baseline_scale: float | None


def _lens(value: Any) -> tuple[float, ...]:
    coefficients = [float(v) for v in (value if isinstance(value, list | tuple) else [value])]
    coefficients += [0.0] * (3 - len(coefficients))
    return () if not any(coefficients) else tuple(coefficients)


def sequence_rig(root: Path) -> Rig:
    """The rig of one KITTI-layout stereo sequence (``calib.txt``, the first left image, ``sim.yaml`` if any)."""
    import yaml
    from pvo_core.errors import DataFormatError
    from pvo_core.imageio import read_image
    from pvo_core.readers.kitti import read_kitti_calibration

    root = Path(root)
    calibration = read_kitti_calibration(root / "calib.txt")
    focal = float(calibration["P0"][0, 0])
    baseline = float(-calibration["P1"][0, 3] / calibration["P1"][0, 0])
    images = sorted((root / "image_0").glob("*.png"))
    if not images:
        raise DataFormatError(root / "image_0", "no images in directory")
    shape = read_image(images[0]).shape
    lens = focal_scale = baseline_scale = None
    meta = root / "sim.yaml"
    if meta.is_file():
        degradations = (yaml.safe_load(meta.read_text()).get("config") or {}).get("degradations") or {}
        lens = _lens(degradations.get("distortion", 0.0))
        focal_scale = float(degradations.get("focal_scale", 1.0))
        baseline_scale = float(degradations.get("baseline_scale", 1.0))
    return Rig((int(shape[1]), int(shape[0])), focal, baseline, lens, focal_scale, baseline_scale)


def training_rig(rigs: Iterable[Rig]) -> dict[str, Any]:
    """What a model card records of its training sequences' rigs: the size, the ranges of focal length and
    baseline, the lens and the calibration scales (one of each; ``ValueError`` naming the disagreement if the
    sequences mix rigs — leave the other rig's sequences out)."""
    rigs = list(rigs)
    if not rigs:
        raise ValueError("no sequence to take the rig from")
    record: dict[str, Any] = {
        "size": list(rigs[0].size),
        "focal_px": [min(r.focal_px for r in rigs), max(r.focal_px for r in rigs)],
        "baseline_m": [min(r.baseline_m for r in rigs), max(r.baseline_m for r in rigs)],
    }
    for name in ("size", "lens", "focal_scale", "baseline_scale"):
        values = {tuple(v) if isinstance(v, list | tuple) else v for v in (asdict(r)[name] for r in rigs)}
        if len(values) > 1:
            raise ValueError(f"the training sequences mix rigs: {name} takes the values {sorted(map(str, values))}")
        value = values.pop()
        record[name] = list(value) if isinstance(value, tuple) else value
    return record


def rig_problems(trained: Mapping[str, Any] | None, rig: Rig, vo: str | None = None) -> tuple[list[str], list[str]]:
    """(refusals, warnings) for using a model trained on the rig ``trained`` (a card's record) on a sequence of
    ``rig``: a different image size, focal length or baseline outside the trained range, or a known different
    lens or calibration error is refused; what cannot be known (a real camera's lens) is a warning, and so is
    a VO other than the one the model learned (``vo``: the VO's signature now, :func:`.data.vo_signature`)."""
    if not trained:
        return [], ["the model card records no rig (a model trained before rig checks): its lens and calibration are unknown"]
    refusals, warnings = [], []
    if vo is not None and trained.get("vo") not in (None, vo):
        warnings.append(f"the model learned the errors of VO {trained['vo']}, this VO is {vo}: its settings changed since")
    if tuple(trained["size"]) != rig.size:
        refusals.append(f"images are {rig.size[0]}x{rig.size[1]}, the model's rig {trained['size'][0]}x{trained['size'][1]}")
    for name, value, unit in (("focal_px", rig.focal_px, "px"), ("baseline_m", rig.baseline_m, "m")):
        low, high = trained[name]
        if not low * (1 - RANGE_SLACK) <= value <= high * (1 + RANGE_SLACK):
            label = name.split("_")[0]
            refusals.append(f"calib.txt's {label} {value:.4g} {unit} is outside the trained {low:.4g}-{high:.4g} {unit}")
    if "lens" not in trained or trained["lens"] is None or rig.lens is None:
        if trained.get("lens") is None:
            described = "an unknown lens (its training images were not rendered)"
        else:
            described = (
                "no lens distortion" if not trained["lens"] else f"the lens k = {', '.join(f'{k:g}' for k in trained['lens'])}"
            )
        warnings.append(f"the lens cannot be checked: the model corrects {described}; use it only on that camera")
    elif not np.allclose(np.asarray(rig.lens or (0.0,) * 3), np.asarray(trained["lens"] or (0.0,) * 3), atol=VALUE_TOLERANCE):
        refusals.append(f"the images' lens {list(rig.lens) or 'none'} is not the model's {list(trained['lens']) or 'none'}")
    for name in ("focal_scale", "baseline_scale"):
        value, expected = getattr(rig, name), trained.get(name)
        what = f"calib.txt's {name.replace('_', ' ')} error"
        if value is None or expected is None:
            if value != expected:
                warnings.append(f"{what} cannot be checked (known for {'the model' if value is None else 'this sequence'} only)")
        elif abs(value - float(expected)) > VALUE_TOLERANCE:
            refusals.append(f"{what} is x{value:g}, the model's x{float(expected):g}")
    return refusals, warnings


def check_rig(trained: Mapping[str, Any] | None, root: Path, allow_any: bool = False) -> list[str]:
    """The warnings for using the model on the sequence at ``root``; ``ValueError`` (one line naming the model's
    rig and the sequence's) when it is another rig's, unless ``allow_any``. The VO is the one the card names
    (:func:`.data.card_vo_config`): flagged only when the card names it by a signature the defaults no longer have."""
    from .data import card_vo_config, vo_signature

    refusals, warnings = rig_problems(trained, sequence_rig(root), vo_signature(card_vo_config(trained)))
    if refusals and not allow_any:
        raise ValueError(f"{root}: not this DPC-Net model's rig: {'; '.join(refusals)} (--any-rig to use it anyway)")
    return [*refusals, *warnings]
