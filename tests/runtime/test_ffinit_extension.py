"""Re-solving a refused start-up window over a longer span (runtime/ffinit/extension.py): DA3 points
carried by the front-end's tracks, newer frames' poses by PnP, and the longer window's scale.

The scene is a tilted plane, so DA3's depth maps, the tracks and the poses have closed forms; the robot
moves at constant velocity and starts to accelerate at the end of the window (a(t) ~ t^4), so the
0.8 s window cannot observe the scale and the longer one can."""
from __future__ import annotations

import numpy as np
import pytest
from ffinit_synth import G0, P_IC_EUROC, R_IC_EUROC
from scipy.spatial.transform import Rotation

from models.depth_model import DepthPrediction
from runtime.events import Frame
from runtime.ffinit import FFInitConfig
from runtime.ffinit.extension import (
    EXTENDABLE,
    ExtensionSeed,
    TrackSet,
    extended_observations,
    track_points_C0,
)
from runtime.ffinit.initializer import FeedForwardInitializer
from runtime.ffinit.window import ImageObservations, Rejection
from runtime.msckf.init_common import InitResult

K = np.array([[400.0, 0.0, 320.0], [0.0, 400.0, 240.0], [0.0, 0.0, 1.0]])
W, H = 640, 480
DA3_SCALE = 2.0
"""Metric = DA3_SCALE x DA3 units."""
N_W, C_W = np.array([-0.3, 0.0, 1.0]), 4.0
"""The plane n . X = c in the world (z = 4 + 0.3 x), in front of the camera."""
T_RAMP = 1.4


def motion(t: float, accel: float = 2.0):
    """Closed-form IMU pose and velocity in the world: 0.3 m/s forward, then a(t) = accel (t / 1.4)^4."""
    e = np.array([0.8, 0.5, 0.3])
    p = np.array([0.3, 0.05, 0.0]) * t + e * accel * T_RAMP ** 2 / 30 * (t / T_RAMP) ** 6
    v = np.array([0.3, 0.05, 0.0]) + e * accel * T_RAMP / 5 * (t / T_RAMP) ** 5
    R = Rotation.from_rotvec([0.05 * np.sin(t), 0.08 * t, 0.03 * np.cos(1.2 * t)]).as_matrix()
    return p, v, R


def camera(t: float) -> tuple[np.ndarray, np.ndarray]:
    p, _, R = motion(t)
    return R @ R_IC_EUROC, p + R @ P_IC_EUROC


def depth_map(t: float) -> np.ndarray:
    """(H, W) metric z-depth of the plane seen from the camera at t (ray-plane intersection)."""
    R_WC, p_WC = camera(t)
    u, v = np.meshgrid(np.arange(W), np.arange(H))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones((H, W))], axis=-1)
    return ((C_W - N_W @ p_WC) / ((rays @ R_WC.T) @ N_W)).astype(np.float32)


def plane_points(n: int = 800, seed: int = 0) -> np.ndarray:
    xy = np.random.default_rng(seed).uniform(-4.0, 6.0, (n, 2))
    return np.column_stack([xy, 4.0 + 0.3 * xy[:, 0]])


def tracks(t: float, P_W: np.ndarray) -> TrackSet:
    """The plane points visible at t: ids = their index, z = exact normalized coordinates."""
    R_WC, p_WC = camera(t)
    P_C = (P_W - p_WC) @ R_WC
    z = P_C[:, :2] / P_C[:, 2:3]
    uv = z * K[0, 0] + K[:2, 2]
    ok = (P_C[:, 2] > 0) & (uv[:, 0] > 2) & (uv[:, 0] < W - 3) & (uv[:, 1] > 2) & (uv[:, 1] < H - 3)
    return TrackSet(int(round(t * 1e9)), np.flatnonzero(ok), z[ok])


def imu(t_end: float, ba: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """400 Hz IMU samples (t_ns, gyro, accel + ba) by central differences of the closed forms."""
    t = np.arange(-0.05, t_end + 0.05, 1 / 400.0)
    h = 1e-5
    gyro, accel = [], []
    for tk in t:
        R = motion(tk)[2]
        Om = R.T @ (motion(tk + h)[2] - motion(tk - h)[2]) / (2 * h)
        gyro.append([Om[2, 1], Om[0, 2], Om[1, 0]])
        a_W = (motion(tk + h)[1] - motion(tk - h)[1]) / (2 * h)
        accel.append(R.T @ (a_W + np.array([0.0, 0.0, G0])))
    return np.round(t * 1e9).astype(np.int64), np.array(gyro), np.array(accel) + ba


WINDOW_T = np.arange(5) * 0.2


class PlaneDA3:
    """A DepthModel answering the unconditioned call exactly, at DA3_SCALE (depths and translations)."""

    K_rect = K

    def predict(self, frames, K_in=None, T_CW=None) -> DepthPrediction:
        ts = [f.t_ns * 1e-9 for f in frames]
        R0, p0 = camera(ts[0])
        T = []
        for t in ts:
            R_WC, p_WC = camera(t)
            T_CC0 = np.eye(4)
            T_CC0[:3, :3] = R_WC.T @ R0
            T_CC0[:3, 3] = R_WC.T @ (p0 - p_WC) / DA3_SCALE
            T.append(T_CC0)
        depth = np.stack([depth_map(t) for t in ts]) / DA3_SCALE
        conf = 1.0 + np.random.default_rng(1).random(depth.shape).astype(np.float32)
        return DepthPrediction(depth, conf, np.stack(T), np.stack([K] * len(ts)))


def _refused_window(ba: np.ndarray):
    """The 0.8 s window through the initializer: (initializer, its rejection, IMU to 2 s)."""
    init = FeedForwardInitializer(PlaneDA3(), R_IC_EUROC, P_IC_EUROC)
    t_imu, gyro, accel = imu(2.0, ba)
    frames = [Frame(int(round(t * 1e9)), np.zeros((H, W), np.uint8)) for t in WINDOW_T]
    return init, init.solve(frames, t_imu, gyro, accel), (t_imu, gyro, accel)


def _later_tracks(until_s: float, P_W: np.ndarray) -> list[TrackSet]:
    return [tracks(t, P_W) for t in WINDOW_T] + [tracks(t, P_W) for t in np.arange(1.0, until_s + 1e-6, 0.2)]


@pytest.mark.parametrize("ba", [np.zeros(3), np.array([0.02, -0.02, 0.02])])
def test_a_window_refused_for_its_span_is_accepted_over_a_longer_one_with_the_right_scale(ba):
    init, refused, (t_imu, gyro, accel) = _refused_window(ba)
    assert isinstance(refused, Rejection) and refused.reason in EXTENDABLE
    assert isinstance(refused.seed, ExtensionSeed)
    P_W = plane_points()
    shorter = init.solve_extended(refused.seed, _later_tracks(1.2, P_W), t_imu, gyro, accel)
    assert isinstance(shorter, Rejection) and shorter.reason == "scale_unobservable"
    assert shorter.seed is refused.seed            # still extendable
    res = init.solve_extended(refused.seed, _later_tracks(1.6, P_W), t_imu, gyro, accel)
    assert isinstance(res, InitResult), res
    assert res.info["extended_frames"] == 4 and res.info["span_s"] == pytest.approx(1.6)
    assert res.t_ns == int(round(1.6e9))
    tol = 1e-3 if not np.any(ba) else 0.03           # a 0.035 m/s^2 bias: within the gate's tolerance
    assert res.info["scale"] == pytest.approx(DA3_SCALE, rel=tol)
    _, v_W, R_WI = motion(1.6)
    # the state's velocity in the gravity-aligned frame has the true speed and vertical component
    assert np.linalg.norm(res.v_OI) == pytest.approx(np.linalg.norm(v_W), rel=3 * tol)
    assert res.v_OI[2] == pytest.approx(v_W[2], abs=0.05 if np.any(ba) else 2e-3)


def test_pnp_gives_each_newer_frame_its_pose_at_the_da3_scale():
    _, refused, _ = _refused_window(np.zeros(3))
    ext = extended_observations(refused.seed, _later_tracks(1.6, plane_points()), FFInitConfig())
    assert isinstance(ext, list)
    assert [t for t, _ in ext] == [int(round(t * 1e9)) for t in (1.0, 1.2, 1.4, 1.6)]
    R0, p0 = camera(0.0)
    for t_ns, obs in ext:
        R_WC, p_WC = camera(t_ns * 1e-9)
        assert np.allclose(obs.R_C0Ci, R0.T @ R_WC, atol=1e-4)   # float32 depth maps
        assert np.allclose(obs.p_C0Ci * DA3_SCALE, R0.T @ (p_WC - p0), atol=1e-4)
        assert len(obs.z) == FFInitConfig().max_points_per_image
        # each point lies on the plane: its depth in C_j is the ray-plane distance
        pts_W = (obs.points_C0 * DA3_SCALE) @ R0.T + p0
        assert np.allclose(pts_W @ N_W, C_W, atol=1e-4)


def _confidence() -> np.ndarray:
    """Confidence 2 except the 150 top rows (31 % of the image, so its 25th percentile is 1)."""
    conf = np.full((H, W), 2.0, np.float32)
    conf[:150, :] = 1.0
    return conf


def test_a_track_on_a_depth_edge_or_below_the_confidence_percentile_carries_no_point():
    depth = np.full((H, W), 4.0, np.float32)
    depth[:, 300:] = 8.0                       # an occlusion boundary between columns 299 and 300
    obs = ImageObservations(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.eye(3), np.zeros(3))
    seed = ExtensionSeed(np.array([0]), [obs], depth[None], _confidence()[None], K, "scale_unobservable")
    uv = np.array([[100.0, 240.0], [500.0, 240.0], [299.6, 240.0], [100.0, 50.0]])
    z = (uv - K[:2, 2]) / K[0, 0]
    pts = track_points_C0(seed, [TrackSet(0, np.arange(4), z)], FFInitConfig())
    assert sorted(pts) == [0, 1]               # the edge pixel and the low-confidence pixel are out
    assert np.allclose(pts[0][0], 4.0 * np.append(z[0], 1.0))
    assert np.allclose(pts[1][0], 8.0 * np.append(z[1], 1.0))


def test_a_track_whose_points_disagree_between_images_is_dropped():
    """Seen in two images, a track's points are averaged (median) when they agree, dropped when one lies
    more than 10 % of the depth from their median (here 13 %)."""
    z = np.array([[0.1, 0.2], [-0.1, 0.25]])
    d0 = np.full((H, W), 5.0, np.float32)
    d1 = d0.copy()
    uv1 = np.rint(z[1] * K[0, 0] + K[:2, 2]).astype(int)
    d1[uv1[1] - 3:uv1[1] + 4, uv1[0] - 3:uv1[0] + 4] = 6.5    # image 1 puts track 1 30 % deeper
    obs = ImageObservations(np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.eye(3), np.zeros(3))
    seed = ExtensionSeed(np.array([0, 1]), [obs, obs], np.stack([d0, d1]), np.stack([_confidence()] * 2), K,
                         "scale_unobservable")
    ts = [TrackSet(0, np.arange(2), z), TrackSet(1, np.arange(2), z)]
    pts = track_points_C0(seed, ts, FFInitConfig())
    assert sorted(pts) == [0] and np.allclose(pts[0][0], 5.0 * np.append(z[0], 1.0))


def test_too_few_tracks_or_wrong_tracks_refuse_the_extension_by_name():
    _, refused, _ = _refused_window(np.zeros(3))
    P_W = plane_points()
    sets = _later_tracks(1.2, P_W)
    few = sets[:5] + [TrackSet(s.t_cam_ns, s.ids[:10], s.z[:10]) for s in sets[5:]]
    rej = extended_observations(refused.seed, few, FFInitConfig())
    assert isinstance(rej, Rejection) and rej.reason == "extension_few_tracks"
    rng = np.random.default_rng(3)
    scrambled = sets[:5] + [TrackSet(s.t_cam_ns, rng.permutation(s.ids), s.z) for s in sets[5:]]
    rej = extended_observations(refused.seed, scrambled, FFInitConfig())
    assert isinstance(rej, Rejection) and rej.reason == "extension_pnp_failed"
    rej = extended_observations(refused.seed, sets[:5], FFInitConfig())
    assert isinstance(rej, Rejection) and rej.reason == "extension_no_frames"


def test_depth_maps_at_another_resolution_than_k_are_refused_by_name():
    _, refused, _ = _refused_window(np.zeros(3))
    seed = refused.seed
    half = ExtensionSeed(seed.t_cam_ns, seed.observations, seed.depth[:, ::2, ::2], seed.conf[:, ::2, ::2],
                         seed.K, seed.reason)
    rej = extended_observations(half, _later_tracks(1.2, plane_points()), FFInitConfig())
    assert isinstance(rej, Rejection) and rej.reason == "extension_depth_size"


def test_tracks_the_camera_model_could_not_undistort_are_skipped_quietly():
    """undistort_points returns NaN rows where it does not converge: no warning, no point from them."""
    import warnings

    _, refused, _ = _refused_window(np.zeros(3))
    sets = _later_tracks(1.2, plane_points())
    for ts in sets:
        ts.z[::3] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        pts = track_points_C0(refused.seed, sets[:5], FFInitConfig())
        ext = extended_observations(refused.seed, sets, FFInitConfig())
    good_ids = {int(i) for ts in sets[:5] for k, i in enumerate(ts.ids) if k % 3}
    assert pts and set(pts) <= good_ids           # a track seen only where NaN carries no point
    assert isinstance(ext, list) and all(np.all(np.isfinite(o.z)) for _, o in ext)
