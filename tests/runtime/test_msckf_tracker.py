"""KLT tracker: synthetic warps with known motion, occlusions, bad frames, real EuRoC images."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib import Pinhole, PinholeRadtan, read_euroc_rig
from runtime.errors import ConfigError, DataError
from runtime.events import Frame
from runtime.msckf.tracker import KltTracker, TrackerConfig

W, H = 640, 480


def textured_image(seed: int = 0) -> np.ndarray:
    """A smooth random texture with plenty of FAST corners (uint8, H x W)."""
    rng = np.random.default_rng(seed)
    coarse = rng.uniform(0, 255, size=(H // 8, W // 8)).astype(np.float32)
    img = cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC)
    img += rng.uniform(-40, 40, size=(H // 2, W // 2)).astype(np.float32).repeat(2, 0).repeat(2, 1)
    img = cv2.GaussianBlur(img, (0, 0), 1.2)
    return np.clip(img, 0, 255).astype(np.uint8)


def warp(img: np.ndarray, Hm: np.ndarray) -> np.ndarray:
    """img warped so that a point x (homogeneous pixel) of img moves to Hm x."""
    return cv2.warpPerspective(img, Hm, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def apply_h(Hm: np.ndarray, uv: np.ndarray) -> np.ndarray:
    p = np.c_[uv, np.ones(len(uv))] @ Hm.T
    return p[:, :2] / p[:, 2:]


def pinhole() -> Pinhole:
    return Pinhole(W, H, 500.0, 500.0, W / 2 - 0.5, H / 2 - 0.5)


HOMOGRAPHIES = {
    "translation": np.array([[1.0, 0.0, 3.37], [0.0, 1.0, -2.61], [0.0, 0.0, 1.0]]),
    "rotation_scale": np.array([[1.005 * np.cos(0.02), -1.005 * np.sin(0.02), 6.0],
                                [1.005 * np.sin(0.02), 1.005 * np.cos(0.02), -11.0], [0.0, 0.0, 1.0]]),
    "perspective": np.array([[1.0, 0.01, 2.0], [-0.005, 0.995, 1.5], [1.5e-5, -1e-5, 1.0]]),
}


@pytest.mark.parametrize("name", sorted(HOMOGRAPHIES))
def test_tracks_follow_known_warp(name: str) -> None:
    Hm = HOMOGRAPHIES[name]
    img0 = textured_image()
    img1 = warp(img0, Hm)
    tracker = KltTracker(pinhole(), TrackerConfig(equalization="none"))
    r0 = tracker.track(Frame(0, img0))
    assert len(r0) == 200 and r0.stats["n_new"] == 200
    r1 = tracker.track(Frame(50_000_000, img1))
    assert r1.stats["n_tracked"] >= 180
    common, i0, i1 = np.intersect1d(r0.ids, r1.ids, return_indices=True)
    assert common.size == r1.stats["n_tracked"]
    expected = apply_h(Hm, r0.uv[i0])
    err = np.linalg.norm(r1.uv[i1] - expected, axis=1)
    assert np.max(err) < 0.3, f"max error {np.max(err):.3f} px"
    # the normalized coordinates are the pinhole back-projection of the pixels
    K = pinhole().K
    np.testing.assert_allclose(r1.xy, (r1.uv - K[:2, 2]) / [K[0, 0], K[1, 1]], atol=1e-12)


def test_new_ids_are_unique_and_persistent() -> None:
    img0 = textured_image(1)
    tracker = KltTracker(pinhole())
    ids = []
    Hm = np.eye(3)
    for k in range(5):
        Hm = HOMOGRAPHIES["translation"] @ Hm
        r = tracker.track(Frame(k * 50_000_000, warp(img0, Hm) if k else img0))
        assert np.unique(r.ids).size == len(r)
        assert r.ids.dtype == np.int64 and r.uv.dtype == np.float64 and r.xy.shape == (len(r), 2)
        ids.append(r.ids)
    # features tracked to the end keep the ids they got in frame 0
    assert np.intersect1d(ids[0], ids[-1]).size >= 150
    # ids of corners detected later are all larger than every earlier id
    for k in range(1, 5):
        fresh = np.setdiff1d(ids[k], np.concatenate(ids[:k]))
        if fresh.size:
            assert fresh.min() > np.concatenate(ids[:k]).max()


def _tracker_with_checks(fb: float, ransac: bool, **kw: object) -> KltTracker:
    return KltTracker(pinhole(), TrackerConfig(equalization="none", fb_check_px=fb, ransac=ransac, **kw))


def test_forward_backward_rejects_occlusion() -> None:
    Hm = HOMOGRAPHIES["translation"]
    img0 = textured_image(2)
    img1 = warp(img0, Hm)
    # paste a different texture over a square: features inside are occluded in frame 1
    x0, y0, s = 200, 150, 160
    img1[y0:y0 + s, x0:x0 + s] = textured_image(99)[y0:y0 + s, x0:x0 + s]
    tracker = _tracker_with_checks(fb=1.0, ransac=False)
    r0 = tracker.track(Frame(0, img0))
    expected_all = apply_h(Hm, r0.uv)
    occluded = ((expected_all[:, 0] > x0 - 2) & (expected_all[:, 0] < x0 + s + 2)
                & (expected_all[:, 1] > y0 - 2) & (expected_all[:, 1] < y0 + s + 2))
    assert occluded.sum() >= 10
    r1 = tracker.track(Frame(1, img1))
    survived = np.isin(r0.ids[occluded], r1.ids)
    assert survived.mean() <= 0.2, f"{survived.sum()} of {occluded.sum()} occluded features survived"
    assert r1.stats["n_fb_rejected"] >= 0.5 * occluded.sum()
    common, i0, i1 = np.intersect1d(r0.ids, r1.ids, return_indices=True)
    visible = ~occluded[i0]
    err = np.linalg.norm(r1.uv[i1] - expected_all[i0], axis=1)
    assert visible.sum() >= 0.9 * (~occluded).sum()
    assert np.max(err[visible]) < 0.3
    # without the check, occluded features come back at wrong places
    plain = _tracker_with_checks(fb=0.0, ransac=False)
    q0 = plain.track(Frame(0, img0))
    q1 = plain.track(Frame(1, img1))
    _, j0, j1 = np.intersect1d(q0.ids, q1.ids, return_indices=True)
    assert np.max(np.linalg.norm(q1.uv[j1] - apply_h(Hm, q0.uv[j0]), axis=1)) > 2.0


def test_ransac_rejects_inconsistent_motion() -> None:
    """Small patches moving independently violate the epipolar geometry of the dominant motion."""
    img0 = textured_image(3)
    Hm = HOMOGRAPHIES["translation"]
    img1 = warp(img0, Hm)
    rng = np.random.default_rng(0)
    s = 48
    moved = np.zeros((H, W), bool)
    for k in range(8):
        x0, y0 = 40 + 70 * k, 60 + (k % 3) * 130
        dx, dy = rng.choice([-1, 1], 2) * rng.uniform(5, 8, 2)
        M = np.array([[1.0, 0.0, dx], [0.0, 1.0, dy]])
        shifted = cv2.warpAffine(img0, M, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        ys, xs = slice(y0, y0 + s), slice(x0, x0 + s)
        img1[ys, xs] = shifted[ys, xs]
        moved[ys, xs] = True
    # a patch moved along its epipolar line cannot be told from the dominant motion: the tighter the
    # threshold, the more moved features go (OpenCV's FM_RANSAC, the default, and USAC_MAGSAC alike)
    for method, threshold_px, rejected in (("ransac", 1.0, 5), ("ransac", 2.0, 4), ("magsac", 1.0, 5)):
        tracker = _tracker_with_checks(fb=1.0, ransac=True, ransac_method=method,
                                       ransac_threshold_px=threshold_px)
        r0 = tracker.track(Frame(0, img0))
        r1 = tracker.track(Frame(1, img1))
        assert r1.stats["n_ransac_rejected"] >= rejected, (method, threshold_px)
        common, i0, i1 = np.intersect1d(r0.ids, r1.ids, return_indices=True)
        err = np.linalg.norm(r1.uv[i1] - apply_h(Hm, r0.uv[i0]), axis=1)
        assert np.mean(err < 0.5) > 0.97
    # without RANSAC the independently moving features stay in
    plain = _tracker_with_checks(fb=1.0, ransac=False)
    q0 = plain.track(Frame(0, img0))
    q1 = plain.track(Frame(1, img1))
    _, j0, j1 = np.intersect1d(q0.ids, q1.ids, return_indices=True)
    assert np.sum(np.linalg.norm(q1.uv[j1] - apply_h(Hm, q0.uv[j0]), axis=1) > 2.0) >= 5


def test_undistortion_through_camera_model() -> None:
    cam = PinholeRadtan(W, H, 450.0, 452.0, 320.0, 240.0, [-0.28, 0.07, 2e-4, 2e-5])
    tracker = KltTracker(cam)
    r = tracker.track(Frame(0, textured_image(4)))
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
    ref = cv2.undistortPoints(r.uv.reshape(-1, 1, 2), cam.K, np.asarray(cam.distortion), criteria=crit)
    ref = ref.reshape(-1, 2)
    np.testing.assert_allclose(r.xy, ref, atol=1e-7)


def test_bad_frames_are_counted_and_tracking_resumes() -> None:
    img0 = textured_image(5)
    tracker = KltTracker(pinhole())
    r0 = tracker.track(Frame(0, img0))
    dark = tracker.track(Frame(1, np.full((H, W), 3, np.uint8)))
    assert dark.stats["dark"] and len(dark) == 0
    frozen = tracker.track(Frame(2, img0.copy()))
    assert frozen.stats["frozen"] and len(frozen) == 0
    r3 = tracker.track(Frame(3, warp(img0, HOMOGRAPHIES["translation"])))
    assert r3.stats["n_tracked"] >= 180 and np.intersect1d(r0.ids, r3.ids).size >= 180
    rep = tracker.report()
    assert rep["dark_frames"] == 1 and rep["frozen_frames"] == 1 and rep["frames"] == 4


def test_featureless_and_bad_input() -> None:
    tracker = KltTracker(pinhole())
    flat = np.full((H, W), 128, np.uint8)
    flat[::2, ::2] = 131  # std ~1.3: counted as dark/featureless
    assert len(tracker.track(Frame(0, flat))) == 0
    smooth = np.tile(np.linspace(20, 230, W).astype(np.uint8), (H, 1))  # a ramp: no corners at all
    r = tracker.track(Frame(1, smooth))
    assert len(r) == 0 and r.stats["n_new"] == 0 and not r.stats["dark"]
    r = tracker.track(Frame(2, textured_image(6)))  # features appear once texture does
    assert len(r) == 200
    with pytest.raises(DataError, match="640x480"):
        tracker.track(Frame(3, np.zeros((240, 320), np.uint8)))
    with pytest.raises(DataError, match="uint8"):
        tracker.track(Frame(4, np.zeros((H, W), np.float32)))
    late = tracker.track(Frame(2, textured_image(6)))
    assert late.stats["out_of_order"] and len(late) == 0
    assert tracker.report()["non_monotonic_frames"] == 1
    with pytest.raises(ConfigError):
        TrackerConfig(equalization="gamma")
    with pytest.raises(ConfigError):
        TrackerConfig(window_px=20)


@pytest.mark.parametrize("equalization", ["histogram", "clahe"])
def test_equalization_modes_track_brightness_change(equalization: str) -> None:
    img0 = textured_image(7)
    Hm = HOMOGRAPHIES["translation"]
    img1 = np.clip(warp(img0, Hm).astype(np.float32) * 0.6 + 10, 0, 255).astype(np.uint8)  # darker frame
    tracker = KltTracker(pinhole(), TrackerConfig(equalization=equalization))
    r0 = tracker.track(Frame(0, img0))
    r1 = tracker.track(Frame(1, img1))
    _, i0, i1 = np.intersect1d(r0.ids, r1.ids, return_indices=True)
    assert i1.size >= 170
    err = np.linalg.norm(r1.uv[i1] - apply_h(Hm, r0.uv[i0]), axis=1)
    assert np.median(err) < 0.1


@pytest.mark.slow
def test_real_euroc_head_keeps_150_tracks(euroc_head) -> None:
    from pathlib import Path

    cam0 = Path(euroc_head) / "mav0" / "cam0" / "data"
    files = sorted(cam0.glob("*.png"))
    assert len(files) >= 90
    cam = read_euroc_rig(euroc_head).camera
    tracker = KltTracker(cam)
    counts = []
    for f in files:
        img = cv2.imread(str(f), cv2.IMREAD_GRAYSCALE)
        counts.append(len(tracker.track(Frame(int(f.stem), img))))
    assert min(counts) >= 150 and np.mean(counts) >= 150
    # the drone sits still: features survive the whole head
    assert tracker.report()["new_features"] < 400


def _occluded_pair(side: int) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    img0 = textured_image(4)
    img1 = warp(img0, HOMOGRAPHIES["translation"])
    x0, y0 = 40, 30
    img1[y0:y0 + side, x0:x0 + side] = textured_image(98)[y0:y0 + side, x0:x0 + side]
    return img0, img1, (x0, y0, side)


@pytest.mark.parametrize("side", [90, 200])
def test_detection_waits_for_missing_tracks_and_fills_the_emptied_cells(side: int) -> None:
    """As OpenVINS' TrackKLT: corners are detected once at least min(20, num_pts / 2) tracks are missing,
    and only in grid cells holding fewer tracks than their share; with min_new_features 1 every loss is
    topped up."""
    img0, img1, (x0, y0, s) = _occluded_pair(side)
    tracker = KltTracker(pinhole(), TrackerConfig(equalization="none"))
    tracker.track(Frame(0, img0))
    r1 = tracker.track(Frame(50_000_000, img1))
    missing = 200 - r1.stats["n_tracked"]
    if missing < 20:
        assert r1.stats["n_new"] == 0
    else:
        assert r1.stats["n_new"] > 0 and len(r1) <= 200
        # the new corners lie in grid cells (5 x 5 of 128 x 96 px) holding fewer tracks than their share (8)
        def cell_of(uv: np.ndarray) -> list[tuple[int, int]]:
            return [(int(u // (W / 5)), int(v // (H / 5))) for u, v in uv]

        tracked = cell_of(r1.uv[:r1.stats["n_tracked"]])
        below = {(cx, cy) for cx in range(5) for cy in range(5) if tracked.count((cx, cy)) < 8}
        assert set(cell_of(r1.uv[r1.stats["n_tracked"]:])) <= below
        assert any(x0 <= u < x0 + s and y0 <= v < y0 + s for u, v in r1.uv[r1.stats["n_tracked"]:])
    topped = KltTracker(pinhole(), TrackerConfig(equalization="none", min_new_features=1))
    topped.track(Frame(0, img0))
    q1 = topped.track(Frame(50_000_000, img1))
    assert q1.stats["n_new"] > 0 and len(q1) >= 195
    assert (side == 90) == (missing < 20)


def test_kernels_are_loaded_when_the_tracker_is_built() -> None:
    """The first frame does not wait for numba: building the tracker loads its detection and (radial-
    tangential) undistortion kernels (checked in a fresh process, where nothing loaded them before)."""
    import subprocess
    import sys

    code = (
        "from calib import PinholeRadtan\n"
        "from calib.radtan_kernel import undistort_radtan\n"
        "from runtime.msckf.corner_grid import block_neighbourhoods, choose_corners\n"
        "from runtime.msckf.tracker import KltTracker\n"
        "kernels = (block_neighbourhoods, choose_corners, undistort_radtan)\n"
        "assert not any(k.signatures for k in kernels)\n"
        "KltTracker(PinholeRadtan(640, 480, 500.0, 500.0, 320.0, 240.0, [-0.28, 0.07, 2e-4, 1e-5]))\n"
        "print([bool(k.signatures) for k in kernels])\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[True, True, True]"


@pytest.mark.parametrize("threshold", [20, 5])
def test_fast_in_a_cell_finds_what_fast_finds_on_the_whole_image(threshold: int) -> None:
    """Detection runs FAST on one grid cell's view at a time: the corners, positions and responses equal
    those OpenCV's FAST finds on the whole image inside that cell, at the image's edges too."""
    img = textured_image(7)
    fast = cv2.FastFeatureDetector_create(threshold=threshold, nonmaxSuppression=True)
    whole = fast.detect(img, None)
    ref_uv = cv2.KeyPoint_convert(whole).astype(np.float64)
    ref = np.column_stack([ref_uv, [k.response for k in whole]])
    for x0, x1, y0, y1 in [(0, 128, 0, 96), (128, 256, 96, 192), (512, 640, 384, 480), (300, 301, 10, 470)]:
        got = KltTracker._fast_in(img, fast, x0, x1, y0, y1)
        inside = ((ref[:, 0] >= x0) & (ref[:, 0] < x1) & (ref[:, 1] >= y0) & (ref[:, 1] < y1))
        assert inside.sum() > 0 or (x1 - x0) == 1
        order = np.lexsort((got[:, 0], got[:, 1]))
        expected = ref[inside][np.lexsort((ref[inside][:, 0], ref[inside][:, 1]))]
        np.testing.assert_array_equal(got[order], expected)
