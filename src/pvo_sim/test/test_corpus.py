"""`pvo_sim.corpus`: varied, deterministic sequences, splits by sequence, a manifest, and resuming."""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_sim.corpus import CorpusConfig, content_hash, plan_sequence, read_manifest, render_corpus

from pvo_sim import corpus as corpus_module

os.environ.setdefault("MUJOCO_GL", "egl")
TINY = CorpusConfig(sequences=3, frames=2, width=96, height=48, seed=11)


def test_plans_vary_and_depend_only_on_seed_and_index() -> None:
    big = CorpusConfig(sequences=200, frames=10, seed=3)
    plans = [plan_sequence(big, i) for i in range(200)]
    assert plan_sequence(CorpusConfig(sequences=5, frames=10, seed=3), 4) == plans[4]  # not on the corpus size
    assert plan_sequence(CorpusConfig(sequences=5, frames=10, seed=4), 4) != plans[4]
    latitudes = np.array([p.config.latitude for p in plans])
    assert latitudes.min() < -10 and latitudes.max() > 60  # both hemispheres, into the Arctic
    assert {p.config.preset for p in plans} == {"urban", "planetary"}
    assert {p.config.path for p in plans} == {"loop", "straight", "s-curve"}
    headings = np.array([p.config.heading_deg for p in plans])
    assert np.histogram(headings, bins=4, range=(0, 360))[0].min() > 20  # all round
    splits = [p.split for p in plans]
    assert 0.6 < splits.count("train") / 200 < 0.8 and splits.count("validation") > 10 and splits.count("test") > 10
    conditions = [c for p in plans for c in p.conditions]
    for name in ("overcast", "motion blur", "exposure changes", "moving vehicles", "texture-poor walls"):
        assert conditions.count(name) > 0, name
    assert any(p.config.degradations.distortion for p in plans)
    assert any(p.config.degradations.focal_scale != 1.0 for p in plans)
    assert len({p.config.camera for p in plans}) == 200  # every sequence its own camera
    assert {p.config.scale for p in plans} == {1}  # rendered at the corpus's size unless asked otherwise
    assert plan_sequence(CorpusConfig(frames=10, seed=3, supersample=2), 4).config.scale == 2


def write_drives(root: Path, names: tuple[str, ...], poses: int) -> Path:
    for name in names:
        (root / f"{name}.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n" * poses)
    return root


def kitti_corpus(drives: Path, sequences: int, frames: int, **options) -> CorpusConfig:
    """A corpus over the drives 00, 02 (train), 04 (validation) and 05 (test) of ``drives``, seed 2."""
    splits = {"kitti_train": ("00", "02"), "kitti_validation": ("04",), "kitti_test": ("05",)}
    return CorpusConfig(sequences=sequences, frames=frames, seed=2, kitti_poses=str(drives), **splits, **options)


def test_kitti_drives_give_each_split_its_own_windows(tmp_path: Path) -> None:
    drives = write_drives(tmp_path, ("00", "02", "04", "05"), 60)
    config = kitti_corpus(drives, 60, 20)
    plain = CorpusConfig(sequences=60, frames=20, seed=2)
    for i in range(60):
        plan, before = plan_sequence(config, i), plan_sequence(plain, i)
        drive = Path(plan.config.poses_file).stem
        assert drive in config.kitti_drives(plan.split), (plan.split, drive)
        assert 0 <= plan.config.start_frame <= 40 and plan.config.path == "kitti"
        assert plan.config.latitude == before.config.latitude and plan.split == before.split  # the rest drawn as before
        assert f"KITTI {drive} from frame {plan.config.start_frame}" in plan.conditions
    with pytest.raises(ValueError, match="a KITTI drive is in the test split and another split"):
        CorpusConfig(kitti_poses=str(drives), kitti_train=("00", "05"), kitti_test=("05",), frames=20)
    with pytest.raises(ValueError, match=r"07.txt not found \(drive 07 of the test split\)"):
        CorpusConfig(kitti_poses=str(drives), kitti_train=("00",), kitti_validation=("04",), kitti_test=("07",), frames=20)
    with pytest.raises(ValueError, match="holds fewer than the 100 poses a window of 100 frames spans"):
        CorpusConfig(kitti_poses=str(drives), kitti_train=("00",), kitti_validation=("04",), kitti_test=("05",), frames=100)


def test_kitti_windows_can_be_levelled_over_their_drive(tmp_path: Path) -> None:
    drives = write_drives(tmp_path, ("00", "02", "04", "05"), 60)
    plans = [plan_sequence(kitti_corpus(drives, 8, 20, kitti_level_frames=50), i) for i in range(8)]
    assert {p.config.level_frames for p in plans} == {50}
    before = [plan_sequence(kitti_corpus(drives, 8, 20), i) for i in range(8)]
    assert [p.config.start_frame for p in plans] == [p.config.start_frame for p in before]  # the same windows
    assert {p.config.level_frames for p in before} == {0}
    with pytest.raises(ValueError, match="--kitti-level-frames must be >= 0"):
        kitti_corpus(drives, 8, 20, kitti_level_frames=-5)


def test_kitti_windows_can_be_replayed_faster(tmp_path: Path) -> None:
    """Each window's factor drawn from the range, its start leaving room for the longer stretch of road it spans;
    without the option nothing is drawn (the same plans as before); a bad range or a drive too short is one line."""
    drives = write_drives(tmp_path, ("00", "02", "04", "05"), 60)
    plans = [plan_sequence(kitti_corpus(drives, 30, 20, kitti_speed_scale=(1.0, 2.5)), i) for i in range(30)]
    scales = np.array([p.config.speed_scale for p in plans])
    assert scales.min() >= 1.0 and scales.max() <= 2.5 and np.ptp(scales) > 0.8
    for plan in plans:
        spanned = int(np.ceil(19 * plan.config.speed_scale - 1e-9)) + 1
        assert plan.config.start_frame + spanned <= 60
        assert f"at {plan.config.speed_scale:.2f}x" in plan.conditions[-1]
    before = [plan_sequence(kitti_corpus(drives, 30, 20), i) for i in range(30)]
    assert {p.config.speed_scale for p in before} == {1.0}
    assert [p.split for p in plans] == [p.split for p in before]
    with pytest.raises(ValueError, match="--kitti-speed-scale must be two factors LO HI"):
        kitti_corpus(drives, 8, 20, kitti_speed_scale=(2.0, 1.0))
    slow = [plan_sequence(kitti_corpus(drives, 30, 20, kitti_speed_scale=(0.02, 1.0)), i) for i in range(30)]
    scales = np.array([p.config.speed_scale for p in slow])  # a crawl to a standstill, which KITTI rarely reaches
    assert scales.min() < 0.2 and scales.max() <= 1.0
    assert all(p.config.start_frame + int(np.ceil(19 * p.config.speed_scale - 1e-9)) + 1 <= 60 for p in slow)
    with pytest.raises(ValueError, match="with 0.02 <= LO <= HI <= 4, got \\[0.01, 1.0\\]"):
        kitti_corpus(drives, 8, 20, kitti_speed_scale=(0.01, 1.0))
    with pytest.raises(ValueError, match="holds fewer than the 77 poses a window of 20 frames spans"):
        kitti_corpus(drives, 8, 20, kitti_speed_scale=(1.0, 4.0))


def test_vehicle_speeds_are_drawn_last_and_only_where_vehicles_move() -> None:
    """``vehicle_speed``: each sequence with moving vehicles draws its vehicles' speed from the range and says so;
    every other draw is the plain corpus's; a bad range is one line."""
    from pvo_sim.degrade import Degradations

    plain = [plan_sequence(CorpusConfig(sequences=40, frames=5, seed=3), i) for i in range(40)]
    fast = [plan_sequence(CorpusConfig(sequences=40, frames=5, seed=3, vehicle_speed=(5.0, 15.0)), i) for i in range(40)]
    moving = [p.config.degradations.moving_vehicles > 0 for p in plain]
    assert 5 <= sum(moving) <= 35
    for before, after, has_vehicles in zip(plain, fast, moving, strict=True):
        speed = after.config.degradations.vehicle_speed
        assert (5.0 <= speed <= 15.0) if has_vehicles else speed == 0.0
        assert replace(after.config, degradations=replace(after.config.degradations, vehicle_speed=0.0)) == before.config
        assert list(after.conditions) == list(before.conditions) + ([f"vehicles at {speed:.1f} m/s"] if has_vehicles else [])
    assert Degradations().vehicle_speed == 0.0
    with pytest.raises(ValueError, match=r"--vehicle-speed must be two speeds LO HI with 0 <= LO <= HI <= 40 m/s"):
        CorpusConfig(vehicle_speed=(10.0, 5.0))


def test_urban_cameras_can_be_pitched_and_the_default_draws_stay() -> None:
    """With --urban-pitch every urban sequence's camera is pitched down by a draw from the range, the planetary ones
    as before; without it the plans are those of a corpus made before the option (urban level, the same draws)."""
    pitched = CorpusConfig(sequences=60, frames=10, seed=3, urban_pitch=(5.0, 25.0))
    level = CorpusConfig(sequences=60, frames=10, seed=3)
    plans = [plan_sequence(pitched, i) for i in range(60)]
    before = [plan_sequence(level, i) for i in range(60)]
    urban = np.array([p.config.pitch_deg for p in plans if p.config.preset == "urban"])
    assert len(urban) > 15 and urban.min() >= 5.0 and urban.max() <= 25.0 and np.ptp(urban) > 10.0
    assert {p.config.pitch_deg for p in before if p.config.preset == "urban"} == {0.0}
    assert [p.split for p in plans] == [p.split for p in before] and [p.config.preset for p in plans] == [
        p.config.preset for p in before
    ]
    assert plan_sequence(CorpusConfig(sequences=60, frames=10, seed=3, urban_pitch=(0.0, 0.0)), 7) == before[7]
    for bad in ((10.0, 5.0), (0.0, 50.0), (-1.0, 5.0)):
        with pytest.raises(ValueError, match="--urban-pitch must be two angles LO HI with 0 <= LO <= HI <= 45 degrees"):
            CorpusConfig(sequences=2, frames=10, urban_pitch=bad)


def test_a_corpus_made_before_a_new_option_is_kept(tmp_path: Path) -> None:
    """A manifest recorded before a field was added to SimConfig still matches plans that leave it at its default
    (nothing re-rendered); a plan that sets it does not match."""
    from dataclasses import asdict

    from pvo_sim.corpus import _plain, _same_config

    planned = _plain(asdict(plan_sequence(TINY, 0).config))
    recorded = {k: v for k, v in planned.items() if k != "speed_scale"}
    assert _same_config(recorded, planned)
    assert not _same_config(recorded, {**planned, "speed_scale": 1.5})
    assert not _same_config({**recorded, "frames": 3}, planned)
    assert not _same_config(None, planned)


def test_turning_windows_are_drawn_in_proportion_to_their_turning(tmp_path: Path) -> None:
    """A drive straight for 100 poses, then turning 1 degree per frame for 20: a 10-pose window's weight is its
    total turn plus a tenth of the mean's, and the turning draw lands in the turn far more often."""
    from pvo_core.lie import so3_exp
    from pvo_sim.corpus import turning_weights

    rows = []
    for k in range(120):
        rotation = so3_exp(np.array([0.0, np.radians(max(0, k - 100)), 0.0]))
        rows.append(" ".join(f"{v:.12g}" for v in np.hstack([rotation, [[k], [0], [0]]]).reshape(-1)))
    drive = tmp_path / "00.txt"
    drive.write_text("\n".join(rows) + "\n")
    weights = turning_weights(drive, 10)
    turning = np.array([np.radians(max(0, start + 9 - max(start, 100))) for start in range(111)])
    expected = turning + 0.1 * turning.mean()
    np.testing.assert_allclose(weights, expected / expected.sum(), rtol=1e-6)  # poses written to 12 digits
    for name in ("02", "04", "05"):
        (tmp_path / f"{name}.txt").write_text(drive.read_text())
    config = kitti_corpus(tmp_path, 40, 10, kitti_turning=True)
    starts = np.array([plan_sequence(config, i).config.start_frame for i in range(40)])
    assert np.mean(starts > 91) > 0.6  # windows holding part of the turn: 19 of 111 starts, most of the weight
    uniform = replace(config, kitti_turning=False)
    assert np.mean([plan_sequence(uniform, i).config.start_frame > 91 for i in range(40)]) < 0.4


def test_sun_elevations_span_low_to_high() -> None:
    from pvo_core.ephemeris import GeodeticOrigin, sun_elevation_azimuth

    from pvo_sim import SimConfig

    big = CorpusConfig(sequences=120, frames=10, seed=5)
    elevations, azimuths = [], []
    for i in range(120):
        config = plan_sequence(big, i).config
        assert isinstance(config, SimConfig)
        e, a = sun_elevation_azimuth(GeodeticOrigin(config.latitude, config.longitude, 0.0), np.array([config.epoch]))
        elevations.append(float(e[0]))
        azimuths.append(float(a[0]))
    assert min(elevations) >= 5.0 and min(elevations) < 15.0 and max(elevations) > 55.0
    assert np.ptp(np.mod(azimuths, 360.0)) > 270.0


def test_bad_corpus_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="presets"):
        CorpusConfig(presets=("lunar",))
    with pytest.raises(ValueError, match="split"):
        CorpusConfig(split=(0.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="overcast"):
        CorpusConfig(overcast=1.5)
    with pytest.raises(ValueError, match="--supersample must be 1, 2, 3 or 4, got 0"):
        CorpusConfig(supersample=0)


def _render(out: Path, **kwargs) -> corpus_module.CorpusResult:
    try:
        return render_corpus(TINY, out, **kwargs)
    except ValueError as exc:
        if "no offscreen renderer" in str(exc):
            pytest.skip(str(exc))
        raise


def test_corpus_is_deterministic_and_resumes_after_a_killed_run(tmp_path: Path, monkeypatch) -> None:
    whole = _render(tmp_path / "whole")
    manifest = read_manifest(tmp_path / "whole")
    assert [e["name"] for e in manifest["sequences"]] == ["0000", "0001", "0002"]
    assert whole.rendered == ["0000", "0001", "0002"]
    for entry in manifest["sequences"]:
        folder = tmp_path / "whole" / entry["name"]
        assert entry["sha256"] == content_hash(folder)
        assert entry["split"] in ("train", "validation", "test")
        assert (folder / "image_0" / "000001.png").is_file() and (folder / "sun.csv").is_file()
        assert yaml.safe_load((folder / "sim.yaml").read_text())["config"] == entry["config"]

    # a run killed while rendering the second sequence: the first is in the manifest, the second half-done
    real = corpus_module._render_one
    calls = []

    def dies_on_the_second(plan, out):
        calls.append(plan.name)
        if len(calls) == 2:
            (out / f".{plan.name}.partial").mkdir()  # what simulate leaves when killed mid-sequence
            raise KeyboardInterrupt
        return real(plan, out)

    monkeypatch.setattr(corpus_module, "_render_one", dies_on_the_second)
    with pytest.raises(KeyboardInterrupt):
        _render(tmp_path / "killed")
    assert [e["name"] for e in read_manifest(tmp_path / "killed")["sequences"]] == ["0000"]
    monkeypatch.setattr(corpus_module, "_render_one", real)
    resumed = _render(tmp_path / "killed")
    assert resumed.kept == ["0000"] and resumed.rendered == ["0001", "0002"]
    again = read_manifest(tmp_path / "killed")
    assert [e["sha256"] for e in again["sequences"]] == [e["sha256"] for e in manifest["sequences"]]
    assert _render(tmp_path / "killed").rendered == []  # nothing left to do


def test_parallel_jobs_render_the_same_corpus(tmp_path: Path) -> None:
    serial = _render(tmp_path / "serial")
    parallel = _render(tmp_path / "parallel", jobs=2)
    assert sorted(parallel.rendered) == serial.rendered
    hashes = [[e["sha256"] for e in read_manifest(tmp_path / d)["sequences"]] for d in ("serial", "parallel")]
    assert hashes[0] == hashes[1]


def test_a_changed_configuration_is_rendered_again(tmp_path: Path) -> None:
    _render(tmp_path / "c")
    manifest = read_manifest(tmp_path / "c")
    manifest["sequences"][1]["config"]["speed"] = 99.0  # as if made by other settings
    (tmp_path / "c" / "manifest.yaml").write_text(yaml.safe_dump(manifest, sort_keys=False))
    assert _render(tmp_path / "c").rendered == ["0001"]


def test_an_unreadable_manifest_is_one_clear_error(tmp_path: Path) -> None:
    (tmp_path / "manifest.yaml").write_text("sequences: [unclosed")
    with pytest.raises(ValueError, match="manifest.yaml: unreadable corpus manifest"):
        render_corpus(TINY, tmp_path)


def test_one_lens_for_the_whole_corpus() -> None:
    lens = CorpusConfig(sequences=30, frames=10, seed=5, lens_distortion=(-0.3, 0.2, 0.01))
    plain = CorpusConfig(sequences=30, frames=10, seed=5)
    for i in range(30):
        plan, before = plan_sequence(lens, i), plan_sequence(plain, i)
        assert plan.config.degradations.radial == (-0.3, 0.2, 0.01) and "lens distortion" in plan.conditions
        assert "radial distortion" not in plan.conditions
        assert plan.config.seed == before.config.seed and plan.split == before.split  # nothing else changes


def test_one_calibration_error_for_the_whole_corpus() -> None:
    wrong = CorpusConfig(sequences=30, frames=10, seed=5, calib_focal_scale=1.03, calib_baseline_scale=0.98)
    plain = CorpusConfig(sequences=30, frames=10, seed=5)
    for i in range(30):
        plan, before = plan_sequence(wrong, i), plan_sequence(plain, i)
        assert (plan.config.degradations.focal_scale, plan.config.degradations.baseline_scale) == (1.03, 0.98)
        assert "rig calibration error" in plan.conditions and "wrong calibration" not in plan.conditions
        assert plan.config.seed == before.config.seed and plan.config.focal == before.config.focal  # the same images
    with pytest.raises(ValueError, match=r"--calib-focal-scale must be in \[0.5, 2\]"):
        CorpusConfig(calib_focal_scale=0.0)


def test_the_sun_sky_changes_the_sky_and_nothing_drawn() -> None:
    sky = CorpusConfig(sequences=30, frames=10, seed=5, sky="sun")
    plain = CorpusConfig(sequences=30, frames=10, seed=5)
    for i in range(30):
        plan, before = plan_sequence(sky, i), plan_sequence(plain, i)
        assert plan.config.sky == "sun" and before.config.sky == "gradient"
        assert replace(plan.config, sky="gradient") == before.config and plan.conditions == before.conditions
    with pytest.raises(ValueError, match="--sky must be one of gradient, sun"):
        CorpusConfig(sky="cloudy")
