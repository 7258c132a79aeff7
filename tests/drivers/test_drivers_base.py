"""The Driver contract and IntakeReport counters, exercised through a tiny in-memory driver."""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from drivers import Driver, Frame, ImuSample, IntakeReport
from drivers.base import check_policy
from runtime.errors import ConfigError


class ListDriver(Driver):
    def __init__(self, events: list) -> None:
        self._events = events
        self.intake = IntakeReport("list", "memory")
        self.closed = False

    @property
    def rig(self) -> None:
        return None

    def events(self) -> Iterator[ImuSample | Frame]:
        yield from self._events

    def report(self) -> dict:
        return self.intake.as_dict()

    def close(self) -> None:
        super().close()
        self.closed = True


def test_context_manager_closes_and_defaults() -> None:
    ev = [ImuSample(1, np.zeros(3), np.zeros(3)), Frame(2, np.zeros((2, 2), np.uint8))]
    with ListDriver(ev) as drv:
        assert list(drv.events()) == ev
        assert drv.groundtruth() is None and drv.rig is None
    assert drv.closed


def test_intake_report_totals_summary_and_accounting() -> None:
    rep = IntakeReport("list", "memory", "drop")
    imu = rep.stream("imu0")
    imu.lines, imu.parsed, imu.dropped_duplicate, imu.dropped_nonfinite = 10, 7, 2, 1
    cam = rep.stream("cam0")
    cam.lines, cam.parsed, cam.truncated_lines, cam.missing_images = 5, 4, 1, 2
    rep.note("unequal camera rates: cam0 20 Hz, cam1 10 Hz")
    rep.note("unequal camera rates: cam0 20 Hz, cam1 10 Hz")
    assert imu.rows_accounted() and cam.rows_accounted() and imu.dropped == 3
    d = rep.as_dict()
    assert d["totals"]["dropped_duplicate"] == 2 and d["totals"]["missing_images"] == 2
    assert d["streams"]["imu0"]["parsed"] == 7
    assert d["notes"] == ["unequal camera rates: cam0 20 Hz, cam1 10 Hz"]
    text = rep.summary()
    assert "imu0: 7/10 rows kept" in text and "dropped duplicate 2" in text and "missing images 2" in text
    assert text.count("unequal camera rates") == 1
    imu.parsed = 8
    assert not imu.rows_accounted()


def test_policy_names() -> None:
    assert check_policy("drop") == "drop" and check_policy("strict") == "strict"
    with pytest.raises(ConfigError, match="unknown intake policy"):
        check_policy("ignore")
