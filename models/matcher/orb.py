"""OpenCV ORB features with brute-force Hamming cross-check matching: the fallback matcher."""

from __future__ import annotations

import cv2
import numpy as np

from models.matcher.features import Features
from runtime.errors import DataError


class OrbDetector:
    """ORB keypoints (FAST + rotated BRIEF, 8-level pyramid) on a grey uint8 image.

    Args:
        n_features: keypoints kept per image (1000-2000 on 2 cores, notes/matcher.md).
    """

    def __init__(self, n_features: int = 2000) -> None:
        self.orb = cv2.ORB_create(nfeatures=int(n_features))

    def detect(self, image: np.ndarray) -> Features:
        img = np.asarray(image)
        if img.ndim == 3 and img.shape[2] == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        if img.ndim != 2 or img.dtype != np.uint8:
            raise DataError(f"ORB needs a grey uint8 image, got {img.dtype} {img.shape}")
        kps, desc = self.orb.detectAndCompute(img, None)
        size = (int(img.shape[1]), int(img.shape[0]))
        if desc is None or not kps:
            empty = np.zeros((0, 2), np.float32), np.zeros(0, np.float32), np.zeros((0, 32), np.uint8)
            return Features(*empty, size)
        kpts = np.array([k.pt for k in kps], np.float32)
        scores = np.array([k.response for k in kps], np.float32)
        return Features(kpts, scores, desc, size)


def match_hamming(desc_a: np.ndarray, desc_b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mutual (cross-checked) nearest neighbours by Hamming distance; scores = 1 - distance / 256."""
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(desc_a, desc_b)
    idx_a = np.array([m.queryIdx for m in matches], np.int64)
    idx_b = np.array([m.trainIdx for m in matches], np.int64)
    scores = 1.0 - np.array([m.distance for m in matches], np.float32) / (8 * desc_a.shape[1])
    return idx_a, idx_b, scores
