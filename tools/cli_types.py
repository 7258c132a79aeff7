"""Argument types of the `davio` options: numbers checked as they are parsed, before any work.

Python's `float()` reads 'nan', 'inf', '1_0' (as 10) and digits of other scripts ('\\u0661' as 1); an
option given one ran on into a traceback deep inside a command or a benchmark, or made its result
meaningless with exit 0. Every float option reads through `number` (finite) or a ranged variant, and
integer counts through `count`; argparse then says "argument --X: ..." with the usage, exit 2.
"""
from __future__ import annotations

import argparse
import math
from collections.abc import Callable

_PLAIN = "a plain decimal number (no digit groups '_', no digits of other scripts)"


def _parse(text: str) -> float:
    s = text.strip()
    if "_" in s or not s.isascii():
        raise argparse.ArgumentTypeError(f"{text!r} is not {_PLAIN}")
    try:
        return float(s)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None


def number(text: str) -> float:
    """A finite number."""
    value = _parse(text)
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def number_or_inf(text: str) -> float:
    """A finite number, or 'inf' (where the option's help says inf switches a bound off)."""
    value = _parse(text)
    if math.isnan(value) or value == -math.inf:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number or 'inf'")
    return value


def number_in(low: float, high: float = math.inf, low_open: bool = False,
              unit: str = "") -> Callable[[str], float]:
    """A finite number in [low, high] ((low, high] with `low_open`); `unit` follows the numbers said."""
    def parse(text: str) -> float:
        value = number(text)
        if value < low or (low_open and value == low) or value > high:
            lo = f"> {low:g}" if low_open else f">= {low:g}"
            span = lo if high == math.inf else f"{lo} and <= {high:g}"
            raise argparse.ArgumentTypeError(f"must be {span}{unit}, got {text.strip()}")
        return value

    parse.__name__ = "number"
    return parse


positive = number_in(0.0, low_open=True)
"""A finite number > 0."""
nonnegative = number_in(0.0)
"""A finite number >= 0."""


def count(low: int = 1, high: int | None = None) -> Callable[[str], int]:
    """An integer in [low, high] written in ASCII digits (int() also reads '1_0' and other scripts)."""
    def parse(text: str) -> int:
        s = text.strip()
        digits = s[1:] if s[:1] in "+-" else s
        if not (digits.isascii() and digits.isdigit()):
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number")
        value = int(s)
        if value < low or (high is not None and value > high):
            span = f">= {low}" if high is None else f"from {low} to {high}"
            raise argparse.ArgumentTypeError(f"must be {span}, got {value}")
        return value

    parse.__name__ = "count"
    return parse
