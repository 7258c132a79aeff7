"""Shared fixtures: the path to ../shared/data (skip with a reason when absent)."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def pytest_configure(config: pytest.Config) -> None:
    """The simulator's parallel kernels run on numba's workqueue layer, as under the `davio` command
    (OpenMP's spinning idle threads would take the CPU the tracked pipeline needs; results are the same:
    every parallel kernel is per pixel). A layer chosen in the environment stands."""
    os.environ.setdefault("NUMBA_THREADING_LAYER", "workqueue")


def shared_path(*parts: str) -> Path:
    """Path under ../shared/data; skips the calling test with a clear reason if it is missing."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"needs {p} (the project's ../shared/data is absent on this checkout)")
    return p


@pytest.fixture
def euroc_head() -> Path:
    """The real EuRoC V1_01_easy head folder (95 frames, full IMU)."""
    return shared_path("euroc", "V1_01_easy_head")


@pytest.fixture(scope="session")
def small_sim_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 6 s simulated EuRoC folder (preset 'euroc': 2 s at rest, then take-off; no depth maps), written
    once per session for the tests that replay files: fault injection, run folders."""
    from drivers.sim import SimConfig, SimRecording
    from drivers.sim.writer import write_euroc

    out = tmp_path_factory.mktemp("sim") / "euroc6"
    write_euroc(SimRecording.from_preset(SimConfig(preset="euroc", seconds=6.0, seed=0)), out, depth=False)
    return out


def cli_exit(argv: list[str]) -> int:
    """The exit code of `davio ARGV` run in-process: returned, or raised by argparse (2: a value the
    command line refused)."""
    from tools.cli import main

    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code)
