"""Localising one map session in another: the rigid transform between two map frames (`davio map align`).

Each run's map frame M is gravity-aligned (the filter's odometry frame, moved by the submap graph in
translation and yaw only), so two sessions of one place differ by a yaw and a translation, T_PN (a
point x_N of the new session's map is T_PN x_N in the prior one). It is found from the submaps' centre
views, which the map archive keeps (keypoints, descriptors, corrected depths):

1. place recognition (`runtime.graph.vocabulary`): a flat visual vocabulary (k-means words of the prior
   map's descriptors, tf-idf weights; DBoW's idea, without its tree) ranks the prior views for each new
   view, and the best `candidates_per_view` are tried;
2. verification: the revisit gates without a prediction (`revisits.verify_geometry`: match count, PnP
   RANSAC with the 2 px / 50 matches / 30 inliers / 0.25 gates, positive depth, image coverage, depth
   agreement); each verified pair gives a hypothesis T_PN = T_PSa T_SaSb T_NSb^-1, refused when its
   rotation is not a yaw within `max_tilt_deg` (both frames are gravity-aligned);
3. consensus (steps 3 and 4: `runtime.graph.place_consensus`): the hypotheses that agree with one centre
   hypothesis (yaws within `agree_deg`, and the two transforms place the midpoint of their new camera
   centres within `agree_m` of each other); the largest group must span `min_views` distinct new views,
   and a group elsewhere that also spans `min_views` and more than half as many makes the place ambiguous
   (refused);
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

from runtime.graph.config import RevisitConfig
from runtime.graph.factors import GraphError
from runtime.graph.place_consensus import (
    Hypothesis,
    centres,
    consensus,
    fit_transform,
    replaces,
    rms,
    tilt_deg,
    yaw_deg,
)
from runtime.graph.revisits import STAGES, RevisitView, verify_geometry
from runtime.graph.vocabulary import Vocabulary

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
        return float("nan") if self.T_PN is None else yaw_deg(self.T_PN[:3, :3])

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


class PriorMapLocalizer:
    """Localises a session's submaps, one at a time, in a prior map: the incremental form of
    `align_sessions`, which a live run calls after each map commit (on the model worker) while the
    tracking thread reads the transform (`T_PN`, thread-safe).

    Per filter segment (each has its own odometry and map frame) it keeps the verified hypotheses (at
    most `max_hypotheses`, the oldest dropped) and the consensus transform, re-fitted whenever a
    hypothesis is added. Once a segment is localised, a new view is tried first against prior views
    whose centres lie within `candidate_radius_m` (the revisits' 8 m) of where the transform puts it;
    when none of those verifies, against the best-ranked prior views anywhere (`global_fallbacks`), so
    that a wrong early lock (three views verified against a look-alike place) can still be outvoted:
    the consensus then replaces the transform with another group's (`switches`), which a live run
    applies at once rather than blending towards it.

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
        self.global_fallbacks = 0
        """Views of a localised segment tried against the whole prior map because nothing near verified."""
        self.switches: dict[int, int] = {}
        """{segment: times its transform was replaced by another consensus (`place_consensus.replaces`)}."""
        self.switch_versions: dict[int, int] = {}
        self._hyps: dict[int, list[Hypothesis]] = {}
        self._result: dict[int, tuple[list[int], str, np.ndarray | None, str]] = {}
        self._lock = threading.Lock()
        self.version = 0
        """Increases whenever a segment's transform changes."""
        self.versions: dict[int, int] = {}

    def _candidates(self, b: PlaceView, segment: int, search_near: bool) -> tuple[list[int], list[int]]:
        """(first, fallback): the prior views to try, best ranked first; once the segment is localised
        (and with `search_near`) `first` holds only those near where the transform puts b, and
        `fallback` the best ranked of the others, tried when none of `first` verifies."""
        sim = self._H @ self.vocabulary.histogram(b.features.desc)
        order = [int(k) for k in np.argsort(-sim, kind="stable") if sim[k] > 0]
        n = self.cfg.candidates_per_view
        T = self.T_PN(segment) if search_near else None
        if T is None:
            return order[:n], []
        c_P = T[:3, :3] @ np.asarray(b.T_MS, np.float64)[:3, 3] + T[:3, 3]
        near = np.linalg.norm(self._centres - c_P, axis=1) <= self.cfg.gates.candidate_radius_m
        return [k for k in order if near[k]][:n], [k for k in order[:n] if not near[k]]

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
        first, fallback = self._candidates(b, segment, search_near)
        new = self._verify(b, first)
        if not new and fallback:
            self.global_fallbacks += 1
            new = self._verify(b, fallback)
        if not new:
            return False
        with self._lock:
            hyps = self._hyps.setdefault(int(segment), [])
            hyps.extend(new)
            if len(hyps) > self.max_hypotheses:
                self.hypotheses_dropped += len(hyps) - self.max_hypotheses
                del hyps[: len(hyps) - self.max_hypotheses]
        return self.solve(segment) if solve else False

    def _verify(self, b: PlaceView, candidates: list[int]) -> list[Hypothesis]:
        """The hypotheses of the candidate prior views that pass verification with b (rejections counted)."""
        new: list[Hypothesis] = []
        for k in candidates:
            a = self.prior[k]
            self.attempts += 1
            res, T_SaSb, p_a, p_b = verify_geometry(a.view, b.view, self.match(a.features, b.features),
                                                    self.cfg.gates)
            if T_SaSb is None:
                self.rejected[res.stage] = self.rejected.get(res.stage, 0) + 1
                continue
            T_MS_b = np.asarray(b.T_MS, np.float64)
            T_PN = np.asarray(a.T_MS, np.float64) @ T_SaSb @ np.linalg.inv(T_MS_b)
            tilt = tilt_deg(T_PN[:3, :3])
            if tilt > self.cfg.max_tilt_deg:
                self.rejected["tilt"] += 1
                continue
            x_P = p_a @ a.T_MS[:3, :3].T + a.T_MS[:3, 3]
            x_N = p_b @ T_MS_b[:3, :3].T + T_MS_b[:3, 3]
            new.append(Hypothesis(a.index, b.index, T_PN, yaw_deg(T_PN[:3, :3]), tilt, res.n_inliers,
                                  res.depth_rel_error, x_P, x_N, T_MS_b[:3, 3].copy()))
        return new

    def solve(self, segment: int = 0) -> bool:
        """Re-run the segment's consensus and transform; returns True when the transform changed. A
        consensus that fails after the segment was localised (hypotheses of a drifted stretch, or an
        ambiguous place) keeps the last transform, counted in `consensus_lost` and said in the reason."""
        seg = int(segment)
        with self._lock:
            hyps = list(self._hyps.get(seg, []))
        idx, reason = consensus(hyps, self.cfg)
        group = [hyps[i] for i in idx]
        T, fit = fit_transform(group, self.cfg) if group else (None, "")
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
                if old is not None and old[2] is not None and replaces(old[0], old[2], group, T,
                                                                       {id(h) for h in hyps}, self.cfg):
                    self.switches[seg] = self.switches.get(seg, 0) + 1
                    self.switch_versions[seg] = self.version
        return changed

    def switched_at(self, segment: int) -> int:
        """The version at which the segment's transform was last replaced by another consensus (0: never)."""
        with self._lock:
            return self.switch_versions.get(int(segment), 0)

    def state(self, segment: int) -> tuple[int, np.ndarray | None, int]:
        """(version, T_PN or None, switch version) of the segment, read together under the lock (a
        thread applying them must not pair one commit's transform with another's version)."""
        seg = int(segment)
        with self._lock:
            r = self._result.get(seg)
            T = None if r is None or r[2] is None else r[2].copy()
            return self.versions.get(seg, 0), T, self.switch_versions.get(seg, 0)

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
            out.rms_m = rms(np.concatenate([h.x_P for h in group]), np.concatenate([h.x_N for h in group]),
                             T)
            out.centre_rms_m = rms(*centres(group), T)
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
