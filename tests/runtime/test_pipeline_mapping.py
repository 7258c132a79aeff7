"""Mapping inside a run: keyframe windows come from the published poses, the mapper runs in the model
worker, and tracking is unaffected by it (identical poses with mapping on and off, even when the
model is too slow and the queue drops windows)."""
from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest

from runtime.config import DavioConfig
from runtime.mapping.mapper import Mapper
from runtime.pipeline import VioPipeline
from runtime.scheduler import FastClock, PacedClock, Scheduler

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recording():
    from drivers.sim import SimConfig, SimRecording

    rec = SimRecording.from_preset(SimConfig(preset="euroc", seconds=8.0, seed=1))
    return rec, list(rec.events())


def _config(mapping: bool, pending: int = 2) -> DavioConfig:
    cfg = DavioConfig()
    # the feed-forward start-up off: the model serves only the mapper, so tracking is deterministic
    return replace(cfg, startup=replace(cfg.startup, feedforward=False),
                   mapping=replace(cfg.mapping, enabled=mapping, max_pending_windows=pending))


def _model(rec):
    from models.emulated_da3 import EmulatedDA3

    cam = rec.rig.camera
    return EmulatedDA3(rec.gt_source, cam.K, cam.width, cam.height, preset="base", seed=1)


def _no_matcher(model, camera, cfg, sink=None, **kw):
    return Mapper(model, camera, cfg, matcher=False, sink=sink, **kw)


def _poses(pipe) -> np.ndarray:
    return np.array([np.r_[p.t_ns, p.p_OI, p.R_OI.ravel()] for p in pipe.published])


def test_windows_follow_published_poses_and_the_map_lies_on_the_scene(recording):
    from tools.evaluation import align, associate
    from tools.evaluation.surface import nearest_distances
    from tools.run_io import published_trajectory

    rec, events = recording
    commits = []
    pipe = VioPipeline(rec.rig, _model(rec), _config(True), map_sink=lambda c, s: commits.append(c),
                       mapper_factory=_no_matcher)
    Scheduler(FastClock(0.5)).run(iter(events), pipe)
    pipe.finish_mapping()
    st = pipe.report()["mapping"]
    assert st["windows_offered"] >= 3 and st["windows_accepted"] == st["windows_offered"] == len(commits)
    # each submap's frame S_j is the centre keyframe's camera at its published pose
    by_t = {p.t_cam_ns: p for p in pipe.published}
    for c in commits:
        sm = c.submap
        p = by_t[int(sm.frame_t_ns[sm.centre])]
        T_OI = np.eye(4)
        T_OI[:3, :3], T_OI[:3, 3] = p.R_OI, p.p_OI
        assert np.allclose(sm.T_OS, T_OI @ rec.rig.T_IC)
        assert np.all(np.diff(sm.frame_t_ns) >= 0.49e9)             # 0.5 s keyframes
    assert all(len(set(a.submap.frame_t_ns) & set(b.submap.frame_t_ns)) == 2
               for a, b in zip(commits, commits[1:], strict=False))
    assert all(c.link is not None and c.link.method == "shared" for c in commits[1:])
    # live poses: once a commit's correction is complete, a published pose is T_MO T_OI with T_MO from
    # that commit's newest node (eq. correction); versions never decrease
    versions = [v for _, v, _ in pipe.causal]
    assert versions == sorted(versions) and versions[-1] >= 1
    last = max((c for c in commits if c.version == versions[-1]), key=lambda c: c.version)
    T_MO = last.submap.T_MS @ np.linalg.inv(last.submap.T_OS)
    (T_MI, _, frac), p = pipe.causal[-1], pipe.published[-1]
    if frac == 1.0:
        assert np.allclose(T_MI[:3, 3], T_MO[:3, :3] @ p.p_OI + T_MO[:3, 3], atol=1e-9)
    # the fused map, moved into the simulator's world by the trajectory's SE(3) alignment, lies on the scene
    est, ref = associate(published_trajectory(pipe.published), rec.groundtruth())
    _, al = align(est, ref, "se3")
    pts, _, _ = pipe.mapper.fused_points()
    pts_W = pts @ al.R.T + al.t
    scene, _ = rec.scene.surface_points(0.02)
    d = nearest_distances(pts_W, scene)
    assert np.mean(d < 0.10) > 0.6 and np.median(d) < 0.08


class _SlowModel:
    """The emulated DA3 with an extra 2.5 s of wall time per call (a model slower than the windows)."""

    def __init__(self, model) -> None:
        self.inner, self.K_rect = model, model.K_rect

    def predict(self, frames, K=None, T_CW=None):
        time.sleep(2.5)
        return self.inner.predict(frames, K, T_CW)


def test_tracking_is_identical_with_mapping_on_and_drops_are_counted(recording):
    rec, events = recording
    off = VioPipeline(rec.rig, None, _config(False))
    Scheduler(FastClock(0.5)).run(iter(events), off)
    on = VioPipeline(rec.rig, _SlowModel(_model(rec)), _config(True, pending=1), mapper_factory=_no_matcher)
    sched = Scheduler(PacedClock(4.0))                                # 8 s of sensor time in 2 s
    rep = sched.run(iter(events), on)
    # without a map no correction ever happens: final poses equal the causal ones equal the odometry
    assert all(np.array_equal(a, c[0]) for a, c in zip(off.final_poses(), off.causal, strict=True))
    assert all(np.allclose(c[0][:3, 3], p.p_OI) for c, p in zip(off.causal, off.published, strict=True))
    st = on.report()["mapping"]
    # windows come every 1.5 s of sensor time = 0.375 s of wall time, each takes > 2.5 s: the queue
    # (one pending window) drops
    assert st["windows_dropped_queue"] >= 1
    assert st["windows_dropped_queue"] == len(st["windows_dropped_ids"])
    assert st["windows_offered"] == st["windows_processed"] + st["windows_dropped_queue"] + len(on.map_queue)
    assert rep.frames == len(rec)
    # tracking never waited for the mapper: the same states as without mapping
    assert np.array_equal(_poses(on), _poses(off))


def test_mapping_exceptions_are_all_counted_and_the_first_messages_kept(recording):
    """A mapping job that raises at every window (a GPU out of memory, say) for hours must not grow the
    report without bound: every failure is counted, the first MAX_ERROR_MESSAGES messages are kept."""
    from runtime.mapping.mapper import MAX_ERROR_MESSAGES

    rec, _ = recording
    pipe = VioPipeline(rec.rig, _model(rec), _config(True), mapper_factory=_no_matcher)
    pipe._job_kind = "mapping"
    n = MAX_ERROR_MESSAGES + 25
    for k in range(n):
        pipe.on_model_result(MemoryError(f"window {k}"))
    st = pipe.map_stats
    assert st.windows_rejected["exception"] == n
    assert st.model_errors == [f"MemoryError: window {k}" for k in range(MAX_ERROR_MESSAGES)]


def test_a_window_failing_after_the_data_ended_is_counted_not_raised() -> None:
    """Session.close() and `davio run` map the queued windows in the calling thread: a model that raised
    (or returned other shapes) escaped close() as a raw exception, the session half-closed."""
    from types import SimpleNamespace

    from calib.io import euroc_rig
    from runtime.config import DavioConfig
    from runtime.mapping.mapper import MappingStats
    from runtime.pipeline import VioPipeline

    pipe = VioPipeline(euroc_rig(), None, DavioConfig())
    pipe.map_stats = MappingStats()               # what a run with a model and the mapping on holds
    queued = ["w2", "w1"]
    pipe.map_queue = SimpleNamespace(pop=lambda: queued.pop() if queued else None)

    def job(window):
        def run():
            raise RuntimeError(f"CUDA error on {window}")
        return run

    pipe._mapping_job = job
    assert pipe.finish_mapping() == 2
    assert pipe.map_stats.windows_rejected == {"exception": 2}
    assert pipe.map_stats.model_errors == ["RuntimeError: CUDA error on w1", "RuntimeError: CUDA error on w2"]


class _BrokenModel:
    """A graph that fails every call at run time (the contract's shapes, non-finite depth)."""

    def __init__(self, model) -> None:
        self.K_rect = model.K_rect

    def predict(self, frames, K=None, T_CW=None):
        from runtime.errors import ModelError

        raise ModelError("da3.onnx: output depth has 25065 non-finite values out of 811440")


def test_a_model_failing_every_call_is_said_as_it_happens_and_counted_whole(recording):
    """The failures lived only in report counters (a Session user heard nothing; the run printed the count
    of the messages kept, at most 10): the first is now an event at once, the rest paced, and every count
    is whole."""
    from tools.run_summary import recovery_lines

    rec, events = recording
    said: list = []
    pipe = VioPipeline(rec.rig, _BrokenModel(_model(rec)), DavioConfig(), mapper_factory=_no_matcher,
                       on_event=said.append)
    Scheduler(FastClock(0.5)).run(iter(events), pipe)
    pipe.finish_mapping()
    rep = pipe.report()
    ff, mapped = rep["tracking"]["ff_errors"], rep["mapping"]["windows_rejected"].get("model_error", 0)
    assert ff >= 1 and mapped >= 1
    errors = [e for e in said if e.kind == "model_error"]
    assert errors[0].detail["failed"] == 1 and "non-finite values" in errors[0].detail["first"]
    # the first at once, the rest (within the ten seconds of pacing) when the data ended
    assert [e.detail["total"] for e in errors] == [1, ff + mapped]
    assert errors[1].detail["failed"] == ff + mapped - 1 and "since the last such event" in errors[1].message
    lines = recovery_lines({"pipeline": rep})
    first = f"feed-forward model calls failed: {ff} (first: ModelError: da3.onnx: output depth"
    assert any(line.startswith(first) for line in lines)
    assert any(line.startswith(f"mapping model calls failed: {mapped} (first: ") for line in lines)


def test_start_up_failures_are_all_counted_and_the_first_messages_kept(recording):
    """ff_exceptions grew by one message per failed start-up job, without bound."""
    from runtime.mapping.mapper import MAX_ERROR_MESSAGES

    rec, _ = recording
    pipe = VioPipeline(rec.rig, _model(rec), _config(True), mapper_factory=_no_matcher)
    pipe._job_kind = "feedforward"
    for k in range(MAX_ERROR_MESSAGES + 25):
        pipe.on_model_result(MemoryError(f"window {k}"))
    assert pipe.stats.ff_errors == MAX_ERROR_MESSAGES + 25
    assert pipe.stats.ff_exceptions == [f"MemoryError: window {k}" for k in range(MAX_ERROR_MESSAGES)]
    assert pipe.events.counts["model_error"] == 1          # the first said at once, the rest paced
