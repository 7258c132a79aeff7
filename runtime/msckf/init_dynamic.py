"""Dynamic initializer: linear visual-inertial solve under |g| = g0, then a nonlinear refinement.

Following the idea of OpenVINS' ``DynamicInitializer`` (Dong-Si & Mourikis, ICRA 2012, Eq. 14):

1. Keyframes: ``num_pose`` frames spread evenly over the last ``init_window_time_s``; features
   seen in at least ``min_feature_observations`` of them (longest first, ``max_features``).
2. Rotations come from gyro preintegration (biases at the prior). With I0 the first keyframe's
   IMU frame, keyframe k sits at ``p_k = v0 t_k + g t_k^2 / 2 + dp_0k`` (all in I0), so each
   normalized observation (x, y) of feature p_f gives two equations linear in (p_f, v0, g):
   ``[1 0 -x; 0 1 -y] (R_CI R_0k^T (p_f - p_k) + p_CI) = 0``.
3. Features and v0 are eliminated; the gravity vector minimises the reduced quadratic on the
   sphere |g| = g0 (Lagrange multiplier found by a 1-D root search below the smallest
   eigenvalue: the global minimum of that trust-region-type problem).
4. The frame O is I0 rotated so that g = (0, 0, -g0) (yaw fixed by Gram-Schmidt, origin at I0).
5. Refinement (scipy least_squares, finite-difference Jacobian with its sparsity pattern) over
   keyframe poses, velocities, shared bias corrections and features: reprojection residuals
   (normalized coordinates scaled by f / sigma_px), preintegration residuals whitened by their
   covariance, bias priors, and a gauge prior on the first position and yaw.
6. Covariance: inverse Gauss-Newton information, marginal of the newest keyframe's
   [theta, p, v] and the biases, inflated per block (OpenVINS init_dyn_inflation_*).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.optimize
import scipy.sparse

from runtime.errors import ConfigError, DataError
from runtime.geometry import so3_exp, so3_log
from runtime.imu import Preintegrator
from runtime.msckf.init_common import ImuWindow, InitResult, RejectionLog, TrackWindow, rotation_from_up

# continuous-time noise densities used when no calib.ImuNoise is given (EuRoC / OpenVINS values)
_DEFAULT_GYRO_DENSITY = 1.6968e-4
_DEFAULT_ACCEL_DENSITY = 2.0e-3


@dataclass
class DynamicInitConfig:
    """Dynamic initializer settings (defaults: OpenVINS EuRoC ``init_dyn_*`` where it has them)."""

    init_window_time_s: float = 2.0
    """Window of frames and IMU used, s (OpenVINS init_window_time)."""
    min_window_fraction: float = 0.9
    """The keyframes must span at least this fraction of the window (OpenVINS waits for a full window)."""
    num_pose: int = 6
    """Keyframes in the window (OpenVINS init_dyn_num_pose)."""
    min_deg: float = 10.0
    """Minimum integrated gyro rotation over the window, degrees (OpenVINS init_dyn_min_deg)."""
    min_parallax_deg: float = 1.0
    """Minimum median rotation-compensated bearing change of the features, degrees."""
    min_features: int = 8
    """Features needed (OpenVINS: 8 valid features)."""
    max_features: int = 50
    """Features used at most, longest tracks first (OpenVINS init_max_features)."""
    min_feature_observations: int = 3
    """Keyframes a feature must be seen in."""
    gravity_mag: float = 9.81
    """Gravity magnitude g0, m/s^2."""
    estimate_gyro_bias: bool = True
    """Estimate the gyro bias from essential-matrix rotations between keyframes before the linear solve."""
    max_visual_gyro_residual_rad: float = 0.2
    """A keyframe pair whose visual and gyro rotations differ by more is left out of that estimate, rad."""
    max_condition: float = 1e10
    """Eigenvalue ratio of the reduced velocity block above which the linear system is degenerate."""
    max_feature_condition: float = 1e8
    """Eigenvalue ratio of a feature's 3x3 normal block above which it has no depth information."""
    mle_max_iterations: int = 20
    """Nonlinear refinement iterations (scipy least_squares max_nfev); 0 disables the refinement."""
    mle_tolerance: float = 1e-6
    """Relative cost / step tolerance that ends the refinement (scipy ftol and xtol)."""
    sigma_px: float = 1.0
    """Pixel noise of the features, px."""
    sigma_bg_prior: float = 0.01
    """Prior std of the gyro bias around bias_g_prior, rad/s."""
    sigma_ba_prior: float = 0.05
    """Prior std of the accelerometer bias around bias_a_prior, m/s^2. A 2 s window barely separates
    this bias from tilt; 0.05 gave a median 0.67 deg gravity error on real V1_02 IMU windows
    (`davio bench euroc-frontend --dynamic`) where 0.2 gave 1.5 deg."""
    bias_g_prior: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Gyro bias guess, rad/s (OpenVINS init_dyn_bias_g)."""
    bias_a_prior: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Accelerometer bias guess, m/s^2 (OpenVINS init_dyn_bias_a)."""
    max_accel_bias_change: float = 1.0
    """An estimated accelerometer bias farther than this from bias_a_prior rejects the solution, m/s^2."""
    max_reprojection_rms_px: float = 3.0
    """After refinement, a larger RMS reprojection error rejects the solution, px."""
    min_positive_depth_fraction: float = 0.9
    """Fraction of features that must lie in front of the first camera after the linear solve."""
    inflation_theta: float = 10.0
    """Variance inflation of the orientation block (OpenVINS init_dyn_inflation_ori)."""
    inflation_p: float = 1.0
    """Variance inflation of the position block."""
    inflation_v: float = 100.0
    """Variance inflation of the velocity block (OpenVINS init_dyn_inflation_vel)."""
    inflation_bg: float = 10.0
    """Variance inflation of the gyro bias block (OpenVINS init_dyn_inflation_bias_gyro)."""
    inflation_ba: float = 100.0
    """Variance inflation of the accelerometer bias block (OpenVINS init_dyn_inflation_bias_accel)."""

    def __post_init__(self) -> None:
        if self.num_pose < 3:
            raise ConfigError(f"dynamic init num_pose must be >= 3, got {self.num_pose}")
        if not self.init_window_time_s > 0:
            raise ConfigError(f"dynamic init window must be > 0 s, got {self.init_window_time_s}")
        if self.min_feature_observations < 2:
            raise ConfigError(f"min_feature_observations must be >= 2, got {self.min_feature_observations}")
        if self.min_features < 1 or self.max_features < self.min_features:
            raise ConfigError(
                f"need 1 <= min_features <= max_features, got {self.min_features}, {self.max_features}"
            )
        if not self.gravity_mag > 0:
            raise ConfigError(f"gravity_mag must be > 0, got {self.gravity_mag}")
        if not self.sigma_px > 0:
            raise ConfigError(f"sigma_px must be > 0, got {self.sigma_px}")


@dataclass
class LinearSolution:
    """Result of the gravity-constrained linear solve, all in the first keyframe's IMU frame I0.

    Attributes:
        v_I0: (3,) velocity of I0, m/s.  g_I0: (3,) gravitational acceleration in I0, |g| = g0.
        p_f: (F, 3) feature positions in I0, m.  cost: residual sum of squares (normalized units).
        condition: eigenvalue ratio of the reduced velocity block after eliminating the features.
        n_good: features with depth information (the others have NaN positions).
    """

    v_I0: np.ndarray
    g_I0: np.ndarray
    p_f: np.ndarray
    cost: float
    condition: float
    n_good: int


def min_quadratic_on_sphere(M: np.ndarray, m: np.ndarray, radius: float) -> np.ndarray:
    """argmin over |g| = radius of g^T M g - 2 m^T g (M symmetric PSD 3x3).

    The stationarity condition (M - lam I) g = m; the global minimum has lam below M's smallest
    eigenvalue, where |g(lam)| grows monotonically, so lam is found by a bracketed root search.
    """
    e, U = np.linalg.eigh(0.5 * (M + M.T))
    mp = U.T @ m
    norm_m = float(np.linalg.norm(mp))
    if norm_m < 1e-300:
        return radius * U[:, 0]
    e0 = float(e[0])

    def excess(lam: float) -> float:
        return float(np.sum((mp / (e - lam)) ** 2) - radius * radius)

    lo = e0 - norm_m / radius - 1e-12 * max(1.0, abs(e0))
    hi = e0 - 1e-15 * max(1.0, abs(e0), norm_m / radius)
    if excess(hi) <= 0.0:
        # hard case: the component along the smallest eigenvector is (numerically) zero
        g = np.zeros(3)
        g[1:] = mp[1:] / (e[1:] - e0)
        rest = radius * radius - float(g @ g)
        g[0] = np.sqrt(max(rest, 0.0)) * (1.0 if mp[0] >= 0 else -1.0)
        return U @ g
    while excess(lo) > 0.0:
        lo = e0 - 2.0 * (e0 - lo)
    lam = scipy.optimize.brentq(excess, lo, hi, xtol=1e-14 * max(1.0, abs(e0)), maxiter=200)
    return U @ (mp / (e - lam))


class DynamicInitializer:
    """Initialize while moving from tracked features and IMU over a short window.

    Args:
        camera: calib.CameraModel of the tracked images (used to undistort the pixels fed).
        T_IC: (4, 4) camera pose in the IMU frame (x_I = T_IC x_C).
        config: settings (DynamicInitConfig() if None).
        imu_noise: calib.ImuNoise (continuous noise densities); EuRoC values if None.
        time_offset_s: t_imu = t_cam + time_offset_s (Kalibr timeshift_cam_imu).
    """

    source = "dynamic"

    def __init__(
        self,
        camera: object,
        T_IC: np.ndarray,
        config: DynamicInitConfig | None = None,
        imu_noise: object | None = None,
        time_offset_s: float = 0.0,
    ) -> None:
        self.camera = camera
        T = np.asarray(T_IC, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise ConfigError(f"T_IC must be a finite 4x4 matrix, got shape {T.shape}")
        self.R_IC = T[:3, :3].copy()
        self.p_IC = T[:3, 3].copy()
        self.R_CI = self.R_IC.T
        self.p_CI = -self.R_IC.T @ self.p_IC
        self.config = config if config is not None else DynamicInitConfig()
        self.gyro_density = float(getattr(imu_noise, "gyro_noise_density", None) or _DEFAULT_GYRO_DENSITY)
        self.accel_density = float(getattr(imu_noise, "accel_noise_density", None) or _DEFAULT_ACCEL_DENSITY)
        self.time_offset_ns = int(round(float(time_offset_s) * 1e9))
        keep = int(round(self.config.init_window_time_s * 1e9)) + 500_000_000
        self.imu = ImuWindow(keep)
        self.tracks = TrackWindow(keep)
        self.log = RejectionLog()
        self.focal = 0.5 * (float(camera.fx) + float(camera.fy))

    # ------------------------------------------------------------------ feeding
    @property
    def last_reason(self) -> str:
        """'code: message' of the last failed attempt ('' before any)."""
        return self.log.last_reason

    def feed_imu(self, sample: object) -> None:
        """Add one drivers.events.ImuSample (t_ns IMU clock, gyro rad/s, accel m/s^2)."""
        self.imu.add(sample.t_ns, sample.gyro, sample.accel)

    def feed_tracks(self, t_ns: int, ids: np.ndarray, uv: np.ndarray) -> None:
        """Add one frame's tracks: camera-clock time, ids (M,), distorted pixels (M, 2)."""
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        xy = self.camera.undistort_points(uv) if uv.shape[0] else np.zeros((0, 2))
        self.tracks.add(t_ns, ids, uv, xy)

    def reset(self) -> None:
        """Forget buffered IMU samples and tracks (after a filter reset); rejection counts are kept."""
        self.imu.clear()
        self.tracks.frames.clear()

    def report(self) -> dict:
        """Counters for the run report."""
        return {
            "rejections": dict(self.log.counts),
            "last_reason": self.last_reason,
            "imu_dropped_nonfinite": self.imu.dropped_nonfinite,
            "imu_dropped_out_of_order": self.imu.dropped_out_of_order,
            "frames_dropped_out_of_order": self.tracks.dropped_out_of_order,
        }

    # ------------------------------------------------------------------ main entry
    def try_initialize(self) -> InitResult | None:
        """An InitResult at the newest keyframe, or None (reason in last_reason)."""
        cfg = self.config
        rej = self.log.reject
        frames = list(self.tracks.frames)
        if not frames:
            return rej(-1, "no_frames", "no tracks fed")
        # frames the IMU has not reached yet (a frame arrives before the samples after its stamp)
        t_imu_newest = self.imu.newest_ns()
        if t_imu_newest is not None:
            frames = [f for f in frames if f[0] + self.time_offset_ns <= t_imu_newest] or frames[:1]
        t_newest = frames[-1][0]
        window_ns = int(round(cfg.init_window_time_s * 1e9))
        frames = [f for f in frames if f[0] >= t_newest - window_ns]
        if len(frames) < cfg.num_pose:
            return rej(
                t_newest, "few_frames", f"{len(frames)} frames in the window < num_pose {cfg.num_pose}"
            )
        pick = np.unique(np.round(np.linspace(0, len(frames) - 1, cfg.num_pose)).astype(int))
        keyframes = [frames[i] for i in pick]
        t_cam = np.array([k[0] for k in keyframes], dtype=np.int64)
        if (t_cam[-1] - t_cam[0]) < cfg.min_window_fraction * window_ns:
            return rej(
                t_newest,
                "short_window",
                f"keyframes span {(t_cam[-1] - t_cam[0]) * 1e-9:.2f} s "
                f"< {cfg.min_window_fraction} x the {cfg.init_window_time_s} s window",
            )
        t_imu = t_cam + self.time_offset_ns

        feat_ids, obs = self._select_features(keyframes)
        if feat_ids.size < cfg.min_features:
            return rej(
                t_newest,
                "few_features",
                f"{feat_ids.size} features seen in >= "
                f"{cfg.min_feature_observations} keyframes < {cfg.min_features}",
            )

        ti, gyro, accel = self.imu.arrays()
        if ti.size < 2 or ti[0] > t_imu[0] or ti[-1] < t_imu[-1]:
            return rej(t_newest, "imu_gap", "the IMU buffer does not cover the keyframes")
        bg0 = np.asarray(cfg.bias_g_prior, dtype=np.float64)
        ba0 = np.asarray(cfg.bias_a_prior, dtype=np.float64)
        inside = (ti >= t_imu[0]) & (ti <= t_imu[-1])
        w_in = gyro[inside]
        if w_in.shape[0] >= 2:
            dts = np.diff(ti[inside]) * 1e-9
            mid = 0.5 * (w_in[1:] + w_in[:-1]) - bg0
            rot_deg = float(np.degrees(np.sum(np.linalg.norm(mid, axis=1) * dts)))
        else:
            rot_deg = 0.0
        if rot_deg < cfg.min_deg:
            return rej(
                t_newest,
                "insufficient_rotation",
                f"gyro rotation {rot_deg:.2f} deg < {cfg.min_deg} deg over the window",
            )

        try:
            from_first, between = self._preintegrate(ti, gyro, accel, t_imu, bg0, ba0)
            bg_visual = None
            if cfg.estimate_gyro_bias:
                bg_visual = self._visual_gyro_bias(keyframes, between, bg0)
                if bg_visual is not None:
                    bg0 = bg_visual
                    from_first, between = self._preintegrate(ti, gyro, accel, t_imu, bg0, ba0)
        except DataError as exc:
            return rej(t_newest, "imu_gap", f"preintegration failed: {exc}")
        R_0k = np.stack([np.eye(3)] + [p.dR for p in from_first[1:]])
        dt_0k = np.array([0.0] + [p.dt for p in from_first[1:]])
        dp_0k = np.stack([np.zeros(3)] + [p.dp for p in from_first[1:]])
        dv_0k = np.stack([np.zeros(3)] + [p.dv for p in from_first[1:]])

        parallax = self._median_parallax_deg(obs, R_0k)
        if parallax < cfg.min_parallax_deg:
            return rej(
                t_newest,
                "insufficient_parallax",
                f"median rotation-compensated parallax {parallax:.3f} deg < {cfg.min_parallax_deg} deg",
            )

        lin = self.solve_linear(obs, feat_ids.size, R_0k, dt_0k, dp_0k)
        if lin.n_good < cfg.min_features:
            return rej(
                t_newest,
                "degenerate",
                f"only {lin.n_good} features with depth information < {cfg.min_features}",
            )
        if not np.isfinite(lin.condition) or lin.condition > cfg.max_condition:
            return rej(
                t_newest,
                "degenerate",
                f"velocity block condition {lin.condition:.3g} > {cfg.max_condition:.3g}",
            )
        usable = np.isfinite(lin.p_f[:, 0])
        depth_C0 = (lin.p_f[usable] - self.p_IC) @ self.R_IC[:, 2]
        if np.mean(depth_C0 > 0) < cfg.min_positive_depth_fraction:
            return rej(
                t_newest,
                "bad_linear_solution",
                f"only {np.mean(depth_C0 > 0):.0%} of the features lie in front of the camera",
            )
        usable[usable] = depth_C0 > 0
        if usable.sum() < cfg.min_features:
            return rej(t_newest, "degenerate", f"only {int(usable.sum())} features in front of the camera")
        new_index = np.cumsum(usable) - 1
        obs = obs[usable[obs[:, 1].astype(int)]].copy()
        obs[:, 1] = new_index[obs[:, 1].astype(int)]
        lin.p_f = lin.p_f[usable]

        # gravity-aligned frame O: origin at I0, z up
        R_OI0 = rotation_from_up(-lin.g_I0)
        g_O = np.array([0.0, 0.0, -cfg.gravity_mag])
        R_k = R_OI0 @ R_0k
        p_k = np.einsum(
            "ij,kj->ki", R_OI0, lin.v_I0 * dt_0k[:, None] + 0.5 * lin.g_I0 * dt_0k[:, None] ** 2 + dp_0k
        )
        v_k = np.einsum("ij,kj->ki", R_OI0, lin.v_I0 + lin.g_I0 * dt_0k[:, None] + dv_0k)
        p_f = lin.p_f @ R_OI0.T
        info = {
            "linear_cost": lin.cost,
            "condition": lin.condition,
            "parallax_deg": parallax,
            "rotation_deg": rot_deg,
            "bg_visual": None if bg_visual is None else bg_visual.copy(),
            "n_features": int(usable.sum()),
            "n_keyframes": len(keyframes),
            "g_I0_linear": lin.g_I0.copy(),
            "v_I0_linear": lin.v_I0.copy(),
        }

        refined = _Refinement(self, obs, between, g_O, bg0, ba0).run(R_k, p_k, v_k, p_f)
        if refined is None:
            return rej(t_newest, "mle_failed", "refinement gave no finite solution or covariance")
        R_k, p_k, v_k, bg, ba, cov, rms_px, nfev = refined
        info.update(reprojection_rms_px=rms_px, mle_evaluations=nfev)
        if rms_px > cfg.max_reprojection_rms_px:
            return rej(
                t_newest,
                "mle_failed",
                f"reprojection RMS {rms_px:.2f} px > {cfg.max_reprojection_rms_px} px after refinement",
            )
        ba_change = float(np.linalg.norm(ba - np.asarray(cfg.bias_a_prior, dtype=np.float64)))
        if ba_change > cfg.max_accel_bias_change:
            return rej(
                t_newest,
                "implausible_bias",
                f"accelerometer bias {ba_change:.2f} m/s^2 from the prior > {cfg.max_accel_bias_change}",
            )
        return InitResult(
            t_ns=int(t_imu[-1]),
            R_OI=R_k[-1],
            p_OI=p_k[-1],
            v_OI=v_k[-1],
            bg=bg,
            ba=ba,
            cov=cov,
            source=self.source,
            info=info,
        )

    # ------------------------------------------------------------------ pieces
    def _preintegrate(
        self,
        ti: np.ndarray,
        gyro: np.ndarray,
        accel: np.ndarray,
        t_imu: np.ndarray,
        bg: np.ndarray,
        ba: np.ndarray,
    ) -> tuple[list, list]:
        """Preintegrations from the first keyframe to each one ([None, ...]) and between neighbours."""
        pre = Preintegrator(bg, ba, self.gyro_density, self.accel_density)
        from_first = [None] + [pre.integrate(ti, gyro, accel, int(t_imu[0]), int(t)) for t in t_imu[1:]]
        between = [
            pre.integrate(ti, gyro, accel, int(t_imu[k]), int(t_imu[k + 1])) for k in range(len(t_imu) - 1)
        ]
        return from_first, between

    def _visual_gyro_bias(self, keyframes: list, between: list, bg0: np.ndarray) -> np.ndarray | None:
        """Gyro bias aligning the preintegrated rotations with the keyframes' essential-matrix rotations.

        For each neighbouring keyframe pair, RANSAC on the essential matrix of the common tracks
        (normalized coordinates) gives R_{Ck Ck+1}; with J_R_bg the rotation's bias Jacobian,
        Log(dR^T R_vis) = J_R_bg dbg is solved in the least-squares sense (VINS-Mono style).
        Pairs with few inliers or a disagreement above max_visual_gyro_residual_rad are left out;
        None when fewer than two pairs remain.
        """
        import cv2

        cfg = self.config
        rows_J, rows_r = [], []
        for k in range(len(keyframes) - 1):
            _, ids_a, _, xy_a = keyframes[k]
            _, ids_b, _, xy_b = keyframes[k + 1]
            common, ia, ib = np.intersect1d(ids_a, ids_b, return_indices=True)
            if common.size < cfg.min_features * 2:
                continue
            pa, pb = xy_a[ia], xy_b[ib]
            good = np.all(np.isfinite(pa), axis=1) & np.all(np.isfinite(pb), axis=1)
            pa, pb = pa[good], pb[good]
            if pa.shape[0] < cfg.min_features * 2:
                continue
            E, mask = cv2.findEssentialMat(pa, pb, np.eye(3), cv2.RANSAC, 0.999, 1.0 / self.focal)
            if E is None or E.shape != (3, 3):
                continue
            n_in, R_ba, _, _ = cv2.recoverPose(E, pa, pb, np.eye(3), mask=mask)
            if n_in < cfg.min_features * 2:
                continue
            # R_ba maps camera-a coordinates to camera b: R_{Cb Ca}; the IMU rotation R_{Ia Ib}
            R_vis = self.R_IC @ R_ba.T @ self.R_CI
            r = so3_log(between[k].dR.T @ R_vis)
            if np.linalg.norm(r) > cfg.max_visual_gyro_residual_rad:
                continue
            rows_J.append(between[k].J_R_bg)
            rows_r.append(r)
        if len(rows_J) < 2:
            return None
        dbg = np.linalg.lstsq(np.concatenate(rows_J), np.concatenate(rows_r), rcond=None)[0]
        return bg0 + dbg

    def _select_features(self, keyframes: list) -> tuple[np.ndarray, np.ndarray]:
        """Feature ids used and observations as rows (keyframe index, feature index, x, y)."""
        cfg = self.config
        counts: dict[int, int] = {}
        for _, ids, _, _ in keyframes:
            for i in ids.tolist():
                counts[i] = counts.get(i, 0) + 1
        eligible = [(-c, i) for i, c in counts.items() if c >= cfg.min_feature_observations]
        eligible.sort()
        chosen = np.array([i for _, i in eligible[: cfg.max_features]], dtype=np.int64)
        index = {int(i): n for n, i in enumerate(chosen)}
        rows = []
        for k, (_, ids, _, xy) in enumerate(keyframes):
            for j, i in enumerate(ids.tolist()):
                n = index.get(i)
                if n is not None and np.all(np.isfinite(xy[j])):
                    rows.append((k, n, xy[j, 0], xy[j, 1]))
        obs = np.array(rows, dtype=np.float64).reshape(-1, 4)
        return chosen, obs

    def _median_parallax_deg(self, obs: np.ndarray, R_0k: np.ndarray) -> float:
        """Median over features of the angle between first and last bearings after removing rotation."""
        angles = []
        for n in np.unique(obs[:, 1]):
            rows = obs[obs[:, 1] == n]
            ka, kb = int(rows[0, 0]), int(rows[-1, 0])
            ba_ = np.array([rows[0, 2], rows[0, 3], 1.0])
            bb_ = np.array([rows[-1, 2], rows[-1, 3], 1.0])
            # bearing of view a expressed in camera b: R_CbCa = R_CI R_0b^T R_0a R_IC
            rot = self.R_CI @ R_0k[kb].T @ R_0k[ka] @ self.R_IC @ ba_
            c = np.cross(rot, bb_)
            angles.append(np.degrees(np.arctan2(np.linalg.norm(c), float(rot @ bb_))))
        return float(np.median(angles)) if angles else 0.0

    def solve_linear(
        self, obs: np.ndarray, n_feat: int, R_0k: np.ndarray, dt_0k: np.ndarray, dp_0k: np.ndarray
    ) -> LinearSolution:
        """Features, v0 and g (|g| = g0) in I0 from observations (rows k, feature, x, y) and preintegration.

        Each feature is eliminated from the normal equations by its own 3x3 block (a Schur
        complement), then v0; features whose block is ill-conditioned (eigenvalue ratio above
        max_feature_condition: no depth information) are left out and get NaN positions.
        ``condition`` is the eigenvalue ratio of the reduced velocity block (inf if too few features).
        """
        cfg = self.config
        k = obs[:, 0].astype(int)
        f = obs[:, 1].astype(int)
        n_obs = obs.shape[0]
        H = np.zeros((n_obs, 2, 3))
        H[:, 0, 0] = 1.0
        H[:, 1, 1] = 1.0
        H[:, 0, 2] = -obs[:, 2]
        H[:, 1, 2] = -obs[:, 3]
        J_f = H @ (self.R_CI[None] @ np.transpose(R_0k[k], (0, 2, 1)))  # (n, 2, 3): H R_CI R_0k^T
        dt = dt_0k[k][:, None, None]
        J_z = np.concatenate([-J_f * dt, -0.5 * J_f * dt**2], axis=2)  # (n, 2, 6): [v0, g]
        rhs = np.einsum("nij,nj->ni", J_f, dp_0k[k]) - H @ self.p_CI
        # per-feature normal blocks
        F_ff = np.zeros((n_feat, 3, 3))
        F_fz = np.zeros((n_feat, 3, 6))
        b_f = np.zeros((n_feat, 3))
        np.add.at(F_ff, f, np.einsum("nri,nrj->nij", J_f, J_f))
        np.add.at(F_fz, f, np.einsum("nri,nrj->nij", J_f, J_z))
        np.add.at(b_f, f, np.einsum("nri,nr->ni", J_f, rhs))
        ev = np.linalg.eigvalsh(F_ff)
        good = ev[:, 0] > ev[:, 2] / cfg.max_feature_condition
        p_f = np.full((n_feat, 3), np.nan)
        if good.sum() < cfg.min_features:
            return LinearSolution(np.zeros(3), np.zeros(3), p_f, float("inf"), float("inf"), int(good.sum()))
        keep_obs = good[f]
        Z = np.einsum("nri,nrj->ij", J_z[keep_obs], J_z[keep_obs])
        b_z = np.einsum("nri,nr->i", J_z[keep_obs], rhs[keep_obs])
        F_inv = np.linalg.inv(F_ff[good])
        S = Z - np.einsum("fia,fij,fjb->ab", F_fz[good], F_inv, F_fz[good])
        sv = b_z - np.einsum("fia,fij,fj->a", F_fz[good], F_inv, b_f[good])
        S_vv, S_vg, S_gg = S[:3, :3], S[:3, 3:], S[3:, 3:]
        e_v = np.linalg.eigvalsh(S_vv)
        condition = float(e_v[2] / e_v[0]) if e_v[0] > 0 else float("inf")
        if not np.isfinite(condition):
            return LinearSolution(np.zeros(3), np.zeros(3), p_f, float("inf"), condition, int(good.sum()))
        S_vv_inv = np.linalg.inv(S_vv)
        M = S_gg - S_vg.T @ S_vv_inv @ S_vg
        m = sv[3:] - S_vg.T @ S_vv_inv @ sv[:3]
        g = min_quadratic_on_sphere(M, m, cfg.gravity_mag)
        v0 = S_vv_inv @ (sv[:3] - S_vg @ g)
        z = np.concatenate([v0, g])
        p_f[good] = np.einsum("fij,fj->fi", F_inv, b_f[good] - F_fz[good] @ z)
        r = np.einsum("nij,nj->ni", J_f, p_f[f]) + J_z @ z - rhs
        cost = float(np.sum(r[keep_obs] ** 2))
        return LinearSolution(
            v_I0=v0, g_I0=g, p_f=p_f, cost=cost, condition=condition, n_good=int(good.sum())
        )


class _Refinement:
    """Nonlinear least squares over keyframe states, bias corrections and features."""

    def __init__(
        self,
        owner: DynamicInitializer,
        obs: np.ndarray,
        between: list,
        g_O: np.ndarray,
        bg0: np.ndarray,
        ba0: np.ndarray,
    ) -> None:
        cfg = owner.config
        self.o = owner
        self.obs_k = obs[:, 0].astype(int)
        self.obs_f = obs[:, 1].astype(int)
        self.obs_xy = obs[:, 2:4]
        self.between = between
        self.g_O = g_O
        self.bg0, self.ba0 = bg0, ba0
        self.n_kf = len(between) + 1
        self.n_feat = int(self.obs_f.max()) + 1
        self.w_px = owner.focal / cfg.sigma_px
        # whitening of each preintegration residual [r_R, r_v, r_p]
        self.sqrt_info = []
        for p in between:
            cov = p.cov + np.eye(9) * 1e-12
            L = np.linalg.cholesky(cov)
            self.sqrt_info.append(np.linalg.inv(L))
        self.cfg = cfg

    # parameter layout: [theta_k, p_k, v_k] * K, dbg, dba, features
    def _unpack(self, x: np.ndarray) -> tuple:
        K = self.n_kf
        st = x[: 9 * K].reshape(K, 9)
        dbg = x[9 * K : 9 * K + 3]
        dba = x[9 * K + 3 : 9 * K + 6]
        feats = x[9 * K + 6 :].reshape(-1, 3)
        R = self.R_hat @ so3_exp(st[:, 0:3])
        return R, st[:, 3:6], st[:, 6:9], dbg, dba, feats

    def residuals(self, x: np.ndarray) -> np.ndarray:
        o = self.o
        R, p, v, dbg, dba, feats = self._unpack(x)
        k, f = self.obs_k, self.obs_f
        p_I = np.einsum("nji,nj->ni", R[k], feats[f] - p[k])
        p_C = p_I @ o.R_CI.T + o.p_CI
        z = np.where(np.abs(p_C[:, 2]) > 1e-6, p_C[:, 2], 1e-6)
        r_proj = ((p_C[:, :2] / z[:, None]) - self.obs_xy) * self.w_px
        out = [r_proj.ravel()]
        g = self.g_O
        for j, pre in enumerate(self.between):
            dR, dv, dp = pre.corrected(dbg, dba)
            dt = pre.dt
            Rt = R[j].T
            r_R = so3_log(dR.T @ Rt @ R[j + 1])
            r_v = Rt @ (v[j + 1] - v[j] - g * dt) - dv
            r_p = Rt @ (p[j + 1] - p[j] - v[j] * dt - 0.5 * g * dt * dt) - dp
            out.append(self.sqrt_info[j] @ np.concatenate([r_R, r_v, r_p]))
        out.append(dbg / self.cfg.sigma_bg_prior)
        out.append(dba / self.cfg.sigma_ba_prior)
        # gauge: first position and yaw (rotation about O's z) stay where the linear solve put them
        out.append((p[0] - self.p0_hat) / 1e-4)
        out.append(np.array([(self.R_hat[0] @ x[0:3])[2] / 1e-4]))
        return np.concatenate(out)

    def sparsity(self) -> scipy.sparse.lil_matrix:
        K, F = self.n_kf, self.n_feat
        n_obs = self.obs_k.size
        n_res = 2 * n_obs + 9 * (K - 1) + 6 + 4
        n_par = 9 * K + 6 + 3 * F
        S = scipy.sparse.lil_matrix((n_res, n_par), dtype=int)
        for i in range(n_obs):
            kk, ff = self.obs_k[i], self.obs_f[i]
            for r in (2 * i, 2 * i + 1):
                S[r, 9 * kk : 9 * kk + 6] = 1
                S[r, 9 * K + 6 + 3 * ff : 9 * K + 9 + 3 * ff] = 1
        base = 2 * n_obs
        for j in range(K - 1):
            rows = slice(base + 9 * j, base + 9 * j + 9)
            S[rows, 9 * j : 9 * j + 18] = 1
            S[rows, 9 * K : 9 * K + 6] = 1
        base += 9 * (K - 1)
        S[base : base + 6, 9 * K : 9 * K + 6] = 1
        S[base + 6 : base + 9, 3:6] = 1
        S[base + 9, 0:3] = 1
        return S

    def run(self, R_k: np.ndarray, p_k: np.ndarray, v_k: np.ndarray, p_f: np.ndarray) -> tuple | None:
        K = self.n_kf
        self.R_hat = R_k.copy()
        self.p0_hat = p_k[0].copy()
        x0 = np.concatenate(
            [np.concatenate([np.zeros((K, 3)), p_k, v_k], axis=1).ravel(), np.zeros(6), p_f.ravel()]
        )
        S = self.sparsity()
        nfev = 0
        x = x0
        if self.cfg.mle_max_iterations > 0:
            sol = scipy.optimize.least_squares(
                self.residuals,
                x0,
                jac_sparsity=S,
                method="trf",
                max_nfev=self.cfg.mle_max_iterations,
                x_scale="jac",
                ftol=self.cfg.mle_tolerance,
                xtol=self.cfg.mle_tolerance,
            )
            x, nfev = sol.x, int(sol.nfev)
            if not np.all(np.isfinite(x)):
                return None
        # Jacobian at the solution, re-centred so theta is a local perturbation of the final rotations
        R, p, v, dbg, dba, feats = self._unpack(x)
        self.R_hat = R
        xc = x.copy()
        xc[: 9 * K].reshape(K, 9)[:, 0:3] = 0.0
        J = _sparse_fd_jacobian(self.residuals, xc, S)
        r = self.residuals(xc)
        n_proj = 2 * self.obs_k.size
        rms_px = float(np.sqrt(np.mean((r[:n_proj] / self.w_px * self.o.focal) ** 2)))
        info = (J.T @ J).toarray()
        try:
            cov_all = np.linalg.inv(info + np.eye(info.shape[0]) * 1e-12 * np.trace(info) / info.shape[0])
        except np.linalg.LinAlgError:
            return None  # singular information: reported as a failed refinement
        idx = np.r_[9 * (K - 1) : 9 * K, 9 * K : 9 * K + 6]
        cov = cov_all[np.ix_(idx, idx)]
        c = self.cfg
        infl = np.sqrt(
            np.repeat([c.inflation_theta, c.inflation_p, c.inflation_v, c.inflation_bg, c.inflation_ba], 3)
        )
        cov = infl[:, None] * cov * infl[None, :]
        cov = 0.5 * (cov + cov.T)
        if not (np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0)):
            return None
        return R, p, v, self.bg0 + dbg, self.ba0 + dba, cov, rms_px, nfev


def _sparse_fd_jacobian(
    fun, x: np.ndarray, S: scipy.sparse.spmatrix, step: float = 1e-7
) -> scipy.sparse.csr_matrix:
    """Central finite-difference Jacobian with the given sparsity, columns grouped greedily."""
    S = scipy.sparse.csc_matrix(S)
    n = x.size
    groups = _group_columns(S)
    rows_all, cols_all, vals_all = [], [], []
    for gidx in np.unique(groups):
        cols = np.flatnonzero(groups == gidx)
        h = step * np.maximum(1.0, np.abs(x[cols]))
        xp = x.copy()
        xm = x.copy()
        xp[cols] += h
        xm[cols] -= h
        diff = fun(xp) - fun(xm)
        for c, hc in zip(cols, h, strict=True):
            rr = S.indices[S.indptr[c] : S.indptr[c + 1]]
            rows_all.append(rr)
            cols_all.append(np.full(rr.size, c))
            vals_all.append(diff[rr] / (2.0 * hc))
    return scipy.sparse.csr_matrix(
        (np.concatenate(vals_all), (np.concatenate(rows_all), np.concatenate(cols_all))),
        shape=(S.shape[0], n),
    )


def _group_columns(S: scipy.sparse.csc_matrix) -> np.ndarray:
    """Greedy grouping of columns that share no row (one finite difference per group)."""
    n_rows, n = S.shape
    groups = np.full(n, -1, dtype=int)
    used: list[np.ndarray] = []
    for c in range(n):
        rr = S.indices[S.indptr[c] : S.indptr[c + 1]]
        for gi, mask in enumerate(used):
            if not mask[rr].any():
                mask[rr] = True
                groups[c] = gi
                break
        else:
            mask = np.zeros(n_rows, dtype=bool)
            mask[rr] = True
            used.append(mask)
            groups[c] = len(used) - 1
    return groups
