"""A run's output folder: checked before the work, written whole or clearly marked unfinished.

    folder = RunFolder.prepare(out, overwrite=args.overwrite)   # errors before any work
    folder.create()                # once the inputs opened
    ... write every output into folder.path (the sibling `<out>.partial/`) ...
    folder.finish("complete")      # run_status.json, then `<out>.partial/` renamed to `<out>/`

While a run works, its files live in `<out>.partial/`; `<out>/` appears (or replaces the previous run,
with --overwrite) only when the run ends, holding `run_status.json` whose "status" is "complete",
"interrupted" (Ctrl-C or SIGTERM: the outputs up to the interruption) or "failed" (an error after
some work: what was computed up to it). A `<out>.partial/` left behind is a run that was killed.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from runtime.errors import ConfigError

STATUS_FILE = "run_status.json"
STATUSES = ("complete", "interrupted", "failed")
RUN_MARKERS = (STATUS_FILE, "report.json", "odometry.tum")
"""Files whose presence suggests a folder holds a DAVIO run (used for messages; replacing one needs more:
`not_replaceable`)."""
DERIVED_FILES = ("map.ply", "map.png", "alignment.json", "final.prior.tum", "map.prior.ply", "map.merged.ply",
                 "causal.earlier-prior.tum")
"""Files `davio map export|view|align` write into a run folder by default after the run ended (`map align
--overwrite` keeps a live run's causal.prior.tum aside as causal.earlier-prior.tum)."""


def _partial_names() -> re.Pattern:
    """What a run writes into `<out>.partial/`: run_io's outputs, the pose journal, the map archive's files
    (map_archive.format) and atomic-write temporaries."""
    from tools.map_archive.format import JOURNAL_NAME as MAP_JOURNAL
    from tools.map_archive.format import MANIFEST_NAME, SUBMAP_RE, TEMP_RE
    from tools.pose_journal import JOURNAL_NAME
    from tools.run_io import RUN_OUTPUTS

    top = "|".join([RUN_OUTPUTS.pattern.strip("^$"), re.escape(JOURNAL_NAME), re.escape(STATUS_FILE),
                    r"map\.ply", r"\..+\.tmp"])
    archive = "|".join([re.escape(MANIFEST_NAME), re.escape(MAP_JOURNAL), SUBMAP_RE.pattern.strip("^$"),
                        TEMP_RE.pattern.strip("^$")])
    return re.compile(f"^(({top})|map/({archive}))$")


OS_METADATA = re.compile(r"(^|/)(\.DS_Store|\._[^/]*|Thumbs\.db|desktop\.ini)$")
"""Files file browsers and some file systems add to any folder (macOS Finder, exFAT/SMB volumes,
Windows Explorer): never a reason to keep or refuse a run folder."""


def holds_files(folder: Path) -> bool:
    """Whether `folder` holds anything but OS metadata files (a folder made in Finder holds .DS_Store)."""
    return any(not OS_METADATA.search(p.name) for p in folder.iterdir())


def _files(folder: Path) -> list[str]:
    """Every file under `folder` (relative, '/'-separated), OS metadata files left out."""
    return sorted(rel for p in folder.rglob("*") if not p.is_dir()
                  and not OS_METADATA.search(rel := p.relative_to(folder).as_posix()))


def _listing(names: list[str]) -> str:
    return ", ".join(names[:3]) + (f" and {len(names) - 3} more" if len(names) > 3 else "")


def not_replaceable(folder: Path) -> str | None:
    """Why `folder` may not be replaced by a new run, or None when it holds a finished DAVIO run and
    nothing else: a `run_status.json` with its status and file list, and only those files (plus
    DERIVED_FILES). Anything the user added, or a folder some other program wrote, is never removed."""
    try:
        status = json.loads((folder / STATUS_FILE).read_text())
    except (OSError, ValueError):
        return f"it holds no readable {STATUS_FILE} (not a finished DAVIO run)"
    if not isinstance(status, dict) or status.get("status") not in STATUSES \
            or not isinstance(status.get("files"), list):
        return f"its {STATUS_FILE} is not one a DAVIO run wrote"
    allowed = {str(f) for f in status["files"]} | {STATUS_FILE, *DERIVED_FILES}
    extra = [f for f in _files(folder) if f not in allowed]
    if extra:
        return f"it holds files the run did not write ({_listing(extra)})"
    return None


def _partial_not_removable(partial: Path) -> str | None:
    """Why a leftover `<out>.partial/` may not be removed, or None when it holds only files a run writes."""
    names = _partial_names()
    extra = [f for f in _files(partial) if not names.match(f)]
    return f"it holds files no DAVIO run writes ({_listing(extra)})" if extra else None


def run_status(folder: str | Path) -> str:
    """"complete", "interrupted" or "failed" for a finished run folder; "unfinished" for a folder
    without a readable status (a killed run's `.partial`, or a run from before run_status.json)."""
    try:
        status = json.loads((Path(folder) / STATUS_FILE).read_text()).get("status")
    except (OSError, ValueError, AttributeError):
        return "unfinished"
    return status if status in STATUSES else "unfinished"


def _partial_of(out: Path) -> Path:
    return out.with_name(out.name + ".partial")


def check_writable_target(out: Path, what: str = "--out") -> None:
    """ConfigError when `out` cannot become a folder: it is a file, lies under a file, or its nearest
    existing ancestor is not writable."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{what} {out} is a file, not a folder")
    parent = out
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ConfigError(f"{what} {out}: {parent} is a file, so no folder can be made under it")
    probe = out if out.exists() else parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ConfigError(f"{what} {out}: {probe} is not writable")


@dataclass
class RunFolder:
    """Where a run writes (`path`, the partial sibling) and where it lands (`out`)."""

    out: Path
    path: Path
    replace_existing: bool
    started_unix_s: float = field(default_factory=time.time)

    @classmethod
    def prepare(cls, out: str | Path, overwrite: bool = False) -> RunFolder:
        """Check `out` before any work (nothing is created until `create`).

        Raises ConfigError: `out` is a file or under a file, not writable, or a non-empty folder
        without `overwrite`, or (with `overwrite`) a non-empty folder that is not a previous DAVIO run
        holding only what it wrote (`not_replaceable`), or a leftover partial folder holding other files.
        """
        out = Path(out)
        if out.name in ("", ".", ".."):     # `--out .`: the partial folder is named after the folder itself
            out = out.resolve()
        check_writable_target(out)
        replace_existing = False
        if out.is_dir() and holds_files(out):
            if not overwrite:
                raise ConfigError(f"--out {out} is not empty (a previous run?); pass --overwrite to replace "
                                  "it, or choose another folder")
            why = not_replaceable(out)
            if why is not None:
                raise ConfigError(f"--out {out} is not replaced: {why}; --overwrite only replaces a previous "
                                  "DAVIO run folder as it wrote it: choose another folder")
            replace_existing = True
        partial = _partial_of(out)
        if partial.exists():
            if not overwrite:
                raise ConfigError(f"{partial} exists: an unfinished run (killed, or still running); remove "
                                  "it or pass --overwrite")
            why = _partial_not_removable(partial) if partial.is_dir() else "it is not a folder"
            if why is not None:
                raise ConfigError(f"{partial} is not removed: {why}; move it away or choose another --out")
        return cls(out, partial, replace_existing)

    def create(self) -> Path:
        """Create the partial folder the run writes into (a stale one is removed); returns it."""
        if self.path.exists():
            shutil.rmtree(self.path)
        try:
            self.path.mkdir(parents=True)
        except OSError as exc:
            raise ConfigError(f"--out {self.out}: cannot create {self.path}: {exc.strerror or exc}") from exc
        return self.path

    @contextlib.contextmanager
    def discard_on_error(self) -> Iterator[None]:
        """Remove the partial folder when the block fails before any run output was written (a bad
        recording or model: nothing to keep); a failure after that (trajectories, a map commit,
        journalled poses or a run event on disk, e.g. the rig finding that explains the failure) leaves it,
        as an unfinished run."""
        from tools.event_output import EVENTS_NAME
        from tools.pose_journal import journal_has_poses

        try:
            yield
        except BaseException:
            events = self.path / EVENTS_NAME
            kept = ((self.path / "odometry.tum").exists() or (self.path / "map" / "manifest.json").exists()
                    or journal_has_poses(self.path) or (events.is_file() and events.stat().st_size > 0))
            if self.path.is_dir() and not kept:
                shutil.rmtree(self.path, ignore_errors=True)
            raise

    def finish(self, status: str, reason: str | None = None) -> Path:
        """Write run_status.json and move the run into place (replacing the previous run when
        allowed); returns the final folder."""
        if status not in STATUSES:
            raise ValueError(f"status must be one of {STATUSES}, got {status!r}")
        from runtime.files import atomic_write_text
        from tools.run_io import versions

        files = _files(self.path)
        atomic_write_text(self.path / STATUS_FILE, json.dumps({
            "status": status, "reason": reason, "started_unix_s": self.started_unix_s,
            "ended_unix_s": time.time(), "davio": versions().get("davio"), "files": files}, indent=1) + "\n")
        if self.out.exists():
            old = self.out.with_name(f"{self.out.name}.old-{os.getpid()}")
            os.replace(self.out, old)   # an empty folder, or a run allowed to be replaced
            os.replace(self.path, self.out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(self.path, self.out)
        return self.out
