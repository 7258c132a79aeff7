"""Feature tracks seen by the filter: per feature id, its observations at clone (camera) times."""
from __future__ import annotations

from bisect import bisect_left
from dataclasses import dataclass, field

import numpy as np


@dataclass(slots=True)
class Track:
    """Observations of one feature: camera times (ns), distorted pixels and normalised coordinates (each a
    2-sequence: a list from the database, an array where a caller builds tracks itself)."""

    fid: int
    t_ns: list[int] = field(default_factory=list)
    uv: list[np.ndarray] = field(default_factory=list)
    xn: list[np.ndarray] = field(default_factory=list)
    created: int = 0     #: the database's running count when the track entered it (0 outside a database)

    def __len__(self) -> int:
        return len(self.t_ns)


class FeatureDatabase:
    """Tracks keyed by feature id.

    The ids added at each frame time are kept beside the tracks, so that dropping a time visits the tracks
    observed then instead of every track (an entry may name a track that lost that observation since).
    Frames are added in increasing time (the estimator processes them in order), so each track's times
    increase and are searched by bisection."""

    def __init__(self) -> None:
        self.tracks: dict[int, Track] = {}
        self._created = 0
        self._ids_at: dict[int, list[int]] = {}

    def add(self, t_ns: int, ids: np.ndarray, uv: np.ndarray, xn: np.ndarray) -> None:
        """Add the observations of one frame."""
        tracks = self.tracks
        fids = ids.tolist()
        self._ids_at.setdefault(t_ns, []).extend(fids)
        # plain lists: cheaper to iterate and to pack into arrays again than rows of the frame's arrays
        for fid, u, x in zip(fids, np.asarray(uv).tolist(), np.asarray(xn).tolist(), strict=True):
            tr = tracks.get(fid)
            if tr is None:
                self._created += 1
                tr = tracks[fid] = Track(fid, created=self._created)
            elif tr.t_ns and tr.t_ns[-1] == t_ns:
                continue
            tr.t_ns.append(t_ns)
            tr.uv.append(u)
            tr.xn.append(x)

    def remove(self, fid: int) -> None:
        self.tracks.pop(fid, None)

    def keep_only_last(self, fid: int) -> None:
        self.keep_only_last_of((fid,))

    def keep_only_last_of(self, fids: object) -> None:
        """keep_only_last for every id of `fids`."""
        tracks = self.tracks
        for fid in fids:
            tr = tracks.get(fid)
            if tr is not None and len(tr.t_ns) > 1:
                tr.t_ns = tr.t_ns[-1:]
                tr.uv = tr.uv[-1:]
                tr.xn = tr.xn[-1:]

    def drop_older_than(self, t_ns: int) -> None:
        """Remove observations older than t_ns; empty tracks are deleted."""
        tracks = self.tracks
        for t_old in [t for t in self._ids_at if t < t_ns]:
            for fid in self._ids_at.pop(t_old):
                tr = tracks.get(fid)
                if tr is None or not tr.t_ns or tr.t_ns[0] >= t_ns:
                    continue
                k = bisect_left(tr.t_ns, t_ns)         # the track's times increase
                if k == len(tr.t_ns):
                    del tracks[fid]
                else:
                    tr.t_ns = tr.t_ns[k:]
                    tr.uv = tr.uv[k:]
                    tr.xn = tr.xn[k:]

    def drop_time(self, t_ns: int) -> None:
        """Remove the observations at time t_ns (a clone dropped from the middle of the window); empty tracks
        are deleted."""
        tracks = self.tracks
        for fid in self._ids_at.pop(t_ns, ()):
            tr = tracks.get(fid)
            if tr is None:
                continue
            k = bisect_left(tr.t_ns, t_ns)
            if k < len(tr.t_ns) and tr.t_ns[k] == t_ns:
                del tr.t_ns[k], tr.uv[k], tr.xn[k]
                if not tr.t_ns:
                    del tracks[fid]

    def clear(self) -> None:
        self.tracks.clear()
        self._ids_at.clear()
