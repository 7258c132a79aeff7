"""EurocDriver on streams that are unusable or in the wrong units: a specific error naming the fix, or a
counted conversion (accelerometer in g, 12-bit images in 16-bit PNGs); reversed files are sorted."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers import EurocDriver
from runtime.errors import DataError
from tests.drivers.test_drivers_euroc import T0, cam_rows, imu_rows, write_asl


def _imu_with(fn, n: int = 40) -> list[str]:
    return [fn(r) for r in imu_rows(n)]


@pytest.mark.parametrize("name, rows, expect", [
    ("temperature column", _imu_with(lambda r: r + ",36.5"), "extra column"),
    ("semicolons", _imu_with(lambda r: r.replace(",", ";")), "';'"),
    ("tabs", _imu_with(lambda r: r.replace(",", "\t")), "spaces or tabs"),
    ("seconds", [f"{(T0 + k * 5_000_000) / 1e9:.9f}," + r.split(",", 1)[1] for k, r in enumerate(imu_rows())],
     "look like seconds"),
    ("all NaN", _imu_with(lambda r: r.split(",", 1)[0] + ",nan,nan,nan,nan,nan,nan"), "NaN or Inf"),
    ("empty", [], "no data rows"),
    ("microseconds", [f"{(T0 // 1000) + k * 5000}," + r.split(",", 1)[1] for k, r in enumerate(imu_rows())],
     "look like microseconds"),
])
def test_unusable_imu_streams_name_the_fix(tmp_path: Path, name: str, rows: list[str], expect: str) -> None:
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(4)})
    with pytest.raises(DataError, match=expect) as info:
        EurocDriver(seq)
    assert "imu0" in str(info.value.path)


def test_reversed_imu_file_is_sorted_and_counted(tmp_path: Path) -> None:
    rows = imu_rows(40)
    seq = write_asl(tmp_path, rows[::-1], {"cam0": cam_rows(4)})
    drv = EurocDriver(seq)
    t, gyro, _ = drv.imu_arrays()
    np.testing.assert_array_equal(t, T0 + 5_000_000 * np.arange(40))
    np.testing.assert_allclose(gyro[:, 0], 0.001 * np.arange(40))
    s = drv.report()["streams"]["imu0"]
    assert s["reordered"] == 39 and s["parsed"] == 40 and s["dropped_nonmonotonic"] == 0
    with pytest.raises(DataError, match="earlier than previous"):
        EurocDriver(seq, policy="strict")


def test_accelerometer_in_g_is_converted_and_counted(tmp_path: Path) -> None:
    rows = [r.rsplit(",", 3)[0] + ",1.0,0.01,-0.02" for r in imu_rows(40)]
    seq = write_asl(tmp_path, rows, {"cam0": cam_rows(4)})
    drv = EurocDriver(seq)
    _, _, accel = drv.imu_arrays()
    np.testing.assert_allclose(accel[:, 0], 9.80665)
    rep = drv.report()
    assert rep["streams"]["imu0"]["converted"] == 40 and any("look like g" in n for n in rep["notes"])
    with pytest.raises(DataError, match="multiply columns 5-7 by 9.80665"):
        EurocDriver(seq, policy="strict")


def test_camera_without_rows_or_images_is_an_error(tmp_path: Path) -> None:
    seq = write_asl(tmp_path / "a", imu_rows(), {"cam0": []})
    with pytest.raises(DataError, match="no usable frame: holds no data rows"):
        EurocDriver(seq)
    seq = write_asl(tmp_path / "b", imu_rows(), {"cam0": cam_rows(4)})
    for f in (seq / "mav0" / "cam0" / "data").iterdir():
        f.unlink()
    with pytest.raises(DataError, match="none of the 4 images it lists exists"):
        EurocDriver(seq)


@pytest.mark.parametrize("content", ["#timestamp [ns],filename \xb5s\n".encode("latin-1"),
                                     "#timestamp [ns],filename\n".encode("utf-16")])
def test_an_unused_camera_in_another_encoding_is_noted_not_fatal(tmp_path: Path, content: bytes) -> None:
    seq = write_asl(tmp_path, imu_rows(), {"cam0": cam_rows(4), "cam1": cam_rows(4)})
    (seq / "mav0" / "cam1" / "data.csv").write_bytes(content)
    drv = EurocDriver(seq)
    assert sum(hasattr(e, "image") for e in drv.events()) == 4
    assert any("cam1 (not read)" in n and "not a UTF-8 text file" in n for n in drv.report()["notes"])
    with pytest.raises(DataError, match="not a UTF-8 text file"):    # the camera read says so too
        EurocDriver(seq, camera="cam1")


def test_image_names_stay_inside_the_folder(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(), {"cam0": cam_rows(4)},
                    extra_cam_lines={"cam0": [f"{T0 + 10**9},../../../imu0/data.csv"]})
    with pytest.raises(DataError, match="points outside cam0/data/") as info:
        EurocDriver(seq)
    assert info.value.line == 6


def test_twelve_bit_images_in_sixteen_bit_pngs_are_scaled(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(), {"cam0": cam_rows(3)})
    data = seq / "mav0" / "cam0" / "data"
    ramp = (np.arange(48, dtype=np.uint16).reshape(6, 8) * 85)      # 0 .. 3995: 12-bit data
    for f in sorted(data.iterdir()):
        cv2.imwrite(str(f), ramp)
    drv = EurocDriver(seq)
    frames = [e for e in drv.events() if hasattr(e, "image")]
    assert len(frames) == 3
    np.testing.assert_array_equal(frames[0].image, (ramp >> 4).astype(np.uint8))   # not >> 8 (near black)
    rep = drv.report()
    assert rep["streams"]["cam0"]["converted"] == 3 and any("12-bit data" in n for n in rep["notes"])
    with pytest.raises(DataError, match="convert the images to 8-bit grey"):
        list(EurocDriver(seq, policy="strict").events())


def test_a_dark_first_sixteen_bit_image_does_not_clip_the_rest(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(), {"cam0": cam_rows(3)})
    files = sorted((seq / "mav0" / "cam0" / "data").iterdir())
    ramp = (np.arange(48, dtype=np.uint16).reshape(6, 8) * 85)      # 0 .. 3995: 12-bit data
    cv2.imwrite(str(files[0]), ramp // 20)                          # dim first image: 8-bit values
    for f in files[1:]:
        cv2.imwrite(str(f), ramp)
    drv = EurocDriver(seq)
    frames = [e for e in drv.events() if hasattr(e, "image")]
    np.testing.assert_array_equal(frames[0].image, (ramp // 20).astype(np.uint8))
    for f in frames[1:]:                # by the bits of the data, not clipped at 255 (>> 0)
        np.testing.assert_array_equal(f.image, (ramp >> 4).astype(np.uint8))
    notes = drv.report()["notes"]
    assert any(f"image {files[1].name} holds 12-bit data (maximum 3995)" in n for n in notes)


def test_images_that_data_csv_does_not_list_are_noted(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(), {"cam0": cam_rows(4)})
    data = seq / "mav0" / "cam0" / "data"
    first = sorted(data.iterdir())[0]
    for extra in ("1000000009000000000.png", "1000000009500000000.png"):   # a data.csv cut short
        (data / extra).write_bytes(first.read_bytes())
    (data / "notes.txt").write_text("not an image")
    drv = EurocDriver(seq)
    assert sum(hasattr(e, "image") for e in drv.events()) == 4
    notes = [n for n in drv.report()["notes"] if "not listed in data.csv" in n]
    assert len(notes) == 1 and "2 images" in notes[0] and "1000000009000000000.png" in notes[0]
    clean = write_asl(tmp_path / "clean", imu_rows(), {"cam0": cam_rows(4)})
    assert not any("not listed" in n for n in EurocDriver(clean).report()["notes"])
    rows = cam_rows(4)
    rows[2] = (rows[1][0], rows[2][1])                  # a duplicate stamp: the row is dropped, counted
    dup = write_asl(tmp_path / "dup", imu_rows(), {"cam0": rows})
    rep = EurocDriver(dup).report()
    assert rep["streams"]["cam0"]["dropped_duplicate"] == 1
    assert not any("not listed" in n for n in rep["notes"])     # its image is listed, not "cut short"


def test_an_image_name_that_is_a_folder_is_said(tmp_path: Path) -> None:
    seq = write_asl(tmp_path, imu_rows(), {"cam0": cam_rows(4)})
    second = sorted((seq / "mav0" / "cam0" / "data").iterdir())[1]
    second.unlink()
    second.mkdir()                      # not "missing": something else stands there
    drv = EurocDriver(seq)
    assert sum(hasattr(e, "image") for e in drv.events()) == 3
    rep = drv.report()
    assert rep["streams"]["cam0"]["missing_images"] == 1
    assert any(f"{second.name} is a folder, not a file: it is not an image file" in n for n in rep["notes"])
    with pytest.raises(DataError, match=f"image file .*{second.name} is a folder, not a file"):
        EurocDriver(seq, policy="strict")
