"""The manifest of a training corpus rendered by `pvo sim corpus` (``OUT/manifest.yaml``)."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

from ..errors import DataFormatError

SPLITS = ("train", "validation", "test")


@dataclass(frozen=True)
class CorpusSequence:
    """One sequence: its folder, split, preset, the conditions drawn for it and the SHA-256 of its files."""

    name: str
    root: Path
    split: str
    preset: str
    conditions: tuple[str, ...]
    sha256: str
    colour: bool


@dataclass(frozen=True)
class CorpusManifest:
    """All sequences of a corpus; ``sha256``: one hash of the whole corpus (over the sequences' hashes)."""

    path: Path
    sequences: tuple[CorpusSequence, ...]
    sha256: str

    def split(self, name: str) -> list[CorpusSequence]:
        if name not in SPLITS:
            raise ValueError(f"unknown split {name!r}: choose one of {', '.join(SPLITS)}")
        return [s for s in self.sequences if s.split == name]


def read_corpus_manifest(corpus: str | Path) -> CorpusManifest:
    """The manifest of the corpus directory (or the manifest file itself); ``DataFormatError`` naming the file."""
    import yaml

    path = Path(corpus)
    if path.is_dir():
        path = path / "manifest.yaml"
    if not path.is_file():
        raise DataFormatError(path, "corpus manifest not found (render one with `pvo sim corpus`)")
    try:
        data = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))  # libyaml: 5x faster
    except (OSError, yaml.YAMLError) as exc:
        raise DataFormatError(path, f"unreadable corpus manifest: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("sequences"), list):
        raise DataFormatError(path, "not a corpus manifest: no 'sequences' list")
    sequences = []
    for number, entry in enumerate(data["sequences"], start=1):
        try:
            name, split, sha = str(entry["name"]), str(entry["split"]), str(entry["sha256"])
            config = entry["config"]
        except (KeyError, TypeError):
            raise DataFormatError(path, f"sequence entry {number} lacks name, split, sha256 or config") from None
        if split not in SPLITS:
            raise DataFormatError(path, f"sequence {name}: unknown split {split!r}")
        sequences.append(
            CorpusSequence(
                name,
                path.parent / name,
                split,
                str(entry.get("preset", config.get("preset", ""))),
                tuple(entry.get("conditions", ())),
                sha,
                bool(config.get("colour", False)),
            )
        )
    digest = hashlib.sha256("".join(f"{s.name}:{s.sha256}\n" for s in sequences).encode()).hexdigest()
    return CorpusManifest(path, tuple(sequences), digest)
