"""Training corpora: many varied sequences rendered by :func:`pvo_sim.simulate`, with a manifest.

Each sequence's configuration is drawn from ``numpy.random.default_rng([seed, index])`` alone, so sequence
``i`` is the same whatever the corpus size, the number of parallel jobs or the order they finish in. The
split (train / validation / test) is by sequence, drawn the same way. ``manifest.yaml`` lists every
sequence's full configuration, its split and a SHA-256 of its files; it is rewritten after each sequence,
so an interrupted run resumes: complete sequences whose configuration and renderer revision match are kept, a partial one
(``simulate`` renders into a hidden sibling and moves it into place only when whole) is rendered again.
"""

from __future__ import annotations

import hashlib
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from datetime import UTC, datetime, timedelta
from pathlib import Path
from typing import Any

import numpy as np
from pvo_core.ephemeris import GeodeticOrigin, sun_elevation_azimuth

from .degrade import CameraModel, Degradations
from .paths import PATH_KINDS
from .render import KITTI_FOCAL_PER_PIXEL_WIDTH, SimConfig, planned_revision, recorded_config, simulate
from .sky import SKIES
from .world import PRESETS

MANIFEST = "manifest.yaml"
SPLITS = ("train", "validation", "test")
# the slowest replay of a KITTI window (--kitti-speed-scale): a 50-frame window then spans one of its drive's frame
# intervals, a standstill
MIN_SPEED_SCALE = 0.02


@dataclass(frozen=True)
class CorpusConfig:
    """What to render: ``sequences`` of ``frames`` each, at ``width`` x ``height``, from ``presets``.

    The fractions say how often each condition is drawn; ``split`` the expected share of train /
    validation / test sequences."""

    sequences: int = 20
    frames: int = 200
    width: int = 620
    height: int = 188
    presets: tuple[str, ...] = PRESETS
    seed: int = 0
    colour: bool = False
    rate: float = 10.0
    split: tuple[float, float, float] = (0.7, 0.15, 0.15)
    overcast: float = 0.15
    motion_blur: float = 0.1
    exposure_changes: float = 0.15
    moving_vehicles: float = 0.5
    texture_poor: float = 0.1
    wrong_calibration: float = 0.05
    radial_distortion: float = 0.05
    jpeg: float = 0.3
    min_sun_elevation: float = 5.0
    # 1, not pvo sim's 2: the learned models read the corpus at half its size or less, where the downsampling
    # integrates each pixel's area as supersampling would; rendering at 2x costs a third of the frame rate
    supersample: int = 1
    # real vehicle motion: with ``kitti_poses`` (a directory of KITTI odometry pose files NN.txt) each sequence
    # drives a window of one of its split's drives (turns, pitch and roll as a car's), not a procedural path;
    # the drives are split as the sequences are, so no stretch of road is in two splits
    kitti_poses: str = ""
    kitti_train: tuple[str, ...] = ("00", "02", "08", "09")
    kitti_validation: tuple[str, ...] = ("04", "10")
    kitti_test: tuple[str, ...] = ("05", "06", "07")
    # windows drawn in proportion to how much the vehicle turns in them (``kitti_turning``: the total rotation
    # angle over the window, plus a floor of a straight window's share), not uniformly: a drive is mostly
    # straight, and a frame-to-frame rotation model sees its sharp turns too rarely to learn them
    kitti_turning: bool = False
    # each window levelled over this many frames of its drive around it (``kitti_path``'s ``level_frames``), so
    # the short windows pitch against the flat ground as a long drive along the same road does (0: on itself)
    kitti_level_frames: int = 0
    # each window's drive replayed faster (or slower) by a factor drawn uniformly from this range (``kitti_path``'s
    # ``speed_scale``): KITTI's training drives exceed 15 m/s in under 2 % of their frames, the validation drive 04
    # in 37 %; and they rarely stop, where a frame-to-frame model sees only the other vehicles move (down to 0.02:
    # 50 frames then span one of the drive's frame intervals, a standstill) (1, 1: as driven, nothing drawn)
    kitti_speed_scale: tuple[float, float] = (1.0, 1.0)
    # each urban sequence's cameras pitched down by a draw from this range (degrees): the corpus draws urban cameras
    # level and planetary ones pitched 0-25 deg, and a body that only saw level cameras misreads a pitched camera's
    # flow (0, 0: level, nothing drawn, the draws of a corpus without it)
    urban_pitch: tuple[float, float] = (0.0, 0.0)
    # each sequence's moving vehicles driving at their own speed, drawn uniformly from this range (m/s; each
    # vehicle within +-30 % of it), so that they pass a stopped or crawling camera too (Degradations.vehicle_speed;
    # 0, 0: each vehicle replays the camera's path, nothing drawn, the draws of a corpus without it)
    vehicle_speed: tuple[float, float] = (0.0, 0.0)
    # one lens for the whole corpus (the rig DPC-Net learns to correct): plumb-bob k1 [k2 k3] on every sequence,
    # instead of the drawn distortion
    lens_distortion: tuple[float, ...] = ()
    # one wrong calibration for the whole corpus (the other rig DPC-Net learns to correct, Table 6.1): every
    # calib.txt written with the focal length and the baseline times these, instead of the drawn error
    calib_focal_scale: float = 1.0
    calib_baseline_scale: float = 1.0
    # the sky of every sequence (pvo_sim.sky): "gradient" (one for every sun) or "sun" (the CIE skies); set after
    # the draws, so a corpus with the sun's sky has the same places, suns and worlds as the one without
    sky: str = "gradient"

    def __post_init__(self) -> None:
        if self.supersample not in (1, 2, 3, 4):
            raise ValueError(f"--supersample must be 1, 2, 3 or 4, got {self.supersample}")
        if self.sequences < 1 or self.frames < 2:
            raise ValueError(f"a corpus needs >= 1 sequence of >= 2 frames, got {self.sequences} x {self.frames}")
        unknown = [p for p in self.presets if p not in PRESETS]
        if unknown or not self.presets:
            raise ValueError(f"--presets {','.join(self.presets)}: choose from {', '.join(PRESETS)}")
        if abs(sum(self.split) - 1.0) > 1e-9 or min(self.split) < 0:
            raise ValueError(f"split fractions must be >= 0 and sum to 1, got {self.split}")
        fractions = ("overcast", "motion_blur", "exposure_changes", "moving_vehicles", "texture_poor")
        fractions += ("wrong_calibration", "radial_distortion", "jpeg")
        for name in fractions:
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"--{name.replace('_', '-')} must be a fraction in [0, 1], got {getattr(self, name)}")
        if self.lens_distortion:  # one line now, not after the first sequence rendered
            try:
                Degradations(distortion=tuple(self.lens_distortion))
            except ValueError as exc:
                raise ValueError(str(exc).replace("--distortion", "--lens-distortion")) from None
        for name in ("calib_focal_scale", "calib_baseline_scale"):
            if not 0.5 <= getattr(self, name) <= 2.0:
                raise ValueError(
                    f"--{name.replace('_', '-')} must be in [0.5, 2] (a calibration error), got {getattr(self, name)}"
                )
        if self.sky not in SKIES:
            raise ValueError(f"--sky must be one of {', '.join(SKIES)}, got {self.sky!r}")
        if self.kitti_level_frames < 0:
            raise ValueError(f"--kitti-level-frames must be >= 0 (0: each window on itself), got {self.kitti_level_frames}")
        speeds = self.kitti_speed_scale
        if len(speeds) != 2 or not MIN_SPEED_SCALE <= speeds[0] <= speeds[1] <= 4.0:
            raise ValueError(
                f"--kitti-speed-scale must be two factors LO HI with {MIN_SPEED_SCALE} <= LO <= HI <= 4, got {list(speeds)}"
            )
        if len(self.vehicle_speed) != 2 or not 0.0 <= self.vehicle_speed[0] <= self.vehicle_speed[1] <= 40.0:
            raise ValueError(
                f"--vehicle-speed must be two speeds LO HI with 0 <= LO <= HI <= 40 m/s, got {list(self.vehicle_speed)}"
            )
        if len(self.urban_pitch) != 2 or not 0.0 <= self.urban_pitch[0] <= self.urban_pitch[1] <= 45.0:
            raise ValueError(
                f"--urban-pitch must be two angles LO HI with 0 <= LO <= HI <= 45 degrees, got {list(self.urban_pitch)}"
            )
        if self.kitti_poses:
            if set(self.kitti_train) & set(self.kitti_test) or set(self.kitti_validation) & set(self.kitti_test):
                raise ValueError("a KITTI drive is in the test split and another split: keep the test drives apart")
            for split, drives in zip(SPLITS, (self.kitti_train, self.kitti_validation, self.kitti_test), strict=True):
                if not drives:
                    raise ValueError(f"--kitti-{split}: no drive for the {split} split")
                for drive in drives:
                    file = Path(self.kitti_poses) / f"{drive}.txt"
                    if not file.is_file():
                        raise ValueError(f"--kitti-poses: {file} not found (drive {drive} of the {split} split)")
                    if sum(1 for _ in file.open()) < self.kitti_span(self.kitti_speed_scale[1]):
                        raise ValueError(
                            f"--kitti-poses: {file} holds fewer than the {self.kitti_span(self.kitti_speed_scale[1])} "
                            f"poses a window of {self.frames} frames spans"
                        )

    def kitti_span(self, speed_scale: float) -> int:
        """How many of its drive's poses a window of ``frames`` frames replayed ``speed_scale`` times faster spans."""
        return int(np.ceil((self.frames - 1) * speed_scale - 1e-9)) + 1

    def kitti_drives(self, split: str) -> tuple[str, ...]:
        return {"train": self.kitti_train, "validation": self.kitti_validation, "test": self.kitti_test}[split]


@dataclass(frozen=True)
class SequencePlan:
    """One sequence of the corpus: its name, split, the configuration that renders it and the conditions
    drawn for it (for the manifest, in words)."""

    index: int
    name: str
    split: str
    config: SimConfig
    conditions: tuple[str, ...] = field(default_factory=tuple)


def _daylight_time(rng: np.random.Generator, latitude: float, longitude: float, minimum_elevation: float) -> tuple[str, float]:
    """A UTC time on a random date (2008-2022) with the sun at least ``minimum_elevation`` degrees up:
    uniform over that day's qualifying minutes (so elevations span the range the place allows and azimuths
    go all round). Returns (ISO time, elevation)."""
    origin = GeodeticOrigin(latitude, longitude, 0.0)
    for _ in range(50):
        day = datetime(2008, 1, 1, tzinfo=UTC) + timedelta(days=int(rng.integers(0, 15 * 365)))
        minutes = np.arange(0, 24 * 60, 5)
        times = day.timestamp() + 60.0 * minutes
        elevation, _ = sun_elevation_azimuth(origin, times)
        ok = np.flatnonzero(elevation >= minimum_elevation + 1.0)  # a margin: the sequence lasts a while
        if ok.size:
            pick = int(rng.choice(ok))
            moment = datetime.fromtimestamp(float(times[pick]), tz=UTC)
            return moment.strftime("%Y-%m-%dT%H:%M:%SZ"), float(elevation[pick])
    raise ValueError(f"no day with the sun above {minimum_elevation} deg at latitude {latitude:.1f}")


def plan_sequence(corpus: CorpusConfig, index: int) -> SequencePlan:
    """Draw sequence ``index``: place, time, path, preset, appearance, camera and degradations."""
    rng = np.random.default_rng([corpus.seed, index, 20260])
    split = SPLITS[int(np.searchsorted(np.cumsum(corpus.split), rng.random(), side="right").clip(0, 2))]
    preset = corpus.presets[int(rng.integers(len(corpus.presets)))]
    conditions: list[str] = []
    # place: both hemispheres, from the tropics to the high Arctic (Devon Island is at 75 N)
    latitude = float(rng.uniform(10.0, 78.0)) * (1.0 if rng.random() < 0.75 else -1.0)
    longitude = float(rng.uniform(-180.0, 180.0))
    start_time, elevation = _daylight_time(rng, latitude, longitude, corpus.min_sun_elevation)
    overcast = bool(rng.random() < corpus.overcast)
    if overcast:
        conditions.append("overcast")
    path = PATH_KINDS[int(rng.integers(len(PATH_KINDS)))]
    speed = float(rng.uniform(4.0, 12.0) if preset == "urban" else rng.uniform(0.8, 4.0))
    if preset == "urban":
        pitch = float(rng.uniform(*corpus.urban_pitch)) if corpus.urban_pitch[1] > 0.0 else 0.0
    else:
        pitch = float(rng.uniform(0.0, 25.0))
    height = 1.65 if preset == "urban" else float(rng.uniform(0.9, 1.8))
    blur = float(rng.uniform(2.0, 8.0)) if rng.random() < corpus.motion_blur else 0.0
    exposure = float(rng.uniform(0.1, 0.4)) if rng.random() < corpus.exposure_changes else 0.0
    moving = int(rng.integers(1, 7)) if preset == "urban" and rng.random() < corpus.moving_vehicles else 0
    texture_poor = float(rng.uniform(0.5, 1.0)) if preset == "urban" and rng.random() < corpus.texture_poor else 0.0
    focal_scale = baseline_scale = 1.0
    if rng.random() < corpus.wrong_calibration:
        focal_scale, baseline_scale = float(rng.uniform(0.97, 1.03)), float(rng.uniform(0.97, 1.03))
        conditions.append("wrong calibration")
    distortion = float(rng.uniform(-0.3, 0.2)) if rng.random() < corpus.radial_distortion else 0.0
    for flag, name in ((blur, "motion blur"), (exposure, "exposure changes"), (moving, "moving vehicles")):
        if flag:
            conditions.append(name)
    if texture_poor:
        conditions.append("texture-poor walls")
    if distortion:
        conditions.append("radial distortion")
    jpeg = int(rng.integers(60, 96)) if rng.random() < corpus.jpeg else 0
    camera = CameraModel(
        target=float(rng.uniform(0.3, 0.55)),
        gamma=float(rng.uniform(1.0, 2.2)),
        vignetting=float(rng.uniform(0.0, 0.4)),
        full_well=float(rng.uniform(2000.0, 12000.0)),
        read_noise=float(rng.uniform(0.5, 3.0)),
        sharpening=float(rng.uniform(0.0, 1.5)),
        jpeg_quality=jpeg,
    )
    config = SimConfig(
        preset=preset,
        frames=corpus.frames,
        width=corpus.width,
        height=corpus.height,
        focal=KITTI_FOCAL_PER_PIXEL_WIDTH * corpus.width * float(rng.uniform(0.85, 1.15)),
        rate=corpus.rate,
        colour=corpus.colour,
        path=path,
        speed=speed,
        camera_height=height,
        heading_deg=float(rng.uniform(0.0, 360.0)),
        pitch_deg=pitch,
        latitude=latitude,
        longitude=longitude,
        altitude=float(rng.uniform(0.0, 1500.0)),
        start_time=start_time,
        overcast=overcast,
        seed=int(rng.integers(0, 2**31 - 1)),
        degradations=Degradations(
            distortion=distortion,
            blur_px=blur,
            exposure=exposure,
            focal_scale=focal_scale,
            baseline_scale=baseline_scale,
            texture_poor=texture_poor,
            moving_vehicles=moving,
        ),
        camera=camera,
        supersample=corpus.supersample,
    )
    del elevation  # drawn through the time of day; the render records the actual range
    if corpus.lens_distortion:  # the rig's lens, on every sequence (nothing drawn: the draws stay as they were)
        lens = corpus.lens_distortion[0] if len(corpus.lens_distortion) == 1 else tuple(corpus.lens_distortion)
        config = replace(config, degradations=replace(config.degradations, distortion=lens))
        conditions = [c for c in conditions if c != "radial distortion"] + ["lens distortion"]
    if (corpus.calib_focal_scale, corpus.calib_baseline_scale) != (1.0, 1.0):  # the rig's calibration error
        rig = {"focal_scale": corpus.calib_focal_scale, "baseline_scale": corpus.calib_baseline_scale}
        config = replace(config, degradations=replace(config.degradations, **rig))
        conditions = [c for c in conditions if c != "wrong calibration"] + ["rig calibration error"]
    if corpus.kitti_poses:  # drawn last: a corpus without KITTI drives draws exactly as before
        drives = corpus.kitti_drives(split)
        drive = drives[int(rng.integers(len(drives)))]
        file = Path(corpus.kitti_poses) / f"{drive}.txt"
        low, high = corpus.kitti_speed_scale
        speed_scale = 1.0 if (low, high) == (1.0, 1.0) else float(rng.uniform(low, high))  # a plain corpus draws as before
        spanned = corpus.kitti_span(speed_scale)
        if corpus.kitti_turning:
            weights = turning_weights(file, spanned)
            start = int(rng.choice(len(weights), p=weights))
        else:
            poses = sum(1 for _ in file.open())
            start = int(rng.integers(0, poses - spanned + 1))
        config = replace(
            config,
            path="kitti",
            poses_file=str(file.resolve()),
            start_frame=start,
            level_frames=corpus.kitti_level_frames,
            speed_scale=speed_scale,
        )
        conditions.append(f"KITTI {drive} from frame {start}" + (f" at {speed_scale:.2f}x" if speed_scale != 1.0 else ""))
    if corpus.vehicle_speed[1] > 0.0 and config.degradations.moving_vehicles:  # drawn after all the others
        vehicle_speed = float(rng.uniform(*corpus.vehicle_speed))
        config = replace(config, degradations=replace(config.degradations, vehicle_speed=vehicle_speed))
        conditions.append(f"vehicles at {vehicle_speed:.1f} m/s")
    if corpus.sky != "gradient":
        config = replace(config, sky=corpus.sky)
    return SequencePlan(index, f"{index:04d}", split, config, tuple(conditions))


def turning_weights(poses_file: Path, frames: int, floor: float = 0.1) -> np.ndarray:
    """Probabilities (N - frames + 1,) of each window start of a KITTI pose file (N poses): each window's total
    frame-to-frame rotation angle (rad), plus ``floor`` times the mean over windows (a straight window keeps a
    chance), normalised."""
    from .paths import drive_poses

    poses = drive_poses(Path(poses_file))
    relative = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])  # C_k-1^T C_k
    angles = np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    cumulative = np.concatenate([[0.0], np.cumsum(angles)])
    turning = cumulative[frames - 1 :] - cumulative[: len(cumulative) - frames + 1]  # the window's frames - 1 steps
    weights = turning + floor * turning.mean()
    return weights / weights.sum()


#: Seconds between manifest rewrites while rendering (the manifest is also written when rendering ends or stops).
MANIFEST_INTERVAL_S = 10.0


def content_hash(folder: Path) -> str:
    """SHA-256 over the relative paths and bytes of every file under ``folder`` (sorted)."""
    digest = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        digest.update(path.relative_to(folder).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()


def _yaml_classes() -> tuple[Any, Any]:
    """The safe YAML dumper and loader, libyaml's where the wheel has it (Python's emitter takes seconds for a
    thousand-sequence manifest)."""
    import yaml

    return getattr(yaml, "CSafeDumper", yaml.SafeDumper), getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def _plain(value: Any) -> Any:
    import yaml

    dumper, loader = _yaml_classes()
    return yaml.load(yaml.dump(value, Dumper=dumper, sort_keys=False), Loader=loader)


def _entry(plan: SequencePlan, folder: Path, seconds: float) -> dict[str, Any]:
    return {
        "name": plan.name,
        "split": plan.split,
        "preset": plan.config.preset,
        "conditions": list(plan.conditions),
        "frames": plan.config.frames,
        "render_seconds": round(seconds, 2),
        "renderer_revision": planned_revision(plan.config),
        "sha256": content_hash(folder),
        "config": _plain(recorded_config(plan.config)),  # as the sequence's sim.yaml records it
    }


def read_manifest(out: Path) -> dict[str, Any]:
    """The corpus manifest (``{}`` when there is none yet); ``ValueError`` naming the file when unreadable."""
    import yaml

    path = Path(out) / MANIFEST
    if not path.is_file():
        return {}
    try:
        data = yaml.load(path.read_text(), Loader=_yaml_classes()[1])
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: unreadable corpus manifest ({exc}); remove it to start afresh") from None
    if not isinstance(data, dict) or not isinstance(data.get("sequences"), list):
        raise ValueError(f"{path}: not a corpus manifest (no 'sequences' list)")
    return data


def _write_manifest(out: Path, corpus: CorpusConfig, entries: dict[str, dict[str, Any]]) -> None:
    import yaml

    dumper = _yaml_classes()[0]
    data = {
        "generator": "pvo sim corpus",
        "corpus": _plain(asdict(corpus)),
        "splits": {s: sorted(n for n, e in entries.items() if e["split"] == s) for s in SPLITS},
        "sequences": [entries[name] for name in sorted(entries)],
    }
    temporary = out / f".{MANIFEST}.tmp"
    temporary.write_text(yaml.dump(data, Dumper=dumper, sort_keys=False))
    os.replace(temporary, out / MANIFEST)


def _same_config(stored: Any, planned: dict[str, Any]) -> bool:
    """Whether a manifest's recorded sequence configuration is the planned one. A field the record lacks (added
    to :class:`SimConfig` since) counts as equal where the plan leaves it at its default, so a new option does not
    re-render every corpus made before it."""
    if not isinstance(stored, dict):
        return False
    defaults = _plain(asdict(SimConfig()))
    planned = {k: v for k, v in planned.items() if k in stored or v != defaults.get(k)}
    return stored == planned


def _render_one(plan: SequencePlan, out: Path) -> tuple[str, float]:
    """Render one sequence in this process; its name and wall time."""
    start = time.perf_counter()
    simulate(plan.config, out / plan.name, overwrite=True)
    return plan.name, time.perf_counter() - start


def render_worker(corpus_json: str, index: int, out: str) -> None:
    """Entry point of a worker process: plan sequence ``index`` again (plans depend on (seed, index) only)
    and render it."""
    import json

    values = json.loads(corpus_json)
    values["presets"] = tuple(values["presets"])
    values["split"] = tuple(values["split"])
    _render_one(plan_sequence(CorpusConfig(**values), index), Path(out))


def _start_worker(corpus: CorpusConfig, plan: SequencePlan, out: Path):
    """A fresh Python process per sequence: its own GL context whatever the parent holds (a forked worker
    would inherit the parent's), and nothing of the parent's ``__main__`` re-run (as spawn would do)."""
    import json
    import subprocess
    import sys

    code = "import sys; from pvo_sim.corpus import render_worker; render_worker(sys.argv[1], int(sys.argv[2]), sys.argv[3])"
    argv = [sys.executable, "-c", code, json.dumps(asdict(corpus)), str(plan.index), str(out)]
    import tempfile

    errors = tempfile.TemporaryFile("w+")  # a file, not a pipe: a chatty worker cannot block on it
    process = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=errors, text=True)
    process.error_log = errors  # type: ignore[attr-defined]
    return process


@dataclass
class CorpusResult:
    out: Path
    rendered: list[str]
    kept: list[str]
    seconds: float
    frames_rendered: int

    @property
    def frames_per_second(self) -> float:
        return self.frames_rendered / max(self.seconds, 1e-9)


@dataclass
class CorpusPlan:
    """What rendering a corpus into a folder would do: the sequences kept (same configuration, rendered as this
    renderer draws them) with their manifest entries, and the plans of those to render; and every planned
    sequence's renderer revision (the one its sim.yaml records: the latest revision only where that revision
    changed its world)."""

    out: Path
    kept: dict[str, dict[str, Any]]
    to_render: list[SequencePlan]
    revisions: dict[str, int]


def plan_corpus(corpus: CorpusConfig, out: Path, indices: Sequence[int] | None = None) -> CorpusPlan:
    """Plan ``corpus`` against what ``out`` holds, rendering nothing (``pvo sim corpus --dry-run``)."""
    plans = [plan_sequence(corpus, i) for i in (range(corpus.sequences) if indices is None else indices)]
    previous = {e.get("name"): e for e in read_manifest(Path(out)).get("sequences", [])}
    kept: dict[str, dict[str, Any]] = {}
    to_render, revisions = [], {}
    for plan in plans:
        revisions[plan.name] = planned_revision(plan.config)
        entry = previous.get(plan.name)
        same = entry and _same_config(entry.get("config"), _plain(recorded_config(plan.config)))
        if same and entry.get("renderer_revision") == revisions[plan.name] and (Path(out) / plan.name / "sim.yaml").is_file():
            kept[plan.name] = entry
        else:
            to_render.append(plan)
    return CorpusPlan(Path(out), kept, to_render, revisions)


def render_corpus(
    corpus: CorpusConfig,
    out: Path,
    jobs: int = 1,
    progress: Callable[[int, int], None] | None = None,
    indices: Sequence[int] | None = None,
) -> CorpusResult:
    """Render every sequence of ``corpus`` into ``out`` not already there with the same configuration;
    ``progress(frames_done, frames_to_render)`` at the start and after each sequence rendered. indices:
    only these sequences (e.g. a corpus's test sequences rendered longer: plans depend on (seed, index) only)."""
    if jobs < 1:
        raise ValueError(f"--jobs must be >= 1, got {jobs}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    planned = plan_corpus(corpus, out, indices)
    kept, todo = list(planned.kept), planned.to_render
    entries = dict(planned.kept)
    total = len(todo) * corpus.frames
    done_frames = 0
    if progress:
        progress(done_frames, total)
    _write_manifest(out, corpus, entries)
    start = time.perf_counter()
    rendered: list[str] = []
    by_name = {p.name: p for p in todo}
    written = start

    def finished(name: str, seconds: float) -> None:
        nonlocal done_frames, written
        entries[name] = _entry(by_name[name], out / name, seconds)
        # the manifest is the resume point: rewritten every few seconds, not after every sequence (rewriting a
        # thousand entries per sequence made the parent process the bottleneck), and always at the end below
        if time.perf_counter() - written >= MANIFEST_INTERVAL_S:
            _write_manifest(out, corpus, entries)
            written = time.perf_counter()
        rendered.append(name)
        done_frames += corpus.frames
        if progress:
            progress(done_frames, total)

    queue = list(todo)
    running: dict[str, tuple[Any, float]] = {}
    try:
        if jobs == 1 or len(todo) <= 1:
            for plan in todo:
                finished(*_render_one(plan, out))
        else:
            while queue or running:
                while queue and len(running) < jobs:
                    plan = queue.pop(0)
                    running[plan.name] = (_start_worker(corpus, plan, out), time.perf_counter())
                time.sleep(0.05)
                for name, (process, started) in list(running.items()):
                    if process.poll() is None:
                        continue
                    del running[name]
                    process.error_log.seek(0)
                    errors = process.error_log.read().strip().splitlines()
                    process.error_log.close()
                    if process.returncode != 0:
                        detail = errors[-1] if errors else f"exit status {process.returncode}"
                        raise ValueError(f"{out / name}: rendering failed: {detail}")
                    finished(name, time.perf_counter() - started)
    finally:
        for process, _ in running.values():  # interrupted: stop the workers; their partial output is discarded
            process.terminate()
            process.wait()
        _write_manifest(out, corpus, entries)  # every sequence finished so far, also when interrupted or failed
    return CorpusResult(out, rendered, kept, time.perf_counter() - start, len(rendered) * corpus.frames)
