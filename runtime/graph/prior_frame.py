"""A live run's poses in a prior map's frame (`davio run ... --prior-map D`, `Session(prior_map=...)`).

The model worker hands each committed submap's centre view to a `PriorMapLocalizer` (right after the
mapper commits it); the tracking thread, when it applies that commit, picks up a changed transform
T_PM (this run's map frame M of the segment -> the prior map frame P) into a per-segment
`CorrectionTimeline`: the first transform applies at once (there was none to blend from), and so does
one that replaces a wrong lock (the localizer's `switches`: blending from a wrong place would only
publish poses between two places); other refinements above 5 cm / 2 deg are blended over a second of
sensor time, as the map correction is.
A pose published at time t in segment s is then T_PI = T_PM(s, t) T_MI(t); before the segment is
localised it has none. The final prior-frame trajectory applies each segment's newest T_PM to its final
map-frame poses.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from runtime.graph.correction import CorrectionTimeline
from runtime.graph.relocalize import PlaceView, PriorMapLocalizer
from runtime.mapping.mapper import MAX_ERROR_MESSAGES


class PriorFrame:
    """The localizer (model worker side) and the per-segment timelines of T_PM (tracking side)."""

    def __init__(self, localizer: PriorMapLocalizer, source: str = "") -> None:
        self.localizer = localizer
        self.source = source
        self.timelines: dict[int, CorrectionTimeline] = {}
        self.localized_at_ns: dict[int, int] = {}
        self._seen: dict[int, int] = {}
        self.submaps_without_view = 0
        self.errors = 0
        self.error_messages: list[str] = []

    def on_submap(self, sub: Any) -> None:
        """A committed submap (model worker): try its centre view against the prior map. Any failure (an
        OpenCV error, a degenerate geometry) is counted and kept as a message: the mapper has already
        committed the submap, and the commit must still reach the tracking thread."""
        if sub.view is None:
            self.submaps_without_view += 1
            return
        try:
            self.localizer.add_view(PlaceView(int(sub.index), np.asarray(sub.T_MS, np.float64), *sub.view),
                                    int(sub.segment))
        except Exception as exc:  # noqa: BLE001 - a localisation failure must never fail the map commit
            self.errors += 1
            if len(self.error_messages) < MAX_ERROR_MESSAGES:
                self.error_messages.append(f"submap {sub.index}: {type(exc).__name__}: {exc}")

    def update(self, t_ns: int) -> None:
        """Take up transforms the localizer changed since the last call (tracking thread), from sensor
        time t_ns."""
        for seg, version in self.localizer.segment_versions().items():
            seen = self._seen.get(seg, 0)
            if version <= seen:
                continue
            version, T, switched = self.localizer.state(seg)
            if T is None:
                continue
            tl = self.timelines.setdefault(seg, CorrectionTimeline())
            t = max(int(t_ns), tl.last_commit_ns or 0)
            # a replacement since the last update applies at once, even when a refinement followed it
            tl.commit(t, T, version, immediate=len(tl) == 0 or switched > seen)
            self._seen[seg] = version
            self.localized_at_ns.setdefault(seg, t)

    def localized(self, segment: int) -> bool:
        """Whether poses of `segment` are published in the prior frame now."""
        return int(segment) in self.timelines

    def pose(self, segment: int, t_ns: int, T_MI: np.ndarray) -> np.ndarray | None:
        """T_PI (4,4) of a pose published at t_ns in `segment` with map-frame pose T_MI, or None while
        the segment was not localised at t_ns."""
        tl = self.timelines.get(int(segment))
        if tl is None:
            return None
        T_PM, version, _ = tl.at(int(t_ns))
        return None if version == 0 else T_PM @ np.asarray(T_MI, np.float64)

    def causal(self, segment: int, t_ns: np.ndarray, T_MI: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(mask (N,), T_PI (K,4,4)) of poses (t_ns (N,), T_MI (N,4,4)) of one segment as they were
        published in the prior frame; mask marks those published after the segment was localised."""
        t_ns = np.asarray(t_ns, np.int64)
        tl = self.timelines.get(int(segment))
        if tl is None:
            return np.zeros(len(t_ns), bool), np.zeros((0, 4, 4))
        at = [tl.at(int(t)) for t in t_ns]
        mask = np.array([v > 0 for _, v, _ in at], bool)
        T = np.array([a[0] for a, m in zip(at, mask, strict=True) if m]).reshape(-1, 4, 4)
        return mask, np.matmul(T, np.asarray(T_MI, np.float64)[mask])

    def final(self, segment: int, T_MI: np.ndarray) -> np.ndarray | None:
        """(N,4,4) final map-frame poses of `segment` moved into the prior frame with its newest T_PM,
        or None when the segment was never localised."""
        T = self.localizer.T_PN(int(segment))
        return None if T is None else np.matmul(T, np.asarray(T_MI, np.float64))

    def report(self) -> dict:
        loc = self.localizer
        segs = {}
        for seg in sorted(set(loc.segments()) | set(self.timelines)):
            a = loc.alignment(seg)
            d = a.as_dict()
            d.pop("hypotheses")
            segs[str(seg)] = {**d, "localized_at_t_ns": self.localized_at_ns.get(seg),
                              "transform_updates": len(self.timelines.get(seg, ())),
                              "switches": loc.switches.get(seg, 0)}
        return {"source": self.source, "prior_views": len(loc.prior), "views_tried": loc.views_tried,
                "seconds": loc.seconds, "seconds_max": loc.seconds_max,
                "attempts": loc.attempts, "rejected": dict(loc.rejected),
                "hypotheses_dropped": loc.hypotheses_dropped, "consensus_lost": loc.consensus_lost,
                "global_fallbacks": loc.global_fallbacks, "switches": sum(loc.switches.values()),
                "submaps_without_view": self.submaps_without_view,
                "errors": self.errors, "error_messages": list(self.error_messages), "segments": segs}
