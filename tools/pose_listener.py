"""The receiving end of `--stream` (tools.pose_stream), for bring-up and for recording on another machine:
each datagram is checked and counted (poses, events, datagrams lost or out of order by `seq`, a new run
id: DAVIO restarted, datagrams that are not DAVIO's), events are said as they come, and poses can be
written to a TUM file in one frame (odometry, map or prior map) as they come."""
from __future__ import annotations

import json
from typing import IO, Any

import numpy as np

from runtime.geometry.quaternion import quat_xyzw_to_rot
from tools.evaluation.trajectory_io import TUM_HEADER, tum_line
from tools.pose_stream import MESSAGE_VERSION

FRAMES = {"odometry": "OI", "map": "MI", "prior": "PI"}


class PoseListener:
    """Counts and checks what arrives; `feed` returns the console lines a datagram gives (events, a new
    run, a foreign datagram).

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
        self.poses = 0
        self.events = 0
        self.lost = 0
        """Datagrams missing by `seq` (counted when a later one arrives)."""
        self.out_of_order = 0
        self.foreign = 0
        """Datagrams that are not a DAVIO stream's (not JSON, another version, no type)."""
        self.runs: list[str] = []
        self.poses_without_frame = 0
        """Poses with no pose in `frame` (a prior-map frame not localised yet)."""
        self.last: dict | None = None
        self._next_seq: int | None = None

    def feed(self, data: bytes) -> list[str]:
        """One datagram; returns what to say of it."""
        try:
            msg = json.loads(data)
            ok = (isinstance(msg, dict) and msg.get("v") == MESSAGE_VERSION
                  and msg.get("type") in ("pose", "event"))
            seq = int(msg["seq"]) if ok else None
        except (ValueError, KeyError, TypeError):
            ok = False
        if not ok:
            self.foreign += 1
            return [f"not a DAVIO stream datagram ({len(data)} bytes): ignored"] if self.foreign == 1 else []
        said = []
        run = str(msg.get("run", ""))
        if not self.runs or run != self.runs[-1]:
            said.append(f"DAVIO run {run or '?'}" + (" (a new run: DAVIO restarted)" if self.runs else ""))
            self.runs.append(run)
            self._next_seq = None
        if self._next_seq is not None:
            if seq > self._next_seq:
                self.lost += seq - self._next_seq
            elif seq < self._next_seq:
                self.out_of_order += 1
                self.lost = max(0, self.lost - 1)      # one counted lost came late
        self._next_seq = max(seq + 1, self._next_seq or 0)
        if msg["type"] == "event":
            self.events += 1
            said.append(f"at {float(msg.get('t_s', 0.0)):.1f} s: {msg.get('message', '')}")
            return said
        self.poses += 1
        self.last = msg
        p, q = msg.get(f"p_{self.key}"), msg.get(f"q_{self.key}")
        if p is None or q is None:
            self.poses_without_frame += 1
        elif self.tum is not None:
            self.tum.write(tum_line(int(msg["t_ns"]), np.asarray(p, float), np.asarray(q, float)) + "\n")
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
                "out_of_order": self.out_of_order, "foreign": self.foreign, "runs": list(self.runs),
                "poses_without_frame": self.poses_without_frame}
