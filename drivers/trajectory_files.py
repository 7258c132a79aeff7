"""Trajectory file readers: TUM (`t[s] x y z qx qy qz qw`) and EuRoC state CSV (`t[ns],p,q_wxyz[,v,bg,ba]`).

Evaluation (tools/evaluation) and the simulator's ground-truth replay (drivers/sim) both read
trajectories here; the EuRoC driver's ground truth goes through its counted drop/strict row policies
(drivers/euroc.py read_euroc_groundtruth) instead.

Stamps become int64 nanoseconds parsed exactly from the decimal text (no float rounding).
Stamps must not decrease; a repeated stamp is kept (as evo keeps it) and counted in
`meta["repeated_stamps"]`, unless `strictly_increasing` asks for it to be an error (replay needs it).
Malformed rows raise `TrajectoryError` naming the file and 1-based line.
Quaternions are Hamilton; TUM orders them x,y,z,w, EuRoC w,x,y,z.
"""
from __future__ import annotations

import math
import re
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from pathlib import Path

import numpy as np

from drivers.validation import is_float
from runtime.errors import TrajectoryError
from runtime.geometry import quat_wxyz_to_rot
from runtime.geometry.trajectory import PoseTrajectory

_NS = Decimal(1_000_000_000)


#: Stamps must fit int64 nanoseconds (about +-292 years around 1970).
_INT64_LIMIT = 2**63
#: A TUM stamp above this many "seconds" (31,700 years) is clearly in nanoseconds.
NS_STAMP_THRESHOLD = Decimal(10) ** 12


def _decimal(text: str) -> Decimal:
    try:
        value = Decimal(text)
    except InvalidOperation as exc:
        raise ValueError(f"not a number: {text!r}") from exc
    if not value.is_finite():
        raise ValueError(f"not a finite number: {text!r}")
    return value


def _int64_ns(value: Decimal, text: str, scale: Decimal = Decimal(1)) -> int:
    """Exact int nanoseconds of `value` * `scale` ns (half-to-even); ValueError outside int64."""
    if value.copy_abs() >= _INT64_LIMIT / scale:  # compared first, so '1e999999999' costs nothing
        raise ValueError(f"{text[:40]!r} is outside the int64 nanosecond range (+-9.2e18 ns, +-292 years)")
    return int((value * scale).to_integral_value(rounding=ROUND_HALF_EVEN))


def seconds_text_to_ns(text: str) -> int:
    """Exact int nanoseconds of a decimal seconds string ('1403715529.112143517', '1.4037e+09').

    Digits below 1 ns are rounded half-to-even. Raises ValueError for anything but a finite number
    whose nanoseconds fit int64.
    """
    return _int64_ns(_decimal(text), text, _NS)


def ns_to_seconds_text(t_ns: int) -> str:
    """Decimal seconds text with 9 fractional digits, exact for any int64 stamp."""
    sign = "-" if t_ns < 0 else ""
    a = abs(int(t_ns))
    return f"{sign}{a // 1_000_000_000}.{a % 1_000_000_000:09d}"


def _lines(path: Path) -> list[tuple[int, str]]:
    """(1-based line number, stripped text) of every non-blank line, comments included."""
    try:
        text = path.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise TrajectoryError(f"cannot read trajectory file: {exc.strerror or exc}", path) from exc
    except UnicodeDecodeError as exc:
        raise TrajectoryError("not a text file", path) from exc
    return [(lineno, s) for lineno, line in enumerate(text.splitlines(), start=1) if (s := line.strip())]


def _data_lines(path: Path) -> list[tuple[int, str]]:
    return [(lineno, s) for lineno, s in _lines(path) if not s.startswith("#")]


def _header_quaternion_order(header: str) -> str | None:
    """'wxyz' or 'xyzw' where a header line names columns 5 to 8 (`q_RS_w [], q_RS_x [] ...`,
    `qx qy qz qw`) by their last letters, else None."""
    text = header.lstrip("#").strip()
    names = text.split(",") if "," in text else text.split()
    cols = [re.sub(r"\[.*?\]", "", c).strip().lower() for c in names]
    if len(cols) < 8:
        return None
    ends = "".join(c[-1:] for c in cols[4:8])
    return ends if ends in ("wxyz", "xyzw") else None


def _fields(line: str) -> list[str]:
    return line.replace(",", " ").split()


def _floats(fields: list[str], path: Path, lineno: int) -> list[float]:
    try:
        vals = [float(f) for f in fields]
    except ValueError as exc:
        raise TrajectoryError(f"unparseable number ({exc})", path, lineno) from exc
    if not all(math.isfinite(v) for v in vals):
        raise TrajectoryError("NaN or Inf value", path, lineno)
    return vals


def _check_order(t_ns: list[int], lines: list[int], path: Path, strictly_increasing: bool) -> int:
    """Raise on a decreasing stamp (or a repeated one when `strictly_increasing`); return how many
    stamps repeat their predecessor (kept, as evo does)."""
    repeats = 0
    for k in range(1, len(t_ns)):
        if t_ns[k] < t_ns[k - 1]:
            raise TrajectoryError("decreasing timestamp (stamps must not go back in time)", path, lines[k])
        if t_ns[k] == t_ns[k - 1] and strictly_increasing:
            raise TrajectoryError("repeated timestamp (stamps must increase strictly here)", path, lines[k])
        repeats += t_ns[k] == t_ns[k - 1]
    return repeats


def _quat_rows(q: np.ndarray, lines: list[int], path: Path) -> None:
    norms = np.linalg.norm(q, axis=1) if len(q) else np.zeros(0)
    bad = np.flatnonzero(np.abs(norms - 1.0) > 1e-2)
    if bad.size:
        raise TrajectoryError(f"quaternion norm {norms[bad[0]]:.4f} is not 1", path, lines[int(bad[0])])


def _finish(path: Path, fmt: str, t_ns: list[int], lines: list[int], p: np.ndarray, q_wxyz: np.ndarray,
            strictly_increasing: bool, **extra: np.ndarray) -> PoseTrajectory:
    """The checks every format shares (non-empty, stamp order, unit quaternions), then the trajectory."""
    if not t_ns:
        raise TrajectoryError("no poses in file", path)
    repeats = _check_order(t_ns, lines, path, strictly_increasing)
    _quat_rows(q_wxyz, lines, path)
    return PoseTrajectory(np.array(t_ns, dtype=np.int64), p, quat_wxyz_to_rot(q_wxyz),
                          meta={"source": str(path), "format": fmt, "repeated_stamps": repeats}, **extra)


def _tum_stamp(text: str, path: Path, lineno: int) -> tuple[int, bool]:
    """(t_ns, True when the text was taken as nanoseconds: above NS_STAMP_THRESHOLD)."""
    try:
        value = _decimal(text)
        if value.copy_abs() > NS_STAMP_THRESHOLD:
            return _int64_ns(value, text), True
        return _int64_ns(value, text, _NS), False
    except ValueError as exc:
        raise TrajectoryError(f"bad timestamp: {exc}", path, lineno) from exc


def read_tum(path: str | Path, strictly_increasing: bool = False) -> PoseTrajectory:
    """Read a TUM file (`t[s] x y z qx qy qz qw`, '#' comments) into poses T_WB.

    Stamps above NS_STAMP_THRESHOLD (1e12) are nanoseconds written where TUM wants seconds (as
    some exporters do); a file whose stamps are all so is read as nanoseconds and says so in
    `meta["stamp_note"]`; a file that mixes both units is a TrajectoryError.
    """
    path = Path(path)
    t_ns: list[int] = []
    vals: list[list[float]] = []
    lines: list[int] = []
    units: list[bool] = []
    for lineno, line in _data_lines(path):
        f = _fields(line)
        if len(f) != 8:
            raise TrajectoryError(f"{len(f)} fields, expected 8 (t x y z qx qy qz qw)", path, lineno)
        t, is_ns = _tum_stamp(f[0], path, lineno)
        if units and is_ns != units[0]:
            first = "nanoseconds" if units[0] else "seconds"
            raise TrajectoryError(f"stamp {f[0]} mixes units: line {lines[0]}'s stamp reads as {first}; "
                                  "TUM stamps are seconds, in one unit for the whole file", path, lineno)
        t_ns.append(t)
        units.append(is_ns)
        vals.append(_floats(f[1:], path, lineno))
        lines.append(lineno)
    v = np.array(vals).reshape(-1, 7)
    traj = _finish(path, "tum", t_ns, lines, v[:, 0:3], v[:, [6, 3, 4, 5]], strictly_increasing)
    if units and units[0]:
        traj.meta["stamp_note"] = (f"{path}: stamps above 1e12 read as nanoseconds (TUM stamps are seconds: "
                                   f"line {lines[0]}'s {t_ns[0]} is {ns_to_seconds_text(t_ns[0])} s)")
    return traj


def read_euroc_csv(path: str | Path, strictly_increasing: bool = False) -> PoseTrajectory:
    """Read an EuRoC state CSV: `t[ns], p xyz, q wxyz` then optionally `v xyz, bg xyz, ba xyz`.

    A first line without '#' whose first field is not a number is taken as a header.
    """
    path = Path(path)
    t_ns: list[int] = []
    vals: list[list[float]] = []
    lines: list[int] = []
    width = None
    for k, (lineno, line) in enumerate(_data_lines(path)):
        f = [x.strip() for x in line.split(",")]
        if k == 0 and not is_float(f[0]):       # '-1', '+2.5e3' start a data row, not a header
            continue  # text header without '#'
        if len(f) not in (8, 17):
            raise TrajectoryError(f"{len(f)} fields, expected 8 (t,p,q) or 17 (t,p,q,v,bg,ba)", path, lineno)
        if width is None:
            width = len(f)
        elif len(f) != width:
            raise TrajectoryError(f"{len(f)} fields where earlier rows had {width}", path, lineno)
        if not (f[0].isascii() and f[0].isdigit()) or len(f[0]) > 19 or int(f[0]) >= _INT64_LIMIT:
            raise TrajectoryError(f"timestamp {f[0][:40]!r} is not an integer number of nanoseconds "
                                  "within int64", path, lineno)
        t_ns.append(int(f[0]))
        vals.append(_floats(f[1:], path, lineno))
        lines.append(lineno)
    v = np.array(vals).reshape(-1, 7 if width is None else width - 1)
    extra = {} if width in (None, 8) else {"v": v[:, 7:10], "bg": v[:, 10:13], "ba": v[:, 13:16]}
    return _finish(path, "euroc", t_ns, lines, v[:, 0:3], v[:, 3:7], strictly_increasing, **extra)


def detect_format(path: str | Path) -> str:
    """'euroc' (comma-separated, integer-ns stamps, 8 or 17 columns) or 'tum' (8 columns).

    A comma-separated file of 8 columns whose stamps are not integers is TUM, unless the header line
    above its first row orders the quaternion w, x, y, z (EuRoC's order): then it is a TrajectoryError
    naming the fix, as reading it either way would be a guess (its stamps, or its quaternions, wrong).
    """
    path = Path(path)
    header = ""
    for lineno, line in _lines(path):
        f = [x.strip() for x in line.split(",")]
        if line.startswith("#") or (not is_float(f[0]) and len(f) > 1):
            header = line  # a comment or a header line
            continue
        if len(f) in (8, 17) and f[0].isascii() and f[0].isdigit():
            return "euroc"
        if len(_fields(line)) == 8:
            if len(f) == 8 and _header_quaternion_order(header) == "wxyz":
                raise TrajectoryError(
                    f"comma-separated with the quaternion w, x, y, z (EuRoC's order, by the header) but the "
                    f"stamp {f[0][:40]!r} is not integer nanoseconds: write the stamps in integer ns (an "
                    "EuRoC state CSV), or the file as TUM (t[s] x y z qx qy qz qw)", path, lineno)
            return "tum"
        raise TrajectoryError("cannot tell the trajectory format (neither TUM nor EuRoC CSV)", path)
    raise TrajectoryError("no poses in file", path)


def read_trajectory(path: str | Path, fmt: str | None = None,
                    strictly_increasing: bool = False) -> PoseTrajectory:
    """Read a TUM or EuRoC-CSV trajectory, detecting the format unless `fmt` says it.

    `strictly_increasing` makes a repeated stamp an error (interpolating replays need it).
    """
    fmt = fmt or detect_format(path)
    if fmt == "tum":
        return read_tum(path, strictly_increasing)
    if fmt == "euroc":
        return read_euroc_csv(path, strictly_increasing)
    raise TrajectoryError(f"unknown trajectory format {fmt!r} (expected 'tum' or 'euroc')", path)
