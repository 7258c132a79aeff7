"""The `davio` command: a thin argparse front end over tools/commands/*.

Each module in `tools.commands` defines `NAME`, `HELP`, `add_arguments(parser)` and `run(args) -> int`.
Modules must import heavy packages inside `run`, never at import time or in `add_arguments`, so that
`davio --help` stays fast (tests/tools/test_cli.py checks that building every command's options imports
neither the pipeline nor the simulator nor a model runtime); a command named on the command line builds
its own options only (`davio listen` starts in about 0.2 s, `davio --help` in 0.9 s, measured 2026-11-28);
`davio --version` builds no parser.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import pkgutil
import signal
import sys
from collections.abc import Iterator

from runtime.errors import DavioError


def _command_modules() -> list:
    import tools.commands as pkg

    mods = []
    for info in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"tools.commands.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods.append(mod)
    order = getattr(pkg, "ORDER", [])
    mods.sort(key=lambda m: (order.index(m.NAME) if m.NAME in order else len(order), m.NAME))
    return mods


class _DefaultsFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Appends '(default: X)' only where the help does not already say what the default is, and never
    '(default: None)' (an option that is off or chosen automatically says so in its help)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        help_text = action.help or ""
        if "(default:" in help_text or action.default is None:
            return help_text
        return super()._get_help_string(action)


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser with every subcommand; with `only`, the options of that subcommand alone (the others
    are listed, not built: building one imports what its options need), and no usage epilog."""
    parser = argparse.ArgumentParser(
        prog="davio",
        description="DAVIO: monocular camera + IMU -> metric pose stream and dense metric map.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="store_true", help="print the version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    lines = []
    for mod in _command_modules():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=getattr(mod, "DESCRIPTION", mod.HELP),
                           formatter_class=_DefaultsFormatter, allow_abbrev=False)
        p.set_defaults(_run=mod.run)
        if only is None or mod.NAME == only:
            mod.add_arguments(p)
            lines.append(_usage_lines(p))
    if only is None:
        parser.epilog = ("usage of each command:\n" + "\n".join(lines)
                         + "\n\nrun 'davio COMMAND --help' for what each option means")
    return parser


def _command_named(argv: list[str]) -> str | None:
    """The subcommand `argv` runs (its first word: the top level takes no option with a value), or None when
    a top-level option comes first (`--help`, `--version` or an abbreviation: they need the full parser)."""
    first = next((a for a in argv if not a.startswith("-")), None)
    if first is None or argv.index(first) > 0:
        return None
    return first


def _usage_lines(p: argparse.ArgumentParser) -> str:
    """'usage: ...' of a subcommand (and of its own subcommands, e.g. eval ate / bench NAME)."""
    out = ["  " + " ".join(p.format_usage().replace("usage: ", "").split())]
    for action in p._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sp in action.choices.values():
                out.append("    " + " ".join(sp.format_usage().replace("usage: ", "").split()))
    return "\n".join(out)


def _owner_parser(parser: argparse.ArgumentParser, args: argparse.Namespace, given: list[str],
                  extra: list[str]) -> argparse.ArgumentParser:
    """The (sub)command parser unrecognised tokens `extra` were given to: the innermost one `args` went
    through (e.g. that of `davio eval ate`) whose command name comes before them in `given`
    (`davio eval --frob ate` is eval's, `davio --frob run` the top level's)."""
    level, start = parser, 0
    while True:
        sub = next((a for a in level._actions if isinstance(a, argparse._SubParsersAction)), None)
        name = None if sub is None else getattr(args, sub.dest, None)
        if sub is None or name not in sub.choices or name not in given[start:]:
            return level
        pos = given.index(name, start)
        if any(tok in given[start:pos] for tok in extra):
            return level
        level, start = sub.choices[name], pos + 1


_EMPTY = "an empty value (give one, or leave the option out)"


def _empty_value(given: list[str]) -> tuple[str, str] | None:
    """(the blank token, the message) of the first empty value on the command line (`--model ''`,
    `--out=`, a shell variable that was not set), or None. Commands test their optional values for truth
    and `type=Path` reads '' as the current folder, so an empty value was taken as not given, or as '.',
    and the default ran unsaid."""
    for k, tok in enumerate(given):
        if tok.startswith("--") and "=" in tok and not tok.split("=", 1)[1].strip():
            return tok, f"argument {tok.split('=', 1)[0]}: {_EMPTY}"
        if not tok.strip():
            before = given[k - 1] if k else ""
            named = before.startswith("-") and "=" not in before and not before.lstrip("-")[:1].isdigit()
            return tok, f"argument {before}: {_EMPTY}" if named else "an empty operand: give a value"
    return None


def _command_path(parser: argparse.ArgumentParser, args: argparse.Namespace) -> str:
    """The (sub)command `args` ran, as typed: "run", "eval ate", "bench startup" (messages name it as
    argparse's own errors do)."""
    names, level = [], parser
    while True:
        sub = next((a for a in level._actions if isinstance(a, argparse._SubParsersAction)), None)
        name = None if sub is None else getattr(args, sub.dest, None)
        if sub is None or name not in sub.choices:
            return " ".join(names)
        names.append(name)
        level = sub.choices[name]


def _drop_stdout() -> None:
    """Point descriptor 1 at /dev/null, so that the interpreter's flush at exit does not fail again on the
    closed pipe."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):
        pass


def _print_version() -> int:
    from importlib.metadata import version

    print(f"davio {version('davio')}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `davio` console script; returns the process exit code."""
    # numba's default OpenMP layer busy-waits its idle threads, which halves throughput on the
    # small shared CPUs DAVIO runs on; the workqueue layer does not (override with the variable).
    os.environ.setdefault("NUMBA_THREADING_LAYER", "workqueue")
    if "numba" in sys.modules:   # imported before (main called in-process): numba read the variable then
        from drivers.sim.threads import prefer_workqueue_layer

        prefer_workqueue_layer()
    given = sys.argv[1:] if argv is None else list(argv)
    if given == ["--version"]:    # before any parser: building them reads every command's options
        try:
            return _print_version()
        except BrokenPipeError:
            _drop_stdout()
            return 141
    parser = build_parser(only=_command_named(given))
    args, extra = parser.parse_known_args(given)
    if extra:   # said by the command it was given to (with that command's usage)
        _owner_parser(parser, args, given, extra).error(f"unrecognized arguments: {' '.join(extra)}")
    empty = _empty_value(given)
    if empty is not None:
        _owner_parser(parser, args, given, [empty[0]]).error(empty[1])
    if args.version:
        return _print_version()
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    with _sigterm_interrupts():
        return _run_command(parser, args)


@contextlib.contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """SIGTERM acts as Ctrl-C for the whole command, from its start: as PID 1 in a container (`docker run`
    without --init) the default action of SIGTERM is to do nothing, so one that came before a run's own
    handler (`tools.run_outcome.interruptible`), while the model loaded, was lost and docker killed the run
    10 s later. Left alone when the process already handles SIGTERM (DAVIO inside another program)."""
    try:
        if signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL:    # ignored or handled: left so
            yield
            return
        signal.signal(signal.SIGTERM, _interrupt)
    except ValueError:       # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


def _run_command(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    try:
        if getattr(args, "json", False):    # stdout holds the JSON only: libraries' lines go to stderr
            from runtime.stdout_fd import json_stdout

            with json_stdout():
                return int(args._run(args) or 0)
        return int(args._run(args) or 0)
    except DavioError as exc:
        print(f"davio {_command_path(parser, args)}: error: {exc}", file=sys.stderr)
        return 1
    except (KeyboardInterrupt, Exception) as exc:   # Ctrl-C, also one surfacing through a C extension
        from runtime.errors import caused_by_interrupt

        if caused_by_interrupt(exc):
            how = "" if isinstance(exc, KeyboardInterrupt) else f" ({type(exc).__name__})"
            print(f"davio {_command_path(parser, args)}: interrupted{how}", file=sys.stderr)
            return 130
        if isinstance(exc, BrokenPipeError):    # `davio ... | head`: the reader has all it wanted
            _drop_stdout()
            return 141
        if isinstance(exc, OSError):     # the machine's (a permission, a full disk): the command said no more
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"davio {_command_path(parser, args)}: error: {where}{exc.strerror or exc}",
                  file=sys.stderr)
            return 1
        raise

if __name__ == "__main__":
    sys.exit(main())
