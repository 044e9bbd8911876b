"""`pvo bench realism`: rendered worlds against the real images of ../shared/data, side by side.

Per image set (left images, grey, at the real data's resolution): the VO's tracked features per frame and
their inlier ratio (tracked on the left images, since KITTI 07 and Devon have no right images), the
power-spectrum slope, and the intensity and
gradient-magnitude histograms as distances to the real set of the same kind. Then the stereo VO's end
drift on the two held-out runs (the planetary s-curve at 75.4° N, the urban loop). A contact sheet PNG
shows real and rendered frames together.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pvo_core.readers import KittiSequence
from pvo_core.results import RunResult
from pvo_frontend.offline import run_sequence, summarise, track_monocular
from pvo_frontend.vo import VOConfig
from pvo_sim.realism import compare, image_statistics

from pvo_sim import KITTI_FOCAL_PER_PIXEL_WIDTH, SimConfig, simulate

Image = NDArray[np.uint8]
URBAN_SIZE = (620, 188)  # KITTI's 1226x370 halved
DEVON_SIZE = (512, 384)
DEVON_FOCAL = 394.0  # px at 512 wide: a 66° horizontal field of view (Bumblebee XB3, 3.8 mm)

#: What is rendered, per kind: a clip like the real data (statistics and tracking), and the held-out VO run.
URBAN_CLIP = SimConfig(frames=60, path="straight", speed=7.0, seed=101)
PLANETARY_CLIP = SimConfig(
    preset="planetary",
    frames=60,
    width=DEVON_SIZE[0],
    height=DEVON_SIZE[1],
    focal=DEVON_FOCAL,
    path="s-curve",
    speed=2.0,
    camera_height=1.2,
    pitch_deg=20.0,
    latitude=75.4,
    longitude=-89.8,
    start_time="2008-07-12T15:00:00Z",
    seed=102,
)
URBAN_LOOP = SimConfig(frames=300, path="loop", seed=0)
URBAN_LOOP_KITTI_SIZE = SimConfig(frames=300, path="loop", seed=0, width=1241, height=376, focal=718.856)
PLANETARY_RUN = SimConfig(preset="planetary", frames=127, path="s-curve", speed=3.0, latitude=75.4, seed=0)


@dataclass
class ImageSet:
    """Left images (grey, all the same size) and the figures measured on them."""

    label: str
    kind: str  # urban | planetary
    real: bool
    images: list[Image]
    figures: dict[str, Any] = field(default_factory=dict)


def _grey(path: Path, size: tuple[int, int] | None) -> Image:
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise ValueError(f"{path}: not a readable image")
    if size is not None and (image.shape[1], image.shape[0]) != size:
        image = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    return image


def real_sets(data: Path) -> list[ImageSet]:
    """KITTI 06 (stereo) and 07 (left), halved to 620x188, and the Devon Island images (512x384)."""
    sets = []
    for name in ("06", "07"):
        folder = data / "kitti" / "sequences" / name
        left = sorted((folder / "image_0").glob("*.png"))
        if not left:
            raise ValueError(f"{folder / 'image_0'}: no images (see ../shared/data/SOURCES.md)")
        sets.append(ImageSet(f"KITTI {name}", "urban", True, [_grey(p, URBAN_SIZE) for p in left]))
    devon = sorted((data / "devon" / "grey-rectified-512x384-s00").glob("*.pgm"))
    if not devon:
        raise ValueError(f"{data / 'devon'}: no Devon Island images (see ../shared/data/SOURCES.md)")
    sets.append(ImageSet("Devon 1-60", "planetary", True, [_grey(p, None) for p in devon]))
    return sets


def rendered_set(label: str, folder: Path, kind: str) -> ImageSet:
    left = sorted((folder / "image_0").glob("*.png"))
    if not left:
        raise ValueError(f"{folder}: no image_0/*.png (a `pvo sim` output with grey images is needed)")
    size = URBAN_SIZE if kind == "urban" else DEVON_SIZE
    return ImageSet(label, kind, False, [_grey(p, size) for p in left])


def render(config: SimConfig, out: Path, reuse: bool = False) -> Path:
    """Render ``config`` into ``out``; with ``reuse``, keep a render of the same configuration already there
    (the renderer itself may have changed since: only for re-measuring the same images)."""
    import yaml

    meta = out / "sim.yaml"
    from pvo_sim.render import recorded_config

    if reuse and meta.is_file() and yaml.safe_load(meta.read_text()).get("config") == _plain(recorded_config(config)):
        return out
    simulate(config, out, overwrite=True)
    return out


def _plain(value: Any) -> Any:
    import yaml

    return yaml.safe_load(yaml.safe_dump(value))


def measure(image_set: ImageSet, config: VOConfig) -> None:
    """Tracking and image statistics of one set, into ``image_set.figures``."""
    mono = track_monocular(image_set.images, config)
    image_set.figures.update(tracked=mono.tracked, inlier_ratio=mono.inlier_ratio)
    statistics = image_statistics(image_set.images)
    image_set.figures.update(spectrum_slope=statistics.spectrum_slope, mean_intensity=statistics.mean_intensity)
    image_set.figures["_statistics"] = statistics


@dataclass(frozen=True)
class RealismOptions:
    data: Path
    work: Path  # where renders are kept between runs
    compare: tuple[tuple[str, Path], ...] = ()  # extra rendered folders (label, folder), e.g. an older renderer's
    reuse: bool = False  # keep earlier renders of the same configurations


def run_realism(options: RealismOptions, say: Callable[[str], None] = print) -> tuple[RunResult, list[ImageSet]]:
    """Render (or reuse) the clips and the held-out runs, measure every set, compare with the real ones."""
    config = VOConfig()
    sets = real_sets(options.data)
    urban_clip = replace(URBAN_CLIP, focal=KITTI_FOCAL_PER_PIXEL_WIDTH * URBAN_SIZE[0])
    say("rendering the urban and planetary clips ...")
    sets.append(rendered_set("rendered urban", render(urban_clip, options.work / "urban_clip", options.reuse), "urban"))
    sets.append(
        rendered_set("rendered planetary", render(PLANETARY_CLIP, options.work / "planetary_clip", options.reuse), "planetary")
    )
    for label, folder in options.compare:
        import yaml

        preset = (
            yaml.safe_load((folder / "sim.yaml").read_text())["config"]["preset"] if (folder / "sim.yaml").is_file() else "urban"
        )
        sets.append(rendered_set(label, folder, preset))
    for image_set in sets:
        say(f"measuring {image_set.label} ({len(image_set.images)} images) ...")
        measure(image_set, config)
    reference = {kind: next(s for s in sets if s.real and s.kind == kind) for kind in ("urban", "planetary")}
    for image_set in sets:
        real = reference[image_set.kind]
        gap = compare(image_set.figures["_statistics"], real.figures["_statistics"])
        image_set.figures.update(
            slope_gap=gap.slope_gap,
            intensity_distance=gap.intensity_distance,
            gradient_distance=gap.gradient_distance,
            tracked_vs_real=image_set.figures["tracked"] / max(real.figures["tracked"], 1e-9),
            inlier_ratio_vs_real=image_set.figures["inlier_ratio"] / max(real.figures["inlier_ratio"], 1e-9),
        )
    drift = {}
    runs = (
        ("planetary s-curve, 75.4 N", PLANETARY_RUN),
        ("urban loop", URBAN_LOOP),
        ("urban loop 1241x376", URBAN_LOOP_KITTI_SIZE),
    )
    for label, sim in runs:
        say(f"rendering and running the VO on the {label} run ...")
        folder = render(
            sim, options.work / label.split(",")[0].replace(" ", "_").replace("1241x376", "kitti_size"), options.reuse
        )
        sequence = KittiSequence(folder, poses_file=folder / "poses.txt")
        run = run_sequence(sequence, config)
        summary = summarise(run, sequence.poses)
        drift[label] = {"end_drift_percent": summary["end_drift_percent"], "path_m": summary["path_m"]}
    table = {
        s.label: {k: v for k, v in s.figures.items() if not k.startswith("_")} | {"kind": s.kind, "real": s.real} for s in sets
    }
    result = RunResult(
        "bench",
        "realism",
        figures={f"end_drift_percent[{k}]": v["end_drift_percent"] for k, v in drift.items()},
        tables={"image_sets": table, "vo_runs": drift},
        inputs={"data": str(options.data), "compare": [f"{label}={folder}" for label, folder in options.compare]},
    )
    return result, sets


def contact_sheet(sets: list[ImageSet], columns: int = 3, width: int = 400) -> Image:
    """Rows of frames (evenly spaced through each set), one row per set, its label on the first frame."""
    import cv2

    rows = []
    for image_set in sets:
        picks = np.linspace(0, len(image_set.images) - 1, columns).round().astype(int)
        tiles = []
        for i in picks:
            image = image_set.images[i]
            height = round(image.shape[0] * width / image.shape[1])
            tiles.append(cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA))
        height = max(t.shape[0] for t in tiles)
        tiles = [np.pad(t, ((0, height - t.shape[0]), (0, 0))) for t in tiles]
        row = cv2.cvtColor(np.hstack(tiles), cv2.COLOR_GRAY2BGR)
        label = f"{image_set.label} ({'real' if image_set.real else 'rendered'})"
        cv2.putText(row, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 3, cv2.LINE_AA)
        cv2.putText(row, label, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (60, 230, 255), 1, cv2.LINE_AA)
        rows.append(np.pad(row, ((0, 4), (0, 0), (0, 0)), constant_values=255))
    return np.vstack(rows)
