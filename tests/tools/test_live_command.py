"""`davio live uvc`, no hardware: a video file stands in for the UVC camera (paced at its frame rate) and a
pseudo-terminal for the serial IMU (the text protocol, written at sensor rate by a thread); the run
publishes metric poses and writes a complete run folder. Missing devices are one-line errors."""
from __future__ import annotations

import contextlib
import json
import socket
from pathlib import Path

import pytest
from live_sources import run_live_uvc, video_from_recording

from tools.cli import main
from tools.run_folder import run_status


@pytest.mark.slow
def test_live_uvc_with_a_serial_imu_publishes_and_writes_a_complete_run(small_sim_folder: Path,
                                                                       tmp_path: Path, capsys,
                                                                       monkeypatch) -> None:
    video = video_from_recording(small_sim_folder, tmp_path / "cam.avi")
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    receiver.settimeout(0.5)
    code = run_live_uvc(small_sim_folder, video,
                        ["live", "uvc", "--rig", str(small_sim_folder), "--native-only", "--seconds", "5",
                         "--out", str(tmp_path / "run"), "--stream",
                         f"udp://127.0.0.1:{receiver.getsockname()[1]}"], monkeypatch)
    captured = capsys.readouterr()
    err = captured.err
    assert code == 0, err
    out = tmp_path / "run"
    assert run_status(out) == "complete"
    report = json.loads((out / "report.json").read_text())
    assert report["published_poses"] > 20 and report["published_by"].startswith("native")
    streams = report["driver"]["streams"]
    assert streams["cam0"]["emitted"] > 60 and streams["imu0"]["emitted"] > 600
    rows = [ln for ln in (out / "odometry.tum").read_text().splitlines() if not ln.startswith("#")]
    assert len(rows) == report["published_poses"]
    # the events were said on the console as they happened, and written to events.jsonl
    # (on a loaded machine a live run may fall behind first: a `falling_behind` event, images dropped,
    # or an IMU gap)
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    publishing = [e for e in events if e["kind"] == "publishing"]
    assert publishing[0]["source"] == report["published_by"]
    said = [ln.strip() for ln in err.splitlines() if "publishing metric poses" in ln]
    assert said[0].endswith(f" s: publishing metric poses ({report['published_by']})"), err
    assert float(said[0].split()[1]) == pytest.approx(publishing[0]["t_s"], abs=0.051)
    # --stream: every pose and event went out over UDP as it happened
    got = []
    with contextlib.suppress(TimeoutError):
        while True:
            got.append(json.loads(receiver.recvfrom(65536)[0]))
    receiver.close()
    poses_got = [m["type"] for m in got].count("pose")
    assert poses_got == report["published_poses"] == report["stream"]["poses_sent"]
    assert f"stream: {poses_got} poses and {len(events)} events sent to udp://127.0.0.1:" in captured.out
    assert "config.toml, events.jsonl" in captured.out
    assert [m["kind"] for m in got if m["type"] == "event"] == [e["kind"] for e in events]


@pytest.mark.slow
def test_a_serial_imu_that_pauses_resets_the_filter_and_the_run_goes_on(small_sim_folder: Path,
                                                                       tmp_path: Path, capsys,
                                                                       monkeypatch) -> None:
    """The IMU silent for 1.5 s (its counter running on): with the old 1 s stall bound the run ended there
    (exit 1, run_status failed); a pause under --imu-stall (5 s) is an IMU outage the filter is reset for."""
    video = video_from_recording(small_sim_folder, tmp_path / "cam.avi")
    code = run_live_uvc(small_sim_folder, video,
                        ["live", "uvc", "--rig", str(small_sim_folder), "--native-only", "--seconds", "6",
                         "--out", str(tmp_path / "run")], monkeypatch, silent_s=(3.0, 4.5))
    err = capsys.readouterr().err
    assert code == 0, err
    out = tmp_path / "run"
    assert run_status(out) == "complete"
    report = json.loads((out / "report.json").read_text())
    reasons = report["pipeline"]["filter"]["divergence_reasons"] or report["pipeline"]["startup"].get(
        "divergence_reasons", [])
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    gaps = [e for e in events if e["kind"] == "imu_gap"]
    assert gaps and max(e["longest_s"] for e in gaps) == pytest.approx(1.5, abs=0.1)
    assert report["driver"]["streams"]["imu0"]["emitted"] > 600
    if report["first_published_by"] is not None and report["T_f_s"] < 2.9:    # published before the pause
        assert any(e["kind"] == "reset" and "IMU outage of 1.5" in e["reason"] for e in events), reasons


def test_live_without_devices_or_calibration_is_a_clear_error(tmp_path: Path, capsys) -> None:
    assert main(["live", "oak", "--out", str(tmp_path / "a")]) == 1     # no OAK on this machine
    assert "no OAK device found" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "a.partial").exists()
    assert main(["live", "uvc", "--out", str(tmp_path / "b")]) == 1
    assert "needs --imu-port" in capsys.readouterr().err
    rig = Path(__file__).resolve().parents[2] / "calib" / "rigs"
    rig_file = next(rig.glob("*.yaml"))
    assert main(["live", "uvc", "--camera", str(tmp_path / "no-such-video.avi"), "--imu-port",
                 str(tmp_path / "ttyUSB9"), "--rig", str(rig_file), "--out", str(tmp_path / "c")]) == 1
    err = capsys.readouterr().err
    assert "davio live: error:" in err
    assert not (tmp_path / "c").exists() and not (tmp_path / "c.partial").exists()


@pytest.mark.parametrize("command", ["live", "calibrate"])
def test_the_model_is_loaded_before_the_camera_starts_when_the_rig_is_given(tmp_path: Path, capsys,
                                                                             monkeypatch, command) -> None:
    """A started camera drops its images until the run reads them: with --rig the model (whose warm-up
    takes seconds) is opened first, and a model that fails leaves the devices unopened. Without --rig (an
    OAK's factory calibration) the device comes first, as the model needs its intrinsics."""
    import tools.commands.live as live
    import tools.model_open as model_open
    from runtime.errors import DeviceError, ModelError

    calls: list[str] = []

    def fake_open_device(args, rig):
        calls.append("device")
        raise DeviceError("no such device (test)")

    def fake_open_da3(*args, **kwargs):
        calls.append("model")
        raise ModelError("bad model (test)")

    monkeypatch.setattr(live, "open_device", fake_open_device)
    monkeypatch.setattr(model_open, "open_da3", fake_open_da3)
    rig_file = Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml"
    model = tmp_path / "da3.onnx"
    model.write_bytes(b"not read")
    out = ["--out", str(tmp_path / ("run" if command == "live" else "rig.yaml"))]
    assert main([command, "uvc", "--imu-port", str(tmp_path / "tty"), "--rig", str(rig_file),
                 "--model", str(model), *out]) == 1
    assert "bad model (test)" in capsys.readouterr().err and calls == ["model"]
    calls.clear()
    assert main([command, "oak", "--model", str(model), *out]) == 1
    assert "no such device (test)" in capsys.readouterr().err and calls == ["device"]


class _FakeDriver:
    """A live driver that counts its stops (no device behind it)."""

    def __init__(self) -> None:
        self.stops = 0

    def start(self) -> None:
        pass

    def stop(self) -> None:
        self.stops += 1

    def events(self):
        return iter(())

    def report(self) -> dict:
        return {}


def _fake_devices(monkeypatch) -> list[_FakeDriver]:
    """open_device hands out _FakeDriver with the EuRoC camchain as the device's calibration."""
    import tools.commands.live as live
    from calib import load_rig

    rig = load_rig(Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml")
    drivers: list[_FakeDriver] = []

    def fake_open_device(args, given):
        drivers.append(_FakeDriver())
        return drivers[-1], given if given is not None else rig

    monkeypatch.setattr(live, "open_device", fake_open_device)
    return drivers


def test_live_stops_the_device_when_the_run_folder_cannot_be_made(tmp_path: Path, capsys,
                                                                   monkeypatch) -> None:
    from runtime.errors import ConfigError
    from tools.run_folder import RunFolder

    drivers = _fake_devices(monkeypatch)

    def cannot_create(self):
        raise ConfigError(f"--out {self.out}: cannot create it (test)")

    monkeypatch.setattr(RunFolder, "create", cannot_create)
    rig_file = Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml"
    assert main(["live", "uvc", "--imu-port", str(tmp_path / "tty"), "--rig", str(rig_file), "--out",
                 str(tmp_path / "run")]) == 1
    assert "cannot create it (test)" in capsys.readouterr().err
    assert len(drivers) == 1 and drivers[0].stops >= 1


def test_calibrate_stops_the_device_when_its_banner_cannot_be_said(tmp_path: Path, monkeypatch) -> None:
    """A console that fails between the device's opening and the run (a closed stdout) still stops it."""
    import errno
    import sys

    drivers = _fake_devices(monkeypatch)

    class ClosedConsole:
        def write(self, text):
            raise OSError(errno.EPIPE, "Broken pipe")

        def flush(self):
            pass

    monkeypatch.setattr(sys, "stdout", ClosedConsole())
    assert main(["calibrate", "oak", "--out", str(tmp_path / "rig.yaml")]) == 141     # a closed pipe: quiet
    assert len(drivers) == 1 and drivers[0].stops >= 1
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("command", ["live", "calibrate"])
@pytest.mark.parametrize("source", ["uvc", "oak"])
def test_the_filter_kernels_are_loaded_before_the_streams_start(tmp_path: Path, capsys, monkeypatch,
                                                                command, source) -> None:
    """A first session loads numba's kernels (0.2 s on a 2-core machine, 1 s on a slow one) while a started
    camera would drop its images: they are loaded before the streams start, with --rig (uvc) and with an
    OAK's factory calibration, also by a calibration, whose filter the bring-up makes mid-run."""
    import runtime.msckf.warmup as warmup
    import tools.commands.live as live
    from calib import load_rig
    from runtime.errors import DeviceError

    monkeypatch.setattr(warmup, "_WARMED", set())
    rig_file = Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml"
    factory = load_rig(rig_file)
    warmed_at_start: list[int] = []

    class Driver(_FakeDriver):
        def start(self) -> None:
            warmed_at_start.append(len(warmup._WARMED))
            raise DeviceError("no such device (test)")

    def fake_open_device(args, rig):
        return Driver(), rig if rig is not None else factory

    monkeypatch.setattr(live, "open_device", fake_open_device)
    device = (["uvc", "--imu-port", str(tmp_path / "tty"), "--rig", str(rig_file)] if source == "uvc"
              else ["oak"])
    out = str(tmp_path / ("run" if command == "live" else "rig.yaml"))
    assert main([command, *device, "--out", out]) == 1
    assert "no such device (test)" in capsys.readouterr().err
    assert len(warmed_at_start) == 1 and warmed_at_start[0] >= 1


def test_the_live_view_opens_before_the_device_and_closes_after_it(tmp_path: Path, capsys,
                                                                   monkeypatch) -> None:
    """--view's server (viser's import: 0.7 s) starts before the camera would drop images; a device that
    then fails closes it, and a run's sinks borrow it without closing it."""
    import tools.commands.live as live
    import tools.live_view as live_view
    from runtime.errors import DeviceError
    from tools.run_sinks import RunSinks

    calls: list[str] = []

    class FakeView:
        def close(self) -> None:
            calls.append("view closed")

        def on_pose(self, pose) -> None:
            pass

    def fake_open_view(port):
        calls.append(f"view {port}")
        return FakeView()

    def fake_open_device(args, rig):
        calls.append("device")
        raise DeviceError("no such device (test)")

    monkeypatch.setattr(live_view, "open_view", fake_open_view)
    monkeypatch.setattr(live, "open_device", fake_open_device)
    rig_file = Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml"
    assert main(["live", "uvc", "--imu-port", str(tmp_path / "tty"), "--rig", str(rig_file), "--view", "8765",
                 "--out", str(tmp_path / "run")]) == 1
    assert "no such device (test)" in capsys.readouterr().err
    assert calls == ["view ('0.0.0.0', 8765)", "device", "view closed"]
    calls.clear()
    sinks = RunSinks(tmp_path, None, None, view=FakeView())
    sinks.close()
    assert calls == [] and sinks.view is not None


@pytest.mark.parametrize("command", ["live", "calibrate"])
def test_an_oaks_factory_calibration_is_read_before_its_streams_start(tmp_path: Path, capsys, monkeypatch,
                                                                       command) -> None:
    """Without --rig the model needs the OAK's factory intrinsics: the device is opened and its calibration
    read, the model loaded (a DA3 warm-up takes seconds), and only then the streams start, so that no image
    is dropped while the model loads. A model that fails leaves the streams unstarted, the device closed."""
    import depthai as dai

    import drivers.oak as oak
    import tools.model_open as model_open
    from runtime.errors import DeviceError, ModelError

    calls: list[str] = []
    fixture = Path(__file__).resolve().parents[1] / "drivers" / "fixtures" / "oak_calib.json"

    class Pipe:
        def stop(self) -> None:
            calls.append("closed")

    def start() -> None:
        calls.append("streams")
        raise DeviceError("streams refused (test)")

    def factory(dev):
        calls.append("opened")
        calibration = dai.CalibrationHandler(str(fixture))
        return oak.OakPipeline(None, None, Pipe(), calibration, "OAK fake", None, start)

    fail_model = [True]

    def fake_open_da3(args, camera, views):
        calls.append(f"model {camera.width}x{camera.height}")
        if fail_model[0]:
            raise ModelError("bad model (test)")
        return None, "fake model"

    monkeypatch.setattr(oak, "build_pipeline", factory)
    monkeypatch.setattr(model_open, "open_da3", fake_open_da3)
    model = tmp_path / "da3.onnx"
    model.write_bytes(b"not read")
    out = str(tmp_path / ("run" if command == "live" else "rig.yaml"))
    assert main([command, "oak", "--model", str(model), "--out", out]) == 1
    assert "bad model (test)" in capsys.readouterr().err
    assert calls == ["opened", "model 640x400", "closed"]
    calls.clear()
    fail_model[0] = False
    assert main([command, "oak", "--model", str(model), "--out", out]) == 1
    assert "streams refused (test)" in capsys.readouterr().err
    assert calls == ["opened", "model 640x400", "streams", "closed"]


@pytest.mark.parametrize("command", ["live", "calibrate"])
def test_an_oak_is_asked_for_the_rigs_image_size_and_a_different_one_is_refused_first(
        tmp_path: Path, capsys, monkeypatch, command) -> None:
    """With --rig the OAK was asked for 640x400 whatever the calibration's size, and the run failed on its
    first image after the model's warm-up."""
    import drivers.oak as oak
    from runtime.errors import DeviceError

    sizes: list[str] = []

    def factory(dev):
        sizes.append(f"{dev.width}x{dev.height}")
        raise DeviceError("stop here (test)")

    monkeypatch.setattr(oak, "build_pipeline", factory)
    rig_file = Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml"
    out = str(tmp_path / ("run" if command == "live" else "rig.yaml"))
    assert main([command, "oak", "--rig", str(rig_file), "--out", out]) == 1
    assert sizes == ["752x480"] and "stop here (test)" in capsys.readouterr().err
    assert main([command, "oak", "--rig", str(rig_file), "--width", "640", "--out", out]) == 1
    assert sizes == ["752x480"]                                  # refused before the device opened
    assert ("--width/--height ask for 640x480 images but the --rig calibration is of 752x480 images"
            in capsys.readouterr().err)


def test_corrupt_factory_extrinsics_are_said_on_the_console(tmp_path: Path, capsys, monkeypatch) -> None:
    import json

    import depthai as dai

    import drivers.oak as oak
    from runtime.errors import DeviceError

    data = json.loads((Path(__file__).resolve().parents[1] / "drivers" / "fixtures" / "oak_calib.json"
                       ).read_text())
    data["imuExtrinsics"]["rotationMatrix"] = [[0.0] * 3] * 3
    eeprom = tmp_path / "eeprom.json"
    eeprom.write_text(json.dumps(data))

    class Pipe:
        def stop(self) -> None:
            pass

    def start() -> None:
        raise DeviceError("streams refused (test)")

    monkeypatch.setattr(oak, "build_pipeline", lambda dev: oak.OakPipeline(
        None, None, Pipe(), dai.CalibrationHandler(str(eeprom)), "OAK fake", None, start))
    assert main(["live", "oak", "--out", str(tmp_path / "run")]) == 1
    err = capsys.readouterr().err
    assert ("davio: note: OAK calibration CAM_B: the factory IMU-camera extrinsics are not a rigid transform"
            in err) and "the hand-eye bring-up estimates them" in err and "streams refused (test)" in err


@pytest.mark.parametrize("command", ["live", "calibrate"])
@pytest.mark.parametrize("source", ["uvc", "oak"])
def test_the_streams_start_once_the_run_can_read_them(tmp_path: Path, capsys, monkeypatch, command,
                                                      source) -> None:
    """A started camera's newest-frames buffer drops the images the run has not read: the streams start
    after the run's session is made, right before the first read. A start that fails is the command's
    one line (no banner before it), closes the device, and leaves no run folder or events file behind;
    with --overwrite an earlier calibration's report and events stay as they were."""
    import drivers.oak as oak
    import runtime.session as session_module
    from drivers.serial_imu import SerialImu
    from runtime.errors import DeviceError

    calls: list[str] = []
    init = session_module.Session.__init__

    def recording_init(self, *args, **kwargs) -> None:
        calls.append("session")
        init(self, *args, **kwargs)

    def refuse(*_args) -> None:
        calls.append("streams")
        raise DeviceError("streams refused (test)")

    class Pipe:
        def stop(self) -> None:
            calls.append("closed")

    monkeypatch.setattr(session_module.Session, "__init__", recording_init)
    if source == "oak":
        dai = pytest.importorskip("depthai")
        fixture = Path(__file__).resolve().parents[1] / "drivers" / "fixtures" / "oak_calib.json"
        monkeypatch.setattr(oak, "build_pipeline", lambda dev: oak.OakPipeline(
            None, None, Pipe(), dai.CalibrationHandler(str(fixture)), "OAK fake", None, refuse))
        device = ["oak"]
    else:       # LiveDriver starts the IMU first, then the camera
        monkeypatch.setattr(SerialImu, "start", refuse)
        rig_file = Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml"
        device = ["uvc", "--imu-port", str(tmp_path / "tty"), "--rig", str(rig_file)]
    out = tmp_path / ("run" if command == "live" else "rig.yaml")
    assert main([command, *device, "--out", str(out)]) == 1
    captured = capsys.readouterr()
    assert captured.err == f"davio {command}: error: streams refused (test)\n" and captured.out == ""
    assert calls == ["session", "streams", "closed"] if source == "oak" else ["session", "streams"]
    assert not any(tmp_path.iterdir())
    if command == "calibrate":
        earlier = {tmp_path / "rig.report.json": "{}\n", tmp_path / "rig.events.jsonl": '{"kind": "x"}\n'}
        for path, text in earlier.items():
            path.write_text(text)
        assert main([command, *device, "--out", str(out), "--overwrite"]) == 1
        assert capsys.readouterr().err == "davio calibrate: error: streams refused (test)\n"
        assert {p: p.read_text() for p in earlier} == earlier
        assert sorted(tmp_path.iterdir()) == sorted(earlier)


def test_imu_stall_and_baud_reach_the_serial_reader(monkeypatch) -> None:
    """--imu-stall (a device that pauses to recalibrate ended the run after 1 s) and --baud are checked
    as parsed and handed to SerialImu."""
    import drivers.serial_imu as serial_imu
    from calib import load_rig
    from tools.cli import build_parser
    from tools.commands.live import _open_driver

    seen = {}

    class Recorder:
        def __init__(self, port, **kw) -> None:
            seen.update(kw, port=port)

    monkeypatch.setattr(serial_imu, "SerialImu", Recorder)
    parser = build_parser(only="live")
    args = parser.parse_args(["live", "uvc", "--camera", "0", "--imu-port", "/dev/ttyX", "--imu-stall", "5",
                              "--baud", "921600", "--imu-protocol", "text"])
    rig = load_rig(Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml")
    _open_driver(args, rig)
    assert seen == {"port": "/dev/ttyX", "protocol": "text", "baudrate": 921600, "stall_timeout_s": 5.0}
    for bad in (["--imu-stall", "0"], ["--imu-stall", "nan"], ["--baud", "0"]):
        with pytest.raises(SystemExit):
            parser.parse_args(["live", "uvc", *bad])
