"""Localising one map session in another: the rigid transform between two map frames (`davio map align`).

Each run's map frame M is gravity-aligned (the filter's odometry frame, moved by the submap graph in
translation and yaw only), so two sessions of one place differ by a yaw and a translation, T_PN (a
point x_N of the new session's map is T_PN x_N in the prior one). It is found from the submaps' centre
views, which the map archive keeps (keypoints, descriptors, corrected depths):

1. place recognition: a flat visual vocabulary (k-means words of the prior map's descriptors, tf-idf
   weights; DBoW's idea, without its tree) ranks the prior views for each new view, and the best
   `candidates_per_view` are tried;
2. verification: the revisit gates without a prediction (`revisits.verify_geometry`: match count, PnP
   RANSAC with the 2 px / 50 matches / 30 inliers / 0.25 gates, positive depth, image coverage, depth
   agreement); each verified pair gives a hypothesis T_PN = T_PSa T_SaSb T_NSb^-1, refused when its
   rotation is not a yaw within `max_tilt_deg` (both frames are gravity-aligned);
3. consensus: the hypotheses that agree with one centre hypothesis (yaws within `agree_deg`, and the
   two transforms place the midpoint of their new camera centres within `agree_m` of each other); the
   largest group must span `min_views` distinct new views, and a group elsewhere that also spans
   `min_views` and more than half as many makes the place ambiguous (refused);
4. the transform: the closed-form yaw-and-translation least squares that puts the agreeing pairs' new
   camera centres (in N) where their PnP poses put them (in P), when those centres spread at least
   `min_centre_spread_m` horizontally (refitted twice without the pairs whose centre lies beyond three
   times the median residual: on synthetic views one pair at 0.17 m, ten times the median, had moved
   the yaw by 0.44 deg); otherwise the circular mean of the pairs' yaws and the mean translation. (On a
   V1_02 pair of sessions the centre fit erred by 0.3 deg and 4 cm against the truth, the same least
   squares over the pairs' 3D correspondences by 0.7 deg and 9 cm: far depths dominate it. The mean of
   the pairs' yaws, which scatter by +-1.5 deg, erred by 1.0 deg.)

Unlike a revisit, the PnP pose is used here: it is the answer, not a factor.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from runtime.geometry.se3 import make_pose
from runtime.geometry.se3 import yaw_translation_fit as fit_yaw
from runtime.geometry.so3 import rot_z
from runtime.graph.config import RevisitConfig
from runtime.graph.factors import GraphError
from runtime.graph.revisits import STAGES, RevisitView, verify_geometry

ALIGN_STAGES = (*STAGES[:5], "tilt")
"""Rejection stages of a candidate pair: the geometry tests of a revisit, then the gravity check."""


@dataclass
class PlaceView:
    """A submap's centre view placed in its session's map frame.

    Attributes:
        index: submap index in its archive.
        T_MS: (4,4) pose of the submap frame (the centre camera) in the map frame.
        features: the matcher's Features of the centre image (kpts, scores, desc, level).
        view: the RevisitView (K, keypoints, corrected depths) of the same keypoints.
    """

    index: int
    T_MS: np.ndarray
    features: object
    view: RevisitView


@dataclass(frozen=True)
class AlignConfig:
    """Settings of `align_sessions`.

    Attributes:
        words: visual words of the vocabulary (k-means centres of the prior map's descriptors).
        candidates_per_view: prior views verified per new view, best ranked first.
        agree_m, agree_deg: two hypotheses agree when they place the midpoint of their new camera centres
            within agree_m (m) of each other and their yaws differ by at most agree_deg (degrees).
        min_views: distinct new views the agreeing hypotheses must come from.
        max_tilt_deg: a hypothesis whose rotation tilts the vertical by more is refused (the frames are
            gravity-aligned: the roll and pitch of a right answer come from the filters' attitude errors).
        min_centre_spread_m: horizontal RMS spread (m) of the agreeing new camera centres above which
            the yaw is fitted to the centres rather than averaged over the pairs.
        gates: the revisit gates the pairs are verified with (PnP, coverage, depth agreement).
        seed: seed of the vocabulary's k-means.
    """

    words: int = 256
    candidates_per_view: int = 5
    agree_m: float = 0.3
    agree_deg: float = 3.0
    min_views: int = 3
    max_tilt_deg: float = 5.0
    min_centre_spread_m: float = 0.5
    gates: RevisitConfig = field(default_factory=RevisitConfig)
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("words", "candidates_per_view", "min_views"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        for name in ("agree_m", "agree_deg", "max_tilt_deg", "min_centre_spread_m"):
            v = getattr(self, name)
            if not np.isfinite(v) or v <= 0:
                raise ValueError(f"{name} must be a positive number, got {v!r}")


def descriptor_vectors(desc: np.ndarray) -> np.ndarray:
    """(N,D) float32 unit vectors of descriptors: float descriptors normalised, binary (uint8) ones
    unpacked to +-1 bits, so that a dot product ranks them as their own distance does."""
    d = np.asarray(desc)
    if np.issubdtype(d.dtype, np.floating):
        v = d.astype(np.float32)
    else:
        v = np.unpackbits(d.astype(np.uint8), axis=1).astype(np.float32) * 2.0 - 1.0
    n = np.linalg.norm(v, axis=1, keepdims=True)
    return v / np.maximum(n, 1e-12)


class Vocabulary:
    """A flat visual vocabulary with tf-idf weights: `histogram` turns a view's descriptors into a unit
    vector; the dot product of two ranks how much of one image's appearance the other holds."""

    def __init__(self, centres: np.ndarray, idf: np.ndarray) -> None:
        self.centres = np.asarray(centres, np.float32)
        self.idf = np.asarray(idf, np.float32)

    @classmethod
    def train(cls, descriptors: Sequence[np.ndarray], words: int = 256, seed: int = 0,
              max_samples: int = 40_000) -> Vocabulary:
        """k-means (OpenCV, k-means++ seeding) of up to `max_samples` descriptors drawn from every view,
        then idf_w = log(views / views holding word w)."""
        import cv2

        vecs = [descriptor_vectors(d) for d in descriptors if len(d)]
        if not vecs:
            raise GraphError("no descriptors to build a vocabulary from")
        allv = np.concatenate(vecs)
        rng = np.random.default_rng(seed)
        if len(allv) > max_samples:
            allv = allv[rng.choice(len(allv), max_samples, replace=False)]
        k = int(min(words, len(allv)))
        cv2.setRNGSeed(int(seed))
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 1e-4)
        _, _, centres = cv2.kmeans(allv, k, None, crit, 1, cv2.KMEANS_PP_CENTERS)
        centres /= np.maximum(np.linalg.norm(centres, axis=1, keepdims=True), 1e-12)
        voc = cls(centres, np.ones(k, np.float32))
        holds = np.zeros(k)
        for v in vecs:
            holds[np.unique(voc.words_of(v))] += 1
        voc.idf = np.log(len(vecs) / np.maximum(holds, 1.0)).astype(np.float32)
        return voc

    def words_of(self, vectors: np.ndarray) -> np.ndarray:
        """(N,) index of the nearest word of each unit vector (largest dot product)."""
        return np.argmax(vectors @ self.centres.T, axis=1)

    def histogram(self, desc: np.ndarray) -> np.ndarray:
        """(W,) tf-idf histogram of one view's descriptors, L2-normalised (zeros when it has none)."""
        h = np.zeros(len(self.centres), np.float32)
        if len(desc):
            np.add.at(h, self.words_of(descriptor_vectors(desc)), 1.0)
            h *= self.idf / len(desc)
        n = float(np.linalg.norm(h))
        return h / n if n > 0 else h


@dataclass
class Hypothesis:
    """One verified pair (prior view a, new view b) and the transform it implies.

    Attributes:
        prior, new: submap indices of a and b.
        T_PN: (4,4) the pair's transform from the new map frame to the prior one.
        yaw_deg: its yaw; tilt_deg: how far it tilts the vertical.
        n_inliers: PnP inliers; depth_rel_error: the pair's median relative depth error.
        x_P, x_N: (K,3) the pair's correspondences placed in the prior and the new map frame.
        c_N: (3,) the new view's camera centre in the new map frame (its centre in the prior frame by
            this pair is T_PN c_N).
    """

    prior: int
    new: int
    T_PN: np.ndarray
    yaw_deg: float
    tilt_deg: float
    n_inliers: int
    depth_rel_error: float
    x_P: np.ndarray
    x_N: np.ndarray
    c_N: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def as_dict(self) -> dict:
        return {"prior": self.prior, "new": self.new, "yaw_deg": self.yaw_deg, "tilt_deg": self.tilt_deg,
                "t": [float(v) for v in self.T_PN[:3, 3]], "n_inliers": self.n_inliers,
                "depth_rel_error": self.depth_rel_error, "n_points": int(len(self.x_P))}


@dataclass
class Alignment:
    """Outcome of `align_sessions`.

    Attributes:
        localized: a transform was found and is unambiguous.
        reason: why not, or 'localized'.
        T_PN: (4,4) new map frame -> prior map frame (None when not localized).
        rms_m: RMS distance of the agreeing pairs' correspondences after the transform (m); it includes
            both sessions' depth errors, so it is a check, not the transform's accuracy.
        centre_rms_m: RMS distance between the agreeing new centres placed by the transform and by their
            pairs' PnP poses (m).
        fit: "centres" or "mean yaw" (module docstring, step 4).
        hypotheses: every verified pair's hypothesis; agreeing: indices into it of the consensus group.
        attempts: candidate pairs tried; rejected: per stage (`ALIGN_STAGES`).
        prior_views, new_views: views used from each session.
    """

    localized: bool
    reason: str
    T_PN: np.ndarray | None = None
    rms_m: float = float("nan")
    centre_rms_m: float = float("nan")
    fit: str = ""
    hypotheses: list[Hypothesis] = field(default_factory=list)
    agreeing: list[int] = field(default_factory=list)
    attempts: int = 0
    rejected: dict = field(default_factory=lambda: {s: 0 for s in ALIGN_STAGES})
    prior_views: int = 0
    new_views: int = 0

    @property
    def yaw_deg(self) -> float:
        return float("nan") if self.T_PN is None else _yaw_deg(self.T_PN[:3, :3])

    def as_dict(self) -> dict:
        T = None if self.T_PN is None else [[float(v) for v in row] for row in self.T_PN]
        return {"localized": self.localized, "reason": self.reason, "T_PN": T, "yaw_deg": self.yaw_deg,
                "t": None if self.T_PN is None else [float(v) for v in self.T_PN[:3, 3]],
                "rms_m": self.rms_m, "centre_rms_m": self.centre_rms_m, "fit": self.fit,
                "prior_views": self.prior_views, "new_views": self.new_views,
                "attempts": self.attempts, "verified": len(self.hypotheses),
                "agreeing": len(self.agreeing),
                "agreeing_new_views": len({self.hypotheses[i].new for i in self.agreeing}),
                "rejected": dict(self.rejected),
                "hypotheses": [h.as_dict() for h in self.hypotheses]}


def _yaw_deg(R: np.ndarray) -> float:
    """Yaw (degrees) of the rotation about z nearest to R (Frobenius)."""
    return float(np.degrees(np.arctan2(R[1, 0] - R[0, 1], R[0, 0] + R[1, 1])))


def _tilt_deg(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))


def yaw_translation_fit(x_P: np.ndarray, x_N: np.ndarray) -> np.ndarray:
    """(4,4) T = [Rz(yaw), t] minimising sum |x_P - T x_N|^2 over (K,3) point pairs (closed form,
    `runtime.geometry.se3.yaw_translation_fit`)."""
    x_P = np.asarray(x_P, np.float64)
    x_N = np.asarray(x_N, np.float64)
    if x_P.shape != x_N.shape or x_P.ndim != 2 or x_P.shape[1] != 3 or len(x_P) < 2:
        raise GraphError(f"need two or more (K,3) point pairs, got {x_P.shape} and {x_N.shape}")
    R, t, _ = fit_yaw(x_N, x_P)
    return make_pose(R, t)


def agreement(hyps: list[Hypothesis], cfg: AlignConfig, block: int = 256) -> np.ndarray:
    """(n,n) bool: hypotheses i and j agree: yaws within agree_deg, and the two transforms put the
    midpoint of their new camera centres within agree_m of each other. (Compared where the views are:
    at the new map's origin, which may lie tens of metres away, a yaw difference of a degree would
    already move the translations apart.) Computed `block` rows at a time."""
    n = len(hyps)
    yaw = np.array([h.yaw_deg for h in hyps])
    R = np.array([h.T_PN[:3, :3] for h in hyps]).reshape(n, 3, 3)
    t = np.array([h.T_PN[:3, 3] for h in hyps]).reshape(n, 3)
    c = np.array([h.c_N for h in hyps]).reshape(n, 3)
    dyaw = (yaw[:, None] - yaw[None, :] + 180.0) % 360.0 - 180.0
    out = np.abs(dyaw) <= cfg.agree_deg
    for a in range(0, n, block):
        b = min(n, a + block)
        m = 0.5 * (c[a:b, None, :] + c[None, :, :])                       # (rows, n, 3)
        p_i = np.einsum("iab,ijb->ija", R[a:b], m) + t[a:b, None, :]
        p_j = np.einsum("jab,ijb->ija", R, m) + t[None, :, :]
        out[a:b] &= np.linalg.norm(p_i - p_j, axis=2) <= cfg.agree_m
    return out


def _largest_group(A: np.ndarray, new: np.ndarray, idx: np.ndarray) -> tuple[int, np.ndarray]:
    """(centre, members): among hypotheses `idx`, the one whose agreeing members (within `idx`) come
    from the most distinct new views (then the most members), and those members."""
    best, best_key = -1, (-1, -1)
    members = np.zeros(0, np.int64)
    for i in idx:
        m = idx[A[i, idx]]
        key = (len(np.unique(new[m])), len(m))
        if key > best_key:
            best, best_key, members = int(i), key, m
    return best, members


def consensus(hyps: list[Hypothesis], cfg: AlignConfig) -> tuple[list[int], str]:
    """(agreeing indices, reason): the largest group of mutually consistent hypotheses (those agreeing
    with one centre hypothesis), refused when it spans fewer than `min_views` new views or when a group
    elsewhere (hypotheses agreeing with neither the centre nor its group) also spans `min_views` and
    more than half as many."""
    if not hyps:
        return [], "no candidate pair passed verification"
    A = agreement(hyps, cfg)
    new = np.array([h.new for h in hyps])
    centre, group = _largest_group(A, new, np.arange(len(hyps)))
    views = len(np.unique(new[group]))
    if views < cfg.min_views:
        return [], (f"the largest consistent group comes from {views} new view(s), fewer than "
                    f"{cfg.min_views}")
    rest = np.flatnonzero(~A[centre] & ~A[group].any(axis=0))
    other_views = len(np.unique(new[_largest_group(A, new, rest)[1]])) if len(rest) else 0
    if other_views >= cfg.min_views and other_views * 2 > views:
        return [], (f"ambiguous: two inconsistent groups of {views} and {other_views} new views (a "
                    "repetitive place, or a different one)")
    return [int(k) for k in group], "localized"


class PriorMapLocalizer:
    """Localises a session's submaps, one at a time, in a prior map: the incremental form of
    `align_sessions`, which a live run calls after each map commit (on the model worker) while the
    tracking thread reads the transform (`T_PN`, thread-safe).

    Per filter segment (each has its own odometry and map frame) it keeps the verified hypotheses (at
    most `max_hypotheses`, the oldest dropped) and the consensus transform, re-fitted whenever a
    hypothesis is added. Once a segment is localised, a new view is tried only against prior views
    whose centres lie within `candidate_radius_m` (the revisits' 8 m) of where the transform puts it.

    Args:
        prior: the prior map's centre views, poses in its map frame P.
        match: (features a, features b) -> (idx_a, idx_b).
        cfg: settings (`AlignConfig`); source: where the prior map came from (reports).
    """

    def __init__(self, prior: Sequence[PlaceView],
                 match: Callable[[object, object], tuple[np.ndarray, np.ndarray]],
                 cfg: AlignConfig | None = None, max_hypotheses: int = 300, source: str = "") -> None:
        import threading

        self.source = source
        self.prior_segment: int | None = None
        """The prior archive's filter segment the views come from (set by whoever loaded them)."""
        self.cfg = cfg or AlignConfig()
        self.prior = list(prior)
        self.match = match
        self.max_hypotheses = int(max_hypotheses)
        if not self.prior:
            raise GraphError("the prior map holds no centre views")
        self.vocabulary = Vocabulary.train([p.features.desc for p in self.prior], self.cfg.words,
                                           self.cfg.seed)
        self._H = np.stack([self.vocabulary.histogram(p.features.desc) for p in self.prior])
        self._centres = np.array([np.asarray(p.T_MS, np.float64)[:3, 3] for p in self.prior])
        self.views_tried = 0
        self.seconds = 0.0
        """Time spent in `add_view` (s), and the longest call."""
        self.seconds_max = 0.0
        self.attempts = 0
        self.rejected = {s: 0 for s in ALIGN_STAGES}
        self.hypotheses_dropped = 0
        self.consensus_lost = 0
        """Consensus updates that failed after the segment was localised (the last transform kept)."""
        self._hyps: dict[int, list[Hypothesis]] = {}
        self._result: dict[int, tuple[list[int], str, np.ndarray | None, str]] = {}
        self._lock = threading.Lock()
        self.version = 0
        """Increases whenever a segment's transform changes."""
        self.versions: dict[int, int] = {}

    def _candidates(self, b: PlaceView, segment: int, search_near: bool) -> list[int]:
        sim = self._H @ self.vocabulary.histogram(b.features.desc)
        order = [int(k) for k in np.argsort(-sim, kind="stable") if sim[k] > 0]
        T = self.T_PN(segment) if search_near else None
        if T is not None:
            c_P = T[:3, :3] @ np.asarray(b.T_MS, np.float64)[:3, 3] + T[:3, 3]
            near = np.linalg.norm(self._centres - c_P, axis=1) <= self.cfg.gates.candidate_radius_m
            order = [k for k in order if near[k]]
        return order[: self.cfg.candidates_per_view]

    def add_view(self, b: PlaceView, segment: int = 0, search_near: bool = True, solve: bool = True) -> bool:
        """Verify view b (pose in the session's map frame of `segment`) against its best-ranked prior
        views (near where the transform puts it once localised, unless `search_near` is False) and,
        with `solve`, update the segment's transform (`solve`); returns True when the transform changed."""
        import time

        t0 = time.perf_counter()
        try:
            return self._add_view(b, segment, search_near, solve)
        finally:
            dt = time.perf_counter() - t0
            self.seconds += dt
            self.seconds_max = max(self.seconds_max, dt)

    def _add_view(self, b: PlaceView, segment: int, search_near: bool, solve: bool) -> bool:
        self.views_tried += 1
        new: list[Hypothesis] = []
        for k in self._candidates(b, segment, search_near):
            a = self.prior[k]
            self.attempts += 1
            res, T_SaSb, p_a, p_b = verify_geometry(a.view, b.view, self.match(a.features, b.features),
                                                    self.cfg.gates)
            if T_SaSb is None:
                self.rejected[res.stage] = self.rejected.get(res.stage, 0) + 1
                continue
            T_MS_b = np.asarray(b.T_MS, np.float64)
            T_PN = np.asarray(a.T_MS, np.float64) @ T_SaSb @ np.linalg.inv(T_MS_b)
            tilt = _tilt_deg(T_PN[:3, :3])
            if tilt > self.cfg.max_tilt_deg:
                self.rejected["tilt"] += 1
                continue
            x_P = p_a @ a.T_MS[:3, :3].T + a.T_MS[:3, 3]
            x_N = p_b @ T_MS_b[:3, :3].T + T_MS_b[:3, 3]
            new.append(Hypothesis(a.index, b.index, T_PN, _yaw_deg(T_PN[:3, :3]), tilt, res.n_inliers,
                                  res.depth_rel_error, x_P, x_N, T_MS_b[:3, 3].copy()))
        if not new:
            return False
        with self._lock:
            hyps = self._hyps.setdefault(int(segment), [])
            hyps.extend(new)
            if len(hyps) > self.max_hypotheses:
                self.hypotheses_dropped += len(hyps) - self.max_hypotheses
                del hyps[: len(hyps) - self.max_hypotheses]
        return self.solve(segment) if solve else False

    def solve(self, segment: int = 0) -> bool:
        """Re-run the segment's consensus and transform; returns True when the transform changed. A
        consensus that fails after the segment was localised (hypotheses of a drifted stretch, or an
        ambiguous place) keeps the last transform, counted in `consensus_lost` and said in the reason."""
        seg = int(segment)
        with self._lock:
            hyps = list(self._hyps.get(seg, []))
        idx, reason = consensus(hyps, self.cfg)
        group = [hyps[i] for i in idx]
        T, fit = _transform(group, self.cfg) if group else (None, "")
        with self._lock:
            old = self._result.get(seg)
            if T is None and old is not None and old[2] is not None:
                self.consensus_lost += 1
                self._result[seg] = (old[0], f"localized; the latest consensus failed ({reason}), the last "
                                              "transform is kept", old[2], old[3])
                return False
            self._result[seg] = (group, reason, T, fit)
            changed = T is not None and (old is None or old[2] is None or not np.array_equal(old[2], T))
            if changed:
                self.version += 1
                self.versions[seg] = self.version
        return changed

    def segment_versions(self) -> dict[int, int]:
        """{segment: the version its transform last changed at} (a copy, thread-safe)."""
        with self._lock:
            return dict(self.versions)

    def T_PN(self, segment: int = 0) -> np.ndarray | None:
        """(4,4) the segment's map frame -> the prior map frame, or None while it is not localised."""
        with self._lock:
            r = self._result.get(int(segment))
            return None if r is None or r[2] is None else r[2].copy()

    def alignment(self, segment: int = 0, new_views: int = 0) -> Alignment:
        """The segment's state as an `Alignment` (hypotheses, consensus, transform, counters), taken
        under the lock (a consistent snapshot while another thread adds views)."""
        with self._lock:
            hyps = list(self._hyps.get(int(segment), []))
            group, reason, T, fit = self._result.get(int(segment), ([], "", None, ""))
            rejected = dict(self.rejected)
        held = {id(h) for h in hyps}
        hyps += [h for h in group if id(h) not in held]     # a kept group's members dropped since
        in_group = {id(h) for h in group}
        out = Alignment(T is not None, reason or "no candidate pair passed verification", T, hypotheses=hyps,
                        agreeing=[k for k, h in enumerate(hyps) if id(h) in in_group], attempts=self.attempts,
                        rejected=rejected, prior_views=len(self.prior),
                        new_views=new_views or self.views_tried, fit=fit)
        if T is not None and group:
            out.rms_m = _rms(np.concatenate([h.x_P for h in group]), np.concatenate([h.x_N for h in group]),
                             T)
            out.centre_rms_m = _rms(*_centres(group), T)
        return out

    def segments(self) -> list[int]:
        """Segments with at least one verified hypothesis."""
        with self._lock:
            return sorted(self._hyps)


def align_sessions(prior: Sequence[PlaceView], new: Sequence[PlaceView],
                   match: Callable[[object, object], tuple[np.ndarray, np.ndarray]],
                   cfg: AlignConfig | None = None,
                   progress: Callable[[int, int], None] | None = None) -> Alignment:
    """The transform T_PN from the new session's map frame to the prior one's (module docstring), all
    of the new session's views tried against the prior map (no search radius: `PriorMapLocalizer`
    narrows it only once the segment is localised, and the views come in their own order here).

    Args:
        prior, new: the two sessions' centre views with their map poses.
        match: (features a, features b) -> (idx_a, idx_b) matched keypoint indices.
        cfg: settings; progress: called with (new views done, new views) after each new view.
    """
    cfg = cfg or AlignConfig()
    if not prior or not new:
        return Alignment(False, "one of the sessions holds no centre views", prior_views=len(prior),
                         new_views=len(new))
    loc = PriorMapLocalizer(prior, match, cfg, max_hypotheses=10**9)
    for n_done, b in enumerate(new, 1):
        loc.add_view(b, 0, search_near=False, solve=False)
        if progress is not None:
            progress(n_done, len(new))
    loc.solve(0)
    return loc.alignment(0, len(new))


def _rms(x_P: np.ndarray, x_N: np.ndarray, T_PN: np.ndarray) -> float:
    """RMS distance (m) between (K,3) points x_P and T_PN x_N."""
    return float(np.sqrt(np.mean(np.sum((x_P - (x_N @ T_PN[:3, :3].T + T_PN[:3, 3])) ** 2, axis=1))))


def _centres(group: list[Hypothesis]) -> tuple[np.ndarray, np.ndarray]:
    """(c_P, c_N): each hypothesis's new camera centre in the prior frame by its own T_PN, and in N."""
    c_N = np.array([h.c_N for h in group])
    return np.array([h.T_PN[:3, :3] @ h.c_N + h.T_PN[:3, 3] for h in group]), c_N


def _transform(group: list[Hypothesis], cfg: AlignConfig) -> tuple[np.ndarray, str]:
    """T_PN from the agreeing hypotheses (module docstring, step 4) and which fit gave it."""
    c_P, c_N = _centres(group)
    spread = float(np.sqrt(np.mean(np.sum((c_N[:, :2] - c_N[:, :2].mean(axis=0)) ** 2, axis=1))))
    if spread >= cfg.min_centre_spread_m:
        T = yaw_translation_fit(c_P, c_N)
        new = np.array([h.new for h in group])
        for _ in range(2):      # trim pairs whose centre lies beyond 3x the median residual, refit
            r = np.linalg.norm(c_P - (c_N @ T[:3, :3].T + T[:3, 3]), axis=1)
            keep = r <= 3.0 * np.median(r)
            if len(np.unique(new[keep])) < cfg.min_views or keep.all():
                break
            T = yaw_translation_fit(c_P[keep], c_N[keep])
        return T, "centres"
    yaws = np.radians([h.yaw_deg for h in group])
    yaw = float(np.arctan2(np.mean(np.sin(yaws)), np.mean(np.cos(yaws))))
    R = rot_z(yaw)
    return make_pose(R, np.mean(c_P - c_N @ R.T, axis=0)), "mean yaw"
