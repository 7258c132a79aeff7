"""EurocDriver on the real V1_01_easy head folder and on small synthetic ASL folders with defects."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers import EurocDriver, Frame, ImuSample, read_camera_timestamps, read_euroc_imu_csv
from runtime.errors import ConfigError, DataError
from tests.conftest import shared_path

IMU_HEADER = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1]," \
             "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
T0 = 1_403_715_273_262_142_976  # a real EuRoC stamp: beyond float64's integer precision


def imu_rows(n: int = 40, period: int = 5_000_000) -> list[str]:
    rows = []
    for i in range(n):
        g = (0.001 * i, -0.002 * i, 0.003)
        a = (9.81, 0.01 * i, -0.2)
        rows.append(f"{T0 + i * period}," + ",".join(repr(x) for x in (*g, *a)))
    return rows


def cam_rows(n: int = 8, period: int = 50_000_000, start: int = 0) -> list[tuple[int, str]]:
    return [(T0 + start + i * period, f"{T0 + start + i * period}.png") for i in range(n)]


def write_asl(root: Path, imu: list[str], cams: dict[str, list[tuple[int, str]]], *,
              imu_header: str | None = IMU_HEADER, cam_header: str | None = "#timestamp [ns],filename",
              rates: dict[str, float] | None = None, newline: str = "\n", trailing_newline: bool = True,
              extra_cam_lines: dict[str, list[str]] | None = None) -> Path:
    """Write a small ASL folder (sequence/mav0/...) and return the sequence folder."""
    mav0 = root / "seq" / "mav0"
    (mav0 / "imu0").mkdir(parents=True)
    text = ([imu_header] if imu_header else []) + imu
    (mav0 / "imu0" / "data.csv").write_bytes((newline.join(text) + (newline if trailing_newline else ""))
                                             .encode())
    for name, rows in cams.items():
        (mav0 / name / "data").mkdir(parents=True)
        lines = ([cam_header] if cam_header else []) + [f"{t},{f}" for t, f in rows]
        lines += (extra_cam_lines or {}).get(name, [])
        (mav0 / name / "data.csv").write_bytes((newline.join(lines) + newline).encode())
        for k, (_, f) in enumerate(rows):
            img = np.full((6, 8), 10 * k % 256, np.uint8)
            img[0, 0] = 255
            cv2.imwrite(str(mav0 / name / "data" / f), img)
        rate = (rates or {}).get(name, 20)
        (mav0 / name / "sensor.yaml").write_text(f"%YAML:1.0\nsensor_type: camera\nrate_hz: {rate}\n")
    return root / "seq"


def split(events: list) -> tuple[list[ImuSample], list[Frame]]:
    return [e for e in events if isinstance(e, ImuSample)], [e for e in events if isinstance(e, Frame)]


def assert_accounted(report: dict, replayed: bool = True) -> None:
    """Every data row is kept or counted; after a replay every kept frame is emitted or counted."""
    for name, s in report["streams"].items():
        dropped = (s["truncated_lines"] + s["malformed_lines"] + s["dropped_nonfinite"]
                   + s["dropped_nonmonotonic"] + s["dropped_duplicate"])
        assert s["lines"] == s["parsed"] + dropped, name
        if replayed and name.startswith("cam"):
            assert s["parsed"] == (s["emitted"] + s["missing_images"] + s["repeated_images"]
                                   + s["unreadable_images"]), name


# ---------------------------------------------------------------------------------------------------
def test_real_head_folder_counts_order_and_groundtruth(euroc_head: Path) -> None:
    mav0 = euroc_head / "mav0"
    n_imu_lines = sum(1 for ln in (mav0 / "imu0" / "data.csv").read_text().splitlines()
                      if ln and not ln.startswith("#"))
    with EurocDriver(euroc_head) as drv:
        events = list(drv.events())
        imu, frames = split(events)
        assert len(frames) == 95
        assert len(imu) == 29_120 == n_imu_lines
        assert frames[0].t_ns == 1_403_715_273_262_142_976
        assert frames[-1].t_ns == 1_403_715_277_962_142_976
        assert frames[0].image.shape == (480, 752) and frames[0].image.dtype == np.uint8
        stamps = np.array([e.t_ns for e in events], dtype=np.int64)
        assert np.all(np.diff(stamps) >= 0)
        # equal stamps: the IMU sample precedes the frame
        assert isinstance(events[0], ImuSample) and isinstance(events[1], Frame)
        assert events[0].t_ns == events[1].t_ns
        # values equal an independent float parse of the same file (gyro columns before accel)
        ref = np.loadtxt(mav0 / "imu0" / "data.csv", delimiter=",", skiprows=1, max_rows=50)
        np.testing.assert_array_equal(np.stack([s.gyro for s in imu[:50]]), ref[:, 1:4])
        np.testing.assert_array_equal(np.stack([s.accel for s in imu[:50]]), ref[:, 4:7])
        gt = drv.groundtruth()
        assert gt is not None and gt.v is not None and gt.bg is not None and gt.ba is not None
        assert 4.9 < (gt.t_ns[-1] - gt.t_ns[0]) * 1e-9 <= 5.0
        gt_csv = mav0 / "state_groundtruth_estimate0" / "data.csv"
        row = np.loadtxt(gt_csv, delimiter=",", skiprows=1, max_rows=1)
        R_ref = Rotation.from_quat(row[[5, 6, 7, 4]]).as_matrix()  # scipy is x,y,z,w
        np.testing.assert_allclose(gt.R[0], R_ref, atol=1e-12)
        np.testing.assert_allclose(gt.p[0], row[1:4])
        np.testing.assert_allclose(gt.ba[0], row[14:17])
        rep = drv.report()
        assert rep["totals"]["missing_images"] == 0 and rep["streams"]["cam0"]["gaps"] == 0
        assert rep["streams"]["cam0"]["median_period_ns"] == pytest.approx(50_000_000, abs=1000)
        assert_accounted(rep)


def test_real_rig_from_sensor_yaml(euroc_head: Path) -> None:
    import yaml

    cam_yaml = euroc_head / "mav0" / "cam0" / "sensor.yaml"
    raw = yaml.safe_load("\n".join(cam_yaml.read_text().splitlines()[1:]))  # strip %YAML:1.0
    rig = EurocDriver(euroc_head).rig
    assert rig is not None
    assert (rig.camera.fx, rig.camera.fy, rig.camera.cx, rig.camera.cy) == tuple(raw["intrinsics"])
    assert (rig.camera.width, rig.camera.height) == tuple(raw["resolution"])
    # imu0's T_BS is the identity in EuRoC, so T_IC equals cam0's T_BS
    np.testing.assert_allclose(rig.T_IC, np.array(raw["T_BS"]["data"]).reshape(4, 4), atol=1e-6)
    assert rig.camera_rate_hz == 20


def test_withheld_calibration_gives_no_rig(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(10), {"cam0": cam_rows(2)})
    (seq / "mav0" / "cam0" / "sensor.yaml").unlink()
    drv = EurocDriver(seq)
    assert drv.rig is None
    assert any("rig calibration unknown" in n for n in drv.report()["notes"])


def test_real_full_sequence_groundtruth_choice(euroc_head: Path) -> None:
    drv = EurocDriver(euroc_head / "mav0", groundtruth_file="full_sequence_vicon2gt.csv")
    gt = drv.groundtruth()
    assert gt is not None and gt.t_ns[0] == 1_403_715_273_262_142_976
    assert (gt.t_ns[-1] - gt.t_ns[0]) * 1e-9 > 100.0


def test_imu_and_camera_helpers_on_imu_gt_files() -> None:
    seq = shared_path("euroc_imu_gt", "V1_02_medium")
    t, gyro, accel = read_euroc_imu_csv(seq / "imu0.csv")
    ref = np.loadtxt(seq / "imu0.csv", delimiter=",", skiprows=1, max_rows=5)
    assert t.dtype == np.int64 and t[0] == 1_403_715_523_912_143_104
    np.testing.assert_array_equal(gyro[:5], ref[:, 1:4])
    np.testing.assert_array_equal(accel[:5], ref[:, 4:7])
    assert np.all(np.diff(t) > 0)
    cam_t = read_camera_timestamps(seq / "cam0_timestamps.txt")
    lines = [int(x) for x in (seq / "cam0_timestamps.txt").read_text().split()]
    np.testing.assert_array_equal(cam_t, np.array(lines, dtype=np.int64))


def test_stamps_are_exact_int64(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(5, period=1), {"cam0": cam_rows(2)})
    t, _, _ = read_euroc_imu_csv(seq / "mav0" / "imu0" / "data.csv")
    np.testing.assert_array_equal(t - T0, np.arange(5))  # 1 ns steps survive (float64 would not)


# ---------------------------------------------------------------------------------------------------
def test_out_of_order_imu_rows_sorted_and_duplicates_dropped(tmp_path: Path) -> None:
    rows = imu_rows(20)
    rows.insert(10, rows[9])                      # duplicate of the previous stamp
    rows.insert(15, rows[3])                      # a repeat of an earlier stamp
    late = f"{T0 + 3 * 5_000_000 + 7}," + rows[0].split(",", 1)[1]
    rows.insert(16, late)                         # a sample written late: sorted into place
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(2)})
    drv = EurocDriver(seq)
    imu, _ = split(list(drv.events()))
    rep = drv.report()
    s = rep["streams"]["imu0"]
    assert s["dropped_duplicate"] == 2 and s["dropped_nonmonotonic"] == 0 and s["reordered"] == 1
    assert len(imu) == 21 and s["emitted"] == 21 and s["lines"] == 23
    assert imu[4].t_ns == T0 + 3 * 5_000_000 + 7
    assert np.all(np.diff([e.t_ns for e in imu]) > 0)
    assert_accounted(rep)


def test_a_block_on_another_clock_is_refused_not_sorted_in(tmp_path: Path) -> None:
    """Rows 30.. shifted 1000 s back (a clock reset): sorting them in would put the two halves in the
    wrong order; the error names the line where the stamps jump back."""
    rows = imu_rows(60)
    for i in range(30, 60):
        t, rest = rows[i].split(",", 1)
        rows[i] = f"{int(t) - 1000 * 10**9},{rest}"
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(2)})
    with pytest.raises(DataError, match=r"data.csv:32: stamps jump back by 999.995 s here and run on"):
        EurocDriver(seq)
    rows = imu_rows(60)                           # a reset whose second span lies inside the first one's
    for i in range(40, 60):
        t, rest = rows[i].split(",", 1)
        rows[i] = f"{int(t) - 150 * 5_000_000 - 10**9},{rest}"
    seq = write_asl(tmp_path / "inside", rows, {"cam0": cam_rows(2)})
    with pytest.raises(DataError, match=r"data.csv:42: stamps jump back by"):
        EurocDriver(seq)


def test_stamp_jumping_ahead_costs_one_row(tmp_path: Path) -> None:
    """A single far-future stamp is dropped instead of every row after it."""
    rows = imu_rows(30)
    rows[8] = str(T0 + 10**12) + "," + rows[8].split(",", 1)[1]
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(2)})
    drv = EurocDriver(seq)
    t, _, _ = drv.imu_arrays()
    assert drv.n_imu == 29 and drv.report()["streams"]["imu0"]["dropped_nonmonotonic"] == 1
    np.testing.assert_array_equal(t, [int(r.split(",")[0]) for i, r in enumerate(rows) if i != 8])


def test_nonfinite_rows_dropped(tmp_path: Path) -> None:
    rows = imu_rows(12)
    rows[4] = rows[4].rsplit(",", 1)[0] + ",nan"
    rows[7] = rows[7].split(",", 2)[0] + ",inf," + rows[7].split(",", 2)[2]
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(2)})
    drv = EurocDriver(seq)
    imu, _ = split(list(drv.events()))
    s = drv.report()["streams"]["imu0"]
    assert s["dropped_nonfinite"] == 2 and len(imu) == 10
    assert all(np.isfinite(e.gyro).all() and np.isfinite(e.accel).all() for e in imu)
    assert_accounted(drv.report())


def test_truncated_last_line(tmp_path: Path) -> None:
    rows = imu_rows(10)
    rows[-1] = rows[-1][: rows[-1].index(",", 25)]       # cut mid-row, no trailing newline
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(2)}, trailing_newline=False)
    drv = EurocDriver(seq)
    assert drv.report()["streams"]["imu0"]["truncated_lines"] == 1
    assert drv.n_imu == 9
    assert_accounted(drv.report(), replayed=False)


def test_a_last_line_without_a_line_end(tmp_path: Path) -> None:
    """Kept with a note, even when its plain-decimal last value may be short ('-0.2' -> '-0' cannot be told
    from a real '-0'); dropped as cut off only when the rows write exponents and this one lost digits."""
    rows = imu_rows(30)
    rows[-1] = rows[-1][:-2]
    seq = write_asl(tmp_path / "plain", rows, {"cam0": cam_rows(2)}, trailing_newline=False)
    drv = EurocDriver(seq, policy="strict")
    assert drv.n_imu == 30 and drv.report()["streams"]["imu0"]["truncated_lines"] == 0
    assert any("the last line has no line end: kept" in n for n in drv.report()["notes"])
    sci = [r.split(",")[0] + "," + ",".join(f"{float(v):.18e}" for v in r.split(",")[1:])
           for r in imu_rows(30)]
    sci[-1] = sci[-1][:-1]                       # '...e-01' -> '...e-0': a value ten times too large
    seq = write_asl(tmp_path / "sci", sci, {"cam0": cam_rows(2)}, trailing_newline=False)
    drv = EurocDriver(seq)
    assert drv.report()["streams"]["imu0"]["truncated_lines"] == 1 and drv.n_imu == 29
    with pytest.raises(DataError, match=r"data.csv:31: the last line has no line end and its last value"):
        EurocDriver(seq, policy="strict")


def test_a_first_row_with_a_flipped_stamp_is_not_a_header(tmp_path: Path) -> None:
    rows = imu_rows(20)
    rows[0] = "q" + rows[0][1:]                  # one flipped bit in the first stamp
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(2)})
    assert EurocDriver(seq).report()["streams"]["imu0"]["malformed_lines"] == 1
    with pytest.raises(DataError, match=r"data.csv:2: stamp 'q"):
        EurocDriver(seq, policy="strict")


def test_a_comment_line_before_a_text_header(tmp_path: Path) -> None:
    """'# recorded by ...' then a header without '#': still a header, not a bad data row."""
    seq = write_asl(tmp_path, imu_rows(20), {"cam0": cam_rows(2)},
                    imu_header="# recorded by my_logger v2\ntimestamp,wx,wy,wz,ax,ay,az")
    drv = EurocDriver(seq, policy="strict")
    assert drv.n_imu == 20 and drv.report()["totals"]["malformed_lines"] == 0


def test_missing_and_corrupt_images(tmp_path: Path) -> None:
    cams = cam_rows(6)
    seq = write_asl(tmp_path, imu_rows(80), {"cam0": cams})
    (seq / "mav0" / "cam0" / "data" / cams[2][1]).unlink()
    (seq / "mav0" / "cam0" / "data" / cams[4][1]).write_bytes(b"\x89PNG\r\n\x1a\nnot really a png")
    drv = EurocDriver(seq)
    assert drv.report()["streams"]["cam0"]["missing_images"] == 1   # known before replay
    _, frames = split(list(drv.events()))
    s = drv.report()["streams"]["cam0"]
    assert s["unreadable_images"] == 1 and s["emitted"] == 4 == len(frames)
    assert [f.t_ns for f in frames] == [cams[i][0] for i in (0, 1, 3, 5)]
    assert frames[0].image[0, 0] == 255 and frames[0].image.shape == (6, 8)
    assert_accounted(drv.report())


def test_an_image_listed_at_two_stamps_is_kept_once(tmp_path: Path) -> None:
    """One picture at two times would be a frame of no motion (and a wrong one); the later listing is
    skipped, counted and noted, and refused when strict."""
    cams = cam_rows(6)
    seq = write_asl(tmp_path, imu_rows(80), {"cam0": cams},
                    extra_cam_lines={"cam0": [f"{cams[-1][0] + 50_000_000},{cams[1][1]}",
                                              f"{cams[-1][0] + 100_000_000},./{cams[2][1]}"]})
    drv = EurocDriver(seq)
    _, frames = split(list(drv.events()))
    rep = drv.report()
    assert [f.t_ns for f in frames] == [t for t, _ in cams]
    assert rep["streams"]["cam0"]["repeated_images"] == 2
    assert any(f"image {cams[1][1]} is listed at two stamps (line 3, and line 8 at the later stamp, skipped)"
               in n for n in rep["notes"])
    assert_accounted(rep)
    again = rf"data.csv:8: image file {cams[1][1]} is listed again \(first on line 3\)"
    with pytest.raises(DataError, match=again):
        EurocDriver(seq, policy="strict")


def test_image_names_that_differ_in_case_from_their_files_are_read_and_noted(tmp_path: Path) -> None:
    """A folder written on a case-insensitive file system (data.csv says .png, the files are .PNG): the files
    are read, with a note; strict refuses it naming both; an image truly missing is still missing."""
    cams = cam_rows(6)
    # the file of frame 2 listed again at a later stamp, in a third spelling: a repeat of the same file
    seq = write_asl(tmp_path, imu_rows(80), {"cam0": cams},
                    extra_cam_lines={"cam0": [f"{cams[-1][0] + 50_000_000},{cams[2][1][:-4]}.Png"]})
    data = seq / "mav0" / "cam0" / "data"
    for k in (1, 2, 4):
        (data / cams[k][1]).rename(data / cams[k][1].replace(".png", ".PNG"))
    (data / cams[5][1]).unlink()
    drv = EurocDriver(seq)
    _, frames = split(list(drv.events()))
    rep = drv.report()
    assert [f.t_ns for f in frames] == [t for t, _ in cams[:5]]
    assert [int(f.image[0, 1]) for f in frames] == [10 * k for k in range(5)]     # each frame its own file
    assert rep["streams"]["cam0"]["missing_images"] == 1 and rep["streams"]["cam0"]["repeated_images"] == 1
    assert any(f"cam0: 3 image names in data.csv differ in case from their files (the first: {cams[1][1]} "
               f"is {cams[1][1][:-4]}.PNG)" in n for n in rep["notes"])
    assert_accounted(rep)
    with pytest.raises(DataError, match=rf"data.csv:3: image file {cams[1][1]} does not exist; "
                                        rf"{cams[1][1][:-4]}.PNG does \(the names differ in case\)"):
        EurocDriver(seq, policy="strict")


def test_a_wrong_size_first_image_is_skipped_against_the_calibration(tmp_path: Path) -> None:
    """With the calibrated size given, a wrong-size image is skipped and counted wherever it lies; without
    it the stream's first image sets the size (and the right ones after it would all be skipped)."""
    cams = cam_rows(5)
    seq = write_asl(tmp_path, imu_rows(80), {"cam0": cams})
    cv2.imwrite(str(seq / "mav0" / "cam0" / "data" / cams[0][1]), np.zeros((4, 8), np.uint8))
    drv = EurocDriver(seq)
    drv.expect_image_size(8, 6)
    _, frames = split(list(drv.events()))
    assert [f.t_ns for f in frames] == [t for t, _ in cams[1:]]
    assert drv.report()["streams"]["cam0"]["unreadable_images"] == 1
    assert_accounted(drv.report())
    strict = EurocDriver(seq, policy="strict")
    strict.expect_image_size(8, 6)
    with pytest.raises(DataError, match=r"data.csv:2: image .* is 8x4, the camera calibration 8x6"):
        list(strict.events())
    alone = EurocDriver(seq)
    _, frames = split(list(alone.events()))
    assert [f.t_ns for f in frames] == [cams[0][0]]
    assert any("is 8x4, the camera calibration 8x6: skipped" in n for n in drv.report()["notes"])
    other_camera = EurocDriver(seq)
    other_camera.expect_image_size(640, 480)     # a calibration of another camera: stop early, say why
    with pytest.raises(DataError, match=r"the first 5 images are 8x6 but the camera calibration is 640x480"):
        list(other_camera.events())


def test_header_variations(tmp_path: Path) -> None:
    """No '#' on the headers, CRLF line endings and spaces after commas still parse."""
    rows = [r.replace(",", ", ") for r in imu_rows(30)]
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(4)}, imu_header="timestamp,wx,wy,wz,ax,ay,az",
                    cam_header="timestamp [ns], filename", newline="\r\n")
    drv = EurocDriver(seq)
    imu, frames = split(list(drv.events()))
    assert len(imu) == 30 and len(frames) == 4
    np.testing.assert_allclose(imu[5].gyro, [0.005, -0.010, 0.003])
    assert sum("header without '#'" in n for n in drv.report()["notes"]) == 2
    assert drv.report()["totals"]["malformed_lines"] == 0


def test_a_corrupt_first_row_after_a_hash_header_is_counted_not_taken_for_a_header(tmp_path: Path) -> None:
    rows = imu_rows(30)
    rows[0] = "nan" + rows[0][rows[0].index(","):]
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(4)})
    drv = EurocDriver(seq)
    imu, _ = split(list(drv.events()))
    s = drv.report()["streams"]["imu0"]
    assert len(imu) == 29 and s["lines"] == 30 and s["dropped_nonmonotonic"] + s["malformed_lines"] == 1
    assert not any("header without '#'" in n for n in drv.report()["notes"])
    with pytest.raises(DataError, match=r"data.csv:2"):
        EurocDriver(seq, policy="strict")


def test_frame_gaps_and_unequal_camera_rates(tmp_path: Path) -> None:
    cam0 = cam_rows(10)
    del cam0[4:6]                                       # two frames lost upstream in one gap
    cam1 = cam_rows(5, period=100_000_000)             # 10 Hz, declared 20 Hz
    seq = write_asl(tmp_path, imu_rows(100), {"cam0": cam0, "cam1": cam1})
    drv = EurocDriver(seq)
    rep = drv.report()
    assert rep["streams"]["cam0"]["gaps"] == 1 and rep["streams"]["cam0"]["missing_estimated"] == 2
    assert any("unequal camera rates" in n for n in rep["notes"])
    assert any(n.startswith("cam1: measured rate 10.00 Hz") for n in rep["notes"])
    stereo = EurocDriver(seq, camera=("cam0", "cam1"))
    _, frames = split(list(stereo.events()))
    assert sorted({f.camera_id for f in frames}) == [0, 1] and len(frames) == 8 + 5
    assert "unequal camera rates" in stereo.intake.summary()


def test_imu_rate_and_coverage_notes(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(20, period=10_000_000), {"cam0": cam_rows(8)})   # 100 Hz, 0.19 s
    (seq / "mav0" / "imu0" / "sensor.yaml").write_text("%YAML:1.0\nsensor_type: imu\nrate_hz: 200\n")
    notes = EurocDriver(seq).report()["notes"]
    assert "imu0: measured rate 100.00 Hz differs from sensor.yaml rate_hz 200" in notes
    assert "cam0: 4 frames lie outside the IMU time span" in notes


def test_malformed_stamp_and_extra_fields(tmp_path: Path) -> None:
    rows = imu_rows(10)
    rows[2] = "1.403715273e18," + rows[2].split(",", 1)[1]      # float stamp: rejected, not rounded
    rows[5] = rows[5] + ",1.0"
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(2)})
    drv = EurocDriver(seq)
    assert drv.report()["streams"]["imu0"]["malformed_lines"] == 2 and drv.n_imu == 8


@pytest.mark.parametrize("defect, line", [
    ("duplicate", 5), ("nonmonotonic", 5), ("nan", 5), ("truncated", 11), ("missing_image", 4),
    ("corrupt_image", 3),
])
def test_strict_policy_raises_with_file_and_line(tmp_path: Path, defect: str, line: int) -> None:
    rows = imu_rows(10)
    cams = cam_rows(4)
    if defect == "duplicate":
        rows[3] = rows[2]
    elif defect == "nonmonotonic":
        rows[3] = rows[0]
    elif defect == "nan":
        rows[3] = rows[3].rsplit(",", 1)[0] + ",NaN"
    elif defect == "truncated":
        rows[9] = rows[9][:25]
    seq = write_asl(tmp_path, rows, {"cam0": cams}, trailing_newline=defect != "truncated")
    if defect == "missing_image":
        (seq / "mav0" / "cam0" / "data" / cams[2][1]).unlink()
    if defect == "corrupt_image":
        (seq / "mav0" / "cam0" / "data" / cams[1][1]).write_bytes(b"garbage")
    expected_file = "cam0" if "image" in defect else "imu0"
    with pytest.raises(DataError) as info:
        drv = EurocDriver(seq, policy="strict")
        list(drv.events())
    assert info.value.line == line
    assert Path(info.value.path).parent.name == expected_file
    assert f"data.csv:{line}" in str(info.value)
    # the same folder replays under the default policy with the defect counted
    drv = EurocDriver(seq)
    list(drv.events())
    assert sum(v for k, v in drv.report()["totals"].items() if k != "gaps") == 1


def test_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(ConfigError):
        EurocDriver(write_asl(tmp_path, imu_rows(3), {"cam0": cam_rows(2)}), policy="lenient")
    with pytest.raises(DataError, match="not an EuRoC"):
        EurocDriver(tmp_path / "seq" / "mav0" / "cam0" / "data")
    with pytest.raises(DataError, match="not a directory"):
        EurocDriver(tmp_path / "nowhere")


def test_groundtruth_rows_validated(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(5), {"cam0": cam_rows(2)})
    gt_dir = seq / "mav0" / "state_groundtruth_estimate0"
    gt_dir.mkdir()
    good = "0.5,1,2,1,0,0,0," + ",".join(["0.1"] * 9)
    rows = [f"{T0 + k},{good}" for k in range(5)]
    rows[2] = f"{T0 + 2},0.5,1,2,0,0,0,0," + ",".join(["0.1"] * 9)     # zero quaternion
    rows[3] = rows[3].replace(",1,2,", ",nan,2,", 1)
    (gt_dir / "data.csv").write_text("#t,...\n" + "\n".join(rows) + "\n")
    drv = EurocDriver(seq)
    gt = drv.groundtruth()
    np.testing.assert_array_equal(gt.t_ns - T0, [0, 1, 4])
    np.testing.assert_allclose(gt.p[0], [0.5, 1, 2])
    np.testing.assert_allclose(gt.R[0], np.eye(3))
    s = drv.report()["streams"]["groundtruth"]
    assert s["malformed_lines"] == 1 and s["dropped_nonfinite"] == 1 and s["emitted"] == 3
    assert_accounted(drv.report(), replayed=False)
    with pytest.raises(DataError) as info:
        EurocDriver(seq, policy="strict").groundtruth()
    assert info.value.line == 4


def test_a_folder_where_a_file_belongs_is_named(tmp_path: Path) -> None:
    from runtime.errors import CalibrationError

    seq = write_asl(tmp_path, imu_rows(5), {"cam0": cam_rows(2)})
    mav0 = seq / "mav0"
    (mav0 / "cam0" / "sensor.yaml").unlink()
    (mav0 / "cam0" / "sensor.yaml").mkdir()           # not "absent: calibration unknown"
    with pytest.raises(CalibrationError, match="sensor.yaml: is a folder, not a file"):
        _ = EurocDriver(seq).rig
    (mav0 / "imu0" / "data.csv").rename(mav0 / "imu0" / "kept.csv")
    (mav0 / "imu0" / "data.csv").symlink_to("data.csv")      # a link to itself
    with pytest.raises(DataError, match="imu0/data.csv is a symbolic link loop"):
        EurocDriver(seq)
    (mav0 / "imu0" / "data.csv").unlink()
    with pytest.raises(DataError, match="missing IMU file imu0/data.csv"):
        EurocDriver(seq)


def test_groundtruth_of_pose_columns_alone_is_read(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(5), {"cam0": cam_rows(2)})
    gt_dir = seq / "mav0" / "state_groundtruth_estimate0"
    gt_dir.mkdir()
    rows = [f"{T0 + k},{0.5 * k},1,2,1,0,0,0" for k in range(5)]       # t, p, q_wxyz (as davio eval reads)
    rows[3] = f"{T0 + 3},0.5,1,2,1,0,0"                                  # one cut short
    (gt_dir / "data.csv").write_text("#t,p,q\n" + "\n".join(rows) + "\n")
    drv = EurocDriver(seq)
    gt = drv.groundtruth()
    np.testing.assert_array_equal(gt.t_ns - T0, [0, 1, 2, 4])
    np.testing.assert_allclose(gt.p[:, 0], [0.0, 0.5, 1.0, 2.0])
    assert gt.v is None and gt.bg is None
    assert drv.report()["streams"]["groundtruth"]["truncated_lines"] == 1


def test_a_first_camera_row_with_a_flipped_stamp_is_not_a_header(tmp_path: Path) -> None:
    cams = cam_rows(4)
    seq = write_asl(tmp_path, imu_rows(80), {"cam0": cams})
    csv = seq / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[1] = "q" + lines[1][1:]                # the first data row's stamp, one bit flipped
    csv.write_text("\n".join(lines) + "\n")
    drv = EurocDriver(seq)
    assert drv.report()["streams"]["cam0"]["malformed_lines"] == 1
    assert not any("header without" in n for n in drv.report()["notes"])
