"""A PROBE model on disk and in the VO: ``model.npz`` (the stored samples and their normalisation) and
``model.yaml`` (the model card: kind, predictors and their settings, the estimator's settings, how it was
trained), and the per-frame noise it gives the VO (:class:`pvo_frontend.vo.pipeline.FeatureNoiseEstimate`)."""

from __future__ import annotations

import zipfile
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from .gk import GKConfig, GKModel
from .knn import KNNConfig, KNNModel
from .predictors import PredictorConfig, compute_predictors

Array = NDArray[np.float64]

FORMAT = 1
KINDS = ("gk", "knn")
#: Models installed with the package (share/pvo_frontend/models/NAME), by name: ``probe.model: probe_kitti``.
SHIPPED = ("probe_kitti", "probe_sim")


def shipped_model(name: str) -> Path:
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        return Path(get_package_share_directory("pvo_frontend")) / "models" / name
    except (PackageNotFoundError, ValueError):
        return Path(__file__).resolve().parents[2] / "models" / name


def resolve_model(name: str) -> Path:
    """A model directory: a shipped model's name (unless a local path of that name exists), or a path."""
    if name in SHIPPED and not Path(name).exists():
        return shipped_model(name)
    return Path(name).expanduser()


def imu_magnitudes(imu: Array | None) -> Array | None:
    """(|specific force|, |angular rate|) of an IMU reading [wx, wy, wz, fx, fy, fz]; None for none."""
    if imu is None:
        return None
    reading = np.asarray(imu, dtype=float).reshape(6)
    return np.array([np.linalg.norm(reading[3:]), np.linalg.norm(reading[:3])])


@dataclass
class ProbeModel:
    """A trained PROBE model: its kind (``gk`` or ``knn``), the predictor settings, the estimator and the
    card's training record. propagate_reference (PROBE-GK): the solver also propagates the reference
    observation's noise on top of the Student-t scale. The stored errors already hold that noise, but on 180
    validation sequences (stop 42) propagating it halved the clean sequences PROBE made more than 5 % worse (4 -> 2
    of 81) for 1-2 points of the mean gain; new models propagate, cards written before the setting do not."""

    kind: str
    predictors: PredictorConfig
    estimator: GKModel | KNNModel
    training: dict[str, Any] = field(default_factory=dict)
    nominal_sigma: tuple[float, float, float] = (1.0, 1.0, 2.0)
    propagate_reference: bool = True
    _without_imu: ProbeModel | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"PROBE model kind must be one of {', '.join(KINDS)}, got {self.kind!r}")
        if tuple(self.estimator.names) != self.predictors.names:
            raise ValueError(
                f"the model's predictors {list(self.estimator.names)} differ from its settings' {list(self.predictors.names)}"
            )

    # ------------------------------------------------------------------ files
    def save(self, directory: Path) -> Path:
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        est = self.estimator
        np.savez_compressed(directory / "model.npz", predictors=est.predictors, errors=est.errors, mean=est.mean, std=est.std)
        card = {
            "format": FORMAT,
            "kind": self.kind,
            "predictors": list(self.predictors.names),
            "predictor_config": asdict(self.predictors),
            "estimator_config": asdict(est.config),
            "nominal_sigma": list(self.nominal_sigma),
            "propagate_reference": self.propagate_reference,
            "samples": len(est.errors),
            "training": self.training,
        }
        (directory / "model.yaml").write_text(yaml.safe_dump(card, sort_keys=False))
        return directory

    @classmethod
    def load(cls, directory: Path) -> ProbeModel:
        """The model of ``directory``; every bad or missing file is one ValueError naming it."""
        directory = Path(directory)
        card_path, data_path = directory / "model.yaml", directory / "model.npz"
        if not directory.is_dir():
            raise ValueError(f"PROBE model {directory}: no such directory")
        for path in (card_path, data_path):
            if not path.is_file():
                raise ValueError(f"PROBE model {directory}: {path.name} is missing")
        try:
            card = yaml.safe_load(card_path.read_text())
            if not isinstance(card, dict):
                raise ValueError("not a mapping")
        except (yaml.YAMLError, ValueError, UnicodeDecodeError) as exc:
            raise ValueError(f"{card_path}: not a readable model card ({exc})") from None
        if card.get("format") != FORMAT:
            raise ValueError(f"{card_path}: format {card.get('format')!r}, this pvo reads {FORMAT}")
        try:
            with np.load(data_path) as data:
                arrays = {name: np.asarray(data[name]) for name in ("predictors", "errors", "mean", "std")}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:
            raise ValueError(f"{data_path}: not a readable PROBE model ({exc})") from None
        try:
            return cls._from_card(card, arrays)
        except (KeyError, TypeError, ValueError) as exc:
            what = f"missing {exc}" if isinstance(exc, KeyError) else str(exc)
            raise ValueError(f"PROBE model {directory}: {what}") from None

    @classmethod
    def _from_card(cls, card: dict[str, Any], arrays: dict[str, Array]) -> ProbeModel:
        predictors = PredictorConfig(**card["predictor_config"])
        names = tuple(card["predictors"])
        if names != predictors.names:
            raise ValueError(f"predictors {list(names)} do not match the predictor settings' {list(predictors.names)}")
        columns = arrays["predictors"].shape[-1] if arrays["predictors"].ndim == 2 else -1
        if columns != len(names):
            raise ValueError(f"model.npz holds {columns} predictor columns, the card names {len(names)}")
        settings = {k: tuple(v) if isinstance(v, list) else v for k, v in card["estimator_config"].items()}
        if card["kind"] == "gk":
            settings.setdefault("prior", "nominal")  # cards written before the fitted prior
        samples = (names, arrays["predictors"], arrays["errors"])
        estimator: GKModel | KNNModel
        if card["kind"] == "gk":
            estimator = GKModel(*samples, GKConfig(**settings), arrays["mean"], arrays["std"])
        elif card["kind"] == "knn":
            estimator = KNNModel(*samples, KNNConfig(**settings), arrays["mean"], arrays["std"])
        else:
            raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {card['kind']!r}")
        nominal = tuple(float(v) for v in card.get("nominal_sigma", (1.0, 1.0, 2.0)))
        propagate = card.get("propagate_reference", False)  # cards from before the setting were measured without
        if not isinstance(propagate, bool):
            raise ValueError(f"propagate_reference must be true or false, got {propagate!r}")
        return cls(card["kind"], predictors, estimator, card.get("training") or {}, nominal, propagate)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ in the VO
    def without_imu(self) -> ProbeModel:
        """This model for frames without an IMU reading: the same stored errors queried over its other
        predictors (the IMU columns marginalised out of the kernel), so that one model uses the IMU where there
        is one and works from the images alone where there is not. A model without IMU predictors is itself."""
        if not self.predictors.imu:
            return self
        if self._without_imu is None:
            predictors = replace(self.predictors, imu=False)
            estimator = self.estimator.marginal(predictors.names)
            self._without_imu = ProbeModel(
                self.kind, predictors, estimator, self.training, self.nominal_sigma, self.propagate_reference
            )
        return self._without_imu

    def feature_noise(self) -> Any:
        """The VO's noise hook (:data:`pvo_frontend.vo.pipeline.FeatureNoise`) for this model; a model with IMU
        predictors queries its stored errors without them (:meth:`without_imu`) at a frame without an IMU
        reading."""

        def hook(before: Any, after: Any, image: NDArray[np.uint8], imu: Array | None = None) -> Any:
            magnitudes = imu_magnitudes(imu)
            model = self if magnitudes is not None else self.without_imu()
            return model.noise(before.left, after.left, image, magnitudes, before.observations()[:, 2])

        return hook

    def noise(
        self,
        reference: Array,
        current: Array,
        image: NDArray[np.uint8] | None,
        imu: Array | None = None,
        disparity: Array | None = None,
    ) -> Any:
        """The noise of features tracked from ``reference`` to ``current`` left positions (N, 2) px in
        ``image`` (the current left image), with their reference disparities (N,): per-feature (u, v, d)
        covariances and robust-loss settings."""
        from ..vo.pipeline import FeatureNoiseEstimate

        phi = compute_predictors(self.predictors, reference, current, image, imu, disparity)
        if isinstance(self.estimator, GKModel):
            noise = self.estimator.noise(phi)
            # eq. 4.25: the Student-t with the posterior's dof and scale (and the reference noise on top when the
            # model says so: see propagate_reference)
            return FeatureNoiseEstimate(noise.scale, noise.dof, loss="student_t", propagate_reference=self.propagate_reference)
        covariances, keep = self.estimator.covariances(phi, np.diag(np.asarray(self.nominal_sigma) ** 2))
        return FeatureNoiseEstimate(covariances, None, keep=keep)


def card_vo_calibration(directory: Path) -> Any:
    """The card's ``vo_calibration`` (written by ``pvo probe calibrate``): the per-axis variance scales that make the
    VO with this PROBE model consistent on its calibration data, as a `pvo_frontend.vo_calibration.VOCalibration`;
    None when the card has none; a malformed entry is a ValueError naming the card."""
    from ..vo_calibration import read_vo_calibration

    return read_vo_calibration(Path(directory) / "model.yaml")


def card_vo_covariance_scale(directory: Path) -> list[float] | None:
    """The card's calibration scales (ROS order x y z rx ry rz: the fusion's ``inputs.vo.covariance_scale`` for this
    VO), None when the card has none."""
    calibration = card_vo_calibration(directory)
    return None if calibration is None else list(calibration.covariance_scale)


def write_vo_calibration(directory: Path, entry: dict[str, Any]) -> Path:
    """Record ``entry`` (``covariance_scale`` and how it was measured) as the card's ``vo_calibration``, every other
    field of the card kept as it was."""
    from ..vo_calibration import write_vo_calibration as write_record

    card_path = Path(directory) / "model.yaml"
    if not card_path.is_file():
        raise ValueError(f"{card_path}: no PROBE model card here")
    return write_record(card_path, entry)
