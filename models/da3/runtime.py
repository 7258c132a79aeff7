"""DA3 through ONNX Runtime: the `DepthModel` backend used on real data (DESIGN §4).

    model = OnnxDA3("da3_small_378x504.onnx", camera)
    pred = model.predict(frames)              # start-up: up-to-scale depth + relative poses
    pred = model.predict(frames, K, T_CW)     # mapping: conditioned on metric poses, metric depth

Depth and intrinsics are returned in the rectified pinhole view (`K_rect`) at the camera's
resolution, whatever the graph's fixed resolution is.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

from calib import CameraModel
from models.da3.contract import (
    FIXED_VIEWS_HINT,
    MAX_VIEWS,
    MIN_VIEWS,
    PRECISION_KEY,
    check_da3_signature,
    da3_resolution,
)
from models.da3.preprocess import (
    camera_centres,
    normalise_image,
    normalise_poses,
    resize_image,
    resize_matrix,
)
from models.da3.similarity import umeyama_sim3
from models.depth_model import DepthPrediction
from models.onnx_file import require_file
from models.providers import CUDA, create_session, quiet_run_options
from runtime.errors import DataError, ModelError
from runtime.events import Frame

log = logging.getLogger(__name__)

#: Below this spread of the input camera centres (metres) the similarity scale is not observable
#: and the fallback (normalised units x the median distance used to normalise) is used.
MIN_CENTRE_SPREAD_M = 1e-3


def export_hint(path: Path, camera: CameraModel | None = None) -> str:
    """The command that produces a missing DA3 graph (named in every 'model missing' error): the size
    the file's name says (e.g. da3_base_322x504.onnx), else Small; the resolution of the camera; fp16 when
    the name says so (da3_base_322x504_fp16.onnx, `davio export-da3 --precision fp16`'s default name)."""
    res = "378x504"
    if camera is not None:
        h, w = da3_resolution(camera.width, camera.height)
        res = f"{h}x{w}"
    words = re.split(r"[^a-z]+", Path(path).name.lower())
    size = next((s for s in ("small", "base", "large", "giant") if s in words), "small")
    precision = " --precision fp16" if "fp16" in re.split(r"[^a-z0-9]+", Path(path).name.lower()) else ""
    return (
        f"davio export-da3 --checkpoint PATH/TO/DA3-{size.upper()}/model.safetensors --size {size} "
        f"--res {res}{precision} --out {path}"
    )


def session_signature(sess) -> tuple[list, list]:
    """(inputs, outputs) of an ORT session as contract signatures."""

    def sig(args):
        return [(a.name, a.type, [d if isinstance(d, int) else None for d in a.shape]) for a in args]

    return sig(sess.get_inputs()), sig(sess.get_outputs())


class OnnxDA3:
    """DA3 ONNX graph (DA3 contract v1) wrapped as a `DepthModel`.

    Args:
        model_path: the exported graph (`davio export-da3`).
        camera: the calibrated camera the frames come from (undistorted to `K_rect`).
        providers: explicit ONNX Runtime providers, or None (CUDA when available, else CPU).
        threads: intra-op threads, or None for the default.

    Raises:
        ModelError: missing file (naming the export command), unloadable or wrong-contract graph.
    """

    def __init__(
        self,
        model_path: str | Path,
        camera: CameraModel,
        providers: Sequence[str] | None = None,
        threads: int | None = None,
        cuda_options: Mapping[str, str] | None = None,
    ) -> None:
        self.path = Path(model_path)
        require_file(self.path, missing=f"DA3 model not found: {self.path}. Export it once from the official "
                     f"checkpoint (Small or Base for commercial use) with: {export_hint(self.path, camera)}")
        # the contract is checked on the file before ONNX Runtime parses it, then on the session
        self.session, self.session_info = create_session(
            self.path, providers, threads, contract=check_da3_signature, cuda_options=cuda_options
        )
        inputs, outputs = session_signature(self.session)
        self.graph_hw = check_da3_signature(inputs, outputs, where=str(self.path))
        #: "fp16" for a graph exported with --precision fp16 (its backbone computes in float16), else "fp32"
        self.precision: str = self.session.get_modelmeta().custom_metadata_map.get(PRECISION_KEY, "fp32")
        self.session_info["precision"] = self.precision
        if self.precision == "fp16" and self.session_info["providers"][0] != CUDA:
            # measured on 16 CPU cores: DA3-Small fp16 1.91 s a 5-view call, fp32 0.89 s (BENCHMARKS.md)
            log.warning(
                "%s is an fp16 graph for GPUs; ONNX Runtime's CPU provider runs it at about half the "
                "speed of the fp32 graph: export `davio export-da3 --precision fp32` for CPU use",
                self.path.name,
            )
        n_dim = inputs[[name for name, _, _ in inputs].index("images")][2][1]
        #: the graph's fixed view count, or None when N is dynamic (the exported graphs: 2..8)
        self.graph_views: int | None = n_dim if isinstance(n_dim, int) and n_dim > 0 else None
        self.camera = camera
        self.cam_hw = (camera.height, camera.width)
        #: (3,3) rectified pinhole intrinsics at the camera resolution (the camera's own K).
        self.K_rect = camera.K.astype(np.float64)
        if camera.is_pinhole_rectified:
            self._maps = None
        else:
            self._maps = camera.undistortion_maps(self.K_rect, (camera.width, camera.height))
        self._A = resize_matrix(self.cam_hw, self.graph_hw)  # camera pixels -> graph pixels
        sx, sy = self._A[0, 0], self._A[1, 1]
        self.aspect_distortion = float(abs(sx / sy - 1.0))
        if self.aspect_distortion > 0.02:
            h, w = da3_resolution(camera.width, camera.height)
            log.warning(
                "DA3 graph %dx%d stretches the %dx%d camera by %.1f%%; a %dx%d graph fits it "
                "(davio export-da3 --res %dx%d)",
                *self.graph_hw,
                camera.width,
                camera.height,
                100 * self.aspect_distortion,
                h,
                w,
                h,
                w,
            )

    # ------------------------------------------------------------------ preparation
    def _images(self, frames: Sequence[Frame]) -> np.ndarray:
        out = np.empty((1, len(frames), 3, *self.graph_hw), dtype=np.float32)
        for i, f in enumerate(frames):
            img = np.asarray(f.image)
            if img.dtype != np.uint8 or img.shape[:2] != self.cam_hw:
                raise DataError(
                    f"frame {i} (t_ns={f.t_ns}) is {img.dtype} {img.shape}, the camera gives "
                    f"uint8 {self.cam_hw[0]}x{self.cam_hw[1]}"
                )
            if self._maps is not None:
                img = cv2.remap(
                    img, self._maps[0], self._maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
                )
            normalise_image(resize_image(img, self.graph_hw), out=out[0, i])
        return out

    def _check_frames(self, frames: Sequence[Frame]) -> int:
        n = len(frames)
        if not MIN_VIEWS <= n <= MAX_VIEWS:
            raise DataError(f"DA3 takes {MIN_VIEWS}..{MAX_VIEWS} frames per call, got {n}")
        if self.graph_views is not None and n != self.graph_views:
            raise DataError(f"{self.path.name} was exported for exactly {self.graph_views} views, got {n}: "
                            f"{FIXED_VIEWS_HINT}")
        return n

    def _run(self, images: np.ndarray, K: np.ndarray, E: np.ndarray, use_pose: bool) -> list[np.ndarray]:
        feeds = {
            "images": images,
            "intrinsics": K.astype(np.float32)[None],
            "extrinsics": E.astype(np.float32)[None],
            "use_pose": np.array([use_pose], dtype=bool),
        }
        try:
            outs = self.session.run(["depth", "conf", "pred_extrinsics", "pred_intrinsics"], feeds,
                                    quiet_run_options())
        except Exception as exc:
            text = str(exc)
            hint = ""
            # ONNX Runtime's arena past gpu_mem_limit ("Available memory of ... is smaller than requested
            # bytes", seen on an H100), its other allocation failures (on the CPU too), and CUDA's own
            if any(w in text.lower() for w in ("smaller than requested bytes", "failed to allocate",
                                                 "out of memory")):
                n = images.shape[1]
                if self.session_info["providers"][0] == CUDA:
                    hint = (f"; out of GPU memory at {n} views: raise or drop --gpu-mem-limit, free the "
                            "GPU, or use a smaller graph (DA3-Small; an --opset 23 export needs less)")
                else:
                    hint = (f"; out of memory at {n} views on the CPU: free memory, or use a smaller graph "
                            "(DA3-Small; an --opset 23 export needs about half)")
            raise ModelError(f"{self.path}: inference failed ({type(exc).__name__}: {text}){hint}") from exc
        self._check_outputs(outs, images.shape[1])
        return outs

    def _check_outputs(self, outs: list[np.ndarray], n: int) -> None:
        """The graph's run-time outputs against the contract: shapes, and finite values.

        Raises:
            ModelError: naming the output and what is wrong (a graph whose declared signature
                passes can still compute the wrong shapes, or overflow, e.g. a broken fp16 export).
        """
        h, w = self.graph_hw
        want = {"depth": (1, n, h, w), "conf": (1, n, h, w), "pred_extrinsics": (1, n, 3, 4),
                "pred_intrinsics": (1, n, 3, 3)}
        for (name, shape), arr in zip(want.items(), outs, strict=True):
            if tuple(arr.shape) != shape:
                raise ModelError(f"{self.path}: output {name} has shape {tuple(arr.shape)}, the DA3 "
                                 f"contract expects {shape} for {n} views")
            bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
            if bad:
                raise ModelError(f"{self.path}: output {name} has {bad} non-finite values out of "
                                 f"{arr.size} (a broken export or an overflow in reduced precision)")

    def warm_up(self, views: int | None = None) -> float:
        """One unconditioned call on synthetic frames, before the run starts; returns seconds.

        `views` defaults to the graph's fixed view count, else 5 (the start-up window).

        The first run of a session pays one-off costs (on the CUDA provider: device memory arena,
        cuDNN algorithm search; seconds on a laptop GPU) that must not land on the start-up call.
        Also checks at load time that the graph really runs and meets the contract at `views`.

        Raises:
            ModelError: the graph fails or breaks the contract on the warm-up call.
        """
        views = views or self.graph_views or 5
        # textured and different per view (a flat or repeated image could take degenerate paths in a real
        # network); fixed seed, so a warm-up failure is reproducible
        h, w = self.cam_hw
        tex = np.random.default_rng(0).integers(0, 256, (h, w + 8 * views), np.uint8)
        frames = [Frame(t_ns=i * 200_000_000, image=np.ascontiguousarray(tex[:, 8 * i : 8 * i + w]))
                  for i in range(views)]
        t0 = time.perf_counter()
        self._check_frames(frames)
        outs = self._run(self._images(frames), np.tile(np.eye(3), (views, 1, 1)),
                         np.tile(np.eye(4), (views, 1, 1)), False)
        if not np.any(outs[0] > 0):
            raise ModelError(f"{self.path}: output depth is not positive at any of its {outs[0].size} pixels "
                             "on the warm-up call: not a DA3 depth graph, or a broken export")
        low = int(np.count_nonzero(outs[1] <= 0))
        if low:     # the start-up weighs each depth by sqrt(conf): such a depth would not count
            raise ModelError(f"{self.path}: output conf is not positive at {low} of its {outs[1].size} "
                             "pixels on the warm-up call; the contract's confidence is >= 1 (DA3's "
                             "1 + exp(x)): a graph that returns log-confidence, or a broken export")
        return time.perf_counter() - t0

    def _to_camera(self, maps: np.ndarray) -> np.ndarray:
        """(N,h,w) graph-resolution maps -> (N,H,W) float32 at the camera resolution."""
        H, W = self.cam_hw
        out = np.empty((len(maps), H, W), dtype=np.float32)
        for m, o in zip(maps, out, strict=True):
            cv2.resize(np.asarray(m, dtype=np.float32), (W, H), dst=o, interpolation=cv2.INTER_LINEAR)
        return out

    # ------------------------------------------------------------------ the DepthModel call
    def predict(
        self, frames: Sequence[Frame], K: np.ndarray | None = None, T_CW: np.ndarray | None = None
    ) -> DepthPrediction:
        """Run DA3 on 2..8 frames; with K (N,3,3) and T_CW (N,4,4) the call is pose-conditioned.

        K are the rectified intrinsics at the camera resolution (normally `K_rect`), T_CW metric
        world-to-camera poses. Conditioned output: depth in metres (divided by the Sim(3) scale
        between input and predicted camera centres), T_CW = the predicted poses expressed in the
        input world, metric. Unconditioned output: up-to-scale depth, T_CW with world = camera 0.
        """
        n = self._check_frames(frames)
        if (K is None) != (T_CW is None):
            raise DataError("pass both K and T_CW for the conditioned call, or neither")
        t0 = time.perf_counter()
        images = self._images(frames)
        conditioned = K is not None
        d_norm = 1.0
        if conditioned:
            K = np.asarray(K, dtype=np.float64)
            T_CW = np.asarray(T_CW, dtype=np.float64)
            if K.shape != (n, 3, 3) or T_CW.shape != (n, 4, 4):
                raise DataError(f"K must be ({n},3,3) and T_CW ({n},4,4), got {K.shape} and {T_CW.shape}")
            if not (np.isfinite(K).all() and np.isfinite(T_CW).all()):
                raise DataError("K or T_CW contains non-finite values")
            E, d_norm = normalise_poses(T_CW)
            K_in = self._A @ K
        else:
            E, K_in = np.tile(np.eye(4), (n, 1, 1)), np.tile(np.eye(3), (n, 1, 1))
        depth, conf, pred_E, pred_K = self._run(images, K_in, E, conditioned)
        latency = time.perf_counter() - t0
        depth, conf, pred_E, pred_K = (
            depth[0],
            conf[0],
            pred_E[0].astype(np.float64),
            pred_K[0].astype(np.float64),
        )
        T_pred = np.tile(np.eye(4), (n, 1, 1))
        T_pred[:, :3, :] = pred_E
        info = {
            "backend": "onnx-da3",
            "model": str(self.path),
            "graph_hw": list(self.graph_hw),
            "latency_s": latency,
            "providers": self.session_info["providers"],
            "precision": self.precision,
            "conditioned": conditioned,
            "aspect_distortion": self.aspect_distortion,
        }
        if not conditioned:
            T_pred = T_pred @ np.linalg.inv(T_pred[0])  # world = camera 0 exactly (DA3's is close to it)
            A_inv = np.linalg.inv(self._A)
            K_out = np.tile(self.K_rect, (n, 1, 1))
            K_out[:, 0, 0] = pred_K[:, 0, 0] * A_inv[0, 0]
            K_out[:, 1, 1] = pred_K[:, 1, 1] * A_inv[1, 1]
            info["pred_intrinsics_graph"] = pred_K
            return DepthPrediction(
                self._to_camera(depth), self._to_camera(conf), T_pred, K_out, 1.0, 0.0, info
            )
        scale, rmse, T_out = self._metric_scale(T_CW, T_pred, d_norm, info)
        return DepthPrediction(
            self._to_camera(depth / scale), self._to_camera(conf), T_out, K.copy(), scale, rmse, info
        )

    def _metric_scale(
        self, T_CW: np.ndarray, T_pred: np.ndarray, d_norm: float, info: dict
    ) -> tuple[float, float, np.ndarray]:
        """Sim(3) between input (metric) and predicted camera centres -> (s, RMSE m, T_CW metric)."""
        c_in = camera_centres(T_CW)
        c_pred = camera_centres(T_pred)
        try:
            sim = umeyama_sim3(c_in, c_pred)
            ok = sim.spread_x >= MIN_CENTRE_SPREAD_M and sim.s > 0 and np.isfinite(sim.s)
        except ValueError:
            ok = False
        if ok:
            s, R, t = sim.s, sim.R, sim.t
            info["scale_source"] = "sim3"
            sv = np.linalg.svd(c_in - c_in.mean(0), compute_uv=False)
            if sv[1] < 1e-3 * sv[0]:
                # collinear centres leave the rotation about their line free: take it from the
                # predicted orientations (chordal mean of R_pred_i^T R_in_i); the scale is unaffected
                M = np.einsum("nji,njk->ik", T_pred[:, :3, :3], T_CW[:, :3, :3])
                U, _, Vt = np.linalg.svd(M)
                R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
                t = c_pred.mean(0) - s * R @ c_in.mean(0)
                info["scale_source"] = "sim3_collinear"
            res = c_pred - (s * c_in @ R.T + t)
            rmse = float(np.sqrt((res**2).sum(1).mean())) / s
        else:
            # the centres barely move: predicted units are the normalised ones, 1 unit = d_norm metres
            s = 1.0 / d_norm
            R = T_pred[0, :3, :3].T @ T_CW[0, :3, :3]
            t = T_pred[0, :3, :3].T @ (T_CW[0, :3, 3] * s - T_pred[0, :3, 3])
            res = c_pred - (s * c_in @ R.T + t)
            rmse = float(np.sqrt((res**2).sum(1).mean())) / s
            info["scale_source"] = "median_distance_fallback"
        # x_pred = s R x_W + t  =>  T_CW_metric = [R_p R | (R_p t + t_p) / s]
        T_out = np.tile(np.eye(4), (len(T_CW), 1, 1))
        T_out[:, :3, :3] = T_pred[:, :3, :3] @ R
        T_out[:, :3, 3] = (np.einsum("nij,j->ni", T_pred[:, :3, :3], t) + T_pred[:, :3, 3]) / s
        return float(s), float(rmse), T_out
