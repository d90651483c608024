"""Parameter tables of the procedural CAD classes and their seeded sampling.

Each class declares an ordered ``ParamSpec`` (name -> distribution). Sampling always draws every
parameter in declaration order, even the overridden ones, so overriding one dimension leaves the
other draws of that seed unchanged (the same seed still means "the same style of object").
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

ParamValue = float | int | str


@dataclass(frozen=True)
class Uniform:
    """A continuous parameter drawn uniformly from ``[low, high]`` (metres unless named otherwise)."""

    low: float
    high: float

    def __post_init__(self) -> None:
        if not self.low <= self.high:
            raise ValueError(f"Uniform range needs low <= high, got [{self.low}, {self.high}]")

    def sample(self, rng: np.random.Generator) -> float:
        return float(rng.uniform(self.low, self.high))

    def check(self, name: str, value: object) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ValueError(f"parameter {name!r} must be a finite number, got {value!r}")
        if self.low > 0.0 and value <= 0.0:
            raise ValueError(f"parameter {name!r} must be positive, got {value!r}")
        return float(value)


@dataclass(frozen=True)
class IntRange:
    """An integer parameter drawn uniformly from ``low..high`` inclusive (counts: shelves, doors)."""

    low: int
    high: int

    def __post_init__(self) -> None:
        if not self.low <= self.high:
            raise ValueError(f"IntRange needs low <= high, got [{self.low}, {self.high}]")

    def sample(self, rng: np.random.Generator) -> int:
        return int(rng.integers(self.low, self.high + 1))

    def check(self, name: str, value: object) -> int:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise ValueError(f"parameter {name!r} must be a non-negative integer, got {value!r}")
        return int(value)


@dataclass(frozen=True)
class Choice:
    """A style parameter: one of ``options`` with optional relative ``weights``."""

    options: tuple[str, ...]
    weights: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        if not self.options:
            raise ValueError("Choice needs at least one option")
        if self.weights is not None and (
            len(self.weights) != len(self.options) or min(self.weights) < 0 or sum(self.weights) <= 0
        ):
            raise ValueError("Choice weights must be non-negative, one per option, not all zero")

    def sample(self, rng: np.random.Generator) -> str:
        p = None
        if self.weights is not None:
            w = np.asarray(self.weights, dtype=np.float64)
            p = w / w.sum()
        return str(self.options[int(rng.choice(len(self.options), p=p))])

    def check(self, name: str, value: object) -> str:
        if value not in self.options:
            raise ValueError(f"parameter {name!r} must be one of {self.options}, got {value!r}")
        return str(value)


Distribution = Uniform | IntRange | Choice
ParamSpec = Mapping[str, Distribution]


def sample_params(
    spec: ParamSpec, rng: np.random.Generator, overrides: Mapping[str, object] | None = None
) -> dict[str, ParamValue]:
    """Draw every parameter of ``spec`` and apply validated ``overrides`` (unknown keys raise)."""
    overrides = dict(overrides or {})
    unknown = sorted(set(overrides) - set(spec))
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}; valid: {list(spec)}")
    out: dict[str, ParamValue] = {}
    for name, dist in spec.items():
        drawn = dist.sample(rng)
        out[name] = dist.check(name, overrides[name]) if name in overrides else drawn
    return out
