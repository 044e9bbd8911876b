"""Sun-BCNN (thesis ch. 5): the sun direction from one image, with its uncertainty by MC dropout."""

from .model import SunBCNN, SunBCNNConfig, SunTask, predict_sun

__all__ = ["SunBCNN", "SunBCNNConfig", "SunTask", "predict_sun"]
