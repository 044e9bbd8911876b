"""`pvo experiment sun-sim` (thesis Table 5.2) as a command: its simulated sun, its record, its errors."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from pvo_core.readers import read_kitti_sun_sequence
from pvo_tools.experiments.sun_sim import sun_measurements, sun_seed


def test_simulated_sun_every_tenth_frame_and_seeded(pvo_data: Path) -> None:
    seq = read_kitti_sun_sequence(pvo_data, "04")
    sun = sun_measurements(seq, 10.0, sun_seed(0, "04", 10.0))
    assert [int((m.stamp - seq.stamps[0]) // 100_000_000) for m in sun] == list(range(0, 271, 10))
    again = sun_measurements(seq, 10.0, sun_seed(0, "04", 10.0))
    assert all(np.array_equal(a.direction, b.direction) for a, b in zip(sun, again, strict=True))
    other = sun_measurements(seq, 10.0, sun_seed(1, "04", 10.0))
    assert not np.array_equal(sun[0].direction, other[0].direction)


def test_sun_seeds_keep_numbered_sequences_and_take_any_drive_name() -> None:
    # the numbered sequences keep the seeds every earlier GT-Sun figure was drawn with
    assert sun_seed(0, "04", 10.0) == 4100 and sun_seed(2, "0014", 20.0) == 214_200
    # a validation drive's name (stop 78: `int("03b")` stopped the GT-Sun rows on them) gets its own stable seed
    named = {name: sun_seed(0, name, 10.0) for name in ("03b", "03bm", "10am", "04")}
    assert len(set(named.values())) == 4 and named["03bm"] == sun_seed(0, "03bm", 10.0)
    assert sun_seed(1, "03bm", 10.0) != named["03bm"]


def test_cli_runs_one_sequence_and_writes_the_run_record(pvo_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "sun"
    command = ["pvo", "experiment", "sun-sim", "--data", str(pvo_data), "--sequences", "04", "--levels", "0", "30"]
    result = subprocess.run([*command, "-q", "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "Trans. ARMSE (EN-plane) [m]" in result.stdout and "GT-Sun-30" in result.stdout
    assert "ARMSE = mean over frames k of CRMSE(k)" in result.stdout
    record = json.loads((out / "metrics.json").read_text())
    assert record["schema"] == "pvo.run-result/1" and record["kind"] == "experiment/sun-sim"
    rows = record["tables"]["sequence 04"]
    assert set(rows) == {"Without Sun", "GT-Sun-0", "GT-Sun-30"}
    assert rows["GT-Sun-0"]["rot"] < rows["Without Sun"]["rot"]
    assert 0.0 < rows["Without Sun"]["anees"]
    assert record["figures"]["GT-Sun-0.rot_change"] == rows["GT-Sun-0"]["rot"] / rows["Without Sun"]["rot"] - 1.0
    assert (out / "report.md").is_file()
    bad = subprocess.run(["pvo", "experiment", "sun-sim", "--data", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "has no kitti/ folder" in bad.stderr


def test_experiments_are_listed_and_unknown_kinds_are_errors() -> None:
    listing = subprocess.run(["pvo", "experiment", "list"], capture_output=True, text=True, timeout=60)
    rows = [line.split(None, 1) for line in listing.stdout.splitlines()]
    assert listing.returncode == 0 and [name for name, _ in rows] == [
        "sun-sim",
        "sun-bcnn",
        "probe",
        "hydranet-1d",
        "hydranet",
        "dpc-net",
    ]
    titles = dict(rows)
    assert titles["sun-sim"].startswith("Table 5.2") and titles["sun-bcnn"].startswith("Sun-BCNN (ch. 5)")
    assert titles["probe"].startswith("PROBE (ch. 4") and titles["hydranet-1d"].startswith("HydraNet 1-D")
    assert titles["dpc-net"].startswith("DPC-Net (ch. 6, Tables 6.1-6.2)")
    assert len({len(line) - len(line.split(None, 1)[1]) for line in listing.stdout.splitlines()}) == 1  # one column
    for command in (["pvo", "experiment", "sun-real"], ["pvo", "bench", "gpu"]):
        bad = subprocess.run(command, capture_output=True, text=True, timeout=60)
        assert bad.returncode == 2 and "invalid choice" in bad.stderr, bad.stderr


def test_bench_fusion_reads_noisy_relative_rotations_every_frame(pvo_data: Path, capsys) -> None:
    """`pvo bench fusion --rotations SIGMA`: one reading per frame pair, C_k,k-1 off the truth by about SIGMA per axis,
    published with that covariance and fused by the rotation factor."""
    from pvo_core.lie import so3_log
    from pvo_tools.cli import main
    from pvo_tools.commands.bench import noisy_relative_rotations

    seq = read_kitti_sun_sequence(pvo_data, "04")
    readings = noisy_relative_rotations(seq.stamps, seq.ground_truth, 0.5)
    assert len(readings) == len(seq.stamps) - 1 and all(r.rotation_only for r in readings)
    truth = [seq.ground_truth[k][:3, :3].T @ seq.ground_truth[k - 1][:3, :3] for k in range(1, len(seq.stamps))]
    errors = np.degrees([so3_log(c.T @ r.transform[:3, :3]) for c, r in zip(truth, readings, strict=True)])
    assert np.std(errors, axis=0) == pytest.approx([0.5, 0.5, 0.5], rel=0.15)
    np.testing.assert_allclose(readings[0].covariance[3:, 3:], np.eye(3) * np.radians(0.5) ** 2)
    assert [r.reference_stamp for r in readings[1:]] == [r.stamp for r in readings[:-1]]
    with pytest.raises(ValueError, match="the noise must be a positive number of degrees, got -1.0"):
        noisy_relative_rotations(seq.stamps, seq.ground_truth, -1.0)
    command = ["bench", "fusion", "--data", str(pvo_data), "--sequence", "04", "--repeat", "1", "--rotations", "0.05"]
    assert main([*command, "-p", "inputs.rotation.gate_probability=0"]) == 0  # no gate: every reading fused
    out = capsys.readouterr().out
    assert "270 relative rotations (0.05 deg per axis)" in out and "'rotation': 270" in out
    assert main(["bench", "fusion", "--data", str(pvo_data), "--sequence", "04", "--rotations", "nan"]) == 2
    assert "--rotations: the noise must be a positive number of degrees, got nan" in capsys.readouterr().err
