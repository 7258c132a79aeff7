"""The OAK's depthai side before any message flows: probing for devices, opening one, reading its
calibration and building the pipeline (`build_pipeline`, `OakDevice`'s default factory), and depthai's
import. What the pipeline holds and why (reconnection off, stop on device loss, the IMU streams) is in
`drivers.oak`'s docstring; `drivers.oak_streams` reads its queues."""
from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from runtime.errors import DavioError, DeviceError
from runtime.stdout_fd import stdout_to_stderr

if TYPE_CHECKING:
    from drivers.oak import OakDevice

SOCKETS: tuple[str, ...] = ("CAM_A", "CAM_B", "CAM_C")
"""Camera sockets: CAM_A = colour (its luma is used), CAM_B = left mono, CAM_C = right mono."""

NO_DEVICE_HINT = ("is it plugged in? USB3? udev rules: SUBSYSTEM==\"usb\", ATTRS{idVendor}==\"03e7\", "
                  "MODE=\"0666\" in /etc/udev/rules.d/80-movidius.rules, then "
                  "`sudo udevadm control --reload-rules && sudo udevadm trigger`")


def _import_depthai() -> Any:
    """depthai 3 (DeviceError naming what is wrong otherwise: not installed, installed but failing to import,
    or depthai 2, whose API differs). Its first import runs with the process's stdout sent to stderr:
    depthai's logger writes to stdout as it loads (e.g. "USB protocol not available" in a container),
    which would break a command's --json output. Later calls (the camera reader's, a frame each) only
    look the module up."""
    dai = sys.modules.get("depthai")
    if dai is None:
        with _IMPORT_LOCK:
            try:
                with stdout_to_stderr():
                    import depthai as dai
            except ImportError as exc:
                if isinstance(exc, ModuleNotFoundError) and exc.name == "depthai":
                    raise DeviceError("the OAK driver needs depthai 3: pip install 'depthai>=3'") from None
                raise DeviceError(f"depthai is installed but does not import ({type(exc).__name__}: "
                                  f"{_one_line(exc)}): reinstall it, pip install --force-reinstall "
                                  f"'depthai>=3'") from None
    version = str(getattr(dai, "__version__", ""))
    major = version.split(".")[0]
    if major.isdigit() and int(major) < 3:
        raise DeviceError(f"depthai {version} is installed; the OAK driver needs depthai 3 (its API "
                          f"differs): pip install 'depthai>=3'")
    return dai


_IMPORT_LOCK = threading.Lock()


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


# -- probing -------------------------------------------------------------------------------------
def oak_available(timeout_s: float = 2.0) -> list[dict[str, Any]]:
    """The OAK devices depthai can see, as dicts: device_id, name, state, protocol, platform (strings),
    info (the `dai.DeviceInfo`, to open that device) and available (False: connected but already opened by
    another program, which `getAllAvailableDevices` leaves out); the available ones first.

    `[]` when none is attached. Raises DeviceError when depthai is not installed or the probe does not
    finish within `timeout_s`."""
    dai = _import_depthai()
    result: dict[str, Any] = {}

    def probe() -> None:
        try:
            result["infos"] = list(dai.Device.getAllAvailableDevices())
            result["connected"] = list(dai.Device.getAllConnectedDevices())
        except BaseException as exc:  # noqa: BLE001 - reported to the caller below
            result["exc"] = exc

    t = threading.Thread(target=probe, name="davio-oak-probe", daemon=True)
    t.start()
    t.join(timeout_s)
    if t.is_alive():
        raise DeviceError(f"probing for OAK devices did not finish within {timeout_s:g} s")
    if "exc" in result:
        raise DeviceError(f"probing for OAK devices failed: {_one_line(result['exc'])}")
    out, seen = [], set()
    for available, infos in ((True, result["infos"]), (False, result["connected"])):
        for info in infos:
            d = {"device_id": str(getattr(info, "deviceId", "") or ""),
                 "name": str(getattr(info, "name", "") or ""),
                 "state": str(getattr(info, "state", "")).split(".")[-1],
                 "protocol": str(getattr(info, "protocol", "")).split(".")[-1],
                 "platform": str(getattr(info, "platform", "")).split(".")[-1],
                 "info": info, "available": available}
            key = d["device_id"] or d["name"]
            if key not in seen:
                seen.add(key)
                out.append(d)
    return out


# -- pipeline ------------------------------------------------------------------------------------
def imu_sensors(dai: Any, calibrated: bool = False) -> list:
    """The accelerometer and gyroscope streams to enable: both in the DepthAI IMU frame (the frame of
    `getImuToCameraExtrinsics`), with or without the stored affine calibration."""
    S = dai.IMUSensor
    if calibrated:
        return [S.ACCELEROMETER_CALIBRATED, S.GYROSCOPE_CALIBRATED]
    return [S.ACCELEROMETER_UNCALIBRATED, S.GYROSCOPE_UNCALIBRATED]


@dataclass
class OakPipeline:
    """What a pipeline factory returns: two depthai-like output queues and what owns them.

    `camera_queue.get(timedelta)` and `imu_queue.get(timedelta)` return a message (`dai.ImgFrame`,
    `dai.IMUData` or objects with the same methods) or None on timeout, and raise once the queue is
    closed (device gone, pipeline stopped). `pipeline` (optional) has `stop()`. `calibration` is the
    device's `dai.CalibrationHandler` (or None). `start` starts the streams when the factory left them
    unstarted (`build_pipeline`: the device is open and its calibration read, so that a model can be loaded
    with the factory intrinsics before images flow and are dropped); None: the factory started them."""

    camera_queue: Any
    imu_queue: Any
    pipeline: Any = None
    calibration: Any = None
    device_info: str = ""
    device: Any = None
    start: Callable[[], None] | None = None
    calibration_problem: str = ""
    """Why no calibration was read (depthai's error), when `calibration` is None."""

    def stop(self) -> None:
        for obj in (self.pipeline, self.device):
            if obj is None:
                continue
            for name in ("stop", "close"):
                fn = getattr(obj, name, None)
                if callable(fn):
                    try:
                        fn()
                    except Exception:  # noqa: BLE001 - a dead device may fail to stop; nothing to do
                        pass
                    break


def build_pipeline(dev: OakDevice) -> OakPipeline:
    """The default pipeline factory: probe, open the device, read its calibration and build the pipeline;
    the returned `start` starts it."""
    dai = _import_depthai()
    found = oak_available(dev.probe_timeout_s)
    if not found:
        raise DeviceError(f"no OAK device found ({NO_DEVICE_HINT})")
    info = found[0]
    if dev.device_id is not None:
        match = [d for d in found if dev.device_id in (d["device_id"], d["name"])]
        if not match:
            listed = ", ".join(f"{d['device_id']} ({d['name']}, {d['state']})" for d in found)
            raise DeviceError(f"OAK device {dev.device_id} not found; attached: {listed}")
        info = match[0]
    what = f"OAK {info['device_id'] or info['name']}"
    if not info.get("available", True):
        raise DeviceError(f"{what}: connected but opened by another program (state {info['state']}); close "
                          "it, or unplug and plug in the device")
    try:
        device = dai.Device(info["info"])
    except Exception as exc:  # noqa: BLE001 - any depthai failure is a device error
        raise DeviceError(f"{what}: cannot be opened ({_one_line(exc)}; state {info['state']}: "
                          f"in use by another program?)") from None
    try:
        device.setMaxReconnectionAttempts(0)      # a reconnected device restarts its clock: fail instead
        pipeline = dai.Pipeline(device)
        pipeline.setStopOnDeviceLoss(True)
        imu_name = str(device.getConnectedIMU()).strip()
        if imu_name.upper() in ("", "NONE"):
            raise DeviceError(f"{what}: has no IMU (depthai reports {imu_name or 'none'}): DAVIO needs the "
                              f"module's IMU (an OAK-D Lite or a board without one cannot run it; use "
                              f"`davio live uvc` with a serial IMU)")
        calibration_problem = ""
        try:              # readCalibration would return a default calibration when none is flashed
            calibration = device.readCalibration2()
        except Exception as exc:  # noqa: BLE001 - streaming works without it; rig() says none was read
            calibration, calibration_problem = None, _one_line(exc)
        socket = getattr(dai.CameraBoardSocket, dev.socket)
        cam = pipeline.create(dai.node.Camera).build(socket)
        kind = dai.ImgFrame.Type.NV12 if dev.socket == "CAM_A" else dai.ImgFrame.Type.GRAY8
        out = cam.requestOutput((dev.width, dev.height), kind, dai.ImgResizeMode.CROP, dev.fps, False)
        q_img = out.createOutputQueue(dev.camera_queue_size, False)
        imu = pipeline.create(dai.node.IMU)
        sensors = imu_sensors(dai, dev.imu_calibrated)
        imu.enableIMUSensor(sensors, int(dev.imu_rate_hz))
        imu.setBatchReportThreshold(1)
        imu.setMaxBatchReports(10)
        q_imu = imu.out.createOutputQueue(dev.imu_queue_size, False)
    except BaseException as exc:  # noqa: BLE001 - Ctrl-C too: the open device is closed, not left to GC
        try:
            device.close()
        except Exception:  # noqa: BLE001 - a failing device may fail to close; the first error is reported
            pass
        if isinstance(exc, DavioError) or not isinstance(exc, Exception):
            raise
        raise DeviceError(f"{what}: the pipeline could not be built ({_one_line(exc)})") from None

    def start() -> None:
        try:
            pipeline.start()
        except Exception as exc:  # noqa: BLE001 - OakDevice.start closes the device
            raise DeviceError(f"{what}: the pipeline could not be started ({_one_line(exc)})") from None

    return OakPipeline(q_img, q_imu, pipeline, calibration, what, device, start, calibration_problem)
