"""A stereo sequence, or a whole corpus, mirrored left-right: the same world seen through a mirror.

Mirroring the world by S = diag(-1, 1, 1) (the camera frame: x right, y down, z forward) turns each right turn into
a left turn of the same size. A stereo rig seen through the mirror is a stereo rig again with its cameras swapped:
the mirrored left image is the right image flipped left-right, the mirrored right image the left one flipped, and
the new left camera's pose is the old right camera's, conjugated by S: T'_k = S T_k E S with E the translation by
the baseline along x (each pose file starts at the identity, so T'_k is taken relative to T'_0). Flipping the
image is this mirror only when the principal point is the image centre, ((W - 1) / 2, (H - 1) / 2) as `pvo sim`
renders; a sequence whose calib.txt says otherwise is refused. A radial lens stays the same lens.

What mirroring keeps: images, calib.txt, times.txt, poses.txt, sun.csv (the sun's x negated) and sim.yaml (with
where the mirror came from). What it drops: imu.csv, gps.csv (a mirrored world has no place on Earth) and depth_0
(the depth of the camera that is now the right one). Training on both a corpus and its mirror makes a learned
correction symmetric in the turn direction (DPC-Net's corrections of a VO were not: issue 16).
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]
MIRROR = np.diag([-1.0, 1.0, 1.0, 1.0])
#: the condition a mirrored corpus sequence adds to its source's
MIRRORED = "mirrored left-right"
IMAGE_FOLDERS = (("image_0", "image_1"), ("image_2", "image_3"))  # (left, right), grey and colour
PRINCIPAL_POINT_TOLERANCE_PX = 1e-3


def mirrored_poses(poses: Array, baseline_m: float) -> Array:
    """The left-camera poses (N, 4, 4, camera-to-world) of a rig with stereo baseline ``baseline_m`` (m, the
    right camera at +x) as the mirrored rig's left camera — the old right camera through the mirror — sees
    them, relative to its first pose."""
    shift = np.eye(4)
    shift[0, 3] = baseline_m
    mirrored = MIRROR @ np.asarray(poses, dtype=np.float64) @ shift @ MIRROR
    return np.linalg.inv(mirrored[0]) @ mirrored


def mirrored_sun(directions: Array) -> Array:
    """Sun unit vectors (N, 3) in the camera frame, through the mirror (x negated)."""
    return np.asarray(directions, dtype=np.float64) * np.array([-1.0, 1.0, 1.0])


def _check_centred(calib: Path) -> float:
    """The baseline calib.txt states (m); ``DataFormatError`` unless its principal point is the image centre."""
    from pvo_core.errors import DataFormatError
    from pvo_core.imageio import read_image
    from pvo_core.readers.kitti import read_kitti_calibration

    projection = read_kitti_calibration(calib)
    first = sorted((calib.parent / "image_0").glob("*.png")) or sorted((calib.parent / "image_2").glob("*.png"))
    if not first:
        raise DataFormatError(calib.parent / "image_0", "no images in directory")
    height, width = read_image(first[0]).shape[:2]
    for name in ("P0", "P1"):
        cx, cy = projection[name][0, 2], projection[name][1, 2]
        if abs(cx - (width - 1) / 2) > PRINCIPAL_POINT_TOLERANCE_PX or abs(cy - (height - 1) / 2) > PRINCIPAL_POINT_TOLERANCE_PX:
            raise DataFormatError(
                calib,
                f"{name}'s principal point ({cx:g}, {cy:g}) is not the centre of the {width}x{height} images: "
                "a flipped image would not be the mirrored camera's",
            )
    return float(-projection["P1"][0, 3] / projection["P1"][0, 0])


def mirror_sequence(source: Path, out: Path, overwrite: bool = False) -> Path:
    """``source`` (a KITTI-layout stereo sequence with poses.txt) mirrored into ``out``; poses.txt is written last,
    so a folder that has it is complete. The true baseline comes from sim.yaml when the sequence was rendered (its
    calib.txt may state a wrong one on purpose), from calib.txt otherwise."""
    import cv2
    import yaml
    from pvo_core.errors import DataFormatError
    from pvo_core.trajectory import read_kitti_poses, write_kitti_poses

    source, out = Path(source), Path(out)
    if source.resolve() == out.resolve():
        raise ValueError(f"{out}: the mirror must go to another folder than its source")
    if out.exists():
        if not overwrite:
            raise FileExistsError(f"{out} exists (overwrite to replace it)")
        shutil.rmtree(out)
    for needed in ("calib.txt", "poses.txt", "times.txt"):
        if not (source / needed).is_file():
            raise DataFormatError(source / needed, "needed to mirror the sequence but missing")
    baseline = _check_centred(source / "calib.txt")
    meta: dict[str, Any] = {}
    if (source / "sim.yaml").is_file():
        meta = yaml.safe_load((source / "sim.yaml").read_text()) or {}
        baseline = float((meta.get("config") or {}).get("baseline", baseline))
    poses = read_kitti_poses(source / "poses.txt")
    sun_lines: list[str] = []
    if (source / "sun.csv").is_file():
        rows = [line.split(",") for line in (source / "sun.csv").read_text().splitlines() if line.strip()]
        try:
            sun_lines = [f"{r[0]},{-float(r[1]):.9f},{r[2]},{r[3]}" for r in rows]
        except (IndexError, ValueError):
            raise DataFormatError(source / "sun.csv", "not rows of image,sx,sy,sz") from None
    counts = set()
    out.mkdir(parents=True)
    for left, right in IMAGE_FOLDERS:
        if not (source / left).is_dir():
            continue
        for folder_in, folder_out in ((right, left), (left, right)):
            (out / folder_out).mkdir()
            names = sorted(p.name for p in (source / folder_in).glob("*.png"))
            counts.add(len(names))
            for name in names:
                image = cv2.imread(str(source / folder_in / name), cv2.IMREAD_UNCHANGED)
                if image is None:
                    raise DataFormatError(source / folder_in / name, "unreadable image")
                cv2.imwrite(str(out / folder_out / name), np.ascontiguousarray(image[:, ::-1]))
    if counts != {len(poses)}:
        raise DataFormatError(source, f"{sorted(counts)} images per folder for {len(poses)} poses")
    for name in ("calib.txt", "times.txt"):
        shutil.copyfile(source / name, out / name)
    if sun_lines:
        (out / "sun.csv").write_text("\n".join(sun_lines) + "\n")
    if meta:
        meta["mirrored_from"] = str(source)
        (out / "sim.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
    temporary = out / ".poses.txt.tmp"
    write_kitti_poses(temporary, mirrored_poses(poses, baseline))
    os.replace(temporary, out / "poses.txt")
    return out


def mirror_corpus(source: Path, out: Path, progress: Callable[[int, int], None] | None = None) -> list[str]:
    """Every sequence of the corpus at ``source`` mirrored into ``out`` with its own manifest (the same splits and
    configurations, :data:`MIRRORED` added to each sequence's conditions, hashes of the mirrored files). Re-running
    resumes: sequences already mirrored (poses.txt written) are kept. Returns the names mirrored now."""
    import yaml
    from pvo_core.readers.corpus import read_corpus_manifest

    from .corpus import MANIFEST, content_hash, read_manifest

    source, out = Path(source), Path(out)
    read_corpus_manifest(source)  # one clear line if it is not a corpus
    data = read_manifest(source)
    out.mkdir(parents=True, exist_ok=True)
    entries, done = [], []
    for number, entry in enumerate(data["sequences"], start=1):
        name = str(entry["name"])
        folder = out / name
        if not (folder / "poses.txt").is_file():
            mirror_sequence(source / name, folder, overwrite=True)
            done.append(name)
        mirrored = dict(entry)
        mirrored["conditions"] = [*entry.get("conditions", []), MIRRORED]
        mirrored["sha256"] = content_hash(folder)
        entries.append(mirrored)
        if progress is not None:
            progress(number, len(data["sequences"]))
    manifest = {
        "generator": "pvo sim mirror",
        "mirrored_from": str(source),
        "corpus": data.get("corpus", {}),
        "splits": data.get("splits", {}),
        "sequences": entries,
    }
    temporary = out / f".{MANIFEST}.tmp"
    temporary.write_text(yaml.safe_dump(manifest, sort_keys=False))
    os.replace(temporary, out / MANIFEST)
    return done
