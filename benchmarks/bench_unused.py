"""Unrequested effects should cost nothing: the price of options a run does not use.

    python benchmarks/bench_unused.py [--lanes N] [--repeats R] [--all-cores] [--out DIR]

Two options that a run can carry without using them (grazejax issue 14, target ≤ 1.05×):

- `zeno="stick"` in a run that never slides (ex1dof μ = 0.2 impacts transversally);
- a large impact log, `max_impacts=4096`, of which 9 rows are used (vs `max_impacts=16`).

Each ratio is measured side by side in one process, the two configurations interleaved
(median of `--repeats` timings of each), at batch 1 (`jit(simulate)`) and at batch N
(`jit(vmap(simulate))`). Wall-clock µs per trajectory; the run is t ∈ [0, 60] from the
cycle's post-impact state (9 impacts), Tsit5 at rtol = atol = 1e-10. One core.

Twice: with glibc's default allocator, then after `grazejax.retain_freed_memory()` (what
`grazejax reproduce` does): a large log's cost at batch N is mostly the fresh pages the
kernel hands out for each call's results (page faults, counted per call).

Writes DIR/unused.md (default benchmarks/results).
"""

import argparse
import os
import resource
import sys
import time

import numpy as np
from bench_roots import write_result

# One core, pinned before JAX starts its thread pools (`--all-cores` lifts it): as the
# throughput and gradient benchmarks.
if __name__ == "__main__" and "--all-cores" not in sys.argv:
    from bench_throughput import pin_to_one_core

    pin_to_one_core()


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--lanes", type=int, default=256)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--all-cores", action="store_true", help="do not pin to one core")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    opts = parser.parse_args(argv)

    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_x64", True)
    import grazejax as gj
    from grazejax import examples as ex

    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    x_cycle = np.array([0.0, 0.0384224329])  # the μ = 0.2 cycle after its impact
    rng = np.random.default_rng(0)
    x_batch = np.tile(x_cycle, (opts.lanes, 1))
    x_batch[:, 1] += rng.uniform(-0.01, 0.01, opts.lanes)

    def run_fn(**kw):
        def one(x0):
            return gj.simulate(scene, x0, 0.0, 60.0, args, rtol=1e-10, atol=1e-10, **kw)

        return jax.jit(one), jax.jit(jax.vmap(one))

    configs = {
        "plain": dict(max_impacts=16),
        "zeno='stick'": dict(max_impacts=16, zeno="stick"),
        "max_impacts=4096": dict(max_impacts=4096),
    }
    runs = {name: run_fn(**kw) for name, kw in configs.items()}
    inputs = (jnp.asarray(x_cycle), jnp.asarray(x_batch))
    for name, fns in runs.items():  # compile, warm, and check the runs do what we claim
        for fn, x in zip(fns, inputs, strict=True):
            sol = jax.block_until_ready(fn(x))
            impacts = np.atleast_1d(np.asarray(sol.num_impacts))
            status = np.atleast_1d(np.asarray(sol.status))
            kinds = np.asarray(sol.impact_kind)
            if np.any(status != int(gj.Status.SUCCESS)) or np.any(
                kinds == int(gj.ImpactKind.STICK)
            ):
                raise RuntimeError(f"{name}: a run did not end as expected")
    print("impacts per run:", int(impacts[0]))
    # The floor under a large log: a program that only fills the 4096-row log's buffers
    # (NaN times and states, -1 surface and kind) and returns them, as the run must.
    runs[FLOOR] = tuple(log_fill(fn(x)) for fn, x in zip(runs["max_impacts=4096"], inputs,
                                                           strict=True))
    per_default, faults_default = timings(runs, inputs, opts)
    # The same runs with glibc keeping freed memory: the 4096-row log's cost at batch N was
    # the kernel's fresh pages for each call's results (grazejax/_memory.py).
    retained = gj.retain_freed_memory()
    per_retained, faults_retained = timings(runs, inputs, opts) if retained else (None, None)
    lines = [
        "# Unused options: cost relative to a plain run (target ≤ 1.05×)", "",
        f"ex1dof μ = 0.2, t ∈ [0, 60] ({int(impacts[0])} impacts, no sliding), Tsit5 1e-10; "
        f"wall µs per trajectory, median of {opts.repeats} interleaved repeats; page faults "
        f"per call of the batch-{opts.lanes} program (`getrusage`, minor faults).", "",
    ]
    lines += table(runs, per_default, faults_default, opts.lanes,
                   "glibc's default allocator (as a script that does not opt in)")
    if retained:
        lines += [""] + table(runs, per_retained, faults_retained, opts.lanes,
                              "after `grazejax.retain_freed_memory()` (as `grazejax reproduce`)")
    else:
        lines += ["", "(`retain_freed_memory()`: not glibc here, nothing to compare)"]
    write_result(lines, opts.out, "unused.md")


FLOOR = "its buffers alone (floor)"


def log_fill(sol):
    """A jitted function of the runs' input that returns NaN/-1-filled buffers of the
    shapes and dtypes of `sol`'s impact log."""
    import jax
    import jax.numpy as jnp

    logs = (sol.impact_times, sol.impact_pre, sol.impact_post, sol.impact_surface,
            sol.impact_kind)

    def fill(x):
        # (depends on the input, so that XLA cannot fold the buffers into constants)
        anchor = jnp.ravel(x)[0] * 0
        return [jnp.full(a.shape, jnp.nan if jnp.issubdtype(a.dtype, jnp.inexact) else -1,
                         a.dtype) + anchor.astype(a.dtype) for a in logs]

    return jax.jit(fill)


def timings(runs, inputs, opts):
    """Median µs per trajectory of each configuration at batch 1 and N, and the minor page
    faults per call of the batch-N programs."""
    import jax

    times = {(name, b): [] for name in runs for b in (0, 1)}
    faults = dict.fromkeys(runs, 0)
    # Batch 1 and batch N in separate passes: a single run timed right after the previous
    # configuration's batched run (58 MB of 4096-row logs written and freed) paid for the
    # evicted caches — the first configuration measured 5.0 ms against 1.7 ms timed alone.
    for b, x in enumerate(inputs):
        for _ in range(opts.repeats):
            for name, fns in runs.items():
                before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
                t = time.perf_counter()
                jax.block_until_ready(fns[b](x))
                times[name, b].append(time.perf_counter() - t)
                if b == 1:
                    faults[name] += resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
    per = {k: np.median(v) / (1 if k[1] == 0 else opts.lanes) * 1e6 for k, v in times.items()}
    return per, {name: n / opts.repeats for name, n in faults.items()}


def table(runs, per, faults, lanes, title):
    lines = [f"{title}:", "",
             f"| configuration | batch 1 | ratio | batch {lanes} | ratio | page faults a call |",
             "|---|---:|---:|---:|---:|---:|"]
    for name in runs:
        r1 = per[name, 0] / per["plain", 0]
        rn = per[name, 1] / per["plain", 1]
        lines.append(f"| {name} | {per[name, 0]:.0f} | {r1:.2f}× | {per[name, 1]:.1f} | "
                     f"{rn:.2f}× | {faults[name]:.0f} |")
    floor = 1 + per[FLOOR, 1] / per["plain", 1]
    lines += ["", f"A 4096-row log at batch {lanes} cannot cost less than plain + its buffers "
              f"alone: {floor:.2f}× here."]
    return lines


if __name__ == "__main__":
    main()
