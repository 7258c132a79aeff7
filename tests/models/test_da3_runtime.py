"""OnnxDA3 on contract-only graphs: preprocessing, output mapping, metric scale, load errors."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from da3_contract_graph import build_da3_contract_graph

from calib import Pinhole, PinholeRadtan
from models.da3 import OnnxDA3
from models.da3.preprocess import IMAGENET_MEAN, IMAGENET_STD, normalise_image
from models.depth_model import DepthModel
from runtime.errors import DataError, ModelError
from runtime.events import Frame
from runtime.geometry import make_pose, so3_exp

GAIN, FOCAL = 2.0, 30.0
CAM = Pinhole(96, 64, 80.0, 82.0, 47.0, 31.5)


@pytest.fixture
def graph(tmp_path):
    return build_da3_contract_graph(tmp_path / "da3_contract_28x42.onnx", 28, 42, GAIN, FOCAL)


def gradient_frames(n: int, cam=CAM) -> list[Frame]:
    u = np.arange(cam.width, dtype=np.float64)
    img = np.tile(40 + 160 * u / (cam.width - 1), (cam.height, 1)).round().astype(np.uint8)
    return [Frame(t_ns=i * 50_000_000, image=img) for i in range(n)]


def random_poses(n: int, rng: np.random.Generator) -> np.ndarray:
    T_WC = [
        make_pose(so3_exp(rng.normal(scale=0.2, size=3)), rng.normal(scale=1.5, size=3)) for _ in range(n)
    ]
    return np.linalg.inv(np.stack(T_WC))


def expected_red_depth(img: np.ndarray) -> np.ndarray:
    """The contract graph's depth for a grey image, at full resolution (linear image => resize-exact)."""
    red = (img.astype(np.float64) / 255.0 - IMAGENET_MEAN[0]) / IMAGENET_STD[0]
    return 2.0 + 0.5 * red


def test_the_graph_runs_quietly(graph):
    """Every inference runs under quiet_run_options (log level 4, fatal only): a failing run is said once,
    by the ModelError, not also by ONNX Runtime's own log on stderr."""
    from run_spy import RunSpy

    model = OnnxDA3(graph, CAM, threads=1)
    model.session = RunSpy(model.session)
    model.predict(gradient_frames(2))
    assert model.session.log_levels == [4]


def test_unconditioned_call_maps_outputs_to_camera_resolution(graph):
    model = OnnxDA3(graph, CAM, threads=1)
    assert isinstance(model, DepthModel) and model.graph_views is None
    assert model.graph_hw == (28, 42)
    np.testing.assert_allclose(model.K_rect, CAM.K)
    frames = gradient_frames(3)
    pred = model.predict(frames)
    assert pred.depth.shape == (3, 64, 96) and pred.conf.shape == (3, 64, 96)
    assert pred.depth.dtype == np.float32
    inner = np.s_[:, 4:-4, 6:-6]
    np.testing.assert_allclose(
        pred.depth[inner], np.broadcast_to(expected_red_depth(frames[0].image), (3, 64, 96))[inner], atol=0.03
    )
    assert (pred.conf >= 1).all()
    np.testing.assert_allclose(pred.T_CW, np.tile(np.eye(4), (3, 1, 1)), atol=1e-6)
    # predicted focal f at 42x28 -> f * 96/42 and f * 64/28 at the camera; principal point = K_rect's
    np.testing.assert_allclose(pred.K[:, 0, 0], FOCAL * 96 / 42, rtol=1e-6)
    np.testing.assert_allclose(pred.K[:, 1, 1], FOCAL * 64 / 28, rtol=1e-6)
    np.testing.assert_allclose(pred.K[:, :2, 2], np.tile([CAM.cx, CAM.cy], (3, 1)))
    assert pred.scale == 1.0 and pred.fit_rmse_m == 0.0
    assert pred.info["backend"] == "onnx-da3" and pred.info["latency_s"] > 0


@pytest.mark.parametrize("n", [2, 5, 8])
def test_conditioned_call_recovers_metric_scale(graph, n):
    rng = np.random.default_rng(n)
    T_CW = random_poses(n, rng)
    K = np.tile(CAM.K, (n, 1, 1))
    model = OnnxDA3(graph, CAM, threads=1)
    frames = gradient_frames(n)
    pred = model.predict(frames, K, T_CW)
    # independent expectation: the graph multiplies normalised translations by GAIN, and DA3's
    # normalisation divides metric ones by the lower median distance of the centres to camera 0.
    centres = np.linalg.inv(T_CW)[:, :3, 3]
    dist = np.sort(np.linalg.norm(centres - centres[0], axis=1))
    d = max(dist[(n - 1) // 2], 0.1)
    assert pred.scale == pytest.approx(GAIN / d, rel=1e-5)
    assert pred.fit_rmse_m < 1e-5
    np.testing.assert_allclose(pred.T_CW, T_CW, atol=1e-5)
    np.testing.assert_allclose(pred.K, K)
    inner = np.s_[:, 4:-4, 6:-6]
    expect = np.broadcast_to(expected_red_depth(frames[0].image) * d / GAIN, (n, 64, 96))
    np.testing.assert_allclose(pred.depth[inner], expect[inner], rtol=0.02)


def test_conditioned_call_without_camera_motion_uses_median_distance_fallback(graph):
    T_CW = np.tile(np.eye(4), (4, 1, 1))
    model = OnnxDA3(graph, CAM, threads=1)
    pred = model.predict(gradient_frames(4), np.tile(CAM.K, (4, 1, 1)), T_CW)
    # all centres coincide: d is clamped to 0.1 m, so 1 predicted unit = 0.1 m
    assert pred.info["scale_source"] == "median_distance_fallback"
    assert pred.scale == pytest.approx(10.0)
    np.testing.assert_allclose(pred.T_CW, T_CW, atol=1e-6)


def test_distorted_camera_frames_are_undistorted_like_opencv(tmp_path):
    cam = PinholeRadtan(96, 64, 80.0, 82.0, 47.0, 31.5, [-0.28, 0.07, 2e-4, -1e-4])
    graph = build_da3_contract_graph(tmp_path / "g.onnx", 28, 42)
    model = OnnxDA3(graph, cam, threads=1)
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.integers(0, 255, (64, 96), dtype=np.uint8), (0, 0), 3)
    got = model._images([Frame(0, img), Frame(1, img)])[0, 0, 0]
    ref = cv2.undistort(img, cam.K, np.array(cam.distortion))
    ref = cv2.resize(ref, (42, 28), interpolation=cv2.INTER_AREA).astype(np.float32) / 255.0
    ref = (ref - IMAGENET_MEAN[0]) / IMAGENET_STD[0]
    assert np.median(np.abs(got[3:-3, 3:-3] - ref[3:-3, 3:-3])) < 0.02


def test_missing_model_names_file_and_export_command(tmp_path):
    path = tmp_path / "da3_small_378x504.onnx"
    with pytest.raises(ModelError) as e:
        OnnxDA3(path, CAM)
    assert str(path) in str(e.value) and "davio export-da3" in str(e.value)
    assert "DA3-SMALL/model.safetensors --size small" in str(e.value)
    with pytest.raises(ModelError, match=r"DA3-BASE/model.safetensors --size base --res \d+x\d+ --out .*"
                                         r"da3_base_322x504.onnx"):
        OnnxDA3(tmp_path / "da3_base_322x504.onnx", CAM)   # the size the file's name says
    with pytest.raises(ModelError, match=r"--size base --res \d+x\d+ --precision fp16 --out .*_fp16.onnx"):
        OnnxDA3(tmp_path / "da3_base_322x504_fp16.onnx", CAM)   # and its precision
    path.mkdir()                               # a folder named like the model: said, no export command
    with pytest.raises(ModelError, match="da3_small_378x504.onnx is a folder, not an ONNX model file$"):
        OnnxDA3(path, CAM)


def test_corrupt_file_is_a_model_error(tmp_path):
    path = tmp_path / "bad.onnx"
    path.write_bytes(np.random.default_rng(0).integers(0, 255, 4096, dtype=np.uint8).tobytes())
    with pytest.raises(ModelError, match="bad.onnx: not a readable ONNX model") as e:
        OnnxDA3(path, CAM)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize(
    "variant,words",
    [
        ("missing_output", "pred_intrinsics"),
        ("wrong_dtype", r"tensor\(double\)"),
        ("fp16_images", r"tensor\(float16\).*keeps float32 inputs and outputs around its float16 backbone"),
        ("dynamic_hw", "fixed resolution"),
        ("wrong_rank", "rank"),
    ],
)
def test_wrong_contract_is_a_model_error(tmp_path, variant, words):
    path = build_da3_contract_graph(tmp_path / f"{variant}.onnx", variant=variant)
    with pytest.raises(ModelError, match=words):
        OnnxDA3(path, CAM)


def test_warm_up_runs_the_graph_once_at_the_start_up_window_size(graph):
    model = OnnxDA3(graph, CAM, threads=1)
    calls = []
    run = model.session.run
    model.session.run = (lambda names, feeds, options=None:
                         calls.append(feeds["images"].shape) or run(names, feeds, options))
    assert model.warm_up() > 0.0
    assert calls == [(1, 5, 3, 28, 42)]


def test_fixed_view_graph_warms_up_at_its_view_count(tmp_path):
    model = OnnxDA3(build_da3_contract_graph(tmp_path / "n4.onnx", variant="fixed_n"), CAM, threads=1)
    assert model.warm_up() > 0.0


def test_graph_whose_depth_is_never_positive_fails_the_warm_up(tmp_path):
    model = OnnxDA3(build_da3_contract_graph(tmp_path / "neg.onnx", variant="negative_depth"), CAM, threads=1)
    with pytest.raises(ModelError, match="neg.onnx: output depth is not positive at any of its 5880 pixels"):
        model.warm_up()


def test_graph_whose_confidence_is_not_positive_fails_the_warm_up(tmp_path):
    """A log-confidence export: the start-up weighed its depths by sqrt(max(conf, 0)) = 0, refused every
    window as ill-conditioned and said nothing of the confidence."""
    model = OnnxDA3(build_da3_contract_graph(tmp_path / "log.onnx", variant="log_conf"), CAM, threads=1)
    with pytest.raises(ModelError, match=r"log.onnx: output conf is not positive at \d+ of its 5880 pixels.*"
                                         r"log-confidence"):
        model.warm_up()


def test_graph_computing_nan_fails_the_warm_up_and_every_call(tmp_path):
    model = OnnxDA3(build_da3_contract_graph(tmp_path / "nan.onnx", variant="nan_depth"), CAM, threads=1)
    with pytest.raises(ModelError, match="output depth has 5880 non-finite values out of 5880"):
        model.warm_up()  # 5 views x 28 x 42
    with pytest.raises(ModelError, match="depth has 3528 non-finite"):
        model.predict(gradient_frames(3))


def test_outputs_of_the_wrong_run_time_shape_are_a_model_error(graph):
    model = OnnxDA3(graph, CAM, threads=1)
    run = model.session.run

    def short_depth(names, feeds, options=None):
        outs = run(names, feeds)
        return [outs[0][..., :-1], *outs[1:]]

    model.session.run = short_depth
    want = r"output depth has shape \(1, 3, 28, 41\).*\(1, 3, 28, 42\) for 3 views"
    with pytest.raises(ModelError, match=want):
        model.predict(gradient_frames(3))


def test_resolution_not_multiple_of_patch_is_rejected(tmp_path):
    path = build_da3_contract_graph(tmp_path / "odd.onnx", 30, 42)
    with pytest.raises(ModelError, match="multiple of the 14"):
        OnnxDA3(path, CAM)


def test_bad_calls_are_data_errors(graph):
    model = OnnxDA3(graph, CAM, threads=1)
    with pytest.raises(DataError, match="2..8"):
        model.predict(gradient_frames(1))
    with pytest.raises(DataError, match="2..8"):
        model.predict(gradient_frames(9))
    with pytest.raises(DataError, match="both"):
        model.predict(gradient_frames(3), K=np.tile(CAM.K, (3, 1, 1)))
    with pytest.raises(DataError, match=r"\(3,4,4\)"):
        model.predict(gradient_frames(3), np.tile(CAM.K, (3, 1, 1)), np.tile(np.eye(4), (2, 1, 1)))
    small = [Frame(0, np.zeros((32, 48), np.uint8)), Frame(1, np.zeros((32, 48), np.uint8))]
    with pytest.raises(DataError, match="frame 0"):
        model.predict(small)


def test_fixed_view_count_graph_is_enforced(tmp_path):
    model = OnnxDA3(build_da3_contract_graph(tmp_path / "n4.onnx", variant="fixed_n"), CAM, threads=1)
    assert model.graph_views == 4
    assert model.predict(gradient_frames(4)).depth.shape == (4, 64, 96)
    with pytest.raises(DataError, match="exactly 4 views"):
        model.predict(gradient_frames(3))


def test_unconditioned_poses_are_re_anchored_on_view_0(graph, monkeypatch):
    model = OnnxDA3(graph, CAM, threads=1)
    rng = np.random.default_rng(9)
    T_pred = random_poses(3, rng)  # what a real DA3 returns: view 0 close to, not exactly, identity
    real_run = model._run

    def fake_run(images, K, E, use_pose):
        depth, conf, _, pred_K = real_run(images, K, E, use_pose)
        return depth, conf, T_pred[None, :, :3, :].astype(np.float32), pred_K

    monkeypatch.setattr(model, "_run", fake_run)
    pred = model.predict(gradient_frames(3))
    np.testing.assert_allclose(pred.T_CW[0], np.eye(4), atol=1e-6)
    for i in (1, 2):  # relative motion between views is unchanged
        np.testing.assert_allclose(
            pred.T_CW[i] @ np.linalg.inv(pred.T_CW[1]), T_pred[i] @ np.linalg.inv(T_pred[1]), atol=1e-5
        )


@pytest.mark.parametrize("shape", [(7, 9), (7, 9, 3)])
def test_normalise_image_matches_the_interleaved_formula_bit_for_bit(shape):
    # the former implementation: an (H,W,3) RGB float32 copy, normalised, then transposed
    img = np.random.default_rng(3).integers(0, 256, shape, dtype=np.uint8)
    rgb = np.repeat(img[:, :, None], 3, axis=2) if img.ndim == 2 else img[:, :, ::-1]
    want = (((rgb.astype(np.float32) / 255.0) - IMAGENET_MEAN) / IMAGENET_STD).transpose(2, 0, 1)
    got = normalise_image(img)
    assert got.dtype == np.float32 and got.shape == (3, 7, 9)
    assert np.array_equal(got, want)
    batch = np.zeros((2, 3, 7, 9), dtype=np.float32)
    assert np.shares_memory(normalise_image(img, out=batch[1]), batch)
    assert np.array_equal(batch[1], want) and not batch[0].any()
    with pytest.raises(ValueError, match="out must be float32"):
        normalise_image(img, out=np.zeros((3, 7, 9), dtype=np.float64))
    with pytest.raises(ValueError, match="grey"):
        normalise_image(np.zeros((7, 9, 4), dtype=np.uint8))


def test_an_allocation_failure_says_how_to_fit_the_gpu(graph):
    model = OnnxDA3(graph, CAM, threads=1)

    class Session:
        def __init__(self, message):
            self.message = message

        def run(self, names, feeds, options=None):
            raise RuntimeError(self.message)

    for message in (  # what ONNX Runtime 1.31 raised on an H100 past gpu_mem_limit; its other arena failure
        "[ONNXRuntimeError] : 1 : FAIL : Non-zero status code returned while running FusedMatMul node. "
        "Name:'node_MatMul_878/MatMulScaleFusion/' Status Message: /onnxruntime_src/onnxruntime/core/"
        "framework/bfc_arena.cc:360 void* onnxruntime::BFCArena::AllocateRawInternal(size_t, bool, "
        "onnxruntime::Stream*) Available memory of 10942464 is smaller than requested bytes of 484725248",
        "[ONNXRuntimeError] : 6 : RUNTIME_EXCEPTION : Failed to allocate memory for requested buffer of "
        "size 1024",
    ):
        model.session = Session(message)
        model.session_info["providers"] = ["CUDAExecutionProvider", "CPUExecutionProvider"]
        with pytest.raises(ModelError, match=r"out of GPU memory at 3 views: raise or drop --gpu-mem-limit"):
            model.predict(gradient_frames(3))
        model.session_info["providers"] = ["CPUExecutionProvider"]   # the CPU's pool fails the same way
        with pytest.raises(ModelError, match=r"out of memory at 3 views on the CPU: free memory") as info:
            model.predict(gradient_frames(3))
        assert "GPU" not in str(info.value)
    model.session = Session("shape mismatch in node /Reshape")
    with pytest.raises(ModelError, match=r"inference failed \(RuntimeError: shape mismatch") as info:
        model.predict(gradient_frames(3))
    assert "GPU memory" not in str(info.value)
