"""`davio bench reliability`: broken inputs a field user meets, run through the real commands.

Each probe writes one defect into a copy of a small simulated recording (or a calibration, config,
trajectory or point-cloud file) and runs the `davio` command on it in this process. The table gives the
exit code, the first line of the message and whether a Python traceback escaped (never expected). The
expected outcome of every probe is written next to it: an error naming the fix (exit 1), or a counted
repair (exit 0, the counter named). Nothing here needs ../shared or a network.
"""
from __future__ import annotations

import argparse
import contextlib
import io
import shutil
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

NAME = "reliability"
HELP = "broken inputs (units, layout, order, files, options) through the real commands: exit code and message"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--keep", metavar="DIR", default=None, help="build the probes here and keep them")
    p.add_argument("--only", metavar="TEXT", default=None, help="run the probes whose name contains TEXT")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--out", metavar="JSON", default=None, help="also write the results here")


@dataclass
class Probe:
    name: str
    expect: str   # "error: <text>" (exit 1, or 2 for a value the command line refused; stderr holds text)
    #               or "repair: <text>" (exit 0, text printed)
    build: Callable[[Path, Path], list[str]]   # (base recording, work dir) -> davio argv


def _copy(base: Path, work: Path) -> Path:
    """A copy of the base recording whose files can be edited (images stay shared through symlinks)."""
    dst = work / "rec"
    shutil.copytree(base, dst, ignore=shutil.ignore_patterns("data"))
    (dst / "mav0" / "cam0" / "data").rmdir() if (dst / "mav0" / "cam0" / "data").exists() else None
    (dst / "mav0" / "cam0" / "data").symlink_to(base / "mav0" / "cam0" / "data")
    return dst


def _edit_imu(base: Path, work: Path, fn: Callable[[list[str]], list[str]]) -> Path:
    rec = _copy(base, work)
    csv = rec / "mav0" / "imu0" / "data.csv"
    lines = csv.read_text().splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    csv.write_text("\n".join(head + fn([ln for ln in lines if ln and not ln.startswith("#")])) + "\n")
    return rec


def _run(rec: Path, work: Path, *extra: str) -> list[str]:
    return ["run", str(rec), "--native-only", "--out", str(work / "out"), *extra]


def _imu(fn: Callable[[list[str]], list[str]], *extra: str) -> Callable[[Path, Path], list[str]]:
    return lambda base, work: _run(_edit_imu(base, work, fn), work, *extra)


def _cols(row: str, fn: Callable[[list[str]], list[str]]) -> str:
    return ",".join(fn(row.split(",")))


def _accel_in_g(rows: list[str]) -> list[str]:
    return [_cols(r, lambda f: f[:4] + [repr(float(x) / 9.80665) for x in f[4:]]) for r in rows]


def _camera(edit: Callable[[Path, Path], None], *extra: str) -> Callable[[Path, Path], list[str]]:
    def build(base: Path, work: Path) -> list[str]:
        rec = _copy(base, work)
        edit(base, rec)
        return _run(rec, work, *extra)
    return build


def _no_images(base: Path, rec: Path) -> None:
    cam = rec / "mav0" / "cam0" / "data"
    cam.unlink()
    cam.mkdir()


def _twelve_bit(base: Path, rec: Path) -> None:
    import cv2
    import numpy as np

    cam = rec / "mav0" / "cam0" / "data"
    cam.unlink()
    cam.mkdir()
    for f in (base / "mav0" / "cam0" / "data").iterdir():
        img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        cv2.imwrite(str(cam / f.name), img.astype(np.uint16) << 4)


def _csv_edit(fn: Callable[[list[str]], list[str]]) -> Callable[[Path, Path], None]:
    def edit(base: Path, rec: Path) -> None:
        csv = rec / "mav0" / "cam0" / "data.csv"
        lines = csv.read_text().splitlines()
        csv.write_text("\n".join(lines[:1] + fn(lines[1:])) + "\n")
    return edit


def _yaml_edit(fn: Callable[[bytes], bytes]) -> Callable[[Path, Path], None]:
    def edit(base: Path, rec: Path) -> None:
        y = rec / "mav0" / "cam0" / "sensor.yaml"
        y.write_bytes(fn(y.read_bytes()))
    return edit


def _manifest_config(key: str, value: object) -> Callable[[Path, Path], list[str]]:
    def build(base: Path, work: Path) -> list[str]:
        import json

        rec = _copy(base, work)
        m = json.loads((rec / "manifest.json").read_text())
        m["config"][key] = value
        (rec / "manifest.json").write_text(json.dumps(m))
        return ["run", str(rec), "--out", str(work / "out")]
    return build


def _out_file(base: Path, work: Path) -> list[str]:
    (work / "taken").write_text("x")
    return ["run", str(base), "--native-only", "--out", str(work / "taken" / "run")]


def _out_non_run(base: Path, work: Path) -> list[str]:
    (work / "photos").mkdir()
    (work / "photos" / "a.jpg").write_text("x")
    return ["run", str(base), "--native-only", "--out", str(work / "photos"), "--overwrite"]


def _out_generic_names(base: Path, work: Path) -> list[str]:
    (work / "thesis" / "chapters").mkdir(parents=True)
    (work / "thesis" / "report.json").write_text("{}")
    (work / "thesis" / "chapters" / "one.tex").write_text("x")
    return ["run", str(base), "--native-only", "--out", str(work / "thesis"), "--overwrite"]


def _config_out_of_range(base: Path, work: Path) -> list[str]:
    (work / "c.toml").write_text("[mapping]\nvoxel_m = -0.04\n")
    return ["run", str(base), "--emulated", "base", "--config", str(work / "c.toml"),
            "--out", str(work / "o")]


def _config_binary(base: Path, work: Path) -> list[str]:
    (work / "c.toml").write_bytes(bytes(range(256)))
    return ["run", str(base), "--native-only", "--config", str(work / "c.toml"), "--out", str(work / "o")]


def _tum_ns(base: Path, work: Path) -> list[str]:
    gt = base / "mav0" / "state_groundtruth_estimate0" / "data.csv"
    rows = [ln.split(",") for ln in gt.read_text().splitlines() if ln and not ln.startswith("#")]
    text = "".join(f"{r[0]} {r[1]} {r[2]} {r[3]} {r[5]} {r[6]} {r[7]} {r[4]}\n" for r in rows)
    (work / "ns.tum").write_text(text)
    return ["eval", "ate", str(work / "ns.tum"), str(gt)]


def _ply_header_only(base: Path, work: Path) -> list[str]:
    ply = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
           b"property float z\nend_header\n")
    (work / "cut.ply").write_bytes(ply)
    return ["eval", "surface", str(work / "cut.ply"), str(work / "cut.ply")]


def _principal_point(yaml_bytes: bytes) -> bytes:
    """sensor.yaml with cx moved 1000 px outside the image."""
    import re

    m = re.search(rb"intrinsics:\s*\[([^\]]*)\]", yaml_bytes)
    vals = [float(v) for v in m.group(1).split(b",")]
    vals[2] += 1000.0
    new = b"intrinsics: [" + b", ".join(repr(v).encode() for v in vals) + b"]"
    return yaml_bytes[:m.start()] + new + yaml_bytes[m.end():]


def _reverse(rows: list[str]) -> list[str]:
    return rows[::-1]


def _dup(rows: list[str]) -> list[str]:
    return rows[:100] + [rows[99]] + rows[100:]


PROBES = [
    Probe("imu: extra temperature column", "error: extra column", _imu(lambda r: [x + ",36.5" for x in r])),
    Probe("imu: ';' separators", "error: separated by ';'", _imu(lambda r: [x.replace(",", ";") for x in r])),
    Probe("imu: stamps in seconds", "error: look like seconds",
          _imu(lambda r: [_cols(x, lambda f: [f"{int(f[0]) / 1e9:.9f}"] + f[1:]) for x in r])),
    Probe("imu: stamps in microseconds", "error: look like microseconds",
          _imu(lambda r: [_cols(x, lambda f: [str(int(f[0]) // 1000)] + f[1:]) for x in r])),
    Probe("imu: every value NaN", "error: every row holds NaN",
          _imu(lambda r: [_cols(x, lambda f: f[:1] + ["nan"] * 6) for x in r])),
    Probe("imu: header only", "error: holds no data rows", _imu(lambda r: [])),
    Probe("imu: reversed file", "repair: out-of-order rows sorted", _imu(_reverse)),
    Probe("imu: accelerometer in g", "repair: converted", _imu(_accel_in_g)),
    Probe("imu: duplicate row under --strict", "error: duplicate stamp", _imu(_dup, "--strict")),
    Probe("cam0: data.csv without rows", "error: no usable frame", _camera(_csv_edit(lambda r: []))),
    Probe("cam0: every image missing", "error: none of the", _camera(_no_images)),
    Probe("cam0: 12-bit data in 16-bit PNGs", "repair: converted", _camera(_twelve_bit)),
    Probe("cam0: image name with ../", "error: points outside",
          _camera(_csv_edit(lambda r: r[:5] + [r[5].split(",")[0] + ",../../imu0/data.csv"] + r[6:]))),
    Probe("cam0: sensor.yaml with a Latin-1 comment", "repair: published",
          _camera(_yaml_edit(lambda b: b.replace(b"\n", b"\n# calibrated by Ren\xe9\n", 1)))),
    Probe("cam0: sensor.yaml 6 MB", "error: limit for calibration files",
          _camera(_yaml_edit(lambda b: b + b"#" + b"x" * 6_000_000 + b"\n"))),
    Probe("cam0: principal point outside the image", "error: principal point",
          _camera(_yaml_edit(_principal_point))),
    Probe("recording too short to publish (1 s)", "error: no pose was published",
          lambda base, work: ["run", str(base), "--native-only", "--seconds", "1", "--out", str(work / "o")]),
    Probe("manifest: seconds 1e7", "error: config.seconds", _manifest_config("seconds", 1e7)),
    Probe("manifest: seed -1", "error: config.seed = -1", _manifest_config("seed", -1)),
    Probe("--out under a file", "error: is a file", _out_file),
    Probe("--overwrite on a folder without a run", "error: not a finished DAVIO run", _out_non_run),
    Probe("--overwrite on a folder with a report.json of its own", "error: not a finished DAVIO run",
          _out_generic_names),
    Probe("--config: mapping.voxel_m = -0.04", "error: mapping.voxel_m must be", _config_out_of_range),
    Probe("--model-latency nan", "error: argument --model-latency: seconds or 'measured': 'nan' is not",
          lambda base, work: ["run", str(base), "--model-latency", "nan", "--out", str(work / "o")]),
    Probe("--config binary file", "error: not a UTF-8 TOML", _config_binary),
    Probe("eval ate: TUM with ns stamps", "repair: nanoseconds", _tum_ns),
    Probe("eval surface: PLY ending at end_header", "error: end_header", _ply_header_only),
]


def _run_probe(probe: Probe, base: Path, work: Path) -> dict:
    from tools.cli import main

    work.mkdir(parents=True)
    argv = probe.build(base, work)
    out, err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    traceback = None
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = int(exc.code or 0)
        except BaseException as exc:  # noqa: BLE001 - an escaped exception is the finding
            code, traceback = None, f"{type(exc).__name__}: {exc}"
    kind, text = probe.expect.split(": ", 1)
    stdout, stderr = out.getvalue(), err.getvalue()
    message = next((ln.strip() for ln in stderr.splitlines() if "error" in ln), "")
    if kind == "repair":
        message = next((ln.strip() for ln in (stdout + stderr).splitlines() if text in ln), message)
    ok = traceback is None and (code in (1, 2) and text in stderr if kind == "error"
                                else code == 0 and text in stdout + stderr)
    return {"probe": probe.name, "command": "davio " + argv[0], "expected": probe.expect, "exit": code,
            "message": (traceback or message)[:200], "traceback": traceback is not None, "as_expected": ok,
            "seconds": time.perf_counter() - t0}


def run(args: argparse.Namespace) -> int:
    import tempfile

    from drivers.sim import SimConfig, SimRecording
    from drivers.sim.writer import write_euroc
    from runtime.errors import ConfigError
    from runtime.json_out import strict_dumps

    probes = [p for p in PROBES if args.only is None or args.only in p.name]
    if not probes:        # "0/0 probes as expected" with exit 0 tested nothing
        raise ConfigError(f"--only {args.only!r} names no probe; the probes: "
                          + "; ".join(p.name for p in PROBES))
    if args.keep:
        from tools.run_folder import check_writable_target

        keep = Path(args.keep)
        check_writable_target(keep, "--keep")
        earlier = sorted(p.name for p in keep.glob("probe[0-9][0-9]")) if keep.is_dir() else []
        if earlier:     # the probes' own folders must be new (base/, the recording, is reused)
            raise ConfigError(f"--keep {args.keep}: holds the probe folders of an earlier run ({earlier[0]}, "
                              "...); remove them or choose another folder")
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="davio_reliability_"))
    root.mkdir(parents=True, exist_ok=True)
    base = root / "base"
    if not (base / "manifest.json").exists():
        shutil.rmtree(base, ignore_errors=True)
        write_euroc(SimRecording.from_preset(SimConfig(preset="euroc", seconds=3.5, seed=0)), base,
                    depth=False)
    rows = []
    for k, probe in enumerate(probes):
        rows.append(_run_probe(probe, base, root / f"probe{k:02d}"))
        if not args.json:
            r = rows[-1]
            print(f"{'ok ' if r['as_expected'] else 'BAD'} exit {r['exit']!s:>4}  {r['seconds']:5.1f} s  "
                  f"{r['probe']:<42} {r['message'][:110]}")
    result = {"probes": rows, "as_expected": sum(r["as_expected"] for r in rows), "total": len(rows),
              "tracebacks": sum(r["traceback"] for r in rows)}
    if args.out:
        Path(args.out).write_text(strict_dumps(result, indent=1))
    if args.json:
        print(strict_dumps(result))
    else:
        print(f"{result['as_expected']}/{result['total']} probes as expected, "
              f"{result['tracebacks']} tracebacks")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)
    return 0 if result["as_expected"] == result["total"] else 1
