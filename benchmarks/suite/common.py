"""The suite's settings per mode, its constants, and the small helpers every section shares:
number formatting for the tables, JSON/CSV writing, power-law fits."""

from __future__ import annotations

import csv
import math
from importlib import metadata

import _cases as C
import diffrax
import numpy as np

# The peers are optional (the `bench` extra): a missing one is skipped, with one line saying
# how to install it; grazejax's own rows always run.
HAVE_HEYOKA, HAVE_SCIPY = C.HAVE_HEYOKA, C.HAVE_SCIPY

SOLVERS = {
    "Tsit5": diffrax.Tsit5,
    "Dopri5": diffrax.Dopri5,
    "Dopri8": diffrax.Dopri8,
    "Kvaerno5": diffrax.Kvaerno5,
}
IMPLICIT = {"Kvaerno5"}
ERROR_LEVELS = [10.0**-k for k in range(3, 12)]  # the dominance check: 1e-3 … 1e-11
METRICS = {"err_t": "impact times", "err_post": "post-impact states", "err_final": "state at t1"}
HEADLINE_CASE = "ex1dof"


def settings(mode: str) -> dict:
    if mode == "smoke":  # the tests: one case, one solver, two tolerances (a few seconds)
        return {
            **settings("quick"),
            **dict(
                tols=[1e-4, 1e-8],
                cases=["exnonaxial"],
                solvers={"exnonaxial": ("Tsit5",)},
                scipy_methods={"exnonaxial": ("RK45",)},
                budget=0.05,
                max_rep=3,
                scipy_cap_s=5.0,
                sections=("work_precision",),
                batch_wp_lanes=0,
                count_explicit=False,
                truth_check=False,
                count_implicit=False,
            ),
        }
    quick = mode == "quick"
    return dict(
        tols=[10.0**-k for k in ((3, 5, 7, 9, 11, 13) if quick else range(3, 14))],
        cases=["exnonaxial", "oscillator", "ex1dof", "stiff"] + ([] if quick else ["ball"]),
        # quick: one compilation per (case, solver) is the main cost; keep the telling ones
        solvers={
            "exnonaxial": ("Tsit5",) if quick else ("Tsit5", "Dopri5", "Dopri8"),
            "oscillator": ("Dopri8",) if quick else ("Tsit5", "Dopri5", "Dopri8"),
            "ex1dof": ("Tsit5", "Dopri8") if quick else ("Tsit5", "Dopri5", "Dopri8"),
            "stiff": ("Kvaerno5",) if quick else ("Kvaerno5", "Tsit5"),
            "ball": ("Tsit5", "Dopri8"),
        },
        count_implicit=not quick,
        grazing_solvers=("Tsit5",) if quick else ("Tsit5", "Dopri8"),
        scipy_methods={"stiff": ("Radau", "LSODA")},
        # exnonaxial's late impacts are ~1e-4 deep (dips ~0.03 long): solve_ivp misses them
        # without a bound on its step; the full mode also runs it with max_step 0.01.
        scipy_max_step={} if quick else {"exnonaxial": 0.01},
        budget=0.1 if quick else 0.6,  # seconds of timed calls per point
        max_rep=20 if quick else 50,
        scipy_cap_s=3.0 if quick else 20.0,  # a slower single run stops that method's sweep
        sections=("work_precision", "grazing", "effects", "compile", "scaling", "floquet"),
        batch_wp_lanes=256 if quick else 1024,  # ex1dof: vmap'ed work-precision, per lane
        count_explicit=not quick,  # calibrate steps × stages against counted f calls
        truth_check=True,  # closed forms vs heyoka in long double
        grazing_depths=[10.0**-k for k in ((1, 3, 5, 7, 9, 11, 13) if quick else range(1, 15))],
        effects_lanes=64 if quick else 256,
        effects_full=not quick,
        scaling_impacts=[4, 16, 64, 256]
        if quick
        else [1, 2, 4, 8, 16, 32, 64, 128, 256, 512, 1024],
        scaling_scipy_max=64 if quick else 256,
        scaling_batch=[16, 64] if quick else [1, 4, 16, 64, 256, 1024, 4096],
        floquet_tols=[] if quick else [1e-4, 1e-6, 1e-8, 1e-10, 1e-12],  # ~30 s compile each
        continue_orbit=not quick,
    )


def finite_or_none(x):
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    return x


def sanitize(obj):
    """JSON-safe copy: numpy → Python, non-finite floats → null."""
    if isinstance(obj, dict):
        return {str(k): sanitize(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [sanitize(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return sanitize(obj.tolist())
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if isinstance(obj, (float, np.floating)):
        return finite_or_none(float(obj))
    return obj


def write_csv(path, rows, columns):
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow(["" if r.get(c) is None else r.get(c) for c in columns])


def stages_per_step(name: str) -> int | None:
    """Vector-field evaluations of one explicit Runge-Kutta step: stages, less one if FSAL."""
    if name in IMPLICIT:
        return None
    tab = SOLVERS[name]().tableau
    return len(tab.c) + 1 - int(bool(tab.fsal))


def fit_power(xs, ys):
    """Least-squares fit of log y = a + p log x; returns p and the prefactor e^a."""
    lx, ly = np.log(np.asarray(xs, float)), np.log(np.asarray(ys, float))
    p, a = np.polyfit(lx, ly, 1)
    return float(p), float(math.exp(a))


def fmt_e(x, digits=1):
    return "—" if x is None or not math.isfinite(x) else f"{x:.{digits}e}"


def fmt_ratio(x):
    if x is None or not math.isfinite(x):
        return "—"
    if 0.9 <= x <= 1.1:
        return f"{x:.3f}"
    return f"{x:.2g}" if x < 10 else f"{x:.0f}"


def fmt_ms(s):
    return "—" if s is None else (f"{1e3 * s:.3g}" if s >= 1e-4 else f"{1e3 * s:.2g}")


def extra_versions():
    out = C.versions()
    for name in ("mpmath", "matplotlib"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
