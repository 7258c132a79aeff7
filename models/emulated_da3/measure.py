"""Measure the emulated DA3's output statistics on the analytic box room (for PRESETS.md).

    python -m models.emulated_da3.measure --preset base --width 504 --height 336 --calls 8 [--json]

Prints, per preset, what the mapping and start-up stages will see: depth error after removing
each call's scale (median log ratio), conditioned vs unconditioned; Spearman correlation of the
confidence with the absolute error after that alignment; share of flying
pixels below the 25th confidence percentile; pose and focal errors; time per call.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from models.emulated_da3.analytic import BoxRoom
from models.emulated_da3.depth_errors import DenseErrorLevels, confidence, corrupt_view
from models.emulated_da3.emulator import EmulatedDA3
from models.emulated_da3.params import make_params
from models.emulated_da3.pose_errors import rotation_angle
from runtime.events import Frame


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    ra = np.argsort(np.argsort(a)).astype(np.float64)
    rb = np.argsort(np.argsort(b)).astype(np.float64)
    return float(np.corrcoef(ra, rb)[0, 1])


def measure(preset: str, width: int, height: int, calls: int, seed: int = 0, n_views: int = 5) -> dict:
    """Statistics of `calls` unconditioned and conditioned calls on a 5-view box-room window."""
    f = 0.73 * width  # about 69 degrees horizontal field of view
    K = np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])
    room = BoxRoom()
    ts = [int(i * 0.2e9) for i in range(n_views)]
    frames = [Frame(t, np.zeros((height, width), np.uint8)) for t in ts]
    truth = np.stack([room.render_view(t, K, width, height).depth for t in ts]).astype(np.float64)
    T_WC = np.stack([room.T_WC(t) for t in ts])
    T_rel = np.linalg.inv(T_WC[0]) @ T_WC
    m = np.isfinite(truth)
    model = EmulatedDA3(room, K, width, height, preset=preset, seed=seed)
    out: dict[str, list[float]] = {
        k: []
        for k in (
            "uncond_abs_log_err",
            "cond_abs_log_err",
            "spearman_cond",
            "spearman_uncond",
            "rot_err_deg",
            "dir_err_deg",
            "focal_log_err",
            "uncond_s",
            "cond_s",
        )
    }
    for _ in range(calls):
        t0 = time.perf_counter()
        u = model.predict(frames)
        out["uncond_s"].append(time.perf_counter() - t0)
        lu = np.log(u.depth[m] / truth[m])
        lu -= np.median(lu)
        out["uncond_abs_log_err"].append(float(np.median(np.abs(lu))))
        out["spearman_uncond"].append(_spearman(u.conf[m], np.abs(np.expm1(lu)) * truth[m]))
        P = np.linalg.inv(u.T_CW)
        out["rot_err_deg"] += list(
            np.rad2deg(rotation_angle(P[1:, :3, :3] @ np.transpose(T_rel[1:, :3, :3], (0, 2, 1))))
        )
        a, b = P[1:, :3, 3], T_rel[1:, :3, 3]
        c = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        out["dir_err_deg"] += list(np.rad2deg(np.arccos(np.clip(c, -1, 1))))
        out["focal_log_err"] += list(np.log(u.K[:, 0, 0] / K[0, 0]))
        t0 = time.perf_counter()
        c_ = model.predict(frames, np.tile(K, (n_views, 1, 1)), np.linalg.inv(T_WC))
        out["cond_s"].append(time.perf_counter() - t0)
        lc = np.log(c_.depth[m] / truth[m])
        lc -= np.median(lc)  # the window scale is not the confidence's business
        out["cond_abs_log_err"].append(float(np.median(np.abs(lc))))
        out["spearman_cond"].append(_spearman(c_.conf[m], np.abs(np.expm1(lc)) * truth[m]))
    # flying pixels vs the 25th confidence percentile (needs the per-pixel flags: one view directly)
    p = make_params(preset)
    v = room.render_view(0, K, width, height)
    rng = np.random.default_rng(seed)
    below = []
    for _ in range(calls):
        cv = corrupt_view(
            rng,
            v.depth.astype(np.float64),
            v.depth.astype(np.float64),
            v.texture,
            v.reflective,
            v.dynamic,
            v.surface_id,
            p,
            DenseErrorLevels(p.image_log_scale_sigma_cond, p.field_sigma_cond, p.noise_sigma),
            3.0,
        )
        conf = confidence(rng, cv.expected_error[None], p)[0]
        below.append(float(np.mean(conf[cv.flying] < np.percentile(conf, 25))))
    return {
        "preset": preset,
        "width": width,
        "height": height,
        "calls": calls,
        "median_abs_log_depth_err_uncond": float(np.mean(out["uncond_abs_log_err"])),
        "median_abs_log_depth_err_cond": float(np.mean(out["cond_abs_log_err"])),
        "spearman_conf_abs_err_cond": float(np.mean(out["spearman_cond"])),
        "spearman_conf_abs_err_uncond": float(np.mean(out["spearman_uncond"])),
        "flying_below_p25": float(np.mean(below)),
        "median_rot_err_deg": float(np.median(out["rot_err_deg"])),
        "median_dir_err_deg": float(np.median(out["dir_err_deg"])),
        "focal_log_err_std": float(np.std(out["focal_log_err"])),
        "uncond_call_s": float(np.median(out["uncond_s"])),
        "cond_call_s": float(np.median(out["cond_s"])),
    }


def main(argv: list[str] | None = None) -> int:
    """Command-line entry: print a table (or one JSON object with --json)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", action="append", help="preset(s) to measure (default: small, base, large)")
    ap.add_argument("--width", type=int, default=504)
    ap.add_argument("--height", type=int, default=336)
    ap.add_argument("--calls", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    rows = [
        measure(p, args.width, args.height, args.calls, args.seed)
        for p in (args.preset or ["small", "base", "large"])
    ]
    if args.json:
        print(json.dumps({"emulated_da3": rows}))
        return 0
    keys = [k for k in rows[0] if k not in ("preset", "width", "height", "calls")]
    print(f"emulated DA3 on the box room, {args.width}x{args.height}, {args.calls} calls of 5 views each")
    print(f"{'statistic':34s}" + "".join(f"{r['preset']:>10s}" for r in rows))
    for k in keys:
        print(f"{k:34s}" + "".join(f"{r[k]:10.4f}" for r in rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
