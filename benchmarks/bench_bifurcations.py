"""Bifurcation points: what a point's derivative costs against locating it, and what a
point of a two-parameter curve costs against a point of a one-parameter branch.

    python benchmarks/bench_bifurcations.py [--quick] [--out DIR]   (default DIR: bench-output/)

Writes DIR/bifurcations.json (every number, with machine info) and DIR/bifurcations.md.

The ball on a vibrating table (`examples.vibrating_table`, e = 0.5, rtol = 1e-11, atol =
1e-13, Tsit5), whose period-doubling point Γ_PD(e) = √(c² + (1 + r²)²) is known in closed
form (r = (1 − e)/(1 + e), c = πr):

- `jax.jit` of Γ_PD(e) by `locate_bifurcation`, of its `jax.jacfwd` (default adjoint), and
  of its `jax.grad` (`adjoint=diffrax.DirectAdjoint()`): first call (compile + run) and min
  of repeats after; target for the derivative: ≤ 3× the locate;
- `continue_bifurcation` of that point from e = 0.5 to 0.9 against `continue_orbit` of the
  period-1 family from Γ = 1.3 to 1.6 (at e = 0.5), per point, each after a first call that
  compiled it.

One process, one thing at a time; read ratios on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from types import SimpleNamespace

import diffrax
import jax
import numpy as np
from bench_orbits import machine, timed

import grazejax as gj
from grazejax import examples as ex

TABLE = ex.vibrating_table()
G, OMEGA, E = 9.81, 2 * math.pi, 0.5
TOL = dict(rtol=1e-11, atol=1e-13)


def args_of(gamma, e):
    return dict(g=G, e=e, A=gamma * G / OMEGA**2, omega=OMEGA)


def closed_form(e):
    r = (1 - e) / (1 + e)
    return math.sqrt((math.pi * r) ** 2 + (1 + r * r) ** 2)


def apex_guess(kind, gamma, e):
    phi = math.acos(math.pi * (1 - e) / (1 + e) / gamma)
    return SimpleNamespace(kind=kind, mu=gamma, period=1.0, t0=phi / OMEGA + 0.5,
                           x0=[args_of(gamma, e)["A"] * math.sin(phi) + G / 8, 0.0])


def point_and_derivatives(repeats):
    guess = apex_guess("period-doubling", closed_form(E) - 0.01, E)

    def mu(e, adjoint=None):
        return gj.locate_bifurcation(TABLE, guess, args_of, e, adjoint=adjoint, **TOL).mu

    e = np.float64(E)
    programs = {
        "locate": jax.jit(mu),
        "jacfwd": jax.jit(jax.jacfwd(mu)),
        "grad (DirectAdjoint)": jax.jit(jax.grad(lambda e: mu(e, diffrax.DirectAdjoint()))),
    }
    out = {}
    for name, program in programs.items():
        value, t = timed(lambda program=program: program(e), repeats)
        t["value"] = float(value)
        out[name] = t
        print(f"{name}: {float(value):.16g}, first call {t['first_call_s']:.1f} s, "
              f"then min {t['min_s'] * 1e3:.2f} ms")
    out["closed_form"] = closed_form(E)
    for name in ("jacfwd", "grad (DirectAdjoint)"):
        out[f"{name} / locate"] = out[name]["min_s"] / out["locate"]["min_s"]
    return out


def curves_per_point(repeats):
    guess = apex_guess("period-doubling", closed_form(E) + 0.003, E)

    def curve():
        return gj.continue_bifurcation(TABLE, guess, args_of, guess.mu, E, 0.9, progress=False,
                                       ds=0.05, ds_max=0.2, **TOL)

    t0, x0 = apex_guess("fold", 1.3, E).t0, apex_guess("fold", 1.3, E).x0
    orbit = gj.find_periodic_orbit(TABLE, x0, 1.0, args_of(1.3, E), t0=t0, fixed_period=True,
                                   start_at_impact=False, num_impacts=1, **TOL)

    def at_e(gamma):  # one function object: the branch's programs are compiled once
        return args_of(gamma, E)

    def branch():
        return gj.continue_orbit(TABLE, orbit, at_e, 1.3, 1.6, progress=False, **TOL)

    out = {}
    for name, fn in (("continue_bifurcation (e 0.5 → 0.9)", curve),
                     ("continue_orbit (Γ 1.3 → 1.6)", branch)):
        result, t = timed(fn, repeats)
        t.update(points=len(result), status=result.message,
                 per_point_ms=1e3 * t["min_s"] / max(len(result), 1))
        out[name] = t
        print(f"{name}: {len(result)} points, first call {t['first_call_s']:.1f} s, then "
              f"{t['min_s']:.2f} s ({t['per_point_ms']:.1f} ms/point)")
    names = list(out)
    out["curve / branch per point"] = out[names[0]]["per_point_ms"] / out[names[1]]["per_point_ms"]
    return out


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer repeats")
    parser.add_argument("--out", default="bench-output")
    opts = parser.parse_args()
    repeats = 2 if opts.quick else 7
    os.makedirs(opts.out, exist_ok=True)
    wall = time.perf_counter()
    res = {"machine": machine(), "tolerances": TOL, "point": point_and_derivatives(repeats),
           "curves": curves_per_point(1 if opts.quick else 3)}
    res["total_wall_s"] = time.perf_counter() - wall
    with open(os.path.join(opts.out, "bifurcations.json"), "w") as fh:
        json.dump(res, fh, indent=1, default=float)
    point, curves = res["point"], res["curves"]
    lines = [
        "# Bifurcation points: timings", "",
        f"Machine: {res['machine']['platform']}, {res['machine']['cpus']} CPUs; load average "
        f"{res['machine'].get('load_average')}. Vibrating table, e = 0.5, rtol = 1e-11.", "",
        "| program (jit) | value | first call (s) | after: min (ms) | / locate |",
        "|---|---:|---:|---:|---:|",
    ]
    for name in ("locate", "jacfwd", "grad (DirectAdjoint)"):
        t = point[name]
        ratio = 1.0 if name == "locate" else point[f"{name} / locate"]
        lines.append(f"| {name} | {t['value']:.16g} | {t['first_call_s']:.1f} | "
                     f"{t['min_s'] * 1e3:.2f} | {ratio:.2f}× |")
    lines += ["", f"Closed form Γ_PD(0.5) = {point['closed_form']:.16g}.", "",
              "| continuation | points | first call (s) | after (s) | ms per point |",
              "|---|---:|---:|---:|---:|"]
    for name, t in curves.items():
        if isinstance(t, dict):
            lines.append(f"| {name} | {t['points']} | {t['first_call_s']:.1f} | "
                         f"{t['min_s']:.2f} | {t['per_point_ms']:.1f} |")
    lines.append(f"\nA curve point costs {curves['curve / branch per point']:.2f}× a branch point.")
    with open(os.path.join(opts.out, "bifurcations.md"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    print(f"total {res['total_wall_s']:.0f} s")


if __name__ == "__main__":
    main()
