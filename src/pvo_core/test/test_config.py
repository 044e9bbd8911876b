"""Typed configs <-> dotted parameter names (pvo_core.config)."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest
from pvo_core.config import flatten, from_flat, parse_assignments


@dataclass(frozen=True)
class Inner:
    rate: float = 1.0
    count: int = 3
    names: tuple[str, ...] = ("a", "b")
    scales: tuple[float, ...] = (1.0, 2.0)


@dataclass(frozen=True)
class Middle:
    inner: Inner = field(default_factory=Inner)
    enabled: bool = True


@dataclass(frozen=True)
class Outer:
    middle: Middle = field(default_factory=Middle)
    low: float = 0.0
    high: float = 1.0

    def __post_init__(self) -> None:
        if self.low >= self.high:
            raise ValueError("invalid test configuration: low must be below high")


def test_flatten_names_every_leaf_with_dots() -> None:
    assert flatten(Outer()) == {
        "middle.inner.rate": 1.0,
        "middle.inner.count": 3,
        "middle.inner.names": ["a", "b"],
        "middle.inner.scales": [1.0, 2.0],
        "middle.enabled": True,
        "low": 0.0,
        "high": 1.0,
    }


def test_from_flat_round_trips_and_coerces() -> None:
    assert from_flat(flatten(Outer()), Outer()) == Outer()
    config = from_flat({"middle.inner.rate": "1e-5", "middle.inner.scales": [3, 4], "middle.inner.count": 7.0}, Outer())
    assert config.middle.inner.rate == 1e-5  # YAML 1.1 reads 1e-5 as text
    assert config.middle.inner.scales == (3.0, 4.0) and config.middle.inner.count == 7


def test_validation_sees_the_final_values_only() -> None:
    # moving both bounds at once is valid although either alone would not be
    assert from_flat({"low": 5.0, "high": 6.0}, Outer()).low == 5.0
    with pytest.raises(ValueError, match="low must be below high"):
        from_flat({"low": 2.0}, Outer())


@pytest.mark.parametrize(
    "values, message",
    [
        ({"middle.inner.rat": 1.0}, "unknown test parameter"),
        ({"middle.inner.rate": "fast"}, "middle.inner.rate must be a number"),
        ({"middle.inner.count": 2.5}, "middle.inner.count must be an integer"),
        ({"middle.enabled": "yes"}, "middle.enabled must be a boolean"),
        ({"middle.inner.scales": "1,2"}, "middle.inner.scales must be a list"),
    ],
)
def test_bad_values_name_the_parameter(values: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        from_flat(values, Outer(), what="test")


def test_assignments_read_their_values_as_yaml_and_name_a_bad_item() -> None:
    values = parse_assignments(["a.b=3", "c=[1, 2.5]", " d =''", "e=x=y", "f=true"])
    assert values == {"a.b": 3, "c": [1, 2.5], "d": "", "e": "x=y", "f": True}
    for bad in ("nothing", "=3"):
        with pytest.raises(ValueError, match=f"{bad!r} must be NAME=VALUE"):
            parse_assignments(["ok=1", bad])
