"""`davio listen`: receive what `davio run|live --stream udp://HOST:PORT` sends, here or elsewhere."""
from __future__ import annotations

import argparse
import socket
import sys
import time
from pathlib import Path

from tools.cli_types import number

NAME = "listen"
HELP = "receive a --stream (poses and events over UDP): say events, count losses, record poses as TUM"
DESCRIPTION = (
    "Listens on udp://[HOST]:PORT for what `davio run` / `davio live --stream udp://THIS_HOST:PORT` sends "
    "(tools/pose_stream.py): says each event as it comes, shows a status line once a second (poses a "
    "second, the newest position, who publishes, datagrams lost by seq), and with --tum writes the poses "
    "of one frame as they come. Ends on Ctrl-C, SIGTERM, or after --seconds; then prints what arrived "
    "(--json: one JSON object on stdout).")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("url", metavar="udp://[HOST]:PORT",
                   help="where to listen: udp://:5005 on every interface, udp://127.0.0.1:5005 on one")
    p.add_argument("--tum", metavar="FILE", help="write the poses as they come (TUM; evo reads it)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --tum file")
    p.add_argument("--frame", choices=["odometry", "map", "prior"], default="map",
                   help="the frame of the poses written and shown (default: map)")
    p.add_argument("--seconds", type=number, default=None, help="stop after S seconds (> 0)")
    p.add_argument("--json", action="store_true", help="print what arrived as one JSON object at the end")


def bind_listener(url: str) -> socket.socket:
    """A UDP socket bound to "udp://[HOST]:PORT" (an IPv6 host's zone, "%eth0" or "%25eth0", picks the
    interface: the address is resolved with its scope id, which a bare (host, port) pair would leave 0);
    ConfigError when it cannot be bound."""
    from runtime.errors import ConfigError
    from tools.pose_stream import parse_stream_url

    host, port = parse_stream_url(url, "the address", host_optional=True)
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    address: tuple = (host, port)
    if "%" in host:
        try:
            address = socket.getaddrinfo(host, port, family, socket.SOCK_DGRAM, 0, socket.AI_PASSIVE)[0][4]
        except socket.gaierror as exc:
            raise ConfigError(f"cannot resolve {host!r} ({exc.strerror})") from None
    sock = socket.socket(family, socket.SOCK_DGRAM)
    try:
        sock.bind(address)
    except OSError as exc:
        sock.close()
        raise ConfigError(f"cannot listen on {url}: {exc.strerror or exc}") from None
    return sock


def run(args: argparse.Namespace) -> int:
    import math

    from runtime.errors import ConfigError
    from runtime.json_out import strict_dumps
    from tools.pose_listener import PoseListener
    from tools.run_outcome import interruptible

    if args.seconds is not None and not (math.isfinite(args.seconds) and args.seconds > 0):
        raise ConfigError(f"--seconds must be a finite number > 0 (got {args.seconds!r})")
    if args.tum is not None and Path(args.tum).exists() and not args.overwrite:
        raise ConfigError(f"--tum {args.tum}: exists; pass --overwrite to replace it, or choose another "
                          "file")
    sock = bind_listener(args.url)
    sock.settimeout(0.2)
    try:
        tum = open(args.tum, "w", encoding="utf-8") if args.tum else None   # noqa: SIM115 - closed below
    except OSError as exc:
        sock.close()
        raise ConfigError(f"cannot write --tum {args.tum}: {exc.strerror or exc}") from None
    listener = PoseListener(args.frame, tum)
    tty = sys.stderr.isatty()
    host = sock.getsockname()[0]
    every = " (every interface: any machine on the network can send)" if host in ("0.0.0.0", "::") else ""
    print(f"davio listen: on {args.url}{every} ({args.frame} frame)"
          + (f", poses to {args.tum}" if tum else "") + "; Ctrl-C to finish", file=sys.stderr, flush=True)
    t0 = last = time.monotonic()
    poses0 = 0
    try:
        with interruptible():
            while args.seconds is None or time.monotonic() - t0 < args.seconds:
                try:
                    data = sock.recv(65536)
                except TimeoutError:
                    data = None
                for line in listener.feed(data) if data is not None else []:
                    print(("\r\033[K" if tty else "") + f"  {line}", file=sys.stderr, flush=True)
                now = time.monotonic()
                if now - last >= 1.0:
                    _status(listener, (listener.poses - poses0) / (now - last), tty)
                    last, poses0 = now, listener.poses
    except KeyboardInterrupt:
        pass
    finally:
        sock.close()
        if tum is not None:
            tum.close()
        if tty:
            print(file=sys.stderr)
    rep = listener.report()
    if args.json:
        print(strict_dumps(rep))
    else:
        dropped = {"duplicates": "duplicates", "malformed": "malformed",
                   "other_version": "of another version", "not_written": "poses not written (not after the "
                   "last)", "seq_jumps": "seq jumps", "interleaved": "of an earlier run"}
        extra = "".join(f", {text} {rep[k]}" for k, text in dropped.items() if rep[k])
        print(f"  received {rep['poses']} poses and {rep['events']} events from {len(rep['runs'])} run(s); "
              f"lost {rep['lost']}, out of order {rep['out_of_order']}, not DAVIO's {rep['foreign']}{extra}"
              + (f"; {rep['poses_without_frame']} poses had no {args.frame}-frame pose" if
                 rep["poses_without_frame"] else ""))
    return 0


def _status(listener, rate: float, tty: bool) -> None:
    last = listener.last_pose()
    where = "-" if last is None else "[" + " ".join(f"{x:+.3f}" for x in last[0]) + "] m"
    from tools.pose_listener import printable

    who = "-" if listener.last is None else (f"{printable(listener.last['source'], 40)} "
                                             f"(segment {listener.last['segment']})")
    line = f"  {rate:5.1f} poses/s  {where}  {who}  lost {listener.lost}"
    print(("\r" + line) if tty else line, end="" if tty else "\n", file=sys.stderr, flush=True)
