"""Sweep throughput at matched accuracy: grazejax vs heyoka's fastest configuration vs SciPy.

    python benchmarks/bench_throughput.py [--quick | --smoke] [--lanes N] [--out DIR]
                                          [--device cpu|any]

The work is the project's main batch use: many starts of ex1dof at μ = 0.2 (every impact
nearly grazing), 10 impacts each, `t1 = inf`. Two kinds of starts (from `bench_phases`):
lanes **in phase** (the cycle's post-impact state, velocity perturbed by ±0.01) and
**random phases** (states of the cycle at uniform random times).

Each tool runs every tolerance of its grid; its error is the worst impact-time error over
the first lanes against heyoka in long double at tol 1e-19. For each accuracy level the
table takes, per tool, the cheapest configuration that reaches it (work-precision), in CPU
µs per trajectory on **one core** (the process is pinned to one CPU before JAX starts, so
XLA's and heyoka's thread pools cannot use a second one; `--all-cores` lifts that).

- grazejax: `jax.jit(jax.vmap(simulate), compiler_options=gj.compiler_options())` over all
  lanes, as `sweep` compiles it with `balance="none"` (on a CPU with AVX-512 the options
  ask XLA for 512-bit vectors), Tsit5, Dopri8 and `grazejax.Vern9`.
- heyoka, two configurations, both measured because the fastest must be the one compared:
  the batch (SIMD) integrator with jumps applied between `propagate_until` calls
  (`peers.HeyokaBatchRunner`) and the scalar integrator with the jump in an event callback
  (`peers.HeyokaImpactRunner`, the benchmark suite's peer). The batch runner's "core" time
  (inside `propagate_until` only) is also reported: what heyoka would cost with a driver
  of zero overhead.
- SciPy `solve_ivp` DOP853 with `max_step=0.05` (without it SciPy steps over these
  near-grazing impacts), a few lanes.

`--device any` runs grazejax on whatever device JAX finds first (a GPU where one is
installed; `JAX_PLATFORMS` decides as usual) and times it in wall-clock seconds, since CPU
time does not see a device's work; the peers stay on the CPU and in CPU time. The default,
`--device cpu`, keeps JAX on the CPU even where a GPU is present (docs/gpu.md says what a
GPU run is expected to show).

Writes DIR/throughput.json and DIR/throughput.md.
"""

import argparse
import json
import os
import sys
import time

import numpy as np

LEVELS = (1e-5, 1e-8, 1e-10)
IMPACTS = 10


def pin_to_one_core():
    cpu = min(os.sched_getaffinity(0))
    os.sched_setaffinity(0, {cpu})
    return cpu


def grazejax_rows(bench_phases, x0s, configs, reference, num_ref, repeats, on_cpu=True):
    import jax.numpy as jnp

    import grazejax as gj

    rows = []
    for name, solver, tol in configs:
        run = bench_phases.runner(solver, tol)
        for kind, x in x0s.items():
            sol = run(jnp.asarray(x))  # compile and warm
            if not np.all(np.asarray(sol.status) == int(gj.Status.MAX_IMPACTS)):
                raise RuntimeError(f"grazejax {name} {tol:g} {kind}: a lane did not finish")
            # (a device's work is not CPU time of this process: wall clock there)
            clock = time.process_time if on_cpu else time.perf_counter
            seconds = bench_phases.cpu_seconds(lambda x=x, run=run: run(jnp.asarray(x)),
                                               repeats, clock)
            rows.append({
                "tool": "grazejax", "mode": kind, "config": f"{name} {tol:.0e}", "tol": tol,
                "us": seconds / len(x) * 1e6,
                "error": worst_error(np.asarray(sol.impact_times), reference[kind], num_ref),
            })
    return rows


def heyoka_rows(peers, x0s, tols, reference, num_ref, repeats, scalar_lanes):
    rows = []
    for tol in tols:
        scalar = peers.HeyokaImpactRunner("ex1dof", tol=tol, mu=0.2)
        for kind, x in x0s.items():
            for callback in (False, True):
                batch = peers.HeyokaBatchRunner("ex1dof", tol=tol, callback=callback, mu=0.2)
                batch.run(x[:batch.simd], 0.0, 1e6, IMPACTS)  # warm
                best, core = np.inf, np.inf
                for _ in range(repeats):
                    t = time.process_time()
                    times, _ = batch.run(x, 0.0, 1e6, IMPACTS)
                    best = min(best, time.process_time() - t)
                    core = min(core, batch.core_seconds)
                how = "jump in callback" if callback else "jumps between calls"
                rows.append({
                    "tool": "heyoka batch", "mode": kind,
                    "config": f"SIMD x{batch.simd}, {how}, {tol:.0e}", "tol": tol,
                    "us": best / len(x) * 1e6, "core_us": core / len(x) * 1e6,
                    "error": worst_error(times, reference[kind], num_ref),
                })
            lanes = x[:scalar_lanes]
            scalar.run(lanes[0], 0.0, 1e6, IMPACTS)
            t = time.process_time()
            out = [scalar.run(x0, 0.0, 1e6, IMPACTS)["impact_times"] for x0 in lanes]
            rows.append({
                "tool": "heyoka scalar", "mode": kind, "config": f"callback {tol:.0e}",
                "tol": tol, "us": (time.process_time() - t) / len(lanes) * 1e6,
                "error": worst_error(np.array(out), reference[kind], min(num_ref, len(lanes))),
            })
    return rows


def scipy_rows(peers, x0s, tols, reference, lanes):
    rows = []
    for tol in tols:
        runner = peers.ScipyImpactRunner("ex1dof", method="DOP853", rtol=tol, atol=tol,
                                         max_step=0.05, mu=0.2)
        for kind, x in x0s.items():
            t = time.process_time()
            out = [runner.run(x0, 0.0, 1e6, IMPACTS)["impact_times"] for x0 in x[:lanes]]
            rows.append({
                "tool": "SciPy", "mode": kind, "config": f"DOP853 max_step 0.05 {tol:.0e}",
                "tol": tol, "us": (time.process_time() - t) / lanes * 1e6,
                "error": worst_error(np.array(out), reference[kind], lanes),
            })
    return rows


def worst_error(times, reference, num_ref):
    return max(float(np.max(np.abs(np.asarray(times[i]) - reference[i]))) for i in range(num_ref))


def cheapest(rows, tool, mode, level):
    ok = [r for r in rows if r["tool"] == tool and r["mode"] == mode and r["error"] <= level]
    return min(ok, key=lambda r: r["us"]) if ok else None


def summary(rows, levels):
    table = []
    for level in levels:
        entry = {"level": level}
        for mode in ("in_phase", "random"):
            for tool in ("grazejax", "heyoka batch", "heyoka scalar", "SciPy"):
                entry[f"{tool}|{mode}"] = cheapest(rows, tool, mode, level)
        heyoka_best = [entry[f"heyoka {k}|random"] for k in ("batch", "scalar")]
        heyoka_best = min((r for r in heyoka_best if r), key=lambda r: r["us"], default=None)
        entry["heyoka fastest"] = heyoka_best
        for mode in ("in_phase", "random"):
            g = entry[f"grazejax|{mode}"]
            entry[f"ratio {mode}"] = g["us"] / heyoka_best["us"] if g and heyoka_best else None
        table.append(entry)
    return table


def markdown(table, lanes, cpu_note):
    fmt = lambda r: "—" if r is None else f"{r['us']:.0f} ({r['config']}, {r['error']:.0e})"  # noqa: E731
    ratio = lambda v: "—" if v is None else f"{v:.2f}×"  # noqa: E731
    lines = [
        "# Sweep throughput at matched accuracy (ex1dof μ = 0.2, 10 impacts per lane)", "",
        f"{lanes} lanes; CPU µs per trajectory, {cpu_note}; in brackets the cheapest "
        "configuration reaching the level and its measured worst impact-time error (vs heyoka "
        "long double at 1e-19). Ratios: grazejax / heyoka's fastest (> 1: grazejax slower).", "",
        "| error ≤ | grazejax in phase | grazejax random phases | heyoka batch (SIMD) "
        "| heyoka scalar + callback | SciPy DOP853 | in phase / heyoka | random / heyoka |",
        "|---|---|---|---|---|---|---:|---:|",
    ]
    for e in table:
        lines.append(
            f"| {e['level']:.0e} | {fmt(e['grazejax|in_phase'])} | {fmt(e['grazejax|random'])} "
            f"| {fmt(e['heyoka batch|random'])} | {fmt(e['heyoka scalar|random'])} "
            f"| {fmt(e['SciPy|random'])} | {ratio(e['ratio in_phase'])} "
            f"| {ratio(e['ratio random'])} |")
    core = [e["heyoka batch|random"] for e in table if e["heyoka batch|random"]]
    if core:
        lines += ["", "heyoka batch, time inside `propagate_until` alone (no Python driver): "
                  + ", ".join(f"{c['core_us']:.0f} µs at {c['config']}" for c in core) + "."]
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--quick", action="store_true")
    mode.add_argument("--smoke", action="store_true", help="one config per tool, 16 lanes")
    parser.add_argument("--lanes", type=int, default=None)
    parser.add_argument("--all-cores", action="store_true", help="do not pin to one core")
    parser.add_argument("--out", default="bench-output")
    parser.add_argument("--device", choices=("cpu", "any"), default="cpu",
                        help="where grazejax runs: the CPU, or JAX's default device")
    opts = parser.parse_args(argv)
    cpu_note = "all cores" if opts.all_cores else f"one core (CPU {pin_to_one_core()})"
    if opts.device == "cpu" and "jax" not in sys.modules:
        os.environ["JAX_PLATFORMS"] = "cpu"  # no GPU backend started for nothing

    import diffrax
    import jax

    import grazejax as gj

    jax.config.update("jax_enable_x64", True)
    device = jax.devices()[0] if opts.device == "any" else jax.devices("cpu")[0]
    on_cpu = device.platform == "cpu"
    if not on_cpu:
        cpu_note += f"; grazejax on {device.device_kind} ({device.platform}), wall-clock µs"
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import bench_phases
    import peers

    lanes = opts.lanes or (16 if opts.smoke else 512 if opts.quick else 2048)
    repeats, num_ref, scipy_lanes = (1, 2, 1) if opts.smoke else (2, 8, 2) if opts.quick else (3, 16, 4)
    scalar_lanes = min(lanes, 16 if opts.smoke else 128)
    if opts.smoke:
        configs, hey_tols, scipy_tols = [("Dopri8", diffrax.Dopri8(), 1e-8)], (1e-8,), (1e-6,)
    else:
        configs = [("Tsit5", diffrax.Tsit5(), t) for t in (1e-6, 1e-8, 1e-10)]
        # Decades, and 1-2-5 steps in the band where each tool's error meets the tightest
        # level (its error is ~5-50× its tolerance for Dopri8, ~1× for heyoka): the
        # cheapest configuration reaching a level is then found to a factor 2 or 2.5 in
        # tolerance for both.
        configs += [("Dopri8", diffrax.Dopri8(), t)
                    for t in (1e-6, 1e-8, 1e-10, 5e-12, 2e-12, 1e-12)]
        # Verner's 9(8) pair: fewer steps than Dopri8 at tight tolerances, more stages each.
        configs += [("Vern9", gj.Vern9(), t) for t in (1e-10, 1e-11, 5e-12, 2e-12)]
        hey_tols = (1e-6, 1e-8, 5e-10, 2e-10, 1e-10, 5e-11, 2e-11, 1e-12, 1e-15)
        scipy_tols = (1e-7, 1e-10, 1e-12)
    x0s = bench_phases.starts(lanes)
    reference_runner = peers.HeyokaImpactRunner("ex1dof", tol=1e-19, fp_type=np.longdouble, mu=0.2)
    reference = {k: [reference_runner.run(x[i], 0.0, 1e6, IMPACTS)["impact_times"]
                     for i in range(num_ref)] for k, x in x0s.items()}
    with jax.default_device(device):
        rows = grazejax_rows(bench_phases, x0s, configs, reference, num_ref, repeats, on_cpu)
    rows += heyoka_rows(peers, x0s, hey_tols, reference, num_ref, repeats, scalar_lanes)
    rows += scipy_rows(peers, x0s, scipy_tols, reference, scipy_lanes)
    table = summary(rows, LEVELS)
    os.makedirs(opts.out, exist_ok=True)
    with open(os.path.join(opts.out, "throughput.json"), "w") as f:
        json.dump({"lanes": lanes, "cpu": cpu_note, "device": str(device), "rows": rows,
                   "summary": table}, f,
                  indent=2, default=str)
    md = markdown(table, lanes, cpu_note)
    with open(os.path.join(opts.out, "throughput.md"), "w") as f:
        f.write(md)
    print(md)
    return rows, table


if __name__ == "__main__":
    main()
