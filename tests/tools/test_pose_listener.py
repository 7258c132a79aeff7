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
    assert lis.feed(b"hello") == ["not a DAVIO stream datagram (5 bytes): ignored"]
    assert lis.feed(b'{"v": 99, "type": "pose", "seq": 1}') == []       # said once, counted always
    assert lis.report()["foreign"] == 2 and lis.poses == 2
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
                                    "runs": None, "poses_without_frame": 0}
    assert rep["runs"] == [stream.run_id]
    assert "at 0.5 s: publishing metric poses (native:static)" in cap.err
    assert len(_rows(out.read_text())) == 10


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
