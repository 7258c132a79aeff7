"""End to end through the pipeline and the scheduler: a start-up window refused for too short a span is
re-solved with the frames tracked after it (no second model call) and publishes a correct metric state
before the native initializer; with the re-solves off, the same recording starts later."""
from __future__ import annotations

import argparse
from dataclasses import replace

import pytest


@pytest.mark.slow
def test_a_refused_window_re_solved_over_a_longer_span_starts_before_the_native_initializer():
    from drivers.sim import SimConfig, SimRecording
    from models.emulated_da3 import EmulatedDA3
    from runtime.config import DavioConfig
    from tools.benchmarks.startup import _error_scales, _score, _WindowDriver
    from tools.run_session import run_pipeline

    rec = SimRecording.from_preset(SimConfig(preset="handheld", seconds=13.0, seed=0))
    gt, cam = rec.groundtruth(), rec.rig.camera
    t0 = int(max(rec.imu.t_ns[0], rec.frame_stamps_ns[0])) + 10_000_000_000
    t1 = t0 + 3_500_000_000
    errors = _error_scales(argparse.Namespace(pose_error_scale=0.05, depth_error_scale=1.0, da3="base"))
    rows = {}
    for extend_s in (1.0, 0.0):
        cfg = DavioConfig()
        cfg = replace(cfg, startup=replace(cfg.startup, extend_refused_s=extend_s))
        model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=1, **errors)
        res = run_pipeline(_WindowDriver(rec, t0, t1), model, cfg, model_latency_s=0.5, show_progress=False)
        rows[extend_s] = (_score(res.pipeline, gt, t0, 3.5, 0.5, 1.0), res.pipeline.startup.report)
    on, on_rep = rows[1.0]
    off, off_rep = rows[0.0]
    # the first window is refused as unobservable in both runs; only the re-solve accepts it
    assert on_rep.ff_rejections.get("scale_unobservable", 0) >= 1 and off_rep.ff_extensions == 0
    assert on_rep.ff_extension_accepted == 1 and on_rep.published_by == "feedforward"
    assert off_rep.published_by.startswith("native:")
    assert on["T_f"] < off["T_f"]
    # and the state it published is right: the first trajectory passes the paper's test, scale within 10 %
    assert on["success"] and not on["published_wrong"] and on["ate"] < 0.05
    assert on["scale_err"] < 0.1


def test_a_failing_re_solve_is_reported_as_such_and_gives_the_re_solves_up():
    """Through the pipeline's own job path: the re-solve job is issued when due, and its exception is
    counted apart from failed model calls and ends the re-solves (model windows are requested again)."""
    from types import SimpleNamespace

    import numpy as np

    from drivers.sim import SimConfig, SimRecording
    from models.emulated_da3 import EmulatedDA3
    from runtime.pipeline import VioPipeline

    rec = SimRecording.from_preset(SimConfig(preset="handheld", seconds=1.6, seed=0))
    cam = rec.rig.camera
    model = EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=0)
    pipe = VioPipeline(rec.rig, model)
    stamps = []
    for ev in rec.events():   # frames to 1.3 s, the IMU a little past them (it must cover the newest frame)
        if ev.t_ns - rec.frame_stamps_ns[0] > 1_320_000_000:
            break
        if hasattr(ev, "image"):
            if ev.t_ns - rec.frame_stamps_ns[0] > 1_300_000_000:
                continue
            pipe.on_frame(ev)
            stamps.append(int(ev.t_ns))
        else:
            pipe.on_imu(ev)
    assert not pipe.startup.published
    window = [t for t in stamps if (t - stamps[0]) % 200_000_000 == 0 and t - stamps[0] <= 800_000_000]
    assert len(window) == 5
    seed = SimpleNamespace(t_cam_ns=np.array(window), last_ns=window[-1])
    pipe.startup.on_feedforward(SimpleNamespace(reason="scale_unobservable", seed=seed))
    job = pipe.next_model_job()
    assert job is not None and job.model_call is False          # the re-solve, not a model window
    pipe.on_model_result(RuntimeError("boom"))
    assert pipe.stats.ff_exceptions == ["start-up re-solve: RuntimeError: boom"]
    assert pipe.startup.report.ff_extension_rejections == {"exception": 1}
    assert not pipe.startup.extension_pending()
    job = pipe.next_model_job()
    assert job is not None and getattr(job, "model_call", True)  # a model window again
