"""Shared fixtures: the path to ../shared/data (skip with a reason when absent)."""
from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


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
