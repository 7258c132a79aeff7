"""Stand-ins for a live camera-IMU module, for the tests of `davio live` and `davio calibrate oak|uvc`: a
recording's images as a video file (the UVC camera) and its IMU rows written at sensor rate to a
pseudo-terminal (the serial IMU, text protocol)."""
from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import cv2

from drivers.serial_imu.text import encode_line


def video_from_recording(rec: Path, out: Path) -> Path:
    files = sorted((rec / "mav0" / "cam0" / "data").glob("*.png"))
    first = cv2.imread(str(files[0]), cv2.IMREAD_GRAYSCALE)
    h, w = first.shape
    writer = cv2.VideoWriter(str(out), cv2.VideoWriter_fourcc(*"MJPG"), 20.0, (w, h), isColor=False)
    for f in files:
        writer.write(cv2.imread(str(f), cv2.IMREAD_GRAYSCALE))
    writer.release()
    return out


def imu_writer(rec: Path, fd: int, go: threading.Event, stop: threading.Event,
               silent_s: tuple[float, float] | None = None) -> threading.Thread:
    """Writes the recording's IMU rows as `$IMU` lines at sensor rate, from the moment `go` is set (the
    camera's first frame), so that camera and IMU share one clock as on a real module. `silent_s` (a, b):
    the rows between a and b seconds are not sent (a device that stalls, its counter running on)."""
    rows = [ln.split(",") for ln in (rec / "mav0" / "imu0" / "data.csv").read_text().splitlines()
            if ln and not ln.startswith("#")]

    def run() -> None:
        go.wait(30)
        t0_dev, t0_host = int(rows[0][0]), time.monotonic()
        for k, r in enumerate(rows):
            due = t0_host + (int(r[0]) - t0_dev) * 1e-9
            while not stop.is_set() and time.monotonic() < due:
                time.sleep(0.001)
            if stop.is_set():
                return
            if silent_s is not None and silent_s[0] <= (int(r[0]) - t0_dev) * 1e-9 < silent_s[1]:
                continue
            gyro, accel = [float(x) for x in r[1:4]], [float(x) for x in r[4:7]]
            try:
                os.write(fd, encode_line(k, (int(r[0]) - t0_dev) // 1000, accel, gyro))
            except OSError:
                return

    th = threading.Thread(target=run, daemon=True)
    th.start()
    return th


def run_live_uvc(rec: Path, video: Path, argv: list[str], monkeypatch: object,
                 silent_s: tuple[float, float] | None = None) -> int:
    """Run the CLI with `argv` + ["--camera", video, "--imu-port", <pty>, "--imu-protocol", "text"]: the
    recording's IMU rows reach the pseudo-terminal at sensor rate from the moment the UVC camera starts (as
    a module streams both sensors when its camera starts). Returns the command's exit code; the pty and the
    writer are closed whatever happens."""
    from drivers.uvc import UvcCamera
    from tools.cli import main

    master, slave = os.openpty()
    stop, go = threading.Event(), threading.Event()
    start = UvcCamera.start

    def start_and_go(self):
        out = start(self)
        go.set()
        return out

    monkeypatch.setattr(UvcCamera, "start", start_and_go)
    writer = imu_writer(rec, master, go, stop, silent_s)
    try:
        return main(argv + ["--camera", str(video), "--imu-port", os.ttyname(slave),
                            "--imu-protocol", "text"])
    finally:
        stop.set()
        writer.join(2)
        os.close(master)
        os.close(slave)
