"""Section 5, scaling with the number of impacts and with the batch size (fitted exponents)."""

from __future__ import annotations

import time

import _cases as C
import jax
import jax.numpy as jnp
import numpy as np
from _cases import first_minus_second, log, measure
from peers import HeyokaImpactRunner, ScipyImpactRunner

from .common import HAVE_HEYOKA, HAVE_SCIPY, fit_power
from .effects import _BATCH, EFFECTS_TOL, batch_timing
from .runners import jit_run


def section_scaling(cases, S, res):
    case = cases["oscillator"]
    tol = 1e-8
    log(f"5) scaling (oscillator, Tsit5, rtol = atol = {tol:g}; heyoka tol {tol:g}; SciPy DOP853)")
    nmax = max(S["scaling_impacts"])
    rows_n, fits_n, c = _scaling_impacts(case, nmax, tol, S)
    rows_b, fit_b, hy_per_run = _scaling_batch(cases, S)
    ex = cases["exnonaxial"]
    res["scaling"] = {
        "impacts": {
            "rows": rows_n,
            "fits": fits_n,
            "compile_s": c["compile_s"],
            "tol": tol,
            "max_impacts_static": nmax + 8,
        },
        "batch": {
            "rows": rows_b,
            "fit": fit_b,
            "t1": ex.t1,
            "tol": EFFECTS_TOL,
            "heyoka_per_run_same_starts_s": hy_per_run,
            "scene": "exnonaxial (the effects scene): starts on circles r = 1.2…1.212 "
            "at random phases, t1 = 100 (17 impacts each), Tsit5, final state",
        },
        "scene": "impacts: forced impact oscillator (ζ 0.05, A 1, ω 1.5, σ 0.2, r 0.8), Tsit5",
    }
    for k, v in fits_n.items():
        log(f"   time ∝ impacts^{v['exponent']:.2f} ({k}, impacts ≥ 16)")
    if fit_b:
        log(f"   time ∝ batch^{fit_b['exponent']:.2f} (batch ≥ 16)")


def _impact_times(case, nmax):
    """The oscillator's first nmax + 1 impact times (heyoka at tol 1e-15, else closed form)."""
    ref = (
        HeyokaImpactRunner(case.peer_system, tol=1e-15).run(
            case.x0, 0.0, 6.0 * (nmax + 2), nmax + 1, **case.peer_params
        )
        if HAVE_HEYOKA
        else None
    )
    if ref is not None:
        times = ref["impact_times"]
    else:  # pragma: no cover
        times = C.LinearStopTruth(C._oscillator_matrix(0.05), [0, 1], 1.0, 1.5, 0.2, 0.8)(
            case.x0, 6.0 * (nmax + 2), nmax + 1
        )["impact_times"]
    return times


def _scaling_impacts(case, nmax, tol, S):
    """Time vs the number of impacts (t1 between impacts n and n + 1), with and without the
    impact log, and the peers; returns the rows, the fits and the compile time."""
    times = _impact_times(case, nmax)
    run = jit_run(case.scene, "Tsit5", nmax + 8, output="final")
    run_log = jit_run(case.scene, "Tsit5", nmax + 8)
    x0 = jnp.asarray(case.x0)
    # t1 always a float64 scalar (a weakly typed Python float would be another signature).
    c = first_minus_second(lambda: run(x0, np.float64(10.0), case.args, tol))
    first_minus_second(lambda: run_log(x0, np.float64(10.0), case.args, tol))
    hy = HeyokaImpactRunner(case.peer_system, tol=tol) if HAVE_HEYOKA else None
    sp = ScipyImpactRunner(case.peer_system, "DOP853", tol, tol) if HAVE_SCIPY else None
    rows_n = []
    for n in S["scaling_impacts"]:
        t1 = np.float64(0.5 * (times[n - 1] + times[n]))  # between impact n and n + 1
        (xf, found, steps), tm = measure(
            lambda t1=t1: jax.block_until_ready(run(x0, t1, case.args, tol)),
            S["budget"],
            S["max_rep"],
        )
        _, tl = measure(
            lambda t1=t1: jax.block_until_ready(run_log(x0, t1, case.args, tol)),
            S["budget"],
            S["max_rep"],
        )
        row = {
            "impacts": n,
            "t1": float(t1),
            "grazejax_s": tm["min_s"],
            "grazejax_log_s": tl["min_s"],
            "grazejax_found": int(found),
            "grazejax_steps": int(steps),
        }
        if hy is not None:
            _, th = measure(
                lambda t1=t1: hy.run(case.x0, 0.0, t1, 10**6, **case.peer_params),
                S["budget"],
                3 * S["max_rep"],
            )
            row["heyoka_s"] = th["min_s"]
        if sp is not None and n <= S["scaling_scipy_max"]:
            _, ts_ = measure(
                lambda t1=t1: sp.run(case.x0, 0.0, t1, 10**6, **case.peer_params), S["budget"], 3
            )
            row["scipy_s"] = ts_["min_s"]
        rows_n.append(row)
        log(
            f"   {n:5d} impacts: grazejax {1e3 * row['grazejax_s']:8.2f} ms (with impact log "
            f"{1e3 * row['grazejax_log_s']:.2f} ms; {row['grazejax_found']} found)"
            + (f", heyoka {1e3 * row['heyoka_s']:.3f} ms" if "heyoka_s" in row else "")
            + (f", scipy {1e3 * row['scipy_s']:.1f} ms" if "scipy_s" in row else "")
        )
    return rows_n, _impact_fits(rows_n), c


def _impact_fits(rows_n):
    """Per tool: power law over N ≥ 16 and a linear fit a + b N over all N."""
    fits_n = {}
    for key in ("grazejax_s", "grazejax_log_s", "heyoka_s", "scipy_s"):
        pts = [(r["impacts"], r[key]) for r in rows_n if key in r and r["impacts"] >= 16]
        if len(pts) >= 2:
            fits_n[key] = {
                "exponent": fit_power(*zip(*pts, strict=True))[0],
                "over": [p[0] for p in pts],
            }
            ns, ys = zip(*[(r["impacts"], r[key]) for r in rows_n if key in r], strict=True)
            b, a = np.polyfit(ns, ys, 1)
            fits_n[key].update({"linear_intercept_s": float(a), "linear_per_impact_s": float(b)})
    return fits_n


def _scaling_batch(cases, S):
    """The shared vmapped run at each batch size, heyoka per run over the same starts, and
    the fitted exponent in the batch size."""
    # Batch size: the effects scene (exnonaxial, 17 impacts per lane), jax.vmap'ed.
    rows_b = []
    for b in S["scaling_batch"]:
        tm, comp, _ = batch_timing(cases, b, S)
        rows_b.append(
            {
                "batch": b,
                "grazejax_s": tm["min_s"],
                "per_lane_s": tm["min_s"] / b,
                "compile_s": comp,
            }
        )
        log(
            f"   batch {b:5d}: {1e3 * tm['min_s']:9.2f} ms total, {1e3 * tm['min_s'] / b:.3f} ms/lane "
            f"(compile {comp:.1f} s)"
        )
    hy_per_run = None
    ex = cases["exnonaxial"]
    starts = _BATCH["starts"]
    if HAVE_HEYOKA:
        hyb = HeyokaImpactRunner(ex.peer_system, tol=EFFECTS_TOL)
        nh = min(len(starts), 256)
        hyb.run(starts[0], 0.0, ex.t1, 10**6, **ex.peer_params)
        t = time.perf_counter()
        for i in range(nh):
            hyb.run(starts[i], 0.0, ex.t1, 10**6, **ex.peer_params)
        hy_per_run = (time.perf_counter() - t) / nh
    pts = [(r["batch"], r["grazejax_s"]) for r in rows_b if r["batch"] >= 16]
    fit_b = (
        {"exponent": fit_power(*zip(*pts, strict=True))[0], "over": [p[0] for p in pts]}
        if len(pts) >= 2
        else None
    )
    if fit_b and len(pts) >= 4:  # the large-batch regime alone (per-lane cost has levelled off)
        fit_b["exponent_largest3"] = fit_power(*zip(*pts[-3:], strict=True))[0]
        fit_b["over_largest3"] = [p[0] for p in pts[-3:]]
    return rows_b, fit_b, hy_per_run
