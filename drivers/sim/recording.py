"""Simulated camera-IMU recordings, usable in memory as a Driver (frames rendered lazily).

Three ways to make one:
  SimRecording.from_preset(SimConfig(...))        motion preset spline + synthetic IMU
  SimRecording.from_trajectory(path)              spline fitted to a trajectory file + synthetic IMU
  SimRecording.from_trajectory(path, imu_path=…)  the real IMU replayed against its real ground
                                                   truth (the EuRoC-trajectory mode), images rendered
                                                   along the interpolated ground truth
  SimRecording.from_euroc_imu_gt(folder)           the same for a shared/data/euroc_imu_gt folder

Clocks: IMU stamps are the true time. A frame stamped t_cam (camera clock) shows the scene at
t_cam + time_offset (t_imu = t_cam + time_offset_s, Kalibr's timeshift_cam_imu).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from drivers.base import Driver, IntakeReport
from drivers.euroc import read_camera_timestamps, read_euroc_imu_csv
from drivers.sim.groundtruth import GroundTruthSource
from drivers.sim.imu_consistent import DEFAULT_SMOOTHING_S, imu_consistent_groundtruth
from drivers.sim.imu_synth import (
    IMU_PROFILES,
    ImuErrorModel,
    ImuStream,
    imu_errors_for,
    imu_stamps,
    synthesize_imu,
)
from drivers.sim.motion import DEFAULT_PRESET, preset_spline
from drivers.sim.render import ImageOptions, Renderer, View
from drivers.sim.rig import euroc_default_rig
from drivers.sim.sampled_motion import SampledMotion
from drivers.sim.scene import Scene, build_scene
from drivers.sim.spline import PoseSpline, fit_pose_spline
from drivers.sim.timeline import (
    crop_trajectory,
    frame_times,
    scene_positions,
    trajectory_gap_notes,
    trajectory_positions,
)
from drivers.trajectory_files import read_trajectory
from runtime.errors import ConfigError, DataError
from runtime.events import Frame, ImuSample
from runtime.geometry.trajectory import PoseTrajectory

if TYPE_CHECKING:
    from calib import Rig



@dataclass(frozen=True)
class SimConfig:
    """How to simulate a recording.

    Attributes:
        preset: motion preset name (drivers.sim.motion.PRESETS); ignored when replaying a trajectory.
        seconds: duration, s (None = the whole trajectory when replaying one).
        seed: seed of the motion, scene, IMU noise and image noise.
        style: scene style, "room" or "hall".
        imu_rate_hz: synthetic IMU rate, Hz.
        camera_rate_hz: camera rate, Hz (None = the rig's, 20 Hz for EuRoC).
        time_offset_s: camera-to-IMU clock offset applied to the frame stamps (t_imu = t_cam + offset).
        imu_errors: synthetic IMU noise and biases (None = `imu_profile` for the rig's noise densities).
        imu_profile: when imu_errors is None, the synthetic IMU's error model (drivers.sim.imu_synth.
            IMU_PROFILES): "datasheet" (white noise and bias random walk at the rig's densities) or
            "euroc-measured" (those plus the slowly varying errors measured on the real EuRoC IMU in
            flight: ImuErrorModel.euroc_measured). Not used when a real IMU is replayed.
        image: image-formation options.
        start_s: when replaying a trajectory, seconds skipped at its start.
        groundtruth_mode: when replaying a real IMU, what the images are rendered from: "imu-consistent"
            (the ground truth without its position jumps, its attitude from the bias-corrected gyro held to
            the ground truth's over attitude_smoothing_s: images and IMU agree as on a real rig) or
            "as-recorded" (the ground truth as is, whose jumps and attitude spells move the images where the
            IMU does not; the behaviour before 2026-11-26). drivers.sim.imu_consistent.
        attitude_smoothing_s: see groundtruth_mode, s.
        scene_span: what the scene is built around (trajectory modes): "recording" (the rendered part,
            the default) or "trajectory" (the whole trajectory file before --start/--seconds cut it, so
            that recordings cut from one file at different starts share one scene: sessions of one
            place, e.g. for `davio map align`).
    """

    preset: str = DEFAULT_PRESET
    seconds: float | None = 20.0
    seed: int = 0
    style: str = "room"
    imu_rate_hz: float = 200.0
    camera_rate_hz: float | None = None
    time_offset_s: float = 0.0
    imu_errors: ImuErrorModel | None = None
    imu_profile: str = "datasheet"
    image: ImageOptions = field(default_factory=ImageOptions)
    start_s: float = 0.0
    groundtruth_mode: str = "imu-consistent"
    attitude_smoothing_s: float = DEFAULT_SMOOTHING_S
    scene_span: str = "recording"

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, numbers.Integral) \
                or not 0 <= self.seed < MAX_SEED:
            raise ConfigError(f"seed must be an integer from 0 to {MAX_SEED - 1}, got {self.seed!r}")
        if self.imu_profile not in IMU_PROFILES:
            raise ConfigError(f"SimConfig.imu_profile must be one of {IMU_PROFILES}, "
                              f"got {self.imu_profile!r}")
        if self.groundtruth_mode not in GROUNDTRUTH_MODES:
            raise ConfigError(f"SimConfig.groundtruth_mode must be one of {GROUNDTRUTH_MODES}, "
                              f"got {self.groundtruth_mode!r}")
        if self.scene_span not in SCENE_SPANS:
            raise ConfigError(f"SimConfig.scene_span must be one of {SCENE_SPANS}, got {self.scene_span!r}")
        check_sim_seconds(self.seconds)
        if isinstance(self.start_s, bool) or not isinstance(self.start_s, numbers.Real) \
                or not (math.isfinite(self.start_s) and 0 <= self.start_s <= MAX_START_S):
            raise ConfigError(f"--start must be a number of seconds from 0 to {MAX_START_S:g} "
                              f"(SimConfig.start_s), got {self.start_s!r}")
        s = self.attitude_smoothing_s
        if isinstance(s, bool) or not isinstance(s, int | float) or not 0.0 < s < float("inf"):
            raise ConfigError(f"SimConfig.attitude_smoothing_s must be a positive number of seconds, "
                              f"got {s!r}")


MAX_SIM_SECONDS = 4 * 3600.0
"""Longest simulated recording (s): the simulated-folder manifests' plausible range (tools.run_io)."""
MAX_START_S = 1e7
"""Largest start_s (s; 116 days): beyond it the crop of a trajectory's stamps leaves int64 ns."""


def check_sim_seconds(seconds: float | None, name: str = "--seconds") -> None:
    """ConfigError unless `seconds` is None or a finite duration in (0, MAX_SIM_SECONDS]."""
    if seconds is None:
        return
    if isinstance(seconds, bool) or not isinstance(seconds, numbers.Real) \
            or not (math.isfinite(seconds) and 0 < seconds <= MAX_SIM_SECONDS):
        raise ConfigError(f"{name} must be a finite number > 0 and at most {MAX_SIM_SECONDS:g} (4 h) for a "
                          f"simulated recording (got {seconds!r})")


GROUNDTRUTH_MODES = ("imu-consistent", "as-recorded")
SCENE_SPANS = ("recording", "trajectory")
MAX_SEED = 2**32
"""Seeds are integers in [0, MAX_SEED) (numpy's generators refuse negative ones)."""


KEEP_FRAMES_LIMIT_BYTES = 512 * 2**20
"""`SimRecording.keep_frames`' default limit: about 1400 EuRoC-sized frames (70 s at 20 Hz)."""


class SimRecording(Driver):
    """A simulated recording: scene, motion, IMU stream and lazily rendered frames.

    Attributes:
        scene, motion (PoseSpline | SampledMotion), imu (ImuStream), frame_stamps_ns (camera clock),
        info (how it was made: mode, preset, seed, sources).
    """

    def __init__(
        self,
        rig: Rig,
        scene: Scene,
        motion,
        imu: ImuStream,
        frame_stamps_ns: np.ndarray,
        groundtruth: PoseTrajectory,
        config: SimConfig,
        info: dict,
    ) -> None:
        self._rig = rig
        self.scene = scene
        self.motion = motion
        self.imu = imu
        self.frame_stamps_ns = np.asarray(frame_stamps_ns, np.int64)
        self._groundtruth = groundtruth
        self.config = config
        self.info = dict(info)
        self.time_offset_ns = int(round((rig.time_offset_s or 0.0) * 1e9))
        self._renderer: Renderer | None = None
        self._kept: dict[int, Frame] | None = None   # keep_frames(): rendered frames by index
        self._kept_bytes = self._keep_limit_bytes = 0
        self.gt_source = GroundTruthSource(scene, motion, rig.T_IC, self.time_offset_ns)
        self._report = IntakeReport("sim", self.info.get("source", "simulator"))
        self._report.note(
            "simulated recording: "
            + ", ".join(f"{k}={v}" for k, v in self.info.items() if k in ("mode", "preset", "seed", "style"))
        )

    # ---------------------------------------------------------------- constructors
    @classmethod
    def from_preset(cls, config: SimConfig | None = None, rig: Rig | None = None) -> SimRecording:
        """A recording along a motion preset with a synthetic IMU."""
        config = config or SimConfig()
        if config.seconds is None or not config.seconds > 0:
            raise ConfigError(f"a preset recording needs seconds > 0, got {config.seconds}")
        if config.scene_span != "recording":
            raise ConfigError("scene_span 'trajectory' needs a trajectory file; a preset's scene is built "
                              "around its own motion")
        spline = preset_spline(config.preset, config.seconds, config.seed)
        return cls._from_spline(
            spline,
            config,
            rig,
            {"mode": "preset", "preset": config.preset, "source": f"preset {config.preset}"},
        )

    @classmethod
    def from_trajectory(
        cls,
        path: str | Path,
        config: SimConfig | None = None,
        rig: Rig | None = None,
        imu_path: str | Path | None = None,
        camera_stamps_path: str | Path | None = None,
    ) -> SimRecording:
        """A recording along a trajectory file (EuRoC state CSV or TUM, poses T_WI).

        Without imu_path the IMU is synthesised from a spline fitted to the trajectory (0.1 s knots;
        the ground truth is then that spline, within millimetres of the file). With it,
        the real IMU is replayed against the real trajectory (EuRoC-trajectory mode); camera
        stamps come from camera_stamps_path, else a cam0_timestamps.txt beside the IMU file, else
        the camera rate.
        """
        config = config or SimConfig(seconds=None)
        whole = read_trajectory(path, strictly_increasing=True)
        traj = crop_trajectory(whole, config.start_s, config.seconds, Path(path))
        around = whole if config.scene_span == "trajectory" else None
        if imu_path is None:
            spline = fit_pose_spline(traj.t_ns, traj.p, traj.R, dt_s=0.1)
            info = {"mode": "trajectory-spline", "source": str(path),
                    "notes": trajectory_gap_notes(traj.t_ns)}
            return cls._from_spline(spline, config, rig, info, scene_around=around)
        if camera_stamps_path is None and (Path(imu_path).parent / "cam0_timestamps.txt").is_file():
            camera_stamps_path = Path(imu_path).parent / "cam0_timestamps.txt"
        return cls._replay(traj, Path(imu_path), camera_stamps_path, config, rig, str(path),
                           scene_around=around)

    @classmethod
    def from_euroc_imu_gt(
        cls, folder: str | Path, config: SimConfig | None = None, rig: Rig | None = None
    ) -> SimRecording:
        """EuRoC-trajectory mode on a folder with groundtruth.csv or groundtruth_tum.txt, imu0.csv
        and cam0_timestamps.txt (shared/data/euroc_imu_gt/<sequence>)."""
        folder = Path(folder)
        if not folder.is_dir():
            raise DataError("is a file, not a euroc_imu_gt sequence folder" if folder.exists() else
                            "no such folder (a euroc_imu_gt sequence: groundtruth.csv, imu0.csv, "
                            "cam0_timestamps.txt)", folder)
        gt = folder / "groundtruth.csv"
        if not gt.is_file():
            gt = folder / "groundtruth_tum.txt"
        if not gt.is_file():
            raise DataError("no groundtruth.csv or groundtruth_tum.txt", folder)
        config = config or SimConfig(seconds=None)
        whole = read_trajectory(gt, strictly_increasing=True)
        traj = crop_trajectory(whole, config.start_s, config.seconds, gt)
        stamps = folder / "cam0_timestamps.txt"
        return cls._replay(
            traj,
            folder / "imu0.csv",
            stamps if stamps.is_file() else None,
            config,
            rig,
            str(folder),
            sequence=folder.name,
            scene_around=whole if config.scene_span == "trajectory" else None,
        )

    @classmethod
    def _from_spline(cls, spline: PoseSpline, config: SimConfig, rig: Rig | None, info: dict,
                     scene_around: PoseTrajectory | None = None) -> SimRecording:
        rig = _with_offset(rig or euroc_default_rig(), config.time_offset_s)
        t0 = spline.t0_ns
        t_end = (
            spline.t_end_ns
            if config.seconds is None
            else min(spline.t_end_ns, t0 + int(config.seconds * 1e9))
        )
        t_imu = imu_stamps(t0, t_end, config.imu_rate_hz)
        errors = config.imu_errors or imu_errors_for(config.imu_profile, rig.imu)
        imu = synthesize_imu(spline, t_imu, errors, seed=config.seed)
        s = spline.sample(t_imu)
        gt = PoseTrajectory(
            t_imu, s.p, s.R, s.v, imu.bg, imu.ba, meta={"frame": "T_WI", "source": "simulator"}
        )
        rate = config.camera_rate_hz or rig.camera_rate_hz or 20.0
        margin = int(config.image.exposure_time_s * 0.5e9) + abs(int(round(config.time_offset_s * 1e9)))
        t_true = frame_times(t0 + margin, t_end, rate, margin)
        stamps = t_true - int(round(config.time_offset_s * 1e9))
        scene = build_scene(scene_positions(spline, t0, t_end, rig.T_IC) if scene_around is None
                            else trajectory_positions(scene_around, rig.T_IC), config.seed, config.style)
        info = {**info, "seed": config.seed, "style": config.style, "seconds": (t_end - t0) * 1e-9}
        if scene_around is not None:
            info["scene_span"] = "trajectory"
        return cls(rig, scene, spline, imu, stamps, gt, config, info)

    @classmethod
    def _replay(
        cls,
        traj: PoseTrajectory,
        imu_path: Path,
        camera_stamps_path: str | Path | None,
        config: SimConfig,
        rig: Rig | None,
        source: str,
        sequence: str | None = None,
        scene_around: PoseTrajectory | None = None,
    ) -> SimRecording:
        rig = _with_offset(rig or euroc_default_rig(), config.time_offset_s)
        t_all, gyro, accel = read_euroc_imu_csv(imu_path, policy="strict")
        t0, t_end = int(traj.t_ns[0]), int(traj.t_ns[-1])
        keep = (t_all >= t0) & (t_all <= t_end)
        if keep.sum() < 2:
            raise DataError("the IMU stream does not overlap the trajectory", imu_path)
        imu = ImuStream(t_all[keep], gyro[keep], accel[keep])
        if config.groundtruth_mode == "imu-consistent":
            # images move as the IMU measured (and as the ground truth over seconds): the recording's truth
            traj = imu_consistent_groundtruth(traj, imu.t_ns, imu.gyro, config.attitude_smoothing_s)
            t0, t_end = int(traj.t_ns[0]), int(traj.t_ns[-1])
        motion = SampledMotion(traj)
        offset_ns = int(round(config.time_offset_s * 1e9))
        margin = int(config.image.exposure_time_s * 0.5e9) + abs(offset_ns)
        if camera_stamps_path is not None:
            real = read_camera_timestamps(camera_stamps_path, policy="strict")
            t_true = real[(real >= t0 + margin) & (real <= t_end - margin)]
        else:
            t_true = frame_times(
                t0 + margin, t_end, config.camera_rate_hz or rig.camera_rate_hz or 20.0, margin
            )
        if t_true.size == 0:
            raise DataError("no camera stamp falls inside the trajectory", camera_stamps_path or imu_path)
        scene = build_scene(scene_positions(motion, t0, t_end, rig.T_IC) if scene_around is None
                            else trajectory_positions(scene_around, rig.T_IC), config.seed, config.style)
        info = {
            "mode": "euroc-trajectory",
            "source": source,
            "imu": str(imu_path),
            "seed": config.seed,
            "style": config.style,
            "seconds": (t_end - t0) * 1e-9,
            "groundtruth_mode": config.groundtruth_mode,
        }
        if "position_jumps_removed" in traj.meta:
            info["position_jumps_removed"] = traj.meta["position_jumps_removed"]
            info["position_jumps_m"] = traj.meta["position_jumps_m"]
        if sequence:
            info["sequence"] = sequence
        if scene_around is not None:
            info["scene_span"] = "trajectory"
        gt = PoseTrajectory(
            traj.t_ns, traj.p, traj.R, traj.v, traj.bg, traj.ba, meta={"frame": "T_WI", "source": source}
        )
        return cls(rig, scene, motion, imu, t_true - offset_ns, gt, config, info)

    # ---------------------------------------------------------------- driver interface
    @property
    def rig(self) -> Rig:
        """The rig the images and IMU were simulated with (EuRoC's by default)."""
        return self._rig

    @property
    def renderer(self) -> Renderer:
        """The image renderer (built on first use)."""
        if self._renderer is None:
            self._renderer = Renderer(self.scene, self._rig.camera, self.config.image, self.config.seed)
        return self._renderer

    def __len__(self) -> int:
        return int(self.frame_stamps_ns.size)

    def render(self, index: int) -> tuple[Frame, View]:
        """Frame `index` (uint8 image, camera-clock stamp) and its view (true z-depth, faces)."""
        if not 0 <= index < len(self):
            raise IndexError(f"frame {index} out of range (0..{len(self) - 1})")
        t_cam = int(self.frame_stamps_ns[index])
        t_true = t_cam + self.time_offset_ns
        opts = self.config.image
        n = opts.motion_blur_samples
        if n > 1:
            half = opts.exposure_time_s * 0.5e9
            times = t_true + np.round(np.linspace(-half, half, n)).astype(np.int64)
        else:
            times = np.array([t_true], np.int64)
        R_WI, p_WI = self.motion.pose(times)
        R_IC, p_IC = self._rig.T_IC[:3, :3], self._rig.T_IC[:3, 3]
        poses = [(R @ R_IC, p + R @ p_IC) for R, p in zip(R_WI, p_WI, strict=True)]
        t_s = (t_true - int(self.imu.t_ns[0])) * 1e-9
        image, view = self.renderer.render(poses, t_s, index)
        meta = {"simulated": True, "exposure_gain": self.renderer.exposure_gain(t_s)}
        return Frame(t_cam, image, 0, meta=meta), view

    def keep_frames(self, limit_bytes: int = KEEP_FRAMES_LIMIT_BYTES) -> None:
        """Keep the frames `events()` renders, up to `limit_bytes` of images, so that a later pass over the
        recording (the demo's native-only race) replays them instead of rendering them again."""
        if limit_bytes < 0:
            raise ValueError(f"limit_bytes must be >= 0, got {limit_bytes}")
        self._kept, self._kept_bytes, self._keep_limit_bytes = {}, 0, int(limit_bytes)

    def release_frames(self) -> None:
        """Drop the kept frames (and stop keeping): later passes render again."""
        self._kept, self._kept_bytes = None, 0

    @property
    def kept_frames(self) -> int:
        """How many rendered frames `keep_frames` holds."""
        return 0 if self._kept is None else len(self._kept)

    def _frame(self, index: int) -> Frame:
        """Frame `index`: a copy of the kept one, else rendered (and kept while the limit allows)."""
        kept = self._kept
        if kept is not None and index in kept:
            f = kept[index]
            return Frame(f.t_ns, f.image.copy(), f.camera_id, meta=dict(f.meta))
        frame, _ = self.render(index)
        if kept is not None and self._kept_bytes + frame.image.nbytes <= self._keep_limit_bytes:
            kept[index] = Frame(frame.t_ns, frame.image.copy(), frame.camera_id, meta=dict(frame.meta))
            self._kept_bytes += frame.image.nbytes
        return frame

    def events(self) -> Iterator[ImuSample | Frame]:
        """IMU samples and lazily rendered frames in stamp order (IMU first at equal stamps)."""
        cam = self._report.stream("cam0")
        imu_counts = self._report.stream("imu0")
        cam.lines = cam.parsed = len(self)
        imu_counts.lines = imu_counts.parsed = len(self.imu)
        cam.emitted = imu_counts.emitted = 0  # counts of this pass
        ti, tf = self.imu.t_ns, self.frame_stamps_ns
        i = f = 0
        while i < ti.size or f < tf.size:
            if f >= tf.size or (i < ti.size and ti[i] <= tf[f]):
                imu_counts.emitted += 1
                yield ImuSample(int(ti[i]), self.imu.gyro[i].copy(), self.imu.accel[i].copy())
                i += 1
            else:
                frame = self._frame(f)
                cam.emitted += 1
                yield frame
                f += 1

    def groundtruth(self) -> PoseTrajectory:
        """True T_WI (IMU clock) with velocity and, for synthetic IMUs, the true biases."""
        return self._groundtruth

    def report(self) -> dict:
        """Counters of emitted events plus how the recording was simulated."""
        out = self._report.as_dict()
        out["simulation"] = dict(self.info)
        return out


def _with_offset(rig: Rig, time_offset_s: float) -> Rig:
    if rig.camera is None or rig.T_IC is None:
        raise ConfigError("simulation needs a rig with a camera model and T_IC")
    if time_offset_s != (rig.time_offset_s or 0.0):
        rig = rig.replace(time_offset_s=float(time_offset_s))
    elif rig.time_offset_s is None:
        rig = rig.replace(time_offset_s=0.0)
    return rig
