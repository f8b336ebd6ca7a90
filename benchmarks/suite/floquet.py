"""Section 6, Floquet multipliers of the forced oscillator's period-1 orbit against a
closed-form truth in mpmath (if the periodic-orbit API exists)."""

from __future__ import annotations

import math
import time
import traceback

import _cases as C
import jax
import jax.numpy as jnp
import numpy as np
from _cases import log, measure

import grazejax as gj


def periodic_guess():
    """State at t = 20 T of the oscillator from rest: on its period-1 impacting orbit."""
    T = 2 * math.pi / C.OSC_PARAMS["omega"]
    truth = C.LinearStopTruth(
        C._oscillator_matrix(C.OSC_PARAMS["zeta"]),
        [0.0, 1.0],
        C.OSC_PARAMS["A"],
        C.OSC_PARAMS["omega"],
        C.OSC_PARAMS["sigma"],
        C.OSC_PARAMS["r"],
    )
    return jnp.asarray(truth(np.zeros(2), 20 * T)["x_final"])


def floquet_truth():
    """Multipliers of the oscillator's period-1 orbit, by the closed-form flow in mpmath:
    fixed point of the stroboscopic map P (period T = 2π/ω) by Newton, monodromy dP/dy by
    central differences (step 1e-12 at 40 digits: error ~1e-24)."""
    import mpmath

    p = C.OSC_PARAMS
    T = 2 * math.pi / p["omega"]
    truth = C.LinearStopTruth(
        C._oscillator_matrix(p["zeta"]), [0.0, 1.0], p["A"], p["omega"], p["sigma"], p["r"]
    )
    y = np.asarray(periodic_guess(), float)
    with mpmath.workdps(C.DPS):
        Tm = 2 * mpmath.pi / mpmath.mpf(p["omega"])

        def P(yv):  # stroboscopic map from t = 0 (the orbit's phase) to T, in mpmath
            return truth.run_mp(yv, Tm)[3]

        def jac(yv, h=None):
            h = mpmath.mpf("1e-12") if h is None else h
            cols = []
            for j in range(2):
                e = [mpmath.mpf(0)] * 2
                e[j] = h
                a = P([yv[0] + e[0], yv[1] + e[1]])
                b = P([yv[0] - e[0], yv[1] - e[1]])
                cols.append([(a[i] - b[i]) / (2 * h) for i in range(2)])
            return mpmath.matrix([[cols[j][i] for j in range(2)] for i in range(2)])

        yv = [mpmath.mpf(float(v)) for v in y]
        for _ in range(30):
            r = P(yv)
            F = mpmath.matrix([r[i] - yv[i] for i in range(2)])
            Jm = jac(yv) - mpmath.eye(2)
            step = mpmath.lu_solve(Jm, F)
            yv = [yv[i] - step[i] for i in range(2)]
            if mpmath.norm(step) < mpmath.mpf(10) ** (-30):
                break
        M = jac(yv)
        ev, _ = mpmath.eig(M)
    return {
        "x0": [float(v) for v in yv],
        "period": T,
        "multipliers": [complex(v) for v in ev],
        "monodromy": [[float(M[i, j]) for j in range(2)] for i in range(2)],
    }


def _match_error(a, b):
    a, b = list(a), list(b)
    best = math.inf
    import itertools

    for perm in itertools.permutations(range(len(b))):
        best = min(best, max(abs(a[i] - b[perm[i]]) for i in range(len(a))))
    return best


def section_floquet(cases, S, res):
    if not S["floquet_tols"]:
        res["floquet"] = {
            "skipped": "full mode only (each tolerance compiles find_periodic_orbit and "
            "floquet_multipliers again, ~30 s on this machine)"
        }
        log("6) Floquet multipliers: full mode only")
        return
    if not (hasattr(gj, "find_periodic_orbit") and hasattr(gj, "floquet_multipliers")):
        res["floquet"] = {
            "skipped": "grazejax.find_periodic_orbit / floquet_multipliers not in the "
            "package (hasattr false): panel skipped"
        }
        log("6) Floquet multipliers: skipped (grazejax.find_periodic_orbit not available)")
        return
    log("6) Floquet multipliers: oscillator period-1 orbit (forced: fixed period)")
    try:
        ref = floquet_truth()
        case = cases["oscillator"]
        T = ref["period"]
        guess = periodic_guess()
        rows = []
        for tol in S["floquet_tols"]:
            # First call: compiles (rtol and atol are static in these functions, so every new
            # tolerance compiles again); then the same call timed again.
            t = time.perf_counter()
            orbit = gj.find_periodic_orbit(
                case.scene, guess, T, case.args, fixed_period=True, rtol=tol, atol=tol
            )
            jax.block_until_ready(orbit.x0)
            first_find = time.perf_counter() - t
            t = time.perf_counter()
            fl = gj.floquet_multipliers(case.scene, orbit, case.args, rtol=tol, atol=tol)
            first_floquet = time.perf_counter() - t
            _, tf = measure(
                lambda tol=tol: jax.block_until_ready(
                    gj.find_periodic_orbit(
                        case.scene, guess, T, case.args, fixed_period=True, rtol=tol, atol=tol
                    ).x0
                ),
                S["budget"],
                5,
            )
            _, tq = measure(
                lambda tol=tol, orbit=orbit: gj.floquet_multipliers(
                    case.scene, orbit, case.args, rtol=tol, atol=tol
                ),
                S["budget"],
                5,
            )
            mult = np.asarray(fl.multipliers).astype(complex).tolist()
            err = _match_error(mult, ref["multipliers"])
            rows.append(
                {
                    "tol": tol,
                    "time_min_s": tf["min_s"] + tq["min_s"],
                    "find_s": tf["min_s"],
                    "floquet_s": tq["min_s"],
                    "first_call_find_s": first_find,
                    "first_call_floquet_s": first_floquet,
                    "err_multipliers": err,
                    "err_x0": float(np.max(np.abs(np.asarray(orbit.x0) - np.asarray(ref["x0"])))),
                    "multipliers": [[z.real, z.imag] for z in mult],
                }
            )
            log(
                f"   tol {tol:.0e}: {1e3 * rows[-1]['time_min_s']:.1f} ms (first calls, compiling: "
                f"{first_find:.1f} + {first_floquet:.1f} s), multiplier error {err:.1e}"
            )
        res["floquet"] = {
            "rows": rows,
            "truth": {**ref, "multipliers": [[z.real, z.imag] for z in ref["multipliers"]]},
            "truth_method": "closed-form stroboscopic map in 40-digit mpmath: Newton for the "
            "fixed point, central differences for the monodromy",
            "peers": "none (SciPy and heyoka have no Floquet solver)",
        }
    except Exception as exc:  # noqa: BLE001
        res["floquet"] = {
            "error": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(),
        }
        log(f"   Floquet section failed: {exc}")
