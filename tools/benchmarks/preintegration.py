"""`davio bench preintegration`: speed of IMU preintegration and of the SO(3) numba kernels."""
from __future__ import annotations

import argparse

from tools.cli_types import count, number_in

NAME = "preintegration"
HELP = "IMU preintegration (numba) time per sample, with and without covariance; SO(3) kernel times"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rate", type=number_in(1, 1e5, unit=" Hz"), default=200.0, help="IMU rate, Hz")
    p.add_argument("--seconds", type=number_in(0, 3600, low_open=True, unit=" s"), default=1.0,
                   help="length of one preintegrated interval, s")
    p.add_argument("--repeats", type=count(1, 1000000), default=200,
                   help="timed calls per figure (best of 5 batches)")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def _best_us(fn, repeats: int) -> float:
    import time

    fn()  # compile / warm up
    best = float("inf")
    for _ in range(5):
        t = time.perf_counter()
        for _ in range(repeats):
            fn()
        best = min(best, (time.perf_counter() - t) / repeats * 1e6)
    return best


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from runtime.geometry.kernels import nb_right_jacobian, nb_so3_exp, nb_so3_log
    from runtime.imu import Preintegrator
    from runtime.json_out import strict_dumps

    rng = np.random.default_rng(0)
    n = int(round(args.rate * args.seconds)) + 1
    t_ns = np.arange(n, dtype=np.int64) * int(round(1e9 / args.rate))
    gyro, accel = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) + [0.0, 0.0, 9.81]
    t0, t1 = int(t_ns[0]) + 1, int(t_ns[-1]) - 1
    with_cov = Preintegrator(np.zeros(3), np.zeros(3), 1.7e-4, 2e-3)
    no_cov = Preintegrator(np.zeros(3), np.zeros(3))
    phi = np.array([0.1, -0.2, 0.3])
    R = nb_so3_exp(phi)
    rows = {
        "integrate_with_cov_us": _best_us(lambda: with_cov.integrate(t_ns, gyro, accel, t0, t1),
                                          args.repeats),
        "integrate_no_cov_us": _best_us(lambda: no_cov.integrate(t_ns, gyro, accel, t0, t1), args.repeats),
        "nb_so3_exp_us": _best_us(lambda: nb_so3_exp(phi), args.repeats * 50),
        "nb_so3_log_us": _best_us(lambda: nb_so3_log(R), args.repeats * 50),
        "nb_right_jacobian_us": _best_us(lambda: nb_right_jacobian(phi), args.repeats * 50),
    }
    result = {"rate_hz": args.rate, "seconds": args.seconds, "samples": n, **rows,
              "per_sample_with_cov_us": rows["integrate_with_cov_us"] / (n - 1),
              "per_sample_no_cov_us": rows["integrate_no_cov_us"] / (n - 1)}
    if args.json:
        print(strict_dumps(result))
    else:
        print(f"preintegration of {args.seconds:g} s at {args.rate:g} Hz ({n} samples), best of 5 batches")
        for key, value in result.items():
            if key.endswith("_us"):
                print(f"  {key:28s} {value:10.2f} us")
    return 0
