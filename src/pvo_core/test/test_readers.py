"""Dataset readers on the real KITTI/Devon files and on broken copies of them."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from pvo_core.errors import DataFormatError
from pvo_core.imageio import read_image
from pvo_core.readers import (
    DevonDataset,
    KittiSequence,
    read_devon_sun_sensor,
    read_devon_sun_sensor_sampled,
    read_kitti_calibration,
    read_kitti_sun_csv,
    read_kitti_times,
)
from pvo_core.sun import vector_to_zenith_azimuth, zenith_azimuth_to_vector
from pvo_core.trajectory import Trajectory, read_kitti_poses, read_tum_trajectory, write_kitti_poses, write_tum_trajectory


def make_clip(pvo_data: Path, tmp_path: Path, frames: int = 3) -> Path:
    """A copy of the first frames of the real 06 clip (images, unlabelled calib, poses)."""
    source = pvo_data / "kitti" / "sequences" / "06"
    clip = tmp_path / "06"
    for side in ("image_0", "image_1"):
        (clip / side).mkdir(parents=True)
        for i in range(frames):
            shutil.copy(source / side / f"{i:06d}.png", clip / side)
    shutil.copy(source / "calib_P0_P1_unlabelled.txt", clip / "calib.txt")
    lines = (source / "poses_frames000-050.txt").read_text().splitlines()[:frames]
    (clip / "poses.txt").write_text("\n".join(lines) + "\n")
    return clip


def test_kitti_calibration_labelled_and_unlabelled(pvo_data: Path) -> None:
    unlabelled = read_kitti_calibration(pvo_data / "kitti/sequences/06/calib_P0_P1_unlabelled.txt")
    labelled = read_kitti_calibration(pvo_data / "kitti/sequences/07/calib.txt")
    assert set(unlabelled) == {"P0", "P1"} and set(labelled) == {"P0", "P1", "P2", "P3"}
    np.testing.assert_allclose(unlabelled["P0"], labelled["P0"])
    assert unlabelled["P1"][0, 3] == pytest.approx(-379.8145)


def test_kitti_sequence_on_real_clip(pvo_data: Path) -> None:
    sequence = KittiSequence(
        pvo_data / "kitti/sequences/06",
        rate_hz=10.0,
        poses_file=pvo_data / "kitti/sequences/06/poses_frames000-050.txt",
        sun_file=pvo_data / "kitti/sun/kitti_sun_test_06.csv",
    )
    assert len(sequence) == 51
    np.testing.assert_allclose(sequence.stamps[:3], [0.0, 0.1, 0.2])
    camera = sequence.camera()
    assert camera.baseline == pytest.approx(0.53716, abs=1e-5)
    left, right = sequence.load_pair(50)
    assert left.shape == right.shape == (370, 1226) and left.dtype == np.uint8
    assert sequence.poses is not None and sequence.poses.shape == (51, 4, 4)
    full = read_kitti_poses(pvo_data / "kitti/poses/06.txt")
    np.testing.assert_allclose(sequence.poses, full[:51])
    assert sequence.sun_vectors is not None
    np.testing.assert_allclose(sequence.sun_vectors[0], [-0.80747, -0.58975, 0.01335], atol=2e-5)
    clip = KittiSequence(pvo_data / "kitti/sequences/06", rate_hz=10.0, start=10, count=5)
    assert clip.frames.tolist() == [10, 11, 12, 13, 14]
    np.testing.assert_allclose(clip.stamps, [1.0, 1.1, 1.2, 1.3, 1.4])


def test_kitti_colour_and_times(pvo_data: Path) -> None:
    colour = KittiSequence(pvo_data / "kitti/sequences/00-colour-pairs", colour=True, rate_hz=10.0)
    left, _ = colour.load_pair(0)
    assert left.ndim == 3 and left.shape[2] == 3
    assert colour.projection_left[0, 3] == pytest.approx(45.38225)
    times = read_kitti_times(pvo_data / "kitti/sequences/07/times.txt")
    assert len(times) == 1101 and times[1] == pytest.approx(0.1038752)


def test_missing_timing_is_reported(pvo_data: Path, tmp_path: Path) -> None:
    clip = make_clip(pvo_data, tmp_path)
    with pytest.raises(DataFormatError, match="no times.txt.*frame rate"):
        KittiSequence(clip)


def test_malformed_calibration(pvo_data: Path, tmp_path: Path) -> None:
    clip = make_clip(pvo_data, tmp_path)
    (clip / "calib.txt").write_text("P0: 1 2 3\nP1: 1 2 3 4 5 6 7 8 9 10 11 12\n")
    with pytest.raises(DataFormatError, match=r"calib.txt:1: P0 needs 12 numbers, got 3"):
        KittiSequence(clip, rate_hz=10)
    (clip / "calib.txt").unlink()
    with pytest.raises(DataFormatError, match="no calib.txt"):
        KittiSequence(clip, rate_hz=10)


def test_malformed_times_and_poses(pvo_data: Path, tmp_path: Path) -> None:
    clip = make_clip(pvo_data, tmp_path)
    (clip / "times.txt").write_text("0.0\n0.1\nabc\n")
    with pytest.raises(DataFormatError, match=r"times.txt:3: non-numeric time"):
        KittiSequence(clip)
    (clip / "times.txt").write_text("0.0\n0.2\n0.1\n")
    with pytest.raises(DataFormatError, match=r"times.txt:3: time 0.1 does not increase"):
        KittiSequence(clip)
    (clip / "times.txt").write_text("0.0\n0.1\n0.2\n")
    lines = (clip / "poses.txt").read_text().splitlines()
    (clip / "poses.txt").write_text("\n".join(lines[:2]) + "\n")
    with pytest.raises(DataFormatError, match=r"2 poses but the images go up to frame 2 \(3 images\)"):
        KittiSequence(clip)
    (clip / "poses.txt").write_text(lines[0] + "\n" + lines[1] + " 7\n" + lines[2] + "\n")
    with pytest.raises(DataFormatError, match=r"poses.txt:2: expected 12 numbers"):
        KittiSequence(clip)
    (clip / "poses.txt").write_text(lines[0] + "\n" + "nan " * 12 + "\n" + lines[2] + "\n")
    with pytest.raises(DataFormatError, match=r"poses.txt:2: NaN"):
        KittiSequence(clip)


def test_unreadable_and_mismatched_images(pvo_data: Path, tmp_path: Path) -> None:
    clip = make_clip(pvo_data, tmp_path)
    broken = clip / "image_1" / "000001.png"
    broken.write_bytes(broken.read_bytes()[:2000])
    sequence = KittiSequence(clip, rate_hz=10)
    sequence.load_pair(0)
    with pytest.raises(DataFormatError, match=r"image_1/000001.png: unreadable or truncated image"):
        sequence.load_pair(1)
    small = read_image(clip / "image_0" / "000002.png")[:100, :200]
    import cv2

    cv2.imwrite(str(clip / "image_1" / "000002.png"), small)
    with pytest.raises(DataFormatError, match=r"000002.png: size 200x100 differs from the left image's 1226x370"):
        sequence.load_pair(2)
    (clip / "image_1" / "000002.png").unlink()
    with pytest.raises(DataFormatError, match=r"image_0 has 3 images and image_1 2; unpaired frames \[2\]"):
        KittiSequence(clip, rate_hz=10)


def test_sun_csv_and_angles(pvo_data: Path, tmp_path: Path) -> None:
    vectors = read_kitti_sun_csv(pvo_data / "kitti/sun/kitti_sun_test_06.csv")
    assert vectors.shape == (1101, 3)
    zenith, azimuth = vector_to_zenith_azimuth(vectors)
    np.testing.assert_allclose(zenith_azimuth_to_vector(zenith, azimuth), vectors, atol=1e-12)
    np.testing.assert_allclose(zenith[0], np.arccos(0.58975), atol=1e-4)
    bad = tmp_path / "sun.csv"
    bad.write_text("a.png,0.1,0.2,0.3\n")
    with pytest.raises(DataFormatError, match=r"sun.csv:1: sun vector .* is not unit length"):
        read_kitti_sun_csv(bad)


def test_devon_on_real_files(pvo_data: Path, tmp_path: Path) -> None:
    dataset = DevonDataset(pvo_data / "devon")
    assert dataset.indices[:2] == [1, 2] and len(dataset.indices) == 60
    assert not dataset.has_right_images
    camera = dataset.camera()
    assert (camera.f, camera.baseline, camera.width) == (387.599884033, 0.239977002, 512)
    image = read_image(dataset.left_images[1])
    assert image.shape == (384, 512)
    import cv2

    np.testing.assert_array_equal(image, cv2.imread(str(dataset.left_images[1]), cv2.IMREAD_UNCHANGED))
    readings = read_devon_sun_sensor(pvo_data / "devon/logs/sun-sensor.txt")
    assert len(readings) == 15256
    assert readings[0].azimuth_deg == pytest.approx(-3.14521) and readings[0].zenith_deg == pytest.approx(61.91469)
    # 2008-07-12T09:57:01.328125-05:00 = 14:57:01.328125 UTC
    assert readings[0].stamp == pytest.approx(1215874621.328125)
    sampled = read_devon_sun_sensor_sampled(pvo_data / "devon/logs/sun-sensor-sampled.txt")
    assert sampled.shape == (13257, 4) and sampled[0, 0] == 4
    assert dataset.image_times() is None and dataset.gps_topocentric() is None
    truncated = tmp_path / "t.pgm"
    truncated.write_bytes(dataset.left_images[1].read_bytes()[:5000])
    with pytest.raises(DataFormatError, match=r"t.pgm: truncated image"):
        read_image(truncated)


def test_devon_logs(tmp_path: Path) -> None:
    folder = tmp_path / "grey-rectified-512x384-s00"
    folder.mkdir()
    header = b"P5\n4 2\n255\n"
    for side in ("left", "right"):
        (folder / f"grey-rectified-{side}-000001.pgm").write_bytes(header + bytes(range(8)))
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "image-times.txt").write_text("1 2008-07-12T09:57:01.500\n")
    (logs / "gps-topocentric.txt").write_text("1\t1.5\t-2.0\t0.25\n")
    (logs / "known-orientations.txt").write_text("1 -0.2660987251 -0.7639785818 0.5878164638 -2.8123980539\n")
    dataset = DevonDataset(tmp_path)
    assert dataset.has_right_images
    assert dataset.image_times() == {1: pytest.approx(1215874621.5)}
    np.testing.assert_allclose(dataset.gps_topocentric()[1], [1.5, -2.0, 0.25])
    rotvec = dataset.known_orientations()[1]
    assert np.linalg.norm(rotvec) == pytest.approx(2.8123980539)
    np.testing.assert_array_equal(read_image(folder / "grey-rectified-left-000001.pgm"), np.arange(8).reshape(2, 4))
    (logs / "gps-topocentric.txt").write_text("1 2 3\n")
    with pytest.raises(DataFormatError, match=r"gps-topocentric.txt:1: expected 4 fields"):
        dataset.gps_topocentric()


def test_trajectory_files_round_trip(pvo_data: Path, tmp_path: Path) -> None:
    poses = read_kitti_poses(pvo_data / "kitti/poses/06.txt")
    assert poses.shape == (1101, 4, 4)
    write_kitti_poses(tmp_path / "p.txt", poses[:20])
    np.testing.assert_allclose(read_kitti_poses(tmp_path / "p.txt"), poses[:20], atol=1e-8)
    trajectory = Trajectory(poses=poses[:20], stamps=np.arange(20) * 0.1)
    write_tum_trajectory(tmp_path / "t.txt", trajectory)
    back = read_tum_trajectory(tmp_path / "t.txt")
    np.testing.assert_allclose(back.poses, trajectory.poses, atol=1e-8)
    np.testing.assert_allclose(back.stamps, trajectory.stamps)
    summary = Trajectory(poses=poses[:51], stamps=np.arange(51) * 0.1).summary()
    assert summary["path_length_m"] == pytest.approx(59.86, abs=0.01)
