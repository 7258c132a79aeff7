"""What the native initializers hand to the filter, and the helpers they share.

Frames: O is the gravity-aligned odometry (filter world) frame, z up, gravitational acceleration
(0, 0, -g0); I is the IMU/body frame. ``R_OI`` maps I-coordinates to O.

Covariance convention of :class:`InitResult.cov` (15 x 15, SI units, radians):
error-state order ``[theta (3), p (3), v (3), bg (3), ba (3)]`` where
``R_OI = R_OI_hat @ Exp(theta)`` (theta is a *local*, body-frame rotation error, as OpenVINS' JPL
error on q_GtoI), ``p_OI = p_hat + dp``, ``v_OI = v_hat + dv``, ``bg = bg_hat + dbg``,
``ba = ba_hat + dba``. :func:`cov_local_to_global` converts theta to the global convention
``R_OI = Exp(theta_O) R_OI_hat``.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

ERROR_STATE_ORDER = ("theta", "p", "v", "bg", "ba")
"""Block order of InitResult.cov (3 rows each)."""


@dataclass
class InitResult:
    """An initial IMU state for the filter.

    Attributes:
        t_ns: time of the state (IMU clock), int64 ns.
        R_OI: (3, 3) orientation of the IMU in the gravity-aligned frame O (yaw is a gauge choice).
        p_OI: (3,) IMU position in O, m.
        v_OI: (3,) IMU velocity in O, m/s.
        bg: (3,) gyroscope bias, rad/s.  ba: (3,) accelerometer bias, m/s^2.
        cov: (15, 15) covariance in ERROR_STATE_ORDER (module docstring), or None.
        source: which initializer produced it ("static", "dynamic", ...).
        info: diagnostics (window statistics, residuals, iteration counts).
    """

    t_ns: int
    R_OI: np.ndarray
    p_OI: np.ndarray
    v_OI: np.ndarray
    bg: np.ndarray
    ba: np.ndarray
    cov: np.ndarray | None
    source: str
    info: dict = field(default_factory=dict)

    @property
    def T_OI(self) -> np.ndarray:
        """(4, 4) pose of the IMU in O."""
        T = np.eye(4)
        T[:3, :3] = self.R_OI
        T[:3, 3] = self.p_OI
        return T

    @property
    def gravity_in_imu(self) -> np.ndarray:
        """(3,) unit 'up' direction expressed in I (R_OI^T e_z): what roll/pitch are compared by."""
        return self.R_OI[2, :].copy()


@dataclass(frozen=True)
class InitRejection:
    """Why an initialization attempt did not produce a state.

    Attributes:
        t_ns: newest data time at the attempt, int64 ns (or -1 when there was no data).
        code: short machine-readable reason (e.g. "no_jerk", "insufficient_parallax").
        message: human-readable detail with the numbers that decided it.
    """

    t_ns: int
    code: str
    message: str

    def __str__(self) -> str:
        return f"{self.code}: {self.message}"


class RejectionLog:
    """The last rejection and a count per reason code, for run reports."""

    def __init__(self) -> None:
        self.last: InitRejection | None = None
        self.counts: dict[str, int] = {}

    def reject(self, t_ns: int, code: str, message: str) -> None:
        """Record a rejection (always returns None so callers can `return log.reject(...)`)."""
        self.last = InitRejection(int(t_ns), code, message)
        self.counts[code] = self.counts.get(code, 0) + 1

    @property
    def last_reason(self) -> str:
        """'code: message' of the last rejection, or '' if none."""
        return "" if self.last is None else str(self.last)


def rotation_from_up(up_I: np.ndarray) -> np.ndarray:
    """R_OI whose O z-axis is the 'up' direction up_I (any length) given in I; yaw is fixed by Gram-Schmidt.

    O's x-axis is the projection of I's x-axis (or y-axis when x is nearly vertical) onto the
    horizontal plane, so the result is deterministic. Rows of R_OI are O's axes expressed in I.
    """
    up = np.asarray(up_I, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(up))
    if not np.isfinite(n) or n <= 0.0:
        raise ValueError(f"the up direction must be a finite non-zero vector, got {up}")
    z = up / n
    e = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = e - z * float(z @ e)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z])


def gravity_angle_deg(up_a: np.ndarray, up_b: np.ndarray) -> float:
    """Angle (degrees) between two 'up' directions in the same frame: the roll/pitch error."""
    a = np.asarray(up_a, float) / np.linalg.norm(up_a)
    b = np.asarray(up_b, float) / np.linalg.norm(up_b)
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), float(a @ b))))


def cov_local_to_global(cov: np.ndarray, R_OI: np.ndarray) -> np.ndarray:
    """The 15x15 covariance with theta expressed globally (R = Exp(theta_O) R_hat, theta_O = R_OI theta)."""
    J = np.eye(15)
    J[:3, :3] = R_OI
    return J @ cov @ J.T


def diagonal_cov(sigmas: tuple[float, float, float, float, float]) -> np.ndarray:
    """(15, 15) diagonal covariance from one standard deviation per block (ERROR_STATE_ORDER)."""
    return np.diag(np.repeat(np.asarray(sigmas, dtype=np.float64) ** 2, 3))


class ImuWindow:
    """A time-ordered buffer of IMU samples; drops (and counts) non-finite or out-of-order ones."""

    def __init__(self, keep_ns: int) -> None:
        self.keep_ns = int(keep_ns)
        self._t: deque[int] = deque()
        self._w: deque[np.ndarray] = deque()
        self._a: deque[np.ndarray] = deque()
        self.dropped_nonfinite = 0
        self.dropped_out_of_order = 0

    def add(self, t_ns: int, gyro: np.ndarray, accel: np.ndarray) -> bool:
        """Append one sample; False (and counted) when it was dropped."""
        w = np.asarray(gyro, dtype=np.float64).reshape(-1)
        a = np.asarray(accel, dtype=np.float64).reshape(-1)
        if w.shape != (3,) or a.shape != (3,) or not (np.all(np.isfinite(w)) and np.all(np.isfinite(a))):
            self.dropped_nonfinite += 1
            return False
        if self._t and int(t_ns) <= self._t[-1]:
            self.dropped_out_of_order += 1
            return False
        self._t.append(int(t_ns))
        self._w.append(w)
        self._a.append(a)
        while self._t and self._t[0] < self._t[-1] - self.keep_ns:
            self._t.popleft()
            self._w.popleft()
            self._a.popleft()
        return True

    def __len__(self) -> int:
        return len(self._t)

    def newest_ns(self) -> int | None:
        """Stamp of the newest sample, or None when empty."""
        return self._t[-1] if self._t else None

    def clear(self) -> None:
        """Forget all samples (counters are kept)."""
        self._t.clear()
        self._w.clear()
        self._a.clear()

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t_ns (N,) int64, gyro (N,3), accel (N,3))."""
        if not self._t:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3))
        return np.fromiter(self._t, np.int64, len(self._t)), np.array(self._w), np.array(self._a)


class TrackWindow:
    """Per-frame feature observations (id -> distorted pixel, optional normalized xy) over a time span."""

    def __init__(self, keep_ns: int) -> None:
        self.keep_ns = int(keep_ns)
        self.frames: deque[tuple[int, np.ndarray, np.ndarray, np.ndarray | None]] = deque()
        self.dropped_out_of_order = 0

    def add(self, t_ns: int, ids: np.ndarray, uv: np.ndarray, xy: np.ndarray | None = None) -> None:
        """Append one frame (ids (M,), uv (M, 2) px, xy (M, 2) normalized or None).

        A frame not after the previous one is dropped and counted; mismatched lengths raise ValueError.
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        if ids.shape[0] != uv.shape[0]:
            raise ValueError(f"ids ({ids.shape[0]}) and uv ({uv.shape[0]}) must have the same length")
        if xy is not None:
            xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
            if xy.shape[0] != ids.shape[0]:
                raise ValueError(f"ids ({ids.shape[0]}) and xy ({xy.shape[0]}) must have the same length")
        if self.frames and int(t_ns) <= self.frames[-1][0]:
            self.dropped_out_of_order += 1
            return
        self.frames.append((int(t_ns), ids, uv, xy))
        while self.frames and self.frames[0][0] < int(t_ns) - self.keep_ns:
            self.frames.popleft()

    @property
    def newest_ns(self) -> int | None:
        return self.frames[-1][0] if self.frames else None

    def disparity(self, t0_ns: int, t1_ns: int) -> tuple[float, int]:
        """Mean first-to-last pixel displacement of tracks seen >= 2 times in [t0, t1], and their count."""
        first: dict[int, np.ndarray] = {}
        last: dict[int, np.ndarray] = {}
        for t, ids, uv, _ in self.frames:
            if t < t0_ns or t > t1_ns:
                continue
            for i, p in zip(ids.tolist(), uv, strict=True):
                if i not in first:
                    first[i] = p
                else:
                    last[i] = p
        if not last:
            return 0.0, 0
        d = [float(np.linalg.norm(last[i] - first[i])) for i in last]
        return float(np.mean(d)), len(d)


def accel_excitation(accel: np.ndarray) -> float:
    """sqrt(sum |a_i - mean|^2 / (n - 1)) over (n, 3) samples, m/s^2 (OpenVINS' accelerometer 'std')."""
    d = accel - accel.mean(axis=0)
    return float(np.sqrt(np.sum(d * d) / (accel.shape[0] - 1)))


class BufferedInitializer:
    """What every native initializer shares: its IMU and track buffers over `keep_ns`, the rejection log
    and the run-report counters. Given a camera, fed tracks are also undistorted to normalized xy."""

    def _init_buffers(self, keep_ns: int, camera: object | None = None) -> None:
        self.imu = ImuWindow(int(keep_ns))
        self.tracks = TrackWindow(int(keep_ns))
        self.log = RejectionLog()
        self._undistort_camera = camera

    @property
    def last_reason(self) -> str:
        """'code: message' of the last failed attempt ('' before any)."""
        return self.log.last_reason

    def feed_imu(self, sample: object) -> None:
        """Add one runtime.events.ImuSample (t_ns IMU clock, gyro rad/s, accel m/s^2)."""
        self.imu.add(sample.t_ns, sample.gyro, sample.accel)

    def feed_tracks(self, t_ns: int, ids: np.ndarray, uv: np.ndarray) -> None:
        """Add one frame's tracks: camera-clock time, ids (M,), distorted pixels (M, 2)."""
        cam = self._undistort_camera
        if cam is None:
            self.tracks.add(t_ns, ids, uv)
            return
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        xy = cam.undistort_points(uv) if uv.shape[0] else np.zeros((0, 2))
        self.tracks.add(t_ns, ids, uv, xy)

    def reset(self) -> None:
        """Forget buffered IMU samples and tracks (after a filter reset); rejection counts are kept."""
        self.imu.clear()
        self.tracks.frames.clear()

    def report(self) -> dict:
        """Counters for the run report."""
        return {"rejections": dict(self.log.counts), "last_reason": self.last_reason,
                "imu_dropped_nonfinite": self.imu.dropped_nonfinite,
                "imu_dropped_out_of_order": self.imu.dropped_out_of_order,
                "frames_dropped_out_of_order": self.tracks.dropped_out_of_order}
