"""`davio bench matcher`: XFeat (ONNX) and ORB latency and match precision on homography pairs.

Pairs: real EuRoC cam0 images (or, without them, synthetic textured scenes) warped by a random
homography (rotation, scale, perspective), so the true correspondence of every pixel is known.
Simulated pairs (drivers.sim): two frames `--gap` apart, truth from the true depth and poses.
A match is correct when the true position of kpt_a in b lies within `--px` pixels of kpt_b;
precision = correct / matches whose truth is known, before ('raw') and after LK refinement.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from runtime.json_out import strict_dumps
from tools.cli_types import count, number_in

NAME = "matcher"
HELP = "XFeat/ORB latency and match precision on image pairs with known homographies"
EUROC_CAM0 = (
    Path(__file__).resolve().parents[3]
    / "shared"
    / "data"
    / "euroc"
    / "V1_01_easy_head"
    / "mav0"
    / "cam0"
    / "data"
)


def synthetic_scene(rng: np.random.Generator, h: int = 480, w: int = 640) -> np.ndarray:
    """A grey uint8 image of random filled shapes, lines and texture (corners and blobs at all scales)."""
    import cv2  # here, not at import: `davio --help` builds this benchmark's options

    img = np.full((h, w), 110, np.uint8)
    for _ in range(60):
        c = int(rng.integers(0, 256))
        kind = rng.integers(0, 3)
        x, y = int(rng.integers(0, w)), int(rng.integers(0, h))
        if kind == 0:
            cv2.rectangle(
                img, (x, y), (x + int(rng.integers(10, 120)), y + int(rng.integers(10, 120))), c, -1
            )
        elif kind == 1:
            cv2.circle(img, (x, y), int(rng.integers(5, 50)), c, -1)
        else:
            cv2.line(
                img, (x, y), (int(rng.integers(0, w)), int(rng.integers(0, h))), c, int(rng.integers(1, 6))
            )
    noise = cv2.GaussianBlur(rng.normal(0, 25, (h, w)), (0, 0), 2.0)
    return np.clip(img + noise, 0, 255).astype(np.uint8)


def random_homography(
    rng: np.random.Generator,
    h: int,
    w: int,
    max_rot_deg: float = 15.0,
    scale_range: tuple[float, float] = (0.85, 1.15),
    max_persp: float = 2e-4,
) -> np.ndarray:
    """A homography about the image centre: rotation, isotropic scale, shift and mild perspective."""
    a = np.deg2rad(rng.uniform(-max_rot_deg, max_rot_deg))
    s = rng.uniform(*scale_range)
    c = np.array([[1, 0, -w / 2], [0, 1, -h / 2], [0, 0, 1]])
    A = np.array(
        [
            [s * np.cos(a), -s * np.sin(a), rng.uniform(-0.05, 0.05) * w],
            [s * np.sin(a), s * np.cos(a), rng.uniform(-0.05, 0.05) * h],
            [rng.uniform(-max_persp, max_persp), rng.uniform(-max_persp, max_persp), 1],
        ]
    )
    return np.linalg.inv(c) @ A @ c


def warp_pair(img: np.ndarray, H: np.ndarray, rng: np.random.Generator, noise: float = 2.0) -> np.ndarray:
    """Image b = img warped by H (pixel-centre convention), plus Gaussian noise."""
    import cv2

    out = cv2.warpPerspective(
        img, H, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT
    )
    return np.clip(out + rng.normal(0, noise, out.shape), 0, 255).astype(np.uint8)


class HomographyTruth:
    """Ground truth of a homography pair: b = H a (pixels), valid where H a falls inside image b."""

    def __init__(self, H: np.ndarray, shape: tuple[int, int]) -> None:
        self.H, self.shape = H, shape

    def __call__(self, pa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        import cv2

        if not len(pa):
            return pa.astype(np.float64), np.zeros(0, bool)
        q = cv2.perspectiveTransform(pa.reshape(-1, 1, 2).astype(np.float64), self.H).reshape(-1, 2)
        h, w = self.shape
        return q, (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)


class DepthTruth:
    """Ground truth of a simulated pair: back-project with the true depth of a, transform with the
    true poses, project into b; valid where the depth is smooth and the point is visible in b."""

    def __init__(
        self, camera, depth_a: np.ndarray, depth_b: np.ndarray, T_WCa: np.ndarray, T_WCb: np.ndarray
    ) -> None:
        self.camera, self.depth_a, self.depth_b = camera, depth_a, depth_b
        self.T_CbCa = np.linalg.inv(T_WCb) @ T_WCa

    def __call__(self, pa: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        import cv2

        h, w = self.depth_a.shape
        if not len(pa):
            return pa.astype(np.float64), np.zeros(0, bool)
        ia = np.clip(np.round(pa).astype(int), 0, [w - 1, h - 1])
        z = self.depth_a[ia[:, 1], ia[:, 0]].astype(np.float64)
        lo = cv2.erode(self.depth_a, np.ones((5, 5), np.uint8))[ia[:, 1], ia[:, 0]]
        hi = cv2.dilate(self.depth_a, np.ones((5, 5), np.uint8))[ia[:, 1], ia[:, 0]]
        smooth = np.isfinite(z) & np.isfinite(hi) & (hi - lo < 0.05 * z)
        p_a = self.camera.unproject(pa.astype(np.float64)) * np.where(np.isfinite(z), z, 1.0)[:, None]
        p_b = p_a @ self.T_CbCa[:3, :3].T + self.T_CbCa[:3, 3]
        front = p_b[:, 2] > 0.05
        q = self.camera.project(np.where(front[:, None], p_b, [0.0, 0.0, 1.0]))
        inside = front & (q[:, 0] >= 0) & (q[:, 0] <= w - 1) & (q[:, 1] >= 0) & (q[:, 1] <= h - 1)
        ib = np.clip(np.round(q).astype(int), 0, [w - 1, h - 1])
        zb = self.depth_b[ib[:, 1], ib[:, 0]]
        visible = inside & (np.abs(zb - p_b[:, 2]) < 0.05 * p_b[:, 2])
        return q, smooth & visible


def match_precision(matches, truth, px: float = 3.0) -> dict:
    """Correct / total matches among those whose truth is known (`truth(points_a)` valid)."""
    q, valid = truth(matches.points_a)
    err = np.linalg.norm(q - matches.points_b.astype(np.float64), axis=1)
    n = int(valid.sum())
    correct = int((err[valid] < px).sum())
    return {"matches": n, "correct": correct, "precision": correct / n if n else 0.0}


def load_pairs(
    n: int, source: str, seed: int, gap: int = 4
) -> list[tuple[str, np.ndarray, np.ndarray, object]]:
    """(name, image a, image b, truth) pairs: EuRoC images or synthetic scenes warped by random
    homographies, or simulated frames `gap` apart along a preset motion (drivers.sim)."""
    import cv2

    rng = np.random.default_rng(seed)
    pairs = []
    if source == "sim":
        from drivers.sim import SimConfig, SimRecording
        from drivers.sim.recording import MAX_SIM_SECONDS
        from runtime.errors import ConfigError

        seconds = max(4.0, 0.25 * (n + 1) * gap)
        if seconds > MAX_SIM_SECONDS:
            raise ConfigError(f"--pairs {n} x --gap {gap} frames needs a {seconds:g} s simulated recording, "
                              f"more than its {MAX_SIM_SECONDS:g} s (4 h): give fewer pairs or a smaller gap")
        rec = SimRecording.from_preset(SimConfig(seconds=seconds, seed=seed))
        cam = rec.rig.camera
        for i in range(n):
            ia = int((i + 0.5) * (len(rec) - gap) / n)
            (fa, va), (fb, vb) = rec.render(ia), rec.render(ia + gap)
            truth = DepthTruth(
                cam,
                va.depth,
                vb.depth,
                rec.gt_source.camera_pose(fa.t_ns),
                rec.gt_source.camera_pose(fb.t_ns),
            )
            pairs.append((f"sim/{ia}-{ia + gap}", fa.image, fb.image, truth))
        return pairs
    files = sorted(EUROC_CAM0.glob("*.png")) if source == "euroc" else []
    if source == "euroc" and not files:
        raise SystemExit(f"no EuRoC images under {EUROC_CAM0}; use --source synthetic")
    for i in range(n):
        if files:
            f = files[int(i * len(files) / n)]
            img, name = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE), f"euroc/{f.name}"
        else:
            img, name = synthetic_scene(rng), f"synthetic/{i}"
        H = random_homography(rng, *img.shape)
        pairs.append((name, img, warp_pair(img, H, rng), HomographyTruth(H, img.shape)))
    return pairs


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--source",
        choices=["euroc", "synthetic", "sim"],
        default="euroc",
        help="EuRoC or synthetic images warped by homographies, or simulated frame pairs",
    )
    p.add_argument("--gap", type=count(1, 100), default=4,
                   help="sim: frames between the two images of a pair")
    p.add_argument("--pairs", type=count(1, 1000), default=10, help="number of image pairs")
    p.add_argument("--top-k", type=count(1, 100000), default=2048, help="keypoints per image (both backends)")
    p.add_argument("--px", type=number_in(0, 1000, low_open=True, unit=" px"), default=3.0,
                   help="correctness radius in pixels")
    p.add_argument("--threads", type=count(1, 256), default=2, help="ONNX Runtime intra-op threads")
    p.add_argument("--repeats", type=count(1, 1000), default=5, help="timed repeats per pair for latency")
    p.add_argument("--seed", type=count(0), default=0)
    p.add_argument(
        "--lighterglue",
        metavar="PATH",
        default=None,
        help="also time XFeat + LighterGlue with this graph (davio export-xfeat --lighterglue PATH)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    import cv2

    from models.matcher import DEFAULT_XFEAT_PATH, Matcher, refine_matches_lk

    cv2.setNumThreads(args.threads)
    pairs = load_pairs(args.pairs, args.source, args.seed, args.gap)
    results = {}
    backends = [("xfeat", DEFAULT_XFEAT_PATH, None), ("orb", None, None)]
    if args.lighterglue:
        backends.insert(1, ("xfeat+lg", DEFAULT_XFEAT_PATH, args.lighterglue))
    for name, path, glue in backends:
        m = Matcher(path, top_k=args.top_k, threads=args.threads, lighterglue_path=glue)
        det_ms, match_ms, refine_ms = [], [], []
        raw, refined = np.zeros(2), np.zeros(2)
        per_pair = []
        for _, a, b, truth in pairs:
            fa = m.detect(a)
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                fb = m.detect(b)
                t1 = time.perf_counter()
                mt = m.match_features(fa, fb)
                t2 = time.perf_counter()
                mr = refine_matches_lk(a, b, mt)
                t3 = time.perf_counter()
                det_ms.append(1e3 * (t1 - t0))
                match_ms.append(1e3 * (t2 - t1))
                refine_ms.append(1e3 * (t3 - t2))
            pr, pf = match_precision(mt, truth, args.px), match_precision(mr, truth, args.px)
            raw += [pr["correct"], pr["matches"]]
            refined += [pf["correct"], pf["matches"]]
            per_pair.append(pf["precision"])
        results[name] = {
            "detect_ms_median": float(np.median(det_ms)),
            "match_ms_median": float(np.median(match_ms)),
            "refine_ms_median": float(np.median(refine_ms)),
            "matches_per_pair_raw": raw[1] / len(pairs),
            "precision_raw": raw[0] / max(raw[1], 1),
            "matches_per_pair": refined[1] / len(pairs),
            "precision": refined[0] / max(refined[1], 1),
            "precision_min_pair": float(np.min(per_pair)),
            # the execution provider of the XFeat graph (ORB runs in OpenCV)
            "provider": (m.detector.session_info["providers"][0]
                         if hasattr(m.detector, "session_info") else "opencv"),
        }
    out = {
        "benchmark": NAME,
        "source": args.source,
        "pairs": len(pairs),
        "image_hw": list(pairs[0][1].shape),
        "top_k": args.top_k,
        "px": args.px,
        "threads": args.threads,
        "results": results,
    }
    if args.json:
        print(strict_dumps(out))
        return 0
    print(
        f"matcher on {len(pairs)} {args.source} pairs ({out['image_hw'][1]}x{out['image_hw'][0]}), "
        f"top-k {args.top_k}, correct within {args.px} px, {args.threads} threads"
    )
    print(
        f"{'backend':<8}{'detect ms':>10}{'match ms':>9}{'LK ms':>7}{'raw matches':>12}{'raw prec':>9}"
        f"{'matches':>8}{'precision':>10}{'worst pair':>11}"
    )
    for name, r in results.items():
        print(
            f"{name:<8}{r['detect_ms_median']:>10.1f}{r['match_ms_median']:>9.1f}{r['refine_ms_median']:>7.1f}"
            f"{r['matches_per_pair_raw']:>12.0f}{r['precision_raw']:>9.3f}{r['matches_per_pair']:>8.0f}"
            f"{r['precision']:>10.3f}{r['precision_min_pair']:>11.3f}"
        )
    return 0
