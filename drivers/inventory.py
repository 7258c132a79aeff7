"""The camera-IMU hardware this machine shows to DAVIO's live drivers, for bring-up (`davio info --devices`):
OAK devices (depthai's probe), V4L2 video nodes (a UVC camera's `--camera`) and serial ports (a serial IMU's
`--imu-port`). Each list comes with a note saying why it is empty or incomplete; nothing is opened, except
that depthai's probe talks to the USB bus (up to `oak_timeout_s`)."""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from runtime.errors import DeviceError

VIDEO4LINUX = Path("/sys/class/video4linux")


def oak_devices(timeout_s: float = 2.0) -> tuple[list[dict[str, Any]], str | None]:
    """(OAK devices as dicts: device_id, name, state, protocol, platform, available (False: opened by another
    program), note): depthai's probe (`drivers.oak_pipeline.oak_available`); the note says when none is
    attached, or why the probe could not run (depthai missing, a probe that failed or did not finish)."""
    from drivers.oak_pipeline import oak_available

    try:
        found = oak_available(timeout_s)
    except DeviceError as exc:
        return [], str(exc)
    devices = [{k: v for k, v in d.items() if k != "info"} for d in found]
    return devices, None if devices else "no OAK device attached (depthai's probe found none)"


def video_devices(root: Path | None = None, dev_root: Path = Path("/dev")) -> tuple[list[dict[str, Any]],
                                                                                    str | None]:
    """(V4L2 video nodes by number: path (/dev/videoN), number (`davio live uvc --camera N`), name (the
    device's), driver (the kernel module, e.g. "uvcvideo"), node (its registration order within the
    device: uvcvideo, since Linux 4.16, registers an image node then a metadata node for each streaming
    interface, so a UVC camera's odd nodes deliver no images), present (its /dev node exists here: a
    container may not pass it), note).

    Read from sysfs (`root`, default Linux's /sys/class/video4linux); elsewhere the list is empty and the
    note says to pass the camera's index."""
    root = VIDEO4LINUX if root is None else root
    if not root.is_dir():
        return [], (f"no {root}: no video device on this Linux machine (in a container: pass the /dev/video* "
                    "nodes), or not Linux (pass the camera's index or path to --camera, as OpenCV numbers "
                    "them)")
    nodes = []
    for entry in root.iterdir():
        match = re.fullmatch(r"video(\d+)", entry.name)
        if match is None:
            continue
        driver = entry / "device" / "driver"
        nodes.append({"path": f"/dev/{entry.name}", "number": int(match.group(1)),
                      "name": _read_text(entry / "name"),
                      "driver": driver.resolve().name if driver.exists() else None,
                      "node": _read_int(entry / "index"), "present": (dev_root / entry.name).exists()})
    nodes.sort(key=lambda d: d["number"])
    return nodes, None if nodes else "no video device (no /dev/video* node)"


def serial_ports() -> tuple[list[dict[str, Any]], str | None]:
    """(serial ports as dicts: device (`--imu-port`), description, hwid, vid, pid, manufacturer, serial_number
    (USB ones; None otherwise), note): pyserial's `list_ports.comports()`."""
    try:
        from serial.tools import list_ports
    except ImportError:
        return [], "pyserial is not installed: pip install pyserial"
    try:
        ports = list(list_ports.comports())
    except Exception as exc:  # noqa: BLE001 - a platform listing that fails is reported, not raised
        return [], f"listing the serial ports failed: {type(exc).__name__}: {exc}"
    out = [{"device": str(p.device), "description": _clean(p.description), "hwid": _clean(p.hwid),
            "vid": p.vid, "pid": p.pid, "manufacturer": p.manufacturer, "serial_number": p.serial_number}
           for p in ports]
    out.sort(key=lambda d: d["device"])
    return out, None if out else "no serial port"


def inventory(oak_timeout_s: float = 2.0, video_root: Path | None = None) -> dict[str, dict[str, Any]]:
    """{"oak": ..., "video": ..., "serial": ...}, each {"devices": [...], "note": str | None}."""
    out = {}
    for key, (devices, note) in (("oak", oak_devices(oak_timeout_s)), ("video", video_devices(video_root)),
                                 ("serial", serial_ports())):
        out[key] = {"devices": devices, "note": note}
    return out


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8", errors="replace").strip() or None
    except OSError:
        return None


def _read_int(path: Path) -> int | None:
    text = _read_text(path)
    try:
        return int(text) if text is not None else None
    except ValueError:
        return None


def _clean(text: Any) -> str | None:
    """pyserial says "n/a" where it knows nothing."""
    text = None if text is None else str(text).strip()
    return None if not text or text == "n/a" else text
