"""The optional live view (tools/live_view.py, viser): what it draws equals what the session published and
committed, the page is served over HTTP, a broken update is counted and never raised, and `davio run
--view` serves it during a run and reports it."""
from __future__ import annotations

import json
import socket
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("viser", reason="the live view's optional package (pip install 'davio[view]')")

from runtime.errors import ConfigError  # noqa: E402
from runtime.geometry import make_pose, so3_exp  # noqa: E402
from runtime.mapping.submap import Submap  # noqa: E402
from tools.live_view import LiveView, open_view, view_address  # noqa: E402


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def submap(index: int, T_MS: np.ndarray, n: int = 50) -> Submap:
    rng = np.random.default_rng(index)
    T_SC = np.stack([np.eye(4), make_pose(np.eye(3), np.array([0.2, 0.0, 0.0]))])
    points = rng.uniform(-1, 1, (n, 3)).astype(np.float32) + [0, 0, 3]
    return Submap(index, np.array([0, 1], np.int64), 0, np.eye(4), T_SC, np.eye(3), 1.0, np.ones(2), points,
                  rng.integers(0, 2, n).astype(np.uint8), np.ones(n, np.float32),
                  rng.integers(0, 255, n).astype(np.uint8), T_MS, lam=0.05)


@pytest.fixture
def view():
    v = LiveView(port=free_port(), host="127.0.0.1", min_interval_s=0.0)
    yield v
    v.close()


def test_the_trajectory_and_body_frame_follow_the_published_poses(view: LiveView) -> None:
    Ts = [make_pose(so3_exp(np.array([0.0, 0.0, 0.1 * k])), np.array([0.5 * k, 0.1 * k, 1.0]))
          for k in range(6)]
    for T in Ts:
        view.on_pose(SimpleNamespace(T_MI=T))
    seg = np.asarray(view.path.points)
    expect = np.array([T[:3, 3] for T in Ts])
    np.testing.assert_allclose(seg[:, 0], expect[:-1], atol=1e-5)
    np.testing.assert_allclose(seg[:, 1], expect[1:], atol=1e-5)
    np.testing.assert_allclose(view.body.position, Ts[-1][:3, 3], atol=1e-6)
    w, x, y, z = view.body.wxyz
    yaw = 2 * np.arctan2(z, w)
    assert yaw == pytest.approx(0.5, abs=1e-6) and abs(x) < 1e-9 and abs(y) < 1e-9
    assert view.report()["poses"] == 6 and view.errors == 0


def test_map_commits_draw_each_submap_at_its_graph_state(view: LiveView) -> None:
    a = submap(0, np.eye(4))
    b = submap(1, make_pose(np.eye(3), np.array([1.0, 0.0, 0.0])))
    view.on_map(SimpleNamespace(submap=a, changed=[]))
    view.on_map(SimpleNamespace(submap=b, changed=[]))
    a.T_MS = make_pose(np.eye(3), np.array([0.0, 0.3, 0.0]))      # the graph moved a
    gone = SimpleNamespace(index=7)                                 # a SubmapState: left memory
    view.on_map(SimpleNamespace(submap=submap(2, np.eye(4)), changed=[a, gone]))
    assert sorted(view.clouds) == [0, 1, 2] and view.submaps == 3 and view.errors == 0
    np.testing.assert_allclose(view.clouds[0].points, a.points_M(), atol=2e-3)   # float16 transport
    np.testing.assert_allclose(view.clouds[1].points, b.points_M(), atol=2e-3)
    np.testing.assert_array_equal(view.clouds[1].colors[:, 0], b.grey)


def test_a_long_run_folds_old_submaps_into_one_bounded_history_cloud() -> None:
    """Every submap's cloud stayed in viser's buffer for the whole run (about 15 MB a minute of a mapping
    run): past max_clouds the least recently drawn ones are folded into one history cloud, a uniform sample
    of at most max_history_points of their points."""
    v = LiveView(port=free_port(), host="127.0.0.1", max_clouds=3, max_history_points=120, history_every=2)
    try:
        subs = [submap(k, make_pose(np.eye(3), np.array([2.0 * k, 0.0, 0.0]))) for k in range(9)]
        for sm in subs:
            v.on_map(SimpleNamespace(submap=sm, changed=[]))
            assert len(v.clouds) <= 3 + 2 - 1                 # never more than max_clouds + history_every - 1
        assert sorted(v.clouds) == [6, 7, 8] and v.submaps_folded == 6 and v.errors == 0
        hist = np.asarray(v.history.points)
        assert len(hist) <= 120 and v.report()["history_points"] == len(hist) > 60
        # every history point is a point of a folded submap (0-5), none of a drawn one
        folded = np.concatenate([sm.points_M() for sm in subs[:6]])
        dist = np.linalg.norm(hist[:, None, :] - folded[None, :, :].astype(np.float32), axis=2)
        assert np.all(dist.min(axis=1) < 1e-2)           # float16 transport at x up to 11 m
        owners = dist.argmin(axis=1) // 50                # 50 points a submap: all six folded are sampled
        assert len(np.unique(owners)) == 6
    finally:
        v.close()


def test_a_folded_submap_moved_later_is_not_drawn_again_and_the_history_sample_is_uniform() -> None:
    v = LiveView(port=free_port(), host="127.0.0.1", max_clouds=2, max_history_points=120, history_every=1)
    try:
        subs = [submap(k, make_pose(np.eye(3), np.array([2.0 * k, 0.0, 0.0]))) for k in range(4)]
        for sm in subs:
            v.on_map(SimpleNamespace(submap=sm, changed=[]))
        assert sorted(v.clouds) == [2, 3] and v.submaps_folded == 2
        subs[0].T_MS = make_pose(np.eye(3), np.array([0.0, 5.0, 0.0]))       # the graph moves a folded one
        v.on_map(SimpleNamespace(submap=submap(4, np.eye(4)), changed=[subs[0]]))
        assert 0 not in v.clouds and v.submaps_folded == 3 and v.errors == 0   # 2 folded now, 0 not redrawn
        # every folded point is kept with the same probability, whenever it was folded
        kept_first, kept_later = [], []
        for trial in range(300):
            v._rng = np.random.default_rng(trial)
            v._history_pts, v._history_rgb, v._history_seen = np.zeros((0, 3), np.float32), \
                np.zeros((0, 3), np.uint8), 0
            for n, x in ((100, 1.0), (1000, 2.0)):
                cloud = SimpleNamespace(points=np.full((n, 3), x), colors=np.zeros((n, 3)),
                                        remove=lambda: None)
                v._fold(cloud)
            kept_first.append(np.sum(v._history_pts[:, 0] == 1.0) / 100)
            kept_later.append(np.sum(v._history_pts[:, 0] == 2.0) / 1000)
        assert np.mean(kept_first) == pytest.approx(120 / 1100, abs=0.01)
        assert np.mean(kept_later) == pytest.approx(120 / 1100, abs=0.005)
    finally:
        v.close()


def test_a_reset_said_while_submaps_are_folded_leaves_none_of_the_old_segment() -> None:
    """The scheduler's thread cleared the view for a reset while the model worker folded submaps: the fold
    then wrote the old segment's history back, drawn in the new segment's frame."""
    import threading
    import time

    v = LiveView(port=free_port(), host="127.0.0.1", max_clouds=1, history_every=1)
    try:
        fold, started = v._fold, []

        def fold_while_a_reset_comes(cloud):
            if not started:
                started.append(threading.Thread(target=v.on_pose, args=(
                    SimpleNamespace(T_MI=np.eye(4), segment=1),)))
                started[0].start()
                time.sleep(0.2)             # the reset's thread runs now (it waits, with the map lock)
            fold(cloud)

        v._fold = fold_while_a_reset_comes
        v.on_pose(SimpleNamespace(T_MI=np.eye(4), segment=0))
        for k in range(2):
            v.on_map(SimpleNamespace(submap=submap(k, np.eye(4)), changed=[]))
        started[0].join(5)
        assert v.segment == 1 and v.segments_cleared == 1 and v.errors == 0
        assert v.report()["history_points"] == 0 and v.history is None and not v.clouds
    finally:
        v.close()


def test_a_filter_reset_starts_the_view_over_in_the_new_frame(view: LiveView) -> None:
    """Each segment has its own odometry and map frame: its trajectory and points were drawn over the
    earlier segment's, in an unrelated frame."""
    for k in range(4):
        view.on_pose(SimpleNamespace(T_MI=make_pose(np.eye(3), np.array([float(k), 0.0, 0.0])), segment=0))
    view.on_map(SimpleNamespace(submap=submap(0, np.eye(4)), changed=[]))
    assert sorted(view.clouds) == [0]
    after = [make_pose(np.eye(3), np.array([0.0, float(k), 5.0])) for k in range(3)]
    for T in after:
        view.on_pose(SimpleNamespace(T_MI=T, segment=1))
    assert view.clouds == {} and view.segments_cleared == 1
    np.testing.assert_allclose(np.asarray(view.path.points)[:, 0], [T[:3, 3] for T in after[:-1]], atol=1e-5)
    late = submap(1, np.eye(4))                      # a window of segment 0 mapped after the reset
    late.segment = 0
    view.on_map(SimpleNamespace(submap=late, changed=[]))
    new = submap(2, np.eye(4))
    new.segment = 1
    view.on_map(SimpleNamespace(submap=new, changed=[]))
    assert sorted(view.clouds) == [2] and view.report()["segments_cleared"] == 1 and view.errors == 0


def test_the_page_is_served_and_a_broken_update_is_counted(view: LiveView) -> None:
    html = urllib.request.urlopen(view.url, timeout=10).read()
    assert b"<html" in html[:200].lower()
    view.on_pose(SimpleNamespace(T_MI=np.full((4, 4), np.nan)))
    assert view.errors == 1 and "not a finite" in view.last_error
    assert view.poses == 0    # refused before it reaches the drawn trajectory
    view.on_map(SimpleNamespace(submap=None, changed=[]))
    assert view.errors >= 1 and view.last_error


def test_open_view_checks_the_port() -> None:
    assert open_view(None) is None
    with pytest.raises(ConfigError, match="port"):
        open_view(70000)


def test_a_busy_port_is_said_not_silently_replaced(capsys) -> None:
    """viser takes the next free port: a tunnel set up for the one asked for reached another program."""
    with socket.socket() as holder:
        holder.bind(("0.0.0.0", 0))
        holder.listen()
        port = holder.getsockname()[1]
        view = open_view(port)
        try:
            served = view.server.get_port()
            err = capsys.readouterr().err
            assert served != port and f"port {port} is busy: " in err and f":{served}" in err
            assert "open to the network" in err
        finally:
            view.close()


@pytest.mark.parametrize("text, expected", [
    ("8080", ("0.0.0.0", 8080)), ("127.0.0.1:9000", ("127.0.0.1", 9000)), ("localhost:1", ("localhost", 1)),
    ("[::1]:65535", ("::1", 65535)), (" 0.0.0.0:8081 ", ("0.0.0.0", 8081))])
def test_view_address_reads_port_or_host_and_port(text: str, expected: tuple) -> None:
    assert view_address(text) == expected


@pytest.mark.parametrize("text, said", [
    ("::1:9000", "brackets"), ("[::1]", "with a port"), (":9000", "no host"), ("127.0.0.1:0", "TCP port"),
    ("127.0.0.1:", "TCP port"),
    ("host:x", "TCP port"), ("70000", "TCP port"), ("", "TCP port"), ("\u0661\u0662", "TCP port")])
def test_view_address_refuses_what_is_not_an_address(text: str, said: str) -> None:
    import argparse

    with pytest.raises(argparse.ArgumentTypeError, match=said):
        view_address(text)


def test_a_view_on_the_loopback_serves_this_machine_and_says_so(capsys) -> None:
    port = free_port()
    view = open_view(("127.0.0.1", port))
    try:
        assert view.url == f"http://127.0.0.1:{port}"
        with urllib.request.urlopen(view.url, timeout=10) as reply:
            assert reply.status == 200
        err = capsys.readouterr().err
        assert "this machine only" in err and "open to the network" not in err
    finally:
        view.close()


@pytest.mark.parametrize("host, said", [("192.0.2.1", "not an address of this machine"),
                                        ("no-such-host.invalid", "not a host name")])
def test_a_host_this_machine_cannot_listen_on_is_refused(host: str, said: str) -> None:
    """viser retries port after port without end on an address that is not this machine's (a hang)."""
    with pytest.raises(ConfigError, match=said):
        open_view((host, free_port()))


def test_davio_run_refuses_a_view_address_before_the_run(small_sim_folder: Path, tmp_path: Path,
                                                          capsys) -> None:
    from conftest import cli_exit

    out = tmp_path / "run"
    assert cli_exit(["run", str(small_sim_folder), "--native-only", "--out", str(out),
                     "--view", "::1:8080"]) == 2
    assert "brackets" in capsys.readouterr().err
    assert cli_exit(["run", str(small_sim_folder), "--native-only", "--out", str(out),
                     "--view", "192.0.2.1:8080"]) == 1
    assert "not an address of this machine" in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "run.partial").exists()


@pytest.mark.slow
def test_davio_run_serves_the_view_and_reports_it(small_sim_folder: Path, tmp_path: Path, capsys) -> None:
    from tools.cli import main

    port = free_port()
    out = tmp_path / "run"
    rc = main(["run", str(small_sim_folder), "--emulated", "--seconds", "4", "--out", str(out),
               "--view", str(port), "--json"])
    assert rc == 0
    report = json.loads((out / "report.json").read_text())
    v = report["view"]
    assert v["url"].endswith(f":{port}") and v["errors"] == 0
    assert v["poses"] == report["published_poses"]
    json.loads(capsys.readouterr().out)          # stdout holds the JSON object only
