"""Session: pushed samples give the same poses as a replay of the same events; a tracker that falls
behind drops the oldest images (counted), never an IMU sample; bad pushes are clear errors."""
from __future__ import annotations

import numpy as np
import pytest

from runtime.config import DavioConfig
from runtime.errors import ConfigError, DataError
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
def test_a_tracker_that_falls_behind_drops_images_not_imu_samples(recording) -> None:
    rec, events = recording
    with Session(rec.rig, max_pending_frames=1) as s:
        _push(s, events)                  # pushed far faster than real time
    rep = s.result.scheduler
    n_frames = sum(isinstance(e, Frame) for e in events)
    assert rep.frames_dropped > 0 and rep.frames + rep.frames_dropped == n_frames
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
    assert s.close().status == "complete"
    with pytest.raises(ConfigError, match="camera intrinsics"):
        Session(rec.rig.replace(camera=None))
