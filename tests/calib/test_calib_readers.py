"""EuRoC and Kalibr readers on the real files, the Kalibr writer round trip, load_rig, euroc_rig."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import yaml

from calib import (
    ImuNoise,
    Pinhole,
    PinholeEquidistant,
    PinholeRadtan,
    PinholeRational,
    Rig,
    euroc_rig,
    find_imu_yaml,
    load_rig,
    read_euroc_rig,
    read_kalibr,
    write_kalibr,
)
from runtime.errors import CalibrationError
from tests.conftest import shared_path

# The numbers printed in EuRoC's mav0/cam0/sensor.yaml and imu0/sensor.yaml (V1_01_easy).
EUROC_T_BS = np.array(
    [
        [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975],
        [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768],
        [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949],
        [0.0, 0.0, 0.0, 1.0],
    ]
)
EUROC_INTRINSICS = [458.654, 457.296, 367.215, 248.375]
EUROC_DISTORTION = [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
EUROC_IMU = ImuNoise(1.6968e-04, 1.9393e-05, 2.0e-3, 3.0e-3, 200.0)


def _jpl_xyzw_to_rot(q: np.ndarray) -> np.ndarray:
    """R from a JPL quaternion (x, y, z, w): (2w^2 - 1) I - 2w [v]x + 2 v v^T (data README)."""
    v, w = np.asarray(q[:3]), float(q[3])
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return (2 * w * w - 1) * np.eye(3) - 2 * w * vx + 2 * np.outer(v, v)


def _check_euroc(rig: Rig) -> None:
    assert isinstance(rig.camera, PinholeRadtan)
    assert rig.camera.size == (752, 480)
    np.testing.assert_array_equal(
        [rig.camera.fx, rig.camera.fy, rig.camera.cx, rig.camera.cy], EUROC_INTRINSICS
    )
    np.testing.assert_array_equal(rig.camera.distortion, EUROC_DISTORTION)
    np.testing.assert_array_equal(rig.T_IC, EUROC_T_BS)  # imu0's T_BS is the identity: body = IMU
    assert rig.imu == EUROC_IMU
    assert rig.camera_rate_hz == 20.0
    assert rig.time_offset_s is None  # EuRoC files state no offset: withheld, not defaulted
    assert rig.missing() == ["time_offset_s"]


@pytest.mark.shared_data
def test_read_euroc_rig_accepts_sequence_mav0_cam0_and_sensor_yaml() -> None:
    seq = shared_path("euroc", "V1_01_easy_head")
    for p in (seq, seq / "mav0", seq / "mav0" / "cam0", seq / "mav0" / "cam0" / "sensor.yaml"):
        rig = read_euroc_rig(p)
        _check_euroc(rig)
        assert rig.name == "V1_01_easy_head"
    _check_euroc(load_rig(seq))
    _check_euroc(load_rig(seq / "mav0" / "cam0" / "sensor.yaml"))


@pytest.mark.shared_data
def test_read_kalibr_openvins_sim_files_agree_with_sim_info() -> None:
    folder = shared_path("openvins_sim", "udel_gore_mono")
    rig = read_kalibr(folder / "kalibr_imucam_chain.yaml", folder / "kalibr_imu_chain.yaml")
    # sim_info.txt states the extrinsics independently, as JPL q_ItoC and p_IinC
    line = next(ln for ln in (folder / "sim_info.txt").read_text().splitlines() if "extrinsics" in ln)
    values = np.array(line.split(")")[-1].split(), dtype=float)
    R_CI = _jpl_xyzw_to_rot(values[:4])
    np.testing.assert_allclose(rig.T_CI[:3, :3], R_CI, atol=1e-9)
    np.testing.assert_allclose(rig.T_CI[:3, 3], values[4:7], atol=1e-9)
    np.testing.assert_allclose(rig.T_IC, EUROC_T_BS, atol=1e-15)  # T_imu_cam is stored as is
    assert rig.camera is not None and rig.camera.isclose(
        PinholeRadtan(752, 480, *EUROC_INTRINSICS, EUROC_DISTORTION)
    )
    assert rig.imu == EUROC_IMU
    assert rig.time_offset_s is None and rig.camera_rate_hz is None
    cam1 = read_kalibr(folder / "kalibr_imucam_chain.yaml", camera="cam1")
    assert cam1.camera is not None and cam1.camera.cx == 379.999 and cam1.imu is None
    # load_rig finds kalibr_imu_chain.yaml beside kalibr_imucam_chain.yaml
    assert find_imu_yaml(folder / "kalibr_imucam_chain.yaml") == folder / "kalibr_imu_chain.yaml"
    assert load_rig(folder / "kalibr_imucam_chain.yaml").isclose(rig)
    assert load_rig(folder).isclose(rig)  # a folder without EuRoC files: its Kalibr camchain


@pytest.mark.shared_data
def test_t_cam_imu_and_t_imu_cam_give_the_same_rig(tmp_path: Path) -> None:
    folder = shared_path("openvins_sim", "udel_gore_mono")
    ov = read_kalibr(folder / "kalibr_imucam_chain.yaml")
    # hand-made Kalibr file: T_cam_imu is the matrix inverse of OpenVINS's T_imu_cam
    text = (folder / "kalibr_imucam_chain.yaml").read_text().split("\n", 1)[1]
    data = yaml.safe_load(text)
    cam0 = data["cam0"]
    cam0["T_cam_imu"] = np.linalg.inv(np.array(cam0.pop("T_imu_cam"))).tolist()
    (tmp_path / "kalibr.yaml").write_text(yaml.safe_dump({"cam0": cam0}))
    kal = read_kalibr(tmp_path / "kalibr.yaml")
    assert kal.isclose(ov, rtol=0, atol=1e-12)
    # and both keys through our writer
    for key in ("T_cam_imu", "T_imu_cam"):
        write_kalibr(ov, tmp_path / f"{key}.yaml", extrinsics_key=key)
        assert key in yaml.safe_load((tmp_path / f"{key}.yaml").read_text())["cam0"]
        assert read_kalibr(tmp_path / f"{key}.yaml").isclose(ov, rtol=0, atol=1e-15)


def _rigs() -> list[Rig]:
    rng = np.random.default_rng(0)
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=3).as_matrix()
    T[:3, 3] = rng.normal(size=3) * 0.1
    radtan = PinholeRadtan(640, 400, 401.123456789, 402.5, 319.25, 201.75, rng.normal(size=4) * 0.01)
    fisheye = PinholeEquidistant(848, 800, 285.7, 285.9, 425.1, 398.2, rng.normal(size=4) * 0.01)
    return [
        Rig(radtan, T, -0.0123456789, ImuNoise(1e-4, 2e-5, 3e-3, 4e-4, 400.0), 30.0, "radtan"),
        Rig(fisheye, T, None, ImuNoise(gyro_noise_density=1e-3), None, "fisheye-partial"),
        Rig(Pinhole(320, 240, 300.0, 300.0, 159.5, 119.5), None, 0.0, None, 15.0, "pinhole"),
        Rig(PinholeRational(1280, 800, 800.0, 800.5, 640.5, 400.25,
                            [9.49, -102.07, 0.0008, 0.0020, 401.19, 9.26, -100.43, 394.56]),
            T, 0.001, None, 30.0, "rational"),
        Rig(None, None, None, None, None, "withheld"),
    ]


@pytest.mark.parametrize("rig", _rigs(), ids=lambda r: r.name)
def test_writer_round_trip(rig: Rig, tmp_path: Path) -> None:
    write_kalibr(rig, tmp_path / "camchain.yaml", tmp_path / "imu.yaml", comment="round trip\ntest")
    back = read_kalibr(tmp_path / "camchain.yaml", tmp_path / "imu.yaml")
    assert back.isclose(rig, rtol=0, atol=1e-15)
    assert back.name == rig.name
    assert back.missing() == rig.missing()
    assert load_rig(tmp_path / "camchain.yaml").isclose(rig, rtol=0, atol=1e-15)  # finds imu.yaml
    assert (tmp_path / "camchain.yaml").read_text().startswith("%YAML 1.1\n---\n# round trip\n# test\n")
    without_imu = read_kalibr(tmp_path / "camchain.yaml")
    assert without_imu.imu is None


def _cv_matrix(node, rows: int, cols: int) -> np.ndarray:
    """A nested-list node read as OpenVINS's YamlParser reads an Eigen matrix (element by element)."""
    assert node.isSeq() and node.size() == rows, node.size()
    return np.array([[node.at(r).at(c).real() for c in range(cols)] for r in range(rows)])


@pytest.mark.parametrize("key", ["T_cam_imu", "T_imu_cam"])
def test_written_files_load_as_openvins_2_7_reads_them(key: str, tmp_path: Path) -> None:
    """OpenVINS 2.7 reads the camchain and IMU YAML with OpenCV's FileStorage, and its parser fails the
    whole configuration when a required node is missing (ov_core/src/utils/opencv_yaml_parse.h at release
    commit 93adc24; the nodes: ov_msckf VioManagerOptions.h, StateOptions.h, ros/ROS1Visualizer.cpp)."""
    cv2 = pytest.importorskip("cv2")
    rig = euroc_rig()
    write_kalibr(rig, tmp_path / "camchain.yaml", tmp_path / "imu.yaml", extrinsics_key=key, comment="x")
    for name in ("camchain.yaml", "imu.yaml"):   # OpenCV 3.x/4.x open a file only when it starts so
        assert (tmp_path / name).read_bytes()[:5] == b"%YAML"
    fs_cam = cv2.FileStorage(str(tmp_path / "camchain.yaml"), cv2.FILE_STORAGE_READ)   # kept open: nodes
    cam = fs_cam.getNode("cam0")                                                        # point into it
    assert cam.getNode("distortion_model").string() == "radtan"
    assert [cam.getNode("intrinsics").at(i).real() for i in range(4)] == EUROC_INTRINSICS
    assert [cam.getNode("distortion_coeffs").at(i).real() for i in range(4)] == EUROC_DISTORTION
    assert [int(cam.getNode("resolution").at(i).real()) for i in range(2)] == [752, 480]
    assert cam.getNode("rostopic").string() == "/cam0/image_raw" and cam.getNode("cam_overlaps").isSeq()
    assert cam.getNode("timeshift_cam_imu").real() == 0.0
    T = _cv_matrix(cam.getNode(key), 4, 4)
    T_IC = T if key == "T_imu_cam" else np.linalg.inv(T)      # OpenVINS inverts T_cam_imu itself
    assert np.allclose(T_IC, EUROC_T_BS, atol=1e-12)
    fs_imu = cv2.FileStorage(str(tmp_path / "imu.yaml"), cv2.FILE_STORAGE_READ)
    imu = fs_imu.getNode("imu0")
    assert imu.getNode("gyroscope_noise_density").real() == EUROC_IMU.gyro_noise_density
    assert imu.getNode("accelerometer_random_walk").real() == EUROC_IMU.accel_random_walk
    assert imu.getNode("rostopic").string() == "/imu0" and imu.getNode("model").string() == "kalibr"
    for name in ("Tw", "Ta", "R_IMUtoACC", "R_IMUtoGYRO"):
        assert np.array_equal(_cv_matrix(imu.getNode(name), 3, 3), np.eye(3)), name
    assert np.array_equal(_cv_matrix(imu.getNode("Tg"), 3, 3), np.zeros((3, 3)))
    # and Kalibr's own readers (PyYAML) find their topics and rate
    assert yaml.safe_load((tmp_path / "imu.yaml").read_text())["imu0"]["update_rate"] == 200.0
    assert yaml.safe_load((tmp_path / "camchain.yaml").read_text())["cam0"]["rostopic"] == "/cam0/image_raw"


def test_bundled_euroc_rig() -> None:
    rig = euroc_rig()
    assert rig.is_complete and rig.time_offset_s == 0.0 and rig.name == "euroc_mav_cam0"
    expected = Rig(
        PinholeRadtan(752, 480, *EUROC_INTRINSICS, EUROC_DISTORTION), EUROC_T_BS, 0.0, EUROC_IMU, 20.0
    )
    assert rig.isclose(expected, rtol=0, atol=1e-15)
    bundled = Path(__file__).resolve().parents[2] / "calib" / "rigs" / "euroc_camchain.yaml"
    assert find_imu_yaml(bundled) == bundled.with_name("euroc_imu.yaml")
    assert load_rig(bundled).isclose(rig)


@pytest.mark.shared_data
def test_bundled_euroc_rig_matches_the_dataset_files() -> None:
    real = read_euroc_rig(shared_path("euroc", "V1_01_easy_head"))
    assert euroc_rig().isclose(real.replace(time_offset_s=0.0), rtol=0, atol=1e-15)


def test_a_folder_with_two_camchains_names_both(tmp_path: Path) -> None:
    """Which of two camchains is meant cannot be told: before, the folder was said not to be an EuRoC one."""
    text = (resources.files("calib") / "rigs" / "euroc_camchain.yaml").read_text()
    for name in ("left-camchain.yaml", "right-camchain.yaml"):
        (tmp_path / name).write_text(text)
    with pytest.raises(CalibrationError, match=r"2 camchains in this folder \(left-camchain.yaml, "
                                               r"right-camchain.yaml\): give the one to use"):
        load_rig(tmp_path)
    (tmp_path / "right-camchain.yaml").unlink()
    assert load_rig(tmp_path).camera is not None


def test_kalibr_camera_imu_output_beside_its_input_camchain_is_chosen(tmp_path: Path) -> None:
    """Kalibr's camera-IMU run writes X-camchain-imucam.yaml beside its input X-camchain.yaml (no
    extrinsics): the folder is a calibration, not an ambiguity."""
    text = (resources.files("calib") / "rigs" / "euroc_camchain.yaml").read_text()
    cameras_only = "\n".join(ln for ln in text.splitlines() if "T_cam_imu" not in ln and not
                             ln.strip().startswith("- ["))
    (tmp_path / "bag-camchain.yaml").write_text(cameras_only)
    (tmp_path / "bag-camchain-imucam.yaml").write_text(text)
    rig = load_rig(tmp_path)
    assert rig.T_IC is not None                           # the file without extrinsics was not read
    (tmp_path / "other-camchain-imucam.yaml").write_text(text)        # a third: ambiguous again
    with pytest.raises(CalibrationError, match="3 camchains in this folder"):
        load_rig(tmp_path)
