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


def check_result_file(path: Path) -> None:
    """ConfigError unless a benchmark may write its JSON result to `path`, checked before the run (the
    result was written after it: a missing folder lost a finished run, and any existing file was replaced,
    one of the benchmark's own inputs included). An existing file is replaced only when it holds JSON
    (an earlier result)."""
    import json

    from runtime.errors import ConfigError
    from tools.output_file import check_output_file

    if path.is_dir():
        raise ConfigError(f"--out {path}: is a folder; name the .json file to write")
    if path.is_file() and path.stat().st_size:      # an empty file (mktemp, touch) holds nothing to lose
        try:
            json.loads(path.read_bytes())
        except (OSError, ValueError) as exc:     # UnicodeDecodeError and JSONDecodeError are ValueErrors
            raise ConfigError(f"--out {path}: exists and is not a JSON result ({type(exc).__name__}); it is "
                              "not replaced: choose another file") from None
    check_output_file(path, "--out", (".json",), replaceable=True)


def run(args: argparse.Namespace) -> int:
    if not getattr(args, "_bench", None):
        names = ", ".join(m.NAME for m in _modules()) or "(none yet)"
        print(f"davio bench: name a benchmark: {names}")
        return 2
    if getattr(args, "out", None) is not None:
        check_result_file(Path(args.out))
    return int(args._bench(args) or 0)
