"""The learning harness every learned pseudo-sensor trains with: datasets over KITTI-layout sequences with
a decoded-image cache (:mod:`.data`), one training loop with DDP through torchrun (:mod:`.training`), and
checkpoints with their model cards (:mod:`.checkpoint`). A model plugs in with a config, a network and a
loss (a :class:`~.training.Task`)."""

from .checkpoint import ModelCard, ModelFileError, load_model, read_card, save_model
from .data import DataSpec, FrameDataset, Source, cached_images, corpus_sources
from .training import TrainConfig, TrainResult, evaluate, fit

__all__ = [
    "DataSpec",
    "FrameDataset",
    "ModelCard",
    "ModelFileError",
    "Source",
    "TrainConfig",
    "TrainResult",
    "cached_images",
    "corpus_sources",
    "evaluate",
    "fit",
    "load_model",
    "read_card",
    "save_model",
]
