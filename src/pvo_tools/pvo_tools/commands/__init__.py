"""One module per `pvo` command; each registers its own subparser (``register(subparsers)``) and sets
``handler`` on it. Adding a command is adding a module and its name to :data:`COMMANDS`."""

from __future__ import annotations

COMMANDS = (
    "convert",
    "bag",
    "run",
    "topic",
    "node",
    "interface",
    "vo",
    "probe",
    "eval",
    "sim",
    "corpus",
    "mirror",
    "demo",
    "experiment",
    "models",
    "bench",
)
