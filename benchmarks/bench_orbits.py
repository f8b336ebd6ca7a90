"""Periodic orbits: solve time, continuation time, compile times.

    python benchmarks/bench_orbits.py [--quick] [--out DIR]      (default DIR: bench-output/)

Writes DIR/orbits.json (every number, with machine info) and DIR/orbits.md (tables).
Goals (issue 4): a periodic-orbit solve after compilation under 1 s; a 100-point
continuation under 60 s.

Problems (all at rtol = 1e-10, atol = 1e-12, Tsit5):

- ex1dof, μ = −0.2: the continuous cycle Ψ_μ (weakly attracting: multiplier 0.9996), from
  a guess 1% off in amplitude and 1.5% in period;
- ex1dof, μ = 0.2: the impacting cycle started at its impact (the paper's phase, x1 = 0);
- the forced impact oscillator (ω = 0.5, σ = 1.2): the period-1 orbit with one impact,
  period fixed (2π/ω);
- `floquet_multipliers` on the impacting cycle (per-impact factors, determinant identity);
- continuation of ex1dof from μ = −0.3 towards 0.3 through the grazing bifurcation at
  μ = 0, stopped at 100 points (ds = ds_max = 0.007, about 0.005 in μ per step).

Each solve is timed from its first call (compile + run) and then as the min and median
of repeats after compilation, with `jax.block_until_ready`. One process, one thing at a
time; read ratios on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from importlib import metadata

import jax
import numpy as np

import grazejax as gj  # noqa: F401  (turns float64 on)
from grazejax import examples as ex
from grazejax._orbits.continuation import continue_orbit
from grazejax._orbits.floquet import floquet_multipliers
from grazejax._orbits.periodic import find_periodic_orbit

TOL = dict(rtol=1e-10, atol=1e-12)


def timed(fn, repeats):
    start = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - start
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - start)
    return out, {"first_call_s": first, "min_s": min(times), "median_s": float(np.median(times)),
                 "repeats": repeats}


def machine():
    info = {"python": platform.python_version(), "platform": platform.platform(),
            "processor": platform.processor(), "cpus": os.cpu_count(),
            "jax_backend": jax.default_backend(), "devices": [str(d) for d in jax.devices()]}
    for pkg in ("jax", "jaxlib", "diffrax", "optimistix", "equinox"):
        try:
            info[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    try:
        info["load_average"] = os.getloadavg()
    except OSError:
        pass
    return info


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    parser.add_argument("--out", default="bench-output")
    opts = parser.parse_args()
    repeats = 3 if opts.quick else 10
    os.makedirs(opts.out, exist_ok=True)
    res = {"machine": machine(), "tolerances": TOL, "solves": {}}
    wall = time.perf_counter()

    ex1dof = ex.ex1dof()
    cases = {
        "ex1dof continuous cycle (μ = −0.2)": lambda: find_periodic_orbit(
            ex1dof, [1.78, 0.0], 6.19, ex.ex1dof_args(-0.2), fix=1, start_at_impact=False, **TOL),
        "ex1dof impacting cycle from its impact (μ = 0.2)": lambda: find_periodic_orbit(
            ex1dof, [0.0, 0.04], 6.2, ex.ex1dof_args(0.2), start_at_impact=True, num_impacts=1,
            **TOL),
    }
    osc = ex.impact_oscillator()
    osc_args = ex.impact_oscillator_args(zeta=0.05, A=1.0, omega=0.5, sigma=1.2, r=0.8)
    cases["impact oscillator period-1 orbit (fixed period)"] = lambda: find_periodic_orbit(
        osc, [1.08, -0.2], 4 * np.pi, osc_args, fixed_period=True, **TOL)
    orbits = {}
    for name, fn in cases.items():
        orbit, t = timed(fn, repeats)
        orbits[name] = orbit
        t.update(status=orbit.message, newton_steps=int(orbit.num_steps),
                 period=float(orbit.period), residual=float(orbit.residual),
                 multipliers=[str(complex(z)) for z in np.asarray(orbit.multipliers)])
        res["solves"][name] = t
        print(f"{name}: first call {t['first_call_s']:.2f} s, then min {t['min_s'] * 1e3:.2f} ms")

    impacting = orbits["ex1dof impacting cycle from its impact (μ = 0.2)"]
    floquet, t = timed(lambda: floquet_multipliers(ex1dof, impacting, ex.ex1dof_args(0.2), **TOL),
                       repeats)
    t.update(determinant_error=float(floquet.determinant_error),
             multipliers=[str(complex(z)) for z in np.asarray(floquet.multipliers)])
    res["floquet"] = t
    print(f"floquet_multipliers: first call {t['first_call_s']:.2f} s, then min {t['min_s'] * 1e3:.1f} ms")

    start = find_periodic_orbit(ex1dof, [1.7, 0.0], 6.28, ex.ex1dof_args(-0.3), fix=1,
                                start_at_impact=False, **TOL)

    def continuation():
        return continue_orbit(ex1dof, start, ex.ex1dof_args, -0.3, 0.3, ds=0.007, ds_max=0.007,
                              max_points=100, progress=False, **TOL)

    branch, t = timed(continuation, 1 if opts.quick else 2)
    t.update(points=len(branch), status=branch.message, mu_last=float(branch.mu[-1]),
             impacts_last=int(branch.num_impacts[-1]),
             grazing_mu=[g.mu for g in branch.grazing])
    t["per_point_ms"] = 1e3 * t["min_s"] / max(len(branch), 1)
    res["continuation_100_points"] = t
    print(f"continuation: {len(branch)} points, first call {t['first_call_s']:.1f} s, "
          f"then {t['min_s']:.2f} s ({t['per_point_ms']:.1f} ms/point)")

    res["total_wall_s"] = time.perf_counter() - wall
    with open(os.path.join(opts.out, "orbits.json"), "w") as fh:
        json.dump(res, fh, indent=1, default=float)
    lines = [
        "# Periodic orbits: timings", "",
        f"Machine: {res['machine']['platform']}, {res['machine']['cpus']} CPUs, JAX "
        f"{res['machine'].get('jax')} on {res['machine']['jax_backend']}; load average "
        f"{res['machine'].get('load_average')}. Tolerances rtol = 1e-10, atol = 1e-12.", "",
        "| task | first call (compile + run) | after compilation: min | median | Newton steps |",
        "|---|---|---|---|---|",
    ]
    for name, t in res["solves"].items():
        lines.append(f"| `find_periodic_orbit`: {name} | {t['first_call_s']:.2f} s | "
                     f"{t['min_s'] * 1e3:.2f} ms | {t['median_s'] * 1e3:.2f} ms | {t['newton_steps']} |")
    t = res["floquet"]
    lines.append(f"| `floquet_multipliers` (impacting cycle) | {t['first_call_s']:.2f} s | "
                 f"{t['min_s'] * 1e3:.1f} ms | {t['median_s'] * 1e3:.1f} ms | |")
    t = res["continuation_100_points"]
    lines.append(f"| `continue_orbit`: ex1dof from μ = −0.3 to {t['mu_last']:.3g}, {t['points']} "
                 f"points, grazing at μ = {t['grazing_mu'][0]:.2g} | {t['first_call_s']:.1f} s | "
                 f"{t['min_s']:.2f} s | {t['median_s']:.2f} s | |")
    lines += ["", "Goals: a solve after compilation < 1 s; a 100-point continuation < 60 s.", ""]
    with open(os.path.join(opts.out, "orbits.md"), "w") as fh:
        fh.write("\n".join(lines))
    print("\n".join(lines))
    print(f"wrote {opts.out}/orbits.json, {opts.out}/orbits.md in {res['total_wall_s']:.0f} s")


if __name__ == "__main__":
    main()
