"""Section 4, compile times of the public entry points (first call minus second call)."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np
from _cases import first_minus_second, log

import grazejax as gj

from .floquet import periodic_guess


def section_compile(cases, S, res, effects_rows):
    log("4) compile times of the public entry points (first call minus second call)")
    rows = _rows_measured_before(effects_rows, res)
    osc = cases["oscillator"]
    # Fresh scene objects: no cache can serve them.
    from grazejax import examples

    # Each entry point gets its own new scene object (built once, outside the timed calls),
    # so that no cache can serve the first call and the second call is a cache hit.
    x0s = np.random.default_rng(0).uniform(-0.3, 0.1, (16, 2))
    sc_sweep = examples.impact_oscillator()
    _timed_first_second(
        rows,
        "grazejax.sweep (16 lanes, oscillator)",
        lambda: (
            gj.sweep(
                sc_sweep,
                x0s,
                0.0,
                50.0,
                osc.args,
                rtol=1e-8,
                atol=1e-8,
                max_impacts=32,
                progress=False,
            ).x_final
        ),
    )
    if hasattr(gj, "flow_jacobian"):
        sc_fj = examples.impact_oscillator()
        _timed_first_second(
            rows,
            "grazejax.flow_jacobian (oscillator)",
            lambda: (
                gj.flow_jacobian(
                    sc_fj,
                    jnp.asarray(osc.x0),
                    0.0,
                    50.0,
                    osc.args,
                    rtol=1e-8,
                    atol=1e-8,
                    max_impacts=32,
                ).jacobian
            ),
        )
    else:
        rows.append(
            {"entry": "grazejax.flow_jacobian", "skipped": "not in grazejax (hasattr false)"}
        )
    _orbit_rows(rows, S, osc)
    res["compile"] = {
        "rows": rows,
        "goal_s": 5.0,
        "method": "time of the first call of a jitted function minus that of the second "
        "(a warm process: JAX's one-time start-up costs are already paid)",
    }
    return rows


def _rows_measured_before(effects_rows, res):
    """Compile times the effects and work-precision sections have already measured."""
    rows = []
    if effects_rows:
        for label, key in (
            (
                "simulate, final state only (exnonaxial, Tsit5, effects base)",
                "base: final state only",
            ),
            ("jax.jacfwd(simulate) (exnonaxial)", "+ Jacobian (jax.jacfwd"),
            ("simulate with saveat (exnonaxial)", "+ dense trajectory"),
        ):
            r = next((r for r in effects_rows if r["effect"].startswith(key)), None)
            if r is not None:
                rows.append(
                    {
                        "entry": label,
                        "compile_s": r["lower_s"] + r["compile_s"],
                        "trace_lower_s": r["lower_s"],
                        "xla_compile_s": r["compile_s"],
                    }
                )
        vm = next(r for r in effects_rows if r["effect"].startswith("+ batch"))
        rows.append(
            {
                "entry": f"jax.vmap(simulate) × {vm['lanes']} (exnonaxial)",
                "compile_s": vm["compile_s"],
            }
        )
    wp = res.get("work_precision", {}).get("cases", {})
    for name, ci in wp.items():
        for s, v in ci.get("compile_s", {}).items():
            rows.append({"entry": f"simulate (jax.jit, {name}, {s})", "compile_s": v})
    return rows


def _timed_first_second(rows, label, fn):
    """Appends fn's compile time (first call minus second call), or the error it raised."""
    try:
        c = first_minus_second(fn)
        rows.append({"entry": label, **c})
        log(f"   {label}: {c['compile_s']:.2f} s")
    except Exception as exc:  # noqa: BLE001
        rows.append({"entry": label, "error": f"{type(exc).__name__}: {exc}"})
        log(f"   {label}: ERROR {exc}")


def _orbit_rows(rows, S, osc):
    """find_periodic_orbit and continue_orbit (full mode only), or why they were skipped."""
    from grazejax import examples

    if hasattr(gj, "find_periodic_orbit") and not S["continue_orbit"]:
        rows.append({"entry": "grazejax.find_periodic_orbit", "skipped": "full mode only (~30 s)"})
        rows.append({"entry": "grazejax.continue_orbit", "skipped": "full mode only"})
    elif hasattr(gj, "find_periodic_orbit"):
        T = 2 * math.pi / float(osc.args["omega"])
        guess = periodic_guess()
        sc_po = examples.impact_oscillator()
        _timed_first_second(
            rows,
            "grazejax.find_periodic_orbit (oscillator, fixed period)",
            lambda: gj.find_periodic_orbit(sc_po, guess, T, osc.args, fixed_period=True).x0,
        )
        if hasattr(gj, "continue_orbit") and S["continue_orbit"]:
            sc_co = examples.ex1dof()
            orbit = gj.find_periodic_orbit(
                sc_co, [1.7, 0.0], 6.28, examples.ex1dof_args(-0.3), fix=1
            )
            _timed_first_second(
                rows,
                "grazejax.continue_orbit (ex1dof, μ −0.3 → −0.25, 3 points)",
                lambda: gj.continue_orbit(
                    sc_co, orbit, examples.ex1dof_args, -0.3, -0.25, max_points=3, progress=False
                ),
            )
        elif not hasattr(gj, "continue_orbit"):
            rows.append(
                {"entry": "grazejax.continue_orbit", "skipped": "not in grazejax (hasattr false)"}
            )
        else:
            rows.append({"entry": "grazejax.continue_orbit", "skipped": "full mode only"})
    else:
        rows.append(
            {"entry": "grazejax.find_periodic_orbit", "skipped": "not in grazejax (hasattr false)"}
        )
        rows.append(
            {"entry": "grazejax.continue_orbit", "skipped": "not in grazejax (hasattr false)"}
        )
