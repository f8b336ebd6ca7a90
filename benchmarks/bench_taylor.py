"""A Taylor method in JAX, measured: is it a way to single runs near heyoka's?

    python benchmarks/bench_taylor.py [--quick | --smoke] [--out DIR]   (default DIR: results/)

Issue 43 asks for one run within 5× heyoka's scalar loop, and names a Taylor method built on
`jax.experimental.jet` as worth a measured try. This script measures the flight alone (no
surface: the solvers, not the impact loop), one trajectory of ex1dof's field at μ = 0.2
from the impacting cycle's post-impact state (0, 0.0384224) over t ∈ [0, 62] (ten periods),
one process, one thing at a time, interleaved rounds, min wall time per run:

- `heyoka`: `taylor_adaptive` (scalar, double), `propagate_until`, at `tol`;
- `jet`: a Taylor method for any field, written with `jax.experimental.jet`: the solution's
  coefficients by p − 1 nested `jet` calls of growing order (the recursion x' = f(x)), the
  order and step size of Jorba & Zou (p = ⌈−ln(tol)/2⌉ + 1, h from the last two
  coefficients, as heyoka chooses them), one `lax.while_loop` over the steps;
- Diffrax's `diffeqsolve` with Tsit5, Dopri8 and grazejax's Vern9 and a PID controller at
  rtol = atol = `tol`, no events (the floor of grazejax's flights);
- `grazejax`: `simulate` of a scene without surfaces with Dopri8 and Vern9: the impact
  loop's own cost over Diffrax's solve, with nothing to detect.

The error is the max-norm distance of x(62) from heyoka's in 80-bit long double at tol
1e-19. Compile time is the first call's wall time minus a later call's. Writes
DIR/taylor.json and DIR/taylor.md. `--quick`: tol 1e-10 only; `--smoke` (the tests): tol
1e-8, heyoka, `jet` and Dopri8 only, one round.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_x64", True)

import diffrax  # noqa: E402
from jax.experimental.jet import jet  # noqa: E402
from peers import SYSTEMS  # noqa: E402

import grazejax as gj  # noqa: E402
from grazejax import examples  # noqa: E402

PARAMS = {"mu": 0.2, "eps": 1e-4}
X0 = (0.0, 0.0384224)
T1 = 62.0
_EX1DOF_FIELD = examples.ex1dof().vector_field


def field(x):
    """ex1dof's vector field (`grazejax.examples.ex1dof`) at μ = 0.2, ε = 1e-4."""
    return _EX1DOF_FIELD(0.0, x, PARAMS)


def order_for(tol: float) -> int:
    """Jorba & Zou's order for a tolerance (heyoka's choice)."""
    return int(math.ceil(-math.log(tol) / 2 + 1))


def jet_coefficients(x0, p):
    """The solution's normalised Taylor coefficients c_0..c_p at x0, by nested `jet`s."""
    derivatives = [field(x0)]  # x^(1), x^(2), ...: jet's series are derivatives
    for _ in range(1, p):
        _, series = jet(field, (x0,), (tuple(derivatives),))
        derivatives = [derivatives[0], *series]
    coefficients, factorial = [x0], 1.0
    for k, d in enumerate(derivatives, start=1):
        factorial *= k
        coefficients.append(d / factorial)
    return jnp.stack(coefficients)


def taylor_run(coefficients, tol):
    p = order_for(tol)
    safety = math.exp(-0.7 / (p - 1)) / math.e**2

    def body(carry):
        t, x, steps = carry
        c = coefficients(x, p)
        scale = jnp.maximum(1.0, jnp.max(jnp.abs(x)))
        rho = jnp.minimum((scale / jnp.max(jnp.abs(c[p - 1]))) ** (1.0 / (p - 1)),
                          (scale / jnp.max(jnp.abs(c[p]))) ** (1.0 / p))
        h = jnp.minimum(safety * rho, T1 - t)
        return t + h, (h ** jnp.arange(p + 1)) @ c, steps + 1

    def run(x0):
        _, x, steps = jax.lax.while_loop(lambda c: c[0] < T1, body, (0.0, x0, 0))
        return x, steps

    return jax.jit(run)


def diffrax_run(solver, tol):
    def run(x0):
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(lambda t, x, a: field(x)), solver, 0.0, T1, None, x0,
            stepsize_controller=diffrax.PIDController(rtol=tol, atol=tol), max_steps=None,
            saveat=diffrax.SaveAt(t1=True),
        )
        return sol.ys[-1], sol.stats["num_accepted_steps"]

    return jax.jit(run)


def grazejax_run(solver, tol):
    scene = gj.Scene(lambda t, x, a: field(x), [])

    def run(x0):
        sol = gj.simulate(scene, x0, 0.0, T1, None, solver=solver, rtol=tol, atol=tol, max_steps=10**6)
        return sol.x_final, sol.num_steps

    return jax.jit(run)


def heyoka_run(tol, fp_type=float):
    import heyoka as hy

    x1, x2 = hy.make_vars("x1", "x2")
    rhs = SYSTEMS["ex1dof"].rhs(hy.time, [x1, x2], PARAMS, None)
    ta = hy.taylor_adaptive(list(zip((x1, x2), rhs, strict=True)), [fp_type(0.0)] * 2, tol=fp_type(tol), fp_type=fp_type)

    def run(x0):
        ta.time = fp_type(0.0)
        ta.state[:] = np.asarray(x0, dtype=fp_type)
        steps = ta.propagate_until(fp_type(T1))[3]
        return np.asarray(ta.state, dtype=np.float64), steps

    return run


def measure(runs: dict, x0, repeats: int) -> dict:
    """Each run's end state, steps, min wall time per call and compile time.

    Interleaved rounds, as `_cases.time_interleaved`, but each sample is ~2 ms of calls in a
    row: one call of heyoka's scalar loop right after a JAX program's took 2–3× its time in
    a row (caches, branch predictors), so that single calls would not time it at its best.
    """
    first, out = {}, {}
    for name, run in runs.items():
        t = time.perf_counter()
        out[name] = jax.block_until_ready(run(x0))
        first[name] = time.perf_counter() - t
    calls = {}
    for name, run in runs.items():
        t = time.perf_counter()
        jax.block_until_ready(run(x0))
        calls[name] = max(1, int(2e-3 / max(time.perf_counter() - t, 1e-6)))
    best = dict.fromkeys(runs, math.inf)
    for _ in range(repeats):
        for name, run in runs.items():
            t = time.perf_counter()
            for _ in range(calls[name]):
                jax.block_until_ready(run(x0))
            best[name] = min(best[name], (time.perf_counter() - t) / calls[name])
    return {name: {"x": np.asarray(out[name][0]), "steps": int(out[name][1]),
                   "run_s": best[name], "compile_s": first[name] - best[name]} for name in runs}


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="tolerance 1e-10 only, fewer rounds")
    parser.add_argument("--smoke", action="store_true", help="tolerance 1e-8, three methods, one round")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results"))
    opts = parser.parse_args(argv)
    tols = (1e-8,) if opts.smoke else (1e-10,) if opts.quick else (1e-8, 1e-10, 1e-12)
    repeats = 1 if opts.smoke else 3 if opts.quick else 8
    x0 = jnp.array(X0)
    truth = heyoka_run(1e-19, np.longdouble)(X0)[0]
    rows = []
    for tol in tols:
        runs = {
            "heyoka": heyoka_run(tol),
            "jet": taylor_run(jet_coefficients, tol),
            "Tsit5": diffrax_run(diffrax.Tsit5(), tol),
            "Dopri8": diffrax_run(diffrax.Dopri8(), tol),
            "Vern9": diffrax_run(gj.Vern9(), tol),
            "grazejax Dopri8": grazejax_run(diffrax.Dopri8(), tol),
            "grazejax Vern9": grazejax_run(gj.Vern9(), tol),
        }
        if opts.smoke:
            runs = {name: runs[name] for name in ("heyoka", "jet", "Dopri8")}
        results = measure(runs, x0, repeats)
        base = results["heyoka"]["run_s"]
        for name, r in results.items():
            rows.append({
                "tol": tol, "method": name, "order": order_for(tol) if name in ("heyoka", "jet") else None,
                "steps": r["steps"], "error": float(np.max(np.abs(r["x"] - truth))),
                "run_us": r["run_s"] * 1e6, "us_per_step": r["run_s"] * 1e6 / r["steps"],
                "vs_heyoka": r["run_s"] / base, "compile_s": r["compile_s"] if name != "heyoka" else None,
            })
            print(f"tol {tol:.0e} {name:>10}: {r['steps']:4d} steps, error {rows[-1]['error']:.1e}, "
                  f"{rows[-1]['run_us']:8.1f} µs ({rows[-1]['us_per_step']:.2f} µs/step, "
                  f"{rows[-1]['vs_heyoka']:.1f}× heyoka)", flush=True)
    out = Path(opts.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "taylor.json").write_text(json.dumps({"rows": rows, "jax": jax.__version__,
                                                 "diffrax": diffrax.__version__}, indent=1))
    lines = ["ex1dof's flight (μ = 0.2, no surface) over [0, 62], one trajectory, one process,",
             "interleaved, min wall time per run (`benchmarks/bench_taylor.py`):", "",
             "| tol | method | order | steps | error at t = 62 | µs per run | µs per step | × heyoka | compile (s) |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        compile_s = "—" if r["compile_s"] is None else f"{r['compile_s']:.2f}"
        lines.append(f"| {r['tol']:.0e} | {r['method']} | {r['order'] or '—'} | {r['steps']} | {r['error']:.1e} | "
                     f"{r['run_us']:.1f} | {r['us_per_step']:.2f} | {r['vs_heyoka']:.1f} | {compile_s} |")
    (out / "taylor.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return rows


if __name__ == "__main__":
    main()
