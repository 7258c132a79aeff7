"""Writing small ROS 1 / ROS 2 bags for the tests, with rosbags itself (the EuRoC / TUM-VI layout:
/cam0/image_raw sensor_msgs/Image, /imu0 sensor_msgs/Imu, header stamps = sensor stamps)."""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np


def _time(ts, t_ns: int):
    Time = ts.types["builtin_interfaces/msg/Time"]
    return Time(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def _header(ts, ros1: bool, t_ns: int, seq: int, frame: str):
    H = ts.types["std_msgs/msg/Header"]
    if ros1:
        return H(seq=seq, stamp=_time(ts, t_ns), frame_id=frame)
    return H(stamp=_time(ts, t_ns), frame_id=frame)


def imu_msg(ts, ros1: bool, t_ns: int, seq: int, gyro, accel):
    V = ts.types["geometry_msgs/msg/Vector3"]
    Q = ts.types["geometry_msgs/msg/Quaternion"]
    z9 = np.zeros(9)
    return ts.types["sensor_msgs/msg/Imu"](
        header=_header(ts, ros1, t_ns, seq, "imu4"), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0),
        orientation_covariance=z9, angular_velocity=V(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
        angular_velocity_covariance=z9,
        linear_acceleration=V(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
        linear_acceleration_covariance=z9)


def image_msg(ts, ros1: bool, t_ns: int, seq: int, image: np.ndarray, encoding: str = "mono8"):
    bpp = {"mono8": 1, "mono16": 2, "rgb8": 3, "bgr8": 3}[encoding]
    h, w = image.shape[:2]
    data = np.ascontiguousarray(image).view(np.uint8).reshape(-1)
    return ts.types["sensor_msgs/msg/Image"](header=_header(ts, ros1, t_ns, seq, "cam0"), height=h, width=w,
                                             encoding=encoding, is_bigendian=0, step=w * bpp, data=data)


def compressed_msg(ts, ros1: bool, t_ns: int, seq: int, image: np.ndarray):
    import cv2

    ok, buf = cv2.imencode(".png", image)
    assert ok
    return ts.types["sensor_msgs/msg/CompressedImage"](header=_header(ts, ros1, t_ns, seq, "cam0"),
                                                       format="png", data=buf.reshape(-1))


def write_bag(path: Path, fmt: str, messages: Iterable[tuple[str, int, object]],
              chunk_bytes: int | None = None) -> Path:
    """Write (topic, record_ns, msg) tuples. fmt: "ros1" (.bag), "mcap" or "sqlite3" (ROS 2 folder);
    `chunk_bytes`: a ROS 1 bag's chunk size (rosbags' default 1 MiB)."""
    from rosbags.typesys import Stores, get_typestore

    ros1 = fmt == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    conns: dict[str, object] = {}
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        if chunk_bytes is not None:
            writer.chunk_threshold = chunk_bytes
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
    with writer:
        for topic, t_rec, msg in messages:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
            raw = ts.serialize_ros1(msg, msg.__msgtype__) if ros1 else ts.serialize_cdr(msg, msg.__msgtype__)
            writer.write(conns[topic], int(t_rec), raw)
    return path


def typestore(fmt: str):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if fmt == "ros1" else Stores.ROS2_HUMBLE)


def bag_from_arrays(path: Path, fmt: str, imu_t, gyro, accel, cam_t, images, encoding: str = "mono8",
                    compressed: bool = False, imu_record_t=None, chunk_bytes: int | None = None,
                    cam_record_t=None) -> Path:
    """A bag with /imu0 and /cam0/image_raw, messages in record-time order (record time = header stamp,
    or `imu_record_t` / `cam_record_t`: a recorder that received messages late or out of order)."""
    ts = typestore(fmt)
    ros1 = fmt == "ros1"
    rec = imu_t if imu_record_t is None else imu_record_t
    msgs = [(int(rec[k]), 0, "/imu0", imu_msg(ts, ros1, int(t), k, gyro[k], accel[k]))
            for k, t in enumerate(imu_t)]
    topic = "/cam0/image_raw/compressed" if compressed else "/cam0/image_raw"
    cam_rec = cam_t if cam_record_t is None else cam_record_t
    for k, (t, img) in enumerate(zip(cam_t, images, strict=True)):
        m = compressed_msg(ts, ros1, int(t), k, img) if compressed else image_msg(ts, ros1, int(t), k, img,
                                                                                 encoding)
        msgs.append((int(cam_rec[k]), 1, topic, m))
    msgs.sort(key=lambda x: (x[0], x[1]))
    return write_bag(path, fmt, ((topic, t, m) for t, _, topic, m in msgs), chunk_bytes)
