"""Emulated DA3 on the simulator's ground truth (drivers.sim), end to end through the DepthModel API."""

from __future__ import annotations

import numpy as np
import pytest

from models.emulated_da3 import EmulatedDA3, GroundTruthSource
from runtime.events import Frame

sim = pytest.importorskip("drivers.sim")


@pytest.fixture(scope="module")
def recording():
    return sim.SimRecording.from_preset(sim.SimConfig(preset="slow", seconds=3.0, seed=1))


def test_emulator_runs_on_simulator_ground_truth(recording):
    gt = recording.gt_source
    assert isinstance(gt, GroundTruthSource)
    cam = recording.rig.camera
    # the emulator never reads pixels: frames only carry the stamps, at 1/8 of the resolution
    w, h = cam.width // 8, cam.height // 8
    K = cam.K.astype(np.float64).copy()
    K[:2] /= 8.0
    K[0, 2] = (cam.K[0, 2] + 0.5) / 8.0 - 0.5  # pixel-centre convention
    K[1, 2] = (cam.K[1, 2] + 0.5) / 8.0 - 0.5
    stamps = recording.frame_stamps_ns[[0, 4, 8, 12, 16]]
    frames = [Frame(int(t), np.zeros((h, w), np.uint8)) for t in stamps]
    model = EmulatedDA3(gt, K, w, h, preset="base", seed=2)
    views = [gt.render_view(int(t), K, w, h) for t in stamps]
    depth = np.stack([v.depth for v in views]).astype(np.float64)
    T_CW = np.stack([np.linalg.inv(v.T_WC) for v in views])
    m = np.isfinite(depth)
    assert m.mean() > 0.5

    cond = model.predict(frames, np.tile(K, (5, 1, 1)), T_CW)
    np.testing.assert_array_equal(cond.T_CW, T_CW)
    r = np.log(cond.depth[m] / depth[m])
    assert abs(np.median(r)) < 0.12 and np.median(np.abs(r - np.median(r))) < 0.06
    assert (cond.conf >= 1).all() and np.isfinite(cond.depth).all()

    unc = model.predict(frames)
    np.testing.assert_array_equal(unc.T_CW[0], np.eye(4))
    T_rel = T_CW @ np.linalg.inv(T_CW[0])  # true T_CiC0
    dR = unc.T_CW[1:, :3, :3] @ np.transpose(T_rel[1:, :3, :3], (0, 2, 1))
    ang = np.arccos(np.clip((np.trace(dR, axis1=1, axis2=2) - 1) / 2, -1, 1))
    assert (np.rad2deg(ang) < 10).all() and (ang > 0).all()


def test_confidence_tracks_the_error_on_simulator_scenes(recording):
    """Spearman(conf, |error|) about -0.5 (notes/da3_accuracy.md), after aligning each call's scale."""
    from scipy.stats import spearmanr

    gt, cam = recording.gt_source, recording.rig.camera
    w, h = cam.width // 4, cam.height // 4
    K = cam.K.astype(np.float64).copy()
    K[:2] /= 4.0
    K[0, 2] = (cam.K[0, 2] + 0.5) / 4.0 - 0.5
    K[1, 2] = (cam.K[1, 2] + 0.5) / 4.0 - 0.5
    stamps = recording.frame_stamps_ns[[10, 20, 30, 40, 50]]
    frames = [Frame(int(t), np.zeros((h, w), np.uint8)) for t in stamps]
    views = [gt.render_view(int(t), K, w, h) for t in stamps]
    depth = np.stack([v.depth for v in views]).astype(np.float64)
    T_CW = np.stack([np.linalg.inv(v.T_WC) for v in views])
    m = np.isfinite(depth)
    model = EmulatedDA3(gt, K, w, h, preset="base", seed=3)
    rho = []
    for _ in range(6):
        pred = model.predict(frames, np.tile(K, (5, 1, 1)), T_CW)
        r = np.log(pred.depth[m] / depth[m])
        rho.append(spearmanr(pred.conf[m], np.abs(np.expm1(r - np.median(r))) * depth[m])[0])
    assert -0.7 < np.mean(rho) < -0.3, rho
