"""Random-phase vs in-phase sweeps: what a lane pays for the other lanes' events.

    python benchmarks/bench_phases.py [--quick] [--lanes N] [--out DIR]

ex1dof at μ = 0.2 (every impact nearly grazing), 10 impacts per lane, `t1 = inf`, one
`jax.vmap` over all lanes (`balance="none"` in `sweep`'s words), CPU time per lane
(`time.process_time`, min of interleaved repeats). Two kinds of starts:

- **in phase**: the cycle's post-impact state with the velocity perturbed by ±0.01, so the
  lanes meet their impacts in the same loop iterations;
- **random phases**: states of the cycle at uniform random times in [0, 2π), so some lane
  has an event search in almost every loop iteration; under `vmap` the search and landing
  branches become selects and every lane pays for them.

heyoka runs each start on its own (scalar Taylor integrator, the jump applied in an event
callback: `peers.HeyokaImpactRunner`) at the same tolerance; its cost does not depend on
the phase. Errors are against heyoka in long double at tol 1e-18 on the first lanes.
Writes DIR/phases.json and DIR/phases.md.
"""

import argparse
import json
import os
import sys
import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
from grazejax import examples as ex

sys.path.insert(0, os.path.dirname(__file__))
import peers  # noqa: E402

CYCLE_POST = np.array([0.0, 0.0384224329])  # post-impact state of the μ = 0.2 cycle
IMPACTS = 10


def starts(lanes, seed=0):
    rng = np.random.default_rng(seed)
    in_phase = np.tile(CYCLE_POST, (lanes, 1))
    in_phase[:, 1] += rng.uniform(-0.01, 0.01, lanes)
    times = np.sort(rng.uniform(0.0, 2 * np.pi, lanes))
    cycle = gj.simulate(ex.ex1dof(), jnp.asarray(CYCLE_POST), 0.0, 2 * np.pi, ex.ex1dof_args(0.2),
                        saveat=jnp.asarray(times), rtol=1e-13, atol=1e-13, max_impacts=10)
    return {"in_phase": in_phase, "random": np.asarray(cycle.xs)}


def runner(solver, tol, **options):
    """The sweep as `sweep` compiles it: `gj.compiler_options()` (512-bit vectors on a CPU
    with AVX-512) with `jit`. `options`: more of `simulate`'s."""
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    return jax.jit(jax.vmap(lambda x0: gj.simulate(
        scene, x0, 0.0, jnp.inf, args, solver=solver, rtol=tol, atol=tol,
        max_impacts=IMPACTS, direction=1, **options)), compiler_options=gj.compiler_options())


def cpu_seconds(fn, repeats, clock=time.process_time):
    """Least time of `repeats` calls of `fn`, each waited for: CPU time of this process by
    default; `clock=time.perf_counter` for work on a device, which CPU time does not see."""
    best = np.inf
    for _ in range(repeats):
        t = clock()
        jax.block_until_ready(fn())
        best = min(best, clock() - t)
    return best


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--smoke", action="store_true", help="one config, 8 lanes (tests)")
    parser.add_argument("--lanes", type=int, default=None)
    parser.add_argument("--out", default="bench-output")
    opts = parser.parse_args(argv)
    lanes = opts.lanes or (8 if opts.smoke else 512 if opts.quick else 2048)
    repeats, num_ref = (1, 2) if opts.smoke else (2, 10) if opts.quick else (4, 40)
    x0s = starts(lanes)
    configs = {"Tsit5 1e-8": (diffrax.Tsit5(), 1e-8), "Dopri8 1e-10": (diffrax.Dopri8(), 1e-10),
               "Dopri8 1e-12": (diffrax.Dopri8(), 1e-12)}
    if opts.smoke:
        configs = {"Dopri8 1e-10": configs["Dopri8 1e-10"]}
    refs = peers.HeyokaImpactRunner("ex1dof", tol=1e-18, fp_type=np.longdouble, mu=0.2)
    reference = {k: [refs.run(x0s[k][i], 0.0, 1e6, IMPACTS) for i in range(num_ref)] for k in x0s}

    def error(times, k):
        return max(float(np.max(np.abs(np.asarray(times[i]) - reference[k][i]["impact_times"])))
                   for i in range(num_ref))

    rows = []
    for name, (solver, tol) in configs.items():
        run = runner(solver, tol)
        row = {"config": name}
        for k, x in x0s.items():
            sol = run(jnp.asarray(x))  # compile and warm
            assert np.all(np.asarray(sol.status) == int(gj.Status.MAX_IMPACTS))
            row[f"{k}_us"] = cpu_seconds(lambda x=x, run=run: run(jnp.asarray(x)), repeats) / lanes * 1e6
            row[f"{k}_error"] = error(np.asarray(sol.impact_times), k)
        hey = peers.HeyokaImpactRunner("ex1dof", tol=tol, mu=0.2)
        hey.run(x0s["random"][0], 0.0, 1e6, IMPACTS)
        t = time.process_time()
        out = [hey.run(x0s["random"][i], 0.0, 1e6, IMPACTS) for i in range(num_ref)]
        row["heyoka_us"] = (time.process_time() - t) / num_ref * 1e6
        row["heyoka_error"] = error([o["impact_times"] for o in out], "random")
        row["random_over_in_phase"] = row["random_us"] / row["in_phase_us"]
        row["random_over_heyoka"] = row["random_us"] / row["heyoka_us"]
        rows.append(row)
    os.makedirs(opts.out, exist_ok=True)
    with open(os.path.join(opts.out, "phases.json"), "w") as f:
        json.dump({"lanes": lanes, "rows": rows, "cpus": os.cpu_count()}, f, indent=2)
    md = ["# Random-phase vs in-phase sweeps (ex1dof μ = 0.2, 10 impacts per lane)", "",
          f"{lanes} lanes, one vmap, CPU µs per lane (min of {repeats}); heyoka scalar per run.", "",
          "| config | in phase µs | random µs | random / in phase | heyoka µs | random / heyoka "
          "| error in phase | error random | error heyoka |",
          "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        md.append(f"| {r['config']} | {r['in_phase_us']:.0f} | {r['random_us']:.0f} | "
                  f"{r['random_over_in_phase']:.2f} | {r['heyoka_us']:.0f} | "
                  f"{r['random_over_heyoka']:.1f} | {r['in_phase_error']:.1e} | "
                  f"{r['random_error']:.1e} | {r['heyoka_error']:.1e} |")
    with open(os.path.join(opts.out, "phases.md"), "w") as f:
        f.write("\n".join(md) + "\n")
    print("\n".join(md))
    return rows


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    main()
