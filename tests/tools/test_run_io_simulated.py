"""`davio run` opening recordings that `davio simulate --trajectory` wrote (tools/run_io.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from drivers.sim import SimConfig, SimRecording, write_euroc
from drivers.sim.imu_synth import ImuErrorModel
from drivers.sim.motion import level_attitude
from drivers.sim.render import ImageOptions
from drivers.sim.rig import euroc_default_rig
from runtime.errors import DataError
from runtime.geometry import PoseTrajectory
from tools.evaluation import write_euroc_csv
from tools.run_io import open_recording

T0_NS = 1_403_715_273_262_142_976  # an EuRoC-like epoch stamp (int64 ns, never float)


def _write_inputs(folder: Path) -> tuple[Path, Path]:
    """A 3 s EuRoC state CSV (200 Hz, gentle arc at 1.2 m) and a 200 Hz EuRoC IMU CSV over it."""
    t = T0_NS + np.arange(601, dtype=np.int64) * 5_000_000
    s = (t - t[0]) * 1e-9
    p = np.stack([0.3 * np.sin(s), 0.4 * s, np.full(s.size, 1.2)], axis=1)
    traj = PoseTrajectory(t, p, level_attitude(0.2 * s))
    gt = folder / "groundtruth.csv"
    write_euroc_csv(gt, traj)
    imu = folder / "imu0.csv"
    rows = ["#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z"]
    rows += [f"{int(k)},0.01,0.2,0.0,9.81,0.0,0.1" for k in t]
    imu.write_text("\n".join(rows) + "\n")
    return gt, imu


def _simulate(root: Path, imu: bool, seconds: float) -> Path:
    """What `davio simulate --trajectory groundtruth.csv [--imu imu0.csv] --start 0.5 --exact` writes,
    on a quarter-size camera without depth maps or scene cloud (fast), from relative input paths."""
    rig = euroc_default_rig()
    rig = rig.replace(camera=rig.camera.scaled(0.25, 0.25))
    cfg = SimConfig(seconds=seconds, start_s=0.5, seed=4, image=ImageOptions.exact(),
                    imu_errors=ImuErrorModel.noise_free())
    out = root / ("sim_replay" if imu else "sim_spline")
    mp = pytest.MonkeyPatch()
    mp.chdir(root)  # relative input paths: the manifest must still find them from elsewhere
    try:
        imu_path = "imu0.csv" if imu else None
        rec = SimRecording.from_trajectory("groundtruth.csv", cfg, rig=rig, imu_path=imu_path)
        write_euroc(rec, out, depth=False, cloud_spacing_m=None)
    finally:
        mp.undo()
    return out


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("traj_sim")
    _write_inputs(root)
    return root


@pytest.fixture(scope="module")
def trajectory_sim(inputs: Path) -> Path:
    """EuRoC-trajectory mode (the IMU file replayed against the trajectory), 0.6 s from 0.5 s in."""
    return _simulate(inputs, imu=True, seconds=0.6)


def test_trajectory_mode_recording_is_rebuilt_for_the_emulated_da3(trajectory_sim: Path) -> None:
    info = json.loads((trajectory_sim / "manifest.json").read_text())
    assert info["simulation"]["mode"] == "euroc-trajectory" and info["config"]["start_s"] == 0.5
    assert info["simulation"]["source"] == "groundtruth.csv"  # as given, relative
    assert Path(info["inputs"]["source"]).is_absolute()
    rec = open_recording(trajectory_sim)
    assert rec.kind == "simulated" and rec.ground_truth_source is not None
    gt = rec.driver.groundtruth()
    assert gt.t_ns[0] == T0_NS + 500_000_000  # the --start crop
    cam = rec.driver.rig.camera
    stamps = rec.driver.frame_stamps(0)
    view = rec.ground_truth_source.render_view(int(stamps[len(stamps) // 2]), cam.K, cam.width, cam.height)
    assert view.depth.shape == (cam.height, cam.width) and np.isfinite(view.depth).all()
    assert 0.1 < float(np.median(view.depth)) < 50.0


def test_native_only_needs_no_rebuild(trajectory_sim: Path, tmp_path: Path) -> None:
    bad = _copy_with_manifest(trajectory_sim, tmp_path, source=str(tmp_path / "gone.csv"))
    rec = open_recording(bad, rebuild=False)
    assert rec.kind == "simulated" and rec.ground_truth_source is None
    assert len(rec.driver.frame_stamps(0)) >= 10


def test_trajectory_spline_mode_is_rebuilt(inputs: Path) -> None:
    folder = _simulate(inputs, imu=False, seconds=0.3)
    assert json.loads((folder / "manifest.json").read_text())["simulation"]["mode"] == "trajectory-spline"
    rec = open_recording(folder)
    cam = rec.driver.rig.camera
    t_ns = int(rec.driver.frame_stamps(0)[0])
    view = rec.ground_truth_source.render_view(t_ns, cam.K, cam.width, cam.height)
    assert np.isfinite(view.depth).all()


def test_manifest_without_start_uses_the_folders_ground_truth(trajectory_sim: Path, tmp_path: Path) -> None:
    """Manifests written before start_s was recorded: the crop comes from the folder's ground truth;
    a wrong crop is refused, not rendered against another scene."""
    old = _copy_with_manifest(trajectory_sim, tmp_path, drop_start=True)
    assert open_recording(old).ground_truth_source is not None
    wrong = _copy_with_manifest(trajectory_sim, tmp_path / "w", start_s=0.0)
    with pytest.raises(DataError, match="does not match"):
        open_recording(wrong)


def test_missing_trajectory_file_is_named(trajectory_sim: Path, tmp_path: Path) -> None:
    gone = tmp_path / "moved" / "groundtruth.csv"
    bad = _copy_with_manifest(trajectory_sim, tmp_path, source=str(gone))
    with pytest.raises(DataError, match="trajectory file") as err:
        open_recording(bad)
    assert str(gone) in str(err.value) and "--native-only" in str(err.value)
    assert err.value.path == str(bad / "manifest.json")


def test_unknown_mode_points_to_native_only(trajectory_sim: Path, tmp_path: Path) -> None:
    bad = _copy_with_manifest(trajectory_sim, tmp_path, mode="hologram")
    with pytest.raises(DataError, match="--native-only"):
        open_recording(bad)


def _copy_with_manifest(src: Path, tmp_path: Path, source: str | None = None, mode: str | None = None,
                        drop_start: bool = False, start_s: float | None = None) -> Path:
    """A copy of the recording (images symlinked) with an edited manifest."""
    dst = tmp_path / "copy"
    (dst / "mav0").mkdir(parents=True)
    for sub in (src / "mav0").iterdir():
        (dst / "mav0" / sub.name).symlink_to(sub, target_is_directory=True)
    info = json.loads((src / "manifest.json").read_text())
    if source is not None:
        info["inputs"]["source"] = info["simulation"]["source"] = source
    if mode is not None:
        info["simulation"]["mode"] = mode
    if drop_start:
        del info["config"]["start_s"]
    if start_s is not None:
        info["config"]["start_s"] = start_s
    (dst / "manifest.json").write_text(json.dumps(info))
    return dst


@pytest.mark.parametrize("edit,message", [
    (lambda m: m["config"].__setitem__("seed", -1), "config.seed = -1 is not an integer from 0"),
    (lambda m: m["config"].__setitem__("seed", 1.5), "config.seed = 1.5 is not an integer"),
    (lambda m: m["config"].__setitem__("seed", "zero"), "config.seed = 'zero' is not an integer"),
    (lambda m: m.__setitem__("simulation", "preset"), "'simulation' is 'preset', expected an object"),
])
def test_a_damaged_manifest_seed_or_simulation_names_the_manifest(tmp_path: Path, edit, message: str) -> None:
    from tools.run_io import read_manifest

    path = tmp_path / "manifest.json"
    m = {"config": {"preset": "euroc", "seconds": 2.0, "seed": 0, "style": "room", "imu_rate_hz": 200.0},
         "simulation": {"mode": "preset"}}
    path.write_text(json.dumps(m))
    assert read_manifest(path)["config"]["seed"] == 0
    edit(m)
    path.write_text(json.dumps(m))
    with pytest.raises(DataError, match="manifest.json: " + message):
        read_manifest(path)


def test_sim_config_seed_range() -> None:
    from runtime.errors import ConfigError

    assert SimConfig(seed=np.int64(3)).seed == 3 and SimConfig(seed=2**32 - 1).seed == 2**32 - 1
    for bad in (-1, 2**32, 1.0, True):
        with pytest.raises(ConfigError, match="seed must be an integer from 0 to 4294967295"):
            SimConfig(seed=bad)


def test_a_simulated_folders_time_offset_reaches_the_run_s_rig(tmp_path: Path) -> None:
    """An ASL sensor.yaml has no field for the camera-IMU time offset: `davio run` takes a simulated
    folder's from its manifest (the offset its images were rendered at), unless --rig gives one."""
    from argparse import Namespace

    from calib.kalibr import write_kalibr
    from runtime.config import DavioConfig
    from tools.commands.run import _open_inputs

    rec = SimRecording.from_preset(SimConfig(preset="euroc", seconds=2.0, seed=0, time_offset_s=0.03))
    folder = tmp_path / "sim"
    write_euroc(rec, folder, depth=False, cloud_spacing_m=None)
    opened = open_recording(folder, rebuild=False)
    assert opened.time_offset_s == pytest.approx(0.03) and opened.driver.rig.time_offset_s in (None, 0.0)
    args = Namespace(path=str(folder), rig=None, native_only=True, strict=False, image_topic=None,
                     imu_topic=None, withhold_extrinsics=False, model=None, emulated=None)
    assert _open_inputs(args, DavioConfig())[1].time_offset_s == pytest.approx(0.03)
    zero = tmp_path / "zero"                              # a known 0 is 0, not withheld (None)
    write_euroc(SimRecording.from_preset(SimConfig(preset="euroc", seconds=2.0, seed=0)), zero, depth=False,
                cloud_spacing_m=None)
    assert _open_inputs(Namespace(**{**vars(args), "path": str(zero)}), DavioConfig())[1].time_offset_s == 0.0
    camchain = tmp_path / "camchain.yaml"                 # a rig file given: its offset (0) is used
    write_kalibr(rec.rig.replace(time_offset_s=0.0), camchain)
    args.rig = str(camchain)
    assert not _open_inputs(args, DavioConfig())[1].time_offset_s
