"""IMU synthesis from a pose spline: exact specific force and body rate, plus noise and biases.

  gyro_k  = omega_I(t_k) + bg(t_k) + n_g,      n_g ~ N(0, (gyro_noise_density * sqrt(rate))^2)
  accel_k = R_WI(t_k)^T (a_W(t_k) + (0, 0, g)) + ba(t_k) + n_a
  b(t_{k+1}) = b(t_k) + random_walk * sqrt(dt) * N(0, I)
with densities in the Kalibr/EuRoC continuous-time convention. Optionally a first-order Gauss-Markov
error m (per axis, stationary std sigma, correlation time tau) is added to the gyro and to the accel:
  m(t_{k+1}) = phi m(t_k) + sigma sqrt(1 - phi^2) N(0, I),   phi = exp(-dt / tau),  m(t_0) ~ N(0, sigma^2)
It is part of the true bias (bg, ba): the slowly varying error a real MEMS IMU shows in flight (bias
instability, vibration rectification, attitude-dependent errors), which the datasheet densities above leave
out (`ImuErrorModel.euroc_measured`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from drivers.sim.motion import G0
from drivers.sim.spline import PoseSpline
from runtime.errors import ConfigError

EUROC_GYRO_GM = (0.0005, 10.0)
"""(sigma rad/s, tau s) of the gyro's Gauss-Markov error measured on the real EuRoC IMU (euroc_measured)."""
EUROC_ACCEL_GM = (0.03, 1.0)
"""(sigma m/s^2, tau s) of the accel's Gauss-Markov error measured on the real EuRoC IMU (euroc_measured)."""
IMU_PROFILES = ("datasheet", "euroc-measured")
"""Named synthetic-IMU error models: the rig's noise densities alone, or with the measured in-flight
errors."""


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
        gyro_gm_sigma: stationary std of the gyro's Gauss-Markov error, rad/s (0 = none).
        gyro_gm_tau_s: its correlation time, s.
        accel_gm_sigma: stationary std of the accel's Gauss-Markov error, m/s^2 (0 = none).
        accel_gm_tau_s: its correlation time, s.
    """

    gyro_noise_density: float = 1.6968e-04
    gyro_random_walk: float = 1.9393e-05
    accel_noise_density: float = 2.0e-3
    accel_random_walk: float = 3.0e-3
    initial_bg_sigma: float = 0.003
    initial_ba_sigma: float = 0.05
    gyro_gm_sigma: float = 0.0
    gyro_gm_tau_s: float = 1.0
    accel_gm_sigma: float = 0.0
    accel_gm_tau_s: float = 1.0

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            finite = isinstance(value, int | float) and not isinstance(value, bool)
            if not finite or not 0.0 <= value < float("inf"):
                raise ConfigError(f"ImuErrorModel.{name} must be a finite number >= 0, got {value!r}")
        for name in ("gyro_gm_tau_s", "accel_gm_tau_s"):
            if not getattr(self, name) > 0.0:
                raise ConfigError(f"ImuErrorModel.{name} must be > 0 s, got {getattr(self, name)!r}")

    @staticmethod
    def noise_free() -> ImuErrorModel:
        """No noise, no bias."""
        return ImuErrorModel(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)

    @staticmethod
    def euroc_measured(noise=None) -> ImuErrorModel:
        """The rig's densities (EuRoC's datasheet values where withheld) plus the Gauss-Markov errors that
        make a synthetic IMU drift from the truth as the real EuRoC IMU drifts from its ground truth.

        Fitted by `davio bench imu-drift --curve 1,2,4 --synthetic euroc-measured` (integration from the
        true state, constant biases fitted over the sequence): the real IMU against the truth that the
        EuRoC-trajectory recordings render from (the ground truth with the gyro's attitude held to it,
        drivers.sim.imu_consistent: what the filter faces there) drifts by 25 / 86 / 279 mm and 0.052 /
        0.099 / 0.19 deg over 1 / 2 / 4 s on V1_02_medium, 22 / 68 / 201 mm and 0.024 / 0.047 / 0.096 deg
        on MH_03_medium (medians); this model along V1_02's trajectory 22 / 80 / 262 mm and 0.039 / 0.069 /
        0.127 deg, against the two sequences' geometric mean 24 / 76 / 237 mm and 0.035 / 0.068 / 0.135 deg.
        The datasheet densities alone give 9 / 36 / 133 mm and 0.017 / 0.024 / 0.034 deg. Windows under 1 s
        are left out of the fit: millimetre-level ground-truth noise can be as large as the drift there
        (1.8 mm at 0.25 s).
        """
        base = ImuErrorModel() if noise is None else ImuErrorModel.from_rig_noise(noise)
        return replace(base, gyro_gm_sigma=EUROC_GYRO_GM[0], gyro_gm_tau_s=EUROC_GYRO_GM[1],
                       accel_gm_sigma=EUROC_ACCEL_GM[0], accel_gm_tau_s=EUROC_ACCEL_GM[1])

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


def imu_errors_for(profile: str, noise=None) -> ImuErrorModel:
    """The ImuErrorModel of a named profile (IMU_PROFILES) for a rig's calib.ImuNoise (None: EuRoC's)."""
    if profile == "datasheet":
        return ImuErrorModel() if noise is None else ImuErrorModel.from_rig_noise(noise)
    if profile == "euroc-measured":
        return ImuErrorModel.euroc_measured(noise)
    raise ConfigError(f"unknown synthetic IMU profile {profile!r}; choose one of {', '.join(IMU_PROFILES)}")


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
    # Gauss-Markov errors from their own stream, so adding them leaves the other draws unchanged
    gm_rng = np.random.default_rng([seed, 4321])
    bg += gauss_markov(dt, errors.gyro_gm_sigma, errors.gyro_gm_tau_s, gm_rng)
    ba += gauss_markov(dt, errors.accel_gm_sigma, errors.accel_gm_tau_s, gm_rng)
    gyro += bg + rng.normal(size=(n, 3)) * errors.gyro_noise_density / np.sqrt(dt_med)
    accel += ba + rng.normal(size=(n, 3)) * errors.accel_noise_density / np.sqrt(dt_med)
    return ImuStream(t_ns, gyro, accel, bg, ba)


def gauss_markov(dt_s: np.ndarray, sigma: float, tau_s: float, rng: np.random.Generator) -> np.ndarray:
    """(len(dt_s) + 1, 3) samples of a stationary first-order Gauss-Markov process (std sigma, correlation
    time tau_s) at sample spacings dt_s, s; zeros when sigma is 0 (no draw is taken then)."""
    n = dt_s.size + 1
    if sigma == 0.0:
        return np.zeros((n, 3))
    phi = np.exp(-np.asarray(dt_s, np.float64) / tau_s)
    drive = rng.normal(size=(n, 3))
    out = np.empty((n, 3))
    out[0] = sigma * drive[0]
    step = sigma * np.sqrt(1.0 - phi * phi)
    for k in range(n - 1):
        out[k + 1] = phi[k] * out[k] + step[k] * drive[k + 1]
    return out
