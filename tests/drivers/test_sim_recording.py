"""Simulated recordings as a driver and as a EuRoC folder read back by the EuRoC driver."""

from __future__ import annotations

import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from drivers.base import Driver
from drivers.euroc import EurocDriver
from drivers.sim.recording import SimConfig, SimRecording
from drivers.sim.render import ImageOptions
from drivers.sim.rig import euroc_default_rig
from drivers.sim.writer import write_euroc
from runtime.errors import ConfigError
from runtime.events import Frame, ImuSample
from runtime.geometry.so3 import so3_log


@pytest.fixture(scope="module")
def small_rig():
    rig = euroc_default_rig()
    return rig.replace(camera=rig.camera.scaled(0.25, 0.25))  # 188 x 120


@pytest.fixture(scope="module")
def rec(small_rig) -> SimRecording:
    return SimRecording.from_preset(SimConfig(seconds=2.5, seed=5, time_offset_s=0.004), rig=small_rig)


def test_events_are_time_ordered_and_complete(rec: SimRecording) -> None:
    assert isinstance(rec, Driver)
    events = list(rec.events())
    stamps = np.array([e.t_ns for e in events])
    assert np.all(np.diff(stamps) >= 0)
    frames = [e for e in events if isinstance(e, Frame)]
    imu = [e for e in events if isinstance(e, ImuSample)]
    # 20 Hz from 31 ms (25 ms + 2 ms half exposure + 4 ms offset margin) up to 2.5 s - 6 ms
    assert len(frames) == len(rec) == int((2.5 - 0.006 - 0.031) / 0.05) + 1
    assert len(imu) == len(rec.imu) == 501
    assert frames[0].image.shape == (120, 188) and frames[0].image.dtype == np.uint8
    for _ in range(2):  # a second pass counts the same
        rep = rec.report()
        assert rep["streams"]["cam0"]["emitted"] == len(frames) and rep["streams"]["imu0"]["emitted"] == len(
            imu
        )
        sum(1 for e in rec.events() if isinstance(e, ImuSample))
    assert rep["simulation"]["mode"] == "preset"
    gt = rec.groundtruth()
    assert gt.v is not None and gt.bg is not None and len(gt) == len(imu)


def test_time_offset_shifts_frame_stamps_not_the_scene(rec: SimRecording) -> None:
    offset_ns = 4_000_000
    assert rec.rig.time_offset_s == pytest.approx(0.004)
    # a frame stamped t_cam shows the true pose at t_cam + offset (IMU clock)
    t_cam = int(rec.frame_stamps_ns[10])
    T_WC = rec.gt_source.camera_pose(t_cam)
    R_WI, p_WI = rec.motion.pose(np.array([t_cam + offset_ns]))
    np.testing.assert_allclose(T_WC[:3, 3], p_WI[0] + R_WI[0] @ rec.rig.T_IC[:3, 3], atol=1e-12)
    assert (rec.frame_stamps_ns[0] + offset_ns - rec.imu.t_ns[0]) >= 25_000_000


def test_euroc_folder_round_trip(rec: SimRecording, tmp_path) -> None:
    manifest = write_euroc(rec, tmp_path / "sim", cloud_spacing_m=0.2)
    assert manifest["counts"]["frames"] == len(rec)
    assert json.loads((tmp_path / "sim" / "manifest.json").read_text())["counts"] == manifest["counts"]
    with EurocDriver(tmp_path / "sim") as drv:
        t_imu, gyro, accel = drv.imu_arrays()
        np.testing.assert_array_equal(t_imu, rec.imu.t_ns)
        np.testing.assert_allclose(gyro, rec.imu.gyro, rtol=0, atol=1e-15)
        np.testing.assert_allclose(accel, rec.imu.accel, rtol=0, atol=1e-15)
        np.testing.assert_array_equal(drv.frame_stamps(0), rec.frame_stamps_ns)
        gt, truth = drv.groundtruth(), rec.groundtruth()
        np.testing.assert_allclose(gt.p, truth.p, atol=1e-8)
        np.testing.assert_allclose(gt.v, truth.v, atol=1e-8)
        np.testing.assert_allclose(gt.bg, truth.bg, atol=1e-12)
        assert np.linalg.norm(so3_log(np.einsum("nji,njk->nik", gt.R, truth.R)), axis=1).max() < 1e-7
        rig = drv.rig
        assert rig is not None
        np.testing.assert_allclose(rig.camera.K, rec.rig.camera.K, atol=1e-9)
        np.testing.assert_allclose(rig.camera.distortion, rec.rig.camera.distortion, atol=1e-12)
        np.testing.assert_allclose(rig.T_IC, rec.rig.T_IC, atol=1e-9)
        assert rig.imu.accel_noise_density == pytest.approx(2.0e-3)
        frames = [e for e in drv.events() if isinstance(e, Frame)]
    frame, view = rec.render(7)
    np.testing.assert_array_equal(frames[7].image, frame.image)
    depth_mm = cv2.imread(
        str(tmp_path / "sim" / "mav0" / "depth0" / "data" / f"{frame.t_ns}.png"), cv2.IMREAD_UNCHANGED
    )
    assert depth_mm.dtype == np.uint16
    np.testing.assert_allclose(depth_mm / 1000.0, view.depth, atol=5e-4 + 1e-6)
    header = (tmp_path / "sim" / "scene_points.ply").read_bytes()[:400].decode("ascii", "replace")
    n = int(header.split("element vertex ")[1].split()[0])
    assert n == manifest["counts"]["scene_points"] > 0
    size = (tmp_path / "sim" / "scene_points.ply").stat().st_size
    assert size == header.index("end_header\n") + len("end_header\n") + 15 * n
    with pytest.raises(ConfigError, match="already holds"):
        write_euroc(rec, tmp_path / "sim")


def test_zero_offset_and_exposure_changes(small_rig) -> None:
    cfg = SimConfig(seconds=1.0, seed=1, image=replace(ImageOptions.exact(), exposure_variation=0.3))
    rec = SimRecording.from_preset(cfg, rig=small_rig)
    assert rec.rig.time_offset_s == 0.0
    gains = [rec.renderer.exposure_gain(t) for t in np.linspace(0, 20, 200)]
    assert 0.65 < min(gains) < 0.9 and 1.1 < max(gains) < 1.35
    frame, _ = rec.render(3)
    t_s = (frame.t_ns - rec.imu.t_ns[0]) * 1e-9
    assert frame.meta["exposure_gain"] == pytest.approx(rec.renderer.exposure_gain(t_s)) != 1.0


def test_preset_needs_positive_seconds() -> None:
    with pytest.raises(ConfigError):
        SimRecording.from_preset(SimConfig(seconds=0.0))


@pytest.mark.parametrize("t0_ns", [1403715524907143354, 1403715524907142912, 10**18 + 1, 0])
def test_scene_times_stay_within_the_span_of_epoch_stamps(t0_ns: int) -> None:
    """A TUM file's first stamp at 1.4e18 ns: the scene's sample times (once float64 stamps, 256 ns coarse)
    start and end exactly at the span's ends, increase, and are about 20 ms apart."""
    from drivers.sim.timeline import scene_times

    t_end = t0_ns + 2_000_000_001
    t = scene_times(t0_ns, t_end)
    assert t.dtype == np.int64 and t[0] == t0_ns and t[-1] == t_end
    assert np.all(np.diff(t) > 0) and 1.9e7 < np.median(np.diff(t)) < 2.1e7


def test_a_gap_in_the_trajectory_is_noted() -> None:
    """Poses every 5 ms with a 2 s dropout: the note names the gap (the spline makes up the motion there);
    poses without a gap give none."""
    from drivers.sim.timeline import trajectory_gap_notes

    t = 10**18 + np.arange(1000) * 5_000_000
    assert trajectory_gap_notes(t) == []
    gappy = np.concatenate([t[:200], t[600:]])
    (note,) = trajectory_gap_notes(gappy)
    assert "1 gap(s) longer than 0.2 s (the longest 2.01 s, 1.00 s after its first pose)" in note
    assert "makes up the motion" in note


def test_kept_frames_replay_without_rendering_again(small_rig, monkeypatch) -> None:
    """keep_frames: the second pass yields the same frames (stamps, pixels, meta) with no render call; a
    consumer changing a frame in place does not change the kept copy; the byte limit is honoured."""
    rec = SimRecording.from_preset(SimConfig(seconds=1.0, seed=3), rig=small_rig)
    renders = []
    original = SimRecording.render

    def counting(self, index):
        renders.append(index)
        return original(self, index)

    monkeypatch.setattr(SimRecording, "render", counting)
    fresh = [e for e in rec.events() if isinstance(e, Frame)]   # before keep_frames: nothing kept
    assert rec.kept_frames == 0 and len(renders) == len(rec)
    rec.keep_frames()
    first = [e for e in rec.events() if isinstance(e, Frame)]
    assert rec.kept_frames == len(rec) and len(renders) == 2 * len(rec)
    for f in first:
        f.image[:] = 0          # a consumer writing into its frame
    second = [e for e in rec.events() if isinstance(e, Frame)]
    assert len(renders) == 2 * len(rec)          # replayed, not rendered
    assert rec.report()["streams"]["cam0"]["emitted"] == len(rec)
    for a, b in zip(fresh, second, strict=True):
        assert a.t_ns == b.t_ns and a.meta == b.meta and a.camera_id == b.camera_id
        np.testing.assert_array_equal(a.image, b.image)
    for f in second:            # a consumer writing into replayed frames does not reach the kept ones
        f.image[:] = 0
        f.meta["written"] = True
    third = [e for e in rec.events() if isinstance(e, Frame)]
    for a, b in zip(fresh, third, strict=True):
        assert a.meta == b.meta
        np.testing.assert_array_equal(a.image, b.image)
    rec.release_frames()
    assert rec.kept_frames == 0
    list(rec.events())
    assert len(renders) == 3 * len(rec)        # released: rendered again
    # a limit of three images keeps the first three frames only; the others are rendered each pass
    rec.keep_frames(limit_bytes=3 * fresh[0].image.nbytes)
    renders.clear()
    list(rec.events())
    list(rec.events())
    assert rec.kept_frames == 3 and len(renders) == 2 * len(rec) - 3
    with pytest.raises(ValueError, match="limit_bytes"):
        rec.keep_frames(limit_bytes=-1)
