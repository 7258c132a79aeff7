"""`davio bench openvins-beside DIR --openvins-bin BIN`: our filter's cost beside OpenVINS's, in one run.

Timings on a shared machine drift by tens of percent between minutes, so a ratio against a figure measured on
another day (the folder's openvins_summary.txt) says little. This benchmark runs OpenVINS's own simulator
binary (`run_simulation` of an OpenVINS build, ROS-free) on the folder's configuration and trajectory, and
`davio bench openvins-sim DIR` on the same folder, alternately, `--repeats` times, each in a fresh process;
it prints per round OpenVINS's time per frame, ours and their ratio, and the median ratio.

OpenVINS's time per frame is the `total` column of its own timing file (`record_timing_information`: the
wall time of VioManager's feature update per camera frame, the simulated tracker's feed included). Ours is
`ms_per_frame` of `bench openvins-sim` (the wall time of the filter per frame, its database included; the
thread CPU time is printed beside it). OpenVINS's configuration is the folder's, with these changes only:
absolute paths, the timing file switched on and written to a temporary folder, and printing silenced (the
simulator's warnings would otherwise be timed on the console). OpenVINS is not part of DAVIO: build it from
its sources (v2.7: ov_msckf's CMake builds `run_simulation` without ROS).
"""
from __future__ import annotations

import argparse
import gzip
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, number_in

NAME = "openvins-beside"
HELP = "our filter's time per frame beside OpenVINS's run_simulation, alternated in one run"
DESCRIPTION = __doc__


class BesideError(RuntimeError):
    """A clear failure of the side-by-side run (missing binary or files, a run that failed)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("folder", type=Path,
                   help="openvins_sim run folder, e.g. ../shared/data/openvins_sim/udel_gore_mono")
    p.add_argument("--openvins-bin", type=Path, required=True,
                   help="OpenVINS's run_simulation executable (a ROS-free build of ov_msckf)")
    p.add_argument("--repeats", type=count(1, 1000), default=3,
                   help="alternating rounds (OpenVINS, then DAVIO)")
    p.add_argument("--timeout", type=number_in(0, 86400, low_open=True, unit=" s"), default=600.0,
                   help="seconds allowed to each single run")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the table")
    p.add_argument("--out", type=Path, default=None, help="also write the JSON result to this file")


_KEY = re.compile(r"^(\s*)([A-Za-z0-9_]+)\s*:(.*)$")


def openvins_config(folder: Path, work: Path) -> Path:
    """Write OpenVINS's configuration of `folder` into `work` for a timed, silent run; returns its path.

    Copies the Kalibr files it names, unpacks the trajectory and rewrites sim_traj_path,
    record_timing_information, record_timing_filepath and verbosity (every other line is kept as is).

    Raises:
        BesideError: a file the configuration needs is missing."""
    src = folder / "openvins_estimator_config.yaml"
    if not src.is_file():
        raise BesideError(f"{src}: no OpenVINS configuration in the folder")
    traj_gz = folder / "udel_gore_trajectory.txt.gz"
    lines = src.read_text().splitlines()
    wanted = {"sim_traj_path": None, "record_timing_filepath": None}
    out = []
    for line in lines:
        m = _KEY.match(line)
        key = m.group(2) if m else None
        if key in ("relative_config_imu", "relative_config_imucam"):
            name = m.group(3).split("#")[0].strip().strip('"')
            if not (folder / name).is_file():
                raise BesideError(f"{folder / name}: named by {src.name} ({key}) but missing")
            shutil.copy(folder / name, work / name)
        elif key == "sim_traj_path":
            name = Path(m.group(3).split("#")[0].strip().strip('"')).name
            gz = folder / (name + ".gz") if (folder / (name + ".gz")).is_file() else traj_gz
            plain = folder / name
            target = work / name
            if plain.is_file():
                shutil.copy(plain, target)
            elif gz.is_file():
                with gzip.open(gz, "rb") as fi, open(target, "wb") as fo:
                    shutil.copyfileobj(fi, fo)
            else:
                raise BesideError(f"{folder}: no trajectory {name} (or {name}.gz) for OpenVINS's simulator")
            line = f'{m.group(1)}sim_traj_path: "{target}"'
            wanted["sim_traj_path"] = target
        elif key == "record_timing_information":
            line = f"{m.group(1)}record_timing_information: true"
        elif key == "record_timing_filepath":
            wanted["record_timing_filepath"] = work / "out" / "timing.txt"
            line = f'{m.group(1)}record_timing_filepath: "{work / "out" / "timing.txt"}"'
        elif key == "verbosity":
            line = f'{m.group(1)}verbosity: "SILENT"'
        out.append(line)
    if wanted["sim_traj_path"] is None:
        raise BesideError(f"{src}: no sim_traj_path (not a simulator configuration)")
    if wanted["record_timing_filepath"] is None:
        out.append(f'record_timing_filepath: "{work / "out" / "timing.txt"}"')
    if not any(_KEY.match(x) and _KEY.match(x).group(2) == "record_timing_information" for x in out):
        out.append("record_timing_information: true")
    cfg = work / "openvins_estimator_config.yaml"
    cfg.write_text("\n".join(out) + "\n")
    return cfg


def timing_ms_per_frame(path: Path) -> tuple[float, int]:
    """(mean total ms per frame, frames) of an OpenVINS timing file (CSV with a '# ...' header naming a
    `total` column, seconds).

    Raises:
        BesideError: missing, empty or without a total column."""
    if not path.is_file():
        raise BesideError(f"{path}: OpenVINS wrote no timing file")
    text = path.read_text().splitlines()
    header = next((x for x in text if x.startswith("#")), None)
    if header is None:
        raise BesideError(f"{path}: no header line")
    cols = [c.strip() for c in header.lstrip("#").split(",")]
    if "total" not in cols:
        raise BesideError(f"{path}: no 'total' column in {cols}")
    k = cols.index("total")
    vals = []
    for x in text:
        if x.startswith("#") or not x.strip():
            continue
        parts = x.split(",")
        try:
            vals.append(float(parts[k]))
        except (IndexError, ValueError):
            raise BesideError(f"{path}: malformed row {x[:80]!r}") from None
    if not vals:
        raise BesideError(f"{path}: no frames")
    return 1e3 * float(np.mean(vals)), len(vals)


def run_openvins(binary: Path, folder: Path, timeout: float) -> dict:
    """One OpenVINS run on `folder`: its mean time per frame (ms) and frames."""
    with tempfile.TemporaryDirectory(prefix="davio_openvins_") as tmp:
        work = Path(tmp)
        cfg = openvins_config(folder, work)
        try:
            proc = subprocess.run([str(binary), str(cfg)], capture_output=True, text=True, timeout=timeout,
                                  cwd=work)
        except subprocess.TimeoutExpired:
            raise BesideError(f"OpenVINS ran past {timeout:g} s") from None
        if proc.returncode != 0:
            tail = (proc.stderr or proc.stdout)[-400:]
            raise BesideError(f"{binary} exited with {proc.returncode}: {tail}")
        ms, frames = timing_ms_per_frame(work / "out" / "timing.txt")
    return {"ms_per_frame": ms, "frames": frames}


def run_davio(folder: Path, timeout: float) -> dict:
    """One `davio bench openvins-sim folder --json` in a fresh process."""
    cmd = [sys.executable, "-m", "tools.cli", "bench", "openvins-sim", str(folder), "--json"]
    root = Path(__file__).resolve().parents[2]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, cwd=root)
    except subprocess.TimeoutExpired:
        raise BesideError(f"DAVIO ran past {timeout:g} s") from None
    if proc.returncode != 0:
        raise BesideError(f"bench openvins-sim exited with {proc.returncode}: {proc.stderr.strip()[-400:]}")
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    return {k: res[k] for k in ("ms_per_frame", "cpu_ms_per_frame", "frames", "rmse_pos_m", "rmse_ori_deg")}


def run(args: argparse.Namespace) -> int:
    binary = args.openvins_bin
    if not (binary.is_file() and binary.stat().st_mode & 0o111):
        print(f"openvins-beside: {binary}: not an executable (build OpenVINS's run_simulation: see "
              "`davio bench openvins-beside --help`)")
        return 2
    if args.repeats < 1:
        print("openvins-beside: --repeats must be >= 1")
        return 2
    rounds = []
    try:
        for i in range(args.repeats):
            ov = run_openvins(binary, args.folder, args.timeout)
            ours = run_davio(args.folder, args.timeout)
            rounds.append({"openvins": ov, "davio": ours, "ratio": ours["ms_per_frame"] / ov["ms_per_frame"]})
            if not args.json:
                print(f"round {i + 1}/{args.repeats}: OpenVINS {ov['ms_per_frame']:.2f} ms/frame, DAVIO "
                      f"{ours['ms_per_frame']:.2f} ({ours['cpu_ms_per_frame']:.2f} CPU), ratio "
                      f"{rounds[-1]['ratio']:.3f}", flush=True)
    except BesideError as exc:
        print(f"openvins-beside: {exc}")
        return 2
    ratios = np.array([r["ratio"] for r in rounds])
    res = {"folder": str(args.folder), "openvins_bin": str(binary), "rounds": rounds,
           "median_ratio": float(np.median(ratios)),
           "ratio_range": [float(ratios.min()), float(ratios.max())],
           "openvins_ms_median": float(np.median([r["openvins"]["ms_per_frame"] for r in rounds])),
           "davio_ms_median": float(np.median([r["davio"]["ms_per_frame"] for r in rounds]))}
    if args.out is not None:
        args.out.write_text(strict_dumps(res, indent=2))
    if args.json:
        print(strict_dumps(res))
        return 0
    print(f"{'round':<8}{'OpenVINS ms':>12}{'DAVIO ms':>10}{'DAVIO CPU':>11}{'ratio':>8}")
    for i, r in enumerate(rounds):
        print(f"{i + 1:<8}{r['openvins']['ms_per_frame']:>12.2f}{r['davio']['ms_per_frame']:>10.2f}"
              f"{r['davio']['cpu_ms_per_frame']:>11.2f}{r['ratio']:>8.3f}")
    print(f"median ratio DAVIO / OpenVINS {res['median_ratio']:.3f} (range {ratios.min():.3f}-"
          f"{ratios.max():.3f}); wall time per camera frame, each run in a fresh process")
    return 0
