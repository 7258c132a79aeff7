"""Reading weight files for the export tools, treating them as untrusted input.

`.safetensors` is always accepted (a flat tensor format: reading it runs no code). Torch pickles
(`.pt`, `.pth`, `.bin`) are read only with `torch.load(weights_only=True)` and only on a torch whose
restricted unpickler has no known bypass: CVE-2025-32434 (GHSA-53q9-r3pm-6pq6, code execution,
fixed in 2.6.0) and CVE-2026-24747 (GHSA-63cw-57p8-fm3p, memory corruption, fixed in 2.10.0).
"""

from __future__ import annotations

import re
from pathlib import Path

from runtime.errors import ModelError

#: first torch release whose `weights_only=True` unpickler has no published bypass
MIN_TORCH_FOR_PICKLE = (2, 10, 0)
SAFETENSORS_SUFFIX = ".safetensors"
PICKLE_SUFFIXES = (".pt", ".pth", ".bin")


def torch_release(version: str) -> tuple[tuple[int, ...], bool]:
    """'2.10.0+cpu' -> ((2, 10, 0), True); the flag is False for pre-releases ('2.10.0a0', '2.10.0.dev1').

    Raises:
        ModelError: the string does not start with a release number.
    """
    m = re.match(r"^\s*v?(\d+(?:\.\d+)*)(.*)$", version)
    if not m:
        raise ModelError(f"cannot read the torch version {version!r}")
    release = tuple(int(p) for p in m.group(1).split("."))
    release += (0,) * (3 - len(release))
    suffix = m.group(2).split("+", 1)[0].lower()
    return release, not re.search(r"(a|b|c|rc|alpha|beta|pre|preview|dev)\d*", suffix)


def pickle_loading_is_safe(version: str) -> bool:
    """Whether this torch version's `torch.load(weights_only=True)` has no known bypass."""
    release, final = torch_release(version)
    return release > MIN_TORCH_FOR_PICKLE or (release == MIN_TORCH_FOR_PICKLE and final)


def _minimum() -> str:
    return ".".join(str(p) for p in MIN_TORCH_FOR_PICKLE)


def read_state_dict(path: str | Path) -> dict:
    """The tensors of a weight file: `.safetensors`, or a torch `.pt/.pth/.bin` pickle on a safe torch.

    Raises:
        ModelError: missing file, another format, a pickle on a torch with a known `weights_only`
            bypass (telling to upgrade torch or convert to safetensors), or an unreadable file.
    """
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"checkpoint not found: {path}")
    suffix = path.suffix.lower()
    if suffix == SAFETENSORS_SUFFIX:
        try:
            from safetensors.torch import load_file
        except ImportError as exc:
            raise ModelError(f"{path}: reading .safetensors needs the safetensors package ({exc})") from exc
        loader = lambda: load_file(str(path))  # noqa: E731
    elif suffix in PICKLE_SUFFIXES:
        import torch

        if not pickle_loading_is_safe(torch.__version__):
            raise ModelError(
                f"{path}: refusing to unpickle a torch checkpoint with torch {torch.__version__}: before "
                f"torch {_minimum()} a crafted file can run code or corrupt memory even with "
                f"torch.load(weights_only=True) (CVE-2025-32434, CVE-2026-24747). Upgrade torch "
                f"(pip install -U 'torch>={_minimum()}') or use the .safetensors release of these weights"
            )
        loader = lambda: torch.load(str(path), map_location="cpu", weights_only=True)  # noqa: E731
    else:
        raise ModelError(
            f"{path}: unsupported weight file {path.suffix or '(no suffix)'!r}; give a .safetensors file "
            f"(or a torch state dict {', '.join(PICKLE_SUFFIXES)})"
        )
    try:
        return loader()
    except Exception as exc:
        text = str(exc)
        if "WeightsUnpickler error:" in text:  # torch's multi-line advice ends in the one line that matters
            why = text.split("WeightsUnpickler error:", 1)[1].split(". Please", 1)[0].strip()
            raise ModelError(
                f"{path}: refused: the checkpoint holds more than tensors ({why}); it may run code when "
                "unpickled, so it is not loaded. Use the .safetensors release of these weights"
            ) from exc
        why = " ".join(text.split())[:300]
        raise ModelError(f"{path}: cannot read checkpoint ({type(exc).__name__}: {why})") from exc
