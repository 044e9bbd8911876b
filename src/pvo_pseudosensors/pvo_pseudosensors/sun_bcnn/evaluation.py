"""Sun-BCNN's predictions against the true sun vectors: Table 5.1's columns, the calibration curve (predicted
sigma against the actual error), Tables 5.7/5.8's Method I/II comparison and the time per image.

Prediction rows are :meth:`.infer.SunPredictions.rows` (N, 10): frame, unit vector s (3) in the camera
optical frame, zenith and azimuth (rad), their covariance (4, rad², row-major)."""

from __future__ import annotations

import time

import numpy as np
import torch
from numpy.typing import NDArray
from pvo_core.sun import (
    UNCALIBRATED,
    CovarianceCalibration,
    aleatoric_covariance,
    angle_mean,
    angular_errors,
    sample_mean_and_covariance,
    unit_zenith_azimuth,
    vector_covariance_in_angles,
    wrap_angle,
)

from ..learning.checkpoint import ModelCard
from .infer import Draws, combine, draw_samples
from .model import SunBCNN

Array = NDArray[np.float64]


def evaluate_predictions(predictions: Array, truth: Array) -> dict[str, float]:
    """Errors of prediction rows (N, 10: frame, s, zenith, azimuth, covariance) against the true unit
    vectors of the same frames (N, 3): mean and median vector-angle, zenith and azimuth errors (degrees),
    and the ANEES over (zenith, azimuth) with the predicted covariances."""
    vectors = predictions[:, 1:4]
    errors = angular_errors(vectors, truth)
    true_zenith, true_azimuth = unit_zenith_azimuth(truth / np.linalg.norm(truth, axis=1, keepdims=True))
    residual = np.column_stack([predictions[:, 4] - true_zenith, wrap_angle(predictions[:, 5] - true_azimuth)])
    covariance = predictions[:, 6:10].reshape(-1, 2, 2)
    nees = np.einsum("ni,nij,nj->n", residual, np.linalg.inv(covariance), residual)
    out = {"images": float(len(vectors))}
    for name, values in errors.items():
        out[f"{name}_mean_deg"] = float(np.degrees(values.mean()))
        out[f"{name}_median_deg"] = float(np.degrees(np.median(values)))
        out[f"{name}_std_deg"] = float(np.degrees(values.std()))
    out["anees"] = float(nees.mean() / 2.0)
    close = 1.0 - np.sum(vectors * truth / np.linalg.norm(truth, axis=1, keepdims=True), axis=1) < 0.3
    out["anees_filtered"] = float(nees[close].mean() / 2.0) if close.any() else float("nan")  # the thesis's code
    out["filtered_images"] = float(close.sum())
    return out


def predicted_sigma(rows: Array) -> Array:
    """Per image, the predicted angular standard deviation per tangent axis (rad): the square root of the mean
    of the zenith variance and the azimuth variance scaled by sin² zenith (an azimuth step moves the vector
    by sin(zenith) times the angle)."""
    sin2 = np.sin(rows[:, 4]) ** 2
    return np.sqrt(0.5 * (rows[:, 6] + sin2 * rows[:, 9]))


def calibration_curve(rows: Array, truth: Array, bins: int = 8) -> tuple[Array, Array]:
    """Images binned by predicted sigma (equal counts): the mean predicted sigma per bin and the actual per-axis
    RMS error (the RMS vector angle over sqrt 2, what sigma is for an isotropic tangent error), degrees."""
    sigma, error = predicted_sigma(rows), angular_errors(rows[:, 1:4], truth)["vector"]
    groups = [g for g in np.array_split(np.argsort(sigma, kind="stable"), bins) if len(g)]
    predicted = np.array([np.degrees(sigma[g].mean()) for g in groups])
    actual = np.array([np.degrees(np.sqrt(np.mean(error[g] ** 2) / 2.0)) for g in groups])
    return predicted, actual


def method_comparison(
    draws: Draws, truth: Array, calibration: CovarianceCalibration = UNCALIBRATED
) -> dict[str, dict[str, float]]:
    """Tables 5.7 and 5.8 over MC draws (S, N, 3) of N images: errors of the Method I (normalised vector mean)
    and Method II (mean of the angles) means, and the ANEES of each covariance — Method I (the vectors'
    covariance mapped to angles) and Method II (the angles' covariance) — with each mean; both covariances
    get the same aleatoric term and the same ``calibration``."""
    mean_one, covariance_two = sample_mean_and_covariance(draws.vectors)
    means = {"Method I": mean_one, "Method II": angle_mean(draws.vectors)}
    aleatoric = np.zeros_like(covariance_two)
    if draws.inverse_concentration is not None:
        aleatoric = aleatoric_covariance(mean_one, draws.inverse_concentration.mean(axis=0))
    covariances = {
        "Method I": calibration.apply(vector_covariance_in_angles(draws.vectors, mean_one) + aleatoric),
        "Method II": calibration.apply(covariance_two + aleatoric),
    }
    true_zenith, true_azimuth = unit_zenith_azimuth(truth)
    out: dict[str, dict[str, float]] = {}
    for mean_name, mean in means.items():
        errors = angular_errors(mean, truth)
        zenith, azimuth = unit_zenith_azimuth(mean)
        residual = np.column_stack([zenith - true_zenith, wrap_angle(azimuth - true_azimuth)])
        row = {
            f"{k}_{s}_deg": float(np.degrees(f(v)))
            for k, v in errors.items()
            for s, f in (("mean", np.mean), ("median", np.median), ("std", np.std))
        }
        for cov_name, covariance in covariances.items():
            nees = np.einsum("ni,nij,nj->n", residual, np.linalg.inv(covariance + 1e-12 * np.eye(2)), residual)
            row[f"anees_cov_{cov_name}"] = float(nees.mean() / 2.0)
        out[mean_name] = row
    return out


def time_per_image(model: SunBCNN, card: ModelCard, count: int, mode: str, samples: int = 25) -> float:
    """Milliseconds per image on the node's path (one image at a time, ``samples`` passes, one thread)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        size = tuple(int(v) for v in card.input["size"])
        generator = torch.Generator().manual_seed(0)
        tensors = [torch.rand(1, 1, *size, generator=generator) for _ in range(count)]
        draw_samples(model, tensors[0], samples, 0, mode)  # warm-up
        start = time.perf_counter()
        for k, tensor in enumerate(tensors):
            combine(draw_samples(model, tensor, samples, k, mode))
        return 1000.0 * (time.perf_counter() - start) / len(tensors)
    finally:
        torch.set_num_threads(threads)
