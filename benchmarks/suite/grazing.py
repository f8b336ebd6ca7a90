"""Section 2, the cost of grazing: one impact at depth δ below the surface, δ → 0."""

from __future__ import annotations

import _cases as C
import jax
import jax.numpy as jnp
import numpy as np
from _cases import log, measure
from peers import HeyokaImpactRunner, ScipyImpactRunner

import grazejax as gj

from .common import HAVE_HEYOKA, HAVE_SCIPY, fit_power, fmt_e
from .runners import jit_run, peer_errors, sol_errors

GRAZING_SETUPS = {
    "rotation": dict(
        title="rotation (exnonaxial): the solver's error ~ tol adds to δ",
        setup="exnonaxial rotation from a start on the circle r = 1 + δ/√2 (Φ_min = −δ at t ≈ 3), "
        "t1 = 6; truth: closed form for the float start (40 digits)",
        t1=6.0,
        fit_min_depth=1e-7,
    ),
    "parabola": dict(
        title="parabola x'' = 1 above a floor: exact flow for every RK method",
        setup="x = h + v0 t + t²/2 with minimum −δ at t = 1 (h = 1/2 − δ, v0 = −1), floor Φ = x, "
        "v → −0.8 v, t1 = 3; truth: closed form for the float start (40 digits)",
        t1=3.0,
        fit_min_depth=1e-13,
    ),
}


def grazing_start(setup, depth):
    if setup == "rotation":
        return C.exnonaxial_grazing_start(depth, 3.0)
    return C.parabola_grazing_start(depth)


def section_grazing(cases, S, res):
    """One impact at depth δ below the surface (δ < 0: a near miss), δ → 0."""
    tol = 1e-10
    rows = []
    log(f"2) grazing: one impact at depth δ, rtol = atol = {tol:g} for every tool")
    out = {"tol": tol, "setups": {}}
    for setup, spec in GRAZING_SETUPS.items():
        rows.extend(_grazing_runs(setup, spec, cases, tol, S))
        srows = [r for r in rows if r["setup"] == setup]
        out["setups"][setup] = _grazing_fits(srows, spec)
    out["rows"] = rows
    res["grazing"] = out
    return rows


def _grazing_problem(setup, cases):
    """The setup's scene and args for grazejax, its system and parameters for the peers."""
    if setup == "rotation":
        return (
            cases["exnonaxial"].scene,
            cases["exnonaxial"].args,
            cases["exnonaxial"].peer_system,
            cases["exnonaxial"].peer_params,
        )
    scene, args = C.parabola_scene(), {"a": jnp.asarray(1.0), "e": jnp.asarray(0.8)}
    system, params = C.PARABOLA_SYSTEM, {"a": 1.0, "e": 0.8}
    return scene, args, system, params


def _grazing_runs(setup, spec, cases, tol, S):
    """Every tool at every depth of one setup (compiled first, outside the timings)."""
    scene, args, system, params = _grazing_problem(setup, cases)
    t1 = spec["t1"]
    runs = {s_: jit_run(scene, s_, 32) for s_ in S["grazing_solvers"]}
    x_warm, _, _ = grazing_start(setup, 1e-3)
    for run in runs.values():  # compile outside the timings (a no-op if already compiled)
        jax.block_until_ready(run(jnp.asarray(x_warm), t1, args, tol))
    hy = HeyokaImpactRunner(system, tol=tol) if HAVE_HEYOKA else None
    sp_runners = {
        "DOP853": ScipyImpactRunner(system, "DOP853", tol, tol),
        "DOP853 max_step 0.05": ScipyImpactRunner(system, "DOP853", tol, tol, max_step=0.05),
    } if HAVE_SCIPY else {}
    depths = list(S["grazing_depths"]) + [-1e-3, -1e-6]
    if setup == "parabola":
        depths = sorted(set(S["grazing_depths"]) | {1e-14}, reverse=True) + [
            -1e-3,
            -1e-6,
            -1e-12,
        ]
    log(f"   {spec['title']}")
    rows = []
    for depth in depths:
        these = _runs_at_depth(setup, depth, t1, args, params, (runs, sp_runners, hy), tol, S)
        rows.extend(these)
        msg = "  ".join(
            f"{r['tool'][:2]}:{r['method'][:6]}{'+ms' if 'max_step' in r['method'] else ''} "
            f"{r['impacts_found']}/{r['impacts_expected']} {fmt_e(r['err_t'])}"
            for r in these
        )
        log(f"   δ {depth:+.0e}: {msg}")
    return rows


def _runs_at_depth(setup, depth, t1, args, params, runners, tol, S):
    """One row per tool (grazejax solvers, SciPy, heyoka) for the start at this depth."""
    runs, sp_runners, hy = runners
    x0, exact_depth, truth = grazing_start(setup, depth)
    base = {
        "setup": setup,
        "depth": depth,
        "depth_exact": exact_depth,
        "tol": tol,
        "impacts_expected": len(truth["impact_times"]),
    }
    these = []
    for s_, run in runs.items():
        sol, tm = measure(
            lambda run=run, x0=x0, t1=t1, args=args: jax.block_until_ready(
                run(jnp.asarray(x0), t1, args, tol)
            ),
            S["budget"] / 3,
            S["max_rep"],
        )
        e = sol_errors(sol, truth)
        k = int(sol.num_impacts)
        kinds = [gj.ImpactKind(int(v)).name for v in np.asarray(sol.impact_kind)[:k]]
        these.append(
            {
                **base,
                "tool": "grazejax",
                "method": s_,
                "time_min_s": tm["min_s"],
                "steps": int(sol.num_steps),
                "accepted": int(sol.num_accepted_steps),
                "kinds": "/".join(kinds),
                **e,
            }
        )
    for label, runner in sp_runners.items():
        r, tm = measure(
            lambda runner=runner, x0=x0, t1=t1, params=params: runner.run(
                x0, 0.0, t1, 10**6, **params
            ),
            S["budget"] / 3,
            5,
            min_repeats=0,
        )
        these.append(
            {
                **base,
                "tool": "scipy",
                "method": label,
                "time_min_s": tm["min_s"],
                "steps": r["nfev"],
                **peer_errors(r, truth),
            }
        )
    if hy is not None:
        r, tm = measure(
            lambda hy=hy, x0=x0, t1=t1, params=params: hy.run(x0, 0.0, t1, 10**6, **params),
            S["budget"] / 3,
            30,
        )
        these.append(
            {
                **base,
                "tool": "heyoka",
                "method": "taylor",
                "time_min_s": tm["min_s"],
                "steps": r["nfev"],
                **peer_errors(r, truth),
            }
        )
    return these


def _grazing_fits(srows, spec):
    """√δ loss: fit err_t ∝ δ^p over depths well above the solver's own error, per tool; and
    the depths where each tool found a wrong number of impacts."""
    fits = {}
    keys = sorted({(r["tool"], r["method"]) for r in srows})
    for key in keys:
        # Contacts reported as grazing (γ, within grazejax's contact floor) are placed at
        # the minimum of Φ by design: not a crossing-time estimate, left out of the fit.
        pts = [
            (r["depth"], r["err_t"])
            for r in srows
            if (r["tool"], r["method"]) == key
            and r["depth"] > 0
            and r.get("ok")
            and r["err_t"]
            and r["depth"] >= spec["fit_min_depth"]
            and "GAMMA" not in r.get("kinds", "")
        ]
        if len(pts) >= 3:
            p, _ = fit_power(*zip(*pts, strict=True))
            fits[f"{key[0]} {key[1]}"] = {"exponent": p, "points": len(pts)}
    wrong = {
        f"{k[0]} {k[1]}": [
            r["depth"] for r in srows if (r["tool"], r["method"]) == k and not r.get("ok")
        ]
        for k in keys
    }
    result = {
        **spec,
        "fits_err_t_vs_depth": fits,
        "wrong_impact_count_at_depths": wrong,
    }
    for k, v in sorted(fits.items()):
        log(
            f"   err_t ∝ δ^{v['exponent']:.2f}  ({k}, {v['points']} depths ≥ {spec['fit_min_depth']:g})"
        )
    return result
