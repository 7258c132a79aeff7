"""tools.cli_types: option values checked as they are parsed, and every float option of every command
reading through them (a NaN, an inf, '1_0' or a count out of range was a traceback or an endless run)."""
from __future__ import annotations

import argparse
import math

import pytest

from tools import cli_types
from tools.cli import build_parser, main
from tools.cli_types import count, number, number_in, number_or_inf


@pytest.mark.parametrize("text", ["nan", "inf", "-inf", "1_0", "\u0661", "\uff15", "x", ""])
def test_number_refuses_what_float_reads_but_no_one_means(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError):
        number(text)


def test_number_reads_plain_decimals() -> None:
    assert number(" 5 ") == 5.0 and number("-1.5e-3") == -1.5e-3 and number("+2") == 2.0
    assert number_or_inf("inf") == math.inf and number_or_inf("0.5") == 0.5
    for bad in ("nan", "-inf"):
        with pytest.raises(argparse.ArgumentTypeError):
            number_or_inf(bad)


def test_ranges_and_counts() -> None:
    every = number_in(0.01, 3600, unit=" s")
    assert every("0.01") == 0.01 and every("3600") == 3600.0
    for bad in ("0", "1e-10", "3601", "nan"):
        with pytest.raises(argparse.ArgumentTypeError):
            every(bad)
    with pytest.raises(argparse.ArgumentTypeError, match="must be > 0"):
        number_in(0, low_open=True)("0")
    assert count(0)("+3") == 3 and count(0)("0") == 0 and count(1, 5)("5") == 5
    for bad, parse in (("-1", count(0)), ("1_0", count(0)), ("1.5", count(0)), ("6", count(1, 5)),
                       ("\u0661", count(0))):
        with pytest.raises(argparse.ArgumentTypeError):
            parse(bad)


def _options(parser: argparse.ArgumentParser, path: str = "davio"):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _options(sub, f"{path} {name}")
        elif action.option_strings:
            yield path, action


def test_no_option_of_any_command_reads_float_unchecked() -> None:
    typed = [(path, a) for path, a in _options(build_parser()) if a.type is not None]
    assert len(typed) > 100
    raw = [f"{path} {a.option_strings[0]}" for path, a in typed if a.type is float]
    assert raw == []
    ours = [(p, a) for p, a in typed if getattr(a.type, "__module__", None) == cli_types.__name__
            and a.type.__name__ in ("number", "number_or_inf")]
    assert len(ours) > 60
    for _, action in ours:          # each refuses NaN before any work
        with pytest.raises(argparse.ArgumentTypeError):
            action.type("nan")


@pytest.mark.parametrize("argv, said", [
    (["startup", "--preset", "euroc", "--every", "0"], "--every: must be >= 0.01"),        # looped forever
    (["imu-drift", "--step", "0"], "--step: must be >= 0.001"),                            # looped forever
    (["matcher", "--source", "sim", "--gap", "99999999"], "--gap: must be from 1 to 100"),  # hung
    (["renderer", "--frames", "1000000"], "--frames: must be from 1 to 10000"),              # 8 GB in 60 s
    (["map-export", "--voxel", "1e-300"], "--voxel: must be >= 0.0001"),       # one voxel, exit 0
    (["preintegration", "--rate", "0"], "--rate: must be >= 1"),              # ZeroDivisionError
    (["mapping-cost", "--speed", "nan"], "--speed: 'nan' is not a finite number"),     # paced nothing
    (["startup", "--preset", "euroc", "--model-latency", "1e308"], "--model-latency: must be >= 0"),
])
def test_bench_values_are_refused_before_any_work(capsys, argv: list[str], said: str) -> None:
    with pytest.raises(SystemExit) as info:
        main(["bench", *argv])
    assert info.value.code == 2 and said in capsys.readouterr().err


def test_simulated_recordings_refuse_lengths_and_starts_out_of_range() -> None:
    from drivers.sim.recording import SimConfig
    from runtime.errors import ConfigError, DavioError
    from runtime.scheduler import PacedClock

    for kw in ({"seconds": 1e7}, {"seconds": math.inf}, {"seconds": 0.0}, {"start_s": math.nan},
               {"start_s": -1.0}, {"start_s": 1e8}):
        with pytest.raises(ConfigError):
            SimConfig(**kw)
    assert SimConfig(seconds=None, start_s=5.0).start_s == 5.0
    for speed in (math.nan, math.inf, 0.0):
        with pytest.raises(DavioError, match="speed must be a finite number > 0"):
            PacedClock(speed)
