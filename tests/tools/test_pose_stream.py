"""Poses and events over UDP (tools.pose_stream): the URL checked before any work, a pose read back by a
plain socket equals the one sent (scipy reads the quaternion), the covariance's upper triangle rebuilds it,
every datagram fits an MTU, and a refused datagram is counted, never raised."""
from __future__ import annotations

import json
import socket

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from runtime.errors import ConfigError
from runtime.run_events import RunEvent
from runtime.session import Pose
from tools.pose_stream import MAX_DATAGRAM_BYTES, PoseStream, parse_stream_url, resolve_stream_url


@pytest.fixture
def receiver():
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(5.0)
    yield sock
    sock.close()


def _pose(seed: int = 0, prior: bool = False) -> Pose:
    rng = np.random.default_rng(seed)

    def T() -> np.ndarray:
        out = np.eye(4)
        out[:3, :3] = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
        out[:3, 3] = rng.normal(scale=5.0, size=3)
        return out

    A = rng.normal(size=(6, 6))
    return Pose(1_403_636_580_013_555_456, 1_403_636_580_013_555_000, T(), T(), rng.normal(size=3),
                A @ A.T * 1e-4, "feedforward", 1, 3, T() if prior else None)


def test_the_url_is_udp_host_port_and_anything_else_is_a_clear_error():
    assert parse_stream_url("udp://127.0.0.1:9870") == ("127.0.0.1", 9870)
    assert parse_stream_url("udp://robot.local:5005/") == ("robot.local", 5005)
    assert parse_stream_url("udp://[::1]:5005") == ("::1", 5005)
    for bad, said in (("tcp://127.0.0.1:9870", "only udp://"), ("udp://127.0.0.1", "port in 1-65535"),
                      ("udp://127.0.0.1:0", "port in 1-65535"), ("udp://127.0.0.1:99999", "udp://HOST:PORT"),
                      ("udp://:9870", "port in 1-65535"), ("udp://127.0.0.1:9870/poses", "after the port"),
                      ("udp://robot:pw@127.0.0.1:9870", "nothing before the host"),
                      ("127.0.0.1:9870", "only udp://")):
        with pytest.raises(ConfigError, match="--stream") as err:
            parse_stream_url(bad)
        assert said in str(err.value), bad


@pytest.mark.skipif(not socket.has_ipv6, reason="this Python was built without IPv6")
def test_a_link_local_ipv6_address_with_its_zone_resolves_to_that_interface():
    # RFC 6874 writes the zone's "%" as "%25" inside a URL; both spellings name the interface
    assert parse_stream_url("udp://[fe80::1%25eth0]:5005") == ("fe80::1%eth0", 5005)
    assert parse_stream_url("udp://[fe80::1%eth0]:5005") == ("fe80::1%eth0", 5005)
    # only "%25" is an escape: a zone by number or beginning with hex digits is taken as written
    assert parse_stream_url("udp://[fe80::1%12]:5005") == ("fe80::1%12", 5005)
    assert parse_stream_url("udp://[fe80::1%ab0]:5005") == ("fe80::1%ab0", 5005)
    assert parse_stream_url("udp://[fe80::1%2512]:5005") == ("fe80::1%12", 5005)
    lo = socket.if_nameindex()[0]          # an interface this machine has, with the kernel's index
    for url in (f"udp://[fe80::1%25{lo[1]}]:5005", f"udp://[fe80::1%{lo[1]}]:5005"):
        assert resolve_stream_url(url) == (socket.AF_INET6, ("fe80::1", 5005, 0, lo[0]))


def test_a_name_with_both_families_goes_over_ipv4_and_one_that_does_not_resolve_is_an_error(monkeypatch):
    v6 = (socket.AF_INET6, socket.SOCK_DGRAM, 17, "", ("::1", 5005, 0, 0))
    v4 = (socket.AF_INET, socket.SOCK_DGRAM, 17, "", ("127.0.0.1", 5005))
    monkeypatch.setattr(socket, "getaddrinfo", lambda *a, **k: [v6, v4])
    assert resolve_stream_url("udp://localhost:5005") == (socket.AF_INET, ("127.0.0.1", 5005))
    monkeypatch.setattr(socket, "getaddrinfo", lambda *a, **k: [v6])
    assert resolve_stream_url("udp://[::1]:5005") == (socket.AF_INET6, ("::1", 5005, 0, 0))

    def unknown(*a, **k):
        raise socket.gaierror(-2, "Name or service not known")

    monkeypatch.setattr(socket, "getaddrinfo", unknown)
    with pytest.raises(ConfigError, match="cannot resolve 'robot.local' \\(Name or service not known\\)"):
        PoseStream("udp://robot.local:5005")


def test_a_pose_read_back_by_a_plain_socket_is_the_pose_sent(receiver):
    stream = PoseStream(f"udp://127.0.0.1:{receiver.getsockname()[1]}")
    poses = [_pose(0), _pose(1, prior=True)]
    for p in poses:
        stream.on_pose(p)
    for k, p in enumerate(poses):
        data, _ = receiver.recvfrom(65536)
        assert len(data) <= MAX_DATAGRAM_BYTES
        msg = json.loads(data)
        head = ("type", "v", "seq", "t_ns", "t_cam_ns", "source", "segment", "correction_version")
        assert tuple(msg[x] for x in head) == ("pose", 1, k, p.t_ns, p.t_cam_ns, "feedforward", 1, 3)
        for name, T in (("OI", p.T_OI), ("MI", p.T_MI), ("PI", p.T_PI)):
            if T is None:
                assert msg[f"p_{name}"] is None and msg[f"q_{name}"] is None
                continue
            np.testing.assert_allclose(msg[f"p_{name}"], T[:3, 3], atol=1e-6)
            # Hamilton x, y, z, w: scipy's own convention
            np.testing.assert_allclose(Rotation.from_quat(msg[f"q_{name}"]).as_matrix(), T[:3, :3], atol=1e-8)
        np.testing.assert_allclose(msg["v_OI"], p.v_OI, atol=1e-6)
        C = np.zeros((6, 6))
        C[np.triu_indices(6)] = msg["cov"]
        C = C + np.triu(C, 1).T
        np.testing.assert_allclose(C, p.covariance, rtol=1e-5)
        assert msg["run"] == stream.run_id and len(stream.run_id) == 8
    assert stream.report() == {"url": stream.url, "poses_sent": 2, "events_sent": 0, "not_sent": 0,
                               "first_error": None}
    stream.close()
    stream.close()


def test_an_event_is_one_datagram_and_a_long_line_is_cut_to_fit(receiver):
    stream = PoseStream(f"udp://127.0.0.1:{receiver.getsockname()[1]}")
    event = RunEvent(2_000_000_000, 2.0, "reset", "the filter publishing poses diverged",
                     {"segment": 0, "reason": "no update", "resets": 1})
    stream.on_event(event)
    stream.on_event(RunEvent(3_000_000_000, 3.0, "rig_finding", "CAMERA-IMU ROTATION: " + "x" * 5000,
                             {"key": "extrinsics_rotation", "evidence": "tracks"}))
    first = json.loads(receiver.recvfrom(65536)[0])
    assert first == {"type": "event", "v": 1, "run": stream.run_id, "seq": 0, **event.to_json()}
    data = receiver.recvfrom(65536)[0]
    second = json.loads(data)
    assert len(data) <= MAX_DATAGRAM_BYTES and second["seq"] == 1 and second["key"] == "extrinsics_rotation"
    assert second["message"].startswith("CAMERA-IMU ROTATION: xx") and second["message"].endswith("...")
    assert stream.report()["events_sent"] == 2
    stream.close()
    other = PoseStream(f"udp://127.0.0.1:{receiver.getsockname()[1]}")      # another run: another id
    assert other.run_id != stream.run_id and first["run"] == stream.run_id
    other.close()


def test_a_datagram_the_network_refuses_is_counted_never_raised(receiver):
    stream = PoseStream(f"udp://127.0.0.1:{receiver.getsockname()[1]}")

    class Full:
        def fileno(self):
            return 3

        def sendto(self, data, address):
            raise BlockingIOError(11, "Resource temporarily unavailable")

    real, stream._sock = stream._sock, Full()
    stream.on_pose(_pose())
    stream.on_pose(_pose())
    assert stream.report()["not_sent"] == 2 and stream.report()["poses_sent"] == 0
    assert stream.first_error == "BlockingIOError: Resource temporarily unavailable"
    stream._sock = real
    stream.on_pose(_pose())                     # the next one goes
    assert json.loads(receiver.recvfrom(65536)[0])["seq"] == 2
    stream.close()
