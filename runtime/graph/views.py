"""Centre views kept for revisits, and how much two of them see of the same scene.

A submap's centre view (matcher features of its centre image and a `RevisitView`: keypoints with their
corrected depths) is what a later revisit is verified against. Views of resident nodes are all kept;
when a node is evicted its view is archived, compactly (descriptors as float16), unless an archived view
already covers the same place: a centre within `view_thin_radius_m` whose optical axis lies within
`view_thin_angle_deg` (the older view is kept: a loop closes on the first visit). At most `max_views`
views are held; beyond that, evicted views are not archived. Memory therefore grows with the explored
space, not with time, and stays below `max_views` views (about 290 kB each with the three-level
pyramid's 1782 XFeat keypoints, 170 kB with 1024 single-scale ones).

`view_overlap` ranks revisit candidates by how much of b's view a could match: the share of b's keypoints
(back-projected with their depths, both views placed by the graph's current states) that land in a's image
in front of its camera, seen from both centres along rays at most `max_ray_angle_deg` apart and at depths
within a factor `max_scale_change` (a local descriptor matches across a moderate change of viewpoint and
scale only).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from runtime.graph.config import RevisitConfig
from runtime.graph.revisits import RevisitView


@dataclass
class ViewStats:
    """Counters of the view store (report.json "mapping.graph.views")."""

    stored: int = 0
    archived: int = 0
    thinned: int = 0
    capped: int = 0


@dataclass
class _Entry:
    features: Any
    view: RevisitView
    archived: bool = False
    centre_M: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis_M: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))


def compact_features(features: Any) -> Any:
    """The features with float descriptors stored as float16 (binary ORB descriptors unchanged)."""
    desc = getattr(features, "desc", None)
    if desc is None or not np.issubdtype(np.asarray(desc).dtype, np.floating):
        return features
    return replace(features, desc=np.asarray(desc, np.float16))


def expanded_features(features: Any) -> Any:
    """The features with float16 descriptors as float32 (others unchanged)."""
    desc = getattr(features, "desc", None)
    if desc is not None and np.asarray(desc).dtype == np.float16:
        return replace(features, desc=np.asarray(desc, np.float32))
    return features


class ViewStore:
    """Centre views by node id: resident ones as given, evicted ones archived with thinning and a cap."""

    def __init__(self, cfg: RevisitConfig | None = None) -> None:
        self.cfg = cfg or RevisitConfig()
        self._views: dict[int, _Entry] = {}
        self.stats = ViewStats()

    def __contains__(self, j: int) -> bool:
        return int(j) in self._views

    def __len__(self) -> int:
        return len(self._views)

    @property
    def ids(self) -> list[int]:
        """Node ids with a view, oldest first."""
        return sorted(self._views)

    def add(self, j: int, features: Any, view: RevisitView) -> None:
        """Keep the view of a new (resident) node j."""
        self._views[int(j)] = _Entry(features, view)
        self.stats.stored += 1

    def get(self, j: int) -> tuple[Any, RevisitView]:
        """(features with float32 descriptors, RevisitView) of node j."""
        e = self._views[int(j)]
        return (expanded_features(e.features) if e.archived else e.features), e.view

    def archive(self, j: int, T_MS: np.ndarray) -> bool:
        """Node j left the graph at pose T_MS (4,4): keep its view compactly, or drop it when an archived
        view covers the same place or the store is full. Returns True when it was archived."""
        j = int(j)
        e = self._views.get(j)
        if e is None or e.archived:
            return e is not None
        centre, axis = np.asarray(T_MS, np.float64)[:3, 3], np.asarray(T_MS, np.float64)[:3, 2]
        cos_max = np.cos(np.radians(self.cfg.view_thin_angle_deg))
        for o in self._views.values():
            if o.archived and (np.linalg.norm(o.centre_M - centre) <= self.cfg.view_thin_radius_m
                               and float(o.axis_M @ axis) >= cos_max):
                del self._views[j]
                self.stats.thinned += 1
                return False
        if sum(o.archived for o in self._views.values()) >= self.cfg.max_views:
            del self._views[j]
            self.stats.capped += 1
            return False
        self._views[j] = _Entry(compact_features(e.features), e.view, True, centre.copy(), axis.copy())
        self.stats.archived += 1
        return True

    def drop(self, j: int) -> None:
        """Forget node j's view (its node left without being archived)."""
        self._views.pop(int(j), None)

    def clear(self) -> None:
        """Forget every view (a new odometry segment: the old views live in another frame)."""
        self._views.clear()


def view_overlap(a: RevisitView, T_MS_a: np.ndarray, b: RevisitView, T_MS_b: np.ndarray,
                 max_ray_angle_deg: float = 180.0, max_scale_change: float = np.inf,
                 max_depth_m: float = 20.0) -> float:
    """Share of b's keypoints with a valid depth that a could match: back-projected in S_b and moved into
    S_a by the two map poses (4,4), in front of a (0 < z <= max_depth_m), inside a's image, with the rays
    from the two centres at most max_ray_angle_deg apart and the ranges within a factor max_scale_change."""
    P = b.points(np.arange(len(b.kpts)))
    P = P[np.isfinite(P).all(axis=1)]
    if not len(P):
        return 0.0
    T_ab = np.linalg.inv(np.asarray(T_MS_a, np.float64)) @ np.asarray(T_MS_b, np.float64)
    q = P @ T_ab[:3, :3].T + T_ab[:3, 3]                 # in S_a
    r_b = P @ T_ab[:3, :3].T                              # the ray from b's centre, in S_a axes
    z = q[:, 2]
    ok = (z > 1e-3) & (z <= max_depth_m)
    uv = q @ a.K.T
    uv = uv[:, :2] / np.where(ok, uv[:, 2], 1.0)[:, None]
    w, h = a.image_size
    ok &= (uv[:, 0] >= -0.5) & (uv[:, 0] <= w - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= h - 0.5)
    n_a, n_b = np.linalg.norm(q, axis=1), np.linalg.norm(r_b, axis=1)
    cos = np.einsum("ij,ij->i", q, r_b) / np.maximum(n_a * n_b, 1e-12)
    ok &= cos >= np.cos(np.radians(min(max_ray_angle_deg, 180.0)))
    ok &= np.maximum(n_a, n_b) <= max_scale_change * np.minimum(n_a, n_b)
    return float(ok.sum()) / len(P)
