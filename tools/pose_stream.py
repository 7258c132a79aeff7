"""The published poses and the run's events sent to another process as they happen, without ROS: one UDP
datagram each, holding one JSON object (`davio run|live --stream udp://HOST:PORT`). A robot's controller,
in any language, reads them with a UDP socket and a JSON parser.

A pose datagram (`"type": "pose"`):
    v: the message version (MESSAGE_VERSION); run: a random id of this run (a new one: DAVIO restarted);
    seq: a counter over every datagram of the run from 0 (a gap: lost);
    t_ns: IMU-clock time (ns); t_cam_ns: the camera time of the frame it followed;
    source: the filter publishing ("feedforward", "native:static", ...); segment: resets before it;
    p_OI, q_OI: IMU position (m) and orientation (Hamilton x, y, z, w) in the odometry frame O (gravity
        aligned, z up); v_OI: velocity in O (m/s);
    p_MI, q_MI: the same pose in the map frame M with the live map correction; correction_version;
    p_PI, q_PI: in a prior map's frame (--prior-map), or null until this segment is localised in it;
    cov: the upper triangle, row by row, of the 6x6 covariance of [rotation error (body frame, rad),
        position (m)] (21 numbers), or null.
An event datagram (`"type": "event"`): v, run, seq and the event's fields (runtime.run_events.RunEvent.
to_json: t_ns, t_s, kind, message and the kind's details).

A HOST name with both an IPv4 and an IPv6 address (`localhost`, `robot.local`) is sent to over IPv4: a
receiver bound to an IPv4 socket gets it; give an IPv6 address ([::1]) for IPv6.

Sending never waits and never ends the run: the socket does not block, and a datagram the network stack
refuses is counted (`report()`), as a UDP receiver that is not listening is not an error.
"""
from __future__ import annotations

import secrets
import socket
from typing import Any
from urllib.parse import urlsplit

import numpy as np

from runtime.errors import ConfigError
from runtime.geometry.quaternion import rot_to_quat_xyzw
from runtime.json_out import strict_dumps

MESSAGE_VERSION = 1
MAX_DATAGRAM_BYTES = 1400
"""Largest datagram sent: within a 1500-byte Ethernet MTU (a pose is 650-850 bytes; an event's long line is
cut to fit). Tunnels with a smaller MTU (WireGuard 1420, Tailscale 1280) may fragment one."""
_ROWS, _COLS = np.triu_indices(6)


def parse_stream_url(url: str, what: str = "--stream", host_optional: bool = False) -> tuple[str, int]:
    """(host, port) of "udp://HOST:PORT" (HOST a name, an IPv4 address or a bracketed IPv6 one, a link-local
    one with its zone as RFC 6874 writes it, "[fe80::1%25eth0]", or plainly "[fe80::1%eth0]"; with
    `host_optional`, as `davio listen` takes it, "udp://:PORT" gives host ""); ConfigError naming `what`
    and what is wrong otherwise."""
    form = "udp://[HOST]:PORT" if host_optional else "udp://HOST:PORT"
    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError as exc:
        raise ConfigError(f"{what} {url!r}: {exc}; expected {form}") from None
    if parts.scheme != "udp":
        raise ConfigError(f"{what} {url!r}: only udp:// is supported; expected {form}")
    if not (parts.hostname or host_optional) or port is None or not 0 < port < 65536:
        raise ConfigError(f"{what} {url!r}: expected {form} with a port in 1-65535")
    if parts.path not in ("", "/") or parts.query or parts.fragment or parts.username is not None:
        raise ConfigError(f"{what} {url!r}: expected {form}, nothing before the host or after the port")
    host = parts.hostname or ""
    address, pct, zone = host.partition("%25")      # RFC 6874: an IPv6 zone's "%" is written "%25"
    return (f"{address}%{zone}" if ":" in address and pct and zone else host), port


def resolve_stream_url(url: str) -> tuple[int, tuple]:
    """(address family, socket address) of "udp://HOST:PORT", an IPv4 address preferred (see the module
    docstring); ConfigError when HOST does not resolve."""
    host, port = parse_stream_url(url)
    try:
        found = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)
    except socket.gaierror as exc:
        raise ConfigError(f"--stream {url!r}: cannot resolve {host!r} ({exc.strerror})") from None
    family, _, _, _, addr = next((a for a in found if a[0] == socket.AF_INET), found[0])
    return family, addr


def _rounded(values: Any, digits: int) -> list:
    return [round(float(x), digits) for x in np.asarray(values, dtype=np.float64).ravel()]


def pose_message(pose: Any, seq: int, run_id: str = "") -> dict:
    """The JSON object of one runtime.session.Pose (see the module docstring)."""
    cov = None
    if pose.covariance is not None:
        C = np.asarray(pose.covariance, dtype=np.float64)
        cov = [float(f"{x:.6g}") for x in C[_ROWS, _COLS]]
    frames = {"OI": pose.T_OI, "MI": pose.T_MI, "PI": pose.T_PI}
    given = {k: np.asarray(T, dtype=np.float64) for k, T in frames.items() if T is not None}
    q = dict(zip(given, rot_to_quat_xyzw(np.stack([T[:3, :3] for T in given.values()])), strict=True))
    poses = {}
    for k in frames:
        T = given.get(k)
        poses[f"p_{k}"] = None if T is None else _rounded(T[:3, 3], 6)
        poses[f"q_{k}"] = None if T is None else _rounded(q[k], 9)
    return {"type": "pose", "v": MESSAGE_VERSION, "run": run_id, "seq": seq, "t_ns": int(pose.t_ns),
            "t_cam_ns": int(pose.t_cam_ns), "source": pose.source, "segment": int(pose.segment),
            "p_OI": poses["p_OI"], "q_OI": poses["q_OI"], "v_OI": _rounded(pose.v_OI, 6),
            "p_MI": poses["p_MI"], "q_MI": poses["q_MI"], "correction_version": int(pose.correction_version),
            "p_PI": poses["p_PI"], "q_PI": poses["q_PI"], "cov": cov}


class PoseStream:
    """Sends each pose (`on_pose`) and event (`on_event`) to udp://HOST:PORT (see the module docstring).

    Args:
        url: "udp://HOST:PORT"; a broadcast address (e.g. 192.168.1.255) reaches every host of that subnet.
    """

    def __init__(self, url: str) -> None:
        self.url = url
        family, self.address = resolve_stream_url(url)
        self.run_id = secrets.token_hex(4)
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self._sock.setblocking(False)
            if family == socket.AF_INET:
                self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        except OSError:
            self._sock.close()
            raise
        self.seq = 0
        self.sent = {"pose": 0, "event": 0}
        self.not_sent = 0
        self.first_error: str | None = None

    def on_pose(self, pose: Any) -> None:
        """Send one runtime.session.Pose."""
        self._send(pose_message(pose, self.seq, self.run_id))

    def on_event(self, event: Any) -> None:
        """Send one runtime.run_events.RunEvent."""
        self._send({"type": "event", "v": MESSAGE_VERSION, "run": self.run_id, "seq": self.seq,
                    **event.to_json()})

    def _send(self, message: dict) -> None:
        self.seq += 1
        data = strict_dumps(message, separators=(",", ":")).encode()
        text = message.get("message", "")
        while len(data) > MAX_DATAGRAM_BYTES and text:     # an event's long line: cut, the JSON still whole
            text = text[:len(text) // 2]
            data = strict_dumps({**message, "message": text + "..."}, separators=(",", ":")).encode()
        try:
            if self._sock.fileno() < 0:
                return
            self._sock.sendto(data, self.address)
        except OSError as exc:      # a full send buffer, no route, a refused port: counted, never raised
            self.not_sent += 1
            if self.first_error is None:
                self.first_error = f"{type(exc).__name__}: {exc.strerror or exc}"
            return
        self.sent[message["type"]] += 1

    def report(self) -> dict:
        """What was sent (report.json's `stream`)."""
        return {"url": self.url, "poses_sent": self.sent["pose"], "events_sent": self.sent["event"],
                "not_sent": self.not_sent, "first_error": self.first_error}

    def close(self) -> None:
        """Close the socket (idempotent)."""
        self._sock.close()


def open_stream(url: str | None) -> PoseStream | None:
    """The PoseStream of --stream (None without it), its address said on stderr."""
    if url is None:
        return None
    import sys

    stream = PoseStream(url)
    print(f"  streaming poses and events to {url} (UDP, one JSON object a datagram)", file=sys.stderr,
          flush=True)
    return stream
