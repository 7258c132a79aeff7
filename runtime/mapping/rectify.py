"""The mapper's image access: rectification of camera images to the depth model's pinhole view, and
nearest-pixel sampling of depth maps at keypoints."""
from __future__ import annotations

from typing import Any

import cv2
import numpy as np


def sample_at(image: np.ndarray, uv: np.ndarray, outside: Any = np.nan) -> np.ndarray:
    """Values of `image` (H,W) at the nearest pixels of (K,2) positions uv; `outside` beyond the image."""
    h, w = image.shape[:2]
    ij = np.round(np.asarray(uv, np.float64)).astype(np.int64).reshape(-1, 2)
    inside = (ij[:, 0] >= 0) & (ij[:, 0] < w) & (ij[:, 1] >= 0) & (ij[:, 1] < h)
    out = np.full(len(ij), outside, dtype=np.result_type(image.dtype, np.asarray(outside).dtype))
    out[inside] = image[ij[inside, 1], ij[inside, 0]]
    return out


class Rectifier:
    """Undistorts camera images to the pinhole view K_rect at the camera resolution (OpenCV remap
    maps built once per rig; pinhole, radial-tangential and equidistant models)."""

    def __init__(self, camera: Any, K_rect: np.ndarray) -> None:
        self.K = np.asarray(K_rect, np.float64)
        self.size = (int(camera.width), int(camera.height))
        self._maps = None if camera.is_pinhole_rectified and np.allclose(camera.K, self.K) \
            else camera.undistortion_maps(self.K, self.size)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        img = np.asarray(image)
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if self._maps is None:
            return img
        return cv2.remap(img, self._maps[0], self._maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
