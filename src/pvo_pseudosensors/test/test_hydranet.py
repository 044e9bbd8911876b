"""HydraNet's network, loss, data and sensor: the loss is eq. 7.17 with Sigma_a = (L L^T)^-1; the flow pairs
carry the true rotations (reversed pairs their inverse); a tiny model learns a rotation-only set to a fraction
of its motion; the sensor reports the first image, a size change, a bad stamp and a missing model."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch
from pvo_core.errors import DataFormatError
from pvo_core.lie import quaternion_to_rotation, so3_exp
from pvo_pseudosensors.hydranet import quaternion as quat
from pvo_pseudosensors.hydranet.config import HydraNetConfig
from pvo_pseudosensors.hydranet.evaluation import evaluate_rotations, true_relative_rotations
from pvo_pseudosensors.hydranet.flow import FlowPairs, dense_flow, texture_map
from pvo_pseudosensors.hydranet.model import HydraNet, HydraTask, head_nll, mirror_pairs, precision_root, predict_rotations
from pvo_pseudosensors.hydranet.synthetic import write_rotation_sequence
from pvo_pseudosensors.learning import Source, TrainConfig, fit
from pvo_pseudosensors.learning.checkpoint import ModelFileError, save_model

TINY = HydraNetConfig(height=48, width=144, widths=(8, 16, 16), feature=32, heads=5, head_hidden=32, head_dropout=0.1)


@pytest.fixture(scope="module")
def rotations(tmp_path_factory) -> dict[str, list[Source]]:
    root = tmp_path_factory.mktemp("rotations")
    sources = {}
    for split, seeds in (("train", range(6)), ("validation", (10,)), ("test", (20, 21))):
        sources[split] = []
        for seed in seeds:
            write_rotation_sequence(root / f"{split}{seed}", frames=25, seed=seed)
            sources[split].append(Source(root / f"{split}{seed}", f"{split}{seed}", split))
    return sources


def test_the_head_loss_is_eq_7_17_with_the_inverse_precision() -> None:
    torch.manual_seed(0)
    raw = torch.randn(4, 6, dtype=torch.float64)
    root = precision_root(raw)
    assert torch.all(torch.triu(root, diagonal=1) == 0.0)  # lower triangular
    heads = quat.exp(0.01 * torch.randn(4, 3, 3, dtype=torch.float64))
    target = quat.exp(0.01 * torch.randn(4, 3, dtype=torch.float64))
    covariance = torch.linalg.inv(root @ root.transpose(-1, -2))
    expected = quat.nll(heads, target.unsqueeze(1).expand_as(heads), covariance.unsqueeze(1).expand(4, 3, 3, 3))
    torch.testing.assert_close(head_nll(heads, target, root), expected)
    diagonal = precision_root(raw[:, :3])
    assert torch.all(diagonal == torch.diag_embed(torch.diagonal(diagonal, dim1=-2, dim2=-1)))


def test_prediction_is_the_head_mean_with_epistemic_plus_aleatoric_covariance() -> None:
    torch.manual_seed(1)
    model = HydraNet(TINY)
    flow = torch.randn(3, 2, 48, 144)
    output = predict_rotations(model, flow)
    heads, root = model(flow)
    heads, root = heads.double(), root.double()
    torch.testing.assert_close(output.quaternion, quat.mean(heads))
    torch.testing.assert_close(output.epistemic, quat.epistemic_covariance(heads, quat.mean(heads)))
    torch.testing.assert_close(output.covariance, output.epistemic + torch.linalg.inv(root @ root.transpose(-1, -2)))
    assert not model.training  # dropout off at prediction
    # the heads start near the identity, apart: a small but non-zero spread
    assert 0.0 < float(torch.linalg.eigvalsh(output.epistemic).max()) < 1e-3


def test_flow_pairs_carry_the_true_rotations_and_reversed_pairs_their_inverse(rotations, tmp_path: Path) -> None:
    source = rotations["train"][0]
    data = FlowPairs([source], (48, 144), reverse=True, cache_dir=tmp_path / "cache")
    assert len(data) == 2 * 24
    from pvo_core.trajectory import read_kitti_poses

    poses = read_kitti_poses(source.root / "poses.txt")
    forward, backward = data[4], data[24 + 4]
    assert int(forward["frame"]) == int(backward["frame"]) == 5 and int(backward["reversed"]) == 1
    truth = poses[5, :3, :3].T @ poses[4, :3, :3]  # C_5,4
    np.testing.assert_allclose(quaternion_to_rotation(forward["rotation"].numpy()), truth, atol=1e-6)
    np.testing.assert_allclose(quaternion_to_rotation(backward["rotation"].numpy()), truth.T, atol=1e-6)
    # the reversed flow points the other way
    assert float((forward["flow"] * backward["flow"]).sum()) < 0.0
    cached = sorted(p.name for p in (tmp_path / "cache").glob("flow-*.npy"))
    assert len(cached) == 2
    again = FlowPairs([source], (48, 144), reverse=True, cache_dir=tmp_path / "cache")  # from the cache
    torch.testing.assert_close(again[30]["flow"], data[30]["flow"])


def test_dense_flow_recovers_a_shift() -> None:
    from pvo_pseudosensors.hydranet.synthetic import scene_texture

    scene = scene_texture((80, 200), 3)
    earlier, later = scene[10:58, 20:164], scene[10:58, 17:161]  # the scene moves 3 px right
    flow = dense_flow(np.ascontiguousarray(earlier), np.ascontiguousarray(later))
    np.testing.assert_allclose(np.median(flow[:, 10:-10, 10:-10], axis=(1, 2)), [3.0, 0.0], atol=0.1)
    with pytest.raises(ValueError, match="two grey images of one size"):
        dense_flow(earlier, later[:, :-1])


def test_from_the_global_shift_farneback_follows_a_turn_its_two_level_pyramid_cannot() -> None:
    """At 64 px high OpenCV's Farnebäck has two pyramid levels: a 12-px shift (a 5 deg yaw at 64x208) is lost from
    zero and read whole from the images' global shift (phase correlation)."""
    from pvo_pseudosensors.hydranet.flow import global_shift
    from pvo_pseudosensors.hydranet.synthetic import scene_texture

    scene = scene_texture((96, 260), 5)
    for shift in (3, 12, 18):
        earlier = np.ascontiguousarray(scene[16:80, 30:238])
        later = np.ascontiguousarray(scene[16:80, 30 - shift : 238 - shift])  # the scene moves `shift` px right
        np.testing.assert_allclose(global_shift(earlier, later), [shift, 0.0], atol=0.2)
        primed = np.median(dense_flow(earlier, later, "shift")[:, 8:-8, 24:-24], axis=(1, 2))
        np.testing.assert_allclose(primed, [shift, 0.0], atol=0.15)
        plain = np.median(dense_flow(earlier, later)[:, 8:-8, 24:-24], axis=(1, 2))
        if shift == 3:
            np.testing.assert_allclose(plain, [shift, 0.0], atol=0.15)  # a small shift reads whole either way
        else:
            assert plain[0] < 0.8 * shift
    with pytest.raises(ValueError, match="unknown flow prior 'warp'"):
        dense_flow(earlier, later, "warp")
    with pytest.raises(ValueError, match="unknown flow_prior 'warp'"):
        HydraNetConfig(flow_prior="warp")


def test_a_shift_primed_model_reads_its_own_flow_through_the_sensor_and_the_sequence_call(rotations, tmp_path: Path) -> None:
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence, sequence_inputs

    config = HydraNetConfig(**{**TINY.__dict__, "flow_prior": "shift"})
    torch.manual_seed(0)
    save_model(tmp_path / "model", HydraNet(config), HydraTask(config).card())
    model, card = load_hydranet(tmp_path / "model")
    assert HydraNetConfig.from_card(card).flow_prior == "shift"
    source = rotations["test"][0]
    primed, _ = sequence_inputs(config, source.root, cache_dir=tmp_path / "cache")
    plain, _ = sequence_inputs(TINY, source.root, cache_dir=tmp_path / "cache")  # its own cache file, not the primed one
    assert not torch.equal(primed, plain)
    again, _ = sequence_inputs(config, source.root, cache_dir=tmp_path / "cache")
    assert torch.equal(primed, again)
    predictions = predict_sequence(model, card, source.root)
    sensor = HydraNetSensor(HydraNetSensorConfig(model=str(tmp_path / "model")))
    import cv2

    paths = source.images("left", False)
    estimates = [
        sensor.estimate(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), (k + 1) * 100_000_000) for k, path in enumerate(paths[:3])
    ]
    for k in (1, 2):
        np.testing.assert_allclose(estimates[k].quaternion, predictions.quaternions[k - 1], atol=1e-5)


def test_missing_poses_are_one_line_naming_the_file(tmp_path: Path) -> None:
    write_rotation_sequence(tmp_path / "seq", frames=3)
    (tmp_path / "seq" / "poses.txt").unlink()
    with pytest.raises(ValueError, match=r"poses.txt: needed for HydraNet's targets but missing"):
        FlowPairs([Source(tmp_path / "seq", "seq")], (48, 144))
    assert len(FlowPairs([Source(tmp_path / "seq", "seq")], (48, 144), targets=False)) == 2  # prediction needs none


def test_a_tiny_hydranet_learns_a_rotation_set(rotations, tmp_path: Path) -> None:
    """Trained for seconds on rotation-only pairs, the heads' mean lands within a fraction of the motion and
    the covariance is within an order of magnitude of consistent."""
    train = FlowPairs(rotations["train"], TINY.size, reverse=True, cache_dir=tmp_path)
    validation = FlowPairs(rotations["validation"], TINY.size, cache_dir=tmp_path)
    config = TrainConfig(epochs=30, batch_size=16, learning_rate=3e-3, patience=0, threads=1)
    result = fit(HydraTask(TINY), train, validation, config, tmp_path / "model", say=lambda _: None)
    assert result.history[-1]["train_loss"] < result.history[0]["train_loss"]
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence

    model, card = load_hydranet(tmp_path / "model")
    figures, motion = [], []
    for source in rotations["test"]:
        predictions = predict_sequence(model, card, source.root, cache_dir=tmp_path)
        from pvo_core.trajectory import read_kitti_poses

        truth = true_relative_rotations(read_kitti_poses(source.root / "poses.txt"), predictions.earlier, predictions.frames)
        figures.append(evaluate_rotations(predictions.quaternions, predictions.covariance, truth))
        identity = evaluate_rotations(np.tile([1.0, 0, 0, 0], (len(truth), 1)), predictions.covariance, truth)
        motion.append(identity["angle_mean_deg"])
    error = np.mean([f["angle_mean_deg"] for f in figures])
    assert error < 0.35 * np.mean(motion), (error, motion)
    assert 0.1 < np.mean([f["anees"] for f in figures]) < 10.0


def test_evaluation_of_errors_known_by_construction() -> None:
    rng = np.random.default_rng(4)
    truth = np.stack([so3_exp(rng.normal(size=3) * 0.01) for _ in range(5)])
    offsets = rng.normal(size=(5, 3)) * 1e-3
    from pvo_core.lie import rotation_to_quaternion

    # C_true = Exp(offset) C_est, so C_est = Exp(-offset) C_true
    estimates = np.stack([rotation_to_quaternion(so3_exp(-d) @ t) for d, t in zip(offsets, truth, strict=True)])
    covariance = np.tile(np.diag([1e-6, 4e-6, 1e-6]), (5, 1, 1))
    figures = evaluate_rotations(estimates, covariance, truth)
    np.testing.assert_allclose(figures["angle_mean_deg"], np.degrees(np.linalg.norm(offsets, axis=1)).mean(), rtol=1e-6)
    nees = np.einsum("ni,ij,nj->n", offsets, np.linalg.inv(covariance[0]), offsets)
    np.testing.assert_allclose(figures["anees"], nees.mean() / 3.0, rtol=1e-6)
    np.testing.assert_allclose(figures["nll"], np.mean(0.5 * nees + 0.5 * np.log(np.linalg.det(covariance[0]))), rtol=1e-6)


@pytest.fixture()
def tiny_model(tmp_path: Path) -> Path:
    torch.manual_seed(0)
    return save_model(tmp_path / "model", HydraNet(TINY), HydraTask(TINY).card())


def test_the_sensor_pairs_images_and_reports_what_it_cannot_pair(tiny_model: Path, tmp_path: Path) -> None:
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig

    write_rotation_sequence(tmp_path / "seq", frames=4, size=(96, 288), focal=140.0)
    import cv2

    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in sorted((tmp_path / "seq" / "image_0").glob("*.png"))]
    sensor = HydraNetSensor(HydraNetSensorConfig(model=str(tiny_model)))
    assert sensor.estimate(images[0], 100) is None  # no predecessor
    estimate = sensor.estimate(images[1], 200)
    assert estimate is not None and estimate.earlier_stamp == 100 and estimate.stamp == 200
    assert np.linalg.norm(estimate.quaternion) == pytest.approx(1.0)
    assert np.all(np.linalg.eigvalsh(estimate.covariance) > 0.0)
    with pytest.raises(ValueError, match="is not after the previous image"):
        sensor.estimate(images[2], 150)
    with pytest.raises(ValueError, match="8-bit grey or RGB"):
        sensor.estimate(images[2].astype(np.uint16), 300)
    assert sensor.estimate(images[2], 300) is not None  # the last good image stayed the predecessor
    with pytest.raises(ValueError, match=r"image size changed from \(96, 288\) to \(48, 144\)"):
        sensor.estimate(images[3][::2, ::2].copy(), 400)
    assert sensor.estimate(images[3][::2, ::2].copy(), 500) is not None  # the new size pairs from then on
    assert sensor.estimate(images[3][::2, ::2].copy(), 500 + 10**9) is None  # a gap of 1 s: starts afresh
    with pytest.raises(ModelFileError, match="model directory not found"):
        HydraNetSensor(HydraNetSensorConfig(model=str(tmp_path / "none")))


def test_bootstrapped_heads_each_train_on_a_fixed_half() -> None:
    from pvo_pseudosensors.hydranet.model import bootstrap_mask

    batch = {"sequence": torch.arange(400) % 7, "frame": torch.arange(400), "reversed": torch.arange(400) % 2}
    mask = bootstrap_mask(batch, 25)
    assert set(mask.unique().tolist()) == {0.0, 1.0}
    assert 0.45 < float(mask.mean()) < 0.55 and bool(torch.all((mask.mean(0) > 0.35) & (mask.mean(0) < 0.65)))
    torch.testing.assert_close(bootstrap_mask(batch, 25), mask)  # fixed per sample: every epoch the same half
    agreement = (mask[:, :1] == mask[:, 1:]).float().mean()
    assert 0.4 < float(agreement) < 0.6  # the heads' halves are unrelated
    task = HydraTask(HydraNetConfig(**{**TINY.__dict__, "bootstrap": True}))
    model = task.build()
    flows = torch.randn(4, 2, 48, 144)
    small = {"flow": flows, "rotation": torch.tensor([[1.0, 0, 0, 0]] * 4), **{k: v[:4] for k, v in batch.items()}}
    model.eval()  # in evaluation every head counts: the plain mean
    heads, root = model(flows)
    torch.testing.assert_close(task.loss(model, small), head_nll(heads, small["rotation"], root).mean())


def _rotation_flow(rotation: np.ndarray, height: int = 24, width: int = 40, focal: float = 30.0) -> np.ndarray:
    """(2, H, W) pixel flow a pure rotation C_k,k-1 makes, principal point at the image's centre."""
    centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0])
    v, u = np.mgrid[0:height, 0:width].astype(float)
    bearings = np.stack([(u - centre[0]) / focal, (v - centre[1]) / focal, np.ones_like(u)], axis=-1)
    moved = bearings @ rotation.T
    projected = focal * moved[..., :2] / moved[..., 2:] + centre
    return np.moveaxis(projected - np.stack([u, v], axis=-1), -1, 0)


def test_a_mirrored_pair_is_the_flow_and_rotation_of_the_mirrored_drive() -> None:
    rotation = so3_exp(np.array([0.01, 0.05, -0.02]))
    mirror = np.diag([-1.0, 1.0, 1.0])
    flow = torch.from_numpy(_rotation_flow(rotation)[None])
    q = quat.exp(torch.tensor([[0.01, 0.05, -0.02]], dtype=torch.float64))
    mirrored_flow, mirrored_q = mirror_pairs(flow, q, torch.tensor([True]))
    np.testing.assert_allclose(mirrored_flow[0].numpy(), _rotation_flow(mirror @ rotation @ mirror), atol=1e-9)
    np.testing.assert_allclose(quaternion_to_rotation(mirrored_q[0].numpy()), mirror @ rotation @ mirror, atol=1e-12)
    kept_flow, kept_q = mirror_pairs(flow, q, torch.tensor([False]))
    assert torch.equal(kept_flow, flow) and torch.equal(kept_q, q)


def test_the_texture_channel_is_the_log_gradient_of_the_image_the_flow_starts_from(rotations, tmp_path: Path) -> None:
    ramp = np.tile((np.arange(40) * 3).astype(np.uint8), (20, 1))  # 3 grey levels per pixel along u
    np.testing.assert_allclose(texture_map(ramp)[5:-5, 5:-5], np.log1p(3.0), rtol=1e-6)
    assert np.all(texture_map(np.full((20, 40), 128, np.uint8)) == 0.0)  # flat: no texture

    source = rotations["train"][0]
    plain = FlowPairs([source], (48, 144), reverse=True, cache_dir=tmp_path)
    textured = FlowPairs([source], (48, 144), reverse=True, cache_dir=tmp_path, texture=True)
    images = textured.pairs[0].images
    forward, backward = textured[4], textured[24 + 4]  # the pair 4 -> 5 and its reverse 5 -> 4
    assert forward["flow"].shape == (3, 48, 144)
    torch.testing.assert_close(forward["flow"][:2], plain[4]["flow"])
    np.testing.assert_allclose(forward["flow"][2].numpy(), texture_map(np.asarray(images[4, 0])))
    np.testing.assert_allclose(backward["flow"][2].numpy(), texture_map(np.asarray(images[5, 0])))
    # mirrored, the texture is flipped but keeps its sign
    mirrored, _ = mirror_pairs(forward["flow"][None], forward["rotation"][None], torch.tensor([True]))
    torch.testing.assert_close(mirrored[0, 2], forward["flow"][2].flip(-1))


def test_the_pitch_channel_is_the_camera_pitch_its_sim_yaml_records(rotations, tmp_path: Path) -> None:
    import shutil

    from pvo_core.errors import DataFormatError

    source = rotations["train"][0]
    with pytest.raises(DataFormatError, match="needs the camera's pitch"):
        FlowPairs([source], (48, 144), cache_dir=tmp_path, pitch=True)
    copy = tmp_path / "pitched"
    shutil.copytree(source.root, copy)
    (copy / "sim.yaml").write_text("config:\n  pitch_deg: 12.5\n")
    pitched = FlowPairs([Source(copy, "pitched")], (48, 144), cache_dir=tmp_path, pitch=True)
    plain = FlowPairs([source], (48, 144), cache_dir=tmp_path)
    sample = pitched[4]
    assert sample["flow"].shape == (3, 48, 144)
    torch.testing.assert_close(sample["flow"][:2], plain[4]["flow"])
    assert torch.all(sample["flow"][2] == 1.25)  # 12.5 deg / 10
    (copy / "sim.yaml").write_text("config: {}\n")
    with pytest.raises(DataFormatError, match="pitch_deg"):
        FlowPairs([Source(copy, "pitched")], (48, 144), cache_dir=tmp_path, pitch=True)
    assert HydraNetConfig(pitch=True, texture=True).channels == 4


def test_a_pitched_model_predicts_through_the_sensor_and_the_sequence_call_alike(rotations, tmp_path: Path) -> None:
    import shutil

    import cv2
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence

    config = HydraNetConfig(**{**TINY.__dict__, "pitch": True})
    torch.manual_seed(0)
    save_model(tmp_path / "model", HydraNet(config), HydraTask(config).card())
    model, card = load_hydranet(tmp_path / "model")
    sequence = tmp_path / "pitched"
    shutil.copytree(rotations["test"][0].root, sequence)
    (sequence / "sim.yaml").write_text("config:\n  pitch_deg: 20.0\n")
    predictions = predict_sequence(model, card, sequence)
    told = predict_sequence(model, card, rotations["test"][0].root, pitch_deg=20.0)  # no sim.yaml there
    np.testing.assert_allclose(told.quaternions, predictions.quaternions, atol=1e-6)
    paths = sorted((sequence / "image_0").iterdir())[:3]
    for pitch, agrees in ((20.0, True), (0.0, False)):
        sensor = HydraNetSensor(HydraNetSensorConfig(model=str(tmp_path / "model"), camera_pitch_deg=pitch))
        images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
        estimates = [sensor.estimate(image, (k + 1) * 100_000_000) for k, image in enumerate(images)]
        assert np.allclose(estimates[2].quaternion, predictions.quaternions[1], atol=1e-5) == agrees


def test_a_textured_model_predicts_through_the_sensor_and_the_sequence_call_alike(rotations, tmp_path: Path) -> None:
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence

    config = HydraNetConfig(**{**TINY.__dict__, "texture": True})
    torch.manual_seed(0)
    save_model(tmp_path / "model", HydraNet(config), HydraTask(config).card())
    model, card = load_hydranet(tmp_path / "model")
    source = rotations["test"][0]
    predictions = predict_sequence(model, card, source.root)
    sensor = HydraNetSensor(HydraNetSensorConfig(model=str(tmp_path / "model")))
    paths = source.images("left", False)
    import cv2

    estimates = [
        sensor.estimate(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE), (k + 1) * 100_000_000) for k, path in enumerate(paths[:3])
    ]
    assert estimates[0] is None
    for k in (1, 2):
        np.testing.assert_allclose(estimates[k].quaternion, predictions.quaternions[k - 1], atol=1e-5)


def test_mirrored_inference_pools_the_heads_of_a_pair_and_of_its_mirror_image() -> None:
    from pvo_pseudosensors.hydranet.model import mirror_flow

    torch.manual_seed(2)
    model = HydraNet(TINY)
    flow = torch.randn(3, 2, 48, 144)
    output = predict_rotations(model, flow, mirrored=True)
    heads, root = model(flow)
    mirror_heads, mirror_root = model(mirror_flow(flow))
    signs = torch.tensor([1.0, 1.0, -1.0, -1.0], dtype=torch.float64)
    pooled = torch.cat([heads.double(), mirror_heads.double() * signs], dim=1)  # 2H heads
    assert pooled.shape == (3, 2 * TINY.heads, 4)
    torch.testing.assert_close(output.quaternion, quat.mean(pooled))
    torch.testing.assert_close(output.epistemic, quat.epistemic_covariance(pooled, quat.mean(pooled)))
    axes = torch.diag(signs[1:])
    aleatoric = torch.linalg.inv(root.double() @ root.double().transpose(-1, -2))
    mirror_aleatoric = axes @ torch.linalg.inv(mirror_root.double() @ mirror_root.double().transpose(-1, -2)) @ axes
    torch.testing.assert_close(output.aleatoric, 0.5 * (aleatoric + mirror_aleatoric))
    # exactly mirror-equivariant: the mirror image's estimate is this one seen in the mirror
    seen = predict_rotations(model, mirror_flow(flow), mirrored=True)
    torch.testing.assert_close(seen.quaternion, output.quaternion * signs)
    torch.testing.assert_close(seen.covariance, axes @ output.covariance @ axes)
    plain = predict_rotations(model, flow)
    assert not torch.allclose(plain.quaternion, output.quaternion)  # the mirror image's heads count


def test_reversed_inference_pools_the_inverted_heads_of_the_pair_read_backwards() -> None:
    torch.manual_seed(3)
    model = HydraNet(TINY)
    forward, backward = torch.randn(3, 2, 48, 144), torch.randn(3, 2, 48, 144)
    output = predict_rotations(model, forward, reversed_flow=backward)
    heads, root = model(forward)
    back_heads, back_root = model(backward)
    inverse = torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=torch.float64)
    pooled = torch.cat([heads.double(), back_heads.double() * inverse], dim=1)  # 2H heads, all of C_k,k-1
    torch.testing.assert_close(output.quaternion, quat.mean(pooled))
    torch.testing.assert_close(output.epistemic, quat.epistemic_covariance(pooled, quat.mean(pooled)))
    # Sigma_a of C_k-1,k carried to C_k,k-1's left tangent space: Exp(e) q -> q^-1 Exp(-e) = Exp(-R e) q^-1
    rotation = torch.from_numpy(np.stack([quaternion_to_rotation(q) for q in output.quaternion.numpy()]))
    aleatoric = torch.linalg.inv(root.double() @ root.double().transpose(-1, -2))
    back_aleatoric = torch.linalg.inv(back_root.double() @ back_root.double().transpose(-1, -2))
    expected = 0.5 * (aleatoric + rotation @ back_aleatoric @ rotation.transpose(-1, -2))
    torch.testing.assert_close(output.aleatoric, expected)
    # exactly time-reversal equivariant: the pair read the other way gives the inverse rotation, its covariance
    # carried by that rotation
    swapped = predict_rotations(model, backward, reversed_flow=forward)
    torch.testing.assert_close(swapped.quaternion, output.quaternion * inverse)
    torch.testing.assert_close(swapped.covariance, rotation.transpose(-1, -2) @ output.covariance @ rotation)
    with pytest.raises(ValueError, match="reversed inputs"):
        predict_rotations(model, forward, reversed_flow=backward[:2])


@pytest.mark.parametrize("mode", ["mirrored", "reversed"])
def test_the_card_mode_runs_through_the_sensor_and_the_sequence_call_alike(rotations, tmp_path: Path, mode: str) -> None:
    import cv2
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_flows, predict_sequence
    from pvo_pseudosensors.learning.checkpoint import write_card
    from pvo_pseudosensors.registry import models

    torch.manual_seed(0)
    directory = save_model(tmp_path / "model", HydraNet(TINY), HydraTask(TINY).card())
    source = rotations["validation"][0]
    with pytest.raises(ValueError, match="--mode full: HydraNet runs plain, mirrored or reversed"):
        models()["hydranet"].calibrate(directory, [source.root], mode="full")
    figures = models()["hydranet"].calibrate(directory, [source.root], mode=mode)
    model, card = load_hydranet(directory)
    assert card.calibration["mode"] == mode and card.calibration["pairs"] == figures["pairs"] == 24
    predictions = predict_sequence(model, card, source.root)
    pairs = FlowPairs([source], TINY.size, reverse=True, targets=False).pairs[0]
    forward, backward = (torch.from_numpy(np.asarray(f, dtype=np.float32)) for f in (pairs.forward, pairs.backward))
    if mode == "mirrored":
        expected, _, _ = predict_flows(model, forward, mirrored=True)
    else:  # each pair also read from the later image to the earlier
        expected, _, _ = predict_flows(model, forward, reversed_flows=backward)
    plain, _, _ = predict_flows(model, forward)
    np.testing.assert_allclose(predictions.quaternions, expected, atol=1e-12)
    assert np.abs(predictions.quaternions - plain).max() > 1e-6
    sensor = HydraNetSensor(HydraNetSensorConfig(model=str(directory)))
    paths = source.images("left", False)
    estimates = [sensor.estimate(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), (k + 1) * 10**8) for k, p in enumerate(paths[:3])]
    for k in (1, 2):
        np.testing.assert_allclose(estimates[k].quaternion, predictions.quaternions[k - 1], atol=1e-5)
        scale = np.abs(predictions.covariance[k - 1]).max()  # the cached flows are float16, the sensor's float32
        np.testing.assert_allclose(estimates[k].covariance, predictions.covariance[k - 1], atol=1e-3 * scale)
    card.calibration["mode"] = "sideways"
    write_card(directory, card)
    with pytest.raises(ValueError, match="unknown HydraNet mode 'sideways'"):
        HydraNetSensor(HydraNetSensorConfig(model=str(directory)))


def test_an_ensemble_pools_every_members_heads_and_averages_their_aleatoric_covariances() -> None:
    from pvo_pseudosensors.hydranet.model import HydraEnsemble

    torch.manual_seed(3)
    first, second = HydraNet(TINY), HydraNet(TINY)
    flow = torch.randn(4, 2, 48, 144)
    output = predict_rotations(HydraEnsemble([first, second]), flow)
    (heads_a, root_a), (heads_b, root_b) = first(flow), second(flow)
    pooled = torch.cat([heads_a, heads_b], dim=1).double()  # 2H heads
    torch.testing.assert_close(output.quaternion, quat.mean(pooled))
    torch.testing.assert_close(output.epistemic, quat.epistemic_covariance(pooled, quat.mean(pooled)))
    # Sigma_a of each member from its precision root, computed here without cholesky_inverse
    covariances = [torch.linalg.inv(r.double() @ r.double().transpose(-1, -2)) for r in (root_a, root_b)]
    torch.testing.assert_close(output.aleatoric, 0.5 * (covariances[0] + covariances[1]), rtol=1e-5, atol=1e-12)
    # two bodies that disagree spread wider than either one's heads alone
    alone = predict_rotations(first, flow)
    assert torch.all(torch.linalg.det(output.epistemic) > torch.linalg.det(alone.epistemic))
    assert HydraEnsemble([first, second]).head_count == 2 * first.head_count == 2 * TINY.heads
    with pytest.raises(ValueError, match="at least two HydraNets"):
        HydraEnsemble([first])


def test_an_ensemble_directory_runs_as_one_model_everywhere_and_bad_ones_are_one_line(rotations, tmp_path: Path) -> None:
    import cv2
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence, write_ensemble
    from pvo_pseudosensors.hydranet.model import HydraEnsemble
    from pvo_pseudosensors.learning.checkpoint import read_card, write_card
    from pvo_pseudosensors.registry import models

    torch.manual_seed(0)
    first = save_model(tmp_path / "a", HydraNet(TINY), HydraTask(TINY).card())
    second = save_model(tmp_path / "b", HydraNet(TINY), HydraTask(TINY).card())
    out = write_ensemble([first, second], tmp_path / "ensemble", "pvo hydranet ensemble a b -o ensemble")
    model, card = load_hydranet(out)
    assert isinstance(model, HydraEnsemble) and card.calibration == {"mode": "plain", "members": ["members/member-1"]}
    assert card.commands["ensemble"] == "pvo hydranet ensemble a b -o ensemble"
    source = rotations["validation"][0]
    predictions = predict_sequence(model, card, source.root)
    direct = predict_rotations(HydraEnsemble([load_hydranet(first)[0], load_hydranet(second)[0]]), _flows(source))
    np.testing.assert_allclose(predictions.quaternions, direct.quaternion.numpy(), atol=1e-12)
    np.testing.assert_allclose(predictions.covariance, direct.covariance.numpy(), rtol=1e-9, atol=1e-15)
    # the node's sensor reads the same directory the same way
    sensor = HydraNetSensor(HydraNetSensorConfig(model=str(out)))
    paths = source.images("left", False)
    estimates = [sensor.estimate(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), (k + 1) * 10**8) for k, p in enumerate(paths[:2])]
    np.testing.assert_allclose(estimates[1].quaternion, predictions.quaternions[0], atol=1e-5)
    # calibrate records its mode and figures and keeps the ensemble one
    models()["hydranet"].calibrate(out, [source.root], mode="mirrored")
    assert read_card(out).calibration["members"] == ["members/member-1"]
    assert isinstance(load_hydranet(out)[0], HydraEnsemble)
    # bad inputs: one line each, nothing written
    with pytest.raises(ValueError, match="at least two models"):
        write_ensemble([first], tmp_path / "one")
    with pytest.raises(ValueError, match="already holds a model"):
        write_ensemble([first, second], out)
    with pytest.raises(ValueError, match="already an ensemble; give its members"):
        write_ensemble([out, first], tmp_path / "nested")
    wider = dataclasses.replace(TINY, width=160)
    other = save_model(tmp_path / "c", HydraNet(wider), HydraTask(wider).card())
    with pytest.raises(ValueError, match=r"read different inputs \(.*a: 48x144 flow, .*c: 48x160 flow\)"):
        write_ensemble([first, other], tmp_path / "mixed")
    pitched = dataclasses.replace(TINY, pitch=True)
    told = save_model(tmp_path / "d", HydraNet(pitched), HydraTask(pitched).card())
    with pytest.raises(ValueError, match=r"read different inputs \(.*a: 48x144 flow, .*d: 48x144 flow with pitch\)"):
        write_ensemble([first, told], tmp_path / "mixed")
    assert not (tmp_path / "one").exists() and not (tmp_path / "mixed").exists()
    import shutil

    member = out / "members" / "member-1"
    shutil.copytree(out, tmp_path / "kept")  # the good ensemble, for the next case
    for name in ("weights.safetensors", "model.yaml"):  # a member of another input size put in by hand
        shutil.copyfile(other / name, member / name)
    with pytest.raises(ModelFileError, match=r"member-1/model.yaml: reads 48x160 flow, the ensemble's first network 48x144"):
        load_hydranet(out)
    nested = read_card(tmp_path / "kept")
    write_card(tmp_path / "kept" / "members" / "member-1", nested)  # a member whose card lists members itself
    with pytest.raises(ModelFileError, match="a member of an ensemble cannot be an ensemble itself"):
        load_hydranet(tmp_path / "kept")
    shutil.copyfile(first / "model.yaml", member / "model.yaml")
    (out / "members" / "member-1" / "weights.safetensors").unlink()
    with pytest.raises(ModelFileError, match=r"member-1/weights.safetensors: weights file not found"):
        load_hydranet(out)
    card = read_card(out)
    card.calibration["members"] = "members/member-1"
    write_card(out, card)
    with pytest.raises(ModelFileError, match="calibration.members must be a list"):
        load_hydranet(out)


def _flows(source) -> torch.Tensor:
    pairs = FlowPairs([source], TINY.size, reverse=False, targets=False).pairs[0]
    return torch.from_numpy(np.asarray(pairs.forward, dtype=np.float32))


def test_the_shipped_default_reads_the_pitch_it_is_told_and_the_level_model_is_found_by_name(pvo_data: Path) -> None:
    """The default model (since stop 68) has the pitch input, so the camera's pitch reaches the network; the level
    model it replaced is a shipped name like ``hydranet_kitti`` and has none: the same two KITTI images read as a level
    and as a 20-degree pitched camera differ.
    (Nothing here asks the weights to be good.)"""
    import cv2
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig, resolve_model
    from pvo_pseudosensors.learning.checkpoint import read_card

    directory = resolve_model("hydranet_level")
    assert directory.parts[-2:] == ("models", "hydranet_level")
    assert not HydraNetConfig.from_card(read_card(directory)).pitch
    assert resolve_model("") == resolve_model("hydranet") and resolve_model("").parts[-2:] == ("models", "hydranet")
    assert HydraNetConfig.from_card(read_card(resolve_model(""))).pitch
    paths = sorted((pvo_data / "kitti" / "sequences" / "06" / "image_0").glob("*.png"))[:2]
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    readings = []
    for pitch in (0.0, 20.0):
        sensor = HydraNetSensor(HydraNetSensorConfig(camera_pitch_deg=pitch))
        estimates = [sensor.estimate(image, (k + 1) * 100_000_000) for k, image in enumerate(images)]
        assert np.all(np.isfinite(estimates[1].quaternion)) and np.all(np.isfinite(estimates[1].covariance))
        readings.append(estimates[1].quaternion)
    assert not np.allclose(readings[0], readings[1], atol=1e-7)


def _stereo_copy(source: Source, root: Path, disparity: int, focal: float = 70.0, baseline: float = 0.5) -> Source:
    """``source`` with a right camera that sees every left image shifted by ``disparity`` px (a fronto-parallel
    scene at Z = focal * baseline / disparity) and the calib.txt of that rig."""
    import cv2

    (root / "image_0").mkdir(parents=True)
    (root / "image_1").mkdir()
    for path in sorted((source.root / "image_0").glob("*.png")):
        left = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(root / "image_0" / path.name), left)
        right = np.roll(left, -disparity, axis=1)  # x_right = x_left - d
        cv2.imwrite(str(root / "image_1" / path.name), right)
    (root / "poses.txt").write_text((source.root / "poses.txt").read_text())
    height, width = left.shape
    p0 = f"{focal} 0 {width / 2} 0 0 {focal} {height / 2} 0 0 0 1 0"
    p1 = f"{focal} 0 {width / 2} {-focal * baseline} 0 {focal} {height / 2} 0 0 0 1 0"
    (root / "calib.txt").write_text(f"P0: {p0}\nP1: {p1}\n")
    return Source(root, root.name)


def test_the_depth_channel_is_the_stereo_inverse_depth_of_the_image_the_flow_starts_from(rotations, tmp_path: Path) -> None:
    """A right camera that sees the scene shifted by 7 px: inverse depth 7 / (f b) wherever the matcher can search,
    0 in the left border it cannot; the channel rides with the flow of the image it starts from (the later one for a
    reversed pair), and a mirrored pair flips it; the sensor refuses such a model with one line."""
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.flow import DEPTH_SCALE, stereo_inverse_depth

    source = _stereo_copy(rotations["train"][0], tmp_path / "stereo", disparity=7)
    import cv2

    left = cv2.imread(str(source.root / "image_0" / "000003.png"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(source.root / "image_1" / "000003.png"), cv2.IMREAD_GRAYSCALE)
    inverse = stereo_inverse_depth(left, right, 70.0, 0.5, left.shape)
    searchable = inverse[8:-8, 40:-16]  # away from the 32-px border the matcher cannot search and the image's edges
    assert np.median(searchable) == pytest.approx(7 * DEPTH_SCALE / 35.0, rel=0.02)
    assert np.all(inverse[:, :16] == 0.0)

    plain = FlowPairs([source], (48, 144), reverse=True, cache_dir=tmp_path)
    deep = FlowPairs([source], (48, 144), reverse=True, cache_dir=tmp_path, depth=True)
    depths = deep.pairs[0].inverse_depths
    assert depths is not None and depths.shape == (25, 1, 48, 144)
    forward, backward = deep[4], deep[24 + 4]  # the pair 4 -> 5 and its reverse 5 -> 4
    assert forward["flow"].shape == (3, 48, 144)
    torch.testing.assert_close(forward["flow"][:2], plain[4]["flow"])
    np.testing.assert_array_equal(forward["flow"][2].numpy(), depths[4, 0].astype(np.float32))
    np.testing.assert_array_equal(backward["flow"][2].numpy(), depths[5, 0].astype(np.float32))
    mirrored, _ = mirror_pairs(forward["flow"][None], forward["rotation"][None], torch.tensor([True]))
    torch.testing.assert_close(mirrored[0, 2], forward["flow"][2].flip(-1))
    assert HydraNetConfig(depth=True).channels == 3 and HydraNetConfig(depth=True, pitch=True).channels == 4

    config = dataclasses.replace(TINY, depth=True)
    task = HydraTask(config)
    save_model(tmp_path / "deep-model", HydraNet(config), task.card())
    from pvo_pseudosensors.hydranet.infer import load_hydranet, predict_sequence

    model, card = load_hydranet(tmp_path / "deep-model")
    predictions = predict_sequence(model, card, source.root, cache_dir=tmp_path)
    assert len(predictions.frames) == 24
    with pytest.raises(ModelFileError, match="depth input .* read by `pvo hydranet predict` only"):
        HydraNetSensor(HydraNetSensorConfig(model=str(tmp_path / "deep-model")))
    with pytest.raises(DataFormatError, match="image directory not found"):
        FlowPairs(rotations["train"][:1], (48, 144), cache_dir=tmp_path, depth=True)  # no right camera


def test_coordinate_channels_are_each_pixels_place_and_round_trip_through_the_card(tmp_path: Path) -> None:
    """`coordinates`: the network appends (u - W/2) / W and (v - H/2) / H of every pixel centre to its input; the
    data keeps its own channels; a card without the field is a model without them."""
    from pvo_pseudosensors.hydranet.infer import load_hydranet

    config = dataclasses.replace(TINY, coordinates=True)
    assert config.channels == 2  # the data's channels: the network adds its own
    model = HydraNet(config)
    inputs = torch.randn(3, 2, 48, 144)
    extended = model._with_coordinates(inputs)
    assert extended.shape == (3, 4, 48, 144)
    torch.testing.assert_close(extended[:, :2], inputs)
    torch.testing.assert_close(extended[1, 2, 7], (torch.arange(144) + 0.5 - 72) / 144)  # u along the width
    torch.testing.assert_close(extended[2, 3, :, 11], (torch.arange(48) + 0.5 - 24) / 48)  # v down the height
    assert torch.equal(HydraNet(TINY)._with_coordinates(inputs), inputs)
    save_model(tmp_path / "coord", model, HydraTask(config).card())
    loaded, card = load_hydranet(tmp_path / "coord")
    assert HydraNetConfig.from_card(card).coordinates and loaded(inputs)[0].shape == (3, 5, 4)
    card.hyperparameters.pop("coordinates")
    assert not HydraNetConfig.from_card(card).coordinates


def test_pairs_a_gap_apart_carry_the_rotation_over_the_gap_and_chain_without_overlap(rotations, tmp_path: Path) -> None:
    """`gap` g: a sample per frame k >= g with the flow from k - g to k and C_k,k-g (reversed pairs its inverse);
    their flows are cached apart from the consecutive ones; prediction pairs the same frames, :func:`chained` keeps
    0 -> g, g -> 2g, ...; the sensor refuses such a model with one line; a sequence shorter than the gap is named."""
    from pvo_core.trajectory import read_kitti_poses
    from pvo_pseudosensors.hydranet.estimator import HydraNetSensor, HydraNetSensorConfig
    from pvo_pseudosensors.hydranet.flow import dense_flow
    from pvo_pseudosensors.hydranet.infer import chained, load_hydranet, predict_sequence

    source = rotations["train"][1]
    consecutive = FlowPairs([source], (48, 144), reverse=True, cache_dir=tmp_path)
    apart = FlowPairs([source], (48, 144), reverse=True, cache_dir=tmp_path, gap=3)
    assert len(apart) == 2 * 22 and len(list(tmp_path.glob("flow-*.npy"))) == 4
    poses = read_kitti_poses(source.root / "poses.txt")
    forward, backward = apart[5], apart[22 + 5]  # the pair 5 -> 8 and its reverse
    assert int(forward["frame"]) == int(backward["frame"]) == 8
    truth = poses[8, :3, :3].T @ poses[5, :3, :3]  # C_8,5
    np.testing.assert_allclose(quaternion_to_rotation(forward["rotation"].numpy()), truth, atol=1e-6)
    np.testing.assert_allclose(quaternion_to_rotation(backward["rotation"].numpy()), truth.T, atol=1e-6)
    images = apart.pairs[0].images
    expected = dense_flow(np.asarray(images[5, 0]), np.asarray(images[8, 0]))
    np.testing.assert_allclose(forward["flow"].numpy(), expected, atol=2e-2)  # float16 in the cache
    assert not torch.allclose(forward["flow"], consecutive[7]["flow"])  # not the pair 7 -> 8
    assert HydraNetConfig(gap=3).spec.delta == 3
    with pytest.raises(ValueError, match="gap must be >= 1"):
        HydraNetConfig(gap=0)

    config = dataclasses.replace(TINY, gap=3)
    save_model(tmp_path / "gap-model", HydraNet(config), HydraTask(config).card())
    model, card = load_hydranet(tmp_path / "gap-model")
    predictions = predict_sequence(model, card, source.root, cache_dir=tmp_path)
    np.testing.assert_array_equal(predictions.frames, np.arange(3, 25))
    np.testing.assert_array_equal(predictions.frames - predictions.earlier, 3)
    chain = chained(predictions)
    np.testing.assert_array_equal(chain.earlier, [0, 3, 6, 9, 12, 15, 18, 21])
    np.testing.assert_array_equal(chain.frames, chain.earlier + 3)
    np.testing.assert_array_equal(chain.quaternions, predictions.quaternions[chain.earlier])
    with pytest.raises(ModelFileError, match="3 frames apart is read by `pvo hydranet predict` only"):
        HydraNetSensor(HydraNetSensorConfig(model=str(tmp_path / "gap-model")))
    with pytest.raises(DataFormatError, match="at least 26 images"):
        FlowPairs([source], (48, 144), gap=25)
    with pytest.raises(ValueError, match="gap must be >= 1 frame, got 0"):
        FlowPairs([source], (48, 144), gap=0)
