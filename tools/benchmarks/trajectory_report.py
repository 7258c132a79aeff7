"""`davio bench trajectory`'s console report: per sequence the trajectory table, the goals, the odometry's
drift with the plain EASY verdict, and the ablation table; then the OpenVINS references."""
from __future__ import annotations

from typing import Any

import numpy as np

from tools.benchmarks.trajectory import EASY_FRACTION, MIN_DRIFT_PATH_M


def _f(x: Any, fmt: str = ".3f") -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, fmt)


def drift_lines(s: dict, refs: dict) -> list[str]:
    """The odometry-drift sentences of one sequence, with the plain verdict."""
    d, tr = s["drift"], s["trajectory"]
    out = [f"odometry ATE {tr['odometry']['ate_m']:.4f} m = {d['ate_percent_of_path']:.3f} % of the "
           f"{d['path_m']:.1f} m path"]
    if d["path_m"] < MIN_DRIFT_PATH_M:
        out.append(f"odometry drift: the path ({d['path_m']:.1f} m) is shorter than {MIN_DRIFT_PATH_M:g} m, "
                   "too short for a drift per distance")
        return out
    rpe = d.get("rpe")
    rpe_txt = f"; RPE over {rpe['segment_m']:g} m: {rpe['mean_percent']:.2f} %" if rpe else ""
    out.append(f"odometry drift: {d['end_error_m']:.3f} m after {d['path_m']:.0f} m = "
               f"{d['percent']:.2f} % of distance (start-anchored){rpe_txt}")
    moved = tr["final"]["ate_m"] - tr["odometry"]["ate_m"]
    ref = refs.get("paper_openvins_mh03")
    if s.get("easy") is None or not ref:
        return out
    mine, theirs = d["ate_percent_of_path"], ref["ate_percent_of_path"]
    if s["easy"]:
        out.append(f"EASY: the simulated odometry's ATE is {mine:.3f} % of its path, less than "
                   f"{EASY_FRACTION:g} x OpenVINS's on real EuRoC MH_03 ({theirs:.3f} %): little error for "
                   f"the graph to remove here (final - odometry ATE: {moved:+.4f} m)")
    else:
        out.append(f"not easy: the odometry's ATE per path ({mine:.3f} %) is at least {EASY_FRACTION:g} x "
                   f"OpenVINS's on real EuRoC MH_03 ({theirs:.3f} %); final - odometry ATE: {moved:+.4f} m")
    return out


def print_tables(result: dict) -> None:
    """Print the benchmark's result (`trajectory.run`'s JSON object) as tables and sentences."""
    from rich.console import Console
    from rich.table import Table

    con = Console(width=max(Console().width, 150))
    for msg in result["skipped"]:
        con.print(msg)
    for name, s in result["sequences"].items():
        if "error" in s:
            con.print(f"{name}: {s['error']}")
            continue
        tr = s["trajectory"]
        t = Table(title=f"{name}: {s['sequence_s']:.0f} s, {s['drift']['path_m']:.0f} m, "
                        f"{s['windows_processed']} windows (emulated DA3 {result['emulated_da3']}, "
                        "native start-up)")
        for c in ("trajectory", "ATE (m)", "/ odometry", "coverage", "T_f (s)"):
            t.add_column(c)
        for key in ("odometry", "causal", "final"):
            t.add_row(key, _f(tr[key]["ate_m"], ".4f"), _f(tr[key]["ratio"]), _f(tr["coverage"]),
                      _f(tr["T_f_s"], ".2f"))
        con.print(t)
        for gname, g in s["goals"].items():
            con.print(f"  goal {gname} {g['target']}: {g['value']:.3f} {'met' if g['met'] else 'NOT met'}")
        h = s.get("tracking", {})
        if h.get("restarts_after_divergence") or h.get("divergence_reasons"):
            con.print(f"  TRACKING: {h['restarts_after_divergence']} restart(s) after a divergence "
                      f"({'; '.join(h['divergence_reasons'])}); filter initialized at the end: "
                      f"{h['initialized_at_end']} (coverage {tr['coverage']:.3f})")
        for line in drift_lines(s, result.get("anchors", {})):
            con.print(f"  {line}")
        a = Table(title=f"{name}: mapping ablations (same windows)")
        for c in ("variant", "F@10", "compl. med (mm)", "final ATE", "causal ATE", "windows", "solves",
                  "revisits acc/att", "rejected by stage", "point groups adj/rev"):
            a.add_column(c)
        for r in s["ablations"].values():
            g, sf = r["graph"], r.get("surface", {})
            rej = ", ".join(f"{k} {v}" for k, v in g.get("revisits_rejected", {}).items()) or "-"
            compl = _f(1e3 * sf["completeness_median_m"], ".0f") if sf else "-"
            a.add_row(r["label"], _f(sf.get("f10")), compl, _f(r["final_ate_m"], ".4f"),
                      _f(r["causal_ate_m"], ".4f"),
                      f"{r['windows_accepted']}/{r['windows_offered']}", str(g.get("solves", "-")),
                      f"{g['revisits_accepted']}/{g['revisits_attempted']}" if g else "-", rej,
                      f"{g['point_groups_adjacent']}/{g['point_groups_revisit']}" if g else "-")
        con.print(a)
        if s.get("error_scales"):
            e = Table(title=f"{name}: the complete system with the odometry's error x k (same run)")
            for c in ("k", "odometry ATE", "final ATE", "final / odometry", "causal ATE", "causal / odometry",
                      "revisits acc/att", "revisit point groups", "F@10"):
                e.add_column(c)
            for r in s["error_scales"].values():
                e.add_row(f"{r['k']:g}", _f(r["odometry_ate_m"], ".4f"), _f(r["final_ate_m"], ".4f"),
                          _f(r["final_ratio"]), _f(r["causal_ate_m"], ".4f"), _f(r["causal_ratio"]),
                          f"{_f(r['revisits_accepted'], 'd')}/{_f(r['revisits_attempted'], 'd')}",
                          _f(r["revisit_point_groups"], "d"), _f(r["f10"]))
            con.print(e)
    an = result.get("anchors", {})
    if "paper_openvins_mh03" in an:
        p = an["paper_openvins_mh03"]
        con.print(f"reference: OpenVINS on real EuRoC MH_03: ATE {p['ate_m']:.3f} m over a "
                  f"{p['path_m']:.0f} m path = {p['ate_percent_of_path']:.3f} % ({p['source']})")
    if "openvins_sim" in an:
        o = an["openvins_sim"]
        con.print(f"reference: {o['what']}: drift {o['percent']:.3f} % of {o['path_m']:.0f} m, RPE over 10 m "
                  f"{o['rpe']['mean_percent']:.2f} %, position RMSE {o['ate_m']:.3f} m = "
                  f"{o['ate_percent_of_path']:.3f} % of the path")
    con.print(f"all goals met: {result['goals_met']}  (wall {result['wall_s']:.0f} s)")
