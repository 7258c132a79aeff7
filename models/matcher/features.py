"""Keypoint sets and matches exchanged by the matcher backends, and mutual nearest-neighbour matching."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Features:
    """Keypoints of one image.

    Attributes:
        kpts: (N, 2) float32 pixel positions (u, v), (0, 0) = centre of the top-left pixel.
        scores: (N,) float32 detection scores (higher is better).
        desc: (N, D) descriptors: float32 L2-normalised (XFeat) or uint8 packed bits (ORB).
        image_size: (width, height) of the image they come from, pixels.
    """

    kpts: np.ndarray
    scores: np.ndarray
    desc: np.ndarray
    image_size: tuple[int, int] = (0, 0)

    def __len__(self) -> int:
        return int(self.kpts.shape[0])


@dataclass
class Matches:
    """Correspondences between two images.

    Attributes:
        kpts_a, kpts_b: (N, 2) and (M, 2) all keypoints of image a and b (pixels).
        idx_a, idx_b: (K,) int64 indices of the matched keypoints: kpts_a[idx_a[k]] <-> kpts_b[idx_b[k]].
        scores: (K,) float32 match scores in [0, 1] (cosine similarity, or 1 - Hamming/256 for ORB).
    """

    kpts_a: np.ndarray
    kpts_b: np.ndarray
    idx_a: np.ndarray
    idx_b: np.ndarray
    scores: np.ndarray

    def __len__(self) -> int:
        return int(self.idx_a.shape[0])

    @property
    def points_a(self) -> np.ndarray:
        """(K, 2) matched positions in image a."""
        return self.kpts_a[self.idx_a]

    @property
    def points_b(self) -> np.ndarray:
        """(K, 2) matched positions in image b."""
        return self.kpts_b[self.idx_b]


def mutual_nearest_neighbours(
    desc_a: np.ndarray, desc_b: np.ndarray, min_cossim: float = -1.0, ratio: float = 1.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mutual nearest neighbours of L2-normalised descriptors by cosine similarity (two GEMMs).

    The second GEMM (b against a) replaces an argmax along axis 0, which is several times slower.

    Args:
        min_cossim: drop pairs whose cosine similarity is not above this.
        ratio: Lowe's ratio test on descriptor distances sqrt(2 - 2 cos): keep a pair only if its
            distance is below `ratio` times the distance to a's second-best neighbour (1 = off).

    Returns:
        (idx_a, idx_b, cosine similarity) of the kept mutual pairs.
    """
    empty = np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    if len(desc_a) == 0 or len(desc_b) == 0:
        return empty
    a = np.ascontiguousarray(desc_a, dtype=np.float32)
    b = np.ascontiguousarray(desc_b, dtype=np.float32)
    S = a @ b.T
    best_ab = np.argmax(S, axis=1)
    best_ba = np.argmax(b @ a.T, axis=1)
    idx_a = np.flatnonzero(best_ba[best_ab] == np.arange(len(a)))
    idx_b = best_ab[idx_a]
    sim = S[idx_a, idx_b]
    keep = sim > min_cossim
    if ratio < 1.0 and S.shape[1] >= 2:
        rows = S[idx_a]
        rows[np.arange(len(idx_a)), idx_b] = -np.inf
        second = rows.max(axis=1)
        d1 = np.sqrt(np.maximum(2.0 - 2.0 * sim, 0.0))
        d2 = np.sqrt(np.maximum(2.0 - 2.0 * second, 0.0))
        keep &= d1 < ratio * d2
    return idx_a[keep].astype(np.int64), idx_b[keep].astype(np.int64), sim[keep].astype(np.float32)
