"""`pvo sim` as a command: the bag it writes carries the sidecars; a missing renderer is one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pvo_sim import SimConfig


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> tuple[Path, SimConfig]:
    """Eight frames rendered by the command itself."""
    from pvo_tools.cli import main

    out = tmp_path_factory.mktemp("sim") / "urban"
    args = ["sim", str(out), "--frames", "8", "--size", "320x120", "--focal", "185.4", "--path", "straight", "--speed", "6"]
    if main([*args, "-q"]) != 0:
        pytest.skip("pvo sim could not render here (no offscreen renderer)")
    return out, SimConfig(width=320, height=120, focal=185.4, path="straight", speed=6.0, frames=8)


def test_the_bag_carries_imu_and_gps_from_the_sidecars(sequence, tmp_path: Path) -> None:
    from pvo_core.errors import DataFormatError
    from pvo_core.readers import KittiSequence, read_gps_csv, read_imu_csv
    from pvo_tools.bagio import iter_messages, open_bag
    from pvo_tools.convert import convert_kitti
    from pvo_tools.typesys import project_typestore

    out, config = sequence
    imu, gps = read_imu_csv(out / "imu.csv"), read_gps_csv(out / "gps.csv")
    kitti = KittiSequence(out, poses_file=out / "poses.txt", sun_file=out / "sun.csv")
    summary = convert_kitti(kitti, tmp_path / "bag", epoch=config.epoch, show_progress=False, imu=imu, gps=gps)
    assert summary.counts["/imu/data"] == 8 and summary.counts["/gps/fix"] == 8
    store = project_typestore()
    with open_bag(tmp_path / "bag") as reader:
        messages = {
            c.topic: store.deserialize_cdr(raw, c.msgtype)
            for c, _, raw in iter_messages(reader)
            if c.topic in ("/imu/data", "/gps/fix")
        }
    last_imu, last_fix = messages["/imu/data"], messages["/gps/fix"]
    np.testing.assert_allclose([last_imu.angular_velocity.x, last_imu.linear_acceleration.z], [imu[-1, 1], imu[-1, 6]])
    assert last_imu.orientation_covariance[0] == -1.0
    assert last_fix.latitude == pytest.approx(gps[-1, 1]) and last_fix.status.status == 0
    bad = tmp_path / "imu.csv"
    bad.write_text("time,wx\n0,1\n")
    with pytest.raises(DataFormatError, match="expected the header"):
        read_imu_csv(bad)


def test_a_missing_renderer_backend_is_one_line(tmp_path: Path) -> None:
    import os
    import subprocess

    env = dict(os.environ, MUJOCO_GL="osmesa", PYOPENGL_PLATFORM="osmesa")
    try:
        import ctypes.util

        if ctypes.util.find_library("OSMesa"):
            pytest.skip("libosmesa6 is installed here: the osmesa back-end works")
    except ImportError:
        pass
    result = subprocess.run(
        ["pvo", "sim", str(tmp_path / "x"), "--frames", "2", "-q"], env=env, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "no offscreen renderer (MUJOCO_GL=osmesa): install libosmesa6" in lines[0]


def test_sim_corpus_command_renders_resumes_and_reports(tmp_path: Path, capsys) -> None:
    import yaml
    from pvo_tools.cli import main

    args = ["sim", "corpus", str(tmp_path / "c"), "--sequences", "2", "--frames", "2", "--size", "96x48", "-q"]
    if main(args) != 0:
        pytest.skip("pvo sim corpus could not render here (no offscreen renderer)")
    first = capsys.readouterr().out
    assert "2 sequence(s) rendered, 0 kept" in first
    manifest = yaml.safe_load((tmp_path / "c" / "manifest.yaml").read_text())
    assert [s["name"] for s in manifest["sequences"]] == ["0000", "0001"]
    assert main(args) == 0
    assert "0 sequence(s) rendered, 2 kept" in capsys.readouterr().out
    # --dry-run: what the command would do, rendering nothing
    more = [*args[:4], "3", *args[5:]]  # --sequences 3
    assert main([*more, "--dry-run"]) == 0
    said = capsys.readouterr().out
    assert "3 sequence(s) planned, 2 kept, 1 to render (2 stereo frames); " in said
    sunny = sum(not yaml.safe_load((tmp_path / "c" / n / "sim.yaml").read_text())["config"]["overcast"] for n in ("0000", "0001"))
    assert sunny >= 1 and " whose world renderer revision 9 changed" in said  # shadows: every sequence with sunshine
    assert not (tmp_path / "c" / "0002").exists()
    assert len(yaml.safe_load((tmp_path / "c" / "manifest.yaml").read_text())["sequences"]) == 2
    # its mirror, with progress on stderr; again: nothing left to do; a folder that is neither is one line
    assert main(["sim", "mirror", str(tmp_path / "c"), str(tmp_path / "m")]) == 0
    printed = capsys.readouterr()
    assert "2 sequence(s) mirrored now" in printed.out and "pvo sim mirror (sequences)" in printed.err
    assert main(["sim", "mirror", str(tmp_path / "c"), str(tmp_path / "m"), "-q"]) == 0
    assert "0 sequence(s) mirrored now" in capsys.readouterr().out
    assert main(["sim", "mirror", str(tmp_path / "nowhere"), str(tmp_path / "m2")]) == 2
    assert "nowhere: no such corpus or sequence directory" in capsys.readouterr().err


def test_sim_corpus_degradation_shares_reach_every_sequence_and_the_card_command(tmp_path: Path) -> None:
    import yaml
    from pvo_core.readers import read_corpus_manifest
    from pvo_tools.cli import main
    from pvo_tools.commands.models import _corpus_command

    out = tmp_path / "c"
    shares = ["--radial-distortion", "1", "--moving-vehicles", "0", "--jpeg", "0", "--overcast", "0"]
    if main(["sim", "corpus", str(out), "--sequences", "3", "--frames", "2", "--size", "96x48", *shares, "-q"]) != 0:
        pytest.skip("pvo sim corpus could not render here (no offscreen renderer)")
    manifest = yaml.safe_load((out / "manifest.yaml").read_text())
    assert manifest["corpus"]["radial_distortion"] == 1.0 and manifest["corpus"]["moving_vehicles"] == 0.0
    for sequence in manifest["sequences"]:
        config = yaml.safe_load((out / sequence["name"] / "sim.yaml").read_text())["config"]
        assert -0.3 <= config["degradations"]["distortion"] <= 0.2 and config["degradations"]["distortion"] != 0.0
        assert "radial distortion" in sequence["conditions"] and "moving vehicles" not in sequence["conditions"]
    command = _corpus_command(read_corpus_manifest(out))
    for option in ("--overcast 0", "--moving-vehicles 0", "--radial-distortion 1", "--jpeg 0"):
        assert f" {option}" in command
    assert "--motion-blur" not in command  # a default share is not repeated


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--presets", "lunar"], "--presets lunar: choose from urban, planetary"),
        (["--split", "0.5,0.5"], "--split '0.5,0.5' must be three numbers"),
        (["--jobs", "0"], "--jobs must be >= 1"),
        (["--kitti-speed-scale", "2", "1"], "--kitti-speed-scale must be two factors LO HI with 0.02 <= LO <= HI <= 4"),
        (["--radial-distortion", "1.5"], "--radial-distortion must be a fraction in [0, 1], got 1.5"),
        (["--vehicle-speed", "10", "5"], "--vehicle-speed must be two speeds LO HI with 0 <= LO <= HI <= 40 m/s"),
    ],
)
def test_sim_corpus_bad_options_are_one_line(tmp_path: Path, capsys, extra: list[str], message: str) -> None:
    from pvo_tools.cli import main

    assert main(["sim", "corpus", str(tmp_path / "c"), "--frames", "2", *extra]) == 2
    assert message in capsys.readouterr().err


def test_camera_and_pitch_options_reach_the_configuration(tmp_path: Path) -> None:
    import yaml
    from pvo_tools.cli import main

    out = tmp_path / "s"
    args = ["sim", str(out), "--frames", "2", "--size", "96x48", "--pitch", "15", "--gamma", "1.5", "--jpeg", "80", "-q"]
    if main(args) != 0:
        pytest.skip("pvo sim could not render here (no offscreen renderer)")
    config = yaml.safe_load((out / "sim.yaml").read_text())["config"]
    assert config["pitch_deg"] == 15.0 and config["camera"]["gamma"] == 1.5 and config["camera"]["jpeg_quality"] == 80
    assert main(["sim", str(tmp_path / "bad"), "--pitch", "80", "-q"]) == 2


def test_a_negative_level_frames_is_one_line_naming_the_option(tmp_path, capsys, pvo_data) -> None:
    from pvo_tools.cli import main

    poses = str(pvo_data / "kitti" / "poses" / "04.txt")
    assert main(["sim", str(tmp_path / "bad"), "--poses", poses, "--frames", "3", "--level-frames", "-1", "-q"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "pvo: error: --level-frames must be >= 0 (0: the window levelled on itself), got -1"
    )
    assert not (tmp_path / "bad" / "image_0").exists()


def test_a_drive_replayed_faster_from_the_command_line(tmp_path, capsys, pvo_data) -> None:
    """`pvo sim --poses 04.txt --speed-scale 2` records the factor and its poses.txt is every second pose of the
    drive replayed as driven; a factor without a drive, or a non-positive one, is one line."""
    import yaml
    from pvo_core.trajectory import read_kitti_poses
    from pvo_tools.cli import main

    poses = str(pvo_data / "kitti" / "poses" / "04.txt")
    common = ["--poses", poses, "--start", "10", "--size", "96x48", "-q"]
    if main(["sim", str(tmp_path / "fast"), "--frames", "3", "--speed-scale", "2", *common]) != 0:
        pytest.skip("pvo sim could not render here (no offscreen renderer)")
    assert main(["sim", str(tmp_path / "driven"), "--frames", "5", *common]) == 0
    assert yaml.safe_load((tmp_path / "fast" / "sim.yaml").read_text())["config"]["speed_scale"] == 2.0
    fast, driven = (read_kitti_poses(tmp_path / name / "poses.txt") for name in ("fast", "driven"))
    np.testing.assert_allclose(fast, driven[::2], atol=1e-6)  # poses.txt written to 9 digits
    capsys.readouterr()
    assert main(["sim", str(tmp_path / "bad"), "--frames", "3", "--speed-scale", "2", "-q"]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        "pvo: error: --speed-scale replays a KITTI drive faster: give the drive with --poses"
    )
    assert main(["sim", str(tmp_path / "bad"), "--frames", "3", "--speed-scale", "0", *common]) == 2
    assert "--speed-scale must be positive" in capsys.readouterr().err
    assert main(["sim", str(tmp_path / "bad"), "--frames", "3", "--vehicle-speed", "-2", *common]) == 2
    assert "--vehicle-speed must be in [0, 40] m/s, got -2.0" in capsys.readouterr().err
    assert not (tmp_path / "bad").exists()


def test_a_mirrored_turning_drive_is_seen_by_the_vo_as_the_mirrored_motion(tmp_path: Path, capsys) -> None:
    """`pvo sim mirror`: the VO on the mirrored images tracks the mirrored truth as well as it tracks the original
    (images, swap and poses agree) and turns the other way."""
    from pvo_core.lie import so3_exp, so3_log
    from pvo_core.readers import KittiSequence
    from pvo_core.trajectory import read_kitti_poses
    from pvo_frontend.offline import run_sequence
    from pvo_frontend.vo import VOConfig
    from pvo_tools.cli import main

    poses = [np.eye(4)]
    for _ in range(15):  # turning right 1.7 deg a frame at 10 m/s
        step = np.eye(4)
        step[:3, :3], step[2, 3] = so3_exp(np.array([0.0, 0.03, 0.0])), 1.0
        poses.append(poses[-1] @ step)
    np.savetxt(tmp_path / "drive.txt", np.array(poses)[:, :3].reshape(len(poses), 12))
    original, mirrored = tmp_path / "turning", tmp_path / "mirrored"
    args = [
        "sim",
        str(original),
        "--frames",
        "14",
        "--size",
        "320x120",
        "--focal",
        "185.4",
        "--poses",
        str(tmp_path / "drive.txt"),
        "--moving",  # what is checked is the mirror: no vehicle's own motion to mislead the VO on 320x120 images
        "0",
    ]
    if main([*args, "-q"]) != 0:
        pytest.skip("pvo sim could not render here (no offscreen renderer)")
    assert main(["sim", "mirror", str(original), str(mirrored)]) == 0
    assert f"{mirrored}: 14 stereo frames mirrored left-right" in capsys.readouterr().out

    def steps(folder: Path) -> tuple[np.ndarray, np.ndarray]:
        """Per frame: the VO's rotation vector (rad) and its error against the truth's (deg) and translation error (m)."""
        estimate = run_sequence(KittiSequence(folder), VOConfig()).poses
        truth = read_kitti_poses(folder / "poses.txt")
        rows = []
        for k in range(1, len(truth)):
            est, gt = np.linalg.inv(estimate[k - 1]) @ estimate[k], np.linalg.inv(truth[k - 1]) @ truth[k]
            error = np.linalg.inv(gt) @ est
            rows.append([*so3_log(est[:3, :3]), np.degrees(np.linalg.norm(so3_log(error[:3, :3]))), np.linalg.norm(error[:3, 3])])
        rows_array = np.array(rows)
        return rows_array[:, :3], rows_array[:, 3:]

    rotation, errors = steps(original)
    rotation_mirrored, errors_mirrored = steps(mirrored)
    print(f"per frame (deg, m): original {errors.mean(axis=0).round(3)}, mirrored {errors_mirrored.mean(axis=0).round(3)}")
    assert np.median(rotation[:, 1]) > 0.02 and np.median(rotation_mirrored[:, 1]) < -0.02
    assert np.abs(rotation_mirrored[:, 1] + rotation[:, 1]).mean() < 0.006  # rad; a turn is 0.03
    # per frame, deg and m: (0.105, 0.105) on the original, (0.163, 0.136) mirrored when written (with moving vehicles;
    # renderer revision 9 without them: (0.048, 0.039), (0.065, 0.042)); the truth not mirrored
    # would be 3.4 deg off
    assert errors_mirrored[:, 0].mean() < 0.4 and errors_mirrored[:, 1].mean() < 0.25
    assert np.all(errors_mirrored.mean(axis=0) < 2 * errors.mean(axis=0) + 0.05)
