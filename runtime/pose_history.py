"""Every published state of a run, kept in compact columns so that a long run's memory stays small.

A run keeps each published IMU state (for `odometry.tum` and the final re-export with the completed map
corrections) and the map-frame pose it was published with (`causal.tum`). As Python objects that is
about 1.5 kB a pose (a dataclass, five small numpy arrays, the filter's 6x6 covariance and a 4x4 pose):
108 MB an hour at 20 Hz. `PoseHistory` holds the same values in fixed-size numpy chunks, 254 bytes a
pose (18.3 MB an hour at 20 Hz), and gives them back as `Published` states and `(T_MI, version,
fraction)` tuples with the same values bit for bit (`davio bench long-run` measures both). The
covariance is not kept: it goes to a live consumer with the state as published (`runtime.session.Pose`),
and nothing reads it later.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import overload

import numpy as np

from runtime.startup import Published

CHUNK_ROWS = 4096
"""Rows per chunk: a chunk is allocated whole (1 MB) and never copied when the history grows."""

ROW = np.dtype([
    ("t_ns", np.int64), ("t_cam_ns", np.int64),
    ("R_OI", np.float64, (3, 3)), ("p_OI", np.float64, 3), ("v_OI", np.float64, 3),
    ("segment", np.int32), ("filter_id", np.int32), ("source", np.int16), ("version", np.int32),
    ("fraction", np.float64), ("T_MI", np.float64, (3, 4)),
])
"""One published state: IMU and camera times (ns), R_OI, p_OI (m), v_OI (m/s) in the odometry frame,
segment, filter id, source (index into the history's names), correction version and interpolation
fraction, and the top three rows of the pose T_MI as published in the map frame."""


class PoseHistory:
    """Published states and their map-frame poses as published, in order of publication."""

    def __init__(self) -> None:
        self._chunks: list[np.ndarray] = []
        self._n = 0
        self._sources: list[str] = []
        self._source_code: dict[str, int] = {}
        self.published = PublishedView(self)
        """The states as a read-only sequence of `Published` (covariance None)."""
        self.causal = CausalView(self)
        """The map-frame poses as published: a read-only sequence of (T_MI (4,4), version, fraction)."""

    def __len__(self) -> int:
        return self._n

    def append(self, p: Published, T_MI: np.ndarray, version: int, fraction: float) -> None:
        """Record one published state and the rigid map-frame pose T_MI (4,4) it was published with (its
        last row is not stored: it reads back as [0, 0, 0, 1]). A value that does not fit (a stamp beyond
        int64, a wrong shape) raises and records nothing: the next append writes the same row."""
        k = self._n % CHUNK_ROWS
        if len(self._chunks) * CHUNK_ROWS <= self._n:
            self._chunks.append(np.zeros(CHUNK_ROWS, ROW))
        row = self._chunks[-1][k]
        code = self._source_code.get(p.source)
        if code is None:
            if len(self._sources) >= np.iinfo(np.int16).max:
                raise ValueError("more than 32767 distinct pose sources")
            code = self._source_code[p.source] = len(self._sources)
            self._sources.append(p.source)
        row["t_ns"], row["t_cam_ns"] = int(p.t_ns), int(p.t_cam_ns)
        row["R_OI"], row["p_OI"], row["v_OI"] = p.R_OI, p.p_OI, p.v_OI
        row["segment"], row["filter_id"], row["source"] = int(p.segment), int(p.filter_id), code
        row["version"], row["fraction"] = int(version), float(fraction)
        row["T_MI"] = np.asarray(T_MI)[:3, :4]
        self._n += 1

    def rows(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Rows [start, stop) as one structured array (a copy), dtype ROW."""
        stop = self._n if stop is None else min(int(stop), self._n)
        start = max(0, int(start))
        if start >= stop:
            return np.zeros(0, ROW)
        c0, c1 = start // CHUNK_ROWS, (stop - 1) // CHUNK_ROWS
        parts = [self._chunks[c] for c in range(c0, c1 + 1)]
        whole = np.concatenate(parts) if len(parts) > 1 else parts[0]
        off = c0 * CHUNK_ROWS
        return whole[start - off:stop - off].copy()

    def row(self, i: int) -> np.void:
        """Row i (negative counts from the end)."""
        if i < 0:
            i += self._n
        if not 0 <= i < self._n:
            raise IndexError(f"pose {i} out of range (history holds {self._n})")
        return self._chunks[i // CHUNK_ROWS][i % CHUNK_ROWS]

    def source(self, code: int) -> str:
        """The source name ("feedforward", "native:dynamic", ...) a row's `source` code stands for."""
        return self._sources[int(code)]

    def nbytes(self) -> int:
        """Bytes held by the columns (whole chunks)."""
        return sum(c.nbytes for c in self._chunks)


def _published(h: PoseHistory, r: np.void) -> Published:
    """A row as the `Published` state it was recorded from (covariance None)."""
    return Published(int(r["t_ns"]), int(r["t_cam_ns"]), np.array(r["R_OI"]), np.array(r["p_OI"]),
                     np.array(r["v_OI"]), h.source(r["source"]), int(r["filter_id"]), int(r["segment"]))


def _T_MI(r: np.void) -> np.ndarray:
    """A row's map-frame pose T_MI (4,4), its last row [0, 0, 0, 1]."""
    T = np.eye(4)
    T[:3, :4] = r["T_MI"]
    return T


class _View(Sequence):
    """A read-only sequence over a PoseHistory, each row given as `one(row)`; slices are lists."""

    def __init__(self, history: PoseHistory, one: Callable[[np.void], object]) -> None:
        self._h = history
        self._one = one

    def __len__(self) -> int:
        return len(self._h)

    @overload
    def __getitem__(self, i: int): ...
    @overload
    def __getitem__(self, i: slice) -> list: ...

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self._one(self._h.row(k)) for k in range(*i.indices(len(self._h)))]
        return self._one(self._h.row(int(i)))

    def __iter__(self) -> Iterator:
        for k in range(len(self._h)):
            yield self._one(self._h.row(k))


class PublishedView(_View):
    """The published states (`Published`, covariance None)."""

    def __init__(self, history: PoseHistory) -> None:
        super().__init__(history, lambda r: _published(history, r))


class CausalView(_View):
    """The poses as published in the map frame: (T_MI (4,4), correction version, interpolation fraction)."""

    def __init__(self, history: PoseHistory) -> None:
        super().__init__(history, lambda r: (_T_MI(r), int(r["version"]), float(r["fraction"])))
