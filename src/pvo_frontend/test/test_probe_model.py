"""PROBE models on disk and in the VO: round trips, one clear line per bad model file, training from a real
KITTI sequence and the VO running with ``probe.model``."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pvo_core.readers import KittiSequence
from pvo_frontend.offline import run_sequence
from pvo_frontend.probe.gk import GKConfig, GKModel
from pvo_frontend.probe.knn import KNNModel
from pvo_frontend.probe.model import ProbeModel
from pvo_frontend.probe.predictors import PredictorConfig
from pvo_frontend.probe.sequences import collect, train_on_sequences
from pvo_frontend.vo import VOConfig, from_flat

from pvo_core import metrics

PREDICTORS = PredictorConfig()


def small_model(kind: str) -> ProbeModel:
    rng = np.random.default_rng(0)
    phi = rng.normal(size=(300, len(PREDICTORS.names)))
    if kind == "gk":
        return ProbeModel(
            "gk", PREDICTORS, GKModel(PREDICTORS.names, phi, rng.normal(size=(300, 3)), GKConfig()), {"note": "test"}
        )
    return ProbeModel("knn", PREDICTORS, KNNModel(PREDICTORS.names, phi, rng.uniform(0.01, 0.2, 300)), {"note": "test"})


@pytest.mark.parametrize("kind", ["gk", "knn"])
def test_a_saved_model_loads_to_the_same_noise(tmp_path: Path, kind: str) -> None:
    model = small_model(kind)
    model.save(tmp_path / "m")
    loaded = ProbeModel.load(tmp_path / "m")
    assert loaded.kind == kind and loaded.training == {"note": "test"}
    image = np.random.default_rng(1).integers(0, 255, (120, 200), dtype=np.uint8)
    current = np.array([[50.0, 60.0], [120.0, 40.0], [180.0, 100.0]])
    disparity = np.array([20.0, 8.0, 3.0])
    a, b = (
        model.noise(current - 1.0, current, image, disparity=disparity),
        loaded.noise(current - 1.0, current, image, disparity=disparity),
    )
    np.testing.assert_allclose(a.covariances, b.covariances)
    if kind == "gk":
        assert a.loss == "student_t" and a.propagate_reference is True and b.propagate_reference is True
        np.testing.assert_allclose(a.loss_scale, b.loss_scale)
    else:
        np.testing.assert_array_equal(a.keep, b.keep)


def test_a_knn_model_with_imu_predictors_works_from_the_images_without_a_reading() -> None:
    """The k-NN model's IMU-less form is its stored errors over the other predictors: the weights a model
    built from those columns gives, which differ from the full model's where the IMU columns matter."""
    with_imu = PredictorConfig(imu=True)
    rng = np.random.default_rng(2)
    phi = rng.normal(size=(400, len(with_imu.names)))
    imu_columns = [with_imu.names.index(n) for n in ("specific_force", "angular_rate")]
    errors = 0.05 + 0.1 * np.abs(phi[:, imu_columns[0]])  # the error grows with |specific force|
    model = ProbeModel("knn", with_imu, KNNModel(with_imu.names, phi, errors))
    without = model.without_imu()
    assert without.predictors.names == PredictorConfig().names and model.without_imu() is without  # built once
    kept = [with_imu.names.index(n) for n in without.predictors.names]
    queries = rng.normal(size=(50, len(with_imu.names)))
    direct = KNNModel(without.predictors.names, phi[:, kept], errors)
    np.testing.assert_allclose(without.estimator.weights(queries[:, kept]), direct.weights(queries[:, kept]), rtol=1e-9)
    assert not np.allclose(model.estimator.weights(queries), direct.weights(queries[:, kept]))


def test_a_card_from_before_the_fitted_prior_loads_with_its_nominal_prior(tmp_path: Path) -> None:
    import yaml

    directory = small_model("gk").save(tmp_path / "old")
    card = yaml.safe_load((directory / "model.yaml").read_text())
    assert card["estimator_config"]["prior"] == "fitted" and card["estimator_config"]["prior_samples"] == 5.0
    card["estimator_config"] = {"radius": 0.25, "max_neighbours": 8, "prior_samples": 3.0, "prior_sigma": [1.0, 1.0, 2.0]}
    (directory / "model.yaml").write_text(yaml.safe_dump(card))
    config = ProbeModel.load(directory).estimator.config
    assert config.prior == "nominal" and config.prior_samples == 3.0 and config.prior_sigma == (1.0, 1.0, 2.0)


def test_a_card_from_before_the_reference_noise_setting_keeps_it_off(tmp_path: Path) -> None:
    """New PROBE-GK models propagate the reference observation's noise in the solver (chosen in stop 42 on 180
    validation sequences); a card without the setting was measured without it and loads that way; a bad value is
    one line."""
    import yaml

    image = np.random.default_rng(1).integers(0, 255, (120, 200), dtype=np.uint8)
    current = np.array([[50.0, 60.0], [120.0, 40.0]])
    directory = small_model("gk").save(tmp_path / "old")
    card = yaml.safe_load((directory / "model.yaml").read_text())
    assert card["propagate_reference"] is True
    del card["propagate_reference"]
    (directory / "model.yaml").write_text(yaml.safe_dump(card))
    old = ProbeModel.load(directory)
    assert old.propagate_reference is False
    assert old.noise(current - 1.0, current, image, disparity=np.array([9.0, 4.0])).propagate_reference is False
    assert old.without_imu().propagate_reference is False
    card["propagate_reference"] = "yes"
    (directory / "model.yaml").write_text(yaml.safe_dump(card))
    with pytest.raises(ValueError, match=r"PROBE model .*old: propagate_reference must be true or false, got 'yes'"):
        ProbeModel.load(directory)


def test_bad_model_files_are_one_clear_line(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no such directory"):
        ProbeModel.load(tmp_path / "nothing")
    good = small_model("gk").save(tmp_path / "good")
    (tmp_path / "no_npz").mkdir()
    (tmp_path / "no_npz" / "model.yaml").write_text((good / "model.yaml").read_text())
    with pytest.raises(ValueError, match="model.npz is missing"):
        ProbeModel.load(tmp_path / "no_npz")
    corrupt = small_model("gk").save(tmp_path / "corrupt")
    (corrupt / "model.npz").write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(ValueError, match=r"model.npz: not a readable PROBE model"):
        ProbeModel.load(corrupt)
    other = small_model("gk").save(tmp_path / "other")
    card = (other / "model.yaml").read_text().replace("- flow_variance\n", "- flow_variance\n- angular_rate\n", 1)
    (other / "model.yaml").write_text(card)
    with pytest.raises(ValueError, match=r"PROBE model .*other: predictors .* do not match"):
        ProbeModel.load(other)
    garbage = small_model("gk").save(tmp_path / "garbage")
    (garbage / "model.yaml").write_text("- just\n- a list\n")
    with pytest.raises(ValueError, match=r"model.yaml: not a readable model card"):
        ProbeModel.load(garbage)
    with pytest.raises(ValueError, match="no such directory"):
        run_sequence_with_model(tmp_path / "missing")


def run_sequence_with_model(model: Path) -> None:
    from pvo_core.camera import StereoCamera
    from pvo_frontend.vo import StereoVO

    StereoVO(StereoCamera(f=700.0, cu=300.0, cv=100.0, baseline=0.5), from_flat({"probe.model": str(model)}))


@pytest.fixture(scope="module")
def kitti06(pvo_data: Path) -> KittiSequence:
    seq = pvo_data / "kitti" / "sequences" / "06"
    return KittiSequence(seq, rate_hz=10.0, poses_file=seq / "poses_frames000-050.txt")


def test_trained_on_kitti_frames_and_run_by_the_vo_through_probe_model(tmp_path: Path, kitti06: KittiSequence) -> None:
    data = collect(kitti06, VOConfig(), PREDICTORS, name="06")
    assert len(data.pairs) == 50 and data.true_motions is not None
    assert all(p.predictors.shape == (len(p), len(PREDICTORS.names)) for p in data.pairs)
    # the recorder leaves the VO as it is
    plain = run_sequence(kitti06, VOConfig())
    np.testing.assert_allclose(np.array(data.vo_motions), np.array([r.transform for r in plain.results[1:]]), atol=1e-12)
    model = train_on_sequences([data], lambda d: kitti06.camera(), PREDICTORS, training={"sequences": ["06"]})
    assert model.training["pairs"] == 50 and len(model.estimator.errors) == model.training["features"]
    path = model.save(tmp_path / "probe06")
    config = replace(VOConfig(), probe=replace(VOConfig().probe, model=str(path)))
    run = run_sequence(kitti06, config)
    assert all(r.transform is not None for r in run.results[1:])
    assert all("feature_noise" in r.timings for r in run.results[1:])
    errors = np.linalg.norm(run.poses[:, :3, 3] - kitti06.poses[:, :3, 3], axis=1)
    assert errors[-1] < 0.05 * metrics.path_distances(kitti06.poses)[-1]  # end drift within 5 % (trained on these frames)
    em = train_on_sequences([data], lambda d: kitti06.camera(), PREDICTORS, em=True, em_iterations=2)
    history = em.training["em_log_likelihood"]["06"]
    assert len(history) == 3 and history[-1] >= history[0]


def imu_model(tmp_path: Path) -> Path:
    """A GK model over image, track, IMU and geometry predictors (random samples: the test is the plumbing)."""
    predictors = PredictorConfig(imu=True)
    rng = np.random.default_rng(3)
    phi = rng.normal(size=(400, len(predictors.names)))
    gk = GKModel(predictors.names, phi, rng.normal(scale=2.0, size=(400, 3)), GKConfig())
    return ProbeModel("gk", predictors, gk, {"note": "imu"}).save(tmp_path / "imu_model")


def test_a_model_with_imu_predictors_reads_the_imu_and_works_from_images_without(tmp_path: Path, kitti06: KittiSequence) -> None:
    frames = KittiSequence(kitti06.root, rate_hz=10.0, poses_file=kitti06.poses_file, count=8)
    imu = np.random.default_rng(5).normal(scale=[0.1, 0.1, 0.1, 2.0, 2.0, 2.0], size=(len(frames), 6))
    with_imu_predictors = PredictorConfig(imu=True)
    data = collect(frames, VOConfig(), with_imu_predictors, name="06", imu=imu)
    trained = train_on_sequences([data], lambda d: frames.camera(), with_imu_predictors)
    model = ProbeModel.load(trained.save(tmp_path / "imu_model"))
    assert model.predictors.imu
    plain = run_sequence(frames, VOConfig())
    without = run_sequence(frames, VOConfig(), feature_noise=model.feature_noise())
    with_imu = run_sequence(frames, VOConfig(), feature_noise=model.feature_noise(), imu=imu)
    # no reading: the same samples without their IMU columns - what a model trained on the other predictors gives
    image_only = PredictorConfig(imu=False)
    columns = [model.predictors.names.index(n) for n in image_only.names]
    stored = model.estimator
    retrained = ProbeModel("gk", image_only, GKModel(image_only.names, stored.predictors[:, columns], stored.errors))
    by_retrained = run_sequence(frames, VOConfig(), feature_noise=retrained.feature_noise()).poses
    np.testing.assert_allclose(without.poses, by_retrained, atol=1e-9)  # the normalisation differs by round-off
    assert not np.allclose(without.poses[-1], plain.poses[-1], atol=1e-9)  # not the default noise
    assert not np.allclose(with_imu.poses[-1], without.poses[-1], atol=1e-9)  # the IMU is used when given
    model = ProbeModel.load(imu_model(tmp_path))
    seen: list[np.ndarray] = []
    hook = model.feature_noise()
    from pvo_frontend.vo.features import StereoFeatures

    left = np.array([[100.0, 100.0], [300.0, 200.0], [600.0, 150.0]])
    features = StereoFeatures(left, left - [10.0, 0.0], np.arange(3), np.ones(3, dtype=np.int64))
    image = np.zeros((370, 1226), np.uint8)
    original = model.noise
    model.noise = lambda *a, **k: seen.append(a[3]) or original(*a, **k)  # type: ignore[method-assign]
    hook(features, features, image, np.array([3.0, 4.0, 0.0, 0.0, 6.0, 8.0]))
    np.testing.assert_allclose(seen[0], [10.0, 5.0])  # (|specific force|, |angular rate|)


def test_imu_readings_nearest_the_frames() -> None:
    from pvo_core.readers import imu_at_stamps

    rows = np.column_stack([np.arange(0.0, 1.0, 0.1), np.arange(10.0).repeat(6).reshape(10, 6)])
    picked = imu_at_stamps(rows, np.array([0.0, 0.14, 0.16, 0.9]))
    np.testing.assert_array_equal(picked[:, 0], [0.0, 1.0, 2.0, 9.0])
    with pytest.raises(ValueError, match="no IMU reading within 0.05 s of the frame at 1.200 s"):
        imu_at_stamps(rows, np.array([0.0, 1.2]))


def test_comparison_averages_each_vo_over_the_ransac_seeds(kitti06: KittiSequence) -> None:
    from pvo_frontend.probe.evaluation import compare_on_sequences

    clip = KittiSequence(kitti06.root, poses_file=kitti06.poses_file, rate_hz=10.0, count=12)
    model = small_model("gk")
    (result,) = compare_on_sequences([("06", clip, None)], VOConfig(), model, seeds=(0, 3))
    independent = []
    for seed in (0, 3):
        config = replace(VOConfig(), ransac=replace(VOConfig().ransac, seed=seed))
        independent.append(metrics.armse(clip.poses, run_sequence(clip, config).poses)["trans"])
    np.testing.assert_allclose(result.default_runs, independent, rtol=1e-12)
    assert result.default["trans"] == pytest.approx(np.mean(independent))
    assert result.default_spread == pytest.approx((max(independent) - min(independent)) / np.mean(independent))
    assert result.change == pytest.approx(np.mean(result.probe_runs) / np.mean(independent) - 1.0)
    with pytest.raises(ValueError, match="at least one RANSAC seed"):
        compare_on_sequences([("06", clip, None)], VOConfig(), model, seeds=())
