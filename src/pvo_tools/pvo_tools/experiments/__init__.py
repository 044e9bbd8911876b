"""Thesis experiments, one module per table: each has ``TITLE``, ``register(parser)`` and ``run(args)``.

Adding an experiment is adding a module and one line to :data:`EXPERIMENTS`.
"""

from __future__ import annotations

import importlib
from types import ModuleType

EXPERIMENTS: dict[str, str] = {
    "sun-sim": "pvo_tools.experiments.sun_sim",
    "sun-bcnn": "pvo_tools.experiments.sun_bcnn",
    "probe": "pvo_tools.experiments.probe",
    "hydranet-1d": "pvo_tools.experiments.hydranet_1d",
    "hydranet": "pvo_tools.experiments.hydranet",
    "dpc-net": "pvo_tools.experiments.dpc_net",
}


def load(name: str) -> ModuleType:
    return importlib.import_module(EXPERIMENTS[name])
