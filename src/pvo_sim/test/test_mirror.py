"""`pvo_sim.mirror`: a sequence mirrored left-right is the mirrored world's stereo sequence (swapped, flipped images;
the old right camera's poses through the mirror), mirroring twice gives the original back, a corpus keeps its
splits, and what cannot be mirrored is refused in one line."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from pvo_core.errors import DataFormatError
from pvo_core.lie import so3_exp, so3_log
from pvo_core.readers.corpus import read_corpus_manifest
from pvo_core.trajectory import read_kitti_poses
from pvo_sim.corpus import CorpusConfig, content_hash, render_corpus
from pvo_sim.mirror import MIRRORED, mirror_corpus, mirror_sequence, mirrored_poses, mirrored_sun
from pvo_sim.render import SimConfig, simulate


def _skip_without_renderer(error: ValueError) -> None:
    if "no offscreen renderer" in str(error):
        pytest.skip(str(error))
    raise error


def _poses(yaws: list[float], steps: list[list[float]]) -> np.ndarray:
    poses = [np.eye(4)]
    for yaw, step in zip(yaws, steps, strict=True):
        move = np.eye(4)
        move[:3, :3] = so3_exp(np.array([0.0, yaw, 0.0]))
        move[:3, 3] = step
        poses.append(poses[-1] @ move)
    return np.array(poses)


@pytest.fixture(scope="module")
def sequence(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("mirror")
    drive = _poses([0.04] * 7, [[0.0, 0.0, 1.0]] * 7)  # turning right 2.3 deg a frame
    np.savetxt(root / "drive.txt", drive[:, :3, :].reshape(len(drive), 12))
    out = root / "turning"
    config = SimConfig(width=160, height=64, focal=92.7, poses_file=str(root / "drive.txt"), frames=5, depth=True)
    try:
        simulate(config, out, overwrite=True)
    except ValueError as exc:
        _skip_without_renderer(exc)
    return out


def test_a_right_turn_becomes_a_left_turn_of_the_same_size_seen_from_the_other_camera() -> None:
    poses = _poses([0.1, 0.05, -0.02], [[0.3, 0.01, 1.0], [0.1, 0.0, 1.2], [-0.2, 0.02, 0.9]])
    mirrored = mirrored_poses(poses, baseline_m=0.54)
    assert np.allclose(mirrored[0], np.eye(4))
    assert np.allclose(np.linalg.det(mirrored[:, :3, :3]), 1.0)
    for k in range(1, len(poses)):
        step, step_mirrored = np.linalg.inv(poses[k - 1]) @ poses[k], np.linalg.inv(mirrored[k - 1]) @ mirrored[k]
        phi, phi_mirrored = so3_log(step[:3, :3]), so3_log(step_mirrored[:3, :3])
        assert phi_mirrored == pytest.approx(phi * [1.0, -1.0, -1.0], abs=1e-12)  # an axial vector through a mirror
        # the right camera's step (the left camera's conjugated by the baseline), x negated
        shift = np.eye(4)
        shift[0, 3] = 0.54
        right = np.linalg.inv(shift) @ step @ shift
        assert step_mirrored[:3, 3] == pytest.approx(right[:3, 3] * [-1.0, 1.0, 1.0], abs=1e-12)
    # through the mirror twice: the original rig again
    assert np.allclose(mirrored_poses(mirrored, 0.54), poses, atol=1e-12)
    assert mirrored_sun(np.array([[0.6, -0.8, 0.0]])) == pytest.approx(np.array([[-0.6, -0.8, 0.0]]))


def test_a_rendered_sequence_mirrored_twice_is_itself(sequence: Path, tmp_path: Path) -> None:
    import cv2

    once = mirror_sequence(sequence, tmp_path / "once")
    twice = mirror_sequence(once, tmp_path / "twice")
    left, right = cv2.imread(str(sequence / "image_0" / "000002.png")), cv2.imread(str(sequence / "image_1" / "000002.png"))
    assert np.array_equal(cv2.imread(str(once / "image_0" / "000002.png")), right[:, ::-1])
    assert np.array_equal(cv2.imread(str(once / "image_1" / "000002.png")), left[:, ::-1])
    for side in ("image_0", "image_1"):
        for image in sorted((sequence / side).glob("*.png")):
            assert np.array_equal(cv2.imread(str(twice / side / image.name)), cv2.imread(str(image)))
    assert np.allclose(read_kitti_poses(twice / "poses.txt"), read_kitti_poses(sequence / "poses.txt"), atol=1e-8)
    assert not (once / "depth_0").exists() and not (once / "imu.csv").exists()  # the old left camera's depth: not carried
    sun = np.loadtxt(sequence / "sun.csv", delimiter=",", usecols=(1, 2, 3))
    assert np.loadtxt(once / "sun.csv", delimiter=",", usecols=(1, 2, 3)) == pytest.approx(sun * [-1, 1, 1], abs=1e-8)
    assert yaml.safe_load((once / "sim.yaml").read_text())["mirrored_from"] == str(sequence)
    # the loop turns: through the mirror its yaw changes sign
    yaw = [so3_log(p[:3, :3])[1] for p in read_kitti_poses(sequence / "poses.txt")[1:]]
    yaw_mirrored = [so3_log(p[:3, :3])[1] for p in read_kitti_poses(once / "poses.txt")[1:]]
    assert abs(yaw[-1]) > 0.01 and yaw_mirrored == pytest.approx(-np.array(yaw), abs=1e-8)


def test_what_cannot_be_mirrored_is_refused_in_one_line(sequence: Path, tmp_path: Path) -> None:
    with pytest.raises(FileExistsError, match="exists"):
        mirror_sequence(sequence, sequence.parent)
    with pytest.raises(ValueError, match="another folder than its source"):
        mirror_sequence(sequence, sequence, overwrite=True)
    off_centre = tmp_path / "off-centre"
    shutil.copytree(sequence, off_centre)
    calib = (off_centre / "calib.txt").read_text().splitlines()
    values = calib[0].split()
    values[3] = f"{float(values[3]) + 2.0:.6e}"  # P0's cx moved 2 px
    (off_centre / "calib.txt").write_text("\n".join([" ".join(values), *calib[1:]]) + "\n")
    with pytest.raises(DataFormatError, match="principal point .* is not the centre of the 160x64 images"):
        mirror_sequence(off_centre, tmp_path / "out")
    shutil.copyfile(sequence / "calib.txt", off_centre / "calib.txt")
    (off_centre / "sun.csv").write_text("image,sx,sy,sz\n")
    with pytest.raises(DataFormatError, match="off-centre/sun.csv: not rows of image,sx,sy,sz"):
        mirror_sequence(off_centre, tmp_path / "out1")
    assert not (tmp_path / "out1").exists()  # refused before anything was written
    (off_centre / "poses.txt").unlink()
    with pytest.raises(DataFormatError, match="off-centre/poses.txt: needed to mirror the sequence but missing"):
        mirror_sequence(off_centre, tmp_path / "out2")


def test_a_mirrored_corpus_keeps_its_splits_and_resumes(tmp_path: Path) -> None:
    try:
        render_corpus(CorpusConfig(sequences=3, frames=2, width=96, height=48, seed=11), tmp_path / "corpus")
    except ValueError as exc:
        _skip_without_renderer(exc)
    assert mirror_corpus(tmp_path / "corpus", tmp_path / "mirror") == ["0000", "0001", "0002"]
    source, mirrored = read_corpus_manifest(tmp_path / "corpus"), read_corpus_manifest(tmp_path / "mirror")
    assert [(s.name, s.split, s.preset) for s in mirrored.sequences] == [(s.name, s.split, s.preset) for s in source.sequences]
    assert all(m.conditions == (*s.conditions, MIRRORED) for s, m in zip(source.sequences, mirrored.sequences, strict=True))
    assert all(m.sha256 == content_hash(m.root) for m in mirrored.sequences)
    shutil.rmtree(tmp_path / "mirror" / "0001")
    assert mirror_corpus(tmp_path / "corpus", tmp_path / "mirror") == ["0001"]
    assert read_corpus_manifest(tmp_path / "mirror").sha256 == mirrored.sha256  # the same files again
    with pytest.raises(DataFormatError, match="corpus manifest not found"):
        mirror_corpus(tmp_path / "mirror" / "0000", tmp_path / "x")
