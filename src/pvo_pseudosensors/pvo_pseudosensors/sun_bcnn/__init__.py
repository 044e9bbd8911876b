"""Sun-BCNN (thesis ch. 5): the sun direction from one image, with its uncertainty by MC dropout.

:mod:`.config` (settings, no torch), :mod:`.model` (network and training task), :mod:`.infer` (prediction
on a sequence, the prediction file), :mod:`.evaluation` (against the truth: Table 5.1, calibration curve,
Method I/II), :mod:`.estimator` (one image at a time, for the node)."""

from .config import ARCHITECTURE, SunBCNNConfig

__all__ = ["ARCHITECTURE", "SunBCNNConfig"]
