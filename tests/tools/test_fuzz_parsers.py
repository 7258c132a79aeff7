"""Property tests of the evaluation parsers (TUM, EuRoC CSV, PLY) and the TOML config loader: any bytes
give a valid object or a DavioError subclass, never another exception; written files read back.

Deterministic in CI; DAVIO_FUZZ_EXAMPLES=5000 runs a longer, randomly seeded campaign.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from runtime.config import DavioConfig
from runtime.config_io import dump_toml, load_toml
from runtime.errors import ConfigError, DataError, TrajectoryError
from runtime.geometry.trajectory import PoseTrajectory
from tools.evaluation.ply import read_ply_vertices
from tools.evaluation.trajectory_io import read_trajectory, write_euroc_csv, write_tum
from tools.map_archive.export import write_ply

FUZZ = settings(max_examples=int(os.environ.get("DAVIO_FUZZ_EXAMPLES", 60)), deadline=None,
                derandomize="DAVIO_FUZZ_EXAMPLES" not in os.environ, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])
TOKENS = [b"0", b"-1", b"nan", b"inf", b"1e999", b"9" * 30, b"1.5", b"", b" ", b",", b"#", b"\n", b"\xe9",
          b"\x00", b"abc", b"1e12", b"1403715529112143517", b"-0", b"\xef\xbb\xbf", b"'", b"[", b"=", b"\"",
          b"\xd9\xa1", b"list", b"float", b"uchar", b"vertex", b"end_header", b"binary_big_endian"]
_TOKEN_RE = re.compile(rb"[-+]?[0-9][0-9.e+-]*|[A-Za-z_]+")


@st.composite
def mutated(draw: st.DrawFn, valid: bytes) -> bytes:
    """`valid` with 1-3 edits: a number or word replaced by a TOKENS entry, a byte changed, a span deleted
    or duplicated, or the file cut."""
    data = valid
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["token"] * 5 + ["byte", "delete", "duplicate", "truncate"]))
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "token":
            spans = [m.span() for m in _TOKEN_RE.finditer(data[:4000])]
            if spans:
                a, b = draw(st.sampled_from(spans))
                data = data[:a] + draw(st.sampled_from(TOKENS)) + data[b:]
        elif op == "byte":
            data = data[:i] + bytes([draw(st.integers(0, 255))]) + data[i + 1:]
        elif op == "delete":
            data = data[:i] + data[i + draw(st.integers(1, 32)):]
        elif op == "duplicate":
            j = draw(st.integers(i, len(data)))
            data = data[:j] + data[i:j] + data[j:]
        else:
            data = data[:i]
    return data


@pytest.fixture(scope="module")
def folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("fuzz_parsers")


def _trajectory(n: int, seed: int, full: bool = False) -> PoseTrajectory:
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    t = 1_403_715_529_000_000_000 + np.cumsum(rng.integers(1, 10**8, n))
    R = Rotation.from_rotvec(rng.normal(size=(n, 3))).as_matrix()
    extra = {k: rng.normal(size=(n, 3)) for k in ("v", "bg", "ba")} if full else {}
    return PoseTrajectory(t.astype(np.int64), rng.normal(size=(n, 3)) * 10, R, **extra)


@pytest.fixture(scope="module")
def valid(folder: Path) -> dict[str, bytes]:
    """Valid TUM, EuRoC CSV, binary and ascii PLY and TOML files, as bytes."""
    write_tum(folder / "v.tum", _trajectory(6, 1))
    write_euroc_csv(folder / "v.csv", _trajectory(6, 2, full=True))
    write_ply(folder / "v.ply", np.arange(18, dtype=float).reshape(6, 3), np.arange(6))
    ascii_ply = (b"ply\nformat ascii 1.0\ncomment x\nelement vertex 3\nproperty float x\nproperty float y\n"
                 b"property float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n"
                 b"0 0 0\n1 0 0\n0 1 0\n")
    return {"tum": (folder / "v.tum").read_bytes(), "csv": (folder / "v.csv").read_bytes(),
            "ply": (folder / "v.ply").read_bytes(), "ascii_ply": ascii_ply,
            "toml": dump_toml(DavioConfig()).encode()}


def _parse(kind: str, path: Path) -> object:
    if kind in ("tum", "csv"):
        traj = read_trajectory(path)
        assert traj.t_ns.dtype == np.int64 and len(traj) > 0 and np.all(np.diff(traj.t_ns) >= 0)
        assert np.all(np.isfinite(traj.p)) and np.all(np.isfinite(traj.R))
        return traj
    if kind.endswith("ply"):
        pts = read_ply_vertices(path)
        assert pts.dtype == np.float64 and pts.ndim == 2 and pts.shape[1] == 3
        return pts
    return load_toml(DavioConfig, path)


KINDS = ["tum", "csv", "ply", "ascii_ply", "toml"]
ERRORS = {"tum": TrajectoryError, "csv": TrajectoryError, "ply": DataError, "ascii_ply": DataError,
          "toml": ConfigError}


@pytest.mark.parametrize("kind", KINDS)
@FUZZ
@given(data=st.data())
def test_mutated_files_parse_or_raise_davio_error(valid: dict[str, bytes], folder: Path, kind: str,
                                                  data: st.DataObject) -> None:
    path = folder / f"fuzz.{kind}"
    path.write_bytes(data.draw(mutated(valid[kind])))
    try:
        _parse(kind, path)
    except ERRORS[kind] as exc:
        assert str(exc).startswith(str(path)) or kind == "toml" and str(path) in str(exc)


@pytest.mark.parametrize("kind", KINDS)
@FUZZ
@given(raw=st.binary(max_size=300) | st.text(max_size=200).map(str.encode))
def test_arbitrary_bytes_parse_or_raise_davio_error(folder: Path, kind: str, raw: bytes) -> None:
    path = folder / f"arbitrary.{kind}"
    path.write_bytes(raw)
    try:
        _parse(kind, path)
    except ERRORS[kind]:
        pass


@FUZZ
@given(n=st.integers(1, 40), seed=st.integers(0, 2**32 - 1), full=st.booleans())
def test_written_trajectories_read_back(folder: Path, n: int, seed: int, full: bool) -> None:
    traj = _trajectory(n, seed, full)
    write_tum(folder / "rt.tum", traj)
    write_euroc_csv(folder / "rt.csv", traj)
    for back in (read_trajectory(folder / "rt.tum"), read_trajectory(folder / "rt.csv")):
        np.testing.assert_array_equal(back.t_ns, traj.t_ns)
        np.testing.assert_array_equal(back.p, traj.p)
        np.testing.assert_allclose(back.R, traj.R, atol=1e-15)


@FUZZ
@given(pts=st.lists(st.tuples(*[st.floats(-1e6, 1e6, width=32)] * 3), max_size=50))
def test_written_ply_reads_back(folder: Path, pts: list[tuple[float, float, float]]) -> None:
    xyz = np.array(pts, dtype=np.float64).reshape(-1, 3)
    write_ply(folder / "rt.ply", xyz, np.zeros(len(xyz)))
    np.testing.assert_array_equal(read_ply_vertices(folder / "rt.ply"), xyz)


def test_ns_stamps_in_a_tum_file_read_as_nanoseconds(folder: Path) -> None:
    traj = _trajectory(5, 7)
    write_tum(folder / "s.tum", traj)
    rows = [line.split() for line in (folder / "s.tum").read_text().splitlines()[1:]]
    (folder / "ns.tum").write_text("".join(" ".join([r[0].replace(".", "")] + r[1:]) + "\n" for r in rows))
    back = read_trajectory(folder / "ns.tum")
    np.testing.assert_array_equal(back.t_ns, traj.t_ns)
    assert "read as nanoseconds" in back.meta["stamp_note"]
    assert "stamp_note" not in read_trajectory(folder / "s.tum").meta
    mixed = (folder / "s.tum").read_text().splitlines()[:3] + (folder / "ns.tum").read_text().splitlines()[2:]
    (folder / "mixed.tum").write_text("\n".join(mixed) + "\n")
    with pytest.raises(TrajectoryError, match="mixes units") as err:
        read_trajectory(folder / "mixed.tum")
    assert err.value.line == 4


@pytest.mark.parametrize("stamp", ["1e999999999", "9" * 30, "-9.3e9"])
def test_out_of_range_stamps_are_trajectory_errors(folder: Path, stamp: str) -> None:
    (folder / "big.tum").write_text(f"{stamp} 0 0 0 0 0 0 1\n")
    with pytest.raises(TrajectoryError, match="int64 nanosecond range") as err:
        read_trajectory(folder / "big.tum")
    assert err.value.line == 1
