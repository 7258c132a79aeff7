"""Online camera-intrinsics calibration: the pixel Jacobian w.r.t. the intrinsics, the state block, the
update columns and the filter's behaviour with the true and with perturbed intrinsics."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from runtime.errors import ConfigError, EstimatorError
from runtime.msckf.camera_kernels import MODEL_CODES, distort_jacobian_params, distort_point
from runtime.msckf.config import MsckfConfig
from runtime.msckf.estimator import MsckfEstimator
from runtime.msckf.measurement import feature_intrinsics_jacobian, feature_jacobians
from runtime.msckf.so3_kernels import exp3
from runtime.msckf.state import State
from tests.runtime.test_msckf_estimator import PRM, _init, _rig, _run, _stream


def _random_params(rng: np.random.Generator, model: str) -> np.ndarray:
    prm = np.zeros(12)
    prm[0:2] = rng.uniform(300.0, 600.0, 2)
    prm[2:4] = rng.uniform(200.0, 400.0, 2)
    if model == "radtan":
        prm[4:9] = [rng.uniform(-0.3, 0.1), rng.uniform(-0.05, 0.1), *rng.uniform(-1e-3, 1e-3, 2),
                    rng.uniform(-0.01, 0.01)]
    elif model == "rational":                      # around an OAK-D factory calibration's coefficients
        prm[4:12] = np.array([9.49, -102.07, 0.0008, 0.0020, 401.19, 9.26, -100.43, 394.56]) * \
            rng.uniform(0.9, 1.1, 8)
    elif model == "equidistant":
        prm[4:8] = rng.uniform(-0.05, 0.05, 4)
    return prm


def _numeric_jacobian(fun, prm: np.ndarray) -> np.ndarray:
    """Central differences of fun (array-valued) w.r.t. the 8 intrinsics prm[:8] (steps 1e-4 px for
    fx fy cx cy, 1e-7 for the distortion coefficients); (fun's size, 8)."""
    cols = []
    for j in range(8):
        h = 1e-4 if j < 4 else 1e-7
        pp, pm = prm.copy(), prm.copy()
        pp[j] += h
        pm[j] -= h
        cols.append((np.ravel(fun(pp)) - np.ravel(fun(pm))) / (2 * h))
    return np.stack(cols, axis=1)


@pytest.mark.parametrize("model", ["radtan", "rational", "equidistant", "none"])
def test_intrinsics_jacobian_matches_central_differences(model: str) -> None:
    rng = np.random.default_rng(7)
    code = MODEL_CODES[model]
    for _ in range(30):
        prm = _random_params(rng, model)
        x, y = rng.uniform(-0.8, 0.8, 2)
        J = distort_jacobian_params(code, prm, x, y)
        num = _numeric_jacobian(lambda q, x=x, y=y: distort_point(code, q, x, y)[:2], prm)
        if model == "none":
            num[:, 4:] = 0.0           # "none" ignores the coefficients: so does its Jacobian
        assert np.allclose(J, num, rtol=1e-6, atol=1e-6), (model, J - num)


def test_the_filters_rational_kernel_is_the_calib_model_and_radtan_with_k4_to_k6_zero() -> None:
    """The filter's distortion kernel against calib.PinholeRational (itself checked against OpenCV's
    projectPoints): pixels and the 2x2 Jacobian; with k4..k6 = 0, a 9-value radtan array gives the same."""
    from calib import PinholeRational
    from runtime.msckf.camera_kernels import CameraParams, distort_points, undistort_points

    coeffs = [9.49, -102.07, 0.0008, 0.0020, 401.19, 9.26, -100.43, 394.56]
    cam = PinholeRational(1280, 800, 800.0, 800.5, 640.5, 400.25, coeffs)
    cp = CameraParams.from_camera(cam)
    assert cp.model == "rational" and cp.params.size == 12 and cp.code == MODEL_CODES["radtan"]
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.7, 0.7, (200, 2))
    np.testing.assert_allclose(distort_points(cp.code, cp.params, xy), cam.distort(xy), rtol=0, atol=1e-9)
    for x, y in xy[:20]:
        np.testing.assert_allclose(distort_point(cp.code, cp.params, x, y)[2],
                                   cam.distort_jacobian(np.array([x, y])), rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(undistort_points(cp.code, cp.params, cam.distort(xy)), xy, atol=1e-10)
    radtan = cp.params.copy()
    radtan[9:] = 0.0
    for x, y in xy[:20]:
        u12, v12, J12 = distort_point(1, radtan, x, y)
        u9, v9, J9 = distort_point(1, radtan[:9], x, y)
        assert (u12, v12) == (u9, v9) and np.array_equal(J12, J9)


def test_equidistant_jacobian_at_the_optical_axis() -> None:
    prm = np.array([400.0, 410.0, 320.0, 240.0, 0.01, -0.02, 0.003, 0.001, 0.0])
    J = distort_jacobian_params(2, prm, 0.0, 0.0)
    expected = np.zeros((2, 8))
    expected[0, 2] = expected[1, 3] = 1.0
    assert np.array_equal(J, expected)


def test_feature_intrinsics_jacobian_matches_the_residual() -> None:
    """-d r / d intrinsics of the measurement model equals feature_intrinsics_jacobian (point fixed)."""
    rng = np.random.default_rng(3)
    R_IC = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    p_IC = np.array([0.05, -0.02, 0.01])
    Rc = np.array([exp3(0.05 * rng.standard_normal(3)) for _ in range(4)])
    pc = 0.2 * rng.standard_normal((4, 3))
    p_O = np.array([4.0, 0.3, -0.2])
    uv = np.full((4, 2), 300.0)
    prm = PRM.copy()
    Hk = feature_intrinsics_jacobian(Rc, pc, p_O, R_IC, p_IC, 1, prm)
    num = -_numeric_jacobian(lambda q: feature_jacobians(Rc, pc, Rc, pc, uv, p_O, p_O, R_IC, p_IC, 1, q)[1],
                             prm)
    assert np.allclose(Hk, num, rtol=1e-6, atol=1e-5)


def test_slam_rows_intrinsics_columns_match_the_residual() -> None:
    from runtime.msckf.update_slam import slam_rows

    R_IC = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    p_IC = np.array([0.05, -0.02, 0.01])
    Rc, pc = exp3(np.array([0.02, -0.03, 0.1])), np.array([0.1, 0.2, 0.0])
    lp = np.array([[5.0, 1.0, 0.5]])
    P = np.eye(40)

    def rows(prm: np.ndarray, kidx: int) -> tuple:
        return slam_rows(P, 0, -1, np.array([20]), np.array([-1]), Rc[None], pc[None], Rc[None], pc[None],
                         np.array([[300.0, 250.0]]), lp, lp, np.eye(3)[None], np.zeros((1, 3)),
                         np.eye(3)[None], np.zeros((1, 3)), R_IC, p_IC, 1, prm, 1.0, kidx)

    ok, d2, r, Hc, Ha, He, Hl, Hk = rows(PRM, 6)
    ok0, d20, _, Hc0, _, _, Hl0, Hk0 = rows(PRM, -1)
    assert ok[0] and ok0[0]
    assert np.array_equal(Hk0, np.zeros((1, 2, 8))) and np.array_equal(Hc0, Hc) and np.array_equal(Hl0, Hl)
    # the gate includes the intrinsics' uncertainty: a larger innovation covariance, a smaller distance
    assert d2[0] < d20[0]
    num = -_numeric_jacobian(lambda q: rows(q, 6)[2][0], PRM)
    assert np.allclose(Hk[0], num, rtol=1e-6, atol=1e-5)


def test_config_accepts_intrinsics_and_rejects_bad_priors() -> None:
    cfg = MsckfConfig(calib_intrinsics=True)
    assert (cfg.sigma_calib_focal, cfg.sigma_calib_center, cfg.sigma_calib_distortion) == (1.0, 1.0, 0.005)
    for field, bad in (("sigma_calib_focal", 0.0), ("sigma_calib_center", -1.0),
                       ("sigma_calib_distortion", float("nan")), ("sigma_calib_focal", float("inf"))):
        with pytest.raises(ConfigError, match=field):
            MsckfConfig(calib_intrinsics=True, **{field: bad})
    MsckfConfig(sigma_calib_focal=0.0)            # not used without calib_intrinsics


def test_state_intrinsics_block_layout_correction_and_marginalisation() -> None:
    st = State(np.eye(3), np.zeros(3), 0.0, True, True, PRM)
    assert (st.idx_dt, st.idx_ext, st.idx_intr, st.size) == (15, 16, 22, 30)
    st.P = np.diag(np.arange(1.0, 31.0))
    st.add_variable(6, np.eye(6), np.zeros((6, 30)))
    from runtime.msckf.state import Clone

    st.clones[5] = Clone(5, np.eye(3), np.zeros(3), np.eye(3), np.zeros(3), 30)
    dx = np.zeros(36)
    dx[22:30] = np.arange(1, 9) * 1e-3
    st.apply_correction(dx)
    assert np.allclose(st.cam_params[:8], PRM[:8] + np.arange(1, 9) * 1e-3) and st.cam_params[8] == PRM[8]
    assert np.array_equal(st.camera_params(np.zeros(9)), st.cam_params)
    st.remove_variable(30, 6)
    st.clones.clear()
    assert st.idx_intr == 22 and np.array_equal(np.diag(st.P), np.arange(1.0, 31.0))
    # without online intrinsics: no block, the fixed parameters are used
    st2 = State(np.eye(3), np.zeros(3), 0.0, False, False)
    assert st2.idx_intr == -1 and st2.size == 15 and st2.camera_params(PRM) is PRM


#: an equidistant (fisheye) camera for the same synthetic scene
EQ_PRM = np.array([380.0, 381.0, 375.0, 240.0, -0.01, 0.02, -0.005, 0.001, 0.0])


def _circle_seen_through(model: str, prm: np.ndarray, duration: float, seed: int, px_sigma: float) -> tuple:
    """The synthetic circle of test_msckf_estimator seen through a camera model: (imu, frames) with
    px_sigma px pixel noise."""
    from runtime.msckf.camera_kernels import distort_points
    from tests.runtime.test_msckf_estimator import R_IC, _landmarks, _truth, p_IC

    imu, frames0 = _stream(duration)
    rng = np.random.default_rng(seed)
    L = _landmarks()
    frames = []
    for t_ns, _, _ in frames0:
        R, p, _, _ = _truth(t_ns * 1e-9)
        pC = (R_IC.T @ (R.T @ (L - p).T - p_IC[:, None])).T
        vis = pC[:, 2] > 0.5
        uv = distort_points(MODEL_CODES[model], prm, pC[vis, :2] / pC[vis, 2:3])
        uv += px_sigma * rng.standard_normal(uv.shape)
        inside = (uv[:, 0] > 0) & (uv[:, 0] < 751) & (uv[:, 1] > 0) & (uv[:, 1] < 479)
        frames.append((t_ns, np.flatnonzero(vis)[inside], uv[inside]))
    return imu, frames


def _equidistant_case(duration: float) -> tuple:
    """The synthetic circle of test_msckf_estimator seen through EQ_PRM: (rig, imu, frames)."""
    from calib import PinholeEquidistant

    imu, frames = _circle_seen_through("equidistant", EQ_PRM, duration, seed=1, px_sigma=1.0)
    rig = _rig()
    cam = PinholeEquidistant(752, 480, *EQ_PRM[:4], distortion=EQ_PRM[4:8])
    return dataclasses.replace(rig, camera=cam), imu, frames


@pytest.mark.slow
@pytest.mark.parametrize("model", ["radtan", "equidistant"])
def test_filter_with_true_intrinsics_stays_at_the_truth(model: str) -> None:
    """Started at the true intrinsics, the estimates stay within 3 sigma of them and their std shrinks
    (synthetic circle: the focal length is only weakly observable there, the principal point and the
    distortion clearly)."""
    if model == "radtan":
        (imu, frames), rig, true = _stream(6.0), _rig(), PRM
    else:
        rig, imu, frames = _equidistant_case(6.0)
        true = EQ_PRM
    prior = np.array([2.0, 2.0, 2.0, 2.0, 0.01, 0.01, 0.01, 0.01])
    cfg = MsckfConfig(max_time_without_update_s=1000.0, calib_intrinsics=True, sigma_calib_focal=2.0,
                      sigma_calib_center=2.0, sigma_calib_distortion=0.01)
    est = MsckfEstimator(rig, cfg)
    assert est.camera.model == model
    _init(est, np.zeros(3))
    assert np.allclose(est.state().intrinsics_std, prior)
    snaps = _run(est, imu, frames)
    assert len(snaps) == len(frames) and est.report()["divergence_resets"] == 0
    last = snaps[-1]
    assert last.intrinsics_covariance.shape == (8, 8)
    err = last.intrinsics[:8] - true[:8]
    std = last.intrinsics_std
    assert np.all(np.abs(err) < 3.0 * std), (err, std)
    assert err @ np.linalg.solve(last.intrinsics_covariance, err) < 26.1      # chi2(8) 99.9 %
    assert np.all(std < prior), std
    if model == "radtan":     # principal point and k1 k2 well informed there
        assert np.all(std[2:4] < 0.7 * prior[2:4]) and np.all(std[4:6] < 0.2 * prior[4:6]), std
    else:                     # the equidistant coefficients are strongly correlated: k1 is still informed
        assert std[4] < 0.5 * prior[4], std
    assert est.report()["msckf_features_used"] > 0 and est.report()["slam_updates"] > 0


def test_set_intrinsics_checks_input_and_without_calibration_fixes_them() -> None:
    est = MsckfEstimator(_rig(), MsckfConfig())
    with pytest.raises(EstimatorError):
        est.set_intrinsics(np.array([0.0, 400.0, 300.0, 200.0, 0, 0, 0, 0]))
    with pytest.raises(EstimatorError):
        est.set_intrinsics(np.ones(5))
    new = PRM[:8] + 1.0
    est.set_intrinsics(new)
    _init(est, np.zeros(3))
    snap = est.state()
    assert np.array_equal(snap.intrinsics, np.append(new, np.zeros(4)))     # the camera's k3..k6: 0
    assert snap.intrinsics_covariance is None and snap.intrinsics_std is None and est.state_.idx_intr == -1
    est.set_intrinsics(snap.intrinsics)                     # a snapshot's 12 values go back as they are
    assert np.array_equal(est.camera.params, snap.intrinsics)


def test_set_intrinsics_keeps_a_rational_cameras_later_coefficients() -> None:
    """Eight values (what the filter estimates) replace fx..p2 of a rational camera; its k3..k6 stay."""
    from calib import PinholeRational

    coeffs = [9.49, -102.07, 0.0008, 0.0020, 401.19, 9.26, -100.43, 394.56]
    rig = _rig().replace(camera=PinholeRational(752, 480, 458.0, 457.0, 367.0, 248.0, coeffs))
    est = MsckfEstimator(rig, MsckfConfig())
    new = np.array([460.0, 459.0, 366.0, 249.0, 9.5, -102.0, 0.001, 0.002])
    est.set_intrinsics(new)
    assert np.array_equal(est.camera.params, np.concatenate([new, coeffs[4:]]))
    assert est.camera.model == "rational"


@pytest.mark.slow
@pytest.mark.shared_data
def test_intrinsics_converge_on_openvins_sim_and_stay_at_the_truth() -> None:
    """20 s of udel_gore: from focal +1.5 %, principal point +3 px, k1 +0.02 every error shrinks at least
    5x; from the true intrinsics (OpenVINS's 1 px / 0.005 prior) the estimate stays within 3 sigma."""
    from conftest import shared_path

    from runtime.msckf.camera_kernels import CameraParams
    from tools.benchmarks.online_calib import (
        intrinsics_errors,
        intrinsics_prior,
        perturbed_intrinsics,
        with_camera_params,
    )
    from tools.benchmarks.openvins_sim import load_sim_folder, run_filter

    run = load_sim_folder(shared_path("openvins_sim", "udel_gore_mono"), max_seconds=20.0)
    true = CameraParams.from_camera(run.rig.camera).params
    start = perturbed_intrinsics(true, 1.5, 3.0, 0.02)
    snaps, report = run_filter(with_camera_params(run, start), intrinsics_prior(run.config, start, true))
    assert report["divergence_resets"] == 0
    e0 = np.array(intrinsics_errors(start, true))
    e1 = np.array(intrinsics_errors(snaps[-1].intrinsics, true))
    assert np.allclose(e0, [1.5, 3.0 * np.sqrt(2.0), 0.02])
    assert np.all(e1 < 0.2 * e0), (e0, e1)
    snaps, report = run_filter(run, run.config.updated(calib_intrinsics=True))
    last = snaps[-1]
    err = last.intrinsics[:8] - true[:8]
    assert report["divergence_resets"] == 0 and np.all(np.abs(err) < 3.0 * last.intrinsics_std), err


@pytest.mark.shared_data
def test_bench_online_calib_reports_intrinsics(capsys) -> None:
    import argparse
    import json

    from conftest import shared_path

    from tools.benchmarks import online_calib

    p = argparse.ArgumentParser()
    online_calib.add_arguments(p)
    args = p.parse_args([str(shared_path("openvins_sim", "udel_gore_mono")), "--max-seconds", "3", "--json",
                         "--intrinsics"])
    assert online_calib.run(args) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["start_focal_pct"] == pytest.approx(1.5) and res["start_dist"] == pytest.approx(0.02)
    assert res["start_center_px"] == pytest.approx(3.0 * np.sqrt(2.0))
    errs = online_calib.intrinsics_errors(np.array(res["intrinsics_final"] + [0.0]),
                                          np.array(res["intrinsics_true"] + [0.0]))
    assert errs == pytest.approx((res["focal_pct_err"], res["center_px_err"], res["dist_err"]))
    assert len(res["intrinsics_std"]) == 8
    # converging toward the truth as the folder's Kalibr file states it (read here, not by the bench):
    # after 3 s the focal error has shrunk from 1.5 % to about 0.3 %, distortion from 0.02 to under 1e-3,
    # the principal point from 4.2 px to about 3 px
    import yaml

    text = shared_path("openvins_sim", "udel_gore_mono", "kalibr_imucam_chain.yaml").read_text()
    cam0 = yaml.safe_load(text.replace("%YAML:1.0", ""))["cam0"]
    true = np.r_[cam0["intrinsics"], cam0["distortion_coeffs"]]
    final = np.array(res["intrinsics_final"])
    assert np.allclose(res["intrinsics_true"], true)
    focal_pct = 100.0 * np.abs(final[0:2] - true[0:2]) / true[0:2]
    assert np.all(focal_pct < 0.5 * res["start_focal_pct"]), focal_pct
    assert np.linalg.norm(final[2:4] - true[2:4]) < res["start_center_px"]
    assert np.abs(final[4:8] - true[4:8]).max() < 0.1 * res["start_dist"]


def test_pinhole_camera_estimates_no_distortion() -> None:
    """A camera without a distortion model: nothing observes d0..d3, so they are reported with zero
    uncertainty (not the 0.005 prior) and stay zero, while the focal length and principal point are
    estimated."""
    from calib import Pinhole

    imu, frames = _circle_seen_through("none", PRM, 3.0, seed=2, px_sigma=0.5)
    rig = dataclasses.replace(_rig(), camera=Pinhole(752, 480, *PRM[:4]))
    cfg = MsckfConfig(max_time_without_update_s=1000.0, calib_intrinsics=True)
    est = MsckfEstimator(rig, cfg)
    assert est.camera.model == "none"
    _init(est, np.zeros(3))
    std0 = est.state().intrinsics_std
    assert np.all(std0[4:] == 0.0) and np.all(std0[:4] > 0.0)
    snaps = _run(est, imu, frames)
    last = snaps[-1]
    assert est.report()["divergence_resets"] == 0 and est.report()["msckf_features_used"] > 0
    assert np.all(last.intrinsics[4:8] == 0.0) and np.all(last.intrinsics_std[4:] == 0.0)
    assert np.all(last.intrinsics_std[:4] < std0[:4])
    assert np.all(np.abs(last.intrinsics[:4] - PRM[:4]) < 3.0 * last.intrinsics_std[:4])
