"""Trained models on disk: ``weights.safetensors`` plus ``model.yaml``, the model card.

The card states the architecture and its hyper-parameters, the input (size, colour, normalisation), the
corpus it was trained on (manifest hash), the commands that made corpus and weights, the commit, and the
validation figures. :func:`load_model` is the one loader for every model: a missing, truncated or corrupt
file, a card without its fields, another architecture or another input size each raise
:class:`ModelFileError`, one line naming the file and what is wrong.
"""

from __future__ import annotations

import subprocess
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import torch

WEIGHTS = "weights.safetensors"
CARD = "model.yaml"
REQUIRED = ("architecture", "hyperparameters", "input")


class ModelFileError(ValueError):
    """A model directory that cannot be used: ``str()`` is one line naming the file."""


@dataclass
class ModelCard:
    """What a trained model is and how it was made (``model.yaml``)."""

    architecture: str
    hyperparameters: dict[str, Any]
    input: dict[str, Any]  # size [height, width], colour, normalisation
    corpus: dict[str, Any] = field(default_factory=dict)  # manifest path and hash
    commands: dict[str, str] = field(default_factory=dict)  # corpus, train
    commit: str = ""
    validation: dict[str, float] = field(default_factory=dict)
    training: dict[str, Any] = field(default_factory=dict)  # epochs, best epoch, seconds, threads, processes
    calibration: dict[str, Any] = field(default_factory=dict)  # set after training, on the validation split
    notes: str = ""
    created: str = ""

    def to_yaml(self) -> str:
        import yaml

        return yaml.safe_dump(_plain(asdict(self)), sort_keys=False, width=120, allow_unicode=True)


def _plain(value: Any) -> Any:
    """YAML-safe copy: tuples to lists, numpy/torch scalars to floats."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if hasattr(value, "item") and not isinstance(value, str):
        return value.item()
    return value


def current_commit(directory: Path | None = None) -> str:
    """The git commit of the working tree (``+dirty`` when it has changes), or "" outside git."""
    try:
        cwd = directory or Path(__file__).parent
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True, timeout=10)
        if rev.returncode != 0:
            return ""
        dirty = subprocess.run(["git", "status", "--porcelain"], cwd=cwd, capture_output=True, text=True, timeout=10)
        return rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return ""


def write_card(directory: Path, card: ModelCard) -> Path:
    """Rewrite ``model.yaml`` (e.g. after calibration), whole or not at all."""
    path = Path(directory) / CARD
    temporary = path.parent / f".{CARD}.tmp"
    temporary.write_text(card.to_yaml())
    temporary.replace(path)
    return path


def save_model(directory: Path, model: torch.nn.Module, card: ModelCard) -> Path:
    """Write the weights and the card into ``directory`` (created); both written whole or not at all."""
    from safetensors.torch import save_file

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    if not card.created:
        card.created = datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
    state = {k: v.detach().contiguous().cpu() for k, v in _unwrapped(model).state_dict().items()}
    temporary = directory / f".{WEIGHTS}.tmp"
    save_file(state, str(temporary), metadata={"architecture": card.architecture})
    temporary.replace(directory / WEIGHTS)
    card_temporary = directory / f".{CARD}.tmp"
    card_temporary.write_text(card.to_yaml())
    card_temporary.replace(directory / CARD)
    return directory


def _unwrapped(model: torch.nn.Module) -> torch.nn.Module:
    return getattr(model, "module", model)  # DistributedDataParallel wraps the model


def read_card(directory: Path) -> ModelCard:
    """The model card of ``directory``; :class:`ModelFileError` naming ``model.yaml`` when it is missing,
    unreadable or lacks a required field."""
    import yaml

    path = Path(directory) / CARD
    if not path.is_file():
        raise ModelFileError(f"{path}: model card not found (a model directory holds {WEIGHTS} and {CARD})")
    try:
        data = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ModelFileError(f"{path}: unreadable model card ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ModelFileError(f"{path}: not a model card (expected a mapping)")
    missing = [name for name in REQUIRED if name not in data]
    if missing:
        raise ModelFileError(f"{path}: model card lacks {', '.join(missing)}")
    if not isinstance(data["input"], dict) or "size" not in data["input"]:
        raise ModelFileError(f"{path}: model card's input lacks its size")
    known = {f for f in ModelCard.__dataclass_fields__}
    return ModelCard(**{k: v for k, v in data.items() if k in known})


def load_model(
    directory: Path, architecture: str, build: Any, input_size: tuple[int, int] | None = None
) -> tuple[torch.nn.Module, ModelCard]:
    """Load a model saved by :func:`save_model`: ``build(card)`` makes the empty network from the card.

    Refused, each with one line naming the file: a missing directory, card or weights file; a truncated or
    corrupt weights file; a card of another ``architecture``; another ``input_size`` (height, width) than the
    caller feeds; weights that do not fit the network the card describes."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    directory = Path(directory)
    if not directory.is_dir():
        raise ModelFileError(f"{directory}: model directory not found")
    card = read_card(directory)
    card_path = directory / CARD
    if card.architecture != architecture:
        raise ModelFileError(f"{card_path}: a {card.architecture!r} model, not {architecture!r}")
    size = tuple(int(v) for v in card.input["size"])
    if input_size is not None and size != tuple(input_size):
        raise ModelFileError(f"{card_path}: made for {size[0]}x{size[1]} (HxW) input, not {input_size[0]}x{input_size[1]}")
    weights = directory / WEIGHTS
    if not weights.is_file():
        raise ModelFileError(f"{weights}: weights file not found")
    try:
        state = load_file(str(weights))
    except (SafetensorError, OSError, ValueError, RuntimeError) as exc:
        raise ModelFileError(f"{weights}: truncated or corrupt weights file ({str(exc).splitlines()[0]})") from None
    model = build(card)
    expected = model.state_dict()
    missing = sorted(set(expected) - set(state))
    unexpected = sorted(set(state) - set(expected))
    if missing or unexpected:
        detail = f"missing {missing[:3]}" if missing else f"unexpected {unexpected[:3]}"
        raise ModelFileError(f"{weights}: weights do not fit the {architecture} network of the card ({detail})")
    for name, tensor in state.items():
        if tensor.shape != expected[name].shape:
            raise ModelFileError(
                f"{weights}: {name} has shape {tuple(tensor.shape)}, the card's network needs {tuple(expected[name].shape)}"
            )
    model.load_state_dict(state)
    model.eval()
    return model, card


def shipped_model(name: str) -> Path:
    """A model directory installed with pvo_pseudosensors (share/pvo_pseudosensors/models/NAME; the source
    tree's models/NAME when the package is not installed)."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        return Path(get_package_share_directory("pvo_pseudosensors")) / "models" / name
    except (PackageNotFoundError, ValueError):
        return Path(__file__).resolve().parents[2] / "models" / name


def resolve_model(model: str, shipped: tuple[str, ...]) -> Path:
    """A ``model`` parameter as a directory: "" is the first of ``shipped``, a name in ``shipped`` that is not
    a local path is that shipped model, anything else a path."""
    if not model:
        return shipped_model(shipped[0])
    if model in shipped and not Path(model).exists():
        return shipped_model(model)
    return Path(model)
