"""IMU synthesis from a pose spline: exact specific force and body rate, plus noise and biases.

  gyro_k  = omega_I(t_k) + bg(t_k) + n_g,      n_g ~ N(0, (gyro_noise_density * sqrt(rate))^2)
  accel_k = R_WI(t_k)^T (a_W(t_k) + (0, 0, g)) + ba(t_k) + n_a
  b(t_{k+1}) = b(t_k) + random_walk * sqrt(dt) * N(0, I)
with densities in the Kalibr/EuRoC continuous-time convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.sim.motion import G0
from drivers.sim.spline import PoseSpline
from runtime.errors import ConfigError


@dataclass
class ImuStream:
    """IMU samples and the true biases at each sample.

    Attributes:
        t_ns: (N,) int64 stamps (IMU clock).  gyro: (N,3) rad/s.  accel: (N,3) m/s^2.
        bg: (N,3) true gyro bias, rad/s, or None (unknown, real IMU).  ba: (N,3) accel bias, m/s^2, or None.
    """

    t_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    bg: np.ndarray | None = None
    ba: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass(frozen=True)
class ImuErrorModel:
    """Noise densities (Kalibr convention) and initial biases of a synthetic IMU.

    Attributes:
        gyro_noise_density: rad/s/sqrt(Hz).   gyro_random_walk: rad/s^2/sqrt(Hz).
        accel_noise_density: m/s^2/sqrt(Hz).  accel_random_walk: m/s^3/sqrt(Hz).
        initial_bg_sigma: std of the random initial gyro bias, rad/s.
        initial_ba_sigma: std of the random initial accel bias, m/s^2.
    """

    gyro_noise_density: float = 1.6968e-04
    gyro_random_walk: float = 1.9393e-05
    accel_noise_density: float = 2.0e-3
    accel_random_walk: float = 3.0e-3
    initial_bg_sigma: float = 0.003
    initial_ba_sigma: float = 0.05

    @staticmethod
    def noise_free() -> ImuErrorModel:
        """No noise, no bias."""
        return ImuErrorModel(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    @staticmethod
    def from_rig_noise(
        noise, initial_bg_sigma: float = 0.003, initial_ba_sigma: float = 0.05
    ) -> ImuErrorModel:
        """From a calib.ImuNoise (withheld fields fall back to EuRoC's values)."""
        d = ImuErrorModel()

        def pick(name: str) -> float:
            given = getattr(noise, name, None)
            return given if given is not None else getattr(d, name)

        return ImuErrorModel(
            pick("gyro_noise_density"),
            pick("gyro_random_walk"),
            pick("accel_noise_density"),
            pick("accel_random_walk"),
            initial_bg_sigma,
            initial_ba_sigma,
        )


def imu_stamps(t0_ns: int, t_end_ns: int, rate_hz: float) -> np.ndarray:
    """Uniform int64 stamps from t0_ns up to t_end_ns at rate_hz."""
    if not rate_hz > 0:
        raise ConfigError(f"IMU rate must be > 0 Hz, got {rate_hz}")
    period = 1e9 / rate_hz
    n = int(np.floor((t_end_ns - t0_ns) / period)) + 1
    return t0_ns + np.round(np.arange(n) * period).astype(np.int64)


def synthesize_imu(
    spline: PoseSpline, t_ns: np.ndarray, errors: ImuErrorModel, seed: int = 0, g: float = G0
) -> ImuStream:
    """IMU samples at stamps t_ns (IMU clock, inside the spline's span) with noise and biases."""
    t_ns = np.asarray(t_ns, dtype=np.int64)
    if t_ns.size < 2 or np.any(np.diff(t_ns) <= 0):
        raise ConfigError("IMU stamps must be at least two and strictly increasing")
    s = spline.sample(t_ns)
    f_W = s.a + np.array([0.0, 0.0, g])
    accel = np.einsum("nji,nj->ni", s.R, f_W)
    gyro = s.omega.copy()
    rng = np.random.default_rng([seed, 1234])
    n = t_ns.size
    dt = np.diff(t_ns).astype(np.float64) * 1e-9
    dt_med = float(np.median(dt))
    bg = np.zeros((n, 3))
    ba = np.zeros((n, 3))
    bg[0] = rng.normal(size=3) * errors.initial_bg_sigma
    ba[0] = rng.normal(size=3) * errors.initial_ba_sigma
    steps_g = rng.normal(size=(n - 1, 3)) * errors.gyro_random_walk * np.sqrt(dt)[:, None]
    steps_a = rng.normal(size=(n - 1, 3)) * errors.accel_random_walk * np.sqrt(dt)[:, None]
    bg[1:] = bg[0] + np.cumsum(steps_g, axis=0)
    ba[1:] = ba[0] + np.cumsum(steps_a, axis=0)
    gyro += bg + rng.normal(size=(n, 3)) * errors.gyro_noise_density / np.sqrt(dt_med)
    accel += ba + rng.normal(size=(n, 3)) * errors.accel_noise_density / np.sqrt(dt_med)
    return ImuStream(t_ns, gyro, accel, bg, ba)
