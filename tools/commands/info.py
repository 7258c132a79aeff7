"""`davio info`: versions, ONNX Runtime execution providers, numba status (and a model check, and the
camera-IMU hardware attached)."""
from __future__ import annotations

import argparse
import platform

from runtime.json_out import strict_dumps

NAME = "info"
HELP = ("report versions, ONNX Runtime providers, numba status; validate a model with --model; list the "
        "attached OAK devices, cameras and serial ports with --devices")

_PACKAGES = ["davio", "numpy", "scipy", "opencv-python-headless", "onnxruntime", "onnxruntime-gpu",
             "onnx", "numba", "open3d-cpu", "open3d", "depthai", "pyserial", "rosbags"]


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.add_argument("--model", metavar="PATH", default=None,
                   help="also load and validate this ONNX model (DA3 or XFeat contract)")
    p.add_argument("--devices", action="store_true",
                   help="also list the hardware `davio live` can open: OAK devices (depthai's probe, up to "
                        "2 s), V4L2 video nodes (--camera) and serial ports (--imu-port)")


def collect() -> dict:
    """Gather the facts `davio info` reports (no hardware is touched)."""
    from importlib.metadata import PackageNotFoundError, version

    versions = {}
    for name in _PACKAGES:
        try:
            versions[name] = version(name)
        except PackageNotFoundError:
            continue
    out: dict = {"python": platform.python_version(), "machine": platform.machine(),
                 "system": platform.system(), "packages": versions}
    try:
        import onnxruntime as ort

        out["onnxruntime"] = {"available_providers": ort.get_available_providers(),
                              "device": ort.get_device()}
    except Exception as exc:  # a broken install is reported, not raised
        out["onnxruntime"] = {"error": f"{type(exc).__name__}: {exc}"}
    try:
        import numba

        from runtime.geometry import kernels_status

        out["numba"] = {"version": numba.__version__, "threading_layer": _numba_layer(),
                        "jit": kernels_status()}
    except Exception as exc:
        out["numba"] = {"error": f"{type(exc).__name__}: {exc}"}
    try:
        from models.providers import describe_providers

        out["execution"] = describe_providers()
    except ImportError:
        pass
    from models.gpu_inventory import gpu_inventory

    gpus, note = gpu_inventory()
    out["gpus"] = {"devices": gpus, "note": note}
    return out


def _numba_layer() -> str:
    import numba

    try:
        return str(numba.config.THREADING_LAYER)
    except Exception:
        return "unknown"


def run(args: argparse.Namespace) -> int:
    info = collect()
    if args.model:
        from models.inspect_model import inspect_model

        info["model"] = inspect_model(args.model)
    if args.devices:
        from drivers.inventory import inventory

        info["devices"] = inventory()
    if args.json:
        print(strict_dumps(info, indent=2))
        return 0
    from rich.table import Table

    from tools.stdout_console import stdout_console

    con = stdout_console()
    t = Table(title="DAVIO environment", show_header=False)
    t.add_row("python", f"{info['python']} ({info['system']} {info['machine']})")
    for k, v in info["packages"].items():
        t.add_row(k, v)
    ort = info["onnxruntime"]
    t.add_row("ORT providers", ", ".join(ort.get("available_providers", [])) or ort.get("error", "?"))
    if "execution" in info:
        ex = info["execution"]
        t.add_row("DA3 will run on", f"{ex.get('selected')} ({ex.get('reason')})")
        if ex.get("warning"):
            t.add_row("ONNX Runtime", f"WARNING: {ex['warning']}")
    for g in info["gpus"]["devices"]:
        t.add_row(f"GPU {g['index']}", f"{g['name']}, {g['memory_total_mib']} MiB "
                                       f"({g['memory_used_mib']} MiB in use)")
    if info["gpus"]["note"]:
        t.add_row("GPUs", info["gpus"]["note"])
    nb = info["numba"]
    t.add_row("numba", nb.get("error") or f"{nb['version']}, kernels: {nb['jit']}")
    con.print(t)
    if "model" in info:
        m = info["model"]
        from rich.markup import escape

        # shapes print as JSON lists ("[null, 5, 3, 322, 504]") and paths may hold brackets: not markup
        mt = Table(title=escape(f"model {args.model}"), show_header=False)
        for k, v in m.items():
            mt.add_row(escape(str(k)), escape(strict_dumps(v) if not isinstance(v, str) else v))
        con.print(mt)
    if "devices" in info:
        con.print(_devices_table(info["devices"]))
    return 0


def _devices_table(devices: dict) -> object:
    """The --devices listing: one row per device, with the option that opens it, or the note of a kind
    with none."""
    from rich.table import Table

    t = Table(title="camera-IMU hardware (davio live)", show_header=False)
    oaks = devices["oak"]["devices"]
    for d in oaks:
        busy = "" if d["available"] else ", opened by another program"
        use = "davio live oak" + ("" if len(oaks) == 1 else f" --device-id {d['device_id'] or d['name']}")
        t.add_row(f"OAK {d['device_id'] or d['name']}",
                  f"{d['platform']} {d['protocol']}, {d['state']}{busy}: {use}")
    for d in devices["video"]["devices"]:
        metadata = d["driver"] == "uvcvideo" and d["node"] is not None and d["node"] % 2 == 1
        role = ", metadata node: no images" if metadata else ""
        absent = "" if d["present"] else f" (no {d['path']} here)"
        t.add_row(d["path"], f"{d['name'] or '?'}{role}{absent}: --camera {d['number']}")
    for d in devices["serial"]["devices"]:
        usb = (f" [USB {d['vid']:04x}:{d['pid']:04x}]" if d["vid"] is not None and d["pid"] is not None
               else "")
        t.add_row(d["device"], f"{d['description'] or d['manufacturer'] or 'serial port'}{usb}: "
                               f"--imu-port {d['device']}")
    for kind, label in (("oak", "OAK"), ("video", "cameras"), ("serial", "serial ports")):
        if devices[kind]["note"]:
            t.add_row(label, devices[kind]["note"])
    return t
