"""ROS 1 and ROS 2 bag replay without ROS, through the rosbags package (pure Python).

Reads `.bag` (ROS 1) files and ROS 2 bags (a folder with metadata.yaml, sqlite3 or mcap storage, or the
`.db3` / `.mcap` file inside one): `sensor_msgs/Image` (mono8, mono16, 8-bit colour; 16-bit data scaled
by the stream's bit depth as the EuRoC driver does), `sensor_msgs/CompressedImage` and `sensor_msgs/Imu`,
stamped by their header (never the record time). Topics are auto-detected (one Imu topic; the image topic
named like cam0 / left, or the only one) or chosen. The rig comes from `--rig FILE` (anything
`calib.load_rig` reads); without it, a `sensor_msgs/CameraInfo` on the image topic's namespace gives the
intrinsics (plumb_bob or equidistant) with the camera-IMU extrinsics withheld.

Stamps and IMU values pass the same validation as the EuRoC CSVs: non-finite samples dropped, duplicates
dropped, out-of-order messages sorted into place (all counted); `policy="strict"` makes each an error.
A bag damaged part-way (a chunk or page that cannot be parsed) is read up to the damage, with a note.
"""
from __future__ import annotations

import contextlib
import heapq
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drivers.base import Driver, IntakeReport, Policy, StreamCounts, check_policy
from drivers.diagnose import check_distinct_stamps
from drivers.images import BitDepthScaler
from drivers.validation import count_gaps, time_order_repair
from runtime.errors import ConfigError, DataError
from runtime.events import Frame, ImuSample
from runtime.units import G_STANDARD, accel_looks_like_g, check_stamp_units

if TYPE_CHECKING:
    from calib import Rig

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
IMU_TYPE = "sensor_msgs/msg/Imu"
CAMERA_INFO_TYPE = "sensor_msgs/msg/CameraInfo"
PREFERRED_IMAGE_NAMES = ("cam0", "left", "infra1", "image_raw")
"""Tie-break for bags with several image topics (EuRoC and TUM-VI: /cam0/image_raw, /cam1/image_raw)."""
REORDER_WINDOW = 64
"""Images held back at most while waiting for an earlier-stamped one recorded later."""


def is_bag(path: str | Path) -> bool:
    """True for a ROS 1 `.bag`, a ROS 2 bag folder (metadata.yaml) or its `.db3` / `.mcap` file."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    return p.suffix in (".bag", ".db3", ".mcap") and p.is_file()


def _stamp_ns(msg: Any) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


class RosbagDriver(Driver):
    """Replay a ROS bag as merged, time-ordered `ImuSample` and `Frame` events.

    Args:
        path: a `.bag` file, a ROS 2 bag folder, or the `.db3` / `.mcap` file inside one.
        rig: the calibration (e.g. `calib.load_rig(FILE)`); None reads a CameraInfo from the bag if there
            is one, else the rig stays unknown.
        image_topic, imu_topic: the topics to read (None: auto-detected; ConfigError when ambiguous).
        policy: "drop" (count and skip bad messages) or "strict" (DataError).
    """

    def __init__(self, path: str | Path, rig: Rig | None = None, image_topic: str | None = None,
                 imu_topic: str | None = None, policy: Policy = "drop") -> None:
        self.policy = check_policy(policy)
        self.path = Path(path)
        if not is_bag(self.path):
            raise DataError("not a ROS bag (a .bag file, a ROS 2 bag folder with metadata.yaml, or its "
                            ".db3 / .mcap file)", self.path)
        self._bag_path = self.path.parent if self.path.is_file() and self.path.suffix != ".bag" else self.path
        self._report = IntakeReport("rosbag", str(self.path), self.policy)
        self._closed = False
        self.damaged: str | None = None
        """Why the bag could not be read past some message (noted; what came before is used), or None."""
        with self._reader() as reader:
            types = {c.topic: c.msgtype for c in reader.connections}
            self.image_topic = self._choose(types, image_topic, IMAGE_TYPES, "image", "--image-topic")
            self.imu_topic = self._choose(types, imu_topic, (IMU_TYPE,), "IMU", "--imu-topic")
            self._image_type = types[self.image_topic]
            self._read_imu_and_stamps(reader)
            self._rig = rig if rig is not None else self._camera_info_rig(reader, types)

    # -- opening -----------------------------------------------------------------------------
    @contextlib.contextmanager
    def _reader(self) -> Iterator[Any]:
        """An open rosbags AnyReader (ROS 2 Humble message definitions for bags that lack them)."""
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        try:
            reader = AnyReader([self._bag_path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises its own types for every format error
            raise DataError(f"cannot read the bag: {type(exc).__name__}: {exc}", self.path) from exc
        try:
            yield reader
        finally:
            reader.close()

    def _messages(self, reader: Any, conns: list) -> Iterator[tuple[Any, int, bytes]]:
        """`reader.messages(connections=conns)` ending where the bag is damaged (a chunk or page that
        cannot be parsed): what came before is kept and the damage noted once (DataError when strict)."""
        it = reader.messages(connections=conns)
        n = 0
        while True:
            try:
                item = next(it)
            except StopIteration:
                return
            except Exception as exc:  # noqa: BLE001 - rosbags and its storage layers raise their own types
                why = f"{type(exc).__name__}: {' '.join(str(exc).split())[:200]}"
                if self.policy == "strict":
                    raise DataError(f"the bag is damaged after {n} messages ({why})", self.path) from exc
                if not self.damaged:
                    self.damaged = f"the bag is damaged after {n} messages of the topics read ({why})"
                    self._report.note(f"{self.damaged}: the data before the damage is used, none after it")
                return
            n += 1
            yield item

    def _choose(self, types: dict[str, str], wanted: str | None, msgtypes: tuple[str, ...], what: str,
                flag: str) -> str:
        found = sorted(t for t, m in types.items() if m in msgtypes)
        if wanted is not None:
            if wanted not in types:
                raise ConfigError(f"{self.path}: no topic {wanted!r}; {what} topics: "
                                  f"{', '.join(found) or 'none'}")
            if types[wanted] not in msgtypes:
                raise ConfigError(f"{self.path}: topic {wanted!r} holds {types[wanted]}, not "
                                  f"{' or '.join(msgtypes)}")
            return wanted
        if not found:
            listing = ", ".join(f"{t} ({m})" for t, m in sorted(types.items())) or "none"
            raise DataError(f"no {what} topic ({' or '.join(msgtypes)}); topics: {listing}", self.path)
        if len(found) == 1:
            return found[0]
        for name in PREFERRED_IMAGE_NAMES if what == "image" else ():
            named = [t for t in found if name in t.split("/")]
            if len(named) == 1:
                self._report.note(f"{len(found)} image topics ({', '.join(found)}): reading {named[0]} "
                                  f"(choose with {flag})")
                return named[0]
        raise ConfigError(f"{self.path}: several {what} topics ({', '.join(found)}); choose one with {flag}")

    def _read_imu_and_stamps(self, reader: Any) -> None:
        """Pass 1: every IMU sample (validated, in memory) and every image's header stamp."""
        conns = [c for c in reader.connections if c.topic in (self.imu_topic, self.image_topic)]
        imu_counts = self._report.stream("imu0")
        cam_counts = self._report.stream("cam0")
        imu_t: list[int] = []
        imu_v: list[tuple[float, ...]] = []
        cam_t: list[int] = []
        cam_ordinal: list[int] = []         # each decoded image's place among the topic's messages
        n_images = 0
        for conn, _, raw in self._messages(reader, conns):
            if conn.topic == self.image_topic:
                n_images += 1
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:  # noqa: BLE001 - a corrupt message is counted, not fatal
                counts = imu_counts if conn.topic == self.imu_topic else cam_counts
                counts.lines += 1
                self._reject(counts, "malformed_lines", f"{conn.topic}: undecodable message ({exc})")
                continue
            if conn.topic == self.imu_topic:
                imu_counts.lines += 1
                w, a = msg.angular_velocity, msg.linear_acceleration
                v = (w.x, w.y, w.z, a.x, a.y, a.z)
                if not all(np.isfinite(v)):
                    self._reject(imu_counts, "dropped_nonfinite",
                                 f"{self.imu_topic}: NaN or Inf at {_stamp_ns(msg)}")
                    continue
                imu_t.append(_stamp_ns(msg))
                imu_v.append(v)
            else:
                cam_counts.lines += 1
                cam_t.append(_stamp_ns(msg))
                cam_ordinal.append(n_images - 1)
        t = np.array(imu_t, np.int64)
        v = np.array(imu_v, np.float64).reshape(-1, 6)
        check_distinct_stamps(t, self.imu_topic, self.path)
        t, v, _ = self._order(t, v, imu_counts, self.imu_topic)
        if t.shape[0] == 0:
            raise DataError(f"no usable IMU sample on {self.imu_topic} ({imu_counts.lines} messages)"
                            + (f": {self.damaged}" if self.damaged else ""), self.path)
        check_stamp_units(t, "IMU", self.path)
        self._imu_t, self._gyro, self._accel = t, v[:, :3].copy(), v[:, 3:].copy()
        med = accel_looks_like_g(self._accel)
        if med is not None:
            what = f"accelerometer values look like g, not m/s^2 (median |a| {med:.2f})"
            if self.policy == "strict":
                raise DataError(f"{self.imu_topic}: {what}", self.path)
            self._accel *= G_STANDARD
            imu_counts.converted += int(t.shape[0])
            self._report.note(f"imu0: {what}; converted to m/s^2 (x {G_STANDARD})")
        count_gaps(self._imu_t, imu_counts)
        # images: bag order -> kept, time-ordered stamps (the replay pass re-reads them in bag order)
        c = np.array(cam_t, np.int64)
        check_distinct_stamps(c, self.image_topic, self.path)
        keep_t, _, kept_index = self._order(c, np.zeros((c.shape[0], 0)), cam_counts, self.image_topic)
        if keep_t.shape[0] == 0:
            raise DataError(f"no image on {self.image_topic} ({cam_counts.lines} messages)"
                            + (f": {self.damaged}" if self.damaged else ""), self.path)
        check_stamp_units(keep_t, "camera", self.path)
        count_gaps(keep_t, cam_counts)
        self._cam_t = keep_t
        self._cam_keep = np.zeros(n_images, bool)       # by the place the replay pass counts
        self._cam_keep[np.asarray(cam_ordinal, np.int64)[kept_index]] = True

    def _order(self, t: np.ndarray, v: np.ndarray, counts: StreamCounts,
               topic: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stamps made strictly increasing as for CSV files; returns (t, values, kept message indices)."""
        index = np.arange(t.shape[0])
        if t.shape[0] and np.any(np.diff(t) <= 0):
            if self.policy == "strict":
                k = int(np.flatnonzero(np.diff(t) <= 0)[0]) + 1
                raise DataError(f"{topic}: message {k} has stamp {t[k]} not after {t[k - 1]}", self.path)
            order, moved, dup, isolated = time_order_repair(t)
            counts.dropped_duplicate += int(dup.sum())
            counts.dropped_nonmonotonic += int(isolated.sum())
            counts.reordered += int(moved.sum())
            index = order[~(dup | isolated)[order]]
        counts.parsed += int(index.shape[0])
        return t[index], v[index], index

    def _reject(self, counts: StreamCounts, counter: str, why: str) -> None:
        setattr(counts, counter, getattr(counts, counter) + 1)
        if self.policy == "strict":
            raise DataError(why, self.path)

    def _camera_info_rig(self, reader: Any, types: dict[str, str]) -> Rig | None:
        """A rig with the intrinsics of the CameraInfo beside the image topic (extrinsics withheld)."""
        from calib import Rig
        from calib.camera import camera_class
        from runtime.errors import CalibrationError

        # beside the image topic, or one level up for image_transport's /cam/image_raw/compressed
        spaces = [self.image_topic.rsplit("/", 1)[0]]
        if self.image_topic.endswith(("/compressed", "/compressedDepth", "/theora")):
            spaces.append(spaces[0].rsplit("/", 1)[0])
        infos = [t for ns in spaces for t, m in sorted(types.items())
                 if m == CAMERA_INFO_TYPE and t.rsplit("/", 1)[0] == ns]
        if not infos:
            self._report.note(f"no --rig and no CameraInfo beside {self.image_topic}: calibration unknown")
            return None
        conn = next(c for c in reader.connections if c.topic == infos[0])
        for _, _, raw in self._messages(reader, [conn]):
            try:
                info = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:  # noqa: BLE001 - rosbags raises its own types for a corrupt message
                raise DataError(f"{infos[0]}: undecodable CameraInfo ({type(exc).__name__}); give the "
                                "calibration with --rig", self.path) from exc
            # ROS 2 names the fields k, d (and r, p); ROS 1 K, D
            K = np.asarray(getattr(info, "k", None) if hasattr(info, "k") else info.K, float).reshape(3, 3)
            d = [float(x) for x in (info.d if hasattr(info, "d") else info.D)]
            model = info.distortion_model or "none"
            if model == "plumb_bob" and len(d) == 5 and d[4] == 0.0:
                d = d[:4]
            if model == "rational_polynomial" and len(d) > 8 and not any(d[8:]):
                d = d[:8]                         # 14 coefficients with no thin-prism or tilt terms
            try:
                cam = camera_class(model if any(d) else "none")(
                    info.width, info.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2], d if any(d) else ())
            except CalibrationError as exc:
                raise DataError(f"{infos[0]}: unusable CameraInfo ({exc}); give the calibration with --rig",
                                self.path) from exc
            self._report.note(f"intrinsics from {infos[0]} ({model}); camera-IMU extrinsics withheld")
            return Rig(camera=cam, name=f"{self.path.name}:{infos[0]}")
        return None

    # -- decoding ------------------------------------------------------------------------------
    def _image(self, msg: Any, t_ns: int) -> np.ndarray | None:
        """A uint8 grey image from an Image or CompressedImage message; None (counted) when unusable."""
        import cv2

        counts = self._report.stream("cam0")
        why = None
        try:
            if self._image_type.endswith("CompressedImage"):
                img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8),
                                   cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
                if img is None:
                    why = f"compressed image ({msg.format}) cannot be decoded"
            else:
                img, why = _raw_image(msg)
        except (ValueError, cv2.error) as exc:
            img, why = None, f"malformed image ({exc})"
        if img is not None and img.dtype == np.uint16:
            img = self._to_8bit(img, t_ns)
        if img is not None and self._rig is not None and self._rig.camera is not None:
            cam = self._rig.camera
            if img.shape != (cam.height, cam.width):
                why = (f"size {img.shape[1]}x{img.shape[0]} differs from the calibration's "
                       f"{cam.width}x{cam.height}")
        if why is None:
            return img
        if self.policy == "strict":
            raise DataError(f"{self.image_topic} at {t_ns}: {why}", self.path)
        counts.unreadable_images += 1
        self._report.note(f"{self.image_topic}: {why}")
        return None

    def _to_8bit(self, img: np.ndarray, t_ns: int) -> np.ndarray:
        """By the stream's bit depth: set by its first image, raised by a later one (drivers.images)."""
        bits = self._bits.bits
        out = self._bits.convert(img)
        if bits is None:
            what = f"cam0: 16-bit images holding {self._bits.bits}-bit data"
            if self.policy == "strict":
                raise DataError(f"{self.image_topic}: {what}; convert to 8-bit grey", self.path)
            self._report.note(f"{what} (first image's maximum {self._bits.first_peak}): scaled to 8 bits "
                              f"(>> {self._bits.bits - 8})")
        elif self._bits.bits != bits:
            self._report.note(self._bits.raise_note("cam0", f"the image at {t_ns} ns"))
        self._report.stream("cam0").converted += 1
        return out

    # -- Driver interface --------------------------------------------------------------------
    @property
    def rig(self) -> Rig | None:
        """The rig given, or the one from the bag's CameraInfo, or None."""
        return self._rig

    def imu_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of (t_ns, gyro, accel) of the validated IMU stream."""
        return self._imu_t.copy(), self._gyro.copy(), self._accel.copy()

    def events(self) -> Iterator[ImuSample | Frame]:
        """IMU samples and frames merged by header stamp; at equal stamps the IMU sample first."""
        if self._closed:
            raise DataError("driver is closed", self.path)
        self._bits = BitDepthScaler()
        cam = self._report.stream("cam0")
        cam.emitted = cam.unreadable_images = cam.converted = cam.late_images = 0
        self._report.stream("imu0").emitted = 0
        imu_i = 0
        for t, image in self._frames_in_time_order():
            while imu_i < self._imu_t.shape[0] and self._imu_t[imu_i] <= t:
                yield self._imu_event(imu_i)
                imu_i += 1
            if image is not None:
                cam.emitted += 1
                yield Frame(int(t), image, 0, meta={"topic": self.image_topic})
        while imu_i < self._imu_t.shape[0]:
            yield self._imu_event(imu_i)
            imu_i += 1

    def _imu_event(self, i: int) -> ImuSample:
        self._report.stream("imu0").emitted += 1
        return ImuSample(int(self._imu_t[i]), self._gyro[i].copy(), self._accel[i].copy())

    def _frames_in_time_order(self) -> Iterator[tuple[int, np.ndarray | None]]:
        """(stamp, image or None) of the kept images in stamp order, read in bag order through a small
        reorder buffer: an image that has not come when REORDER_WINDOW later-stamped ones wait behind it
        is counted (`late_images`) and skipped, and so is its message when it comes."""
        expected = iter(self._cam_t.tolist())
        counts = self._report.stream("cam0")
        nxt = next(expected, None)
        heap: list[tuple[int, int, np.ndarray | None]] = []

        def ready(window: int) -> Iterator[tuple[int, np.ndarray | None]]:
            nonlocal nxt
            while heap and nxt is not None:
                if heap[0][0] < nxt:              # its place was passed: given up on, counted then
                    heapq.heappop(heap)
                elif heap[0][0] == nxt:
                    t0, _, img = heapq.heappop(heap)
                    yield t0, img
                    nxt = next(expected, None)
                elif len(heap) > window:          # `nxt` has not come within the window: recorded late
                    if not counts.late_images:
                        self._report.note(f"{self.image_topic}: images recorded more than {REORDER_WINDOW} "
                                          f"images after their place in time are skipped (late_images; the "
                                          f"first stamped {nxt})")
                    counts.late_images += 1
                    nxt = next(expected, None)
                else:
                    return

        with self._reader() as reader:
            conns = [c for c in reader.connections if c.topic == self.image_topic]
            k = -1
            for conn, _, raw in self._messages(reader, conns):
                k += 1
                if k >= self._cam_keep.shape[0] or not self._cam_keep[k]:
                    continue
                try:
                    msg = reader.deserialize(raw, conn.msgtype)
                except Exception:  # noqa: BLE001 - counted in pass 1 already
                    continue
                t = _stamp_ns(msg)
                if nxt is not None and t < nxt:    # an image given up on comes at last: skipped
                    continue
                heapq.heappush(heap, (t, k, self._image(msg, t)))
                yield from ready(REORDER_WINDOW)
        yield from ready(0)
        missing = 0 if nxt is None else 1 + sum(1 for _ in expected)
        if missing:            # read the first time, not the second (the bag changed, or its damage moved)
            counts.unreadable_images += missing
            self._report.note(f"{self.image_topic}: {missing} images read on the first pass did not come on "
                              "the second (counted as unreadable)")

    def groundtruth(self) -> None:
        """Bags carry no ground truth DAVIO reads."""
        return None

    def report(self) -> dict:
        """Intake counters ("imu0", "cam0") and notes (topics chosen, conversions)."""
        d = self._report.as_dict()
        d["topics"] = {"image": self.image_topic, "imu": self.imu_topic}
        return d


def _raw_image(msg: Any) -> tuple[np.ndarray | None, str | None]:
    """A grey image (uint8 or uint16) from a sensor_msgs/Image, or (None, reason)."""
    import cv2

    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data), np.uint8)
    channels = {"mono8": 1, "8uc1": 1, "mono16": 2, "16uc1": 2, "rgb8": 3, "bgr8": 3, "rgba8": 4, "bgra8": 4}
    if enc not in channels:
        return None, f"unsupported encoding {msg.encoding!r} (mono8, mono16, rgb8, bgr8, rgba8, bgra8)"
    bpp = channels[enc]
    if h <= 0 or w <= 0 or step < w * bpp or data.shape[0] < h * step:
        return None, f"{len(data)} bytes do not hold {h}x{w} {enc} with step {step}"
    rows = data[:h * step].reshape(h, step)[:, :w * bpp]
    if bpp == 1:
        return rows.copy(), None
    if enc in ("mono16", "16uc1"):
        dt = np.dtype(">u2" if msg.is_bigendian else "<u2")
        return rows.copy().view(dt).reshape(h, w).astype(np.uint16), None
    img = rows.reshape(h, w, bpp)
    code = {"rgb8": cv2.COLOR_RGB2GRAY, "bgr8": cv2.COLOR_BGR2GRAY, "rgba8": cv2.COLOR_RGBA2GRAY,
            "bgra8": cv2.COLOR_BGRA2GRAY}[enc]
    return cv2.cvtColor(np.ascontiguousarray(img), code), None
