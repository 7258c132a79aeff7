"""Motion presets: seeded, smooth T_WI(t) splines for simulated recordings.

Every preset starts at t0 and is built from control points at `knot_s` spacing, so the motion is
C2 (continuous acceleration, finite jerk). Identical control points give an exactly static
segment (zero velocity and rate); equally spaced collinear ones give an exactly constant-velocity,
constant-attitude segment (the degenerate case for visual-inertial initialisation).

The body (IMU) frame is mounted as on the EuRoC MAV: x_I up, z_I forward (the camera looks along
z_I), so a level attitude with heading psi is R_WI = Rz(psi) R_LEVEL, and the drone tilts toward
its horizontal acceleration like a multicopter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.sim.spline import PoseSpline
from runtime.errors import ConfigError
from runtime.geometry.so3 import so3_exp

G0 = 9.81
"""Gravitational acceleration magnitude used by the simulator, m/s^2 (world gravity (0, 0, -G0))."""

R_LEVEL = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
"""R_WI of a level body with heading 0: x_I = up (W z), y_I = -W y, z_I = forward (W x)."""


@dataclass(frozen=True)
class MotionPreset:
    """Parameters of a motion preset.

    Attributes:
        name: preset name.
        description: one line for the help text.
        static_s: seconds at rest at the start (on the ground for take-off presets).
        constant_velocity_s: seconds of straight constant-velocity, constant-attitude motion after
            the static part (0 = none).
        speed_mps: typical flight speed, m/s.
        yaw_rate_rps: typical yaw rate, rad/s.
        amplitude_m: for hovering: size of the position wander, m (0 = free flight).
        start_height_m: height of the body above the floor at the start, m.
        flight_height_m: typical flight height above the floor, m.
        knot_s: control-point spacing of the flight part, s.
        tilt_gain: multiplier of the multicopter tilt (horizontal accel / g).
    """

    name: str
    description: str
    static_s: float
    constant_velocity_s: float
    speed_mps: float
    yaw_rate_rps: float
    amplitude_m: float
    start_height_m: float
    flight_height_m: float
    knot_s: float = 0.5
    tilt_gain: float = 1.0


PRESETS: dict[str, MotionPreset] = {
    p.name: p
    for p in [
        MotionPreset(
            "euroc",
            "EuRoC-like: 2 s at rest on the ground, take-off, then moderate flight",
            static_s=2.0,
            constant_velocity_s=0.0,
            speed_mps=0.8,
            yaw_rate_rps=0.35,
            amplitude_m=0.0,
            start_height_m=0.15,
            flight_height_m=1.4,
        ),
        MotionPreset(
            "constant-velocity",
            "20 s of constant velocity from the first frame (degenerate for initialisation), then flight",
            static_s=0.0,
            constant_velocity_s=20.0,
            speed_mps=0.6,
            yaw_rate_rps=0.3,
            amplitude_m=0.0,
            start_height_m=1.2,
            flight_height_m=1.2,
        ),
        MotionPreset(
            "hover",
            "1 s at rest, take-off, then hovering with small wander",
            static_s=1.0,
            constant_velocity_s=0.0,
            speed_mps=0.15,
            yaw_rate_rps=0.1,
            amplitude_m=0.15,
            start_height_m=0.15,
            flight_height_m=1.2,
        ),
        MotionPreset(
            "slow",
            "slow hand-held-like motion from the first second",
            static_s=0.0,
            constant_velocity_s=0.0,
            speed_mps=0.3,
            yaw_rate_rps=0.2,
            amplitude_m=0.0,
            start_height_m=1.3,
            flight_height_m=1.3,
        ),
        MotionPreset(
            "handheld",
            "a hand-held camera carried at walking pace from the first frame (in motion, with sway)",
            static_s=0.0,
            constant_velocity_s=0.0,
            speed_mps=0.5,
            yaw_rate_rps=0.3,
            amplitude_m=0.0,
            start_height_m=1.3,
            flight_height_m=1.3,
            knot_s=0.3,
        ),
        MotionPreset(
            "rotation",
            "pure rotation in place: the body turns about its IMU and never translates (degenerate)",
            static_s=0.0,
            constant_velocity_s=0.0,
            speed_mps=0.0,
            yaw_rate_rps=0.6,
            amplitude_m=0.0,
            start_height_m=1.3,
            flight_height_m=1.3,
        ),
        MotionPreset(
            "aggressive",
            "1 s at rest, then fast flight with strong tilts and yaw",
            static_s=1.0,
            constant_velocity_s=0.0,
            speed_mps=2.0,
            yaw_rate_rps=1.0,
            amplitude_m=0.0,
            start_height_m=0.15,
            flight_height_m=1.5,
            knot_s=0.4,
            tilt_gain=1.5,
        ),
    ]
}
"""The motion presets by name (`davio simulate --preset NAME`)."""

DEFAULT_PRESET = "euroc"


def level_attitude(
    yaw: np.ndarray, roll: np.ndarray | None = None, pitch: np.ndarray | None = None
) -> np.ndarray:
    """R_WI for headings `yaw` (rad, about W z) with small world-frame tilts about W x (roll) and W y."""
    yaw = np.asarray(yaw, dtype=np.float64).reshape(-1)
    zero = np.zeros_like(yaw)
    roll = zero if roll is None else np.asarray(roll, dtype=np.float64).reshape(-1)
    pitch = zero if pitch is None else np.asarray(pitch, dtype=np.float64).reshape(-1)
    tilt = so3_exp(np.stack([roll, pitch, zero], axis=1))
    head = so3_exp(np.stack([zero, zero, yaw], axis=1))
    return tilt @ head @ R_LEVEL


def preset_spline(
    name: str, seconds: float, seed: int = 0, t0_ns: int = 1_000_000_000_000_000_000
) -> PoseSpline:
    """A seeded T_WI(t) spline for preset `name` lasting at least `seconds` from t0_ns.

    The motion stays inside a box of about 6 x 5 m around the origin (free flight) and starts
    with the body at (0, 0, start_height_m) above a floor at z = 0, heading along +x.
    """
    if name not in PRESETS:
        raise ConfigError(f"unknown motion preset {name!r}; choose one of {', '.join(PRESETS)}")
    if not seconds > 0:
        raise ConfigError(f"--seconds must be > 0, got {seconds}")
    pr = PRESETS[name]
    rng = np.random.default_rng(seed)
    k = pr.knot_s
    n_total = int(np.ceil(seconds / k)) + 4
    p0 = np.array([0.0, 0.0, pr.start_height_m])
    vel = np.array([pr.speed_mps, 0.0, 0.0])
    # the first segment's four control points: equal (at rest) or collinear (moving at vel from t0)
    moving = pr.static_s == 0 and pr.constant_velocity_s > 0
    pts = [p0 + (j - 1) * k * vel * moving for j in range(3)]
    yaws = [0.0, 0.0, 0.0]
    # static part: repeated control points
    for _ in range(int(np.ceil(pr.static_s / k - 1e-9))):
        pts.append(p0.copy())
        yaws.append(0.0)
    # constant-velocity part: equally spaced collinear control points, constant yaw
    for _ in range(int(np.ceil(pr.constant_velocity_s / k - 1e-9))):
        pts.append(pts[-1] + vel * k)
        yaws.append(0.0)
    n_fixed = len(pts)
    # flight: smoothed random velocity with soft walls, height pulled to flight_height_m
    home = np.array([pts[-1][0], pts[-1][1], pr.flight_height_m])
    v = vel.copy() if pr.constant_velocity_s > 0 else np.zeros(3)
    yaw_rate = 0.0
    take_off = pr.static_s > 0 and pr.start_height_m < pr.flight_height_m
    half = np.array([3.0, 2.5, 0.6])
    while len(pts) < n_total:
        p = pts[-1]
        if pr.amplitude_m > 0:  # hovering: wander around home
            target = home + rng.normal(size=3) * pr.amplitude_m * np.array([1.0, 1.0, 0.5])
            v_new = (target - p) / (2.0 * k)
            v = 0.5 * v + 0.5 * v_new
        else:
            v = 0.7 * v + 0.6 * rng.normal(size=3) * pr.speed_mps * np.array([1.0, 1.0, 0.3])
            off = (p - home) / half
            v -= 0.6 * pr.speed_mps * np.clip(off, -2, 2) * (np.abs(off) > 0.6)
            sp = np.linalg.norm(v[:2])
            if sp > 1e-9:
                v[:2] *= 0.5 * (1.0 + pr.speed_mps / sp) if sp > pr.speed_mps else 1.0
        if take_off and len(pts) - n_fixed < int(round(1.5 / k)):  # climb first
            v[2] = (pr.flight_height_m - pr.start_height_m) / 1.5
            v[:2] *= 0.3
        pts.append(p + v * k)
        yaw_rate = 0.8 * yaw_rate + 0.2 * rng.normal() * pr.yaw_rate_rps * 2.0
        yaws.append(yaws[-1] + yaw_rate * k)
    P = np.array(pts)
    yaw = np.array(yaws)
    # multicopter tilt from the control polygon's second differences (~ horizontal acceleration)
    acc = np.zeros_like(P)
    acc[1:-1] = (P[2:] - 2 * P[1:-1] + P[:-2]) / k**2
    acc[:n_fixed] = 0.0
    g = pr.tilt_gain / G0
    roll = np.clip(-acc[:, 1] * g, -0.5, 0.5)
    pitch = np.clip(acc[:, 0] * g, -0.5, 0.5)
    R = level_attitude(yaw, roll, pitch)
    return PoseSpline(t0_ns, k, P, R)
