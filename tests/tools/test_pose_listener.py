"""`davio listen` and tools.pose_listener: what `--stream` sends is read back (the TUM rows are the poses
sent, read by scipy), losses and late datagrams are counted by seq, a restarted DAVIO and foreign datagrams
are said."""
from __future__ import annotations

import io
import json
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from runtime.errors import ConfigError
from runtime.run_events import RunEvent
from runtime.session import Pose
from tools.cli import main
from tools.pose_listener import PoseListener
from tools.pose_stream import pose_message


def _pose(k: int, prior: bool = True) -> Pose:
    rng = np.random.default_rng(k)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    T[:3, 3] = rng.normal(size=3)
    return Pose(1_000_000_000 + k * 50_000_000, 0, np.eye(4), T, np.zeros(3), None, "native:static", 0, 0,
                T @ T if prior else None)


def _datagram(pose: Pose, seq: int, run: str = "a1b2c3d4") -> bytes:
    return json.dumps(pose_message(pose, seq, run)).encode()


def _rows(text: str) -> np.ndarray:
    return np.array([[float(x) for x in r.split()] for r in text.splitlines() if not r.startswith("#")])


def test_the_listener_writes_the_poses_of_one_frame_and_counts_losses_by_seq():
    tum = io.StringIO()
    lis = PoseListener("map", tum)
    poses = [_pose(k) for k in range(6)]
    said = lis.feed(_datagram(poses[0], 0))
    assert said == ["DAVIO run a1b2c3d4"]
    for seq in (1, 3, 4):                              # 2 is lost
        assert lis.feed(_datagram(poses[seq], seq)) == []
    event = RunEvent(2_000_000_000, 1.0, "reset", "the filter diverged", {})
    said = lis.feed(json.dumps({"type": "event", "v": 1, "run": "a1b2c3d4", "seq": 6, **event.to_json()})
                    .encode())
    assert said == ["at 1.0 s: the filter diverged"]      # 5 lost too ...
    lis.feed(_datagram(poses[5], 5))                      # ... until it comes late
    assert (lis.poses, lis.events, lis.lost, lis.out_of_order) == (5, 1, 1, 1)
    rows = _rows(tum.getvalue())
    sent = [poses[k] for k in (0, 1, 3, 4, 5)]
    np.testing.assert_allclose(rows[:, 0], [p.t_ns / 1e9 for p in sent])
    np.testing.assert_allclose(rows[:, 1:4], [p.T_MI[:3, 3] for p in sent], atol=1e-6)
    for r, p in zip(rows, sent, strict=True):
        np.testing.assert_allclose(Rotation.from_quat(r[4:]).as_matrix(), p.T_MI[:3, :3], atol=1e-8)
    pos, R = lis.last_pose()
    np.testing.assert_allclose(pos, poses[5].T_MI[:3, 3], atol=1e-6)
    np.testing.assert_allclose(R, poses[5].T_MI[:3, :3], atol=1e-8)


def test_a_restarted_davio_a_frame_not_localised_yet_and_foreign_datagrams_are_said():
    lis = PoseListener("prior")
    lis.feed(_datagram(_pose(0), 0, "run1"))
    said = lis.feed(_datagram(_pose(1, prior=False), 0, "run2"))
    assert said == ["DAVIO run run2 (a new run: DAVIO restarted)"]
    assert lis.lost == 0 and lis.runs == ["run1", "run2"] and lis.poses_without_frame == 1
    assert lis.last_pose() is None                       # the newest has no prior-frame pose
    assert lis.feed(b"hello") == ["not a DAVIO stream datagram (5 bytes): ignored (counted)"]
    assert lis.feed(b"[1, 2]") == []                                     # said once, counted always
    said = lis.feed(b'{"v": 99, "type": "pose", "seq": 1}')
    assert said == ["DAVIO stream datagrams of protocol version 99; this listener reads version 1: ignored "
                    "(counted); update davio on this machine"]
    assert lis.report()["foreign"] == 2 and lis.report()["other_version"] == 1 and lis.poses == 2
    with pytest.raises(ValueError, match="frame must be one of"):
        PoseListener("world")


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_until_bound(port: int, timeout_s: float = 20.0) -> None:
    """Wait until a UDP socket is bound on 127.0.0.1:port (Linux: /proc/net/udp; elsewhere 0.5 s)."""
    table = Path("/proc/net/udp")
    if not table.exists():
        time.sleep(0.5)
        return
    local = {f"0100007F:{port:04X}", f"7F000001:{port:04X}"}   # the address in host byte order
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if any(line.split()[1] in local for line in table.read_text().splitlines()[1:]):
            return
        time.sleep(0.02)
    raise AssertionError(f"nothing bound 127.0.0.1:{port} in {timeout_s} s")


def test_davio_listen_receives_a_stream_and_reports_it(tmp_path, capsys):
    from tools.pose_stream import PoseStream

    port = _free_port()
    out = tmp_path / "poses.tum"
    result: list[int] = []
    listening = threading.Thread(target=lambda: result.append(main(
        ["listen", f"udp://127.0.0.1:{port}", "--seconds", "1.5", "--tum", str(out), "--json"])))
    listening.start()
    _wait_until_bound(port)
    stream = PoseStream(f"udp://127.0.0.1:{port}")
    for k in range(10):
        stream.on_pose(_pose(k))
    stream.on_event(RunEvent(1_500_000_000, 0.5, "publishing", "publishing metric poses (native:static)", {}))
    stream.close()
    listening.join(timeout=10)
    assert result == [0]
    cap = capsys.readouterr()
    rep = json.loads(cap.out)
    assert rep | {"runs": None} == {"poses": 10, "events": 1, "lost": 0, "out_of_order": 0, "foreign": 0,
                                    "runs": None, "poses_without_frame": 0, "duplicates": 0, "seq_jumps": 0,
                                    "other_version": 0, "malformed": 0, "not_written": 0, "interleaved": 0}
    assert rep["runs"] == [stream.run_id]
    assert "at 0.5 s: publishing metric poses (native:static)" in cap.err
    assert len(_rows(out.read_text())) == 10


def _msg(pose: Pose, seq: int, run: str = "r1", changes: dict | None = None) -> bytes:
    m = pose_message(pose, seq, run)
    m.update(changes or {})
    return json.dumps(m).encode()


def test_the_tum_file_keeps_increasing_stamps_whatever_arrives():
    """Late, repeated and restarted datagrams wrote stamps going back (evo refuses such a file)."""
    tum = io.StringIO()
    lis = PoseListener("map", tum)
    p = [_pose(k) for k in range(5)]
    for seq in (0, 2, 1, 3, 3):                        # 1 late, 3 twice
        lis.feed(_msg(p[seq], seq))
    lis.feed(_msg(p[0], 0, run="r2"))                  # a restarted DAVIO: its stamps start again
    lis.feed(_msg(p[4], 1, run="r2"))
    t = _rows(tum.getvalue())[:, 0]
    assert list(t) == sorted(set(t)) and len(t) == 4   # 0, 2, 3, then 4 of the new run
    rep = lis.report()
    assert (rep["duplicates"], rep["out_of_order"], rep["lost"], rep["not_written"]) == (1, 1, 0, 2)


@pytest.mark.parametrize("changes, why", [
    ({"seq": float("inf")}, "seq"), ({"seq": -1}, "seq"), ({"seq": 5.7}, "seq"),
    ({"t_ns": None}, "t_ns"), ({"t_ns": "abc"}, "t_ns"), ({"t_ns": -5}, "t_ns"),
    ({"p_MI": "abc"}, "p_MI"), ({"p_MI": [1e308, 10**400, 3]}, "p_MI"), ({"p_MI": [1]}, "p_MI"),
    ({"p_MI": [float("nan"), 1, 2]}, "p_MI"), ({"q_MI": [0, 0, 0, 1, 5, 6]}, "q_MI"),
    ({"q_MI": [0, 0, 0, 0]}, "q_MI"), ({"source": None}, "source"),
])
def test_a_malformed_datagram_is_counted_and_the_listener_goes_on(changes: dict, why: str):
    tum = io.StringIO()
    lis = PoseListener("map", tum)
    lis.feed(_msg(_pose(0), 0))
    said = lis.feed(_msg(_pose(1), 1, changes=changes))
    assert len(said) == 1 and said[0].startswith("malformed DAVIO datagram (") and why in said[0]
    lis.feed(_msg(_pose(2), 2))
    assert lis.malformed == 1 and lis.poses == 2 and lis.last_pose() is not None
    rows = _rows(tum.getvalue())
    assert rows.shape == (2, 8) and np.all(np.isfinite(rows))


def test_hostile_datagrams_neither_crash_nor_drive_the_terminal():
    lis = PoseListener("map")
    huge = {"type": "event", "v": 1, "run": "r0", "seq": 0, "t_ns": 5, "t_s": 10**400, "message": "x"}
    said = lis.feed(json.dumps(huge).encode())                     # float(10**400): OverflowError
    assert said[-1].startswith("malformed DAVIO datagram (t_s")
    deep = b"[" * 32000 + b"]" * 32000                  # RecursionError in json.loads
    assert lis.feed(deep)[0].startswith("not a DAVIO stream datagram")
    event = {"type": "event", "v": 1, "run": "r1", "seq": 0, "t_ns": 5, "t_s": 1.0, "kind": "x",
             "message": "\x1b[2J\x1b]0;pwned\x07hi\nfake line"}
    said = lis.feed(json.dumps(event).encode())
    assert "\x1b" not in said[-1] and "\n" not in said[-1] and "\\x1b[2J" in said[-1]
    lis.feed(_msg(_pose(0), 1, run="r1"))
    lis.feed(_msg(_pose(1), 2**63, run="r1"))          # a stray seq: no 9e18 losses
    lis.feed(_msg(_pose(2), 3, run="r1"))
    assert lis.lost == 0 and lis.seq_jumps == 1
    for k in range(4):                                  # two senders on one port
        lis.feed(_msg(_pose(k), 10 + k, run="r1" if k % 2 else "r2"))
    assert lis.runs == ["r1", "r2"] and lis.interleaved == 2


def test_a_bad_address_or_a_port_in_use_is_a_clear_error(capsys):
    assert main(["listen", "tcp://:5005"]) == 1
    assert "expected udp://[HOST]:PORT" in capsys.readouterr().err
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:
        busy.bind(("127.0.0.1", 0))
        assert main(["listen", f"udp://127.0.0.1:{busy.getsockname()[1]}", "--seconds", "1"]) == 1
    assert capsys.readouterr().err.startswith("davio listen: error: cannot listen on udp://127.0.0.1:")
    assert main(["listen", f"udp://127.0.0.1:{_free_port()}", "--tum", "/nonexistent-folder/poses.tum"]) == 1
    err = capsys.readouterr().err
    assert err == ("davio listen: error: cannot write --tum /nonexistent-folder/poses.tum: No such file or "
                   "directory\n")


def _link_local_address() -> tuple[str, str, int] | None:
    """(address, interface, index) of a link-local IPv6 address of this machine, or None (Linux only)."""
    try:
        lines = open("/proc/net/if_inet6").read().split("\n")
    except OSError:
        return None
    for line in lines:
        f = line.split()
        if len(f) == 6 and f[0].startswith("fe80"):
            return ":".join(f[0][i:i + 4] for i in range(0, 32, 4)), f[5], int(f[1], 16)
    return None


@pytest.mark.skipif(_link_local_address() is None, reason="this machine has no link-local IPv6 address")
def test_a_link_local_address_is_bound_on_the_interface_its_zone_names():
    from tools.commands.listen import bind_listener

    address, interface, index = _link_local_address()
    for zone in (f"%25{interface}", f"%{interface}"):
        port = _free_port()
        with bind_listener(f"udp://[{address}{zone}]:{port}") as sock:
            bound = sock.getsockname()
            assert bound[1] == port and bound[3] == index
    with pytest.raises(ConfigError, match="cannot resolve"):
        bind_listener(f"udp://[{address}%25no-such-interface]:{_free_port()}")


def test_listening_on_every_interface_is_said(capsys):
    port = _free_port()
    assert main(["listen", f"udp://:{port}", "--seconds", "0.2"]) == 0
    assert "(every interface: any machine on the network can send)" in capsys.readouterr().err
    assert main(["listen", f"udp://127.0.0.1:{port}", "--seconds", "0.2"]) == 0
    assert "every interface" not in capsys.readouterr().err
