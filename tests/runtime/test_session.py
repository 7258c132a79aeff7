"""Session: pushed samples give the same poses as a replay of the same events; a tracker that falls
behind drops the oldest images (counted), never an IMU sample; bad pushes are clear errors."""
from __future__ import annotations

import time

import numpy as np
import pytest

from runtime.config import DavioConfig
from runtime.errors import ConfigError, DataError, DavioError
from runtime.events import Frame
from runtime.session import Pose, Session


@pytest.fixture(scope="module")
def recording():
    from drivers.sim import SimConfig, SimRecording

    rec = SimRecording.from_preset(SimConfig(preset="euroc", seconds=4.0, seed=2))
    return rec, list(rec.events())


def _push(session: Session, events) -> None:
    for ev in events:
        if isinstance(ev, Frame):
            session.add_image(ev.t_ns, ev.image)
        else:
            session.add_imu(ev.t_ns, ev.gyro, ev.accel)


@pytest.mark.slow
def test_pushed_samples_publish_what_a_replay_publishes(recording) -> None:
    rec, events = recording
    replayed = Session(rec.rig, config=DavioConfig()).replay(iter(events)).pipeline.published
    got: list[Pose] = []
    with Session(rec.rig, on_pose=got.append, max_pending_frames=10_000) as s:
        _push(s, events)
    assert s.result.status == "complete" and s.result.scheduler.frames_dropped == 0
    assert len(got) == len(replayed) > 20
    for pose, ref in zip(got, replayed, strict=True):
        assert pose.t_ns == ref.t_ns
        np.testing.assert_array_equal(pose.T_OI, ref.T_OI)
        np.testing.assert_array_equal(pose.T_MI, ref.T_OI)       # no map: the map frame is the odometry frame
    # the covariance is the filter's [rotation, position] block: symmetric, positive, metric-sized
    cov = got[-1].covariance
    assert cov.shape == (6, 6) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)
    assert 1e-6 < np.sqrt(np.trace(cov[3:, 3:])) < 1.0
    assert list(s.poses()) == got                                 # the same poses through the iterator


@pytest.mark.slow
def test_an_error_in_the_session_thread_reaches_the_caller_at_close(recording) -> None:
    """A callback that raises after the last push stops the session's thread; leaving the `with` block
    raises it (as add_* does when it comes earlier) and the result says failed."""
    rec, events = recording
    calls = []

    def on_pose(pose: Pose) -> None:
        calls.append(pose)
        if len(calls) == 5:
            raise KeyError("t_ns")

    with pytest.raises(DavioError, match="the session stopped: 't_ns'") as info:
        with Session(rec.rig, on_pose=on_pose, max_pending_frames=10_000) as s:
            for ev in events:     # straight into the inbox: every push is in before the thread fails
                s._inbox.put(ev)
    assert isinstance(info.value.__cause__, KeyError)
    assert s.result.status == "failed" and "KeyError" in s.result.reason and len(calls) == 5
    with pytest.raises(ValueError, match="the caller's own"):       # an exception already leaving is kept
        with Session(rec.rig, on_pose=on_pose) as s2:
            _push(s2, events[:100])
            raise ValueError("the caller's own")


@pytest.mark.slow
def test_a_tracker_that_falls_behind_drops_images_not_imu_samples(recording) -> None:
    rec, events = recording
    said: list = []
    with Session(rec.rig, max_pending_frames=1, on_event=said.append) as s:
        _push(s, events)                  # pushed far faster than real time
    rep = s.result.scheduler
    n_frames = sum(isinstance(e, Frame) for e in events)
    assert rep.frames_dropped > 0 and rep.frames + rep.frames_dropped == n_frames
    # the supervisor hears of it as it happens: at once, then at most once every ten data seconds
    behind = [e for e in said if e.kind == "falling_behind"]
    assert behind and behind[0].detail["total"] == behind[0].detail["dropped"] >= 1
    assert sum(e.detail["dropped"] for e in behind) == behind[-1].detail["total"] == rep.frames_dropped
    # (the last may be the end's, which says what was left)
    assert all(b.t_s - a.t_s >= 10.0 for a, b in zip(behind[:-1], behind[1:-1], strict=False))
    assert rep.imu_samples == len(events) - n_frames


def test_bad_pushes_are_clear_errors(recording) -> None:
    rec, _ = recording
    s = Session(rec.rig)
    with pytest.raises(DataError, match="grey \\(H, W\\) uint8"):
        s.add_image(0, np.zeros((480, 752, 3), np.uint8))
    with pytest.raises(DataError, match="differs from the calibration's 752x480"):
        s.add_image(0, np.zeros((240, 376), np.uint8))
    with pytest.raises(DataError, match="integer number of nanoseconds"):
        s.add_imu(1.5, [0, 0, 0], [0, 0, 9.81])
    with pytest.raises(DataError, match="integer number of nanoseconds"):
        s.add_imu(float("nan"), [0, 0, 0], [0, 0, 9.81])
    with pytest.raises(DataError, match="add_imu at 7: gyro needs 3 values"):
        s.add_imu(7, np.zeros(2), [0, 0, 9.81])
    with pytest.raises(DataError, match="add_imu at 7: accel is not numeric"):
        s.add_imu(7, [0, 0, 0], ["x", 0, 9.81])
    for stamp in (2**70, np.uint64(2**63 + 5), None, "abc", np.array([1, 2]), -3):
        with pytest.raises(DataError, match="nanoseconds"):
            s.add_imu(stamp, [0, 0, 0], [0, 0, 9.81])
    assert s.close().status == "complete"
    assert s.close().status == "complete"                       # a second close: the same result
    with pytest.raises(DavioError, match="the session is closed"):
        s.add_imu(10, [0, 0, 0], [0, 0, 9.81])
    with pytest.raises(ConfigError, match="camera intrinsics"):
        Session(rec.rig.replace(camera=None))


def test_unread_poses_are_bounded_and_counted_while_the_callback_gets_every_pose(recording) -> None:
    """A caller that reads only through on_pose (or never reads) must not grow memory over a long run:
    poses() keeps the newest max_unread_poses, and the ones it dropped are counted."""
    rec, events = recording
    got: list[Pose] = []
    s = Session(rec.rig, on_pose=got.append, max_unread_poses=5)
    res = s.replay(iter(events))
    n = len(res.pipeline.published)
    assert n > 20 and len(got) == n
    assert list(s.poses()) == got[-5:]                     # the newest five, the same objects
    assert s.unread_poses_dropped == n - 5
    for bad in (0, -3, 2.5, True, "10"):
        with pytest.raises(ConfigError, match="max_unread_poses must be a whole number >= 1"):
            Session(rec.rig, max_unread_poses=bad)
    assert Session(rec.rig, max_unread_poses=np.int64(3))._poses.maxsize == 3



def _frames_then_ctrl_c_inside_an_extension(session: Session, after: int) -> None:
    """The pipeline's frame handler raises, after `after` frames, what a Ctrl-C landing inside a C
    extension (numba loading its kernel cache) raises: a SystemError with the KeyboardInterrupt as context."""
    on_frame = session.pipeline.on_frame
    count = [0]

    def wrapped(ev):
        count[0] += 1
        if count[0] > after:
            try:
                raise KeyboardInterrupt
            except KeyboardInterrupt:
                raise SystemError("<built-in function> returned a result with an exception set")  # noqa: B904
        return on_frame(ev)

    session.pipeline.on_frame = wrapped


def test_a_ctrl_c_inside_an_extension_ends_a_replay_as_interrupted(recording) -> None:
    rec, events = recording
    s = Session(rec.rig)
    _frames_then_ctrl_c_inside_an_extension(s, 10)
    res = s.replay(iter(events), keep_partial=True)
    assert res.status == "interrupted" and res.reason.startswith("interrupted after")
    assert 0.4 < res.scheduler.sensor_s < 1.0   # stopped at the 11th frame (20 Hz)
    s = Session(rec.rig)
    _frames_then_ctrl_c_inside_an_extension(s, 10)
    with pytest.raises(SystemError):   # without keep_partial it propagates
        s.replay(iter(events))


def test_other_extension_errors_are_not_taken_for_an_interrupt(recording) -> None:
    from runtime.errors import caused_by_interrupt

    rec, events = recording
    s = Session(rec.rig)

    def broken(ev):
        raise SystemError("a real fault")

    s.pipeline.on_frame = broken
    with pytest.raises(SystemError):
        s.replay(iter(events), keep_partial=True)
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as ki:
        assert caused_by_interrupt(ki)
    assert not caused_by_interrupt(ValueError("x"))


def test_stop_replay_ends_a_replay_at_the_first_pose_and_touches_nothing_else(recording) -> None:
    """From on_pose, a replay ends at its first pose (the same pose a whole replay publishes first); outside
    a replay, and on a session fed by add_*, stop_replay does nothing and says so."""
    rec, events = recording
    whole = Session(rec.rig).replay(iter(events))
    s = Session(rec.rig)
    assert s.stop_replay() is False
    s.on_pose = lambda _pose: s.stop_replay()
    first = s.replay(iter(events))
    assert first.scheduler.stopped_early and not whole.scheduler.stopped_early
    assert len(first.pipeline.published) == 1
    assert first.pipeline.published[0].t_ns == whole.pipeline.published[0].t_ns
    assert first.scheduler.events < whole.scheduler.events and s.stop_replay() is False
    with Session(rec.rig, max_pending_frames=10_000) as pushed:
        _push(pushed, events[:50])
        assert pushed.stop_replay() is False
        _push(pushed, events[50:])
    assert pushed.result.status == "complete" and not pushed.result.scheduler.stopped_early
    assert pushed.result.scheduler.events == whole.scheduler.events


@pytest.mark.parametrize("scale, said", [(1e-3, "IMU stamps look like microseconds"),
                                         (1e-6, "IMU stamps look like milliseconds"),
                                         (1e-9, "distinct stamps in the first 50 samples")])
def test_imu_stamps_in_other_units_are_named(recording, scale: float, said: str) -> None:
    """The file drivers check the units; pushed samples in us or s published nothing, counted only as
    out-of-order samples (or not at all)."""
    rec, _ = recording
    s = Session(rec.rig)
    pushed: list = []
    s._push = pushed.append                        # the checks run on the caller's side of the queue
    with pytest.raises(DataError, match=said):
        for k in range(60):
            s.add_imu(int((10**18 + k * 5_000_000) * scale), [0, 0, 0], [0, 0, 9.81])
    assert len(pushed) == 49                       # judged at the 50th sample, before it is pushed


def test_imu_samples_stamped_once_per_batch_are_named(recording) -> None:
    """A driver that stamps a FIFO batch once (10 samples, one stamp, 20 batches a second) was told its stamps
    might be whole seconds or milliseconds."""
    rec, _ = recording
    s = Session(rec.rig)
    s._push = lambda ev: None
    with pytest.raises(DataError, match="the samples come in batches of about 10 sharing one stamp, 20 "
                                        "batches per second: stamp each sample"):
        for k in range(60):
            s.add_imu(10**18 + (k // 10) * 50_000_000, [0, 0, 0], [0, 0, 9.81])


def test_imu_stamps_truncated_to_whole_seconds_or_milliseconds_are_not_taken_for_batches() -> None:
    from runtime.units import repeated_stamps_cause

    seconds = np.repeat(10**18 + np.arange(3) * 1_000_000_000, 20)          # a 20 Hz IMU, ns truncated to s
    millis = np.repeat(10**18 + np.arange(13) * 1_000_000, 4)                # 4 kHz, truncated to ms
    slow = np.repeat(10**18 + np.arange(3) * 999_000_000, 20)                # one batch a second
    for stamps in (seconds, millis, slow):
        assert repeated_stamps_cause(stamps).endswith("(whole seconds or milliseconds?)")
    batches = np.repeat(10**18 + np.arange(5) * 50_000_000, 10)
    assert repeated_stamps_cause(batches).startswith("the samples come in batches of about 10")


def test_an_accelerometer_in_g_and_camera_stamps_in_us_are_named(recording) -> None:
    rec, _ = recording
    s = Session(rec.rig)
    s._push = lambda ev: None
    with pytest.raises(DataError, match="looks like g, not m/s\\^2; multiply it by 9.80665"):
        for k in range(50):                        # one NaN sample among them made the median NaN: unsaid
            s.add_imu(10**18 + k * 5_000_000, [0, 0, 0], [float("nan") if k == 7 else 0.01, 0, 1.0])
    ok = Session(rec.rig)
    ok._push = lambda ev: None
    for k in range(60):                            # m/s^2 and ns: nothing said
        ok.add_imu(10**18 + k * 5_000_000, [0, 0, 0], [0.1, 0, 9.81])
    image = np.zeros((480, 752), np.uint8)
    with pytest.raises(DataError, match="camera stamps look like microseconds"):
        for k in range(5):
            ok.add_image(10**12 + k * 50_000, image)


def test_an_image_is_copied_so_a_reused_buffer_does_not_change_queued_frames(recording) -> None:
    """A driver that fills one buffer for every frame (V4L2 mmap, cap.read(buf)) changed the images held
    for the start-up and mapping windows: 25 of 30 frames the model got were another frame's."""
    rec, _ = recording
    s = Session(rec.rig)
    pushed: list = []
    s._push = pushed.append
    buf = np.zeros((480, 752), np.uint8)
    for k in range(3):
        buf[:] = k + 1
        s.add_image(10**18 + k * 50_000_000, buf)
    assert [int(f.image[0, 0]) for f in pushed] == [1, 2, 3]
    assert all(f.image.flags.c_contiguous and f.image is not buf for f in pushed)


def test_poses_waits_without_a_timeout_and_a_closed_session_does_not_start_again(recording) -> None:
    import threading

    rec, _ = recording
    s = Session(rec.rig)
    pose = Pose(1, 1, np.eye(4), np.eye(4), np.zeros(3), None, "test", 0, 0)
    threading.Timer(0.2, s._queue_pose, args=(pose,)).start()
    assert list(s.poses(timeout=None)) == [pose]             # None returned at once
    s.close()
    with pytest.raises(DavioError, match="the session is closed"):
        s.start()                                            # a scheduler thread nothing could stop
    assert s._thread is None


def test_an_imu_outage_resets_the_running_filter_a_short_gap_does_not(recording) -> None:
    """After a 1 s IMU gap the filter dead-reckoned across it and published poses drifting 12 m with a
    0.05-0.24 m position std for 7 s: beyond msckf.max_imu_outage_s (0.5 s) it is reset, said as a reset."""
    from runtime.events import ImuSample

    rec, events = recording
    t0 = events[0].t_ns

    def without_imu(lo: float, hi: float) -> list:
        return [e for e in events if not (isinstance(e, ImuSample) and lo <= (e.t_ns - t0) * 1e-9 < hi)]

    said: list = []
    session = Session(rec.rig, config=DavioConfig(), on_event=said.append)
    long_gap = session.replay(iter(without_imu(2.6, 3.2)))
    reasons = long_gap.pipeline.report()["filter"]["divergence_reasons"]
    assert len(reasons) == 1 and reasons[0].startswith("IMU outage of 0.60 s > 0.5 s (max_imu_outage_s)")
    # the refusals before the first pose, as they stood then: the filter's own counts went on after the reset
    before, now = (long_gap.pipeline.report()["startup"]["refused_before_first"],
                   long_gap.pipeline.report()["filter"]["initializers"])
    assert 0 < before["static"]["rejections"]["short_window"] < now["static"]["rejections"]["short_window"]
    assert [e.kind for e in said].count("reset") == 1
    gap = [e for e in said if e.kind == "imu_gap"][0]
    assert gap.message.endswith("a running filter is reset (longer than msckf.max_imu_outage_s)")
    assert all(not (int(2.6e9) <= p.t_ns - t0 < int(3.2e9)) for p in long_gap.pipeline.published)
    short_gap = Session(rec.rig, config=DavioConfig()).replay(iter(without_imu(2.6, 3.0)))
    assert short_gap.pipeline.report()["filter"]["divergence_reasons"] == []


def test_a_clock_that_goes_back_past_the_outage_bound_resets_the_filter(recording) -> None:
    """A device clock that jumped back 1 s: its data was dropped until the stamps passed the newest one, and
    the filter then went on from the state of 1 s of real time before, as if no time had passed (the stamps
    said 5 ms). The time it could not propagate is at least the jump: an outage, said as one."""
    import dataclasses

    rec, events = recording
    t0 = events[0].t_ns

    def restamped(at_s: float, back_s: float) -> list:
        return [dataclasses.replace(e, t_ns=e.t_ns - int(back_s * 1e9))
                if e.t_ns - t0 >= int(at_s * 1e9) else e for e in events]

    said: list = []
    jumped = Session(rec.rig, config=DavioConfig(), on_event=said.append).replay(iter(restamped(2.6, 1.0)))
    reasons = jumped.pipeline.report()["filter"]["divergence_reasons"]
    assert len(reasons) == 1 and reasons[0].startswith(
        "IMU stamps went back 1.00 s: at least 1.00 s without usable samples > 0.5 s (max_imu_outage_s)")
    kinds = [e.kind for e in said]
    assert kinds.count("reset") == 1 and kinds.count("stamps_back") == 1
    back = said[kinds.index("stamps_back")]
    assert "a running filter is reset when it is longer than msckf.max_imu_outage_s" in back.message
    assert back.detail["back_s"] == pytest.approx(1.0, abs=0.01)
    gap = [e for e in said if e.kind == "imu_gap"]
    assert len(gap) == 1 and gap[0].detail["longest_s"] == pytest.approx(1.0, abs=0.01)
    short = Session(rec.rig, config=DavioConfig()).replay(iter(restamped(2.6, 0.3)))
    assert short.pipeline.report()["filter"]["divergence_reasons"] == []
    k = next(i for i, e in enumerate(events) if e.t_ns - t0 >= int(2.6e9) and not isinstance(e, Frame))
    stray = events[:k] + [dataclasses.replace(events[k], t_ns=events[k].t_ns - int(0.8e9))] + events[k:]
    one = Session(rec.rig, config=DavioConfig()).replay(iter(stray))      # one stamp 0.8 s back: no outage
    assert one.pipeline.report()["filter"]["divergence_reasons"] == []
    assert one.pipeline.report()["filter"]["imu_out_of_order"] == 1
    repeat = dataclasses.replace(events[k - 1]) if not isinstance(events[k - 1], Frame) else events[k - 2]
    stray2 = stray[:k + 1] + [repeat] + stray[k + 1:]         # then a repeat of the newest: still none
    two = Session(rec.rig, config=DavioConfig()).replay(iter(stray2))
    assert two.pipeline.report()["filter"]["divergence_reasons"] == []
    assert two.pipeline.report()["filter"]["imu_out_of_order"] == 2
    flagged = stray[:k] + [dataclasses.replace(stray[k], lost_before=3)] + stray[k + 1:]
    carried = Session(rec.rig, config=DavioConfig()).replay(iter(flagged))   # its gap flag goes to the next
    assert carried.pipeline.report()["filter"]["imu_lost"] == 3


def test_samples_a_driver_lost_are_passed_on_and_counted(recording) -> None:
    """The imu_gap event counts samples the driver lost; pushed data had no way to say so."""
    rec, events = recording
    s = Session(rec.rig)
    pushed: list = []
    s._push = pushed.append
    s.add_imu(10**18, [0, 0, 0], [0, 0, 9.81], lost_before=np.int64(7))
    assert pushed[0].lost_before == 7
    for bad in (-1, 1.5, True, "3"):
        with pytest.raises(DataError, match="lost_before must be a whole number >= 0"):
            s.add_imu(10**18 + 5_000_000, [0, 0, 0], [0, 0, 9.81], lost_before=bad)
    from runtime.events import ImuSample

    said: list = []
    imu = [i for i, e in enumerate(events) if isinstance(e, ImuSample)]
    with Session(rec.rig, on_event=said.append, max_pending_frames=10_000) as live:
        for k, ev in enumerate(events):
            if isinstance(ev, Frame):
                live.add_image(ev.t_ns, ev.image)
            else:
                live.add_imu(ev.t_ns, ev.gyro, ev.accel, lost_before=3 if k == imu[400] else 0)
    assert live.pipeline.report()["filter"]["imu_lost"] == 3
    assert [e.detail["lost"] for e in said if e.kind == "imu_gap"] == [3]


def test_a_push_racing_close_is_refused_not_queued_behind_the_close(recording) -> None:
    """A push whose closed-check passed just before another thread's close() put its marker was queued
    behind it: never processed, and no error said so."""
    import threading

    rec, _ = recording
    s = Session(rec.rig)
    s.add_imu(10**18, [0, 0, 0], [0, 0, 9.81])
    start, closer = s.start, threading.Thread(target=s.close)

    def start_then_close():          # the push passed its checks; close() runs in between
        out = start()
        closer.start()
        while not s._closing:
            time.sleep(0.001)
        time.sleep(0.05)
        return out

    s.start = start_then_close
    with pytest.raises(DavioError, match="the session is closed"):
        s.add_imu(10**18 + 5_000_000, [0, 0, 0], [0, 0, 9.81])
    closer.join(10)
    assert s.result.scheduler.events == 1


def test_a_push_while_close_runs_fails_instead_of_starting_a_second_scheduler(recording) -> None:
    """close() let the thread go, then mapped the queued windows: a push from an IMU thread in that time
    started a new scheduler on the same pipeline, left running after close() returned."""
    import threading

    rec, _ = recording
    before = set(threading.enumerate())
    s = Session(rec.rig)
    s.add_imu(10**18, [0, 0, 0], [0, 0, 9.81])
    entered, release = threading.Event(), threading.Event()

    def slow_finish() -> int:
        entered.set()
        release.wait(5)
        return 0

    s.pipeline.finish_mapping = slow_finish
    closer = threading.Thread(target=s.close)
    closer.start()
    assert entered.wait(5)
    with pytest.raises(DavioError, match="the session is closed"):
        s.add_imu(10**18 + 5_000_000, [0, 0, 0], [0, 0, 9.81])
    assert s._thread is None
    waiting = threading.Thread(target=lambda: list(s.poses(timeout=None)))   # wakes when the session ends
    waiting.start()
    release.set()
    closer.join(5)
    waiting.join(5)
    assert not closer.is_alive() and not waiting.is_alive()
    assert not [t for t in threading.enumerate() if t not in before and t.name == "davio-session"]
