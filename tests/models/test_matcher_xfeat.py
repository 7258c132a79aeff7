"""XFeat backend: committed graph, post-processing pieces, matching precision, errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from da3_contract_graph import build_da3_contract_graph

from models.inspect_model import inspect_model
from models.matcher import DEFAULT_XFEAT_PATH, Matcher, XFeatDetector, mutual_nearest_neighbours
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
