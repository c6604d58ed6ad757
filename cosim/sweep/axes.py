"""The values of one sweep axis: a grid (``values``) or Monte Carlo draws (``seeds``, ``distribution``).

* ``values = [...]``: a grid axis; its values are TOML values put into the scenario as
  written (numbers, unit strings such as ``"0.1 mm"``, lists such as ``["standard"]``).
* ``seeds = N``: N integer seeds ``first_seed, first_seed + 1, ...`` (default first 0),
  for a scenario key that seeds a random generator (noise, true robot, ...).
* ``distribution = {kind = "normal", mean = ..., std = ...}`` with ``samples = N`` and
  ``seed``: N random draws. Kinds: ``normal`` (mean, std), ``uniform`` (low, high),
  ``lognormal`` (median, sigma = standard deviation of the natural log). Parameters are
  numbers or unit strings of one unit (``mean = "0.1 mm", std = "0.02 mm"``); draws are
  written in that unit (``"0.10731 mm"``) so the scenario's own validation converts them.
  The generator is numpy's default (PCG64) seeded with ``[seed, crc32(key)]``: the same
  sweep file always gives the same draws, and two axes with one seed are independent.
"""
from __future__ import annotations

import re
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from cosim.scenario.schema import Where
from cosim.scenario.keypath import KeyPath

#: The kinds of ``distribution`` and their parameters (all required).
DISTRIBUTIONS: dict[str, tuple[str, ...]] = {
    "normal": ("mean", "std"),
    "uniform": ("low", "high"),
    "lognormal": ("median", "sigma"),
}
#: Parameters without a unit (a unit string there is an error).
DIMENSIONLESS = {"sigma"}

GRID, SEEDS, DISTRIBUTION = "grid", "seeds", "distribution"

_QUANTITY = re.compile(r"^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S.*?)?\s*$")


@dataclass(frozen=True)
class Axis:
    """One axis of a sweep.

    Attributes:
        key: the key path as canonical text (``fmus[0].parameters."q0[2]"``); the table column.
        path: the parsed key path.
        kind: ``"grid"``, ``"seeds"`` or ``"distribution"`` (the last two are Monte Carlo axes).
        values: the values put into the scenario, in order (raw TOML values).
        where: the axis in the sweep file (``axes[1]``), for errors.
        source: the sweep-file key the values come from (``values``, ``seeds`` or ``distribution``).
    """

    key: str
    path: KeyPath
    kind: str
    values: tuple[Any, ...]
    where: Where
    source: str

    @property
    def monte_carlo(self) -> bool:
        """True for random draws (zipped with the other Monte Carlo axes), False for a grid."""
        return self.kind != GRID

    def value_where(self, index: int) -> Where:
        """Position in the sweep file of value ``index`` (``axes[1].values[2]`` or ``axes[1].seeds``)."""
        return (self.where / "values")[index] if self.kind == GRID else self.where / self.source


def _split_quantity(value: Any, where: Where) -> tuple[float, str | None]:
    """``2.5`` -> (2.5, None); ``"0.1 mm"`` -> (0.1, "mm")."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value), None
    if isinstance(value, str):
        m = _QUANTITY.match(value)
        if m:
            return float(m.group(1)), m.group(2)
    raise where.error("a number or a string '<number> <unit>' such as '0.1 mm'", value)


def distribution_draws(spec: dict[str, Any], samples: int, seed: int, key: str, where: Where) -> list[Any]:
    """``samples`` draws of the distribution table ``spec`` (already checked for its keys).

    Returns floats, or strings ``"<float> <unit>"`` when the parameters carry a unit.
    """
    kind = spec["kind"]
    numbers: dict[str, float] = {}
    units: dict[str, str | None] = {}
    for name in DISTRIBUTIONS[kind]:
        numbers[name], units[name] = _split_quantity(spec[name], where / name)
        if name in DIMENSIONLESS and units[name] is not None:
            raise (where / name).error("a plain number (the standard deviation of the natural log)", spec[name])
    dimensional = {n: u for n, u in units.items() if n not in DIMENSIONLESS}
    unit_set = set(dimensional.values())
    if len(unit_set) > 1:
        raise where.error(f"the parameters {', '.join(dimensional)} in one unit (all numbers, or all strings "
                          f"with the same unit)", {n: spec[n] for n in dimensional}, problem="mixed units")
    unit = unit_set.pop() if unit_set else None
    rng = np.random.default_rng([seed, zlib.crc32(key.encode("utf-8"))])
    if kind == "normal":
        if numbers["std"] < 0:
            raise (where / "std").error("a standard deviation >= 0", spec["std"])
        draws = rng.normal(numbers["mean"], numbers["std"], samples)
    elif kind == "uniform":
        if not numbers["high"] > numbers["low"]:
            raise (where / "high").error(f"a number > low = {spec['low']!r}", spec["high"])
        draws = rng.uniform(numbers["low"], numbers["high"], samples)
    else:
        if numbers["median"] <= 0 or numbers["sigma"] < 0:
            bad = "median" if numbers["median"] <= 0 else "sigma"
            raise (where / bad).error("a median > 0 and a sigma >= 0", spec[bad])
        draws = numbers["median"] * np.exp(rng.normal(0.0, numbers["sigma"], samples))
    return [float(x) if unit is None else f"{float(x)!r} {unit}" for x in draws]


def seed_values(count: int, first: int) -> list[int]:
    """``count`` consecutive integer seeds from ``first``."""
    return list(range(first, first + count))


__all__ = ["Axis", "DISTRIBUTION", "DISTRIBUTIONS", "GRID", "SEEDS", "distribution_draws", "seed_values"]
