"""A rig that starts standing still: with the zero-velocity update (the default) the static initializer
starts the filter as soon as it has seen a still window, as OpenVINS does with ZUPT; without it, it waits
for a jerk."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from runtime.config import DavioConfig
from runtime.msckf.init_static import StaticInitConfig, StaticInitializer


def test_unresolved_jerk_rule_waits_for_the_jerk() -> None:
    assert StaticInitConfig().wait_for_jerk is None
    assert StaticInitializer().wait_for_jerk is True
    assert StaticInitializer(StaticInitConfig(wait_for_jerk=False)).wait_for_jerk is False


@pytest.mark.slow
@pytest.mark.shared_data
def test_real_euroc_head_standing_start(euroc_head: Path) -> None:
    """V1_01_easy's first 4.7 s: the MAV stands on the ground. The default publishes from the static
    initializer once its 2 s window is full and holds the position within 3 cm; with the zero-velocity
    update off nothing is published (no jerk in these seconds)."""
    from drivers.euroc import EurocDriver
    from tools.run_session import run_pipeline

    t_first_imu = None
    published = {}
    for zupt in (True, False):
        cfg = DavioConfig()
        cfg = replace(cfg, msckf=replace(cfg.msckf, try_zupt=zupt))
        drv = EurocDriver(euroc_head)
        if t_first_imu is None:
            t_first_imu = next(ev.t_ns for ev in drv.events() if not hasattr(ev, "image"))
        res = run_pipeline(drv, None, cfg, show_progress=False)
        published[zupt] = (res.pipeline.published, res.pipeline.startup.report.published_by)
    pub, by = published[True]
    assert by == "native:static" and len(pub) > 20
    assert (pub[0].t_ns - t_first_imu) * 1e-9 < 2.2
    P = np.array([s.p_OI for s in pub])
    assert np.abs(P - P[0]).max() < 0.03
    assert len(published[False][0]) == 0
