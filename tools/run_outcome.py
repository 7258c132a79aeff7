"""How a run ends: its status, why nothing was published when nothing was, the exit code.

A run that cannot publish says why and exits non-zero; Ctrl-C, SIGTERM (systemd, docker stop) or SIGHUP
(a dropped SSH session) ends it with the outputs up to the interruption (exit 130); an error after the
work started keeps what was computed (exit 1). Once the data phase is over (`finishing()`), a signal no
longer stops the run: writing its outputs (map.ply, trajectories, report) is what it is doing.
"""
from __future__ import annotations

import contextlib
import signal
import sys
from collections.abc import Callable, Iterator
from typing import Any

EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130

STOP_SIGNALS = ("SIGINT", "SIGTERM", "SIGHUP")
"""Signals that finish a run cleanly (those the platform has)."""


class _Stops:
    """The signals one `interruptible` block received."""

    def __init__(self) -> None:
        self.count = 0
        self.finishing: str | None = None
        self.said = False


_ACTIVE: list[_Stops] = []


def _on_signal(signum: int, frame: Any) -> None:
    st = _ACTIVE[-1] if _ACTIVE else None
    if st is None:
        raise KeyboardInterrupt
    st.count += 1
    if st.count == 1 and st.finishing is None:
        raise KeyboardInterrupt          # the run stops reading data and writes what it has
    if not st.said:                       # a second signal, or one while the outputs are written
        st.said = True
        from tools.stderr_lines import say

        name = signal.Signals(signum).name
        say(f"\ndavio: {name}: still {st.finishing or 'finishing the run'}; it ends by itself, and stopping "
            "it now would lose the run's outputs (kill -9 stops it at once)")


@contextlib.contextmanager
def interruptible() -> Iterator[None]:
    """Within the block Ctrl-C, SIGTERM and SIGHUP raise KeyboardInterrupt once, so each finishes a run
    cleanly; a later one (a second Ctrl-C while the run winds down), or any after `finishing()`, is said
    and otherwise ignored. A signal the process was told to ignore stays ignored (`nohup davio live ...`
    survives a dropped SSH session; a background job `davio run ... &` ignores the terminal's Ctrl-C)."""
    names = [n for n in STOP_SIGNALS if hasattr(signal, n)]
    try:
        names = [n for n in names if signal.getsignal(getattr(signal, n)) is not signal.SIG_IGN]
        previous = {n: signal.signal(getattr(signal, n), _on_signal) for n in names}
    except ValueError:   # not the main thread: leave signals alone
        yield
        return
    _ACTIVE.append(_Stops())
    try:
        yield
    finally:
        _ACTIVE.pop()
        for n, handler in previous.items():
            signal.signal(getattr(signal, n), handler)


def finishing(what: str = "writing the run's outputs") -> None:
    """From here to the end of the `interruptible` block a signal does not stop the work (`what` is said
    when one comes)."""
    if _ACTIVE:
        _ACTIVE[-1].finishing = what


def finish_mapping(res: Any, pipeline: Any) -> None:
    """Map the windows still queued when the data ended (a complete run only). Ctrl-C or SIGTERM there
    stops the mapping: the run is interrupted and writes what it has."""
    if res.status != "complete":
        return
    try:
        pipeline.finish_mapping()
    except KeyboardInterrupt:
        res.status = "interrupted"
        res.reason = "interrupted while mapping the windows queued at the end of the data"


def why_nothing_published(pipeline_report: dict, driver_report: dict | None, sched: Any) -> str:
    """One paragraph: what reached the pipeline and what each initializer did with it."""
    parts: list[str] = []
    if sched.imu_samples == 0:
        parts.append("no IMU sample reached the filter")
    if sched.frames == 0:
        parts.append("no camera frame reached the tracker")
    streams = (driver_report or {}).get("streams") or {}
    for name, c in streams.items():
        lost = ("missing_images", "repeated_images", "unreadable_images", "late_images")
        bad = {k: c.get(k, 0) for k in lost if c.get(k)}
        if bad:
            parts.append(f"{name}: " + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in bad.items()))
    parts.extend((driver_report or {}).get("notes") or [])
    tracking = pipeline_report.get("tracking") or {}
    if sched.frames and tracking.get("frames_without_tracks", 0) >= sched.frames:
        parts.append("no frame had trackable features (dark, blank or unfocused images?)")
    check = pipeline_report.get("rig_check") or {}      # a wrong rig the tracked features named
    parts.extend(f"{name}: {check[key]}" for key, name in (("gyro_scale", "GYROSCOPE SCALE"),
                                                          ("extrinsics_rotation", "CAMERA-IMU ROTATION"),
                                                          ("extrinsics_suspect", "CAMERA-IMU ROTATION?"))
                 if check.get(key))
    bu = pipeline_report.get("bringup") or {}
    if bu and not bu.get("R_IC"):
        from runtime.bringup import gyro_blamed

        rej = ", ".join(f"{k} x{v}" for k, v in sorted((bu.get("rejections") or {}).items())) or "none"
        gyro = gyro_blamed(bu)
        parts.append(f"GYROSCOPE SCALE: {gyro}" if gyro else
                     f"the hand-eye bring-up never completed ({bu.get('windows_used', 0)} windows held, "
                     f"rejections: {rej}): the camera-IMU rotation stayed unknown"
                     + ("; windows no rotation fits point at the gyroscope's scale or a large camera-IMU "
                        "time offset" if (bu.get("rejections") or {}).get("handeye_poor_fit") else ""))
    st = pipeline_report.get("startup") or {}
    if st.get("ff_requests"):
        rej = ", ".join(f"{k} x{v}" for k, v in sorted((st.get("ff_rejections") or {}).items())) or "none"
        parts.append(f"feed-forward start-up: {st.get('ff_requests', 0)} windows tried, "
                     f"{st.get('ff_accepted', 0)} accepted (rejected: {rej})")
    started, selected = st.get("candidates_started") or 0, st.get("candidates_selected") or 0
    if started and not selected:
        gone = {k: st.get(f"candidates_{k}") or 0 for k in ("abandoned", "diverged", "outrun")}
        fates = ", ".join(f"{v} {k}" for k, v in gone.items() if v)
        parts.append(f"{started} feed-forward candidate(s) started, none confirmed (it takes "
                     "startup.consecutive_states live states) before the data ended"
                     + (f" ({fates})" if fates else ""))
    if st.get("ff_extensions"):
        ext_rej = st.get("ff_extension_rejections") or {}
        rej = ", ".join(f"{k} x{v}" for k, v in sorted(ext_rej.items())) or "none"
        parts.append(f"{st['ff_extensions']} re-solves of refused windows over a longer span, "
                     f"{st.get('ff_extension_accepted', 0)} accepted (rejected: {rej})")
    errors = tracking.get("ff_exceptions") or []
    if errors:
        failed = max(tracking.get("ff_errors") or 0, len(errors))
        parts.append(f"{failed} model calls failed (first: {errors[0]})")
    filt = pipeline_report.get("filter") or {}
    if filt and not filt.get("initialized"):
        why = "; ".join(f"{name}: {_rejections(r)}" for name, r in (filt.get("initializers") or {}).items())
        parts.append(f"the native initializer found no start in {sched.sensor_s:.1f} s of data (it needs a "
                     "standstill or enough motion with tracked features)" + (f"; {why}" if why else ""))
    if filt and filt.get("initialized") and not filt.get("frames_processed"):
        no_imu = int(filt.get("frames_no_imu") or 0)
        parts.append(f"the filter started but processed no frame ({no_imu} frames had no IMU data up to "
                     "their stamp): the camera and IMU stamps do not overlap once the rig's camera-IMU time "
                     "offset is applied (check time_offset_s / timeshift_cam_imu and the clocks)" if no_imu
                     else "the filter started but processed no frame")
    return "; ".join(parts) or "no reason recorded"


def _rejections(init_report: dict) -> str:
    """'code xN, ... (last: the last reason)' of one native initializer's report."""
    rej = init_report.get("rejections") or {}
    if not rej:
        return "never tried"
    return ", ".join(f"{k} x{v}" for k, v in sorted(rej.items())) + f" (last: {init_report['last_reason']})"


def judge(res: Any, driver_report: dict | None) -> None:
    """Mark a run that ended normally but published nothing as failed, with the reason."""
    if res.status == "complete" and not res.pipeline.published:
        res.status = "failed"
        res.reason = "no pose was published: " + why_nothing_published(
            res.pipeline.report(), driver_report, res.scheduler)


def conclude(folder: Any, res: Any, report: dict, as_json: bool,
             summary: Callable[[dict, Any], None]) -> int:
    """Move the run folder into place with its status, print the summary (or the JSON report) and
    the error when the run did not complete; returns the exit code."""
    from runtime.json_out import strict_dumps

    out = folder.finish(res.status, res.reason)
    if as_json:
        print(strict_dumps(report))
    else:
        summary(report, out)
    if res.status == "interrupted":
        print(f"davio: {res.reason}; the outputs up to then are in {out} (run_status.json: interrupted)",
              file=sys.stderr)
        return EXIT_INTERRUPTED
    if res.status == "failed":
        print(f"davio: error: {res.reason}\n  what was computed is in {out} (run_status.json: failed)",
              file=sys.stderr)
        return EXIT_FAILED
    return EXIT_OK
