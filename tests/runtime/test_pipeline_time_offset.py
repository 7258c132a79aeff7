"""VioPipeline's part in adopting a camera-IMU time offset the start-up found (runtime/ffinit/
time_offset_check.py, runtime/startup.py): what takes the adopted offset up; nothing without correction."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from calib.io import euroc_rig
from runtime.config import DavioConfig
from runtime.ffinit.window import Rejection
from runtime.pipeline import VioPipeline


def _pipeline(correct: bool = True) -> VioPipeline:
    cfg = DavioConfig()
    cfg = replace(cfg, mapping=replace(cfg.mapping, enabled=False), use_dynamic_init=True,
                  ffinit=replace(cfg.ffinit, correct_time_offset=correct))
    model = SimpleNamespace(K_rect=np.eye(3))     # never called here: only the start-up's bookkeeping runs
    return VioPipeline(euroc_rig(), model, cfg)


def test_an_adopted_offset_reaches_the_windows_the_native_filter_and_every_filter_made_later():
    pipe = _pipeline()
    rig_offset = pipe.time_offset_s
    pipe.on_model_result(Rejection("time_offset", "fits +40 ms", time_offset_s=rig_offset + 0.04))
    adopted = rig_offset + 0.04
    assert pipe.time_offset_s == pytest.approx(adopted)
    assert pipe.ffinit.time_offset_s == pytest.approx(adopted)
    assert pipe.startup.offset_ns == int(round(adopted * 1e9))
    native = pipe.startup.native
    assert native.time_offset_s == pytest.approx(adopted)
    later = pipe.startup.make_filter(True)        # a candidate, or the native filter after a reset
    assert later.time_offset_s == pytest.approx(adopted)
    offsets = {type(i).__name__: i.time_offset_ns for i in later.initializers if hasattr(i, "time_offset_ns")}
    assert set(offsets) == {"TurningInitializer", "DynamicInitializer"}
    assert set(offsets.values()) == {int(round(adopted * 1e9))}


def test_without_correction_a_finding_moves_nothing():
    pipe = _pipeline(correct=False)
    rig_offset = pipe.time_offset_s
    pipe.on_model_result(Rejection("time_offset", "fits +40 ms", time_offset_s=rig_offset + 0.04))
    assert pipe.startup.report.time_offset_findings == 1 and pipe.startup.report.time_offset_adopted_s is None
    assert pipe.time_offset_s == rig_offset and pipe.ffinit.time_offset_s == rig_offset
    assert pipe.startup.native.time_offset_s == pytest.approx(rig_offset)
