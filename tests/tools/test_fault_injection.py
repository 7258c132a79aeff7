"""Fault-injection replay: a simulated recording with dropped, duplicated and reordered frames and IMU
samples, a NaN burst, a time jump and an IMU gap during motion. Every fault is counted exactly as
injected (expected counters derived from the injection list, not from the driver), and the run still
publishes a trajectory close to ground truth."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers import EurocDriver
from runtime.config import DavioConfig
from tools.evaluation import ate
from tools.run_io import published_trajectory
from tools.run_session import run_pipeline

pytestmark = pytest.mark.slow


def _rows(path: Path) -> tuple[list[str], list[str]]:
    lines = path.read_text().splitlines()
    return [ln for ln in lines if ln.startswith("#")], [ln for ln in lines if ln and not ln.startswith("#")]


def _stamp(row: str) -> int:
    return int(row.split(",", 1)[0])


def _inject(src: Path, dst: Path) -> dict:
    """Copy `src` (mav0 layout) to `dst` with faults; returns the counters they must produce."""
    mav_src, mav = src / "mav0", dst / "mav0"
    (mav / "cam0" / "data").mkdir(parents=True)
    (mav / "imu0").mkdir(parents=True)
    for name in ("cam0/sensor.yaml", "imu0/sensor.yaml", "state_groundtruth_estimate0", "body.yaml"):
        if (mav_src / name).exists():
            (mav / name).symlink_to(mav_src / name)
    # -- camera: 3 consecutive frames dropped, one duplicated row, one swapped pair, one image missing
    head, cam = _rows(mav_src / "cam0" / "data.csv")
    for f in (mav_src / "cam0" / "data").iterdir():
        (mav / "cam0" / "data" / f.name).symlink_to(f)
    missing = cam[90].split(",")[1]
    (mav / "cam0" / "data" / missing).unlink()
    cam_out = cam[:50] + cam[53:]                       # frames 50-52 dropped upstream
    cam_out.insert(60, cam_out[59])                     # a duplicated row
    cam_out[70], cam_out[71] = cam_out[71], cam_out[70]   # a swapped pair
    (mav / "cam0" / "data.csv").write_text("\n".join(head + cam_out) + "\n")
    # -- IMU (200 Hz; motion after 2 s): duplicates, a NaN burst, a swapped pair, a time jump, a gap
    head, imu = _rows(mav_src / "imu0" / "data.csv")
    out = list(imu)
    for i in range(600, 605):                          # NaN burst of 5 samples at 3.0 s
        f = out[i].split(",")
        f[4] = "nan"
        out[i] = ",".join(f)
    t_jump = _stamp(out[700])
    out[700] = f"{t_jump + 1000 * 10**9}," + out[700].split(",", 1)[1]   # a stamp 1000 s ahead
    out[800], out[801] = out[801], out[800]            # a swapped pair
    del out[900:920]                                   # 0.1 s IMU gap during motion (4.5 s)
    out.insert(400, out[399])                          # duplicated samples
    out.insert(1000, out[999])
    (mav / "imu0" / "data.csv").write_text("\n".join(head + out) + "\n")
    return {
        "cam0": {"dropped_duplicate": 1, "reordered": 1, "missing_images": 1, "dropped_nonfinite": 0,
                 "dropped_nonmonotonic": 0, "gaps": 2, "missing_estimated": 4,
                 "parsed": len(cam) - 3, "emitted": len(cam) - 4},
        # gaps: the NaN burst (5 missing), the jumped sample's empty slot (1), the deleted 20 samples
        "imu0": {"dropped_duplicate": 2, "reordered": 1, "dropped_nonfinite": 5, "dropped_nonmonotonic": 1,
                 "gaps": 3, "missing_estimated": 26, "parsed": len(imu) - 20 - 5 - 1,
                 "emitted": len(imu) - 26},
    }


def test_faults_are_counted_as_injected_and_the_run_survives(small_sim_folder: Path, tmp_path: Path) -> None:
    expected = _inject(small_sim_folder, tmp_path / "faulty")
    clean = EurocDriver(small_sim_folder)
    faulty = EurocDriver(tmp_path / "faulty")
    res_clean = run_pipeline(clean, None, DavioConfig(), show_progress=False)
    res = run_pipeline(faulty, None, DavioConfig(), show_progress=False)
    streams = faulty.report()["streams"]
    for name, counts in expected.items():
        got = {k: streams[name][k] for k in counts}
        assert got == counts, name
    # the missing image's frame is the camera gap of one frame; the rest of the stream is intact
    gt = clean.groundtruth()
    e_clean = ate(published_trajectory(res_clean.pipeline.published), gt, align_method="se3").trans["rmse"]
    e = ate(published_trajectory(res.pipeline.published), gt, align_method="se3").trans["rmse"]
    assert len(res.pipeline.published) >= len(res_clean.pipeline.published) - 5
    assert e < max(3 * e_clean, 0.05), (e, e_clean)
    assert res.scheduler.frames == expected["cam0"]["emitted"]
    assert np.isfinite(e)
