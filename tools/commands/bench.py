"""`davio bench NAME ...`: run one benchmark of tools/benchmarks (each prints a table or JSON)."""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import re
from pathlib import Path

NAME = "bench"
HELP = "run a benchmark (openvins-sim, startup, renderer, da3-latency, matcher, ...)"


def _modules() -> list:
    """The benchmark modules (those defining NAME and run), by name. A module without a top-level NAME is a
    helper of the others and is not imported here: some import the whole pipeline."""
    import tools.benchmarks as pkg

    mods = []
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        if info.name.startswith("_") or not _defines_name(Path(info.module_finder.path) / f"{info.name}.py"):
            continue
        mod = importlib.import_module(f"tools.benchmarks.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods.append(mod)
    return mods


def _defines_name(path: Path) -> bool:
    try:
        return re.search(r"^NAME = ", path.read_text(encoding="utf-8"), re.MULTILINE) is not None
    except OSError:     # not a plain source file (a package, a zip): import it and look
        return True


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="benchmark", metavar="NAME")
    for mod in _modules():
        bp = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                            formatter_class=argparse.ArgumentDefaultsHelpFormatter)
        mod.add_arguments(bp)
        bp.set_defaults(_bench=mod.run)


def run(args: argparse.Namespace) -> int:
    if not getattr(args, "_bench", None):
        names = ", ".join(m.NAME for m in _modules()) or "(none yet)"
        print(f"davio bench: name a benchmark: {names}")
        return 2
    return int(args._bench(args) or 0)
