"""Weight files as untrusted input: safetensors always, torch pickles only on a torch without known
`weights_only` bypasses (CVE-2025-32434, CVE-2026-24747)."""

from __future__ import annotations

from pathlib import Path

import pytest

from runtime.errors import ModelError
from tools.export.checkpoint import pickle_loading_is_safe, read_state_dict, torch_release


@pytest.mark.parametrize(
    "version, safe",
    [
        ("2.4.1", False),
        ("2.5.1+cu124", False),
        ("2.6.0", False),  # fixed CVE-2025-32434, not CVE-2026-24747
        ("2.9.1+cpu", False),
        ("2.10.0a0+git1234", False),  # a pre-release of the fixed version
        ("2.10.0.dev20251201", False),
        ("2.10.0", True),
        ("2.10.0+cpu", True),
        ("2.13.0+cpu", True),
        ("3.0", True),
    ],
)
def test_torch_versions_allowed_to_unpickle(version, safe):
    assert pickle_loading_is_safe(version) is safe


def test_unreadable_torch_version_is_a_model_error():
    assert torch_release("2.10") == ((2, 10, 0), True)
    with pytest.raises(ModelError, match="torch version"):
        torch_release("unknown")


def _torch():
    torch = pytest.importorskip("torch", reason="needs the export extra (torch)")
    pytest.importorskip("safetensors", reason="needs the export extra (safetensors)")
    return torch


def _weights(torch) -> dict:
    return {"layer.weight": torch.arange(6, dtype=torch.float32).reshape(2, 3), "layer.bias": torch.ones(2)}


@pytest.fixture
def old_torch(monkeypatch):
    """torch reporting a version with a known weights_only bypass, and a torch.load that must not run."""
    torch = _torch()

    def forbidden(*args, **kwargs):
        raise AssertionError("torch.load was called on a torch with a known weights_only bypass")

    monkeypatch.setattr(torch, "__version__", "2.5.1")
    monkeypatch.setattr(torch, "load", forbidden)
    return torch


@pytest.mark.export
def test_safetensors_is_read_even_on_an_old_torch(tmp_path, old_torch):
    from safetensors.torch import save_file

    save_file(_weights(old_torch), str(tmp_path / "w.safetensors"))
    got = read_state_dict(tmp_path / "w.safetensors")
    assert set(got) == {"layer.weight", "layer.bias"} and float(got["layer.weight"][1, 2]) == 5.0


@pytest.mark.export
@pytest.mark.parametrize("suffix", [".pt", ".pth", ".bin"])
def test_pickle_is_refused_on_an_old_torch_before_torch_load(tmp_path, old_torch, suffix):
    path = tmp_path / f"w{suffix}"
    path.write_bytes(b"any bytes: the file must not be opened by torch.load")
    with pytest.raises(ModelError) as err:
        read_state_dict(path)
    msg = str(err.value)
    assert str(path) in msg and "torch 2.5.1" in msg
    assert "torch>=2.10.0" in msg and ".safetensors" in msg and "CVE-2025-32434" in msg


@pytest.mark.export
def test_pickle_state_dict_is_read_on_a_fixed_torch(tmp_path, monkeypatch):
    torch = _torch()
    monkeypatch.setattr(torch, "__version__", "2.10.0+cpu")
    torch.save(_weights(torch), tmp_path / "w.pt")
    got = read_state_dict(tmp_path / "w.pt")
    assert torch.equal(got["layer.weight"], _weights(torch)["layer.weight"])


class _Payload:
    """Unpickling this writes a marker file (what a malicious checkpoint would do, harmlessly)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "pwned"))


@pytest.mark.export
def test_pickle_with_code_is_refused_by_the_weights_only_unpickler(tmp_path):
    torch = _torch()
    if not pickle_loading_is_safe(torch.__version__):
        pytest.skip(f"torch {torch.__version__} refuses every pickle (tested above)")
    marker = tmp_path / "marker.txt"
    torch.save({"layer.weight": torch.zeros(2), "evil": _Payload(marker)}, tmp_path / "evil.pt")
    with pytest.raises(ModelError, match=r"evil.pt: refused: the checkpoint holds more than tensors") as e:
        read_state_dict(tmp_path / "evil.pt")
    assert not marker.exists()
    assert "\n" not in str(e.value) and "weights_only=False" not in str(e.value)


@pytest.mark.export
def test_other_formats_and_missing_files_are_refused(tmp_path):
    _torch()
    (tmp_path / "w.ckpt").write_bytes(b"x")
    with pytest.raises(ModelError, match=r"unsupported weight file '.ckpt'.*\.safetensors"):
        read_state_dict(tmp_path / "w.ckpt")
    with pytest.raises(ModelError, match="checkpoint not found"):
        read_state_dict(tmp_path / "absent.safetensors")
    (tmp_path / "bad.safetensors").write_bytes(b"not a safetensors file")
    with pytest.raises(ModelError, match="bad.safetensors: cannot read checkpoint"):
        read_state_dict(tmp_path / "bad.safetensors")


@pytest.mark.export
def test_da3_checkpoint_loader_applies_the_policy(tmp_path, old_torch):
    pytest.importorskip("depth_anything_3.model.da3", reason="needs depth-anything-3 (pip install --no-deps)")
    from tools.export.da3_net import build_net, load_checkpoint_

    (tmp_path / "model.pth").write_bytes(b"pickle")
    with pytest.raises(ModelError, match="model.pth: refusing to unpickle"):
        load_checkpoint_(build_net("tiny"), tmp_path / "model.pth")
