"""Section 1, work-precision: every tool on every case over the tolerance sweep, and the
time each needs to reach each error level (the dominance check)."""

from __future__ import annotations

import _cases as C
import numpy as np
from _cases import log
from peers import HeyokaImpactRunner

from .common import ERROR_LEVELS, HAVE_HEYOKA, HAVE_SCIPY, HEADLINE_CASE, IMPLICIT, METRICS
from .runners import peer_errors, wp_batch, wp_grazejax, wp_heyoka, wp_scipy


def front(rows, metric, E):
    """Cheapest (min time) ok row with error ≤ E, or None."""
    good = [
        r
        for r in rows
        if r.get("ok")
        and r.get(metric) is not None
        and r[metric] <= E
        and r.get("time_min_s") is not None
    ]
    return min(good, key=lambda r: r["time_min_s"]) if good else None


def dominance(rows, case):
    """Time to reach each error level: grazejax (any solver, single run) vs the best SciPy
    method and heyoka, per metric."""
    gjr = [r for r in rows if r["case"] == case and r["tool"] == "grazejax"]
    spr = [r for r in rows if r["case"] == case and r["tool"] == "scipy"]
    hyr = [r for r in rows if r["case"] == case and r["tool"] == "heyoka"]
    out = {}
    for metric in METRICS:
        levels = []
        for E in ERROR_LEVELS:
            g, s, h = front(gjr, metric, E), front(spr, metric, E), front(hyr, metric, E)
            lvl = {
                "level": E,
                "grazejax": None
                if g is None
                else {"method": g["method"], "tol": g["tol"], "time_s": g["time_min_s"]},
                "scipy": None
                if s is None
                else {
                    "method": s["method"],
                    "tol": s["tol"],
                    "max_step": s["max_step"],
                    "time_s": s["time_min_s"],
                },
                "heyoka": None if h is None else {"tol": h["tol"], "time_s": h["time_min_s"]},
            }
            lvl["grazejax_over_scipy"] = g["time_min_s"] / s["time_min_s"] if g and s else None
            lvl["grazejax_over_heyoka"] = g["time_min_s"] / h["time_min_s"] if g and h else None
            if g is None:
                lvl["grazejax_dominates_scipy"] = False if s is not None else None
            else:
                lvl["grazejax_dominates_scipy"] = (
                    True if s is None else bool(g["time_min_s"] < s["time_min_s"])
                )
            levels.append(lvl)
        decided = [
            lv["grazejax_dominates_scipy"]
            for lv in levels
            if lv["grazejax_dominates_scipy"] is not None
        ]
        ratios = [
            (lv["grazejax_over_scipy"], lv["level"])
            for lv in levels
            if lv["grazejax_over_scipy"] is not None
        ]
        worst = max(ratios) if ratios else (None, None)
        out[metric] = {
            "levels": levels,
            # None: not compared (SciPy not installed).
            "dominates_scipy_everywhere": (bool(decided) and all(decided)) if spr else None,
            "worst_ratio_grazejax_over_scipy": worst[0],
            "worst_level": worst[1],
            # Within ±10% the verdict is timing noise on a shared machine.
            "ties_within_10pct": [lv for r_, lv in ratios if 0.9 <= r_ <= 1.1],
            # Levels no grazejax run reached (tol ≥ 1e-13) but SciPy did.
            "not_reached_by_grazejax": [
                {"level": lv["level"], **lv["scipy"]}
                for lv in levels
                if lv["grazejax"] is None and lv["scipy"] is not None
            ],
        }
    return out


def section_work_precision(cases, S, res):
    rows = []
    info = {}
    for name in S["cases"]:
        if name not in cases:
            log(f"1) work-precision: {name} skipped: no reference without heyoka or SciPy "
                f"(install them with `{C.BENCH_INSTALL}`)")
            continue
        case = cases[name]
        truth = case.truth()
        log(f"1) work-precision: {case.title}")
        log(
            f"   truth: {case.truth_method}: {len(truth['impact_times'])} impacts ({truth['seconds']:.2f} s)"
        )
        ci = info.setdefault(
            name,
            {
                "title": case.title,
                "truth_method": case.truth_method,
                "x0": case.x0.tolist(),
                "t1": case.t1,
                "notes": case.notes,
                "params": case.peer_params,
                "max_impacts": case.max_impacts,
                "truth": {k: v for k, v in truth.items()},
                "scipy_max_step": case.scipy_max_step,
            },
        )
        # Independent check of a closed-form truth against heyoka in long double.
        if HAVE_HEYOKA and name != "ex1dof" and S["truth_check"]:
            ld = C.heyoka_reference(case.peer_system, case.x0, case.t1, case.peer_params)
            same = len(ld["impact_times"]) == len(truth["impact_times"])
            ci["truth_check_heyoka_longdouble"] = (
                {
                    "impacts_agree": True,
                    "max_diff_t": float(
                        np.max(np.abs(ld["impact_times"] - truth["impact_times"]), initial=0.0)
                    ),
                    "max_diff_post": float(
                        np.max(np.abs(ld["impact_post"] - truth["impact_post"]), initial=0.0)
                    ),
                    "max_diff_final": float(np.max(np.abs(ld["x_final"] - truth["x_final"]))),
                }
                if same
                else {"impacts_agree": False}
            )
        if name == "ex1dof" and HAVE_HEYOKA:
            d = HeyokaImpactRunner(case.peer_system, tol=1e-15).run(
                case.x0, 0.0, case.t1, 10**6, **case.peer_params
            )
            ci["truth_check_heyoka_double_1e-15"] = peer_errors(d, truth)
        solvers = S["solvers"].get(name, case.grazejax_solvers)
        for s in solvers:
            wp_grazejax(case, s, S, rows, ci)
        for m in S["scipy_methods"].get(name, case.scipy_methods) if HAVE_SCIPY else ():
            wp_scipy(case, m, S, rows)
        if HAVE_HEYOKA:
            wp_heyoka(case, S, rows)
        if name == HEADLINE_CASE and S["batch_wp_lanes"] and not HAVE_HEYOKA:
            log(f"   batch: skipped: its per-lane long-double references need heyoka "
                f"(install it with `{C.BENCH_INSTALL}`)")
        elif name == HEADLINE_CASE and S["batch_wp_lanes"]:
            best = "Dopri8" if "Dopri8" in solvers else solvers[0]
            log(f"   batch: vmap × {S['batch_wp_lanes']} ({best}), per lane")
            wp_batch(case, best, S["batch_wp_lanes"], S, rows)
        ci["dominance"] = dominance(rows, name)
        for metric, d in ci["dominance"].items() if HAVE_SCIPY else ():
            log(
                f"   grazejax dominates scipy at every level 1e-3…1e-11 ({METRICS[metric]}): "
                f"{d['dominates_scipy_everywhere']}"
            )
    # Calibration of steps × stages against counted calls (full mode).
    calib = [
        {
            "case": r["case"],
            "method": r["method"],
            "tol": r["tol"],
            "steps": r["steps"],
            "nominal": r["evals"],
            "counted": r["f_calls_counted"],
            "counted_over_nominal": r["f_calls_counted"] / r["evals"],
        }
        for r in rows
        if r["tool"] == "grazejax" and r["method"] not in IMPLICIT and "f_calls_counted" in r
    ]
    res["work_precision"] = {
        "rows": rows,
        "cases": info,
        "evals_calibration": calib,
        "tolerances": S["tols"],
        "error_levels": ERROR_LEVELS,
    }
    return rows
