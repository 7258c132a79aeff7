"""XFeat keypoints and descriptors from the backbone ONNX graph, with numpy post-processing.

Post-processing follows the XFeat paper's sparse pipeline: softmax over the 65 cell logits, the 64
keypoint bins unfolded to a full-resolution heatmap, 5x5 non-maximum suppression above a
threshold, score = heatmap x reliability (bilinear), top-k, descriptors sampled bicubically from
the 1/8 feature map and L2-normalised. Images are resized to multiples of 32 first (as upstream)
and keypoints mapped back.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from models.matcher.contract import CELL, check_xfeat_signature
from models.matcher.features import Features, pyramid_scales
from models.onnx_file import require_file
from models.providers import create_session, quiet_run_options
from runtime.errors import DataError, ModelError

#: the backbone graph committed with DAVIO (Apache-2.0, see models/onnx/NOTICE)
DEFAULT_XFEAT_PATH = Path(__file__).resolve().parents[1] / "onnx" / "xfeat_backbone.onnx"


def _cubic_weights(t: np.ndarray, a: float = -0.75) -> np.ndarray:
    """(N, 4) cubic-convolution weights (Keys, a = -0.75 as torch/OpenCV) for offsets -1, 0, 1, 2."""
    d = np.stack([1 + t, t, 1 - t, 2 - t], axis=-1)
    near = ((a + 2) * d - (a + 3)) * d * d + 1
    far = ((a * d - 5 * a) * d + 8 * a) * d - 4 * a
    return np.where(d <= 1, near, far)


def sample_bicubic(fmap: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bicubic samples of fmap (C, h, w) at map coordinates (u, v) (pixel centres at integers),
    zeros outside; returns (N, C)."""
    C, h, w = fmap.shape
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    wu, wv = _cubic_weights(u - u0), _cubic_weights(v - v0)
    xs = u0[:, None] + np.arange(-1, 3)
    ys = v0[:, None] + np.arange(-1, 3)
    wu = np.where((xs >= 0) & (xs < w), wu, 0.0)
    wv = np.where((ys >= 0) & (ys < h), wv, 0.0)
    xs, ys = np.clip(xs, 0, w - 1), np.clip(ys, 0, h - 1)
    patch = fmap[:, ys[:, :, None], xs[:, None, :]]  # (C, N, 4, 4)
    return np.einsum("cnij,ni,nj->nc", patch, wv, wu).astype(np.float32)


def sample_bilinear(fmap: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples of fmap (C, h, w) at map coordinates (u, v), zeros outside; (N, C)."""
    C, h, w = fmap.shape
    u0, v0 = np.floor(u).astype(np.int64), np.floor(v).astype(np.int64)
    fu, fv = u - u0, v - v0
    out = np.zeros((len(u), C), np.float64)
    for dy, wy in ((0, 1 - fv), (1, fv)):
        for dx, wx in ((0, 1 - fu), (1, fu)):
            x, y = u0 + dx, v0 + dy
            ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
            out += (wx * wy * ok)[:, None] * fmap[:, np.clip(y, 0, h - 1), np.clip(x, 0, w - 1)].T
    return out.astype(np.float32)


def logits_to_heatmap(logits: np.ndarray) -> np.ndarray:
    """(65, h, w) cell logits -> (8h, 8w) keypoint probability map (the 'no keypoint' bin dropped)."""
    z = logits - logits.max(axis=0, keepdims=True)
    p = np.exp(z)
    p = p[: CELL * CELL] / p.sum(axis=0, keepdims=True)
    h, w = logits.shape[1:]
    return p.reshape(CELL, CELL, h, w).transpose(2, 0, 3, 1).reshape(h * CELL, w * CELL)


class XFeatDetector:
    """XFeat sparse features through ONNX Runtime.

    Args:
        model_path: backbone graph (default: the committed models/onnx/xfeat_backbone.onnx).
        top_k: keypoints kept per image (1024-2048 on 2 CPU cores, notes/matcher.md).
        threshold: heatmap threshold of the NMS (upstream 0.05).
        nms_size: NMS window (pixels).
        providers, threads: ONNX Runtime session settings (models.providers).
    """

    def __init__(
        self,
        model_path: str | Path | None = None,
        top_k: int = 2048,
        threshold: float = 0.05,
        nms_size: int = 5,
        providers: Sequence[str] | None = None,
        threads: int | None = None,
    ) -> None:
        path = Path(model_path) if model_path is not None else DEFAULT_XFEAT_PATH
        require_file(path, missing=f"XFeat model not found: {path}. Export it with: "
                                   f"davio export-xfeat --out {path}")
        self.path = path
        self.session, self.session_info = create_session(
            path, providers, threads, contract=check_xfeat_signature
        )
        sig = [
            (a.name, a.type, [d if isinstance(d, int) else None for d in a.shape])
            for a in self.session.get_inputs()
        ]
        osig = [
            (a.name, a.type, [d if isinstance(d, int) else None for d in a.shape])
            for a in self.session.get_outputs()
        ]
        check_xfeat_signature(sig, osig, str(path))
        if top_k < 1 or nms_size < 1 or nms_size % 2 == 0:
            raise ModelError(f"top_k must be >= 1 and nms_size odd, got {top_k} and {nms_size}")
        self.top_k, self.threshold, self.nms_size = top_k, threshold, nms_size

    def backbone(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
        """Run the graph on a grey uint8 image; returns feats, logits, reliability (batch dropped)
        and the (sx, sy) factors mapping graph pixels back to image pixels."""
        img = np.asarray(image)
        if img.ndim == 3 and img.shape[2] == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if img.ndim != 2 or img.dtype != np.uint8 or min(img.shape) < 32:
            raise DataError(f"XFeat needs a grey uint8 image of at least 32x32, got {img.dtype} {img.shape}")
        H, W = img.shape
        H32, W32 = H // 32 * 32, W // 32 * 32
        x = img.astype(np.float32) / 255.0
        if (H32, W32) != (H, W):
            x = cv2.resize(x, (W32, H32), interpolation=cv2.INTER_LINEAR)
        try:
            feats, logits, rel = self.session.run(None, {"image": x[None, None]}, quiet_run_options())
        except Exception as exc:
            raise ModelError(f"{self.path}: inference failed ({type(exc).__name__}: {exc})") from exc
        return feats[0], logits[0], rel[0], W / W32, H / H32

    def detect(self, image: np.ndarray) -> Features:
        """Keypoints (u, v) in image pixels, scores and L2-normalised 64-D descriptors (top-k)."""
        return self._detect(image, self.top_k)

    def _detect(self, image: np.ndarray, top_k: int) -> Features:
        feats, logits, rel, sx, sy = self.backbone(image)
        size = (int(np.asarray(image).shape[1]), int(np.asarray(image).shape[0]))
        heat = logits_to_heatmap(logits)
        H, W = heat.shape
        local_max = cv2.dilate(heat, np.ones((self.nms_size, self.nms_size), np.uint8))
        ys, xs = np.nonzero((heat == local_max) & (heat > self.threshold))
        h, w = feats.shape[1:]
        # grid_sample(align_corners=False) convention of upstream: pixel x -> map x * w / (W - 1) - 0.5
        u, v = xs * (w / (W - 1)) - 0.5, ys * (h / (H - 1)) - 0.5
        scores = heat[ys, xs] * sample_bilinear(rel, u, v)[:, 0]
        order = np.argsort(-scores, kind="stable")[:top_k]
        xs, ys, u, v, scores = xs[order], ys[order], u[order], v[order], scores[order]
        desc = sample_bicubic(feats, u, v)
        desc /= np.maximum(np.linalg.norm(desc, axis=1, keepdims=True), 1e-12)
        kpts = np.stack([xs * sx, ys * sy], axis=1).astype(np.float32)
        return Features(kpts, scores.astype(np.float32), desc, size)

    def detect_pyramid(self, image: np.ndarray, scales: Sequence[float] = (1.0, 0.7, 0.5),
                       base: Features | None = None) -> Features:
        """Keypoints of an image pyramid, for matching across a change of scale (a revisit seen from
        nearer or farther away: XFeat's descriptors are not scale-invariant beyond about 1.4x).

        Level k is the image resized by scales[k] (area interpolation) and keeps
        round(top_k * scales[k]^2) keypoints (the same density per pixel); its keypoints are mapped back
        to full-resolution pixels and tagged with `Features.level` = k. Levels smaller than 32 px are
        left out; the full-resolution level is never left out (a too small image is a DataError).
        `base`: this image's single-scale features (`detect`), reused as level 0 instead of detecting again.
        """
        img = np.asarray(image)
        if img.ndim == 3 and img.shape[2] == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        try:
            sc = pyramid_scales(scales)
        except ValueError as exc:
            raise ModelError(str(exc)) from None
        H, W = img.shape[:2]
        parts: list[Features] = []
        for k, s in enumerate(sc):
            w, h = round(W * s), round(H * s)
            if k > 0 and min(w, h) < 32:
                break
            if k == 0 and base is not None:
                if tuple(base.image_size) != (W, H) or base.level is not None:
                    raise ModelError(f"base features of a {base.image_size} image (multi-level: "
                                     f"{base.level is not None}) do not fit level 0 of this {W}x{H} image")
                parts.append(replace(base, level=np.zeros(len(base), np.int8)))
                continue
            level_img = img if k == 0 else cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
            f = self._detect(level_img, max(1, round(self.top_k * s * s)))
            # pixel centres: (u' + 0.5) * W / w - 0.5 (Features' (0, 0) = centre of the top-left pixel)
            f.kpts = ((f.kpts + 0.5) * np.array([W / w, H / h], np.float32) - 0.5).astype(np.float32)
            f.level = np.full(len(f), k, np.int8)
            parts.append(f)
        return Features(
            np.concatenate([f.kpts for f in parts]).reshape(-1, 2),
            np.concatenate([f.scores for f in parts]),
            np.concatenate([f.desc for f in parts]),
            (int(W), int(H)),
            np.concatenate([f.level for f in parts]),
        )
