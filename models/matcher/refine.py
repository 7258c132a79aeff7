"""Sub-pixel refinement of matches by pyramidal Lucas-Kanade from image a into image b.

XFeat's sparse keypoints are detected per 8x8 cell and jitter by 1-3 px between views; tracking
each matched keypoint of a into b with LK, started at its matched position, re-localises it to
sub-pixel accuracy. Matches whose LK fails, or moves by more than `max_shift_px`, are dropped.
"""

from __future__ import annotations

import cv2
import numpy as np

from models.matcher.features import Matches


def _grey(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img


def refine_matches_lk(
    image_a: np.ndarray,
    image_b: np.ndarray,
    matches: Matches,
    window: int = 15,
    max_shift_px: float = 4.0,
    levels: int = 1,
) -> Matches:
    """Matches with b-positions re-localised by LK (kpts_b is copied; matched entries replaced).

    Args:
        image_a, image_b: the grey uint8 images the matches come from.
        window: LK window (pixels); levels: extra pyramid levels.
        max_shift_px: largest accepted move of a b-position; beyond it the match is dropped.
    """
    if len(matches) == 0:
        return matches
    pa = matches.points_a.astype(np.float32).reshape(-1, 1, 2)
    pb = matches.points_b.astype(np.float32).reshape(-1, 1, 2).copy()
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01)
    nb, status, _ = cv2.calcOpticalFlowPyrLK(
        _grey(image_a),
        _grey(image_b),
        pa,
        pb,
        winSize=(window, window),
        maxLevel=levels,
        criteria=crit,
        flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
    )
    nb = nb.reshape(-1, 2)
    ok = status.ravel().astype(bool) & np.isfinite(nb).all(1)
    ok &= np.linalg.norm(nb - matches.points_b, axis=1) <= max_shift_px
    kpts_b = matches.kpts_b.astype(np.float32).copy()
    kpts_b[matches.idx_b[ok]] = nb[ok]
    return Matches(matches.kpts_a, kpts_b, matches.idx_a[ok], matches.idx_b[ok], matches.scores[ok])
