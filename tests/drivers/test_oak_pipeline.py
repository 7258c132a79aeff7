"""The OAK pipeline factory (`drivers.oak_pipeline`) against depthai's real classes: the probe, the streams
it enables, what it calls on the device and pipeline, and that a device it opened is closed whenever the
build fails, Ctrl-C included."""
from __future__ import annotations

import os
import re
import types

import pytest

os.environ.setdefault("DEPTHAI_LEVEL", "error")
dai = pytest.importorskip("depthai")

import drivers.oak_pipeline as oak_pipeline  # noqa: E402
from drivers.oak import OakDevice  # noqa: E402
from drivers.oak_pipeline import imu_sensors  # noqa: E402
from runtime.errors import DeviceError  # noqa: E402


def test_imu_streams_are_in_the_depthai_imu_frame() -> None:
    """The streams enabled are the ones depthai documents as aligned to the DepthAI IMU frame (the frame
    getImuToCameraExtrinsics relates to the camera), never the _RAW ones (the chip's native axes)."""
    members = re.split(r"\n  ([A-Z_]+) : ", dai.IMUSensor.__doc__)
    doc = {name: " ".join(text.split()) for name, text in zip(members[1::2], members[2::2], strict=True)}
    for sensor in (*imu_sensors(dai), *imu_sensors(dai, calibrated=True)):
        assert "aligned to the DepthAI IMU frame" in doc[sensor.name], sensor.name
    assert "sensor-native frame" in doc["ACCELEROMETER_RAW"] and "sensor-native frame" in doc["GYROSCOPE_RAW"]
    assert [x.name for x in imu_sensors(dai)] == ["ACCELEROMETER_UNCALIBRATED", "GYROSCOPE_UNCALIBRATED"]


class _Recorder:
    """Stands in for a depthai object: records every method called on it as (real class, name)."""

    def __init__(self, calls: list, real: type, children: dict | None = None) -> None:
        self._calls, self._real, self._children = calls, real, children or {}

    def __getattr__(self, name: str):
        if name in self._children:
            return self._children[name]

        def method(*args, **kwargs):
            self._calls.append((self._real, name, args))
            return self._children.get(f"{name}()", _Recorder(self._calls, object))
        return method


def test_a_device_opened_by_another_program_is_named_as_such(monkeypatch) -> None:
    """getAllAvailableDevices leaves out a device another program opened; the probe also lists the
    connected ones, after the available ones, so the error says it is in use, not that none is plugged in."""

    busy = types.SimpleNamespace(deviceId="1844301011", name="1.3", state="XLinkDeviceState.X_LINK_BOOTED",
                                 protocol="X_LINK_USB_VSC", platform="RVC2")
    free = types.SimpleNamespace(deviceId="1944301022", name="1.4", state="XLinkDeviceState.X_LINK_UNBOOTED",
                                 protocol="X_LINK_USB_VSC", platform="RVC2")
    for available, connected in (([], [busy]), ([free], [busy, free])):
        fake = types.SimpleNamespace(Device=types.SimpleNamespace(
            getAllAvailableDevices=lambda a=available: a, getAllConnectedDevices=lambda c=connected: c))
        monkeypatch.setattr(oak_pipeline, "_import_depthai", lambda f=fake: f)
        found = oak_pipeline.oak_available(1.0)
        assert [d["available"] for d in found] == [True] * len(available) + [False]
        assert found[0]["device_id"] == (free.deviceId if available else busy.deviceId)
    monkeypatch.setattr(oak_pipeline, "oak_available", lambda timeout: [
        {"info": busy, "device_id": busy.deviceId, "name": busy.name, "state": "X_LINK_BOOTED",
         "available": False}])
    with pytest.raises(DeviceError, match=r"^OAK 1844301011: connected but opened by another program "
                                          r"\(state X_LINK_BOOTED\)"):
        oak_pipeline.build_pipeline(OakDevice())


def _fake_depthai(monkeypatch, fail: tuple[str, BaseException] | None = None) -> list:
    """Patch in a recording stand-in of depthai with one attached device; returns the calls list. `fail`:
    (method name, exception) raised by the device's or pipeline's method of that name, or by the creation
    of the Camera node ("create")."""
    calls: list = []
    out = _Recorder(calls, dai.Node.Output)
    cam = _Recorder(calls, dai.node.Camera, {"requestOutput()": out})
    imu = _Recorder(calls, dai.node.IMU, {"out": out})
    pipe = _Recorder(calls, dai.Pipeline)
    device = _Recorder(calls, dai.Device)
    creations = iter([_Recorder(calls, dai.node.Camera, {"build()": cam}), imu])

    def create(node):
        calls.append((dai.Pipeline, "create", (node,)))
        if fail is not None and fail[0] == "create":
            raise fail[1]
        return next(creations)
    pipe.create = create
    if fail is not None and fail[0] != "create":
        obj = device if hasattr(dai.Device, fail[0]) else pipe

        def raising(*args, name=fail[0], real=obj._real, exc=fail[1]):
            calls.append((real, name, args))
            raise exc
        setattr(obj, fail[0], raising)
    fake = types.SimpleNamespace(
        Device=lambda info: device, Pipeline=lambda d: pipe, node=dai.node, IMUSensor=dai.IMUSensor,
        CameraBoardSocket=dai.CameraBoardSocket, ImgFrame=dai.ImgFrame, ImgResizeMode=dai.ImgResizeMode)
    monkeypatch.setattr(oak_pipeline, "_import_depthai", lambda: fake)
    monkeypatch.setattr(oak_pipeline, "oak_available", lambda timeout: [
        {"info": None, "device_id": "X1", "name": "1.1", "state": "UNBOOTED"}])
    return calls


def test_the_pipeline_disables_reconnection_and_stops_on_device_loss(monkeypatch) -> None:
    """build_pipeline against a recording stand-in of depthai: every method it calls on the device,
    pipeline and nodes exists on the real depthai class; reconnection is off before the pipeline is
    built, the pipeline stops on device loss, and the IMU enables the frame-aligned streams. It opens the
    device and reads its calibration; the pipeline starts only when its `start` is called."""

    calls = _fake_depthai(monkeypatch)
    built = oak_pipeline.build_pipeline(OakDevice())
    assert (dai.Pipeline, "start") not in [(real, name) for real, name, _ in calls]   # opened, not started
    built.start()
    names = [(real, name) for real, name, _ in calls]
    assert names.index((dai.Device, "readCalibration2")) < names.index((dai.Pipeline, "start"))
    for real, name in names:
        assert hasattr(real, name), f"{real.__name__}.{name} does not exist in depthai"
    assert names.index((dai.Device, "setMaxReconnectionAttempts")) < names.index((dai.Pipeline, "start"))
    assert [a for r, n, a in calls if n == "setMaxReconnectionAttempts"] == [(0,)]
    assert [a for r, n, a in calls if n == "setStopOnDeviceLoss"] == [(True,)]
    sensors = [a[0] for r, n, a in calls if n == "enableIMUSensor"][0]
    assert sensors == imu_sensors(dai)


@pytest.mark.parametrize("reported", ["NONE", ""])
def test_an_oak_without_an_imu_is_said_and_closed(monkeypatch, reported: str) -> None:
    """An OAK-D Lite has no IMU: the IMU queue stayed silent and the run failed 10 s later as 'unplugged or
    stalled', with a false note that the consumer fell behind the camera."""
    calls = _fake_depthai(monkeypatch)
    device = oak_pipeline._import_depthai().Device(None)
    device._children["getConnectedIMU()"] = reported
    with pytest.raises(DeviceError, match=r"^OAK X1: has no IMU \(depthai reports (NONE|none)\): DAVIO "):
        oak_pipeline.build_pipeline(OakDevice())
    names = [(real, name) for real, name, _ in calls]
    assert names[-1] == (dai.Device, "close") and (dai.Pipeline, "create") not in names


def test_depthai_2_or_a_failing_import_is_named(monkeypatch, tmp_path) -> None:
    """depthai 2's API differs (the build failed on a missing method, the calibration on dai.LengthUnit);
    a depthai that is installed but fails to load is not 'not installed'."""
    import sys

    monkeypatch.setitem(sys.modules, "depthai", types.SimpleNamespace(__version__="2.28.0.0"))
    with pytest.raises(DeviceError, match=r"^depthai 2\.28\.0\.0 is installed; the OAK driver needs "):
        oak_pipeline._import_depthai()
    broken = tmp_path / "depthai"
    broken.mkdir()
    (broken / "__init__.py").write_text("raise ImportError('libusb-1.0.so.0: cannot open shared object "
                                        "file', name='depthai')\n")
    monkeypatch.delitem(sys.modules, "depthai")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(DeviceError, match=r"^depthai is installed but does not import \(ImportError: "
                                          r"libusb-1.0.so.0: cannot open"):
        oak_pipeline._import_depthai()
    monkeypatch.setitem(sys.modules, "depthai", None)        # not installed
    with pytest.raises(DeviceError, match=r"^the OAK driver needs depthai 3: pip install"):
        oak_pipeline._import_depthai()


def test_start_without_a_device_is_one_line_naming_the_probe_and_the_udev_rule() -> None:
    """The real depthai probe (no OAK is attached here): a probe that did not finish within its 2 s would
    say so instead."""
    dev = OakDevice()
    with pytest.raises(DeviceError) as info:
        dev.start()
    msg = str(info.value)
    assert msg.startswith("no OAK device found (is it plugged in? USB3? udev rules:") and "\n" not in msg
    assert "03e7" in msg


@pytest.mark.parametrize("fail", [("setMaxReconnectionAttempts", RuntimeError("X_LINK_ERROR")),
                                  ("setStopOnDeviceLoss", RuntimeError("not supported")),
                                  ("create", KeyboardInterrupt()),
                                  ("readCalibration2", KeyboardInterrupt())])
def test_a_device_opened_is_closed_when_the_build_fails(monkeypatch, fail) -> None:
    """Whatever stops the build after the device opened (a depthai error, or Ctrl-C while the nodes are
    made) closes the device before the error goes on; a depthai error is one line naming the device."""
    calls = _fake_depthai(monkeypatch, fail)
    expected = (KeyboardInterrupt if isinstance(fail[1], KeyboardInterrupt) else
                DeviceError)
    with pytest.raises(expected) as info:
        oak_pipeline.build_pipeline(OakDevice())
    if expected is DeviceError:
        assert str(info.value) == f"OAK X1: the pipeline could not be built ({fail[1]})"
    names = [(real, name) for real, name, _ in calls]
    assert (dai.Device, fail[0]) in names or (dai.Pipeline, fail[0]) in names
    assert names[-1] == (dai.Device, "close")
