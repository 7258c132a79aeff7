"""Lengthening a refused start-up window with the frames that arrived while the model ran.

Within a 0.8 s window an accelerometer bias cannot be told from acceleration, so a window with weak
excitation is refused (`scale_unobservable`, `ill_conditioned`, `small_baseline`) although nothing in
it is wrong: it is too short. By the time DA3 answers, the front-end has tracked the window's features
into newer frames. Those tracks carry DA3's points (DA3's scale, camera 0's frame) into the newer
frames, whose poses PnP gives in the same frame and scale; the window then spans more IMU time and is
solved again with the same gates -- without a second model call.

Frames: C0 = the window's first camera (DA3's world); C_j = a newer frame's camera. Tracks are
undistorted normalized coordinates (the rig's camera model), the same pinhole view as DA3's K.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from runtime.ffinit.config import FFInitConfig
from runtime.ffinit.window import ImageObservations, Rejection

#: Rejections a longer span can cure (the scale or the baseline is too weakly observed).
EXTENDABLE = ("scale_unobservable", "ill_conditioned", "small_baseline")


@dataclass
class ExtensionSeed:
    """What a refused window keeps for a longer re-solve.

    Attributes:
        t_cam_ns: (N,) camera-clock stamps of the DA3 images, int64 ns.
        observations: the N sampled ImageObservations of the DA3 call (reused as they are).
        depth: (N, H, W) DA3 up-to-scale z-depths; conf: (N, H, W) DA3 confidences.
        K: (3, 3) intrinsics of the rectified pinhole view the depth maps live in.
        reason: the rejection that asked for a longer span.
    """

    t_cam_ns: np.ndarray
    observations: list[ImageObservations]
    depth: np.ndarray
    conf: np.ndarray
    K: np.ndarray
    reason: str

    @property
    def last_ns(self) -> int:
        return int(self.t_cam_ns[-1])


@dataclass
class TrackSet:
    """The front-end's tracks in one frame: ids (M,) and undistorted normalized coordinates z (M, 2)."""

    t_cam_ns: int
    ids: np.ndarray
    z: np.ndarray


def _sample_map(m: np.ndarray, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear values of map m at pixels uv (pixel centres at integers), and the max/min ratio of the 3x3
    neighbourhood of the nearest pixel (inf outside the image or where a neighbour is not a positive
    finite value)."""
    h, w = m.shape
    finite = np.all(np.isfinite(uv), axis=1)
    iu = np.where(finite, np.rint(np.where(finite, uv[:, 0], -1.0)), -1).astype(int)
    iv = np.where(finite, np.rint(np.where(finite, uv[:, 1], -1.0)), -1).astype(int)
    inside = finite & (iu >= 1) & (iu < w - 1) & (iv >= 1) & (iv < h - 1)
    val = np.full(len(uv), np.nan)
    ratio = np.full(len(uv), np.inf)
    if not np.any(inside):
        return val, ratio
    iu_in, iv_in = iu[inside], iv[inside]
    nb = np.stack([m[iv_in + dv, iu_in + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)], axis=1)
    ok = np.all(np.isfinite(nb) & (nb > 0), axis=1)
    ratio[inside] = np.where(ok, nb.max(axis=1) / np.where(ok, nb.min(axis=1), 1.0), np.inf)
    u, v = uv[inside, 0], uv[inside, 1]
    u0 = np.clip(np.floor(u).astype(int), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(int), 0, h - 2)
    fu, fv = u - u0, v - v0
    val[inside] = ((1 - fv) * ((1 - fu) * m[v0, u0] + fu * m[v0, u0 + 1])
                   + fv * ((1 - fu) * m[v0 + 1, u0] + fu * m[v0 + 1, u0 + 1]))
    return val, ratio


def track_points_C0(seed: ExtensionSeed, tracks: Sequence[TrackSet],
                    cfg: FFInitConfig) -> dict[int, tuple[np.ndarray, float]]:
    """DA3 points in C0 (DA3 scale) of the tracks seen in the window's images: id -> (p_C0, conf).

    Per image, a track's pixel takes DA3's depth when its confidence exceeds the image's
    `conf_percentile` and no depth edge runs through it (3x3 max/min depth below
    1 + extension_edge_ratio: KLT corners sit on occlusion boundaries, where a pixel's depth may be
    either surface's); depth and confidence are interpolated bilinearly. A track seen in several images
    takes the median of its points, and is dropped when one of them lies further than
    extension_point_spread x the median of its depths (in the cameras that see it) from that median.
    """
    by_id: dict[int, list[tuple[np.ndarray, float, float]]] = {}
    K = seed.K
    for i, ts in enumerate(tracks):
        if len(ts.ids) == 0:
            continue
        obs = seed.observations[i]
        uv = ts.z * np.array([K[0, 0], K[1, 1]]) + K[:2, 2]
        d, ratio = _sample_map(seed.depth[i], uv)
        c, _ = _sample_map(seed.conf[i], uv)
        dm, cm = seed.depth[i], seed.conf[i]
        valid = np.isfinite(dm) & (dm > 0) & np.isfinite(cm)   # as runtime.ffinit.sampling
        thr = np.percentile(cm[valid], cfg.conf_percentile) if np.any(valid) else np.inf
        good = np.isfinite(d) & (d > 0) & np.isfinite(c) & (c > thr) & \
            (ratio < 1.0 + cfg.extension_edge_ratio) & np.all(np.isfinite(ts.z), axis=1)
        zt = np.column_stack([ts.z[good], np.ones(int(good.sum()))])
        p = (d[good, None] * zt) @ obs.R_C0Ci.T + obs.p_C0Ci
        for tid, pk, ck, dk in zip(ts.ids[good], p, c[good], d[good], strict=True):
            by_id.setdefault(int(tid), []).append((pk, float(ck), float(dk)))
    out: dict[int, tuple[np.ndarray, float]] = {}
    for tid, items in by_id.items():
        P = np.array([it[0] for it in items])
        p_med = np.median(P, axis=0)
        depth = float(np.median([it[2] for it in items]))
        if len(items) > 1 and np.max(np.linalg.norm(P - p_med, axis=1)) > cfg.extension_point_spread * depth:
            continue
        out[tid] = (p_med, float(np.median([it[1] for it in items])))
    return out


def pnp_observations(points: dict[int, tuple[np.ndarray, float]], ts: TrackSet, cfg: FFInitConfig,
                     focal_px: float, rng: np.random.Generator,
                     guess: tuple[np.ndarray, np.ndarray] | None = None) -> ImageObservations | Rejection:
    """A newer frame's observations of the DA3 points: its pose in C0 at DA3's scale by PnP RANSAC
    (OpenCV, then Levenberg-Marquardt on the inliers), at most max_points_per_image inliers with their
    depth in C_j. focal_px: converts extension_pnp_px to normalized units (fx of the rectified view).
    guess: (rvec, tvec) of T_CjC0 from the previous frame."""
    import cv2

    keep = [k for k, tid in enumerate(ts.ids) if int(tid) in points and np.all(np.isfinite(ts.z[k]))]
    if len(keep) < cfg.extension_min_inliers:
        return Rejection("extension_few_tracks",
                         f"{len(keep)} tracks carry DA3 points into the frame at {ts.t_cam_ns} ns "
                         f"(< {cfg.extension_min_inliers})")
    obj = np.array([points[int(ts.ids[k])][0] for k in keep], np.float64)
    conf = np.array([points[int(ts.ids[k])][1] for k in keep])
    img = np.ascontiguousarray(ts.z[keep], np.float64)
    thr = cfg.extension_pnp_px / focal_px
    use_guess = guess is not None
    rvec0, tvec0 = (guess if use_guess else (np.zeros(3), np.zeros(3)))
    ok, rvec, tvec, inl = cv2.solvePnPRansac(obj, img, np.eye(3), None, rvec0.copy().reshape(3, 1),
                                             tvec0.copy().reshape(3, 1), use_guess, 200, thr, 0.999,
                                             flags=cv2.SOLVEPNP_ITERATIVE)
    n_in = 0 if inl is None else len(inl)
    if not ok or n_in < cfg.extension_min_inliers or n_in < cfg.extension_min_inlier_fraction * len(keep):
        return Rejection("extension_pnp_failed",
                         f"PnP kept {n_in} of {len(keep)} DA3 points in the frame at {ts.t_cam_ns} ns")
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], np.eye(3), None, rvec, tvec)
    R_CjC0 = cv2.Rodrigues(rvec)[0]
    t_CjC0 = tvec.ravel()
    p_Cj = obj @ R_CjC0.T + t_CjC0
    proj = p_Cj[:, :2] / p_Cj[:, 2:3]
    err = np.linalg.norm(proj - img, axis=1)
    good = (p_Cj[:, 2] > 0) & (err < thr)
    idx = np.flatnonzero(good)
    if len(idx) < cfg.extension_min_inliers:
        return Rejection("extension_pnp_failed",
                         f"{len(idx)} DA3 points in front of the camera within {cfg.extension_pnp_px} px "
                         f"in the frame at {ts.t_cam_ns} ns")
    if len(idx) > cfg.max_points_per_image:
        idx = np.sort(rng.choice(idx, cfg.max_points_per_image, replace=False))
    R_C0Cj = R_CjC0.T
    return ImageObservations(z=img[idx], depth=p_Cj[idx, 2], conf=conf[idx], R_C0Ci=R_C0Cj,
                             p_C0Ci=-R_C0Cj @ t_CjC0)


def extended_observations(seed: ExtensionSeed, tracks: Sequence[TrackSet],
                          cfg: FFInitConfig) -> list[tuple[int, ImageObservations]] | Rejection:
    """(t_cam_ns, observations) of each newer frame (tracks after the window's images), or the Rejection.

    tracks: the front-end's tracks in the window's N images (same order), then in the newer frames.
    """
    import cv2

    n = len(seed.t_cam_ns)
    if len(tracks) <= n:
        return Rejection("extension_no_frames", "no frame after the window's images")
    h, w = seed.depth.shape[1:]
    cx, cy = seed.K[0, 2], seed.K[1, 2]
    if not (0.25 * w < cx < 0.75 * w and 0.25 * h < cy < 0.75 * h):
        return Rejection("extension_depth_size",
                         f"the depth maps ({w}x{h}) do not hold K's principal point ({cx:.0f}, {cy:.0f}) "
                         "near their centre: they are not at the resolution K describes")
    points = track_points_C0(seed, tracks[:n], cfg)
    rng = np.random.default_rng(cfg.seed)
    out: list[tuple[int, ImageObservations]] = []
    guess = None
    for ts in tracks[n:]:
        obs = pnp_observations(points, ts, cfg, float(seed.K[0, 0]), rng, guess)
        if isinstance(obs, Rejection):
            return obs
        R_CjC0 = obs.R_C0Ci.T
        guess = (cv2.Rodrigues(R_CjC0)[0].ravel(), -R_CjC0 @ obs.p_C0Ci)
        out.append((int(ts.t_cam_ns), obs))
    return out
