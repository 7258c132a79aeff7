"""The receiving end of `--stream` (tools.pose_stream), for bring-up and for recording on another machine:
each datagram is checked and counted (poses, events, datagrams lost or out of order by `seq`, a new run
id: DAVIO restarted, datagrams that are not DAVIO's), events are said as they come, and poses can be
written to a TUM file in one frame (odometry, map or prior map) as they come."""
from __future__ import annotations

import json
from collections import deque
from typing import IO, Any

import numpy as np

from runtime.geometry.quaternion import quat_xyzw_to_rot
from tools.evaluation.trajectory_io import TUM_HEADER, tum_line
from tools.pose_stream import MESSAGE_VERSION

FRAMES = {"odometry": "OI", "map": "MI", "prior": "PI"}


MAX_SEQ_JUMP = 1_000_000
"""A seq this far ahead of the run's next is no loss (a day of datagrams at 10 Hz): a foreign or corrupt
counter; it is counted (`seq_jumps`) and the count restarts there."""
_RECENT_SEQS = 4096
"""Seqs remembered per run to tell a duplicate datagram from a late one."""


def printable(text: object, limit: int = 300) -> str:
    """`text` with control characters escaped (an escape sequence from the network must not drive the
    terminal), cut to `limit` characters."""
    s = str(text)[:limit]
    return "".join(ch if ch.isprintable() else ch.encode("unicode_escape").decode("ascii") for ch in s)


def _finite_vector(value: object, n: int, bound: float) -> bool:
    if not isinstance(value, list) or len(value) != n:
        return False
    if not all(isinstance(x, int | float) and not isinstance(x, bool) for x in value):
        return False
    try:
        a = np.asarray(value, dtype=np.float64)
    except OverflowError:           # an integer beyond a float
        return False
    return bool(np.all(np.isfinite(a)) and np.all(np.abs(a) <= bound))


def _problem(msg: dict, key: str) -> str | None:
    """Why a DAVIO datagram of the right version cannot be used, or None."""
    seq, t_ns = msg.get("seq"), msg.get("t_ns")
    if isinstance(seq, bool) or not isinstance(seq, int) or seq < 0:
        return f"seq {printable(seq, 40)} is not a count"
    if not isinstance(msg.get("run", ""), str):
        return "run is not a string"
    if isinstance(t_ns, bool) or not isinstance(t_ns, int) or not 0 <= t_ns < 2**63:
        return f"t_ns {printable(t_ns, 40)} is not a stamp in ns"
    if msg["type"] == "event":
        t_s = msg.get("t_s", 0.0)
        if not _finite_vector([t_s], 1, 1e12):
            return f"t_s {printable(t_s, 40)} is not a number of seconds"
        return None
    if not isinstance(msg.get("source"), str) or isinstance(msg.get("segment"), bool) \
            or not isinstance(msg.get("segment"), int):
        return "a pose without its source or segment"
    p, q = msg.get(f"p_{key}"), msg.get(f"q_{key}")
    if p is None and q is None:
        return None
    if not _finite_vector(p, 3, 1e7):
        return f"p_{key} is not 3 finite coordinates within 1e7 m"
    if not _finite_vector(q, 4, 2.0) or abs(float(np.linalg.norm(q)) - 1.0) > 1e-3:
        return f"q_{key} is not a unit quaternion"
    return None


class PoseListener:
    """Counts and checks what arrives; `feed` returns the console lines a datagram gives (events, a new
    run, a foreign or malformed datagram).

    The TUM file receives a pose only when its stamp is after the last one written (a late or repeated
    datagram, or a restarted DAVIO's stamps starting again, are counted in `not_written`), with finite
    values and a unit quaternion; each line is flushed as it is written.

    Args:
        frame: the frame whose poses `tum` receives and `last_position` holds: odometry, map or prior.
        tum: an open text file for the poses (TUM: t x y z qx qy qz qw), or None.
    """

    def __init__(self, frame: str = "map", tum: IO[str] | None = None) -> None:
        if frame not in FRAMES:
            raise ValueError(f"frame must be one of {', '.join(FRAMES)}, got {frame!r}")
        self.key = FRAMES[frame]
        self.tum = tum
        if tum is not None:
            tum.write(TUM_HEADER + "\n")
            tum.flush()
        self.poses = 0
        self.events = 0
        self.lost = 0
        """Datagrams missing by `seq` (counted when a later one arrives)."""
        self.out_of_order = 0
        self.duplicates = 0
        """Datagrams whose seq already arrived (dropped)."""
        self.seq_jumps = 0
        self.foreign = 0
        """Datagrams that are not a DAVIO stream's (not JSON, not an object, no type)."""
        self.other_version = 0
        """DAVIO datagrams of another protocol version (dropped)."""
        self.malformed = 0
        """DAVIO datagrams with a missing or unusable field (dropped)."""
        self.not_written = 0
        """Poses not written to the TUM file: their stamp is not after the last written."""
        self.runs: list[str] = []
        self.interleaved = 0
        """Datagrams of an earlier run arriving after a newer one's (two senders on one port?)."""
        self.poses_without_frame = 0
        """Poses with no pose in `frame` (a prior-map frame not localised yet)."""
        self.last: dict | None = None
        self._next_seq: dict[str, int] = {}
        self._recent: dict[str, deque[int]] = {}
        self._last_written_ns: int | None = None
        self._said: set[str] = set()

    def _once(self, kind: str, line: str) -> list[str]:
        if kind in self._said:
            return []
        self._said.add(kind)
        return [line]

    def feed(self, data: bytes) -> list[str]:
        """One datagram; returns what to say of it."""
        try:
            msg = json.loads(data)
        except (ValueError, RecursionError):       # not JSON, not UTF-8, nested beyond the parser
            msg = None
        if not isinstance(msg, dict) or msg.get("type") not in ("pose", "event") or "v" not in msg:
            self.foreign += 1
            return self._once("foreign",
                              f"not a DAVIO stream datagram ({len(data)} bytes): ignored (counted)")
        if msg.get("v") != MESSAGE_VERSION:
            self.other_version += 1
            version = printable(msg["v"], 20)
            return self._once("version", f"DAVIO stream datagrams of protocol version {version}; this "
                                         f"listener reads version {MESSAGE_VERSION}: ignored (counted); "
                                         "update davio on this machine")
        why = _problem(msg, self.key)
        if why is not None:
            self.malformed += 1
            return self._once(f"malformed:{why}", f"malformed DAVIO datagram ({why}): ignored (counted)")
        said = self._run_and_seq(msg)
        if said is None:
            return []
        if msg["type"] == "event":
            self.events += 1
            said.append(f"at {float(msg.get('t_s', 0.0)):.1f} s: {printable(msg.get('message', ''))}")
            return said
        self.poses += 1
        self.last = msg
        p, q = msg.get(f"p_{self.key}"), msg.get(f"q_{self.key}")
        if p is None or q is None:
            self.poses_without_frame += 1
        elif self.tum is not None:
            t_ns = msg["t_ns"]
            if self._last_written_ns is not None and t_ns <= self._last_written_ns:
                self.not_written += 1
                said += self._once("not_written", "a pose not after the last one written (a late or repeated "
                                                  "datagram, or a restarted run) is counted, not written: "
                                                  "the TUM file keeps increasing stamps")
            else:
                self.tum.write(tum_line(t_ns, np.asarray(p, float), np.asarray(q, float)) + "\n")
                self.tum.flush()
                self._last_written_ns = t_ns
        return said

    def _run_and_seq(self, msg: dict) -> list[str] | None:
        """Lines to say of the datagram's run and seq; None for a duplicate (dropped)."""
        said: list[str] = []
        run, seq = msg.get("run", ""), msg["seq"]
        if run not in self.runs:
            said.append(f"DAVIO run {printable(run, 40) or '?'}"
                        + (" (a new run: DAVIO restarted)" if self.runs else ""))
            self.runs.append(run)
        elif run != self.runs[-1]:
            self.interleaved += 1
            said += self._once("interleaved", f"datagrams of run {printable(run, 40)} arrive after those of "
                                              f"{printable(self.runs[-1], 40)} (two senders on one port?): "
                                              "counted")
        recent = self._recent.setdefault(run, deque(maxlen=_RECENT_SEQS))
        if seq in recent:
            self.duplicates += 1
            return None
        recent.append(seq)
        nxt = self._next_seq.get(run)
        if nxt is not None:
            if seq - nxt > MAX_SEQ_JUMP:
                self.seq_jumps += 1
                self._next_seq[run] = seq + 1
                return said
            if seq > nxt:
                self.lost += seq - nxt
            elif seq < nxt:
                self.out_of_order += 1
                self.lost = max(0, self.lost - 1)      # one counted lost came late
        self._next_seq[run] = max(seq + 1, nxt or 0)
        return said

    def last_pose(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(position (3,), rotation (3,3)) of the newest pose in the listener's frame, or None."""
        if self.last is None or self.last.get(f"p_{self.key}") is None:
            return None
        return (np.asarray(self.last[f"p_{self.key}"], float),
                quat_xyzw_to_rot(np.asarray(self.last[f"q_{self.key}"], float)))

    def report(self) -> dict[str, Any]:
        """What arrived (`davio listen --json`)."""
        return {"poses": self.poses, "events": self.events, "lost": self.lost,
                "out_of_order": self.out_of_order, "duplicates": self.duplicates, "seq_jumps": self.seq_jumps,
                "foreign": self.foreign, "other_version": self.other_version, "malformed": self.malformed,
                "not_written": self.not_written, "runs": list(self.runs), "interleaved": self.interleaved,
                "poses_without_frame": self.poses_without_frame}
