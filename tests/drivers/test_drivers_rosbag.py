"""RosbagDriver: ROS 1 / ROS 2 (mcap, sqlite3) bags written with rosbags itself replay exactly as the EuRoC
folder they came from; topic detection, encodings, CameraInfo, and bad bags counted or refused."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers import EurocDriver, Frame
from drivers.rosbag import RosbagDriver, is_bag
from runtime.errors import ConfigError, DataError
from tests.conftest import shared_path
from tests.drivers.bag_writer import bag_from_arrays, compressed_msg, image_msg, imu_msg, typestore, write_bag
from tools.cli import main

FORMATS = ["ros1", "mcap", "sqlite3"]


def _bag_path(tmp: Path, fmt: str, name: str = "rec") -> Path:
    return tmp / (f"{name}.bag" if fmt == "ros1" else f"{name}_{fmt}")


def _synthetic(n_imu: int = 200, n_cam: int = 10, t0: int = 1_000_000_000_000_000_000):
    rng = np.random.default_rng(0)
    imu_t = t0 + 5_000_000 * np.arange(n_imu)
    gyro = rng.normal(0, 0.1, (n_imu, 3))
    accel = rng.normal(0, 0.1, (n_imu, 3)) + [0, 0, 9.81]
    cam_t = t0 + 50_000_000 * np.arange(n_cam) + 2_000_000
    images = [rng.integers(0, 256, (24, 32), dtype=np.uint8) for _ in range(n_cam)]
    return imu_t, gyro, accel, cam_t, images


def _frames(drv) -> list[Frame]:
    return [e for e in drv.events() if isinstance(e, Frame)]


@pytest.fixture(scope="module")
def head_events() -> tuple:
    """The first 3.2 s of the real V1_01 head as events, and its rig."""
    drv = EurocDriver(shared_path("euroc", "V1_01_easy_head"))
    ev = list(drv.events())
    ev = [e for e in ev if e.t_ns - ev[0].t_ns <= 3_200_000_000]
    return ev, drv.rig


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_bag_of_a_euroc_folder_replays_the_same_events(tmp_path: Path, head_events: tuple,
                                                         fmt: str) -> None:
    ev, rig = head_events
    imu = [e for e in ev if not isinstance(e, Frame)]
    frames = [e for e in ev if isinstance(e, Frame)]
    path = bag_from_arrays(_bag_path(tmp_path, fmt), fmt, [e.t_ns for e in imu], [e.gyro for e in imu],
                           [e.accel for e in imu], [f.t_ns for f in frames], [f.image for f in frames])
    assert is_bag(path)
    got = list(RosbagDriver(path, rig=rig).events())
    assert len(got) == len(ev)
    for a, b in zip(ev, got, strict=True):
        assert type(a) is type(b) and a.t_ns == b.t_ns
        if isinstance(a, Frame):
            np.testing.assert_array_equal(a.image, b.image)
        else:
            np.testing.assert_array_equal(a.gyro, b.gyro)
            np.testing.assert_array_equal(a.accel, b.accel)


def test_davio_run_on_the_bag_equals_the_run_on_the_folder(tmp_path: Path, head_events: tuple) -> None:
    ev, _ = head_events
    head = shared_path("euroc", "V1_01_easy_head")
    imu = [e for e in ev if not isinstance(e, Frame)]
    frames = [e for e in ev if isinstance(e, Frame)]
    bag = bag_from_arrays(tmp_path / "head.bag", "ros1", [e.t_ns for e in imu], [e.gyro for e in imu],
                          [e.accel for e in imu], [f.t_ns for f in frames], [f.image for f in frames])
    assert main(["run", str(bag), "--native-only", "--out", str(tmp_path / "bag_run")]) == 1   # no rig
    common = ["--native-only", "--seconds", "3"]
    assert main(["run", str(bag), "--rig", str(head), *common, "--out", str(tmp_path / "bag_run")]) == 0
    assert main(["run", str(head), *common, "--out", str(tmp_path / "dir_run")]) == 0
    odo = (tmp_path / "bag_run" / "odometry.tum").read_text()
    assert odo == (tmp_path / "dir_run" / "odometry.tum").read_text() and len(odo.splitlines()) > 15


def test_topics_are_detected_and_ambiguity_is_an_error(tmp_path: Path) -> None:
    ts = typestore("mcap")
    imu_t, gyro, accel, cam_t, images = _synthetic()
    msgs = [("/imu0", int(t), imu_msg(ts, False, int(t), k, gyro[k], accel[k])) for k, t in enumerate(imu_t)]
    for cam in ("/cam0/image_raw", "/cam1/image_raw"):
        msgs += [(cam, int(t), image_msg(ts, False, int(t), k, images[k])) for k, t in enumerate(cam_t)]
    two = write_bag(tmp_path / "stereo", "mcap", sorted(msgs, key=lambda m: m[1]))
    drv = RosbagDriver(two)
    assert drv.image_topic == "/cam0/image_raw"
    assert any("choose with --image-topic" in n for n in drv.report()["notes"])
    assert RosbagDriver(two, image_topic="/cam1/image_raw").image_topic == "/cam1/image_raw"
    with pytest.raises(ConfigError, match="holds sensor_msgs/msg/Imu"):
        RosbagDriver(two, image_topic="/imu0")
    with pytest.raises(ConfigError, match="no topic '/left'"):
        RosbagDriver(two, image_topic="/left")
    msgs2 = [(t.replace("cam0", "front").replace("cam1", "rear"), s, m) for t, s, m in msgs]
    with pytest.raises(ConfigError, match="several image topics"):
        RosbagDriver(write_bag(tmp_path / "ambiguous", "mcap", sorted(msgs2, key=lambda m: m[1])))
    no_imu = write_bag(tmp_path / "no_imu", "mcap", [m for m in msgs if m[0] != "/imu0"])
    with pytest.raises(DataError, match="no IMU topic"):
        RosbagDriver(no_imu)


@pytest.mark.parametrize("encoding, compressed", [("rgb8", False), ("bgr8", False), ("mono16", False),
                                                  ("mono8", True)])
def test_encodings_become_the_same_grey_image(tmp_path: Path, encoding: str, compressed: bool) -> None:
    import cv2

    imu_t, gyro, accel, cam_t, images = _synthetic()
    if encoding in ("rgb8", "bgr8"):
        colour = [np.dstack([img, img // 2, 255 - img]) for img in images]
        code = cv2.COLOR_RGB2GRAY if encoding == "rgb8" else cv2.COLOR_BGR2GRAY
        expected = [cv2.cvtColor(c, code) for c in colour]
        sent = colour
    elif encoding == "mono16":
        sent = [img.astype(np.uint16) << 4 for img in images]   # 12-bit data
        expected = images
    else:
        sent = expected = images
    bag = bag_from_arrays(tmp_path / "enc", "sqlite3", imu_t, gyro, accel, cam_t, sent, encoding=encoding,
                          compressed=compressed)
    drv = RosbagDriver(bag)
    frames = _frames(drv)
    assert len(frames) == len(expected)
    for f, e in zip(frames, expected, strict=True):
        np.testing.assert_array_equal(f.image, e)
    if encoding == "mono16":
        assert drv.report()["streams"]["cam0"]["converted"] == len(images)


def test_a_dark_first_mono16_image_does_not_clip_the_rest(tmp_path: Path) -> None:
    imu_t, gyro, accel, cam_t, images = _synthetic()
    sent = [img.astype(np.uint16) << 4 for img in images]                   # 12-bit data
    sent[0] = images[0].astype(np.uint16) // 2                              # a dim first image
    bag = bag_from_arrays(tmp_path / "dark", "sqlite3", imu_t, gyro, accel, cam_t, sent, encoding="mono16")
    drv = RosbagDriver(bag)
    frames = _frames(drv)
    np.testing.assert_array_equal(frames[0].image, images[0] // 2)
    for f, e in zip(frames[1:], images[1:], strict=True):
        np.testing.assert_array_equal(f.image, e)
    assert any(f"the image at {cam_t[1]} ns holds 12-bit data" in n for n in drv.report()["notes"])


def test_bad_messages_are_counted_and_strict_refuses_them(tmp_path: Path) -> None:
    imu_t, gyro, accel, cam_t, images = _synthetic()
    gyro[50:53] = np.nan                       # a NaN burst
    imu_t = imu_t.copy()
    imu_t[[100, 101]] = imu_t[[101, 100]]      # two samples stamped in swapped order
    imu_t[150] = imu_t[149]                    # a duplicated stamp
    record_t = _synthetic()[0]                 # received in index order
    bag = bag_from_arrays(tmp_path / "bad.bag", "ros1", imu_t, gyro, accel, cam_t, images,
                          imu_record_t=record_t)
    drv = RosbagDriver(bag)
    t, _, _ = drv.imu_arrays()
    s = drv.report()["streams"]["imu0"]
    assert (s["dropped_nonfinite"], s["dropped_duplicate"], s["reordered"]) == (3, 1, 1)
    assert np.all(np.diff(t) > 0) and t.shape[0] == 200 - 3 - 1 and s["parsed"] == t.shape[0]
    with pytest.raises(DataError, match="NaN or Inf"):
        RosbagDriver(bag, policy="strict")


def test_camera_info_gives_intrinsics_and_a_size_mismatch_is_counted(tmp_path: Path) -> None:
    from calib import Rig
    from calib.camera import Pinhole

    ts = typestore("mcap")
    imu_t, gyro, accel, cam_t, images = _synthetic()
    msgs = [("/imu0", int(t), imu_msg(ts, False, int(t), k, gyro[k], accel[k])) for k, t in enumerate(imu_t)]
    msgs += [("/cam0/image_raw", int(t), image_msg(ts, False, int(t), k, images[k]))
             for k, t in enumerate(cam_t)]
    Info = ts.types["sensor_msgs/msg/CameraInfo"]
    hdr = msgs[-1][2].header
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                       do_rectify=False)
    info = Info(header=hdr, height=24, width=32, distortion_model="plumb_bob",
                d=np.array([-0.28, 0.07, 0.0002, 0.00002, 0.0]),
                k=np.array([30.0, 0, 16, 0, 31.0, 12, 0, 0, 1]),
                r=np.eye(3).reshape(-1), p=np.zeros(12), binning_x=0, binning_y=0, roi=roi)
    msgs.append(("/cam0/camera_info", int(cam_t[0]), info))
    bag = write_bag(tmp_path / "info", "mcap", sorted(msgs, key=lambda m: m[1]))
    drv = RosbagDriver(bag)
    cam = drv.rig.camera
    assert (cam.width, cam.height, cam.fx, cam.cy) == (32, 24, 30.0, 12.0)
    assert cam.distortion_model == "radtan"
    assert drv.rig.T_IC is None     # extrinsics withheld: the bring-up estimates them (with a model)
    rational = [-0.28, 0.07, 0.0002, 0.00002, 0.01, 0.1, 0.02, 0.003]
    msgs[-1] = (msgs[-1][0], msgs[-1][1], Info(header=hdr, height=24, width=32,
                                                distortion_model="rational_polynomial",
                                                d=np.array(rational + [0.0] * 6),    # 14, no thin prism
                                                k=np.array([30.0, 0, 16, 0, 31.0, 12, 0, 0, 1]),
                                                r=np.eye(3).reshape(-1), p=np.zeros(12), binning_x=0,
                                                binning_y=0, roi=roi))
    rat = RosbagDriver(write_bag(tmp_path / "rational", "mcap", sorted(msgs, key=lambda m: m[1]))).rig.camera
    assert rat.distortion_model == "rational" and rat.distortion.tolist() == rational
    wrong = Rig(camera=Pinhole(64, 48, 50.0, 50.0, 32.0, 24.0))
    drv = RosbagDriver(bag, rig=wrong)
    assert _frames(drv) == [] and drv.report()["streams"]["cam0"]["unreadable_images"] == len(images)
    assert any("differs from the calibration's 64x48" in n for n in drv.report()["notes"])


@pytest.mark.parametrize("fmt,image_topic", [("ros1", "/cam0/image_raw"),
                                              ("mcap", "/cam0/image_raw/compressed")])
def test_camera_info_of_ros1_and_beside_a_compressed_topic(tmp_path: Path, fmt: str, image_topic: str
                                                           ) -> None:
    """ROS 1 names the CameraInfo fields K and D (ROS 2: k, d); image_transport puts a compressed stream
    one level below the camera's namespace (/cam0/image_raw/compressed beside /cam0/camera_info)."""
    ros1 = fmt == "ros1"
    ts = typestore(fmt)
    imu_t, gyro, accel, cam_t, images = _synthetic()
    msgs = [("/imu0", int(t), imu_msg(ts, ros1, int(t), k, gyro[k], accel[k])) for k, t in enumerate(imu_t)]
    make = compressed_msg if image_topic.endswith("compressed") else image_msg
    msgs += [(image_topic, int(t), make(ts, ros1, int(t), k, images[k])) for k, t in enumerate(cam_t)]
    Info = ts.types["sensor_msgs/msg/CameraInfo"]
    roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                       do_rectify=False)
    fields = dict(D=np.array([-0.28, 0.07, 0.0002, 0.00002, 0.0]),
                  K=np.array([30.0, 0, 16, 0, 31.0, 12, 0, 0, 1]), R=np.eye(3).reshape(-1), P=np.zeros(12))
    if not ros1:
        fields = {k.lower(): v for k, v in fields.items()}
    info = Info(header=msgs[-1][2].header, height=24, width=32, distortion_model="plumb_bob", binning_x=0,
                binning_y=0, roi=roi, **fields)
    msgs.append(("/cam0/camera_info", int(cam_t[0]), info))
    bag = write_bag(_bag_path(tmp_path, fmt, "info"), fmt, sorted(msgs, key=lambda m: m[1]))
    cam = RosbagDriver(bag).rig.camera
    assert (cam.width, cam.height, cam.fx, cam.fy, cam.cx, cam.cy) == (32, 24, 30.0, 31.0, 16.0, 12.0)
    assert cam.distortion_model == "radtan"


@pytest.mark.parametrize("topic", ["/imu0", "/cam0/image_raw"])
def test_a_publisher_that_does_not_stamp_its_messages_is_named(tmp_path: Path, topic: str) -> None:
    """Header stamps all 0 on one topic (record times fine): a clear error naming the topic, not a run that
    spans decades and blames the motion."""
    ts = typestore("mcap")
    imu_t, gyro, accel, cam_t, images = _synthetic()
    def stamp(t: int, on: str) -> int:
        return 0 if on == topic else t

    msgs = [("/imu0", int(t), imu_msg(ts, False, stamp(int(t), "/imu0"), k, gyro[k], accel[k]))
            for k, t in enumerate(imu_t)]
    msgs += [("/cam0/image_raw", int(t), image_msg(ts, False, stamp(int(t), "/cam0/image_raw"), k, images[k]))
             for k, t in enumerate(cam_t)]
    bag = write_bag(tmp_path / "unstamped", "mcap", sorted(msgs, key=lambda m: m[1]))
    with pytest.raises(DataError, match=rf"{topic}: (\d+) of \1 messages share the header stamp 0 "
                                        r"\(1 distinct stamps\): the publisher does not stamp"):
        RosbagDriver(bag)
    twice = write_bag(tmp_path / "twice", "mcap", sorted(
        [(tp, t, m) for tp, t, _ in msgs for m in [
            imu_msg(ts, False, t, 0, gyro[0], accel[0]) if tp == "/imu0" else
            image_msg(ts, False, t, 0, images[0])]] * 2, key=lambda m: m[1]))
    drv = RosbagDriver(twice)                        # every stamp twice: a topic recorded twice, repaired
    assert drv.report()["streams"]["imu0"]["dropped_duplicate"] == len(imu_t)


def test_not_a_bag_and_a_corrupt_bag_are_clear_errors(tmp_path: Path) -> None:
    (tmp_path / "x.bag").write_bytes(b"#ROSBAG V2.0\n" + b"\x00" * 40)
    with pytest.raises(DataError, match="cannot read the bag"):
        RosbagDriver(tmp_path / "x.bag")
    with pytest.raises(DataError, match="not a ROS bag"):
        RosbagDriver(tmp_path)


def _damage(path: Path, at: float, fill: int) -> None:
    """Overwrite 512 bytes at fraction `at` of the file with `fill` (a bad sector)."""
    data = bytearray(path.read_bytes())
    k = int(len(data) * at)
    data[k:k + 512] = bytes([fill]) * 512
    path.write_bytes(bytes(data))


def test_a_damaged_bag_keeps_what_precedes_the_damage(tmp_path: Path) -> None:
    imu_t, gyro, accel, cam_t, images = _synthetic()
    arrays = (imu_t, gyro, accel, cam_t, images)
    whole = bag_from_arrays(tmp_path / "whole.bag", "ros1", *arrays, chunk_bytes=4096)   # many chunks
    n_whole = len(list(RosbagDriver(whole).events()))
    bag = bag_from_arrays(tmp_path / "cut.bag", "ros1", *arrays, chunk_bytes=4096)
    _damage(bag, 0.6, 0x00)              # zeros: record headers unreadable, no value turned NaN
    drv = RosbagDriver(bag)
    events = list(drv.events())
    assert 0 < len(events) < n_whole                       # a prefix, in time order
    assert [e.t_ns for e in events] == sorted(e.t_ns for e in events)
    assert drv.damaged and "ReaderError" in drv.damaged
    assert any("the bag is damaged after" in n and "none after it" in n for n in drv.report()["notes"])
    with pytest.raises(DataError, match="the bag is damaged after"):
        RosbagDriver(bag, policy="strict")


def test_a_bag_damaged_before_its_first_message_says_so(tmp_path: Path) -> None:
    imu_t, gyro, accel, cam_t, images = _synthetic()
    bag = bag_from_arrays(tmp_path / "m", "mcap", imu_t, gyro, accel, cam_t, images)
    _damage(next(bag.glob("*.mcap")), 0.5, 0xFF)
    with pytest.raises(DataError, match="no usable IMU sample .*the bag is damaged after 0 messages"):
        RosbagDriver(bag)


def test_an_image_recorded_past_the_reorder_window_alone_is_skipped(tmp_path: Path) -> None:
    from drivers.rosbag import REORDER_WINDOW

    imu_t, gyro, accel, cam_t, images = _synthetic(n_imu=1000, n_cam=REORDER_WINDOW + 20)
    rec_t = cam_t.copy()
    rec_t[5] = cam_t[-1] + 1_000_000                    # image 5 reaches the recorder after all others
    rec_t[9] = cam_t[30]                                # image 9: late, but within the window
    bag = bag_from_arrays(tmp_path / "late", "sqlite3", imu_t, gyro, accel, cam_t, images, cam_record_t=rec_t)
    drv = RosbagDriver(bag)
    frames = _frames(drv)
    assert [f.t_ns for f in frames] == [int(t) for k, t in enumerate(cam_t) if k != 5]
    for f in frames:                                    # every other image is its own, none lost
        np.testing.assert_array_equal(f.image, images[int(np.flatnonzero(cam_t == f.t_ns)[0])])
    c = drv.report()["streams"]["cam0"]
    assert c["late_images"] == 1 and c["unreadable_images"] == 0
    assert c["parsed"] == c["emitted"] + c["late_images"]
    assert sum("recorded more than" in n for n in drv.report()["notes"]) == 1
    with pytest.raises(DataError, match="has stamp .* not after"):      # strict refuses any reordering
        RosbagDriver(bag, policy="strict")


def test_an_undecodable_image_does_not_shift_the_images_after_it(tmp_path: Path, monkeypatch) -> None:
    """Pass 1 left an undecodable image out of its stamps while the replay pass counted it: every later
    image was matched to its neighbour's keep flag and the last one fell off, uncounted."""
    from rosbags.highlevel import AnyReader

    imu_t, gyro, accel, cam_t, images = _synthetic()
    bag = bag_from_arrays(tmp_path / "b", "sqlite3", imu_t, gyro, accel, cam_t, images)
    decode = AnyReader.deserialize

    def corrupt_third(self, raw, msgtype):
        msg = decode(self, raw, msgtype)
        if msgtype.endswith("/Image") and _stamp(msg) == int(cam_t[3]):
            raise ValueError("corrupt CDR")
        return msg

    monkeypatch.setattr(AnyReader, "deserialize", corrupt_third)
    drv = RosbagDriver(bag)
    frames = _frames(drv)
    assert [f.t_ns for f in frames] == [int(t) for k, t in enumerate(cam_t) if k != 3]
    for f in frames:
        np.testing.assert_array_equal(f.image, images[int(np.flatnonzero(cam_t == f.t_ns)[0])])
    c = drv.report()["streams"]["cam0"]
    assert (c["malformed_lines"], c["parsed"], c["emitted"]) == (1, 9, 9)


def _stamp(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
