"""The emulated DA3: a `DepthModel` fed with simulator ground truth and DA3's error modes.

    model = EmulatedDA3(ground_truth, K_rect, width, height, preset="base", seed=0)
    pred = model.predict(frames)             # start-up: up-to-scale depth, relative poses, intrinsics
    pred = model.predict(frames, K, T_CW)    # mapping: conditioned on metric poses, metric depth

The frames' timestamps select the ground-truth views (the pixels themselves are not read). What
the outputs are made of, per call:
  * unconditioned: truth depth with dense errors (depth_errors), times a random global scale;
    relative poses = true relative poses with sampled rotation, direction, length and floor
    errors (pose_errors); intrinsics with a focal error. Never exact.
  * conditioned: the depth the images imply when the model trusts the INPUT poses (conditioning),
    with the smaller conditioned dense errors and a window scale error; the input poses and K are
    returned, and the depth is divided by the Umeyama scale between the input camera centres and
    the model's own normalised cameras, as the ONNX wrapper does.
The ground truth only plays the role of the images: no output is more accurate than the error
model says. Each call draws from its own generator seeded by (seed, call index).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np

from models.depth_model import DepthPrediction
from models.emulated_da3.conditioning import (
    MIN_CENTRE_SPREAD_M,
    camera_centres,
    conditioned_depth,
    median_consecutive_baseline,
    model_camera_centres,
    pose_normalisation_distance,
    true_to_input_similarity,
    umeyama,
)
from models.emulated_da3.depth_errors import DenseErrorLevels, confidence, corrupt_view
from models.emulated_da3.groundtruth import GroundTruthSource, GroundTruthView, check_view
from models.emulated_da3.params import EmulatorParams, make_params
from models.emulated_da3.pose_errors import predicted_intrinsics, predicted_relative_poses
from runtime.errors import DataError
from runtime.events import Frame

MIN_VIEWS, MAX_VIEWS = 2, 8
"""Views per call (the DA3 graph's dynamic range)."""

BACKEND = "emulated-da3"
#: Rendered views kept for reuse (consecutive mapping windows share frames).
VIEW_CACHE_SIZE = 16
#: Conditioned depths below this fraction of the window's median depth are clamped (a wrong input
#: pose put the point behind the camera; DA3's depth is exp(.) > 0).
MIN_DEPTH_FRAC = 0.01


class EmulatedDA3:
    """Emulated Depth Anything 3 (`DepthModel`) for simulated recordings.

    Args:
        ground_truth: renders true views (`GroundTruthSource`), e.g. the simulator's.
        K_rect: (3,3) intrinsics of the rectified pinhole view at the camera resolution.
        width, height: camera resolution (pixels); frames must have this size.
        preset: "small", "base" or "large", or "<size>_upper" with the upper-bound pose errors
            (PRESETS.md).
        seed: seed of the error draws (call k uses the generator seeded by (seed, k)).
        **overrides: any `EmulatorParams` field, e.g. noise_sigma=0.0.

    Raises:
        ConfigError: unknown preset or parameter, invalid value.
        DataError: K_rect not a (3,3) finite pinhole matrix, non-positive size.
    """

    def __init__(
        self,
        ground_truth: GroundTruthSource,
        K_rect: np.ndarray,
        width: int,
        height: int,
        preset: str = "base",
        seed: int = 0,
        **overrides: object,
    ) -> None:
        K = np.asarray(K_rect, dtype=np.float64)
        if K.shape != (3, 3) or not np.isfinite(K).all() or K[0, 0] <= 0 or K[1, 1] <= 0:
            raise DataError(
                f"K_rect must be a finite (3,3) pinhole matrix with positive focal lengths, got {K}"
            )
        if int(width) <= 0 or int(height) <= 0:
            raise DataError(f"image size must be positive, got {width}x{height}")
        self.ground_truth = ground_truth
        #: (3,3) rectified pinhole intrinsics at the camera resolution.
        self.K_rect = K
        self.width, self.height = int(width), int(height)
        self.preset = preset
        self.seed = int(seed)
        self.params: EmulatorParams = make_params(preset, **overrides)
        self.calls = 0
        #: What the last call drew and derived from the truth (far-range start, flying-pixel and
        #: edge-band counts, window scale errors...). For evaluation only: it is not part of the
        #: DepthPrediction, because the real model could not report it.
        self.last_diagnostics: dict = {}
        self._cache: OrderedDict[int, GroundTruthView] = OrderedDict()

    # ------------------------------------------------------------------ inputs
    def _view(self, t_ns: int) -> GroundTruthView:
        if t_ns in self._cache:
            self._cache.move_to_end(t_ns)
            return self._cache[t_ns]
        view = self.ground_truth.render_view(t_ns, self.K_rect, self.width, self.height)
        check_view(view, t_ns, self.width, self.height)
        self._cache[t_ns] = view
        if len(self._cache) > VIEW_CACHE_SIZE:
            self._cache.popitem(last=False)
        return view

    def _check_frames(self, frames: Sequence[Frame]) -> int:
        n = len(frames)
        if not MIN_VIEWS <= n <= MAX_VIEWS:
            raise DataError(f"DA3 takes {MIN_VIEWS}..{MAX_VIEWS} frames per call, got {n}")
        for i, f in enumerate(frames):
            shape = np.shape(f.image)
            if shape[:2] != (self.height, self.width):
                raise DataError(
                    f"frame {i} (t_ns={f.t_ns}) is {shape}, the camera gives {self.height}x{self.width}"
                )
        return n

    @staticmethod
    def _check_conditioning(n: int, K: np.ndarray, T_CW: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        K = np.asarray(K, dtype=np.float64)
        T_CW = np.asarray(T_CW, dtype=np.float64)
        if K.shape != (n, 3, 3) or T_CW.shape != (n, 4, 4):
            raise DataError(
                f"K must be ({n},3,3) and T_CW ({n},4,4) for {n} frames, got {K.shape} and {T_CW.shape}"
            )
        if not (np.isfinite(K).all() and np.isfinite(T_CW).all()):
            raise DataError("K or T_CW contains non-finite values")
        if (K[:, 0, 0] <= 0).any() or (K[:, 1, 1] <= 0).any():
            raise DataError("K must have positive focal lengths")
        R = T_CW[:, :3, :3]
        orth = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
        bad = np.flatnonzero(
            (orth > 1e-4) | (np.linalg.det(R) < 0) | (np.abs(T_CW[:, 3] - [0, 0, 0, 1]).max(1) > 1e-9)
        )
        if bad.size:
            raise DataError(
                f"T_CW[{int(bad[0])}] is not a rigid world-to-camera pose (rotation not orthonormal "
                f"or last row not [0 0 0 1])"
            )
        return K, T_CW

    def _baseline_terms(self, centres: np.ndarray) -> tuple[float, float]:
        """(median consecutive true baseline m, far-range start d_far m) of a window."""
        p = self.params
        b = median_consecutive_baseline(centres)
        return b, float(np.clip(p.far_baseline_factor * b, p.far_min_m, p.far_max_m))

    # ------------------------------------------------------------------ the DepthModel call
    def predict(
        self, frames: Sequence[Frame], K: np.ndarray | None = None, T_CW: np.ndarray | None = None
    ) -> DepthPrediction:
        """Emulate DA3 on 2..8 frames; pass both K (N,3,3) and T_CW (N,4,4, metric) to condition.

        Returns the `DepthPrediction` of the ONNX backend (depth, conf >= 1, T_CW, K, scale,
        fit_rmse_m, info). Unconditioned: depth and translations in one random scale, T_CW[0] = I,
        predicted K. Conditioned: metric depth, the input T_CW and K.

        Raises:
            DataError: wrong frame count or size, K/T_CW given alone, wrong shape or invalid values.
        """
        n = self._check_frames(frames)
        if (K is None) != (T_CW is None):
            raise DataError("pass both K and T_CW for the conditioned call, or neither")
        if K is not None:
            K, T_CW = self._check_conditioning(n, K, T_CW)
        t0 = time.perf_counter()
        rng = np.random.default_rng([self.seed, self.calls])
        info = {
            "backend": BACKEND,
            "emulated": True,
            "preset": self.preset,
            "seed": self.seed,
            "call_index": self.calls,
            "conditioned": K is not None,
        }
        self.calls += 1
        views = [self._view(int(f.t_ns)) for f in frames]
        if K is None:
            pred = self._unconditioned(rng, views, info)
        else:
            pred = self._conditioned(rng, views, K, T_CW, info)
        pred.info["latency_s"] = time.perf_counter() - t0
        return pred

    def _dense(
        self,
        rng: np.random.Generator,
        depth_model: list[np.ndarray],
        views: Sequence[GroundTruthView],
        levels: DenseErrorLevels,
        d_far: float,
    ) -> tuple[np.ndarray, np.ndarray, dict]:
        out, expected, n_fly, n_band = [], [], 0, 0
        for dm, v in zip(depth_model, views, strict=True):
            cv = corrupt_view(
                rng,
                dm,
                np.asarray(v.depth, np.float64),
                np.asarray(v.texture),
                np.asarray(v.reflective),
                np.asarray(v.dynamic),
                np.asarray(v.surface_id),
                self.params,
                levels,
                d_far,
            )
            out.append(cv.depth)
            expected.append(cv.expected_error)
            n_fly += int(cv.flying.sum())
            n_band += int(cv.band.sum())
        conf = confidence(rng, np.stack(expected), self.params)
        return np.stack(out), conf, {"flying_pixels": n_fly, "edge_band_pixels": n_band}

    def _unconditioned(
        self, rng: np.random.Generator, views: list[GroundTruthView], info: dict
    ) -> DepthPrediction:
        p = self.params
        n = len(views)
        T_WC = np.stack([np.asarray(v.T_WC, np.float64) for v in views])
        T_C0Ci = np.linalg.inv(T_WC[0]) @ T_WC
        depths = [np.asarray(v.depth, np.float64) for v in views]
        finite = np.concatenate([d[np.isfinite(d)] for d in depths])
        median_depth = float(np.median(finite)) if finite.size else p.far_min_m
        _, d_far = self._baseline_terms(T_WC[:, :3, 3])

        # the arbitrary output scale: window normalised to unit mean camera-0 point distance, jittered
        g = np.exp(rng.normal(0.0, p.global_log_scale_sigma)) / self._mean_point_distance(depths, T_C0Ci)

        dyn = np.array([float(np.mean(v.dynamic)) for v in views])
        gain = 1.0 + p.dynamic_pose_gain * 0.5 * (dyn[0] + dyn)
        T_pred = predicted_relative_poses(rng, T_C0Ci, p, median_depth, gain)
        T_pred[:, :3, 3] *= g
        T_CW = np.linalg.inv(T_pred)
        T_CW[0] = np.eye(4)
        K_pred = predicted_intrinsics(rng, self.K_rect, n, p)

        levels = DenseErrorLevels(p.image_log_scale_sigma, p.field_sigma, p.noise_sigma)
        depth, conf, extra = self._dense(rng, depths, views, levels, d_far)
        self.last_diagnostics = {**extra, "d_far_m": d_far, "global_scale": float(g)}
        return DepthPrediction((depth * g).astype(np.float32), conf, T_CW, K_pred, 1.0, 0.0, info)

    def _mean_point_distance(self, depths: list[np.ndarray], T_C0Ci: np.ndarray, stride: int = 4) -> float:
        """Mean distance (m) of the window's visible points from camera 0 (on a pixel grid)."""
        Kinv = np.linalg.inv(self.K_rect)
        u, v = np.meshgrid(
            np.arange(0, self.width, stride, dtype=np.float64),
            np.arange(0, self.height, stride, dtype=np.float64),
        )
        rays = np.stack([u, v, np.ones_like(u)], -1) @ Kinv.T
        dist = []
        for d, T in zip(depths, T_C0Ci, strict=True):
            ds = d[::stride, ::stride]
            m = np.isfinite(ds)
            X = (rays[m] * ds[m][:, None]) @ T[:3, :3].T + T[:3, 3]
            dist.append(np.linalg.norm(X, axis=1))
        allx = np.concatenate(dist)
        return float(allx.mean()) if allx.size else 1.0

    def _conditioned(
        self,
        rng: np.random.Generator,
        views: list[GroundTruthView],
        K: np.ndarray,
        T_CW: np.ndarray,
        info: dict,
    ) -> DepthPrediction:
        p = self.params
        n = len(views)
        T_WC_true = np.stack([np.asarray(v.T_WC, np.float64) for v in views])
        baseline, d_far = self._baseline_terms(T_WC_true[:, :3, 3])

        # geometry the images imply once the model trusts the input poses
        S, observable = true_to_input_similarity(
            T_WC_true, T_CW, float(np.exp(rng.normal(0.0, p.mono_log_scale_sigma)))
        )
        c_model = model_camera_centres(T_WC_true, T_CW, S, p.cond_image_weight)
        depths = []
        for i, v in enumerate(views):
            d = conditioned_depth(
                np.asarray(v.depth, np.float64), self.K_rect, T_WC_true[i], S, T_CW[i, :3, :3], c_model[i]
            )
            # a wrong input focal length rescales the triangulated depth
            d *= np.sqrt(K[i, 0, 0] * K[i, 1, 1] / (self.K_rect[0, 0] * self.K_rect[1, 1]))
            depths.append(d)
        finite = np.concatenate([d[np.isfinite(d)] for d in depths])
        pos = finite[finite > 0]
        min_depth = MIN_DEPTH_FRAC * (float(np.median(pos)) if pos.size else 1.0)
        clamped = 0
        for d in depths:
            bad = np.isfinite(d) & (d < min_depth)
            clamped += int(bad.sum())
            d[bad] = min_depth

        # dense errors: conditioned levels, moved back towards unconditioned on short baselines
        levels = DenseErrorLevels(p.image_log_scale_sigma_cond, p.field_sigma_cond, p.noise_sigma)
        if baseline < p.small_baseline_m:
            keep = p.small_baseline_gain_factor
            levels = DenseErrorLevels(
                p.image_log_scale_sigma_cond
                + (1 - keep) * (p.image_log_scale_sigma - p.image_log_scale_sigma_cond),
                p.field_sigma_cond + (1 - keep) * (p.field_sigma - p.field_sigma_cond),
                p.noise_sigma,
            )
        depth, conf, extra = self._dense(rng, depths, views, levels, d_far)

        # the model's own cameras in DA3's normalised frame (camera 0 at the origin), with its
        # camera-scale error (outliers = conditioning failures) and centre noise
        d_norm = pose_normalisation_distance(T_CW)
        c_in = camera_centres(T_CW)
        outlier = rng.random() < p.window_outlier_prob
        w_cam = float(rng.choice([-1.0, 1.0]) * rng.uniform(*p.window_outlier_range)) if outlier else 0.0
        r_depth = float(rng.normal(0.0, p.window_log_scale_sigma_cond))
        median_depth = float(np.median(finite)) if finite.size else 1.0
        sigma_c = np.hypot(p.cond_centre_noise_frac, p.centre_floor_frac * median_depth / d_norm)
        c_pred = np.exp(w_cam) * (c_model - c_model[0]) @ T_CW[0, :3, :3].T / d_norm
        c_pred[1:] += rng.normal(0.0, sigma_c, size=(n - 1, 3))

        # the wrapper: Umeyama from the input metric centres onto the predicted ones
        sim, rmse_pred, spread = umeyama(c_in, c_pred)
        if spread >= MIN_CENTRE_SPREAD_M and sim.s > 0:
            s, rmse, source = sim.s, rmse_pred / sim.s, "sim3"
        else:
            s = 1.0 / d_norm
            rmse = (
                float(
                    np.sqrt(
                        (
                            np.linalg.norm(c_pred - (c_in - c_in[0]) @ T_CW[0, :3, :3].T * s, axis=1) ** 2
                        ).mean()
                    )
                )
                / s
            )
            source = "median_distance_fallback"
        internal = depth * np.exp(r_depth) / d_norm
        info.update(
            scale_source=source, pose_norm_distance_m=d_norm, log_scale_normalised=float(np.log(s * d_norm))
        )
        self.last_diagnostics = {
            **extra,
            "d_far_m": d_far,
            "clamped_pixels": clamped,
            "similarity_observable": observable,
            "window_log_scale_depth": r_depth,
            "window_log_scale_cameras": w_cam,
        }
        return DepthPrediction(
            (internal / s).astype(np.float32), conf, T_CW.copy(), K.copy(), float(s), float(rmse), info
        )
