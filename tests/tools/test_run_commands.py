"""End to end: `davio demo` (simulated recording, emulated DA3) publishes a metric trajectory that
matches the simulator's ground truth; `davio run` replays a real EuRoC folder and writes its outputs."""
from __future__ import annotations

import contextlib
import json
import socket
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from tests.conftest import cli_exit
from tools.cli import main
from tools.evaluation import ate, read_tum


@pytest.mark.slow
def test_demo_publishes_metric_trajectory_matching_ground_truth(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--seconds", "9", "--seed", "1"]) == 0
    text = capsys.readouterr().out
    assert "EMULATED DA3" in text
    report = json.loads((out / "report.json").read_text())
    assert report["published_poses"] > 50
    assert report["T_f_s"] is not None and report["T_f_s"] < 6.0
    # independent check: re-simulate the same recording and score odometry.tum against its truth
    from drivers.sim import SimConfig, SimRecording
    from tools.commands.demo import DEFAULT_PRESET

    gt = SimRecording.from_preset(SimConfig(preset=DEFAULT_PRESET, seconds=9, seed=1)).groundtruth()
    est = read_tum(out / "odometry.tum")
    res = ate(est, gt, align_method="se3")
    assert res.trans["rmse"] < 0.15
    assert report["metrics"]["ate_se3_m"] == pytest.approx(res.trans["rmse"], rel=1e-6)
    assert "model" in report and "EMULATED" in report["model"]
    assert (out / "config.toml").exists() and (out / "trajectory.png").exists()
    # the dense map: archive checkpointed per commit, map.ply re-exported from it
    from tools.evaluation.ply import read_ply_vertices
    from tools.map_archive import check_integrity, read_manifest

    mapping = report["pipeline"]["mapping"]
    assert mapping["windows_accepted"] >= 2
    manifest = read_manifest(out / "map")
    assert len(manifest["submaps"]) == mapping["windows_accepted"] == report["map"]["submaps"]
    # paths relative to the run folder (the run was written in OUT.partial/ and renamed)
    assert report["map"]["archive"] == "map" and report["map"]["ply"] == "map.ply"
    assert (out / report["map"]["archive"] / "manifest.json").is_file()
    assert (out / report["map"]["ply"]).is_file()
    assert check_integrity(out / "map") == []
    assert len(read_ply_vertices(out / "map.ply")) == report["map"]["voxels"] > 10_000
    assert "map: " in text and "windows mapped" in text
    # the demo starts in motion: the feed-forward start-up publishes first; the native initializer alone,
    # replayed on the same recording, is reported beside it
    assert report["published_by"] == "feedforward"
    nat = report["native_only"]
    assert nat["T_f_s"] is None or nat["T_f_s"] > report["T_f_s"]
    assert "start-up race: feedforward published first" in text and "native initializer alone" in text
    first = json.loads((out / "events.jsonl").read_text().splitlines()[0])
    assert (first["kind"], first["source"]) == ("publishing", "feedforward")
    assert (out / "groundtruth.tum").exists() and report["reproduce"][0].startswith("davio simulate --preset")
    for name in ("causal.tum", "final.tum"):   # map-frame trajectories, one pose per published state
        assert len(read_tum(out / name)) == report["published_poses"]
    rows = (out / "poses.csv").read_text().splitlines()
    assert rows[0].startswith("t_ns,") and len(rows) == report["published_poses"] + 1


def test_the_demo_race_stops_at_the_native_initializers_first_pose():
    """The native-only replay ends at its first published pose, with the same publication time and source
    as the same replay run to the end of the recording."""
    import argparse
    from dataclasses import replace

    from drivers.sim import SimConfig, SimRecording
    from runtime.config import DavioConfig
    from tools.commands.demo import _native_only
    from tools.run_session import run_pipeline

    rec = SimRecording.from_preset(SimConfig(preset="handheld", seconds=4, seed=0))
    race = _native_only(rec, DavioConfig(), argparse.Namespace(seconds=4))
    config = DavioConfig()
    config = replace(config, mapping=replace(config.mapping, enabled=False))    # as the race runs
    full = run_pipeline(rec, None, config, show_progress=False)
    st = full.pipeline.startup.report
    assert race["published_by"] == st.first_published_by is not None
    t_f = (st.first_publish_t_ns - full.scheduler.first_t_ns) * 1e-9
    assert race["T_f_s"] == pytest.approx(t_f, abs=1e-9)
    assert race["replayed_s"] == pytest.approx(race["T_f_s"], abs=0.06) and full.scheduler.sensor_s > 3.5


def test_run_on_real_euroc_head_writes_outputs(tmp_path, capsys):
    path = shared_path("euroc", "V1_01_easy_head")
    out = tmp_path / "run"
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)    # a robot's controller, say
    receiver.bind(("127.0.0.1", 0))
    receiver.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    receiver.settimeout(0.5)
    stream = f"udp://127.0.0.1:{receiver.getsockname()[1]}"
    assert main(["run", str(path), "--out", str(out), "--native-only", "--seconds", "3", "--json",
                 "--stream", stream]) == 0
    # --json: stdout holds the JSON object only, strict (no NaN / Infinity tokens)
    report = json.loads(capsys.readouterr().out, parse_constant=lambda c: pytest.fail(f"non-strict {c}"))
    assert report["status"] == "complete"
    assert report["scheduler"]["frames"] == 61  # 20 Hz, first 3 s inclusive
    assert report["scheduler"]["imu_samples"] > 590
    assert report["pipeline"]["tracking"]["mean_tracks_per_frame"] > 150
    # the drone sits still: with the zero-velocity update the static initializer starts the filter once its
    # 2 s window is full (without it, it would wait for a jerk: tests/runtime/test_pipeline_standing_start)
    assert report["published_by"] == "native:static" and report["T_f_s"] == pytest.approx(2.0, abs=0.06)
    assert report["published_poses"] >= 15
    assert (out / "report.json").exists()
    rows = [ln for ln in (out / "odometry.tum").read_text().splitlines() if ln and not ln.startswith("#")]
    assert len(rows) == report["published_poses"]
    # the calibration the run used is recorded (here the folder's own sensor.yaml files)
    rig = json.loads((out / "report.json").read_text())["rig"]
    assert rig["source"] == "the recording (euroc)" and rig["camera"]["width"] == 752
    assert rig["camera"]["K"][0][0] == pytest.approx(458.654) and len(rig["T_IC"]) == 4
    assert rig["imu_noise"]["gyro_noise_density"] == pytest.approx(1.6968e-04)
    # the pose journal a killed run would leave is gone once the run's own trajectories are written
    assert not (out / "causal.journal.tum").exists()
    assert "causal.journal.tum" not in json.loads((out / "run_status.json").read_text())["files"]
    # the run's events, one JSON line each: the static initializer began publishing with the first pose
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    assert [(e["kind"], e["source"], e["segment"]) for e in events] == [("publishing", "native:static", 0)]
    assert events[0]["t_ns"] * 1e-9 == pytest.approx(float(rows[0].split()[0]), abs=1e-6)
    assert events[0]["t_s"] == pytest.approx(report["T_f_s"], abs=0.06)
    assert report["pipeline"]["events"] == {"counts": {"publishing": 1}, "not_kept": 0}
    assert "events.jsonl" in json.loads((out / "run_status.json").read_text())["files"]
    # --stream: each pose and event went out as it happened, one UDP datagram each: the same as the files
    got = []
    with contextlib.suppress(TimeoutError):
        while True:
            got.append(json.loads(receiver.recvfrom(65536)[0]))
    receiver.close()
    assert [m["seq"] for m in got] == list(range(len(rows) + 1))
    assert [m["type"] for m in got].count("event") == 1
    sent = [m for m in got if m["type"] == "pose"]
    tum = np.array([[float(x) for x in r.split()] for r in rows])
    np.testing.assert_allclose([m["t_ns"] * 1e-9 for m in sent], tum[:, 0], atol=1e-6)
    np.testing.assert_allclose([m["p_OI"] for m in sent], tum[:, 1:4], atol=1e-5)
    event = next(m for m in got if m["type"] == "event")
    keys = ("kind", "source", "t_ns")
    assert {k: event[k] for k in keys} == {k: events[0][k] for k in keys}
    assert report["stream"] == {"url": stream, "poses_sent": len(rows), "events_sent": 1, "not_sent": 0,
                                "first_error": None}


def _euroc_copy(tmp_path: Path, imu_lines=None, gt_text: str | None = None, imu_yaml: bool = True) -> Path:
    """The real V1_01 head as a folder of symlinks, with the IMU rows (or the ground truth) replaced by
    the given text and imu0/sensor.yaml left out on request; returns the recording folder."""
    src = shared_path("euroc", "V1_01_easy_head") / "mav0"
    dst = tmp_path / "rec" / "mav0"
    dst.mkdir(parents=True)
    for name in ("body.yaml", "cam0"):
        (dst / name).symlink_to(src / name)
    (dst / "imu0").mkdir()
    if imu_yaml:
        (dst / "imu0" / "sensor.yaml").symlink_to(src / "imu0" / "sensor.yaml")
    if imu_lines is None:
        (dst / "imu0" / "data.csv").symlink_to(src / "imu0" / "data.csv")
    else:
        (dst / "imu0" / "data.csv").write_text("\n".join(imu_lines) + "\n")
    if gt_text is None:
        (dst / "state_groundtruth_estimate0").symlink_to(src / "state_groundtruth_estimate0")
    else:
        (dst / "state_groundtruth_estimate0").mkdir()
        (dst / "state_groundtruth_estimate0" / "data.csv").write_text(gt_text)
    return dst.parent


def _run_with_imu_lines(tmp_path: Path, capsys, lines: list[str]) -> tuple[str, dict]:
    """`davio run --native-only` over 2.5 s of the V1_01 head with the given IMU rows: (console, report)."""
    out = tmp_path / "run"
    assert main(["run", str(_euroc_copy(tmp_path, imu_lines=lines)), "--out", str(out), "--native-only",
                 "--seconds", "2.5"]) == 0
    return capsys.readouterr().out, json.loads((out / "report.json").read_text())


def _euroc_rows(name: str) -> list[str]:
    return (shared_path("euroc", "V1_01_easy_head") / "mav0" / name / "data.csv").read_text().splitlines()


def test_run_reports_input_repairs_on_the_console(tmp_path, capsys):
    """Corrupted IMU rows are dropped, counted in report.json and named on the console."""
    lines = _euroc_rows("imu0")
    for i in (100, 101, 102):  # three NaN accelerometer rows
        cols = lines[i].split(",")
        cols[4] = "nan"
        lines[i] = ",".join(cols)
    lines.insert(200, lines[199])  # one duplicated timestamp
    text, report = _run_with_imu_lines(tmp_path, capsys, lines)
    assert "input imu0: non-finite samples dropped 3, duplicates dropped 1" in text
    imu = report["driver"]["streams"]["imu0"]
    assert imu["dropped_nonfinite"] == 3 and imu["dropped_duplicate"] == 1
    assert report["imu_noise_defaulted"] == [] and "IMU noise withheld" not in text


def test_a_run_keeps_no_queue_of_poses_nobody_reads(tmp_path, capsys, monkeypatch):
    """`davio run` hands poses to its sinks through on_pose and never reads Session.poses(): its queue held
    up to 12000 unread poses (about 13 MB on a long run, helper audit)."""
    from runtime.session import Session

    made: list = []
    init = Session.__init__

    def recording_init(self, *a, **kw):
        init(self, *a, **kw)
        made.append(self)

    monkeypatch.setattr(Session, "__init__", recording_init)
    _, report = _run_with_imu_lines(tmp_path, capsys, _euroc_rows("imu0"))
    assert len(made) == 1 and made[0]._poses.maxsize == 1
    assert made[0].unread_poses_dropped == report["published_poses"] - 1 > 0


def test_withheld_imu_noise_is_said_not_silently_defaulted(tmp_path, capsys):
    """Without imu0/sensor.yaml the filter runs on EuRoC's default densities, and the run says so."""
    from runtime.msckf.config import DEFAULT_IMU_NOISE

    out = tmp_path / "run"
    rec = _euroc_copy(tmp_path, imu_yaml=False)
    assert main(["run", str(rec), "--out", str(out), "--native-only", "--seconds", "2.5"]) == 0
    text = capsys.readouterr().out
    assert ("note: IMU noise withheld in the calibration: gyro_noise_density, gyro_random_walk, "
            "accel_noise_density, accel_random_walk from the EuRoC (ADIS16448) defaults") in text
    assert json.loads((out / "report.json").read_text())["imu_noise_defaulted"] == list(DEFAULT_IMU_NOISE)


def test_a_run_without_a_start_names_each_native_initializers_reasons(tmp_path, capsys):
    """1 s of a standstill is too short for both initializers: the console and report.json say why, per
    initializer, with counts (the static one needs 2 s of IMU, the dynamic one 0.9 x its 2 s window)."""
    out = tmp_path / "run"
    assert main(["run", str(shared_path("euroc", "V1_01_easy_head")), "--native-only", "--seconds", "1",
                 "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "static: " in err and "(last: short_window: 1.00 s of IMU < 2.0 s)" in err
    assert "dynamic: " in err and "keyframes span 1.00 s < 0.9 x the 2.0 s window" in err
    inits = json.loads((out / "report.json").read_text())["pipeline"]["filter"]["initializers"]
    assert set(inits) == {"static", "turning", "dynamic"}
    assert inits["static"]["rejections"]["short_window"] > 0
    assert inits["dynamic"]["rejections"]["short_window"] > 0


def test_run_with_an_onnx_model_warms_it_up_and_refuses_a_broken_one(tmp_path, capsys, monkeypatch):
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parents[1] / "models"))
    from da3_contract_graph import build_da3_contract_graph

    path = shared_path("euroc", "V1_01_easy_head")
    graph = build_da3_contract_graph(tmp_path / "contract.onnx", 28, 42)
    out = tmp_path / "run"
    # 1 s of a standstill is too short for either initializer: the run says why and exits 1
    assert main(["run", str(path), "--model", str(graph), "--out", str(out), "--seconds", "1",
                 "--gpu-mem-limit", "4096", "--model-latency", "measured"]) == 1
    cap = capsys.readouterr()
    assert "on CPUExecutionProvider (warm-up call" in cap.out  # the cap concerns CUDA alone
    # the replay simulates the latency of one timed call of the graph, and the report says which
    measured = json.loads((out / "report.json").read_text())["replay"]["model_latency_s"]
    assert 0 < measured < 5 and f"replay latency {measured:.3f} s (measured, one call)" in cap.out
    assert "no pose was published: feed-forward start-up: 1 windows tried" in cap.err
    assert json.loads((out / "run_status.json").read_text())["status"] == "failed"
    broken = build_da3_contract_graph(tmp_path / "nan.onnx", 28, 42, variant="nan_depth")
    args = ["run", str(path), "--model", str(broken), "--out", str(tmp_path / "r2"), "--seconds", "1"]
    assert main(args) == 1
    err = capsys.readouterr().err
    assert "nan.onnx: output depth has 5880 non-finite values" in err
    assert not (tmp_path / "r2" / "report.json").exists()  # refused before any sensor data was read


def test_run_missing_folder_is_a_clear_error(tmp_path, capsys):
    assert main(["run", str(tmp_path / "nope"), "--out", str(tmp_path / "out")]) == 1
    assert "not found" in capsys.readouterr().err


def test_run_emulated_on_real_data_is_refused(tmp_path, capsys):
    path = shared_path("euroc", "V1_01_easy_head")
    assert main(["run", str(path), "--emulated", "base", "--seconds", "1", "--out", str(tmp_path / "x")]) == 1
    assert not (tmp_path / "x").exists() and not (tmp_path / "x.partial").exists()
    assert "davio simulate" in capsys.readouterr().err


def test_odometry_file_round_trips_published_states(tmp_path):
    from runtime.startup import Published
    from tools.run_io import published_trajectory

    pub = [Published(1_000_000_000 + k, k, np.eye(3), np.array([k, 0.0, 0.0]), np.zeros(3), "x", 0)
           for k in range(3)]
    traj = published_trajectory(pub)
    assert list(traj.t_ns) == [1_000_000_000, 1_000_000_001, 1_000_000_002]
    np.testing.assert_allclose(traj.p[:, 0], [0, 1, 2])


def test_depths_mostly_out_of_range_are_said_with_the_likely_causes():
    """A graph whose depth was in mm mapped nothing; the console said "0 points kept" and no reason."""
    from tools.run_summary import mapping_line, recovery_lines

    mp = {"windows_accepted": 0, "windows_offered": 3, "windows_processed": 3, "windows_dropped_queue": 0,
          "windows_rejected": {"invalid_depth": 3}, "points_sampled": 6000, "rejected_invalid_depth": 6000,
          "rejected_confidence": 0, "rejected_multiview": 0, "points_retained": 0}
    report = {"pipeline": {"mapping": mp}, "config": {"mapping": {"max_depth_m": 20.0}}}
    warned = [x for x in recovery_lines(report) if x.startswith("MODEL DEPTH? 100 % of the depths")]
    assert len(warned) == 1 and "(0, 20 m] (3 windows refused as invalid_depth)" in warned[0]
    assert "not mm, not inverse depth" in warned[0]
    assert "0 points kept (100 % invalid depth, 0 % low confidence" in mapping_line(mp, {}, None)
    # a scene partly beyond the range, every window mapped: no warning
    mp.update(windows_accepted=3, windows_rejected={}, rejected_invalid_depth=2000, points_retained=4000)
    assert not any(x.startswith("MODEL DEPTH?") for x in recovery_lines(report))
    # one window of 100 refused (down a long hall), 3 % of the depths out of range: the scene, no alarm
    mp.update(windows_processed=100, windows_accepted=99, windows_rejected={"invalid_depth": 1},
              points_sampled=200_000, rejected_invalid_depth=6000)
    assert not any(x.startswith("MODEL DEPTH?") for x in recovery_lines(report))


def test_a_late_first_pose_says_what_the_initializers_refused_before_it():
    """A vibrating standstill (accelerometer std 1.4 m/s^2): the first pose came at 10.6 s and the console
    said nothing of the 173 refusals before it (their reasons were in report.json only)."""
    from tools.run_summary import recovery_lines

    static = {"rejections": {"moving": 173}, "last_reason": "moving: excitation 2.485 > 1.5 m/s^2"}
    dynamic = {"rejections": {"insufficient_parallax": 175}, "last_reason": "insufficient_parallax: 0.85 deg"}
    report = {"T_f_s": 10.627, "pipeline": {"startup": {"refused_before_first": {
        "static": static, "turning": {"rejections": {}}, "dynamic": dynamic}}}}
    late = [x for x in recovery_lines(report) if x.startswith("LATE START")]
    assert late == ["LATE START: the first pose came 10.6 s into the data; before it the native initializers "
                    "refused: static: moving x173 (last: moving: excitation 2.485 > 1.5 m/s^2); dynamic: "
                    "insufficient_parallax x175 (last: insufficient_parallax: 0.85 deg)"]
    report["T_f_s"] = 2.03                                              # an ordinary start: nothing said
    assert not any(x.startswith("LATE START") for x in recovery_lines(report))


def test_recovery_lines_name_every_counted_recovery():
    from tools.run_summary import recovery_lines as _recovery_lines

    clean = {"driver": {"streams": {"imu0": {"dropped_nonfinite": 0, "emitted": 10}}},
             "pipeline": {"startup": {"ff_rejections": {}, "restarts_after_divergence": 0}}}
    assert _recovery_lines(clean) == []
    report = {
        "driver": {"streams": {"imu0": {"dropped_duplicate": 2, "gaps": 1, "emitted": 10},
                               "cam0": {"unreadable_images": 1}}},
        "pipeline": {"startup": {"ff_rejections": {"small_baseline": 3, "refit_failed": 1},
                                 "restarts_after_divergence": 2},
                     "filter": {"divergence_resets": 0}},  # the last filter's own counter: not the total
        "segments": [{}, {}, {}],
    }
    assert _recovery_lines(report) == [
        "input imu0: duplicates dropped 2, gaps 1",
        "input cam0: unreadable images 1",
        "feed-forward windows rejected: refit_failed x1, small_baseline x3",
        "filter resets after divergence: 2 (3 segments)",
    ]
    report["pipeline"]["startup"]["ff_rejections"]["gyro_scale"] = 4
    report["pipeline"]["startup"]["ff_rejection_first"] = {"gyro_scale": "the gyroscope turns 57.1x as fast"}
    lines = _recovery_lines(report)
    assert lines[2] == "feed-forward windows rejected: gyro_scale x4, refit_failed x1, small_baseline x3"
    assert lines[3].startswith("GYROSCOPE SCALE: 4 windows refused, the first: the gyroscope turns 57.1x")
    report["pipeline"]["startup"]["ff_rejections"]["extrinsics_rotation"] = 1     # one window: not blamed
    report["pipeline"]["startup"]["ff_rejection_first"]["extrinsics_rotation"] = "the rig's ... inverted"
    assert not any(line.startswith("CAMERA-IMU") for line in _recovery_lines(report))
    report["pipeline"]["startup"]["ff_rejections"]["extrinsics_rotation"] = 2
    line = [x for x in _recovery_lines(report) if x.startswith("CAMERA-IMU ROTATION: 2 windows refused")]
    assert len(line) == 1 and "inverted" in line[0] and "--withhold-extrinsics" in line[0]
    # without a model the tracked features' checks speak for themselves
    report["pipeline"]["rig_check"] = {"gyro_scale": "the gyroscope turns 57.9x as far",
                                       "extrinsics_rotation": None}
    gyro = [x for x in _recovery_lines(report) if x.startswith("GYROSCOPE SCALE (tracked features): ")]
    assert len(gyro) == 1 and "57.9x" in gyro[0]
    assert not any(x.startswith("CAMERA-IMU ROTATION (tracked") for x in _recovery_lines(report))
    report["pipeline"]["rig_check"]["extrinsics_rotation"] = "178.1 deg ... inverted"
    assert any(x.startswith("CAMERA-IMU ROTATION (tracked features): 178.1") for x in _recovery_lines(report))
    report["pipeline"]["rig_check"]["error"] = "DataError: ..."
    assert "rig check from the tracked features ended early: DataError: ..." in _recovery_lines(report)


def test_the_time_offset_line_says_what_the_start_up_did_with_its_finding():
    from tools.run_summary import recovery_lines as _recovery_lines

    def lines(startup: dict, rig_offset=None) -> list[str]:
        report = {"rig": {"time_offset_s": rig_offset},
                  "pipeline": {"startup": {"ff_rejections": {}, "restarts_after_divergence": 0, **startup}}}
        return [x for x in _recovery_lines(report) if x.startswith("CAMERA-IMU TIME OFFSET")]

    assert lines({"time_offset_findings": 0}) == []
    first = {"time_offset": "the window's rotations fit ... +60 ms"}
    adopted = lines({"time_offset_findings": 2, "time_offset_adopted_s": 0.0601, "ff_rejection_first": first},
                    0.01)
    assert adopted == ["CAMERA-IMU TIME OFFSET: 2 windows fit another offset, adopted +60.1 ms (the rig says "
                       "+10.0 ms); the first: the window's rotations fit ... +60 ms. Put the offset in the "
                       "rig file (Kalibr timeshift_cam_imu: t_imu = t_cam + shift)"]
    solved = lines({"time_offset_findings": 1, "ff_time_offset_s": -0.03,
                    "ff_time_offset_first": "fits -30 ms"})
    assert "a window was solved at -30.0 ms (the rig says +0.0 ms); the first: fits -30 ms" in solved[0]
    assert "1 window fits another offset, not adopted" in lines({"time_offset_findings": 1,
                                                                  "ff_rejection_first": first})[0]
    # a finding that came with a refusal a longer span may cure: its detail is the start-up's first finding
    cured = lines({"time_offset_findings": 1, "time_offset_adopted_s": -0.0016,
                   "time_offset_first": "at the offset the rotations fit (-48 ms ...): short"}, 0.05)
    assert "; the first: at the offset the rotations fit (-48 ms ...): short. Put" in cured[0]


def test_the_filter_s_estimate_of_the_time_offset_is_named_when_it_ends_far_from_the_offset_in_use():
    from tools.run_summary import ESTIMATED_OFFSET_NOTE_S
    from tools.run_summary import recovery_lines as _recovery_lines

    def lines(filt: dict, rig_offset=0.01, adopted=None) -> list[str]:
        report = {"rig": {"time_offset_s": rig_offset},
                  "pipeline": {"filter": {"time_offset_estimated": True, "time_offset_std_s": 0.0004, **filt},
                               "startup": {"ff_rejections": {}, "restarts_after_divergence": 0,
                                           "time_offset_adopted_s": adopted}}}
        return [x for x in _recovery_lines(report) if x.startswith("CAMERA-IMU TIME OFFSET: the filter")]

    def any_line(filt: dict) -> list[str]:
        report = {"rig": {"time_offset_s": 0.01},
                  "pipeline": {"filter": {"time_offset_estimated": True, **filt},
                               "startup": {"ff_rejections": {}, "restarts_after_divergence": 0}}}
        return [x for x in _recovery_lines(report) if "TIME OFFSET" in x]

    assert lines({"time_offset_s": 0.0612}) == [
        "CAMERA-IMU TIME OFFSET: the filter estimated +61.2 +- 0.4 ms at the end (the rig says +10.0 ms; "
        "t_imu = t_cam + offset). If the rig file is yours, put the estimate in it "
        "(Kalibr timeshift_cam_imu)"]
    assert lines({"time_offset_s": 0.01 - 0.9 * ESTIMATED_OFFSET_NOTE_S}) == []           # within the spread
    assert len(lines({"time_offset_s": 0.01 - 1.1 * ESTIMATED_OFFSET_NOTE_S})) == 1
    # an uncertain estimate (a short run, a late start) must be three standard deviations off, and is not
    # offered as the rig's: a wrong rotation or a slow start bent estimates 11-17 ms off a true 0 (std 1-2.7)
    assert any_line({"time_offset_s": 0.0212, "time_offset_std_s": 0.004}) == []      # within 3 std: nothing
    [said] = any_line({"time_offset_s": 0.0232, "time_offset_std_s": 0.004})             # beyond: unsettled
    assert said.startswith("CAMERA-IMU TIME OFFSET? the filter's estimate ended at +23.2 +- 4.0 ms")
    unsettled = [x for x in _recovery_lines({"rig": {"time_offset_s": 0.0}, "pipeline": {
        "filter": {"time_offset_estimated": True, "time_offset_std_s": 0.0027, "time_offset_s": 0.017},
        "startup": {"ff_rejections": {}, "restarts_after_divergence": 0}}}) if "TIME OFFSET" in x]
    assert unsettled == ["CAMERA-IMU TIME OFFSET? the filter's estimate ended at +17.0 +- 2.7 ms (the rig "
                         "says +0.0 ms), not settled enough to copy into a rig file: an estimate this "
                         "uncertain can absorb another error (a camera-IMU rotation a few degrees off, a "
                         "slow or weak start)"]
    assert lines({"time_offset_s": 0.0612, "time_offset_estimated": False}) == []        # the rig's, fixed
    assert lines({"time_offset_s": 0.0612, "time_offset_std_s": None}) == []             # not running
    assert len(lines({"time_offset_s": -0.02}, rig_offset=None)) == 1                    # the rig says 0
    # after an adoption the estimate is compared with the adopted offset, and the line names both
    assert lines({"time_offset_s": 0.0612}, adopted=0.06) == []
    back = lines({"time_offset_s": 0.011}, adopted=0.06)
    assert len(back) == 1 and "(the rig says +10.0 ms, the start-up adopted +60.0 ms;" in back[0]


@pytest.mark.parametrize("args, message", [
    (["--seconds", "0"], "--seconds must be a finite number > 0"),
    (["--seconds", "nan"], "argument --seconds: 'nan' is not a finite number"),     # exit 2: argparse's
    (["--seconds", "inf"], "argument --seconds: 'inf' is not a finite number"),
    (["--model-latency", "-1"], "--model-latency must be a number of seconds from 0 to 3600"),
    (["--model-latency", "inf"], "argument --model-latency: seconds or 'measured': 'inf' is not a finite"),
    (["--paced", "--speed", "0"], "--speed must be > 0"),
])
def test_run_refuses_impossible_options_before_reading_anything(tmp_path, capsys, args, message):
    code = cli_exit(["run", str(tmp_path / "not-even-read"), "--out", str(tmp_path / "o"), *args])
    assert code == (2 if "argument" in message else 1)
    assert message in capsys.readouterr().err and not (tmp_path / "o").exists()


def test_a_recording_that_cannot_publish_says_why_and_exits_non_zero(tmp_path, capsys):
    """A head whose images are all missing stops before the run with the reason (and leaves no folder)."""
    src = shared_path("euroc", "V1_01_easy_head") / "mav0"
    dst = tmp_path / "rec" / "mav0"
    (dst / "cam0").mkdir(parents=True)
    (dst / "cam0" / "sensor.yaml").symlink_to(src / "cam0" / "sensor.yaml")
    (dst / "cam0" / "data").mkdir()
    (dst / "cam0" / "data.csv").symlink_to(src / "cam0" / "data.csv")
    (dst / "imu0").mkdir()
    (dst / "imu0" / "data.csv").symlink_to(src / "imu0" / "data.csv")
    assert main(["run", str(dst.parent), "--out", str(tmp_path / "o"), "--native-only"]) == 1
    err = capsys.readouterr().err
    assert "none of the 95 images it lists exists" in err and not (tmp_path / "o.partial").exists()


def test_ground_truth_on_another_clock_gives_the_reason_not_nan(tmp_path, capsys):
    rows = _euroc_rows("state_groundtruth_estimate0")
    shifted = [rows[0]] + [f"{int(r.split(',', 1)[0]) + 10**12},{r.split(',', 1)[1]}" for r in rows[1:]]
    out = tmp_path / "run"
    rec = _euroc_copy(tmp_path, gt_text="\n".join(shifted) + "\n")
    assert main(["run", str(rec), "--out", str(out), "--native-only", "--seconds", "2.5"]) == 0
    text = capsys.readouterr().out
    assert "ATE: not computed: " in text and "nan" not in text.split("ATE:")[1].splitlines()[0]
    metrics = json.loads((out / "report.json").read_text())["metrics"]
    assert "ate_se3_m" not in metrics and metrics["ate_se3_error"] in text


def test_imu_values_beyond_any_imu_are_dropped_and_said(tmp_path, capsys):
    """One accelerometer value of 1e6 m/s^2 (a corrupt row) never reaches an initializer or the filter."""
    lines = _euroc_rows("imu0")
    cols = lines[150].split(",")
    cols[5] = "1e6"
    lines[150] = ",".join(cols)
    text, report = _run_with_imu_lines(tmp_path, capsys, lines)
    assert "IMU samples beyond any IMU's range dropped: 1" in text
    assert report["pipeline"]["tracking"]["imu_out_of_range"] == 1 and report["published_poses"] > 0


def test_the_summary_names_who_published_first_even_after_a_reset():
    from tools.run_summary import first_published_line as line

    base = {"T_f_s": 2.03, "published_poses": 16}
    assert line({**base, "first_published_by": "native:static", "published_by": None}) == (
        "first published state: 2.03 s by native:static (at the end: nobody, after a reset); 16 poses")
    assert line({**base, "first_published_by": "feedforward", "published_by": "feedforward"}).endswith(
        "2.03 s by feedforward; 16 poses")
    assert line({"T_f_s": None, "published_poses": 0}) == "first published state: none by -; 0 poses"
