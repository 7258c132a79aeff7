"""`drivers.inventory` (`davio info --devices`): the video nodes read from a sysfs tree written here, the
serial ports from pyserial's listing (faked where this machine has none to show), the OAK probe for real
(no OAK is attached here), and the command's JSON kept clean of depthai's log lines."""
from __future__ import annotations

import json
import subprocess
import sys
import types
from pathlib import Path

import pytest

from drivers import inventory
from runtime.errors import DeviceError
from tools.cli import main

ROOT = Path(__file__).resolve().parents[2]


def _sysfs(root: Path, nodes: dict[str, tuple[str | None, str | None, str | None]]) -> Path:
    """A /sys/class/video4linux tree: node name -> (its device's name, its index, its driver's name)."""
    for name, (label, index, driver) in nodes.items():
        (root / name / "device").mkdir(parents=True)
        if label is not None:
            (root / name / "name").write_text(label + "\n")
        if index is not None:
            (root / name / "index").write_text(index + "\n")
        if driver is not None:
            (root.parent / "drivers" / driver).mkdir(parents=True, exist_ok=True)
            (root / name / "device" / "driver").symlink_to(root.parent / "drivers" / driver)
    return root


def test_video_nodes_are_listed_by_number_with_their_driver_and_node_index(tmp_path: Path) -> None:
    root = _sysfs(tmp_path / "video4linux", {
        "video10": ("OAK-D UVC", "0", "uvcvideo"), "video0": ("HD USB Camera", "0", "uvcvideo"),
        "video1": ("HD USB Camera", "1", "uvcvideo"), "video2": (None, "x", None),
        "video3": ("bcm2835-isp", "1", "bcm2835-isp"), "v4l-subdev0": ("isp", "0", None)})
    dev = tmp_path / "dev"
    dev.mkdir()
    for name in ("video0", "video1", "video3"):
        (dev / name).touch()
    nodes, note = inventory.video_devices(root, dev)
    assert note is None
    assert nodes == [
        {"path": "/dev/video0", "number": 0, "name": "HD USB Camera", "driver": "uvcvideo", "node": 0,
         "present": True},
        {"path": "/dev/video1", "number": 1, "name": "HD USB Camera", "driver": "uvcvideo", "node": 1,
         "present": True},
        {"path": "/dev/video2", "number": 2, "name": None, "driver": None, "node": None, "present": False},
        {"path": "/dev/video3", "number": 3, "name": "bcm2835-isp", "driver": "bcm2835-isp", "node": 1,
         "present": True},
        {"path": "/dev/video10", "number": 10, "name": "OAK-D UVC", "driver": "uvcvideo", "node": 0,
         "present": False}]
    nodes, note = inventory.video_devices(tmp_path / "absent")
    assert nodes == [] and note.startswith(f"no {tmp_path / 'absent'}: no video device")
    (tmp_path / "empty").mkdir()
    assert inventory.video_devices(tmp_path / "empty") == ([], "no video device (no /dev/video* node)")


def test_serial_ports_come_from_pyserials_listing(monkeypatch) -> None:
    from serial.tools import list_ports

    usb = types.SimpleNamespace(device="/dev/ttyUSB0", description="MTi-630 AHRS",
                                hwid="USB VID:PID=2639:0300", vid=0x2639, pid=0x0300, manufacturer="Xsens",
                                serial_number="DB8E1234")
    legacy = types.SimpleNamespace(device="/dev/ttyS0", description="n/a", hwid="n/a", vid=None, pid=None,
                                   manufacturer=None, serial_number=None)
    monkeypatch.setattr(list_ports, "comports", lambda: [usb, legacy])
    ports, note = inventory.serial_ports()
    assert note is None and [p["device"] for p in ports] == ["/dev/ttyS0", "/dev/ttyUSB0"]
    assert ports[0]["description"] is None and ports[0]["hwid"] is None          # pyserial's "n/a"
    assert ports[1] == {"device": "/dev/ttyUSB0", "description": "MTi-630 AHRS", "hwid": usb.hwid,
                        "vid": 0x2639, "pid": 0x0300, "manufacturer": "Xsens", "serial_number": "DB8E1234"}

    def broken():
        raise OSError("sysfs unreadable")

    monkeypatch.setattr(list_ports, "comports", broken)
    assert inventory.serial_ports() == ([], "listing the serial ports failed: OSError: sysfs unreadable")
    monkeypatch.setattr(list_ports, "comports", lambda: [])
    assert inventory.serial_ports() == ([], "no serial port")


def test_the_oak_probe_runs_and_says_why_it_found_none(monkeypatch) -> None:
    pytest.importorskip("depthai")
    import drivers.oak_pipeline as oak_pipeline

    devices, note = inventory.oak_devices(2.0)
    if devices:         # a machine with an OAK attached
        assert note is None and {"device_id", "state", "available"} <= set(devices[0])
    else:
        assert note == "no OAK device attached (depthai's probe found none)"

    def failing(timeout_s):
        raise DeviceError("probing for OAK devices did not finish within 2 s")

    monkeypatch.setattr(oak_pipeline, "oak_available", failing)
    assert inventory.oak_devices(2.0) == ([], "probing for OAK devices did not finish within 2 s")
    busy = {"device_id": "1844301011", "name": "1.3", "state": "X_LINK_BOOTED", "protocol": "X_LINK_USB_VSC",
            "platform": "RVC2", "info": object(), "available": False}
    monkeypatch.setattr(oak_pipeline, "oak_available", lambda timeout_s: [busy])
    devices, note = inventory.oak_devices(2.0)
    assert note is None and devices == [{k: v for k, v in busy.items() if k != "info"}]


def test_info_devices_lists_each_kind_with_the_option_that_opens_it(tmp_path: Path, capsys,
                                                                     monkeypatch) -> None:
    from serial.tools import list_ports

    import drivers.oak_pipeline as oak_pipeline

    monkeypatch.setattr(inventory, "VIDEO4LINUX", _sysfs(tmp_path / "v4l", {
        "video0": ("HD USB Camera", "0", "uvcvideo"), "video1": ("HD USB Camera", "1", "uvcvideo"),
        "video2": ("bcm2835-isp", "1", "bcm2835-isp")}))
    monkeypatch.setattr(list_ports, "comports", lambda: [types.SimpleNamespace(
        device="/dev/ttyUSB0", description="MTi-630 AHRS", hwid="USB", vid=0x2639, pid=0x0300,
        manufacturer="Xsens", serial_number=None)])
    oaks = [{"device_id": f"184430100{k}", "name": f"1.{k}", "state": "X_LINK_UNBOOTED",
             "protocol": "X_LINK_USB_VSC", "platform": "RVC2", "info": None, "available": k == 1}
            for k in (1, 2)]
    monkeypatch.setattr(oak_pipeline, "oak_available", lambda timeout_s: oaks)
    monkeypatch.setenv("COLUMNS", "200")      # rich's table on one line a row
    assert main(["info", "--devices"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "RVC2 X_LINK_USB_VSC, X_LINK_UNBOOTED: davio live oak --device-id 1844301001" in out
    assert "X_LINK_UNBOOTED, opened by another program: davio live oak --device-id 1844301002" in out
    # this machine has no /dev/video* node: each is listed as absent here
    assert "HD USB Camera (no /dev/video0 here): --camera 0" in out
    assert "HD USB Camera, metadata node: no images (no /dev/video1 here): --camera 1" in out
    assert "bcm2835-isp (no /dev/video2 here): --camera 2" in out     # not a UVC camera: no role said
    assert "MTi-630 AHRS [USB 2639:0300]: --imu-port /dev/ttyUSB0" in out
    assert main(["info", "--devices", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)["devices"]
    assert [d["device_id"] for d in got["oak"]["devices"]] == ["1844301001", "1844301002"]
    assert [d["number"] for d in got["video"]["devices"]] == [0, 1, 2] and got["serial"]["note"] is None


def test_info_devices_json_is_clean_of_depthais_log_lines() -> None:
    """depthai's logger writes to stdout (in a container: "USB protocol not available"); a fresh process's
    --json output must still be one JSON object."""
    pytest.importorskip("depthai")
    out = subprocess.run([sys.executable, "-m", "tools.cli", "info", "--devices", "--json"], cwd=str(ROOT),
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert set(json.loads(out.stdout)["devices"]) == {"oak", "video", "serial"}


def test_depthai_loads_with_stdout_on_stderr_once(monkeypatch) -> None:
    """Once depthai is loaded the camera reader's look-up (a frame each) moves nothing."""
    pytest.importorskip("depthai")
    import drivers.oak_pipeline as oak_pipeline

    def must_not_move():
        raise AssertionError("stdout moved although depthai is loaded")

    monkeypatch.setattr(oak_pipeline, "stdout_to_stderr", must_not_move)
    assert oak_pipeline._import_depthai() is sys.modules["depthai"]
