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
        level: (N,) int8 image-pyramid level each keypoint was detected at (0 = full resolution;
            `XFeatDetector.detect_pyramid`), or None for single-scale features. Keypoints of every
            level are in full-resolution pixels; descriptors of different levels are matched level
            pair by level pair (`match_levels`).
    """

    kpts: np.ndarray
    scores: np.ndarray
    desc: np.ndarray
    image_size: tuple[int, int] = (0, 0)
    level: np.ndarray | None = None

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


def pyramid_scales(scales) -> tuple[float, ...]:
    """`scales` as a tuple of floats after checking it is an image pyramid: 1.0 first, then strictly
    decreasing finite scales above 0. Raises ValueError naming what is wrong."""
    sc = tuple(float(x) for x in scales)
    if (not sc or sc[0] != 1.0 or not all(np.isfinite(sc)) or sc[-1] <= 0.0
            or any(a <= b for a, b in zip(sc, sc[1:], strict=False))):
        raise ValueError(f"pyramid scales must start at 1.0 and decrease strictly within (0, 1], got "
                         f"{list(sc)}")
    return sc


def _levels(f: Features) -> np.ndarray:
    return np.zeros(len(f), np.int64) if f.level is None else np.asarray(f.level, np.int64)


def match_levels(
    fa: Features, fb: Features, min_cossim: float = -1.0, ratio: float = 1.0, dedupe_px: float = 3.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mutual nearest neighbours of multi-level (pyramid) features, level pair by level pair.

    Each pair of pyramid levels (one of a, one of b) is matched on its own with
    `mutual_nearest_neighbours` (so a keypoint's second-best neighbour, for the ratio test, is never
    the same point seen at another level); the union is then made one-to-one, best cosine first:
    each keypoint is used once, and a pair whose positions lie within `dedupe_px` of an already kept
    pair's in both images (the same point found at two levels) is dropped.

    Returns:
        (idx_a, idx_b, cosine similarity) into fa's and fb's keypoints, best first.
    """
    la, lb = _levels(fa), _levels(fb)
    ia_all, ib_all, s_all = [], [], []
    for va in np.unique(la):
        sel_a = np.flatnonzero(la == va)
        for vb in np.unique(lb):
            sel_b = np.flatnonzero(lb == vb)
            ia, ib, s = mutual_nearest_neighbours(fa.desc[sel_a], fb.desc[sel_b], min_cossim, ratio)
            ia_all.append(sel_a[ia])
            ib_all.append(sel_b[ib])
            s_all.append(s)
    if not ia_all:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.float32)
    ia, ib, s = np.concatenate(ia_all), np.concatenate(ib_all), np.concatenate(s_all)
    order = np.argsort(-s, kind="stable")
    ia, ib, s = ia[order], ib[order], s[order]
    pa = np.asarray(fa.kpts, np.float64)[ia].tolist()
    pb = np.asarray(fb.kpts, np.float64)[ib].tolist()
    used_a: set[int] = set()
    used_b: set[int] = set()
    cells: dict[tuple[int, int], list[int]] = {}      # kept pairs by their a-position on a dedupe_px grid
    keep = np.zeros(len(ia), bool)
    for k, (i, j) in enumerate(zip(ia.tolist(), ib.tolist(), strict=True)):
        if i in used_a or j in used_b:
            continue
        (ua, va), (ub, vb) = pa[k], pb[k]
        cx, cy = int(ua // dedupe_px), int(va // dedupe_px)
        if any(abs(pa[q][0] - ua) < dedupe_px and abs(pa[q][1] - va) < dedupe_px
               and abs(pb[q][0] - ub) < dedupe_px and abs(pb[q][1] - vb) < dedupe_px
               for dx in (-1, 0, 1) for dy in (-1, 0, 1) for q in cells.get((cx + dx, cy + dy), ())):
            continue
        keep[k] = True
        used_a.add(i)
        used_b.add(j)
        cells.setdefault((cx, cy), []).append(k)
    return ia[keep], ib[keep], s[keep].astype(np.float32)
