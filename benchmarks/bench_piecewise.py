"""Switching and sliding: the Coulomb friction oscillator, grazejax against SciPy.

x'' + x = −μ sign(x'), μ = 0.1, from (1, 0): it turns at t = π, 2π, 3π, 4π and sticks at
5π (closed form, `grazejax.examples.friction_oscillator_turns`). Error = the largest error
of the five event times; time = the median of repeated runs after one compilation.

- grazejax: `examples.friction_oscillator()` (a `PiecewiseScene`: two modes, the switching
  surface x' = 0, Filippov sliding), one `jax.jit`-compiled run per tolerance.
- SciPy: `solve_ivp` (DOP853) with a terminal event on x' = 0 per half cycle, restarted by
  hand in the other mode; sticking is decided at each event (|x| ≤ μ), as one would write
  it by hand.
- heyoka (if installed): one `taylor_adaptive` per tolerance with the friction's sign as a
  runtime parameter (`par[0]`) and two terminal events on x' (up- and down-crossings); the
  same restart loop flips `par[0]`, zeroes x' and stops at a stick. An event of the other
  direction at the restart point (x' = 0 there; heyoka reports a root at the start) is
  skipped. Compiled once per tolerance; each timed run resets time, state and parameter.

Usage: `python benchmarks/bench_piecewise.py [--out DIR] [--repeats N]`.
"""

import argparse
import importlib.util
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
HAVE_HEYOKA = importlib.util.find_spec("heyoka") is not None
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


def heyoka_integrator(tol):
    import heyoka as hy

    x, v = hy.make_vars("x", "v")
    events = [hy.t_event(v, direction=hy.event_direction.positive),  # in "backward" (v < 0)
              hy.t_event(v, direction=hy.event_direction.negative)]  # in "forward" (v > 0)
    return hy.taylor_adaptive([(x, v), (v, -x - hy.par[0] * hy.par[1])], [X0, 0.0], tol=tol,
                              pars=[-1.0, MU], t_events=events)


def heyoka_events(ta):
    import heyoka as hy

    ta.time, ta.state[:], ta.pars[0] = 0.0, [X0, 0.0], -1.0
    times = []
    while True:
        outcome, *_ = ta.propagate_until(T1)
        if outcome == hy.taylor_outcome.time_limit:
            break
        # Terminal event i stops with outcome -1 - i; the live one is the side's exit.
        if -1 - int(outcome) != (0 if ta.pars[0] < 0 else 1):
            continue  # the other direction's root at the restart point (x' = 0 there)
        times.append(ta.time)
        if abs(ta.state[0]) <= MU:  # both sides push into x' = 0: the mass sticks
            break
        ta.pars[0], ta.state[1] = -ta.pars[0], 0.0
    return np.array(times)


def _error(times, exact):
    return float(np.max(np.abs(times - exact))) if times.shape == exact.shape else math.inf


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
        row = {"tol": tol, "grazejax_error": error, "grazejax_seconds": seconds,
               "scipy_error": scipy_error, "scipy_seconds": scipy_seconds}
        line = (f"tol {tol:.0e}: grazejax error {error:.2e} in {seconds * 1e3:.2f} ms; "
                f"SciPy DOP853 error {scipy_error:.2e} in {scipy_seconds * 1e3:.2f} ms")
        if HAVE_HEYOKA:
            ta = heyoka_integrator(tol)
            row["heyoka_error"] = _error(heyoka_events(ta), exact)
            row["heyoka_seconds"] = median_time(lambda ta=ta: heyoka_events(ta),
                                                max(options.repeats, 20))
            line += f"; heyoka error {row['heyoka_error']:.2e} in {row['heyoka_seconds'] * 1e3:.3f} ms"
        rows.append(row)
        print(line)
    probe = probe_cost(options.repeats)
    options.out.mkdir(parents=True, exist_ok=True)
    (options.out / "piecewise.json").write_text(json.dumps({"work_precision": rows,
                                                            "field_probe_cost": probe}, indent=1))


def probe_cost(repeats):
    """The field-jump probe's cost (`simulate(check_field_jumps=...)`): the same compiled
    run with and without it, per event. Two event-heavy scenes: the friction oscillator
    above (5 events) and an elastic bouncing ball (200 impacts, a cheap field)."""
    ball = ex.bouncing_ball()
    cases = [("friction oscillator", ex.friction_oscillator().scene,
              ex.friction_oscillator().state([X0, 0.0], "backward"), T1, {"mu": MU}, {}),
             ("elastic ball, 200 impacts", ball, np.array([1.0, 0.0]), math.inf,
              {"g": 9.81, "e": 1.0}, {"max_impacts": 200})]
    out = []
    for name, scene, y0, t1, args, extra in cases:
        runs = {}
        for check in (True, False):
            runs[check] = jax.jit(lambda y, check=check, scene=scene, t1=t1, args=args, extra=extra:
                                  gj.simulate(scene, y, 0.0, t1, args, rtol=1e-10, atol=1e-10,
                                              direction=1, check_field_jumps=check, **extra))
            events = int(runs[check](y0).num_impacts)
        # Interleaved, the minimum of many: the difference is a few percent on a shared CPU.
        samples = {True: [], False: []}
        for _ in range(20 * max(repeats, 5)):
            for check in (True, False):
                start = time.perf_counter()
                runs[check](y0).t_final.block_until_ready()
                samples[check].append(time.perf_counter() - start)
        seconds = {check: float(np.min(v)) for check, v in samples.items()}
        per_event = (seconds[True] - seconds[False]) / max(events, 1)
        out.append({"case": name, "events": events, "seconds_with_probe": seconds[True],
                    "seconds_without_probe": seconds[False], "seconds_per_event": per_event})
        print(f"field probe, {name}: {seconds[True] * 1e3:.3f} ms with, "
              f"{seconds[False] * 1e3:.3f} ms without ({events} events: "
              f"{per_event * 1e6:+.2f} µs per event)")
    return out


if __name__ == "__main__":
    main()
