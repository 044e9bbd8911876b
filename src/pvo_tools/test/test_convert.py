"""Converters and bag I/O: real data in, decoded back, broken inputs reported in one line."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from pvo_core.errors import DataFormatError
from pvo_core.imageio import read_image
from pvo_core.readers import DevonDataset, KittiSequence
from pvo_tools.baginfo import bag_info, bag_trajectory
from pvo_tools.bagio import SafeBagWriter, iter_messages, open_bag
from pvo_tools.convert import SunSensorConvention, convert_devon, convert_kitti
from pvo_tools.errors import BagError, UnknownMessageType
from pvo_tools.typesys import project_typestore
from rosbags.rosbag2 import Reader


def pvo(*args: str, env: dict[str, str] | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(["pvo", *args], capture_output=True, text=True, env=env, timeout=timeout)


def read_all(bag: Path) -> dict[str, list]:
    store = project_typestore()
    out: dict[str, list] = {}
    with Reader(bag) as reader:
        for connection, stamp, raw in reader.messages():
            out.setdefault(connection.topic, []).append((stamp, store.deserialize_cdr(raw, connection.msgtype)))
    return out


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_kitti_conversion_decodes_back(pvo_data: Path, tmp_path: Path, storage: str) -> None:
    root = pvo_data / "kitti/sequences/06"
    sequence = KittiSequence(
        root,
        rate_hz=10.0,
        poses_file=root / "poses_frames000-050.txt",
        sun_file=pvo_data / "kitti/sun/kitti_sun_test_06.csv",
        count=4,
    )
    summary = convert_kitti(sequence, tmp_path / "bag", storage=storage, epoch=1.3e9, show_progress=False)
    assert summary.frames == 4 and all(count == 4 for count in summary.counts.values()) and len(summary.counts) == 6
    messages = read_all(tmp_path / "bag")
    for i, (stamp, image) in enumerate(messages["/stereo/right/image_rect"]):
        assert stamp == round((1.3e9 + 0.1 * i) * 1e9)
        assert image.header.stamp.sec * 10**9 + image.header.stamp.nanosec == stamp
        assert (image.encoding, image.width, image.height, image.step) == ("mono8", 1226, 370, 1226)
        np.testing.assert_array_equal(image.data.reshape(370, 1226), read_image(root / f"image_1/{i:06d}.png"))
    info = messages["/stereo/right/camera_info"][0][1]
    assert info.p[3] == pytest.approx(-379.8145) and info.k[0] == pytest.approx(707.0912)
    assert info.header.frame_id == "camera_right_optical"
    odom = messages["/ground_truth/odometry"][3][1]
    assert odom.pose.pose.position.z == pytest.approx(sequence.poses[3][2, 3])
    sun = messages["/ground_truth/sun_direction"][0][1]
    assert (sun.direction.x, sun.direction.y) == pytest.approx((-0.80747, -0.58975), abs=2e-5)
    assert sun.zenith == pytest.approx(np.arccos(0.58975), abs=1e-4)
    trajectory = bag_trajectory(tmp_path / "bag")
    np.testing.assert_allclose(trajectory.poses, sequence.poses, atol=1e-9)


def test_existing_output_and_interrupted_conversion(pvo_data: Path, tmp_path: Path) -> None:
    clip = tmp_path / "clip"
    for side in ("image_0", "image_1"):
        (clip / side).mkdir(parents=True)
        for i in range(3):
            shutil.copy(pvo_data / f"kitti/sequences/06/{side}/{i:06d}.png", clip / side)
    shutil.copy(pvo_data / "kitti/sequences/06/calib_P0_P1_unlabelled.txt", clip / "calib.txt")
    broken = clip / "image_0" / "000002.png"
    broken.write_bytes(broken.read_bytes()[:1000])
    sequence = KittiSequence(clip, rate_hz=10)
    with pytest.raises(DataFormatError, match="000002.png: unreadable or truncated"):
        convert_kitti(sequence, tmp_path / "out", show_progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip"]  # nothing half-written left
    (tmp_path / "out").mkdir()
    with pytest.raises(BagError, match="output exists; pass --overwrite"):
        convert_kitti(sequence, tmp_path / "out", show_progress=False)
    # The CLI says the same in one line and exits 2.
    result = pvo("convert", "kitti", str(clip), "--out", str(tmp_path / "out"), "--rate", "10")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"pvo: error: {tmp_path / 'out'}: output exists; pass --overwrite to replace it"
    ]
    result = pvo("convert", "kitti", str(clip), "--out", str(tmp_path / "out2"), "--rate", "10", "-q")
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert result.stderr.strip().endswith("000002.png: unreadable or truncated image")
    assert not (tmp_path / "out2").exists()


def test_devon_conversion(pvo_data: Path, tmp_path: Path) -> None:
    dataset = DevonDataset(pvo_data / "devon")
    with pytest.raises(DataFormatError, match="no right images.*--mono"):
        convert_devon(dataset, tmp_path / "bag", rate_hz=1.0)
    convention = SunSensorConvention(azimuth_sign=-1.0)
    summary = convert_devon(
        dataset, tmp_path / "bag", mono=True, rate_hz=2.0, start_time=1215874600.0, convention=convention, show_progress=False
    )
    assert summary.counts["/stereo/left/image_rect"] == 60
    assert "/stereo/right/image_rect" not in summary.counts
    messages = read_all(tmp_path / "bag")
    sun = messages["/sun_sensor/direction"]
    # sun-sensor-sampled.txt rows for images 4, 5, 8, ... within the first 60 images
    assert len(sun) > 10
    first = sun[0][1]
    assert first.header.frame_id == "sun_sensor"
    assert np.degrees(first.zenith) == pytest.approx(61.57167, abs=1e-6)
    assert np.degrees(first.azimuth) == pytest.approx(2.46419, abs=1e-6)  # sign flipped by the convention
    image_stamp = 1215874600.0 + 3 / 2.0  # image 4 is the fourth image
    assert sun[0][0] == pytest.approx((image_stamp - 0.14062) * 1e9, abs=2)
    result = pvo("convert", "devon", str(pvo_data / "devon"), "--out", str(tmp_path / "b2"))
    assert result.returncode == 2 and "no right images" in result.stderr and len(result.stderr.strip().splitlines()) == 1


def test_bag_info_and_broken_bags(sample_bag: Path, tmp_path: Path) -> None:
    info = bag_info(sample_bag)
    assert info.message_count == 306 and info.storage == "mcap"
    assert {t[0]: t[2] for t in info.topics}["/stereo/left/image_rect"] == 51
    assert info.duration_s == pytest.approx(5.196, abs=1e-3)
    with pytest.raises(BagError, match="no such bag"):
        bag_info(tmp_path / "missing")
    truncated = tmp_path / "truncated"
    truncated.mkdir()
    shutil.copy(sample_bag / "metadata.yaml", truncated)
    data = (sample_bag / "kitti06_sample.mcap").read_bytes()
    (truncated / "kitti06_sample.mcap").write_bytes(data[: len(data) // 3])
    with pytest.raises(BagError, match="truncated"):
        with open_bag(truncated) as reader:
            for _ in iter_messages(reader):
                pass
    result = pvo("bag", "info", str(truncated))
    assert result.returncode in (0, 2) and "Traceback" not in result.stderr
    corrupt = tmp_path / "corrupt"
    corrupt.mkdir()
    (corrupt / "metadata.yaml").write_text("rosbag2_bagfile_information: [this is not\n")
    result = pvo("bag", "info", str(corrupt))
    assert result.returncode == 2 and result.stderr.startswith(f"pvo: error: {corrupt}: cannot open bag")
    result = pvo("bag", "play", str(corrupt))
    assert result.returncode == 2 and "Traceback" not in result.stderr


def test_unknown_message_type(tmp_path: Path) -> None:
    with SafeBagWriter(tmp_path / "bag") as writer, pytest.raises(UnknownMessageType, match="nosuch_msgs/msg/Thing"):
        writer.add_topic("/x", "nosuch_msgs/msg/Thing")
    result = pvo("interface", "show", "nosuch_msgs/msg/Thing")
    assert result.returncode == 2 and "unknown message type 'nosuch_msgs/msg/Thing'" in result.stderr


def test_interface_show_and_run_errors() -> None:
    result = pvo("interface", "show", "pvo_msgs/msg/RelativePose")
    assert result.returncode == 0 and "builtin_interfaces/Time reference_stamp" in result.stdout
    result = pvo("run", "no_such_package", "x")
    assert result.returncode == 2 and "package 'no_such_package' not found" in result.stderr
    result = pvo("run", "pvo_tools", "nope")
    assert result.returncode == 2 and "no executable 'nope' in package 'pvo_tools' (it has: pvo)" in result.stderr


def test_pvo_run_resolves_through_the_ament_index(sample_bag: Path) -> None:
    result = pvo("run", "pvo_tools", "pvo", "bag", "info", str(sample_bag))
    assert result.returncode == 0 and "Messages:          306" in result.stdout
    # The same layout `ros2 run` relies on: <prefix>/lib/<package>/<executable> plus the index marker.
    prefixes = [Path(p) for p in os.environ["AMENT_PREFIX_PATH"].split(os.pathsep)]
    tools = next(p for p in prefixes if (p / "share/ament_index/resource_index/packages/pvo_tools").is_file())
    assert os.access(tools / "lib/pvo_tools/pvo", os.X_OK)
