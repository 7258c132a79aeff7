"""One matching interface over XFeat (ONNX) and ORB (OpenCV): `match(image_a, image_b) -> Matches`."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from models.matcher.features import Features, Matches, match_levels, mutual_nearest_neighbours
from models.matcher.lighterglue import LighterGlue
from models.matcher.orb import OrbDetector, match_hamming
from models.matcher.refine import refine_matches_lk
from models.matcher.xfeat import DEFAULT_XFEAT_PATH, XFeatDetector
from runtime.errors import ModelError

log = logging.getLogger(__name__)


class Matcher:
    """Sparse feature matcher.

    With `model_path` (an XFeat backbone graph) it uses XFeat + mutual nearest neighbours on
    cosine similarity, or LighterGlue when `lighterglue_path` is given; without it, OpenCV ORB +
    Hamming cross-check (warned once).

    Args:
        model_path: XFeat backbone .onnx, or None for ORB.
        top_k: keypoints per image.
        min_cossim: XFeat only: drop mutual pairs below this cosine similarity (-1 keeps all).
        ratio: XFeat only: Lowe ratio test on descriptor distances (1 = off). XFeat's sparse keypoints
            jitter by 1-3 px between views; 0.8 keeps the precision within 3 px above 0.8 on
            simulated and homography pairs (BENCHMARKS.md) at about 80 % of the matches.
        lighterglue_path: optional LighterGlue graph (`davio export-xfeat --lighterglue PATH`).
        providers, threads: ONNX Runtime settings for XFeat.
    """

    _warned = False

    def __init__(
        self,
        model_path: str | Path | None = None,
        top_k: int = 2048,
        min_cossim: float = -1.0,
        ratio: float = 0.8,
        providers: Sequence[str] | None = None,
        threads: int | None = None,
        lighterglue_path: str | Path | None = None,
    ) -> None:
        if not 0.0 < ratio <= 1.0:
            raise ValueError(f"ratio must be in (0, 1], got {ratio}")
        self.min_cossim, self.ratio = min_cossim, ratio
        if model_path is None:
            self.backend = "orb"
            self.detector = OrbDetector(top_k)
            if not Matcher._warned:
                log.warning("no XFeat graph configured: matching with OpenCV ORB (davio export-xfeat)")
                Matcher._warned = True
        else:
            self.backend = "xfeat"
            self.detector = XFeatDetector(model_path, top_k=top_k, providers=providers, threads=threads)
        self.glue = None
        if lighterglue_path is not None:
            if self.backend != "xfeat":
                raise ModelError("LighterGlue matches XFeat features: give the XFeat model path too")
            self.glue = LighterGlue(lighterglue_path, providers=providers, threads=threads)
            self.backend = "xfeat+lighterglue"

    @classmethod
    def default(cls, **kwargs) -> Matcher:
        """XFeat with the committed graph when it is installed, ORB otherwise."""
        return cls(DEFAULT_XFEAT_PATH if DEFAULT_XFEAT_PATH.is_file() else None, **kwargs)

    def detect(self, image: np.ndarray) -> Features:
        """Keypoints, scores and descriptors of one grey uint8 image (cache them per keyframe)."""
        return self.detector.detect(image)

    def detect_pyramid(self, image: np.ndarray, scales: Sequence[float] = (1.0, 0.7, 0.5),
                       base: Features | None = None) -> Features:
        """Multi-level features for matching across a change of scale (`XFeatDetector.detect_pyramid`;
        `match_features` matches them level pair by level pair, with mutual nearest neighbours even
        when LighterGlue is configured). ORB builds its own 8-level pyramid, so its features are
        returned as by `detect`; a single scale (1.0,) is `detect`. `base`: the image's `detect`
        features, reused (as level 0, or as the result) instead of detecting again."""
        if self.backend == "orb" or tuple(float(x) for x in scales) == (1.0,):
            return base if base is not None else self.detect(image)
        return self.detector.detect_pyramid(image, scales, base)

    def match_features(self, fa: Features, fb: Features) -> Matches:
        """Match two precomputed feature sets (pyramid features: `features.match_levels`)."""
        multi_level = fa.level is not None or fb.level is not None
        if self.glue is not None and not multi_level and self.backend != "orb":
            ia, ib, s = self.glue.match(fa, fb, fa.image_size, fb.image_size)
            return Matches(fa.kpts, fb.kpts, ia, ib, s)
        return match_stored(fa, fb, self.min_cossim, self.ratio)

    def match(self, image_a: np.ndarray, image_b: np.ndarray, refine: bool = True) -> Matches:
        """Detect in both images and match them; `refine` re-localises the b-positions with LK
        (sub-pixel, drops matches that do not track), see models/matcher/refine.py."""
        m = self.match_features(self.detect(image_a), self.detect(image_b))
        return refine_matches_lk(image_a, image_b, m) if refine else m


def match_stored(fa: Features, fb: Features, min_cossim: float = -1.0, ratio: float = 0.8) -> Matches:
    """Match two stored feature sets without a model: binary (uint8) descriptors by Hamming
    cross-check, pyramid features level pair by level pair (`match_levels`), others by mutual nearest
    neighbours on cosine similarity with the ratio test (as `Matcher.match_features` without LighterGlue)."""
    if not np.issubdtype(np.asarray(fa.desc).dtype, np.floating):
        ia, ib, s = match_hamming(fa.desc, fb.desc)
    elif fa.level is not None or fb.level is not None:
        ia, ib, s = match_levels(fa, fb, min_cossim, ratio)
    else:
        ia, ib, s = mutual_nearest_neighbours(fa.desc, fb.desc, min_cossim, ratio)
    return Matches(fa.kpts, fb.kpts, ia, ib, s)
