"""XFeat backend: committed graph, post-processing pieces, matching precision, errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from da3_contract_graph import build_da3_contract_graph

from models.inspect_model import inspect_model
from models.matcher import DEFAULT_XFEAT_PATH, Features, Matcher, XFeatDetector, mutual_nearest_neighbours
from models.matcher.features import match_levels
from models.matcher.xfeat import logits_to_heatmap, sample_bicubic, sample_bilinear
from runtime.errors import DataError, ModelError
from tools.benchmarks.matcher import (
    HomographyTruth,
    match_precision,
    random_homography,
    synthetic_scene,
    warp_pair,
)


def test_committed_graph_contract_and_notice():
    info = inspect_model(DEFAULT_XFEAT_PATH)
    assert info["contract"] == "davio.xfeat_backbone"
    assert info["model_card"]["licence"] == "Apache-2.0" and info["model_card"]["check"]["worst"] < 1e-3
    notice = (DEFAULT_XFEAT_PATH.parent / "NOTICE").read_text()
    assert "Apache License 2.0" in notice and "verlab/accelerated_features" in notice
    assert DEFAULT_XFEAT_PATH.stat().st_size < 5_000_000
    assert json.loads(DEFAULT_XFEAT_PATH.with_suffix(".json").read_text())["file"] == DEFAULT_XFEAT_PATH.name


@pytest.mark.parametrize(
    "fn,interp", [(sample_bicubic, cv2.INTER_CUBIC), (sample_bilinear, cv2.INTER_LINEAR)]
)
def test_sparse_sampling_matches_opencv_remap(fn, interp):
    rng = np.random.default_rng(0)
    fmap = rng.normal(size=(3, 20, 30)).astype(np.float32)
    u = rng.uniform(-1.5, 30.5, 400)
    v = rng.uniform(-1.5, 20.5, 400)
    ref = np.stack(
        [
            cv2.remap(
                fmap[c],
                u[None].astype(np.float32),
                v[None].astype(np.float32),
                interp,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=0,
            )[0]
            for c in range(3)
        ],
        axis=1,
    )
    np.testing.assert_allclose(fn(fmap, u, v), ref, atol=2e-5)


def test_heatmap_unfolds_cells_row_major():
    logits = np.full((65, 3, 4), -10.0, np.float32)
    logits[64] = 5.0  # "no keypoint" everywhere ...
    logits[8 * 5 + 2, 1, 3] = 20.0  # ... except cell (1, 3): pixel dy=5, dx=2
    heat = logits_to_heatmap(logits)
    assert heat.shape == (24, 32)
    assert np.unravel_index(np.argmax(heat), heat.shape) == (8 + 5, 24 + 2)
    np.testing.assert_allclose(heat.reshape(3, 8, 4, 8).sum(axis=(1, 3))[1, 3], 1.0, atol=1e-6)


def test_mutual_nearest_neighbours_against_brute_force():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(60, 16)).astype(np.float32)
    b = np.concatenate([a[:40] + 0.1 * rng.normal(size=(40, 16)), rng.normal(size=(30, 16))]).astype(
        np.float32
    )
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    expect = []
    for i in range(len(a)):
        j = max(range(len(b)), key=lambda k: float(a[i] @ b[k]))
        if max(range(len(a)), key=lambda k: float(a[k] @ b[j])) == i:
            sims = sorted((float(a[i] @ b[k]) for k in range(len(b))), reverse=True)
            d1, d2 = np.sqrt(2 - 2 * sims[0]), np.sqrt(2 - 2 * sims[1])
            expect.append((i, j, d1 < 0.8 * d2))
    ia, ib, s = mutual_nearest_neighbours(a, b)
    assert [(i, j) for i, j, _ in expect] == list(zip(ia.tolist(), ib.tolist(), strict=True))
    np.testing.assert_allclose(s, np.einsum("ij,ij->i", a[ia], b[ib]), rtol=1e-6)
    ia, ib, _ = mutual_nearest_neighbours(a, b, ratio=0.8)
    assert [(i, j) for i, j, keep in expect if keep] == list(zip(ia.tolist(), ib.tolist(), strict=True))
    assert all(len(x) == 0 for x in mutual_nearest_neighbours(a[:0], b))


def test_detect_outputs():
    img = synthetic_scene(np.random.default_rng(2), 240, 336)
    f = XFeatDetector(top_k=500, threads=1).detect(img)
    assert 100 < len(f) <= 500
    assert f.desc.shape == (len(f), 64)
    np.testing.assert_allclose(np.linalg.norm(f.desc, axis=1), 1.0, atol=1e-5)
    assert (np.diff(f.scores) <= 0).all()
    assert (f.kpts >= 0).all() and (f.kpts[:, 0] <= 335).all() and (f.kpts[:, 1] <= 239).all()


@pytest.mark.parametrize("backend", ["xfeat", "orb"])
def test_precision_on_synthetic_homography_pair(backend):
    rng = np.random.default_rng(3)
    img = synthetic_scene(rng)
    H = random_homography(rng, *img.shape)
    b = warp_pair(img, H, rng)
    m = Matcher(DEFAULT_XFEAT_PATH if backend == "xfeat" else None, top_k=2048, threads=2)
    r = match_precision(m.match(img, b), HomographyTruth(H, img.shape))
    assert r["matches"] >= 200 and r["precision"] >= 0.8, r


def _zoom(z: float, shape: tuple[int, int]) -> np.ndarray:
    """Homography of a zoom by z about the image centre (pixel centres at integers)."""
    h, w = shape
    return np.array([[z, 0, (1 - z) * (w - 1) / 2], [0, z, (1 - z) * (h - 1) / 2], [0, 0, 1.0]])


def test_pyramid_features_match_across_a_zoom_that_defeats_single_scale():
    rng = np.random.default_rng(3)
    img = synthetic_scene(rng)
    H = _zoom(1.8, img.shape)                         # the place seen again from 1.8x nearer
    b = cv2.warpPerspective(img, H, (img.shape[1], img.shape[0]), flags=cv2.INTER_LINEAR)
    m = Matcher(DEFAULT_XFEAT_PATH, top_k=1024, threads=2)
    truth = HomographyTruth(H, img.shape)
    single = match_precision(m.match_features(m.detect(img), m.detect(b)), truth)
    fa, fb = m.detect_pyramid(img, (1.0, 0.7, 0.5)), m.detect_pyramid(b, (1.0, 0.7, 0.5))
    pyramid = match_precision(m.match_features(fa, fb), truth)
    assert single["correct"] < 20, single
    assert pyramid["correct"] >= 80 and pyramid["precision"] >= 0.5, pyramid
    # per-level budgets keep the keypoint density: 1024, 1024 * 0.49, 1024 * 0.25
    assert np.bincount(fa.level).tolist() == [1024, 502, 256]
    single_a = m.detect(img)                          # reused as level 0: the same features
    again = m.detect_pyramid(img, (1.0, 0.7, 0.5), base=single_a)
    assert np.array_equal(again.kpts, fa.kpts) and np.array_equal(again.desc, fa.desc)
    assert np.array_equal(again.level, fa.level)
    with pytest.raises(ModelError, match="do not fit"):
        m.detect_pyramid(img[:240], (1.0, 0.7, 0.5), base=single_a)
    assert fa.desc.shape == (len(fa), 64) and fa.kpts.shape == (len(fa), 2) and fa.image_size == (640, 480)
    assert (fa.kpts >= -0.5).all() and (fa.kpts[:, 0] <= 639.5).all() and (fa.kpts[:, 1] <= 479.5).all()


def test_pyramid_keypoints_are_in_full_resolution_pixels():
    """Level 1 (scale 0.5) of an image enlarged 2x by OpenCV is, nearly, the original image: its
    keypoints must land where the original's keypoints map under OpenCV's pixel-centre convention
    u_big = 2 (u + 0.5) - 0.5."""
    img = synthetic_scene(np.random.default_rng(4), 240, 320)
    big = cv2.resize(img, (640, 480), interpolation=cv2.INTER_LINEAR)
    det = XFeatDetector(top_k=1600, threads=1)
    f = det.detect_pyramid(big, (1.0, 0.5))
    lvl1 = f.kpts[f.level == 1]
    ref = 2.0 * (det.detect(img).kpts[:400] + 0.5) - 0.5
    d = np.linalg.norm(lvl1[:, None, :] - ref[None, :, :], axis=2).min(axis=0)
    assert len(lvl1) == 400 and np.median(d) < 0.5, (len(lvl1), np.median(d))
    with pytest.raises(ModelError, match="start at 1.0"):
        det.detect_pyramid(img, (0.7, 0.5))
    with pytest.raises(ModelError):
        det.detect_pyramid(img, (1.0, 0.5, 0.5))
    with pytest.raises(ModelError):
        det.detect_pyramid(img, (1.0, float("nan")))
    tiny = det.detect_pyramid(img[:40, :600], (1.0, 0.5))      # level 1 would be 20 px high: left out
    assert set(np.unique(tiny.level).tolist()) == {0}


def test_match_levels_is_one_to_one_and_drops_a_point_found_at_two_levels():
    rng = np.random.default_rng(7)
    n = 30
    d = rng.standard_normal((n, 64)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    kp = rng.uniform(0, 600, (n, 2)).astype(np.float32)
    noisy = d + 0.05 * rng.standard_normal(d.shape).astype(np.float32)
    noisy /= np.linalg.norm(noisy, axis=1, keepdims=True)
    single_a = Features(kp, np.ones(n, np.float32), d, (640, 480))
    single_b = Features(kp + 1.0, np.ones(n, np.float32), noisy, (640, 480))
    # single-level inputs: the same pairs as mutual nearest neighbours (best first)
    ia, ib, s = match_levels(single_a, single_b, ratio=0.8)
    ja, jb, _ = mutual_nearest_neighbours(d, noisy, ratio=0.8)
    pairs = sorted(zip(ia.tolist(), ib.tolist(), strict=True))
    assert pairs == sorted(zip(ja.tolist(), jb.tolist(), strict=True))
    assert (np.diff(s) <= 0).all()
    # each point also found at level 1 of both images (0.5 px away, a slightly different descriptor)
    d2 = d + 0.02 * rng.standard_normal(d.shape).astype(np.float32)
    d2 /= np.linalg.norm(d2, axis=1, keepdims=True)
    lv = np.repeat(np.int8([0, 1]), n)
    fa = Features(np.vstack([kp, kp + 0.5]), np.ones(2 * n, np.float32), np.vstack([d, d2]), (640, 480), lv)
    fb = Features(np.vstack([kp + 1.0, kp + 1.5]), np.ones(2 * n, np.float32), np.vstack([noisy, d2]),
                  (640, 480), lv)
    ia, ib, _ = match_levels(fa, fb, ratio=0.8)
    assert len(set(ia.tolist())) == len(ia) and len(set(ib.tolist())) == len(ib)
    assert sorted(set((ia % n).tolist())) == list(range(n))      # every point once ...
    assert len(ia) == n                                          # ... and only once
    assert (ia % n == ib % n).all()                              # and matched to itself
    m = Matcher(DEFAULT_XFEAT_PATH, threads=1).match_features(fa, fb)
    assert len(m) == n


@pytest.mark.slow
def test_precision_on_simulated_pairs():
    pytest.importorskip("drivers.sim", reason="needs the simulator")
    from tools.benchmarks.matcher import load_pairs

    pairs = load_pairs(2, "sim", seed=5, gap=4)
    for backend in (DEFAULT_XFEAT_PATH, None):
        m = Matcher(backend, top_k=2048, threads=2)
        tot = np.zeros(2)
        for _, a, b, truth in pairs:
            r = match_precision(m.match(a, b), truth)
            tot += [r["correct"], r["matches"]]
        assert tot[1] >= 200 and tot[0] / tot[1] >= 0.8, (backend, tot)


def test_errors(tmp_path):
    with pytest.raises(ModelError, match="davio export-xfeat"):
        XFeatDetector(tmp_path / "absent.onnx")
    with pytest.raises(ModelError, match="not a XFeat graph"):
        XFeatDetector(build_da3_contract_graph(tmp_path / "da3.onnx"))
    det = XFeatDetector(threads=1)
    with pytest.raises(DataError):
        det.detect(np.zeros((16, 16), np.uint8))
    with pytest.raises(DataError):
        det.detect(np.zeros((64, 64), np.float32))
    with pytest.raises(ValueError):
        Matcher(None, ratio=0.0)


def test_a_missing_or_folder_model_path_is_named(tmp_path):
    with pytest.raises(ModelError, match="XFeat model not found: .*absent.onnx. Export it with: davio"):
        XFeatDetector(tmp_path / "absent.onnx")
    (tmp_path / "xfeat.onnx").mkdir()
    with pytest.raises(ModelError, match="xfeat.onnx is a folder, not an ONNX model file$"):
        XFeatDetector(tmp_path / "xfeat.onnx")
