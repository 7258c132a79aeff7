"""Range checks of configuration values, named by their TOML key (`mapping.voxel_m`).

A config dataclass's `__post_init__` calls these, so an out-of-range value in a config.toml (or in code)
is a ConfigError naming the key when the configuration is built, before any work, instead of a failure
deep inside a run.
"""
from __future__ import annotations

import dataclasses
import math
import numbers
from collections.abc import Iterable

from runtime.errors import ConfigError


def _fail(section: str, name: str, value: object, must: str) -> None:
    raise ConfigError(f"{section}.{name} must be {must}, got {value!r}")


def _number(obj: object, section: str, name: str) -> float:
    value = getattr(obj, name)
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or math.isnan(value):
        _fail(section, name, value, "a number")
    return float(value)


def positive(obj: object, section: str, *names: str, finite: bool = True) -> None:
    """Each named field is a number > 0 (and finite unless `finite` is False)."""
    for name in names:
        v = _number(obj, section, name)
        if not v > 0 or (finite and math.isinf(v)):
            _fail(section, name, getattr(obj, name), "a finite number > 0" if finite else "> 0")


def non_negative(obj: object, section: str, *names: str) -> None:
    """Each named field is a finite number >= 0."""
    for name in names:
        v = _number(obj, section, name)
        if not (v >= 0 and math.isfinite(v)):
            _fail(section, name, getattr(obj, name), "a finite number >= 0")


def in_range(obj: object, section: str, name: str, lo: float, hi: float, *, lo_open: bool = False,
             hi_open: bool = False) -> None:
    """The named field lies in [lo, hi] (an open end with `lo_open` / `hi_open`)."""
    v = _number(obj, section, name)
    ok = (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
    if not ok:
        _fail(section, name, getattr(obj, name),
              f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}")


def at_least(obj: object, section: str, minimum: int, *names: str) -> None:
    """Each named field is an integer >= minimum."""
    for name in names:
        value = getattr(obj, name)
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < minimum:
            _fail(section, name, value, f"an integer >= {minimum}")


def each_at_least(values: Iterable[int], section: str, name: str, minimum: int) -> None:
    """Every item of a list field is an integer >= minimum."""
    values = list(values)
    if any(isinstance(v, bool) or not isinstance(v, numbers.Integral) or v < minimum for v in values):
        _fail(section, name, values, f"a list of integers >= {minimum}")


def finite_fields(obj: object, section: str, allow_inf: Iterable[str] = ()) -> None:
    """Every field of dataclass `obj` that holds a float is finite: a NaN passes or fails every comparison
    further down, so it surfaced as a failure deep inside a run."""
    allowed = set(allow_inf)
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if isinstance(v, float) and not math.isfinite(v) and not (f.name in allowed and math.isinf(v)):
            _fail(section, f.name, v, "a finite number")
