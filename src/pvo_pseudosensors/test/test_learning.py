"""The learning harness: datasets and their cache, the training loop (loss falls, determinism, resume,
DDP through torchrun), checkpoints and every bad-checkpoint case. Tiny data and models: seconds."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from pvo_core.errors import DataFormatError
from pvo_pseudosensors.learning import (
    DataSpec,
    FrameDataset,
    ModelFileError,
    Source,
    TrainConfig,
    fit,
    load_model,
    save_model,
)
from pvo_pseudosensors.sun_bcnn import SunBCNNConfig
from pvo_pseudosensors.sun_bcnn.model import (
    SunBCNN,
    SunTask,
    bin_spacing,
    decode_bins,
    random_rotations,
    rotate_cameras,
    rotation_matrices,
    soft_bin_targets,
    sphere_directions,
)

SIZE = (24, 64)  # the tiny model's input (height, width)
TINY = SunBCNNConfig(
    height=SIZE[0],
    width=SIZE[1],
    widths=(4, 8),
    hidden=8,
    dropout=0.1,
    grid=(1, 1),
    mirror=False,
    augment=False,
    aleatoric=False,
    bins=0,
    rotate=0.0,  # the regressed vector, no turned cameras: what most tests here are about
)


def write_sequence(root: Path, frames: int = 12, seed: int = 0, size: tuple[int, int] = (48, 128)) -> Path:
    """A KITTI-layout sequence whose brightness ramps towards the sun (learnable from one image)."""
    import cv2

    rng = np.random.default_rng(seed)
    (root / "image_0").mkdir(parents=True)
    (root / "image_1").mkdir()
    height, width = size
    v, u = np.mgrid[0:height, 0:width].astype(float)
    u, v = (u - width / 2) / width, (v - height / 2) / height
    suns, poses = [], []
    for k in range(frames):
        sun = rng.normal(size=3)
        sun[2] = abs(sun[2])
        sun /= np.linalg.norm(sun)
        image = 128 + 200 * (sun[0] * u + sun[1] * v) + rng.normal(0, 1, (height, width))
        for folder in ("image_0", "image_1"):
            cv2.imwrite(str(root / folder / f"{k:06d}.png"), np.clip(image, 0, 255).astype(np.uint8))
        suns.append(f"image_0/{k:06d}.png,{sun[0]:.9f},{sun[1]:.9f},{sun[2]:.9f}\n")
        pose = np.eye(4)
        pose[2, 3] = 0.8 * k  # driving forward along the optical axis
        poses.append(" ".join(f"{x:.9e}" for x in pose[:3].reshape(-1)) + "\n")
    (root / "sun.csv").write_text("".join(suns))
    (root / "poses.txt").write_text("".join(poses))
    return root


@pytest.fixture(scope="module")
def sequences(tmp_path_factory) -> dict[str, list[Source]]:
    base = tmp_path_factory.mktemp("sequences")
    train = [Source(write_sequence(base / f"t{i}", frames=16, seed=i), f"t{i}", "train") for i in range(4)]
    validation = [Source(write_sequence(base / "v0", frames=16, seed=10), "v0", "validation")]
    return {"train": train, "validation": validation}


def datasets(sequences, cache: Path | None = None) -> tuple[FrameDataset, FrameDataset]:
    spec = TINY.spec
    return FrameDataset(sequences["train"], spec, cache), FrameDataset(sequences["validation"], spec, cache)


# --- data -----------------------------------------------------------------------------------------


def test_samples_carry_resized_images_and_truth(sequences, tmp_path: Path) -> None:
    spec = DataSpec(SIZE, right=True, delta=2, sun=True)
    data = FrameDataset(sequences["train"][:1], spec, tmp_path / "cache")
    assert len(data) == 16 - 2
    sample = data[0]
    assert sample["left"].shape == (1, *SIZE) and sample["left"].dtype == torch.float32
    assert 0.0 <= float(sample["left"].min()) and float(sample["left"].max()) <= 1.0
    assert sample["right"].shape == sample["previous"].shape == (1, *SIZE)
    assert int(sample["frame"]) == 2
    # T_k,k-2 maps a point ahead of the earlier camera into the later one: 1.6 m closer
    np.testing.assert_allclose(sample["relative"].numpy()[:3, 3], [0.0, 0.0, -1.6], atol=1e-6)
    assert float(torch.linalg.norm(sample["sun"])) == pytest.approx(1.0, abs=1e-6)


def test_the_cache_is_built_once_and_rebuilt_when_images_change(sequences, tmp_path: Path) -> None:
    import cv2

    cache = tmp_path / "cache"
    decoded = []
    FrameDataset(sequences["train"][:1], TINY.spec, cache, progress=lambda: decoded.append(1))
    assert len(decoded) == 16 and len(list(cache.glob("*.npy"))) == 1
    FrameDataset(sequences["train"][:1], TINY.spec, cache, progress=lambda: decoded.append(1))
    assert len(decoded) == 16  # the second dataset decoded nothing
    cached = FrameDataset(sequences["train"][:1], TINY.spec, cache)[3]["left"]
    direct = FrameDataset(sequences["train"][:1], TINY.spec, None)[3]["left"]
    assert torch.equal(cached, direct)
    copy = tmp_path / "copy"
    import shutil

    shutil.copytree(sequences["train"][0].root, copy)
    image = cv2.imread(str(copy / "image_0" / "000003.png"), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(copy / "image_0" / "000003.png"), 255 - image)
    changed = FrameDataset([Source(copy, "copy")], TINY.spec, cache)
    assert not torch.equal(changed[3]["left"], cached)


def test_a_flat_folder_of_left_images_is_a_source(tmp_path: Path) -> None:
    import shutil

    root = write_sequence(tmp_path / "kitti", frames=4)
    flat = tmp_path / "devon"
    flat.mkdir()
    for k, image in enumerate(sorted((root / "image_0").glob("*.png"))):
        shutil.copy(image, flat / f"grey-rectified-left-{k + 1:06d}.png")
    data = FrameDataset([Source(flat, "devon")], DataSpec(SIZE))
    assert len(data) == 4
    assert torch.equal(data[2]["left"], FrameDataset([Source(root, "kitti")], DataSpec(SIZE))[2]["left"])
    with pytest.raises(ValueError, match="left images only"):
        FrameDataset([Source(flat, "devon")], DataSpec(SIZE, right=True))


def test_missing_truth_is_one_line_naming_the_file(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "s", frames=3)
    (root / "sun.csv").unlink()
    with pytest.raises(ValueError, match=r"s/sun.csv: needed by the dataset but missing"):
        FrameDataset([Source(root, "s")], TINY.spec)


# --- training -------------------------------------------------------------------------------------

CONFIG = TrainConfig(epochs=6, batch_size=16, learning_rate=1e-2, schedule="cosine", patience=0, seed=3, threads=1)


def weights(out: Path) -> dict[str, torch.Tensor]:
    from safetensors.torch import load_file

    return load_file(str(out / "weights.safetensors"))


def test_training_lowers_the_loss_and_writes_its_records(sequences, tmp_path: Path) -> None:
    train, validation = datasets(sequences)
    result = fit(SunTask(TINY), train, validation, replace(CONFIG, epochs=12), tmp_path / "run", say=lambda _: None)
    first, last = result.history[0], result.history[-1]
    assert last["train_loss"] < 0.6 * first["train_loss"]
    assert result.best_validation < 0.6 * first["validation_loss"]
    for name in ("weights.safetensors", "model.yaml", "history.csv", "loss.png", "checkpoint.pt"):
        assert (tmp_path / "run" / name).is_file(), name
    assert len((tmp_path / "run" / "history.csv").read_text().splitlines()) == 13
    _, card = load_model(tmp_path / "run", "sun-bcnn", lambda c: SunBCNN(SunBCNNConfig.from_card(c)), SIZE)
    assert card.validation["loss"] == pytest.approx(result.best_validation)
    assert card.training["best_epoch"] == result.best_epoch


def test_same_command_same_weights(sequences, tmp_path: Path) -> None:
    train, validation = datasets(sequences)
    for name in ("a", "b"):
        fit(SunTask(TINY), train, validation, CONFIG, tmp_path / name, say=lambda _: None)
    a, b = weights(tmp_path / "a"), weights(tmp_path / "b")
    assert all(torch.equal(a[k], b[k]) for k in a)
    fit(SunTask(TINY), train, validation, replace(CONFIG, seed=4), tmp_path / "c", say=lambda _: None)
    c = weights(tmp_path / "c")
    assert not all(torch.equal(a[k], c[k]) for k in a)


def test_resume_reaches_the_weights_of_an_uninterrupted_run(sequences, tmp_path: Path) -> None:
    train, validation = datasets(sequences)
    config = replace(CONFIG, epochs=5)
    whole = fit(SunTask(TINY), train, validation, config, tmp_path / "whole", say=lambda _: None)

    def interrupt(line: str) -> None:
        if line.startswith("epoch 3/"):
            raise KeyboardInterrupt  # killed right after epoch 3 was checkpointed

    with pytest.raises(KeyboardInterrupt):
        fit(SunTask(TINY), train, validation, config, tmp_path / "cut", say=interrupt)
    said: list[str] = []
    resumed = fit(SunTask(TINY), train, validation, config, tmp_path / "cut", resume=True, say=said.append)
    assert said[0].startswith("resuming after epoch 3 of 5")
    assert [r["validation_loss"] for r in resumed.history] == [r["validation_loss"] for r in whole.history]
    a, b = weights(tmp_path / "whole"), weights(tmp_path / "cut")
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match="other training settings"):
        fit(SunTask(TINY), train, validation, replace(config, learning_rate=5e-2), tmp_path / "cut", resume=True)


def test_early_stopping_stops_after_patience(sequences, tmp_path: Path) -> None:
    train, validation = datasets(sequences)
    config = replace(CONFIG, epochs=40, patience=2, learning_rate=0.3, schedule="constant")  # far too large: no progress
    result = fit(SunTask(TINY), train, validation, config, tmp_path / "s", say=lambda _: None)
    assert result.stopped_early and result.epochs_run < 40
    assert result.epochs_run - result.best_epoch == 2


DDP_SCRIPT = """
import sys
from pathlib import Path
from pvo_pseudosensors.learning import FrameDataset, Source, TrainConfig, fit
from pvo_pseudosensors.sun_bcnn import SunBCNNConfig
from pvo_pseudosensors.sun_bcnn.model import SunTask

roots, out = sys.argv[1:-1], Path(sys.argv[-1])
# no per-process randomness: no dropout, mirroring or jitter
config = SunBCNNConfig(height=24, width=64, widths=(4, 8), hidden=8, dropout=0.0, mirror=False, augment=False, bins=0, rotate=0.0)
train = FrameDataset([Source(Path(r), Path(r).name) for r in roots[:-1]], config.spec)
validation = FrameDataset([Source(Path(roots[-1]), "v")], config.spec)
fit(SunTask(config), train, validation, TrainConfig(epochs=3, batch_size=16, learning_rate=3e-3, patience=0, seed=1, threads=1),
    out, say=lambda _: None)
"""


def test_two_processes_under_torchrun_match_one(sequences, tmp_path: Path) -> None:
    script = tmp_path / "train.py"
    script.write_text(DDP_SCRIPT)
    roots = [str(s.root) for s in sequences["train"]] + [str(sequences["validation"][0].root)]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    single = subprocess.run([sys.executable, str(script), *roots, str(tmp_path / "one")], env=env, capture_output=True, text=True)
    assert single.returncode == 0, single.stderr[-2000:]
    import socket

    with socket.socket() as probe:  # a free port for the rendezvous (a fixed one may be taken)
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    torchrun = [sys.executable, "-m", "torch.distributed.run", "--nproc-per-node", "2", "--master-port", str(port)]
    double = subprocess.run([*torchrun, str(script), *roots, str(tmp_path / "two")], env=env, capture_output=True, text=True)
    # the launcher's summary ends stderr; the failing rank's own words (an abort's reason) are earlier
    assert double.returncode == 0, double.stderr[:3000] + "\n...\n" + double.stderr[-1500:]
    one, two = weights(tmp_path / "one"), weights(tmp_path / "two")
    for name in one:
        torch.testing.assert_close(two[name], one[name], atol=1e-5, rtol=1e-4)


# --- checkpoints ----------------------------------------------------------------------------------


def build(card) -> SunBCNN:
    return SunBCNN(SunBCNNConfig.from_card(card))


@pytest.fixture()
def saved(tmp_path: Path) -> Path:
    torch.manual_seed(0)
    model = SunBCNN(TINY)
    return save_model(tmp_path / "model", model, SunTask(TINY).card())


def test_checkpoint_round_trip(saved: Path) -> None:
    torch.manual_seed(0)
    original = SunBCNN(TINY).eval()
    model, card = load_model(saved, "sun-bcnn", build, SIZE)
    image = torch.rand(2, 1, *SIZE)
    torch.testing.assert_close(model(image), original(image))
    assert card.input["size"] == list(SIZE) and card.created


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        ("no directory", "model directory not found"),
        ("no card", "model.yaml: model card not found"),
        ("no weights", "weights.safetensors: weights file not found"),
        ("truncated", "weights.safetensors: truncated or corrupt weights file"),
        ("corrupt", "weights.safetensors: truncated or corrupt weights file"),
        ("other architecture", "model.yaml: a 'dpc-net' model, not 'sun-bcnn'"),
        ("card without fields", "model.yaml: model card lacks hyperparameters"),
        ("unreadable card", "model.yaml: unreadable model card"),
        ("other widths", "weights do not fit|has shape"),
    ],
)
def test_each_bad_checkpoint_is_one_line_naming_the_file(saved: Path, damage: str, message: str) -> None:
    import shutil

    import yaml

    weights_file, card_file = saved / "weights.safetensors", saved / "model.yaml"
    card = yaml.safe_load(card_file.read_text())
    if damage == "no directory":
        shutil.rmtree(saved)
    elif damage == "no card":
        card_file.unlink()
    elif damage == "no weights":
        weights_file.unlink()
    elif damage == "truncated":
        weights_file.write_bytes(weights_file.read_bytes()[:100])
    elif damage == "corrupt":
        data = bytearray(weights_file.read_bytes())
        data[:8] = b"\xff" * 8  # the header length
        weights_file.write_bytes(bytes(data))
    elif damage == "other architecture":
        card_file.write_text(yaml.safe_dump({**card, "architecture": "dpc-net"}))
    elif damage == "card without fields":
        card_file.write_text(yaml.safe_dump({"architecture": "sun-bcnn", "input": card["input"]}))
    elif damage == "unreadable card":
        card_file.write_text("architecture: [unclosed")
    elif damage == "other widths":
        card_file.write_text(yaml.safe_dump({**card, "hyperparameters": {**card["hyperparameters"], "widths": [4, 16]}}))
    with pytest.raises(ModelFileError, match=message) as error:
        load_model(saved, "sun-bcnn", build, SIZE)
    assert "\n" not in str(error.value) and str(saved) in str(error.value)


def test_another_input_size_is_refused(saved: Path) -> None:
    with pytest.raises(ModelFileError, match=r"model.yaml: made for 24x64 \(HxW\) input, not 48x128"):
        load_model(saved, "sun-bcnn", build, (48, 128))


class _Direct(torch.nn.Module):
    """A stand-in with SunBCNN's interface: the direction from ``direction_of``, no aleatoric output."""

    def forward(self, images: torch.Tensor, with_concentration: bool = False):
        vectors = self.direction_of(images)
        return (vectors, None) if with_concentration else vectors


def test_mirroring_negates_the_suns_x_with_the_image() -> None:
    class Equivariant(_Direct):
        """Reads the sun's x from which side of the image is brighter: mirroring the image mirrors the answer."""

        def direction_of(self, images: torch.Tensor) -> torch.Tensor:
            half = images.shape[-1] // 2
            x = images[..., half:].mean(dim=(1, 2, 3)) - images[..., :half].mean(dim=(1, 2, 3))
            return torch.nn.functional.normalize(torch.stack([x, torch.zeros_like(x), torch.full_like(x, 0.1)], dim=1), dim=1)

    ramp = torch.linspace(0, 1, 16).repeat(4, 1, 8, 1)  # brighter to the right: the sun to the right (+x)
    batch = {"left": ramp, "sun": torch.nn.functional.normalize(torch.tensor([[1.0, 0.0, 0.1]] * 4), dim=1)}
    task = SunTask(replace(TINY, mirror=True))
    model = Equivariant().train()
    plain = float(SunTask(replace(TINY, mirror=False)).loss(model, batch))
    torch.manual_seed(0)
    assert float(task.loss(model, batch)) == pytest.approx(plain, abs=1e-6)  # flipped or not, the same error

    class Constant(_Direct):
        def direction_of(self, images: torch.Tensor) -> torch.Tensor:
            return batch["sun"][: len(images)]

    torch.manual_seed(0)
    assert float(task.loss(Constant().train(), batch)) > 0.5  # some samples were mirrored: their sun moved to -x


def _sun_disc(camera: tuple[float, float, float, float], suns: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """Images (B, 1, H, W) black but for a bright Gaussian disc (sigma 1.5 px) where each sun (B, 3) projects."""
    fx, fy, cx, cy = camera
    v, u = torch.meshgrid(torch.arange(size[0], dtype=torch.float64), torch.arange(size[1], dtype=torch.float64), indexing="ij")
    at_u = fx * suns[:, 0] / suns[:, 2] + cx
    at_v = fy * suns[:, 1] / suns[:, 2] + cy
    squared = (u - at_u[:, None, None]) ** 2 + (v - at_v[:, None, None]) ** 2
    return torch.exp(-squared / (2 * 1.5**2))[:, None].float()


def _disc_centre(images: torch.Tensor) -> torch.Tensor:
    """(B, 2) brightness-weighted centre (u, v) of each image, in pixels."""
    v, u = torch.meshgrid(torch.arange(images.shape[2]), torch.arange(images.shape[3]), indexing="ij")
    weights = images[:, 0] ** 4  # the disc, not the border pixels the warp repeats
    total = weights.sum(dim=(1, 2))
    return torch.stack([(weights * u).sum(dim=(1, 2)) / total, (weights * v).sum(dim=(1, 2)) / total], dim=1)


def test_a_turned_camera_sees_the_sun_where_the_turned_sun_vector_projects() -> None:
    """The warp K R K^-1 is the image a turned pinhole camera sees: a disc drawn where the sun projects moves to
    where the turned vector projects (principal point off centre, fx != fy, turns about all three axes)."""
    size, camera = (94, 310), (150.0, 153.0, 150.2, 44.7)
    suns = torch.nn.functional.normalize(torch.tensor([[0.3, -0.2, 1.0], [-0.5, 0.1, 1.0], [0.05, 0.25, 1.0]]), dim=1)
    images = _sun_disc(camera, suns.double(), size)
    degrees = torch.tensor([[9.0, 2.0, -3.0], [-12.0, -1.5, 2.5], [4.0, 3.0, 5.0]])  # yaw, pitch, roll
    turns = rotation_matrices(*torch.deg2rad(degrees).T)
    warped, turned = rotate_cameras(images, suns, torch.tensor([camera] * 3), turns)
    expected = _disc_centre(_sun_disc(camera, turned.double(), size))
    np.testing.assert_allclose(_disc_centre(warped).numpy(), expected.numpy(), atol=0.05)
    np.testing.assert_allclose(torch.linalg.norm(turned, dim=1).numpy(), 1.0, atol=1e-6)
    moved = torch.linalg.norm(_disc_centre(warped) - _disc_centre(images), dim=1)
    assert float(moved.min()) > 10.0  # the turns are large enough to test something
    # yaw turns about the optical frame's y axis (down): a positive yaw moves a sun ahead towards +x
    from pvo_core.lie import so3_exp  # an independent implementation: R = Rz(roll) Ry(yaw) Rx(pitch)

    for (yaw, pitch, roll), matrix in zip(torch.deg2rad(degrees).double().tolist(), turns.double().numpy(), strict=True):
        expected = so3_exp([0.0, 0.0, roll]) @ so3_exp([0.0, yaw, 0.0]) @ so3_exp([pitch, 0.0, 0.0])
        np.testing.assert_allclose(matrix, expected, atol=1e-6)
    yawed = rotation_matrices(*torch.deg2rad(torch.tensor([[10.0], [0.0], [0.0]])))[0]
    assert float((yawed @ torch.tensor([0.0, 0.0, 1.0]))[0]) > 0


def test_rotation_augmentation_keeps_image_and_sun_consistent_with_mirroring() -> None:
    """In the loss, a model that reads the sun off the disc's position (the camera known) stays exact however
    the images are mirrored and turned, while one that ignores the image loses: the suns moved."""
    size, camera = (48, 128), (60.0, 60.0, 63.5, 23.5)
    suns = torch.nn.functional.normalize(torch.tensor([[0.4, -0.1, 1.0], [-0.3, 0.2, 1.0]] * 4), dim=1)
    batch = {"left": _sun_disc(camera, suns.double(), size), "sun": suns, "camera": torch.tensor([camera] * 8)}

    class Reader(_Direct):
        def direction_of(self, images: torch.Tensor) -> torch.Tensor:
            centre = _disc_centre(images)
            rays = torch.stack([(centre[:, 0] - camera[2]) / camera[0], (centre[:, 1] - camera[3]) / camera[1]], 1)
            return torch.nn.functional.normalize(torch.cat([rays, torch.ones(len(rays), 1)], dim=1), dim=1)

    task = SunTask(replace(TINY, height=size[0], width=size[1], mirror=True, rotate=20.0))
    torch.manual_seed(3)
    assert float(task.loss(Reader().train(), batch)) < 1e-5

    class Constant(_Direct):
        def direction_of(self, images: torch.Tensor) -> torch.Tensor:
            return suns[: len(images)]

    torch.manual_seed(3)
    assert float(task.loss(Constant().train(), batch)) > 1e-3
    with pytest.raises(ValueError, match="camera intrinsics"):
        task.loss(Reader().train(), {"left": batch["left"], "sun": suns})
    angles = torch.rad2deg(torch.acos(random_rotations(2000, 20.0)[:, 2, 2].clamp(-1, 1)))
    assert 10.0 < float(angles.max()) <= 20.0 * 1.1  # yaw up to 20 deg, pitch up to 5: the forward axis turns up to ~21


def test_a_dataset_with_camera_carries_the_intrinsics_at_its_size(tmp_path: Path) -> None:
    root = write_sequence(tmp_path / "s", frames=3)  # 48x128 images, resized to 24x64
    spec = replace(TINY, rotate=10.0).spec
    with pytest.raises(DataFormatError, match="calib.txt.*camera intrinsics"):
        FrameDataset([Source(root, "s")], spec)
    row = "100 0 63.5 0 0 90 23.5 0 0 0 1 0"
    (root / "calib.txt").write_text(f"P0: {row}\nP1: {row}\n")
    sample = FrameDataset([Source(root, "s")], spec)[0]
    np.testing.assert_allclose(sample["camera"].numpy(), [50.0, 45.0, 31.5, 11.5])
    assert "camera" not in FrameDataset([Source(root, "s")], TINY.spec)[0]
    for wrong in (-1.0, 90.0):
        with pytest.raises(ValueError, match="rotate must be a yaw range in \\[0, 60\\] degrees"):
            replace(TINY, rotate=wrong)


def test_the_vmf_likelihood_matches_scipy_and_the_loss_teaches_kappa_the_error() -> None:
    from pvo_pseudosensors.sun_bcnn.model import vmf_negative_log_likelihood
    from scipy.stats import vonmises_fisher

    mu = np.array([0.0, 0.0, 1.0])
    for kappa, angle in ((0.5, 2.0), (3.0, 0.4), (80.0, 0.1), (5000.0, 0.01)):
        s = np.array([np.sin(angle), 0.0, np.cos(angle)])
        ours = float(vmf_negative_log_likelihood(torch.tensor(kappa, dtype=torch.float64), torch.tensor(np.cos(angle))))
        assert ours == pytest.approx(-vonmises_fisher(mu, kappa).logpdf(s), rel=1e-9, abs=1e-9)
    # with the direction held, the NLL is least where 1/kappa is the mean of 1 - cos over the batch (large kappa)
    cosine = torch.cos(torch.full((64,), 0.05, dtype=torch.float64))
    kappas = torch.linspace(50, 2000, 400, dtype=torch.float64)
    nll = torch.stack([vmf_negative_log_likelihood(k, cosine).mean() for k in kappas])
    assert float(kappas[nll.argmin()]) == pytest.approx(1.0 / float((1 - cosine).mean()), rel=0.02)


def _ramp_images(count: int, seed: int, hidden: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Images (count, 1, H, W) brighter towards their sun (flat where ``hidden``) and the suns (count, 3), all ahead
    of the camera."""
    rng = np.random.default_rng(seed)
    suns = rng.normal(size=(count, 3))
    suns[:, 2] = np.abs(suns[:, 2]) + 0.5
    suns /= np.linalg.norm(suns, axis=1, keepdims=True)
    u, v = np.meshgrid(np.linspace(-1, 1, SIZE[1]), np.linspace(-1, 1, SIZE[0]))
    shown = np.ones(count) if hidden is None else (~hidden).astype(float)
    images = np.stack([0.5 + 0.3 * k * (s[0] * u + s[1] * v) for s, k in zip(suns, shown, strict=True)])
    return torch.tensor(images[:, None], dtype=torch.float32), torch.tensor(suns, dtype=torch.float32)


def _fit_on(config: SunBCNNConfig, images: torch.Tensor, targets: torch.Tensor, steps: int) -> SunBCNN:
    """A network of ``config`` fitted to the images' suns by Adam (3e-3), full batch."""
    task, model = SunTask(config), SunBCNN(config)
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)
    for _ in range(steps):
        optimiser.zero_grad()
        task.loss(model.train(), {"left": images, "sun": targets}).backward()
        optimiser.step()
    return model


def test_the_aleatoric_output_learns_larger_covariance_for_noisier_images(tmp_path: Path) -> None:
    """Images whose sun is hidden (flat) and images showing it (a ramp): the trained kappa is far lower on the
    flat ones, and the predicted covariance (with no tau) far larger."""
    from pvo_pseudosensors.sun_bcnn.infer import combine, draw_samples

    torch.manual_seed(0)
    hidden = np.arange(256) % 2 == 1
    images, targets = _ramp_images(256, 0, hidden)
    model = _fit_on(replace(TINY, mirror=False, dropout=0.05, aleatoric=True), images, targets, 250)
    draws = draw_samples(model, images, 8, seed=1)
    assert draws.inverse_concentration is not None
    inverse = draws.inverse_concentration.mean(axis=0)
    assert np.median(inverse[hidden]) > 5 * np.median(inverse[~hidden])
    _, covariance = combine(draws)
    spread = np.trace(covariance, axis1=1, axis2=2)
    assert np.median(spread[hidden]) > 3 * np.median(spread[~hidden])
    assert np.all(np.linalg.eigvalsh(covariance) > 0) and np.allclose(covariance, covariance.transpose(0, 2, 1))


def _angles_deg(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(torch.acos((a * b).sum(dim=1).clamp(-1.0, 1.0)))


def test_the_bins_cover_the_sphere_and_their_soft_targets_decode_to_the_sun() -> None:
    directions = sphere_directions(512)
    np.testing.assert_allclose(torch.linalg.norm(directions, dim=1).numpy(), 1.0, atol=1e-6)
    torch.manual_seed(0)
    suns = torch.nn.functional.normalize(torch.randn(3000, 3), dim=1)
    nearest = torch.rad2deg(torch.acos((suns @ directions.T).max(dim=1).values.clamp(-1, 1)))
    assert float(nearest.max()) < 0.75 * np.degrees(bin_spacing(512))  # no direction is far from a bin
    targets = soft_bin_targets(suns, 512)
    np.testing.assert_allclose(targets.sum(dim=1).numpy(), 1.0, atol=1e-5)
    assert float(_angles_deg(decode_bins(torch.log(targets), directions), suns).max()) < 0.25
    # two modes, the sun ahead (60 %) or behind (40 %): the answer is the one ahead, not their average
    ahead, behind = torch.tensor([[0.3, -0.4, 0.866]]), torch.tensor([[0.3, -0.4, -0.866]])
    mixture = 0.6 * soft_bin_targets(ahead, 512) + 0.4 * soft_bin_targets(behind, 512)
    assert float(_angles_deg(decode_bins(torch.log(mixture), directions), ahead)[0]) < 0.5
    with pytest.raises(ValueError, match="bins must be 0 .* got 10"):
        replace(TINY, bins=10)


def test_a_wider_decode_radius_pulls_a_ring_of_suns_to_its_centre() -> None:
    # near the zenith the classifier spreads its mass over a ring of azimuths: the local decode lands on the
    # ring (elevation 70 deg here), the whole sphere's mean at its centre (straight up: -y in the optical frame)
    directions = sphere_directions(256)
    azimuths = torch.arange(12) * (2.0 * math.pi / 12)
    up = torch.tensor([[0.0, -1.0, 0.0]])
    elevation = math.radians(70.0)
    ring = torch.stack(
        [
            math.cos(elevation) * torch.cos(azimuths),
            torch.full_like(azimuths, -math.sin(elevation)),
            math.cos(elevation) * torch.sin(azimuths),
        ],
        dim=1,
    )
    weights = torch.linspace(1.0, 1.2, 12)[:, None]  # one azimuth a little more probable: a definite mode
    logits = torch.log((weights * soft_bin_targets(ring, 256)).sum(dim=0, keepdim=True))
    local = float(_angles_deg(decode_bins(logits, directions, radius=1.0), up)[0])
    assert local > 8.0  # towards the ring, not at its centre (a ring 20 deg from the zenith)
    assert float(_angles_deg(decode_bins(logits, directions, radius=math.inf), up)[0]) < 2.0
    # the default four spacings (51 deg) already reach across this ring: between the two
    assert float(_angles_deg(decode_bins(logits, directions), up)[0]) < local
    for radius in (0.5, math.nan):
        with pytest.raises(ValueError, match="decode_radius must be at least 1 bin spacing"):
            replace(TINY, bins=256, decode_radius=radius)


def test_a_tiny_classifying_model_learns_where_the_sun_is() -> None:
    """Ramp images brighter towards the sun: with 64 bins (~25 deg apart) the head learns the suns from an
    untrained guess (> 30 deg off) to within a fraction of a bin (< 10 deg), and its MC passes give a covariance
    as the regressing head's do."""
    from pvo_pseudosensors.sun_bcnn.infer import combine, draw_samples

    images, targets = _ramp_images(128, 1)
    # batch normalisation (as shipped): without it, this tiny a network at times needs far more steps, whatever its head
    config = replace(TINY, dropout=0.05, bins=64, aleatoric=True, batch_norm=True)
    torch.manual_seed(0)
    with torch.no_grad():
        untrained = _angles_deg(SunBCNN(config).eval()(images), targets)
    model = _fit_on(config, images, targets, 250)
    draws = draw_samples(model, images, 8, seed=1)
    assert draws.inverse_concentration is not None
    mean, covariance = combine(draws)
    assert np.all(np.linalg.eigvalsh(covariance) > 0)
    trained = _angles_deg(torch.from_numpy(mean), targets.double())
    assert float(untrained.median()) > 30.0 and float(trained.median()) < 10.0


def test_mirrored_mc_modes_pool_the_image_and_its_mirror() -> None:
    """A mirrored mode is the plain mode's passes over the image plus its passes over the mirrored image with
    the sun's x negated; without dropout, so every pass is the same, the mirrored image's mean is exactly the
    image's mean mirrored - which the plain mode of an untrained network is not."""
    from pvo_pseudosensors.sun_bcnn.infer import combine, draw_samples

    torch.manual_seed(0)
    images = torch.rand(3, 1, *SIZE)
    flipped = torch.flip(images, dims=[-1])
    model = SunBCNN(replace(TINY, aleatoric=True))
    mirrored = draw_samples(model, images, 5, seed=3, mode="full-mirrored")
    direct, other = draw_samples(model, images, 3, seed=3, mode="full"), draw_samples(model, flipped, 2, seed=4, mode="full")
    np.testing.assert_allclose(mirrored.vectors, np.concatenate([direct.vectors, other.vectors * [-1.0, 1.0, 1.0]]))
    assert mirrored.inverse_concentration is not None and other.inverse_concentration is not None
    np.testing.assert_allclose(mirrored.inverse_concentration[3:], other.inverse_concentration)
    head = draw_samples(model, images, 4, seed=3, mode="head-mirrored")
    assert head.vectors.shape == (4, 3, 3)

    deterministic = SunBCNN(replace(TINY, dropout=0.0))
    mirror_x = np.array([-1.0, 1.0, 1.0])
    for mode, equivariant in (("full-mirrored", True), ("full", False)):
        mean, _ = combine(draw_samples(deterministic, images, 4, seed=0, mode=mode))
        mean_flipped, _ = combine(draw_samples(deterministic, flipped, 4, seed=0, mode=mode))
        assert np.allclose(mean_flipped, mean * mirror_x, atol=1e-6) == equivariant
    with pytest.raises(ValueError, match="at least 2 samples"):
        draw_samples(model, images, 1, seed=0, mode="head-mirrored")
    with pytest.raises(ValueError, match="unknown MC mode 'sideways'"):
        draw_samples(model, images, 4, seed=0, mode="sideways")


@pytest.mark.parametrize("pass_batch", [1, 4, 128])
def test_full_mode_passes_share_the_stem_and_draw_their_own_masks(monkeypatch: pytest.MonkeyPatch, pass_batch: int) -> None:
    """The full mode runs the stem (everything before the first dropout) once and the passes as a batch of image
    copies in chunks: without dropout every pass of every image is the network's output on that image; with it
    the passes differ from each other, the same seed gives the same draws, and the chunking changes neither the
    shapes nor the spread's scale."""
    from pvo_pseudosensors.sun_bcnn import infer

    monkeypatch.setattr(infer, "PASS_BATCH", pass_batch)
    torch.manual_seed(0)
    images = torch.rand(3, 1, *SIZE)
    deterministic = SunBCNN(replace(TINY, dropout=0.0, aleatoric=True)).eval()
    with torch.no_grad():
        expected, kappa = deterministic.outputs(deterministic.pooled(images))
        assert torch.allclose(deterministic.pooled_from_stem(deterministic.stem(images)), deterministic.pooled(images))
    draws = infer.draw_samples(deterministic, images, 5, seed=0, mode="full")
    assert draws.vectors.shape == (5, 3, 3) and draws.inverse_concentration is not None
    for one_pass, inverse in zip(draws.vectors, draws.inverse_concentration, strict=True):
        np.testing.assert_allclose(one_pass, expected.double().numpy(), atol=1e-6)
        np.testing.assert_allclose(inverse, 1.0 / kappa.double().numpy(), rtol=1e-5)

    model = SunBCNN(replace(TINY, dropout=0.3))
    draws = infer.draw_samples(model, images, 6, seed=2, mode="full")
    again = infer.draw_samples(model, images, 6, seed=2, mode="full")
    np.testing.assert_array_equal(draws.vectors, again.vectors)
    spread = np.linalg.norm(draws.vectors - draws.vectors.mean(axis=0), axis=2)  # (passes, images)
    assert np.all(spread.max(axis=0) > 1e-4)  # every image's passes differ: each row its own masks
    assert not model.training


def test_the_sensor_runs_in_the_mode_its_model_was_calibrated_in_unless_told(sequences, tmp_path: Path) -> None:
    """mode "" is the card's calibrated mode (the covariance's tau holds for that one), else the default; a
    given mode wins; a sequence's predictions do the same; the shipped models' cards name theirs."""
    from pvo_pseudosensors.sun_bcnn.estimator import SunBCNNSensor, SunBCNNSensorConfig
    from pvo_pseudosensors.sun_bcnn.infer import DEFAULT_MODE, model_mode, sample_sequence

    model, card = SunBCNN(TINY), SunTask(TINY).card()
    save_model(tmp_path / "model", model, card)
    assert SunBCNNSensor(SunBCNNSensorConfig(model=str(tmp_path / "model"))).mode == DEFAULT_MODE  # no calibration yet
    card.calibration = {"tau": 4.0, "mode": "full"}
    assert model_mode(card) == "full" and model_mode(card, "head") == "head"
    root = sequences["validation"][0].root
    _, own = sample_sequence(model, card, root, samples=4)
    np.testing.assert_array_equal(own.vectors, sample_sequence(model, card, root, samples=4, mode="full")[1].vectors)
    assert not np.allclose(own.vectors, sample_sequence(model, card, root, samples=4, mode="head-mirrored")[1].vectors)
    assert SunBCNNSensor(SunBCNNSensorConfig(model="sun_bcnn")).mode == "head-mirrored"
    assert SunBCNNSensor(SunBCNNSensorConfig(model="sun_bcnn_kitti")).mode == "head-mirrored"  # its tau fitted in it
    assert SunBCNNSensor(SunBCNNSensorConfig(model="sun_bcnn_kitti", mode="head")).mode == "head"
    with pytest.raises(ValueError, match="unknown mode 'sideways'"):
        SunBCNNSensorConfig(mode="sideways")
    card.calibration = {"tau": 4.0, "mode": "sideways"}
    with pytest.raises(ValueError, match="model card's calibration.mode: unknown MC mode 'sideways'"):
        model_mode(card)


def test_an_equalising_sensor_reads_what_the_plain_one_reads_from_the_equalised_image(tmp_path: Path) -> None:
    """`equalize`: the model reads every image histogram-equalised (as OpenCV's equalizeHist does it), whatever
    it was trained on; the card's own setting is untouched on disk."""
    import cv2
    from pvo_pseudosensors.sun_bcnn.estimator import SunBCNNSensor, SunBCNNSensorConfig

    torch.manual_seed(0)
    save_model(tmp_path / "model", SunBCNN(TINY), SunTask(TINY).card())
    rng = np.random.default_rng(1)
    v, u = np.mgrid[0 : SIZE[0], 0 : SIZE[1]]
    image = np.clip(60 + 2 * u + v + rng.normal(0, 3, SIZE), 0, 255).astype(np.uint8)  # a dim, low-contrast frame
    equalised = cv2.equalizeHist(image)
    assert not np.array_equal(image, equalised)

    def reading(picture: np.ndarray, equalize: bool) -> np.ndarray:
        sensor = SunBCNNSensor(SunBCNNSensorConfig(model=str(tmp_path / "model"), samples=4, equalize=equalize))
        return sensor.estimate(picture).direction

    np.testing.assert_allclose(reading(image, True), reading(equalised, False), atol=1e-6)
    assert not np.allclose(reading(image, True), reading(image, False), atol=1e-4)
    assert "equalize: false" in (tmp_path / "model" / "model.yaml").read_text()


def test_the_model_parameter_names_a_shipped_model_or_a_path(tmp_path: Path) -> None:
    from pvo_pseudosensors.sun_bcnn.estimator import resolve_model

    assert resolve_model("").parts[-2:] == ("models", "sun_bcnn")
    assert resolve_model("sun_bcnn_kitti").parts[-2:] == ("models", "sun_bcnn_kitti")
    assert resolve_model(str(tmp_path)) == tmp_path


def test_photometric_jitter_changes_brightness_not_geometry() -> None:
    from pvo_pseudosensors.sun_bcnn.model import photometric_jitter

    ramp = torch.linspace(0.1, 0.9, 64).repeat(8, 1, 24, 1)  # brighter to the right in every image
    torch.manual_seed(3)
    jittered = photometric_jitter(ramp)
    torch.manual_seed(3)
    assert torch.equal(jittered, photometric_jitter(ramp))  # seeded
    assert jittered.shape == ramp.shape and float(jittered.min()) >= 0.0 and float(jittered.max()) <= 1.0
    assert not torch.allclose(jittered, ramp, atol=0.02)
    columns = jittered.mean(dim=(1, 2))  # (8, 64): the ramp still rises left to right in every image
    assert bool((columns[:, -8:].mean(dim=1) > columns[:, :8].mean(dim=1) + 0.2).all())


def test_batch_normalised_mc_passes_keep_the_running_statistics() -> None:
    """With batch normalisation an MC pass uses the running statistics, not its batch's: an image's draws are
    the same alone or beside others, without dropout every pass is the evaluated network's output, and the
    running statistics are left as they were; the shipped layout's layer indices are unchanged without it."""
    from pvo_pseudosensors.sun_bcnn import infer

    torch.manual_seed(0)
    model = SunBCNN(replace(TINY, batch_norm=True, dropout=0.0))
    model.train()
    with torch.no_grad():
        for _ in range(3):  # running statistics away from their initial (0, 1)
            model(torch.rand(8, 1, *SIZE) * 0.5 + 0.3)
    model.eval()
    norms = [m for m in model.modules() if isinstance(m, torch.nn.BatchNorm2d)]
    assert len(norms) == 2 * len(TINY.widths)
    before = [m.running_mean.clone() for m in norms]
    images = torch.rand(4, 1, *SIZE)
    with torch.no_grad():
        expected = model(images).double().numpy()
    for mode in ("full", "head"):
        together = infer.draw_samples(model, images, 3, seed=1, mode=mode).vectors
        alone = infer.draw_samples(model, images[:1], 3, seed=1, mode=mode).vectors
        np.testing.assert_allclose(together, np.broadcast_to(expected, together.shape), atol=1e-6)
        np.testing.assert_allclose(alone[:, 0], together[:, 0], atol=1e-6)
    assert all(torch.equal(m.running_mean, b) for m, b in zip(norms, before, strict=True))
    assert not model.training

    plain = SunBCNN(TINY)
    assert [type(layer).__name__ for layer in plain.features[:5]] == ["Conv2d", "ReLU", "Conv2d", "ReLU", "Dropout2d"]
    old_card = SunTask(TINY).card()  # a card written before the option: no batch_norm key
    del old_card.hyperparameters["batch_norm"]
    assert SunBCNNConfig.from_card(old_card).batch_norm is False


def test_histogram_equalisation_matches_opencv_per_channel() -> None:
    import cv2
    from pvo_pseudosensors.sun_bcnn.model import equalize_histograms

    rng = np.random.default_rng(5)
    grey = [(rng.beta(2.0, 5.0, size=(30, 50)) * 180 + 30).astype(np.uint8) for _ in range(4)]
    batch = torch.from_numpy(np.stack(grey)[:, None] / 255.0).float()
    equalised = (equalize_histograms(batch)[:, 0].numpy() * 255).round().astype(np.uint8)
    for image, ours in zip(grey, equalised, strict=True):
        np.testing.assert_array_equal(ours, cv2.equalizeHist(image))
    colour = torch.from_numpy(np.stack(grey[:3])[None] / 255.0).float()  # one image, three different channels
    np.testing.assert_array_equal(equalize_histograms(colour)[0], equalize_histograms(batch[:3])[:, 0])
    flat = torch.full((1, 1, 8, 8), 77 / 255.0)  # one grey level: nothing to spread
    assert torch.equal(equalize_histograms(flat), flat)


def test_an_equalising_model_reads_any_order_preserving_rescaling_of_an_image_alike() -> None:
    """With ``equalize`` the network's input is the order of the grey levels: a darker exposure or another
    camera's response curve (an order-preserving map of the levels) gives the same answer; without it, not.
    The card says so, and a card written before the option reads as without it."""
    torch.manual_seed(0)
    levels = torch.randint(0, 128, (2, 1, *SIZE))  # 8-bit images that use levels 0-127
    image = levels / 255.0
    rescaled = (2 * levels + 1) / 255.0  # the same order, twice the contrast, brighter
    for equalize in (True, False):
        model = SunBCNN(replace(TINY, equalize=equalize)).eval()
        with torch.no_grad():
            same = torch.allclose(model(image), model(rescaled), atol=1e-6)
        assert same is equalize
    card = SunTask(replace(TINY, equalize=True)).card()
    assert card.input["normalisation"].startswith("histogram-equalised") and SunBCNNConfig.from_card(card).equalize
    del card.hyperparameters["equalize"]
    assert SunBCNNConfig.from_card(card).equalize is False


# --- fine-tunes that keep part of the network -----------------------------------------------------

TINY_NORM = replace(TINY, batch_norm=True)
NORM_PARAMETERS = {f"features.{i}.{p}" for i in (1, 4, 8, 11) for p in ("weight", "bias")}  # TINY_NORM's batch norms


def test_a_fine_tune_changes_only_what_it_is_told_to(sequences, tmp_path: Path) -> None:
    from pvo_pseudosensors.learning.training import FineTune

    train, validation = datasets(sequences)
    torch.manual_seed(0)
    start = save_model(tmp_path / "start", SunBCNN(TINY_NORM), SunTask(TINY_NORM).card())
    before = weights(start)
    for name, trainable, changed in (
        ("features", ("features",), lambda key: key.startswith("features.")),
        ("head", ("head",), lambda key: key.startswith("head.")),
        ("norm", ("norm",), lambda key: key in NORM_PARAMETERS),
        ("all", (), lambda key: True),
    ):
        task = FineTune(SunTask(TINY_NORM), start, trainable)
        fit(task, train, validation, replace(CONFIG, epochs=2, patience=0), tmp_path / name, say=lambda _: None)
        after = weights(tmp_path / name)
        learned = {key for key in after if not key.endswith(("running_mean", "running_var", "num_batches_tracked"))}
        for key in learned:
            assert torch.equal(after[key], before[key]) != changed(key), (name, key)
        notes = load_model(tmp_path / name, "sun-bcnn", build, SIZE)[1].notes
        assert ("the rest kept" in notes) == bool(trainable)


def test_trainable_entries_are_named_and_checked() -> None:
    from pvo_pseudosensors.learning.training import trainable_parameters
    from pvo_pseudosensors.sun_bcnn.model import trainable_selection

    assert trainable_selection("blocks:1", TINY_NORM) == ("features.0.", "features.1.", "features.3.", "features.4.")
    assert trainable_selection("blocks:1", TINY) == ("features.0.", "features.2.")  # no batch norm: conv, relu, ...
    assert trainable_selection("head, norm", TINY) == ("head", "norm")
    with pytest.raises(ValueError, match="'blocks:3': K must be 1 to 2"):
        trainable_selection("blocks:3", TINY)
    with pytest.raises(ValueError, match="'blocks:x': K must be 1 to 2"):
        trainable_selection("blocks:x", TINY)
    model = SunBCNN(TINY_NORM)
    assert trainable_parameters(model, ("norm",)) == NORM_PARAMETERS
    with pytest.raises(ValueError, match="'norm' picks no parameter"):
        trainable_parameters(SunBCNN(TINY), ("norm",))
    with pytest.raises(ValueError, match=r"'backbone' picks no parameter of this network \(its parts: features, head"):
        trainable_parameters(model, ("backbone",))
