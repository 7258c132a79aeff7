"""`davio bench openvins-beside`: OpenVINS's configuration rewritten for a timed run, its timing file read,
and a clear refusal without a binary (OpenVINS itself is not installed in CI)."""
from __future__ import annotations

import argparse
import gzip
import os
import sys
from pathlib import Path

import pytest

from tools.benchmarks import openvins_beside as ob

CONFIG = """%YAML:1.0 # need to specify the file type at the top!
verbosity: "WARNING"
max_clones: 11
record_timing_information: false # whether to record
record_timing_filepath: "timing.txt"
relative_config_imu: "kalibr_imu_chain.yaml"
relative_config_imucam: "kalibr_imucam_chain.yaml"
sim_traj_path: "udel_gore_trajectory.txt"
sim_freq_cam: 10
"""


def _folder(tmp_path: Path) -> Path:
    d = tmp_path / "run"
    d.mkdir()
    (d / "openvins_estimator_config.yaml").write_text(CONFIG)
    (d / "kalibr_imu_chain.yaml").write_text("imu0: {}\n")
    (d / "kalibr_imucam_chain.yaml").write_text("cam0: {}\n")
    with gzip.open(d / "udel_gore_trajectory.txt.gz", "wt") as f:
        f.write("0.0 0 0 0 0 0 0 1\n")
    return d


def test_config_is_rewritten_for_a_timed_silent_run_and_everything_else_kept(tmp_path: Path) -> None:
    folder = _folder(tmp_path)
    work = tmp_path / "work"
    work.mkdir()
    cfg = ob.openvins_config(folder, work)
    text = cfg.read_text().splitlines()
    kv = {ln.split(":", 1)[0]: ln.split(":", 1)[1].strip() for ln in text[1:] if ":" in ln}
    assert kv["verbosity"] == '"SILENT"'
    assert kv["record_timing_information"] == "true"
    assert kv["record_timing_filepath"] == f'"{work / "out" / "timing.txt"}"'
    assert kv["sim_traj_path"] == f'"{work / "udel_gore_trajectory.txt"}"'
    assert kv["max_clones"] == "11" and kv["sim_freq_cam"] == "10"
    assert text[0].startswith("%YAML:1.0")
    assert (work / "udel_gore_trajectory.txt").read_text() == "0.0 0 0 0 0 0 0 1\n"
    assert (work / "kalibr_imu_chain.yaml").read_text() == "imu0: {}\n"


def test_missing_kalibr_file_or_trajectory_is_named(tmp_path: Path) -> None:
    folder = _folder(tmp_path)
    (folder / "kalibr_imucam_chain.yaml").unlink()
    with pytest.raises(ob.BesideError, match="kalibr_imucam_chain.yaml"):
        ob.openvins_config(folder, tmp_path)
    (tmp_path / "b").mkdir()
    folder = _folder(tmp_path / "b")
    (folder / "udel_gore_trajectory.txt.gz").unlink()
    with pytest.raises(ob.BesideError, match="trajectory"):
        ob.openvins_config(folder, tmp_path / "b")


def test_timing_file_mean_of_the_total_column(tmp_path: Path) -> None:
    p = tmp_path / "timing.txt"
    p.write_text("# timestamp (sec),tracking,propagation,total\n"
                 "1.0,0.001,0.002,0.004\n2.0,0.001,0.002,0.008\n")
    ms, n = ob.timing_ms_per_frame(p)
    assert n == 2 and ms == pytest.approx(6.0)
    p.write_text("# timestamp (sec),tracking\n1.0,0.001\n")
    with pytest.raises(ob.BesideError, match="total"):
        ob.timing_ms_per_frame(p)
    p.write_text("# timestamp (sec),total\n1.0,abc\n")
    with pytest.raises(ob.BesideError, match="malformed"):
        ob.timing_ms_per_frame(p)
    with pytest.raises(ob.BesideError, match="no timing file"):
        ob.timing_ms_per_frame(tmp_path / "absent.txt")


@pytest.mark.skipif(os.name != "posix", reason="the stand-in OpenVINS binary is a POSIX script")
def test_run_openvins_reads_what_the_binary_wrote_where_the_config_says(tmp_path: Path) -> None:
    # a stand-in for run_simulation: reads record_timing_filepath from the config it is given (as OpenVINS)
    fake = tmp_path / "run_simulation"
    fake.write_text(f"""#!{sys.executable}
import re, sys, pathlib
text = pathlib.Path(sys.argv[1]).read_text()
path = pathlib.Path(re.search(r'record_timing_filepath: "(.*)"', text).group(1))
path.parent.mkdir(parents=True, exist_ok=True)
path.write_text("# t,total\\n1,0.010\\n2,0.020\\n3,0.030\\n")
""")
    fake.chmod(0o755)
    res = ob.run_openvins(fake, _folder(tmp_path), timeout=60)
    assert res == {"ms_per_frame": pytest.approx(20.0), "frames": 3}


def test_refuses_a_missing_binary_with_a_clear_message(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    args = argparse.Namespace(folder=_folder(tmp_path), openvins_bin=tmp_path / "nope", repeats=3,
                              timeout=10.0, json=False, out=None)
    assert ob.run(args) == 2
    assert "not an executable" in capsys.readouterr().out
