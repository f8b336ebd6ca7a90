"""The in-step root searches: iterations per call and sweep throughput, by method.

    python benchmarks/bench_roots.py [--lanes N] [--repeats R] [--out DIR]

Compares Chandrupatla's search (the default) with ITP and the safeguarded Newton search
(`simulate(..., event_root_finder=...)`), side by side in one process:

1. Iterations per call (`bracketed_root(count=True)`, recorded by a host callback in
   single, un-batched runs; calls on an empty bracket are not counted): a transversal
   case (exnonaxial, a rotation meeting a line), a near-grazing case (ex1dof at μ = 0.2,
   where every impact nearly grazes) and a Zeno sequence (a bouncing ball, e = 0.8, run
   until ZENO).
2. µs per trajectory of `bench_phases`' sweep (ex1dof μ = 0.2, 10 impacts, Dopri8) for
   lanes in phase and at random phases, at three tolerances (repeats interleaved), with
   the worst impact-time difference of each method from the default's run (the accuracy
   against a long-double reference is `bench_throughput`'s: not here, to stay quick).

Writes DIR/roots.md (default benchmarks/results).
"""

import argparse
import os
import sys

import numpy as np

METHODS = ("chandrupatla", "itp", "newton")
LABELS = {"chandrupatla": "Chandrupatla", "itp": "ITP", "newton": "Newton"}


def finder(method):
    """grazejax's root finder for `method` (`simulate(..., event_root_finder=...)`)."""
    import grazejax as gj

    return {"chandrupatla": gj.Chandrupatla, "itp": gj.ITP, "newton": gj.BracketedNewton}[method]()


def iteration_counts(method):
    import jax
    import jax.numpy as jnp

    import grazejax as gj
    import grazejax._loop.events as events
    from grazejax import _roots
    from grazejax import examples as ex

    calls = []
    original = _roots.bracketed_root

    def recording(fn, lo, hi, f_lo, f_hi, **kw):
        lo_, hi_, it = original(fn, lo, hi, f_lo, f_hi, count=True, **kw)
        jax.debug.callback(lambda n: calls.append(int(n)) if n > 0 else None, it)
        return lo_, hi_

    cases = {
        "transversal (exnonaxial)": (ex.exnonaxial(), jnp.array([0.0, 1.2]), 20.0,
                                     ex.exnonaxial_args(), {}),
        "near grazing (ex1dof μ=0.2)": (ex.ex1dof(), jnp.array([0.0, 0.9]), 60.0,
                                        ex.ex1dof_args(0.2), {"direction": 1}),
        "Zeno (bouncing ball e=0.8)": (ex.bouncing_ball(), jnp.array([1.0, 0.0]), 10.0,
                                       {"g": 9.81, "e": 0.8}, {}),
    }
    out = {}
    events.bracketed_root = recording
    try:
        for name, (scene, x0, t1, args, kw) in cases.items():
            calls.clear()
            sol = gj.simulate(scene, x0, 0.0, t1, args, rtol=1e-10, atol=1e-10,
                              max_impacts=40, event_root_finder=finder(method), **kw)
            jax.block_until_ready(sol.x_final)
            out[name] = (np.mean(calls), max(calls), len(calls), int(sol.num_impacts),
                         np.asarray(sol.impact_times))
    finally:
        events.bracketed_root = original
    return out


def throughput(lanes, repeats, tols):
    import diffrax
    import jax.numpy as jnp

    sys.path.insert(0, os.path.dirname(__file__))
    import bench_phases

    x0s = bench_phases.starts(lanes)
    rows = []
    for tol in tols:
        for kind, x in x0s.items():
            res = {}
            for method in METHODS:
                run = bench_phases.runner(diffrax.Dopri8(), tol,
                                          event_root_finder=finder(method))
                sol = run(jnp.asarray(x))
                res[method] = (run, np.asarray(sol.impact_times))
            times = {m: [] for m in res}
            for _ in range(repeats):  # interleaved, so that load affects both alike
                for m, (run, _) in res.items():
                    times[m].append(bench_phases.cpu_seconds(lambda r=run, x=x: r(jnp.asarray(x)), 1))
            us = {m: np.median(v) / lanes * 1e6 for m, v in times.items()}
            base = res[METHODS[0]][1]
            diffs = [np.nanmax(np.abs(res[m][1] - base)) for m in METHODS[1:]]
            rows.append((tol, kind, [us[m] for m in METHODS], diffs))
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--lanes", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    parser.add_argument("--skip-throughput", action="store_true")
    opts = parser.parse_args(argv)
    import jax

    jax.config.update("jax_enable_x64", True)
    lines = ["# In-step root searches: " + ", ".join(LABELS[m] for m in METHODS), ""]
    counts = {m: iteration_counts(m) for m in METHODS}
    base = METHODS[0]
    lines += ["Iterations per call (single runs, rtol = atol = 1e-10, calls on a non-empty "
              "bracket), mean / max (calls):", "",
              "| case | " + " | ".join(LABELS[m] for m in METHODS)
              + " | impact times, max diff from " + LABELS[base] + " |",
              "|---|" + "---|" * len(METHODS) + "---|"]
    for name in counts[base]:
        cells = [f"{counts[m][name][0]:.1f} / {counts[m][name][1]} ({counts[m][name][2]})"
                 for m in METHODS]
        a = counts[base][name]
        diffs = [np.nanmax(np.abs(counts[m][name][4] - a[4])) if counts[m][name][3] == a[3]
                 else float("nan") for m in METHODS[1:]]
        lines.append(f"| {name} | " + " | ".join(cells) + " | "
                     + ", ".join(f"{d:.1e}" for d in diffs) + " |")
    if not opts.skip_throughput:
        rows = throughput(opts.lanes, opts.repeats, (1e-8, 1e-10, 1e-12))
        lines += ["", f"Sweep throughput ({opts.lanes} lanes, ex1dof μ = 0.2, 10 impacts, "
                  f"Dopri8, vmap), CPU µs per trajectory, median of {opts.repeats} "
                  "interleaved repeats; the other methods' time over the default's, and "
                  "their largest impact-time difference from it:", "",
                  "| tol | starts | " + " | ".join(LABELS[m] for m in METHODS) + " | "
                  + " | ".join(f"{LABELS[m]} / {LABELS[base]}" for m in METHODS[1:])
                  + " | impact times, max diff |",
                  "|---|---|" + "---:|" * (2 * len(METHODS) - 1) + "---:|"]
        for tol, kind, us, diffs in rows:
            lines.append(f"| {tol:.0e} | {kind} | " + " | ".join(f"{u:.0f}" for u in us)
                         + " | " + " | ".join(f"{u / us[0]:.2f}×" for u in us[1:]) + " | "
                         + ", ".join(f"{d:.1e}" for d in diffs) + " |")
    write_result(lines, opts.out, "roots.md")


def write_result(lines, out, name):
    """Print a Markdown report and write it to out/name."""
    text = "\n".join(lines) + "\n"
    print(text)
    os.makedirs(out, exist_ok=True)
    with open(os.path.join(out, name), "w") as fh:
        fh.write(text)


if __name__ == "__main__":
    main()
