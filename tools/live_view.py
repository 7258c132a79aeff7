"""An optional browser view of a running session: the map-frame trajectory, the current body frame and
the map's points as the mapper commits them.

It uses viser (https://github.com/nerfstudio-project/viser, MIT): a pure-Python package (a 4 MB wheel)
whose server runs inside the DAVIO process and serves the viewer as a web page, so a robot without a
screen is watched from any laptop's browser at http://ROBOT:PORT with nothing to install there. (rerun
is as well kept, but ships a 170 MB native viewer and needs its viewer on the watching machine; foxglove
needs its desktop or web app and an account.) viser is an optional extra: `pip install 'davio[view]'`;
nothing else in DAVIO imports it.

    view = LiveView(port=8080)                       # prints nothing; view.url says where to look
    session = Session(rig, model, on_pose=view.on_pose, map_sink=view.chain(map_out.sink))
    ...
    view.close()

Updates come from the session's threads (poses from the scheduler, map commits from the model worker);
every update is cheap and throttled, and a failing view never stops the run (errors are counted).
"""
from __future__ import annotations

import argparse
import contextlib
import socket
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from runtime.errors import ConfigError

DEFAULT_HOST = "0.0.0.0"
"""Interface the view listens on by default: every one (reachable from other machines)."""
DEFAULT_PORT = 8080
TRAJECTORY_RGB = (255, 140, 0)
"""Colour of the published map-frame trajectory."""


def _wxyz(R: np.ndarray) -> np.ndarray:
    """Hamilton quaternion (w, x, y, z) of a rotation matrix (viser's convention)."""
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return np.array([w, x, y, z])


class LiveView:
    """A viser server showing a session (module docstring).

    Args:
        port: TCP port of the web viewer (viser takes the next free one when it is busy: see `url`).
        host: interface to listen on ("0.0.0.0": reachable from other machines).
        max_trajectory: trajectory points kept (older ones are thinned out by half when full).
        max_points_per_submap: map points sent per committed submap (a random subset).
        min_interval_s: the trajectory is redrawn at most this often.
        max_clouds: submaps drawn one by one; when `history_every` more are drawn, the least recently drawn
            ones are folded into the history cloud, sent again whole (viser keeps every drawn cloud for new
            browsers: a long run's view grew by about 15 MB a minute).
        max_history_points: points the history cloud holds (a uniform sample of every folded submap's).
    """

    def __init__(self, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST, max_trajectory: int = 20000,
                 max_points_per_submap: int = 20000, min_interval_s: float = 0.1, max_clouds: int = 64,
                 max_history_points: int = 300_000, history_every: int = 16) -> None:
        try:
            import viser
        except ImportError as exc:
            raise ConfigError("the live view needs viser: pip install 'davio[view]' (or pip install viser)"
                              ) from exc
        with contextlib.redirect_stdout(sys.stderr):     # viser's banner: stdout stays for --json
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
        self.host = host
        self.server.scene.set_up_direction("+z")
        self.max_trajectory = int(max_trajectory)
        self.max_points = int(max_points_per_submap)
        self.min_interval_s = float(min_interval_s)
        self._lock = threading.Lock()
        # map commits come from the model worker, a reset's clearing from the scheduler's: one at a time
        self._map_lock = threading.RLock()
        self._trajectory: list[np.ndarray] = []
        self._last_draw = 0.0
        self._rng = np.random.default_rng(0)
        self.poses = 0
        self.submaps = 0
        self.errors = 0
        self.last_error = ""
        self.body = self.server.scene.add_frame("/body", axes_length=0.3, axes_radius=0.015)
        self.path = None
        self.clouds: dict[int, Any] = {}
        self.max_clouds = int(max_clouds)
        self.max_history_points = int(max_history_points)
        self.history_every = int(history_every)
        self.history = None                     # the cloud of folded submaps (viser handle)
        self._history_pts = np.zeros((0, 3), np.float32)
        self._history_rgb = np.zeros((0, 3), np.uint8)
        self._history_seen = 0                  # points folded so far (the sample's denominator)
        self._folded: set[int] = set()          # submaps in the history: not drawn again when moved later
        self.submaps_folded = 0
        self.segment: int | None = None
        """The filter segment drawn: a reset starts a new odometry and map frame, so the view starts over
        (the earlier segment's trajectory and points would lie in an unrelated frame)."""
        self.segments_cleared = 0

    @property
    def url(self) -> str:
        """Where to point a browser (localhost when it listens on every interface; from another machine
        use this machine's address then)."""
        host = "localhost" if self.host in ("0.0.0.0", "::", "") else self.host
        host = f"[{host}]" if ":" in host else host
        return f"http://{host}:{self.server.get_port()}"

    def _guard(self, fn: Callable[[], None]) -> None:
        try:
            fn()
        except Exception as exc:  # noqa: BLE001 - the view must never stop the run
            self.errors += 1
            self.last_error = f"{type(exc).__name__}: {exc}"

    # -- poses ---------------------------------------------------------------------------------
    def on_pose(self, pose: Any) -> None:
        """A published pose (runtime.session.Pose): moves the body frame, extends the trajectory."""
        self._guard(lambda: self._pose(np.asarray(pose.T_MI, np.float64), int(getattr(pose, "segment", 0))))

    def _pose(self, T_MI: np.ndarray, segment: int = 0) -> None:
        if T_MI.shape != (4, 4) or not np.isfinite(T_MI).all():
            raise ValueError(f"pose T_MI is not a finite 4x4 matrix (shape {T_MI.shape})")
        self._new_segment(segment)
        with self._lock:
            self.poses += 1
            self._trajectory.append(T_MI[:3, 3].copy())
            if len(self._trajectory) > self.max_trajectory:
                self._trajectory = self._trajectory[::2]
            now = time.monotonic()
            if now - self._last_draw < self.min_interval_s:
                return
            self._last_draw = now
            pts = np.array(self._trajectory)
        self.body.position = T_MI[:3, 3]
        self.body.wxyz = _wxyz(T_MI[:3, :3])
        if len(pts) >= 2:
            seg = np.stack([pts[:-1], pts[1:]], axis=1)
            if self.path is None:
                self.path = self.server.scene.add_line_segments("/trajectory", seg, TRAJECTORY_RGB,
                                                               thickness=2.0, thickness_units="screen")
            else:
                self.path.points = seg

    # -- map -----------------------------------------------------------------------------------
    def on_map(self, commit: Any, stats: Any = None) -> None:
        """A map commit (runtime.mapping.MapCommit): shows the new submap's points at its graph state and
        moves the resident submaps the graph moved."""
        self._guard(lambda: self._map(commit))

    def _new_segment(self, segment: int) -> None:
        """Start over when the filter was reset (a later segment): clear the trajectory and the points."""
        if self.segment is not None and segment <= self.segment:
            return
        with self._map_lock, self._lock:   # poses come from the scheduler's thread, commits from the worker's
            if self.segment is not None and segment <= self.segment:
                return
            first = self.segment is None
            self.segment = segment
            if first:
                return
            self._trajectory = []
            path, self.path = self.path, None
            clouds, self.clouds = list(self.clouds.values()), {}
            history, self.history = self.history, None
            self._history_pts, self._history_rgb = self._history_pts[:0], self._history_rgb[:0]
            self._history_seen = 0
            self._folded = set()
            self.segments_cleared += 1
        for item in (path, history, *clouds):
            if item is not None:
                item.remove()

    def _map(self, commit: Any) -> None:
        with self._map_lock:
            self._map_locked(commit)

    def _map_locked(self, commit: Any) -> None:
        seg = getattr(commit.submap, "segment", None)
        if seg is not None:
            if self.segment is not None and seg < self.segment:
                return                           # a window of the segment before the reset, mapped late
            self._new_segment(int(seg))
        for sm in (commit.submap, *commit.changed):
            if not hasattr(sm, "points_M") or sm.index in self._folded:
                continue       # a submap that left memory, or one folded into the history: stays as drawn
            P = sm.points_M()
            grey = np.asarray(sm.grey)
            if len(P) > self.max_points:
                keep = self._rng.choice(len(P), self.max_points, replace=False)
                P, grey = P[keep], grey[keep]
            rgb = np.repeat(grey[:, None], 3, axis=1).astype(np.uint8)
            old = self.clouds.pop(sm.index, None)
            if old is not None:
                old.remove()
            self.clouds[sm.index] = self.server.scene.add_point_cloud(
                f"/map/submap_{sm.index:05d}", P.astype(np.float32), rgb, point_size=0.03)
        self.submaps += 1
        if len(self.clouds) >= self.max_clouds + self.history_every:
            while len(self.clouds) > self.max_clouds:
                index = next(iter(self.clouds))
                self._fold(self.clouds.pop(index))
                self._folded.add(index)
            # the same name: viser replaces the node (and its buffered message) with the new cloud
            self.history = self.server.scene.add_point_cloud(
                "/map/history", self._history_pts, self._history_rgb, point_size=0.03)

    def _fold(self, cloud: Any) -> None:
        """Move a drawn submap's points into the history cloud: a uniform sample of at most
        `max_history_points` of every folded point (each point seen is kept with the same probability)."""
        pts, rgb = np.asarray(cloud.points, np.float32), np.asarray(cloud.colors, np.uint8)
        cloud.remove()
        seen = self._history_seen + len(pts)
        if seen > self.max_history_points:
            # each held point stands for max(seen before, M) / M points: kept with M / seen in all
            keep_old = self._rng.random(len(self._history_pts)) < max(self._history_seen,
                                                                      self.max_history_points) / seen
            keep_new = self._rng.random(len(pts)) < self.max_history_points / seen
            pts = np.concatenate([self._history_pts[keep_old], pts[keep_new]])
            rgb = np.concatenate([self._history_rgb[keep_old], rgb[keep_new]])
            if len(pts) > self.max_history_points:
                keep = self._rng.choice(len(pts), self.max_history_points, replace=False)
                pts, rgb = pts[keep], rgb[keep]
        else:
            pts = np.concatenate([self._history_pts, pts])
            rgb = np.concatenate([self._history_rgb, rgb])
        self._history_pts, self._history_rgb, self._history_seen = pts, rgb, seen
        self.submaps_folded += 1

    def chain(self, sink: Callable[[Any, Any], None] | None) -> Callable[[Any, Any], None]:
        """A map sink that calls `sink` (the run's archive, or None) and then shows the commit."""

        def both(commit: Any, stats: Any) -> None:
            if sink is not None:
                sink(commit, stats)
            self.on_map(commit, stats)

        return both

    def report(self) -> dict:
        """Counters for report.json: poses and commits shown, view errors."""
        return {"url": self.url, "poses": self.poses, "submaps": self.submaps, "errors": self.errors,
                "last_error": self.last_error, "segments_cleared": self.segments_cleared,
                "submaps_folded": self.submaps_folded, "history_points": len(self._history_pts)}

    def close(self) -> None:
        """Stop the web server."""
        with contextlib.redirect_stdout(sys.stderr):
            self._guard(self.server.stop)


def add_view_argument(p: Any) -> None:
    """The `--view [[HOST:]PORT]` option of `davio run` and `davio live`."""
    p.add_argument("--view", nargs="?", const=(DEFAULT_HOST, DEFAULT_PORT), type=view_address, default=None,
                   metavar="[HOST:]PORT",
                   help=f"serve a live view of the trajectory and the map in a browser at http://HOST:PORT "
                        f"(default port {DEFAULT_PORT}, on every interface: reachable from other machines, "
                        f"without a password; 127.0.0.1:PORT keeps it to this machine; needs the optional "
                        f"viser package: pip install 'davio[view]')")


def view_address(text: str) -> tuple[str, int]:
    """`--view`'s value: (host, port) from `PORT`, `HOST:PORT` or `[IPv6]:PORT` (argparse type)."""
    host, sep, port_text = text.strip().rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    elif host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    elif ":" in host or text.strip().startswith("["):
        raise argparse.ArgumentTypeError(f"{text!r}: an IPv6 address goes in brackets, with a port: "
                                         "[::1]:8080")
    if sep and not host:
        raise argparse.ArgumentTypeError(f"{text!r}: no host before ':' (PORT alone: every interface)")
    if not (port_text.isascii() and port_text.isdigit()) or not 0 < int(port_text) < 65536:
        raise argparse.ArgumentTypeError(f"{text!r}: the port must be a TCP port (1-65535), as in 8080 or "
                                         "127.0.0.1:8080")
    return host, int(port_text)


def _check_listenable(host: str) -> None:
    """Refuse a host this machine cannot listen on (viser would retry port after port without end)."""
    try:
        family, _, _, _, address = socket.getaddrinfo(host, None, type=socket.SOCK_STREAM,
                                                      flags=socket.AI_PASSIVE)[0]
    except (socket.gaierror, UnicodeError) as exc:
        raise ConfigError(f"--view: {host!r} is not a host name or address this machine resolves "
                          f"({getattr(exc, 'strerror', None) or exc})") from None
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        try:
            probe.bind((address[0], 0))
        except OSError as exc:
            raise ConfigError(f"--view: cannot listen on {host} ({exc.strerror or exc}): not an address of "
                              f"this machine") from None


def open_view(address: tuple[str, int] | int | None) -> LiveView | None:
    """The live view at `address` ((host, port), a port on every interface, None: no view), its address
    printed on stderr."""
    if address is None:
        return None
    host, port = (DEFAULT_HOST, address) if isinstance(address, int) else address
    if not 0 < int(port) < 65536:
        raise ConfigError(f"--view: {port} is not a TCP port (1-65535)")
    _check_listenable(host)
    view = LiveView(port=int(port), host=host)
    served = view.server.get_port()
    busy = f"port {port} is busy: " if served != int(port) else ""
    if host in ("0.0.0.0", "::", ""):
        reach = (f"open to the network, without a password: from another machine "
                 f"http://<this machine's address>:{served}; --view 127.0.0.1:{port} keeps it to this "
                 f"machine")
    elif _is_loopback(host):
        reach = "this machine only"
    else:
        reach = f"on {host} only, without a password"
    print(f"  live view: {busy}{view.url} ({reach})", file=sys.stderr, flush=True)
    return view


def _is_loopback(host: str) -> bool:
    try:
        addresses = {info[4][0] for info in socket.getaddrinfo(host, None, type=socket.SOCK_STREAM)}
    except (socket.gaierror, UnicodeError):
        return False
    return all(a.startswith("127.") or a == "::1" for a in addresses)
