"""The learning harness every learned pseudo-sensor trains with: datasets over KITTI-layout sequences with
a decoded-image cache (:mod:`.data`), one training loop with DDP through torchrun (:mod:`.training`), and
checkpoints with their model cards (:mod:`.checkpoint`). A model plugs in with a config, a network and a
loss (a :class:`~.training.Task`). Imported lazily: ``pvo --help`` need not load torch."""

from __future__ import annotations

import importlib
from typing import Any

_HOMES = {
    "DataSpec": "spec",
    "FrameDataset": "data",
    "Source": "data",
    "cached_images": "data",
    "corpus_sources": "data",
    "ModelCard": "checkpoint",
    "ModelFileError": "checkpoint",
    "load_model": "checkpoint",
    "read_card": "checkpoint",
    "save_model": "checkpoint",
    "TrainConfig": "training",
    "TrainResult": "training",
    "evaluate": "training",
    "fit": "training",
}
__all__ = sorted(_HOMES)


def __getattr__(name: str) -> Any:
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f".{_HOMES[name]}", __name__), name)
