"""Replay of EuRoC / ASL folders behind the driver interface.

Layout (sequence dir or its `mav0`): `imu0/data.csv` (t_ns, wx, wy, wz, ax, ay, az: gyro before
accel), `cam0/data.csv` (t_ns, filename) with images in `cam0/data/`, optional `cam1/`, optional
`state_groundtruth_estimate0/data.csv` (t_ns, p xyz, q wxyz Hamilton, v xyz, bg xyz, ba xyz), and
the `sensor.yaml` files. Stamps are int64 nanoseconds, parsed from the decimal strings.
Images are decoded lazily, only when their `Frame` is produced.
"""
from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drivers.base import Driver, IntakeReport, Policy, StreamCounts, check_policy
from drivers.diagnose import explain_unreadable
from drivers.euroc_files import (  # noqa: F401 - read_* and find_mav0 are this module's API too
    CAMERA_COLUMNS,
    IMAGE_SUFFIXES,
    IMU_COLUMNS,
    RATE_TOLERANCE,
    CaseInsensitiveNames,
    declared_rate_hz,
    find_mav0,
    read_camera_timestamps,
    read_euroc_groundtruth,
    read_euroc_imu_csv,
)
from drivers.images import BitDepthScaler
from drivers.validation import count_gaps, read_stamped_csv
from runtime.errors import DataError
from runtime.events import Frame, ImuSample
from runtime.file_kind import MISSING, file_problem
from runtime.geometry.trajectory import PoseTrajectory
from runtime.units import G_STANDARD, accel_looks_like_g, check_stamp_units

if TYPE_CHECKING:
    from calib import Rig

SIZE_MISMATCHES_FATAL = 5
"""With the calibrated size given, this many images of another size before any of the right size stop
the replay: the calibration belongs to another camera or resolution (a few odd images are skipped)."""


class EurocDriver(Driver):
    """Replay an EuRoC/ASL folder as merged, time-ordered `ImuSample` and `Frame` events.

    Args:
        path: the sequence folder or its `mav0`.
        camera: camera folder name(s) to replay ("cam0", or ("cam0", "cam1")); camera_id of a
            Frame is the index in this list.
        policy: "drop" (default: drop bad rows/images, count them in `report()`) or "strict"
            (raise DataError naming the file and line).
        groundtruth_file: file inside `state_groundtruth_estimate0/` used by `groundtruth()`
            (e.g. "full_sequence_vicon2gt.csv").
    """

    def __init__(self, path: str | Path, camera: str | Sequence[str] = "cam0", policy: Policy = "drop",
                 groundtruth_file: str = "data.csv") -> None:
        self.policy = check_policy(policy)
        self.mav0 = find_mav0(path)
        self.cameras = [camera] if isinstance(camera, str) else list(camera)
        self.groundtruth_file = groundtruth_file
        self._report = IntakeReport("euroc", str(self.mav0), self.policy)
        self._rig: Rig | None = None
        self._rig_loaded = False
        self._expected_shape: tuple[int, int] | None = None
        self._size_mismatches = self._size_matches = 0
        self._gt: PoseTrajectory | None = None
        self._gt_loaded = False
        self._closed = False

        imu_csv = self.mav0 / "imu0" / "data.csv"
        if (why := file_problem(imu_csv)) is not None:
            raise DataError("missing IMU file imu0/data.csv" if why == MISSING else f"imu0/data.csv {why}",
                            imu_csv)
        counts = self._report.stream("imu0")
        self._imu_t, self._gyro, self._accel = read_euroc_imu_csv(imu_csv, self.policy, counts, self._report)
        if self._imu_t.shape[0] == 0:
            raise DataError("no usable IMU sample: " + explain_unreadable(imu_csv, 6, IMU_COLUMNS, counts),
                            imu_csv)
        check_stamp_units(self._imu_t, "IMU", imu_csv)
        self._accel_units(imu_csv, counts)
        count_gaps(self._imu_t, counts)

        self._cam_t: list[np.ndarray] = []
        self._cam_files: list[list[Path]] = []
        self._cam_lines: list[np.ndarray] = []
        for name in self.cameras:
            self._load_camera(name)
        self._check_camera_rates()
        self._check_coverage()

    # -- reading -------------------------------------------------------------------------------
    def _accel_units(self, imu_csv: Path, counts: StreamCounts) -> None:
        """Convert an accelerometer recorded in g to m/s^2 (counted and noted; an error when strict)."""
        med = accel_looks_like_g(self._accel)
        if med is None:
            return
        what = (f"accelerometer values look like g, not m/s^2 (median |a| {med:.2f}; gravity is "
                f"{G_STANDARD} m/s^2)")
        if self.policy == "strict":
            raise DataError(f"{what}: multiply columns 5-7 by {G_STANDARD}", imu_csv)
        self._accel *= G_STANDARD
        counts.converted += int(self._accel.shape[0])
        self._report.note(f"imu0: {what}; converted to m/s^2 (x {G_STANDARD})")

    def _note_unlisted(self, name: str, listed: set[Path]) -> None:
        """Note the image files in `name`/data that no line of data.csv names, kept or not (a data.csv cut
        short by a crash, images copied in): they are never read."""
        folder = self.mav0 / name / "data"
        try:
            text = (self.mav0 / name / "data.csv").read_text(encoding="utf-8-sig", errors="replace")
        except OSError:
            return
        for line in text.splitlines():          # the rows the reader dropped name their images too
            fields = line.split(",")
            if len(fields) > 1 and not line.lstrip().startswith("#"):
                listed.add(Path(os.path.normpath(folder / fields[1].strip())))
        try:
            with os.scandir(folder) as entries:
                images = [Path(os.path.normpath(folder / e.name)) for e in entries
                          if e.name.lower().endswith(IMAGE_SUFFIXES) and e.is_file()]
        except OSError:
            return
        unlisted = sorted(p for p in images if p not in listed)
        if unlisted:
            self._report.note(f"{name}: {len(unlisted)} images in {name}/data are not listed in data.csv and "
                              f"are not read (the first: {unlisted[0].name}); is data.csv cut short?")

    def _load_camera(self, name: str) -> None:
        cam_dir = self.mav0 / name
        csv = cam_dir / "data.csv"
        if (why := file_problem(csv)) is not None:
            raise DataError(f"missing camera file {name}/data.csv" if why == MISSING
                            else f"{name}/data.csv {why}", csv)
        counts = self._report.stream(name)
        rows = read_stamped_csv(csv, 1, counts, self.policy, text=True, report=self._report)
        if rows.t_ns.shape[0] == 0:
            raise DataError("no usable frame: " + explain_unreadable(csv, 1, CAMERA_COLUMNS, counts), csv)
        files = [cam_dir / "data" / r[0] for r in rows.text]
        keep = np.ones(len(files), dtype=bool)
        first_listed: dict[Path, int] = {}
        by_case = CaseInsensitiveNames()
        case_fixed: list[tuple[str, str]] = []
        for i, f in enumerate(files):
            name_parts = Path(rows.text[i][0]).parts
            if Path(rows.text[i][0]).is_absolute() or ".." in name_parts:   # symlinked files are fine
                raise DataError(f"image file name {rows.text[i][0]!r} points outside {name}/data/",
                                csv, int(rows.line[i]))
            present = f.is_file()
            fixed = None
            if not present and (other := by_case.match(f)) is not None:
                # a folder written on a case-insensitive file system (Windows, macOS): the file is there
                if self.policy == "strict":
                    raise DataError(f"image file {rows.text[i][0]} does not exist; {other.name} does (the "
                                    "names differ in case)", csv, int(rows.line[i]))
                fixed, present = (rows.text[i][0], other.name), True
                f = files[i] = other
            earlier = first_listed.setdefault(Path(os.path.normpath(f)), i)
            if earlier != i:     # one picture at two times: the second would be a frame of no motion
                listed = rows.text[i][0]
                if self.policy == "strict":
                    raise DataError(f"image file {listed} is listed again (first on line "
                                    f"{int(rows.line[earlier])})", csv, int(rows.line[i]))
                if not counts.repeated_images:
                    self._report.note(f"{name}: image {listed} is listed at two stamps (line "
                                      f"{int(rows.line[earlier])}, and line {int(rows.line[i])} at the later "
                                      "stamp, skipped); every repeat is skipped at its later stamp (counted)")
                counts.repeated_images += 1
                keep[i] = False
                continue
            if not present:
                why = file_problem(f) or MISSING      # "does not exist", or what is there instead
                if self.policy == "strict":
                    raise DataError(f"image file {f} {why}", csv, int(rows.line[i]))
                if why != MISSING and not any("is not an image file" in n for n in self._report.notes):
                    self._report.note(f"{name}: {rows.text[i][0]} {why}: it is not an image file (counted "
                                      "with the missing images)")
                counts.missing_images += 1
                keep[i] = False
            elif fixed is not None:
                case_fixed.append(fixed)
        if case_fixed:
            self._report.note(f"{name}: {len(case_fixed)} image names in data.csv differ in case from their "
                              f"files (the first: {case_fixed[0][0]} is {case_fixed[0][1]}); the files were "
                              "read (policy strict refuses this)")
        self._note_unlisted(name, set(first_listed))
        if not keep.any():
            raise DataError(f"none of the {len(files)} images it lists exists in {cam_dir / 'data'} "
                            f"(first: {files[0].name})", csv)
        check_stamp_units(rows.t_ns, "camera", csv)
        t = rows.t_ns[keep]
        count_gaps(t, counts)
        self._cam_t.append(t)
        self._cam_files.append([f for f, k in zip(files, keep, strict=True) if k])
        self._cam_lines.append(rows.line[keep])

    def _check_camera_rates(self) -> None:
        """Note measured vs declared camera rates and unequal rates between the folder's cameras."""
        measured: dict[str, float] = {}
        for cam_dir in sorted(p for p in self.mav0.glob("cam*") if p.is_dir()):
            name = cam_dir.name
            if name in self.cameras:
                period = self._report.streams[name].median_period_ns
            else:
                try:
                    t = read_camera_timestamps(cam_dir / "data.csv")
                except DataError as exc:
                    if (cam_dir / "data.csv").exists():
                        self._report.note(f"{name} (not read): its rate is not compared ({exc})")
                    continue
                period = int(np.median(np.diff(t))) if t.shape[0] > 2 else 0
            if period <= 0:
                continue
            rate = 1e9 / period
            measured[name] = rate
            declared = declared_rate_hz(cam_dir / "sensor.yaml")
            if declared and abs(rate - declared) > RATE_TOLERANCE * declared:
                self._report.note(f"{name}: measured rate {rate:.2f} Hz differs from sensor.yaml "
                                  f"rate_hz {declared:g}")
        if len(measured) > 1:
            lo, hi = min(measured.values()), max(measured.values())
            if hi - lo > RATE_TOLERANCE * hi:
                rates = ", ".join(f"{k} {v:.2f} Hz" for k, v in measured.items())
                self._report.note(f"unequal camera rates: {rates}")
        self.camera_rates_hz = measured

    def _check_coverage(self) -> None:
        """Note the IMU rate against imu0/sensor.yaml and frames outside the IMU's time span."""
        period = self._report.streams["imu0"].median_period_ns
        declared = declared_rate_hz(self.mav0 / "imu0" / "sensor.yaml")
        if period > 0 and declared and abs(1e9 / period - declared) > RATE_TOLERANCE * declared:
            self._report.note(f"imu0: measured rate {1e9 / period:.2f} Hz differs from sensor.yaml "
                              f"rate_hz {declared:g}")
        for name, t in zip(self.cameras, self._cam_t, strict=True):
            if self._imu_t.size == 0:
                self._report.note(f"{name}: no IMU samples at all")
                continue
            outside = int(np.sum((t < self._imu_t[0]) | (t > self._imu_t[-1])))
            if outside:
                self._report.note(f"{name}: {outside} frames lie outside the IMU time span")

    def expect_image_size(self, width: int, height: int) -> None:
        """The first camera's images must be width x height (the calibration the run uses): one of another
        size is unreadable (counted; an error when strict) wherever it lies in the stream. Without it the
        stream's first image sets the size."""
        self._expected_shape = (int(height), int(width))

    def _image(self, cam: int, i: int) -> np.ndarray | None:
        """Decode one grey image; None (counted) or DataError (strict) when it cannot be read."""
        import cv2

        path = self._cam_files[cam][i]
        name = self.cameras[cam]
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
        reason = None
        if image is None:
            reason = "cannot be decoded as an image" if path.is_file() else "disappeared"
        else:
            if image.dtype == np.uint16 and image.ndim == 2:
                image = self._to_8bit(cam, image, path, i)
            if image.dtype != np.uint8 or image.ndim != 2:
                reason = f"decodes to {image.dtype} {image.shape}, expected an 8- or 16-bit grey image"
            elif cam == 0 and self._expected_shape is not None:
                if image.shape != self._expected_shape:
                    reason = (f"is {image.shape[1]}x{image.shape[0]}, the camera calibration "
                              f"{self._expected_shape[1]}x{self._expected_shape[0]}")
                    self._size_mismatches += 1
                    if self._size_mismatches == 1:
                        self._report.note(f"{name}: image {path.name} {reason}: skipped (so is every image "
                                          "of another size)")
                    if self._size_mismatches == SIZE_MISMATCHES_FATAL and not self._size_matches:
                        raise DataError(f"the first {SIZE_MISMATCHES_FATAL} images are "
                                        f"{image.shape[1]}x{image.shape[0]} but the camera calibration is "
                                        f"{self._expected_shape[1]}x{self._expected_shape[0]}: is --rig the "
                                        "calibration of this camera, at this resolution?",
                                        self.mav0 / name / "data.csv")
                else:
                    self._size_matches += 1
            else:
                first = self._first_shape.setdefault(cam, image.shape)
                if image.shape != first:
                    reason = f"size {image.shape[::-1]} differs from the stream's {first[::-1]}"
        if reason is None:
            return image
        if self.policy == "strict":
            raise DataError(f"image {path.name} {reason}", self.mav0 / name / "data.csv",
                            int(self._cam_lines[cam][i]))
        self._report.stream(name).unreadable_images += 1
        return None

    def _to_8bit(self, cam: int, image: np.ndarray, path: Path, i: int) -> np.ndarray:
        """A 16-bit grey image scaled to 8 bits by the stream's bit depth (set by its first image, raised by
        a later one holding larger values: drivers.images), counted and noted; an error when strict."""
        name = self.cameras[cam]
        scaler = self._bit_depth.setdefault(cam, BitDepthScaler())
        bits = scaler.bits
        out = scaler.convert(image)
        if bits is None:
            what = (f"{name}: 16-bit images holding {scaler.bits}-bit data (first image's maximum "
                    f"{scaler.first_peak})")
            if self.policy == "strict":
                raise DataError(f"image {path.name}: {what}; convert the images to 8-bit grey",
                                self.mav0 / name / "data.csv", int(self._cam_lines[cam][i]))
            self._report.note(f"{what}: scaled to 8 bits (>> {scaler.bits - 8})")
        elif scaler.bits != bits:
            self._report.note(scaler.raise_note(name, f"image {path.name}"))
        self._report.stream(name).converted += 1
        return out

    # -- Driver interface ----------------------------------------------------------------------
    @property
    def rig(self) -> Rig | None:
        """The rig from the folder's sensor.yaml files (`calib.read_euroc_rig`).

        None when the camera's sensor.yaml is absent (calibration withheld); a malformed file raises
        CalibrationError.
        """
        if not self._rig_loaded:
            yaml = self.mav0 / self.cameras[0] / "sensor.yaml"
            if (why := file_problem(yaml)) not in (None, MISSING):
                from runtime.errors import CalibrationError

                raise CalibrationError(why, yaml, None)
            if why == MISSING:
                self._report.note(f"{self.cameras[0]}/sensor.yaml is absent: rig calibration unknown")
            else:
                from calib import read_euroc_rig

                self._rig = read_euroc_rig(self.mav0, camera=self.cameras[0])
            self._rig_loaded = True
        return self._rig

    @property
    def n_imu(self) -> int:
        """IMU samples kept after validation."""
        return int(self._imu_t.shape[0])

    def frame_stamps(self, cam: int = 0) -> np.ndarray:
        """(N,) int64 stamps of the frames of camera `cam` whose image file exists."""
        return self._cam_t[cam].copy()

    def imu_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Copies of (t_ns, gyro, accel) of the validated IMU stream."""
        return self._imu_t.copy(), self._gyro.copy(), self._accel.copy()

    def events(self) -> Iterator[ImuSample | Frame]:
        """IMU samples and frames merged by t_ns; at equal stamps IMU first, then cameras in order."""
        if self._closed:
            raise DataError("driver is closed", self.mav0)
        self._first_shape: dict[int, tuple[int, ...]] = {}
        self._size_mismatches = self._size_matches = 0
        self._bit_depth: dict[int, BitDepthScaler] = {}
        for name in self.cameras:
            self._report.stream(name).converted = 0
            self._report.stream(name).emitted = 0
            self._report.stream(name).unreadable_images = 0
        self._report.stream("imu0").emitted = 0
        # one sorted key list: (stamp, source order) with IMU = -1 before cameras 0..k
        n_imu = self._imu_t.shape[0]
        stamps = [self._imu_t] + self._cam_t
        source = [np.full(n_imu, -1, np.int64)] + [np.full(t.shape[0], c, np.int64)
                                                    for c, t in enumerate(self._cam_t)]
        index = [np.arange(n_imu)] + [np.arange(t.shape[0]) for t in self._cam_t]
        t_all = np.concatenate(stamps)
        s_all = np.concatenate(source)
        i_all = np.concatenate(index)
        order = np.lexsort((s_all, t_all))
        imu_counts = self._report.stream("imu0")
        for k in order:
            src = int(s_all[k])
            i = int(i_all[k])
            if src < 0:
                imu_counts.emitted += 1
                yield ImuSample(int(self._imu_t[i]), self._gyro[i].copy(), self._accel[i].copy())
            else:
                image = self._image(src, i)
                if image is None:
                    continue
                self._report.stream(self.cameras[src]).emitted += 1
                yield Frame(int(self._cam_t[src][i]), image, src,
                            meta={"file": str(self._cam_files[src][i])})

    def groundtruth(self) -> PoseTrajectory | None:
        """Ground truth T_WI with v, bg, ba from `state_groundtruth_estimate0/<groundtruth_file>`."""
        if not self._gt_loaded:
            path = self.mav0 / "state_groundtruth_estimate0" / self.groundtruth_file
            if path.is_file():
                counts = self._report.stream("groundtruth")
                self._gt = read_euroc_groundtruth(path, self.policy, counts)
                counts.emitted = len(self._gt)
            self._gt_loaded = True
        return self._gt

    def report(self) -> dict:
        """Intake counters per stream ("imu0", "cam0", "groundtruth") and notes."""
        return self._report.as_dict()

    @property
    def intake(self) -> IntakeReport:
        """The live IntakeReport (its `summary()` is a readable text)."""
        return self._report

    def close(self) -> None:
        """Mark the driver closed (the arrays are in memory; no file stays open)."""
        super().close()
