"""Package attributes imported on first use (PEP 562), so that importing one light submodule of a package
does not import the heavy ones its `__init__` re-exports (the `davio` command reads the simulator's presets
and the calibration thresholds when it builds its options)."""
from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any


def lazy_exports(package: str,
                 exports: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """(`__getattr__`, `__dir__`) for `package`, whose names `exports` maps to the modules defining them.

    A name is looked up in its module at every access (not cached), so it is always that module's own value.
    Called from the package's `__init__`, while the package is in sys.modules.
    """
    namespace = vars(sys.modules[package])     # the live globals, kept if the package leaves sys.modules

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(module), name)

    def __dir__() -> list[str]:
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__
