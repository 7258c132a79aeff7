"""Property tests of the sensor-file parsers: mutated or arbitrary EuRoC `imu0/data.csv` and
`cam0/data.csv` give a driver whose stream is strictly time-ordered, finite and fully accounted for,
or a DataError naming the file; a mutated `davio simulate` manifest reads or raises DataError."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers import EurocDriver, Frame
from runtime.errors import DataError
from tests.drivers.test_drivers_euroc import assert_accounted, cam_rows, imu_rows, write_asl
from tests.tools.test_fuzz_parsers import FUZZ, mutated
from tools.run_io import _describe_simulation, read_manifest


@pytest.fixture(scope="module")
def asl(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_asl(tmp_path_factory.mktemp("fuzz_asl"), imu_rows(40), {"cam0": cam_rows(6)})


def _replay_or_data_error(seq: Path) -> None:
    try:
        drv = EurocDriver(seq)
        events = list(drv.events())
    except DataError as exc:
        assert exc.path is not None and "mav0" in str(exc.path)
        return
    t = [e.t_ns for e in events]
    imu_t = [e.t_ns for e in events if not isinstance(e, Frame)]
    assert np.all(np.diff(imu_t) > 0) and np.all(np.diff(t) >= 0)
    assert all(np.all(np.isfinite(e.gyro)) and np.all(np.isfinite(e.accel)) for e in events
               if not isinstance(e, Frame))
    assert_accounted(drv.report())


@pytest.mark.parametrize("stream", ["imu0", "cam0"])
@FUZZ
@given(data=st.data())
def test_mutated_sensor_csv_replays_or_raises_data_error(asl: Path, stream: str, data: st.DataObject) -> None:
    csv = asl / "mav0" / stream / "data.csv"
    valid = csv.read_bytes()
    try:
        csv.write_bytes(data.draw(mutated(valid)))
        _replay_or_data_error(asl)
    finally:
        csv.write_bytes(valid)


@pytest.mark.parametrize("stream", ["imu0", "cam0"])
@FUZZ
@given(raw=st.binary(max_size=300) | st.text(max_size=300).map(str.encode))
def test_arbitrary_sensor_csv_replays_or_raises_data_error(asl: Path, stream: str, raw: bytes) -> None:
    csv = asl / "mav0" / stream / "data.csv"
    valid = csv.read_bytes()
    try:
        csv.write_bytes(raw)
        _replay_or_data_error(asl)
    finally:
        csv.write_bytes(valid)


MANIFEST = json.dumps({"schema": 1, "generator": "davio simulate",
                       "simulation": {"mode": "preset", "preset": "euroc", "seed": 0, "seconds": 4.0},
                       "config": {"preset": "euroc", "seconds": 4.0, "seed": 0, "style": "room",
                                  "imu_rate_hz": 200.0, "time_offset_s": 0.0, "start_s": 0.0,
                                  "camera_rate_hz": None}}, indent=1).encode()


@FUZZ
@given(data=st.data())
def test_mutated_manifest_reads_or_raises_data_error(tmp_path_factory, data: st.DataObject) -> None:
    path = tmp_path_factory.mktemp("manifest") / "manifest.json"
    path.write_bytes(data.draw(mutated(MANIFEST)))
    try:
        info = read_manifest(path)
    except DataError as exc:
        assert exc.path == str(path)
        return
    assert isinstance(info, dict)
    assert isinstance(_describe_simulation(info), str)


@pytest.mark.parametrize("key, value", [("seconds", 1e7), ("seconds", -1), ("imu_rate_hz", 0),
                                        ("time_offset_s", 5.0), ("seconds", "4"),
                                        ("attitude_smoothing_s", 1e6), ("attitude_smoothing_s", "1"),
                                        ("groundtruth_mode", "gyro"), ("groundtruth_mode", 3)])
def test_implausible_manifest_values_are_refused(tmp_path: Path, key: str, value: object) -> None:
    info = json.loads(MANIFEST)
    info["config"][key] = value
    path = tmp_path / "manifest.json"
    path.write_text(json.dumps(info))
    with pytest.raises(DataError, match=f"config.{key}"):
        read_manifest(path)
