"""Switching and sliding: the Coulomb friction oscillator, grazejax against SciPy.

x'' + x = −μ sign(x'), μ = 0.1, from (1, 0): it turns at t = π, 2π, 3π, 4π and sticks at
5π (closed form, `grazejax.examples.friction_oscillator_turns`). Error = the largest error
of the five event times; time = the median of repeated runs after one compilation.

- grazejax: `examples.friction_oscillator()` (a `PiecewiseScene`: two modes, the switching
  surface x' = 0, Filippov sliding), one `jax.jit`-compiled run per tolerance.
- SciPy: `solve_ivp` (DOP853) with a terminal event on x' = 0 per half cycle, restarted by
  hand in the other mode; sticking is decided at each event (|x| ≤ μ), as one would write
  it by hand. heyoka could express the same with its terminal events and a restart loop;
  it is not run here.

Usage: `python benchmarks/bench_piecewise.py [--out DIR] [--repeats N]`.
"""

import argparse
import json
import math
import time
from pathlib import Path

import jax
import numpy as np
from scipy.integrate import solve_ivp

import grazejax as gj
from grazejax import examples as ex

MU, X0, T1 = 0.1, 1.0, 20.0
TOLERANCES = [1e-4, 1e-6, 1e-8, 1e-10, 1e-12]


def scipy_events(tol):
    t, x, v, sign, times = 0.0, X0, 0.0, -1.0, []
    while t < T1:
        event = lambda s, y: y[1]  # noqa: E731
        event.terminal, event.direction = True, -sign  # leave the side v·sign > 0
        sol = solve_ivp(lambda s, y, sg=sign: [y[1], -y[0] - sg * MU], (t, T1), [x, v],
                        method="DOP853", rtol=tol, atol=tol, events=event)
        if not sol.t_events[0].size:
            break
        t, (x, v) = sol.t_events[0][0], sol.y_events[0][0]
        times.append(t)
        if abs(x) <= MU:  # both sides push into x' = 0: the mass sticks for good
            break
        sign, v = -sign, 0.0
    return np.array(times)


def median_time(fn, repeats):
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - start)
    return float(np.median(samples))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("bench-piecewise"))
    parser.add_argument("--repeats", type=int, default=5)
    options = parser.parse_args()
    exact, _ = ex.friction_oscillator_turns(X0, MU)
    pw = ex.friction_oscillator()
    y0 = pw.state([X0, 0.0], "backward")
    rows = []
    for tol in TOLERANCES:
        run = jax.jit(lambda y, tol=tol: gj.simulate(pw.scene, y, 0.0, T1, {"mu": MU},
                                                     rtol=tol, atol=tol))
        sol = run(y0)
        got = np.array([e.time for e in pw.events(sol)])
        error = float(np.max(np.abs(got - exact))) if got.shape == exact.shape else math.inf
        seconds = median_time(lambda run=run: run(y0).t_final.block_until_ready(),
                              options.repeats)
        reference = scipy_events(tol)
        scipy_error = (float(np.max(np.abs(reference - exact)))
                       if reference.shape == exact.shape else math.inf)
        scipy_seconds = median_time(lambda tol=tol: scipy_events(tol), options.repeats)
        rows.append({"tol": tol, "grazejax_error": error, "grazejax_seconds": seconds,
                     "scipy_error": scipy_error, "scipy_seconds": scipy_seconds})
        print(f"tol {tol:.0e}: grazejax error {error:.2e} in {seconds * 1e3:.2f} ms; "
              f"SciPy DOP853 error {scipy_error:.2e} in {scipy_seconds * 1e3:.2f} ms")
    options.out.mkdir(parents=True, exist_ok=True)
    (options.out / "piecewise.json").write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
