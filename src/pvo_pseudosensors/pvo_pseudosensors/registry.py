"""The learned pseudo-sensors, one entry each: how to build a model's training task from its settings, and
how to predict and evaluate with a trained one. `pvo <model> train|predict|eval` is generated from this
table; a new model plugs in with a config, a network, a loss (its :class:`~.learning.training.Task`) and
an entry here."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from .learning.spec import DataSpec


@dataclass(frozen=True)
class ModelEntry:
    """name: the command (`pvo NAME ...`); config: the model's settings dataclass (its fields become
    `train` options); task: settings -> Task; spec: settings -> what the dataset must carry;
    predict / evaluate: the library calls behind `predict` and `eval`."""

    name: str
    description: str
    config: type
    task: Callable[[Any], Any]
    spec: Callable[[Any], DataSpec]
    predict: Callable[..., Any]
    evaluate: Callable[..., dict[str, float]]
    calibrate: Callable[..., dict[str, float]] | None = None  # model dir, validation sequences -> card figures
    prediction_header: str = ""
    options: dict[str, str] = field(default_factory=dict)  # option help per config field


def _sun_bcnn() -> ModelEntry:
    from pvo_core.readers import SUN_PREDICTIONS_HEADER

    from .sun_bcnn.config import SunBCNNConfig

    def task(config: SunBCNNConfig):
        from .sun_bcnn.model import SunTask

        return SunTask(config)

    def predict(model_dir, sequence, samples=25, seed=0, cache_dir=None, mode="full"):
        from .sun_bcnn.infer import load_sun_bcnn, predict_sequence

        model, card = load_sun_bcnn(model_dir)
        return predict_sequence(model, card, sequence, samples=samples, seed=seed, cache_dir=cache_dir, mode=mode)

    def calibrate(model_dir, sequences, samples=25, mode="full", cache_dir=None):
        from .learning.checkpoint import write_card
        from .sun_bcnn.infer import calibrate, load_sun_bcnn

        model, card = load_sun_bcnn(model_dir)
        figures = calibrate(model, card, sequences, samples=samples, mode=mode, cache_dir=cache_dir)
        card.calibration = {**figures, "mode": mode}
        write_card(model_dir, card)
        return figures

    def evaluate(predictions, truth):
        from .sun_bcnn.evaluation import evaluate_predictions

        return evaluate_predictions(predictions, truth)

    return ModelEntry(
        name="sun-bcnn",
        description="Sun-BCNN: the sun direction with covariance from one image (thesis ch. 5)",
        config=SunBCNNConfig,
        task=task,
        spec=lambda config: config.spec,
        predict=predict,
        evaluate=evaluate,
        calibrate=calibrate,
        prediction_header=SUN_PREDICTIONS_HEADER,
        options={
            "height": "input height (px)",
            "width": "input width (px)",
            "colour": "RGB input (image_2) instead of grey (image_0)",
            "widths": "channels of the convolutional blocks, comma-separated",
            "hidden": "units of the fully connected layer",
            "dropout": "dropout probability (kept on for MC sampling)",
            "grid": "rows,columns of the region pooling before the head (1,1: global)",
            "mirror": "mirror training images left-right at random (the sun's x negated)",
            "aleatoric": "a von Mises-Fisher concentration per image (heteroscedastic covariance)",
            "augment": "photometric jitter in training (gain, gamma, noise)",
        },
    )


def models() -> dict[str, ModelEntry]:
    """Every learned pseudo-sensor, by command name."""
    entries = [_sun_bcnn()]
    return {entry.name: entry for entry in entries}
