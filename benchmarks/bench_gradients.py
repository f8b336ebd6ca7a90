"""Reverse mode through impacts: what `jax.grad` costs against the primal run and `jax.jacfwd`.

    python benchmarks/bench_gradients.py [--quick] [--out DIR]
    grazejax bench --script gradients [--quick]

Writes into DIR (default benchmarks/results/): `gradients.json` (every number, the machine
and package versions), `gradients_impacts.csv`, `gradients_direct.csv`,
`gradients_many.csv`, and `gradients.md` (the tables of benchmarks/README.md).

Sections:

1. **impacts**: the forced impact oscillator (`examples.impact_oscillator()`, default
   args: a stable period-1 motion, one impact and ~53 Tsit5 steps per forcing period) run
   to 10, 100 and 1000 impacts (t1 chosen for the count; one impact log of 1000 rows in
   every run, so that each mode is one compiled program). Loss = mean impact time +
   x_final·(1, 1), differentiated with respect to 7 inputs (x0 and the 5 args). Times:
   the primal run, `jax.jacfwd` (default adjoint, 7 tangents) and `jax.grad` with
   `diffrax.RecursiveCheckpointAdjoint(checkpoints=c)` for several c (None: grazejax's
   default, two levels of every-step checkpoints, `_loop/reverse.py: two_level_checkpointed`;
   447 = ⌊√(2·max_steps)⌋ for max_steps = 100 000 is what Equinox's own schedule takes
   by default, grazejax's default before).
2. **memory**: XLA's own account of each compiled program,
   `jax.jit(f).lower(...).compile().memory_analysis()`: `temp_size_in_bytes` (the scratch
   buffers: checkpoints, residuals, loop carries) is the number reported; argument and
   output sizes are tiny here.
3. **direct**: with `max_steps` set to 1.5× the steps the run needs, `jax.grad` with
   `diffrax.RecursiveCheckpointAdjoint(checkpoints=max_steps)` (every step's linearisation
   stored: nothing recomputed) at 10, 100 and 1000 impacts, and with
   `diffrax.DirectAdjoint()` (a bounded loop that stores every step up to `max_steps`) at
   10 (and 100) impacts; both against `jax.jacfwd`.
4. **many**: a Fourier-forced impact oscillator (`examples.fourier_impact_oscillator()`,
   M = 50 harmonics, 100 parameters; also M = 200 in the full run); loss = Σ_{i≤K} (t_i − t_i^obs)² over the first K
   impact times against those of another profile. `jax.grad` (RecursiveCheckpointAdjoint,
   and DirectAdjoint with max_steps 1.5× the start profile's steps) vs `jax.jacfwd` (2M
   tangents).

Every time is the min (and median) of repeats after compilation, with
`block_until_ready`, taken in interleaved rounds (one call of each mode per round) so that the
ratios of one section share the machine's load; compile times are reported separately.
The process runs on one core (`--all-cores` lifts that; see below).
`--quick` (~4 minutes on a shared 2-core machine) uses fewer checkpoint counts and repeats.
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

# One core, pinned before JAX starts its thread pools (`--all-cores` lifts it): on a 2-core
# machine, unpinned, the gradient/primal ratios of the same code moved by up to 1.6x between
# runs (every step stored at 10 impacts: 3.4-5.3x old code, 2.3-3.5x new; pinned: 3.0x and
# 2.3x in every run), as XLA's executor spread the reverse pass's loops over both cores.
# (Only as a script: the smoke test calls `main` inside a test worker.)
if __name__ == "__main__" and "--all-cores" not in sys.argv:
    from bench_throughput import pin_to_one_core  # (os and NumPy only: JAX not started)

    pin_to_one_core()

import diffrax  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from _cases import SHARED_MACHINE_NOTE, log, machine, time_interleaved, versions  # noqa: E402

import grazejax as gj  # noqa: E402  (turns float64 on)
from grazejax import examples  # noqa: E402

TOL = dict(rtol=1e-8, atol=1e-10)
PERIOD = 2 * math.pi / 1.5  # forcing period of the default impact oscillator
LOG_ROWS = 1000  # impact log of every run in section 1
NAMES = ("zeta", "A", "omega", "sigma", "r")
OSC = examples.impact_oscillator()
FOURIER = examples.fourier_impact_oscillator()
P0 = np.concatenate([[0.0, 0.0], [float(v) for v in examples.impact_oscillator_args().values()]])


def _loss(p, t1, adjoint, max_steps=100_000, max_impacts=LOG_ROWS):
    args = dict(zip(NAMES, p[2:], strict=True))
    sol = gj.simulate(
        OSC,
        p[:2],
        0.0,
        t1,
        args,
        adjoint=adjoint,
        max_steps=max_steps,
        max_impacts=max_impacts,
        direction=1,
        **TOL,
    )
    rows = jnp.arange(max_impacts) < sol.num_impacts
    mean_time = jnp.sum(jnp.where(rows, sol.impact_times, 0.0)) / jnp.maximum(sol.num_impacts, 1)
    return mean_time + sol.x_final[0] + sol.x_final[1]


def _compile(fn, *example):
    """`(compiled, seconds, memory)`: one XLA program, and its memory as XLA accounts it."""
    t = time.perf_counter()
    compiled = jax.jit(fn).lower(*example).compile()
    seconds = time.perf_counter() - t
    mem = compiled.memory_analysis()
    memory = {
        "temp_bytes": int(mem.temp_size_in_bytes),
        "argument_bytes": int(mem.argument_size_in_bytes),
        "output_bytes": int(mem.output_size_in_bytes),
    }
    return compiled, seconds, memory


def _interleaved(programs, inputs, repeats):
    """`time_interleaved` of the compiled `programs` on `inputs` (at least 3 rounds)."""
    calls = {
        name: (lambda program=program: jax.block_until_ready(program(*inputs)))
        for name, program in programs.items()
    }
    return time_interleaved(calls, max(3, repeats))


def _modes(checkpoints):
    modes = {
        "primal": (lambda p, t1: _loss(p, t1, None)),
        "jacfwd": jax.jacfwd(lambda p, t1: _loss(p, t1, None)),
    }
    for c in checkpoints:
        adjoint = diffrax.RecursiveCheckpointAdjoint(checkpoints=c)
        modes[f"grad_rca_{c or 'default'}"] = jax.grad(
            lambda p, t1, adjoint=adjoint: _loss(p, t1, adjoint)
        )
    return modes


def section_impacts(sizes, checkpoints, max_repeats):
    """Gradient cost vs the primal at several impact counts, and memory per mode."""
    p = jnp.asarray(P0)
    rows, memory, programs = [], [], {}
    for name, fn in _modes(checkpoints).items():
        compiled, compile_s, mem = _compile(fn, p, jnp.asarray(1.0))
        programs[name] = compiled
        memory.append({"mode": name, "compile_s": compile_s, **mem})
        log(f"  {name}: compiled in {compile_s:.1f} s, temp {mem['temp_bytes'] / 2**20:.1f} MiB")
    for n in sizes:
        t1 = jnp.asarray(n * PERIOD + 1.0)  # the n-th impact comes near n·PERIOD − 0.1
        timings, outs = _interleaved(programs, (p, t1), max_repeats)
        for name, st in timings.items():
            rows.append(
                {
                    "mode": name,
                    "target_impacts": n,
                    "min_s": st["min_s"],
                    "median_s": st["median_s"],
                    "repeats": st["repeats"],
                    "finite": bool(np.all(np.isfinite(np.asarray(outs[name])))),
                }
            )
    # Check the impact counts and the agreement of the modes once, outside the timings.
    run = jax.jit(_primal)
    for r in rows:
        t1 = jnp.asarray(r["target_impacts"] * PERIOD + 1.0)
        sol = run(p, t1)
        r["impacts"], r["steps"] = int(sol.num_impacts), int(sol.num_steps)
    primal = {r["target_impacts"]: r["min_s"] for r in rows if r["mode"] == "primal"}
    for r in rows:
        r["ratio_to_primal"] = r["min_s"] / primal[r["target_impacts"]]
    return rows, memory, programs


def _primal(p, t1):
    """The oscillator from p = (x0, v0, parameters...) to t1, logging up to LOG_ROWS impacts."""
    args = dict(zip(NAMES, p[2:], strict=True))
    return gj.simulate(OSC, p[:2], 0.0, t1, args, max_impacts=LOG_ROWS, direction=1, **TOL)


def section_agreement(compiled):
    """grad (every checkpoint count) equals jacfwd at 10 impacts: the benchmark times the
    right thing. Reuses the programs compiled for the timings."""
    p, t1 = jnp.asarray(P0), jnp.asarray(10 * PERIOD + 1.0)
    ref = np.asarray(compiled["jacfwd"](p, t1))
    worst = 0.0
    for name, program in compiled.items():
        if name.startswith("grad"):
            g = np.asarray(program(p, t1))
            worst = max(worst, float(np.max(np.abs(g - ref)) / np.max(np.abs(ref))))
    return worst


def section_direct(sizes, max_repeats, direct_sizes):
    """Every step stored (at each of `sizes`) and `DirectAdjoint()` (at `direct_sizes`),
    with `max_steps` 1.5× the run's need; gradients against `jax.jacfwd`'s."""
    p = jnp.asarray(P0)
    rows = []
    for n in sizes:
        t1 = jnp.asarray(n * PERIOD + 1.0)
        steps = int(jax.jit(lambda p, t1: _primal(p, t1).num_steps)(p, t1))
        max_steps = int(1.5 * steps)
        # Every step a checkpoint: no recomputation (each step's linearisation stored).
        every_step = diffrax.RecursiveCheckpointAdjoint(checkpoints=max_steps)
        grad_every = jax.grad(functools.partial(_loss, adjoint=every_step, max_steps=max_steps))
        primal = functools.partial(_loss, adjoint=None, max_steps=max_steps)
        row = {"target_impacts": n, "steps": steps, "max_steps": max_steps}
        modes = [("primal", primal), ("grad_rca_every_step", grad_every),
                 ("jacfwd", jax.jacfwd(primal))]
        if n in direct_sizes:
            modes.append(("grad_direct", jax.grad(functools.partial(
                _loss, adjoint=diffrax.DirectAdjoint(), max_steps=max_steps))))
        programs = {}
        for name, fn in modes:
            programs[name], compile_s, mem = _compile(fn, p, t1)
            row[f"{name}_compile_s"], row[f"{name}_temp_bytes"] = compile_s, mem["temp_bytes"]
        timings, outs = _interleaved(programs, (p, t1), max_repeats)
        for name in programs:
            row[f"{name}_min_s"] = timings[name]["min_s"]
        row["every_step_ratio_to_primal"] = row["grad_rca_every_step_min_s"] / row["primal_min_s"]
        forward = np.asarray(outs["jacfwd"])
        for name, key in (("grad_rca_every_step", "every_step"), ("grad_direct", "direct")):
            if name in outs:
                row[f"{key}_vs_jacfwd_rel"] = float(
                    np.max(np.abs(np.asarray(outs[name]) - forward)) / np.max(np.abs(forward)))
        if "grad_direct" in programs:
            row["ratio_to_primal"] = row["grad_direct_min_s"] / row["primal_min_s"]
        log(f"  bounded, {n} impacts: grad/primal {row['every_step_ratio_to_primal']:.2f} "
            f"(every step stored, {row['grad_rca_every_step_temp_bytes'] / 2**20:.1f} MiB)"
            + (f", {row['ratio_to_primal']:.2f} (direct)" if "ratio_to_primal" in row else ""))
        rows.append(row)
    return rows


def fourier_run(coefficients, harmonics, num_times, adjoint=None, max_steps=100_000):
    """The Fourier-forced oscillator from rest to its `num_times`-th impact."""
    a, b = coefficients[:harmonics], coefficients[harmonics:]
    args = examples.fourier_impact_oscillator_args(a, b)
    return gj.simulate(
        FOURIER, jnp.zeros(2), 0.0, jnp.inf, args, max_impacts=num_times, adjoint=adjoint,
        max_steps=max_steps, **TOL,
    )


def fourier_loss(coefficients, observed, adjoint, harmonics, num_times, max_steps=100_000):
    sol = fourier_run(coefficients, harmonics, num_times, adjoint, max_steps)
    return jnp.sum((sol.impact_times - observed) ** 2)


def fourier_profiles(harmonics):
    """A true profile (decaying random harmonics on top of the unit cosine) and a start."""
    rng = np.random.default_rng(0)
    decay = 0.3 / np.arange(1, harmonics + 1) ** 2
    true = np.concatenate([[1.0] + [0.0] * (harmonics - 1), [0.0] * harmonics])
    true = true + np.concatenate([decay, decay]) * rng.standard_normal(2 * harmonics)
    start = np.concatenate([[1.0] + [0.0] * (harmonics - 1), [0.0] * harmonics])
    return true, start


def section_many(harmonics, num_times, max_repeats):
    true, start = fourier_profiles(harmonics)
    observed = fourier_run(jnp.asarray(true), harmonics, num_times).impact_times
    c = jnp.asarray(start)
    rca, direct = diffrax.RecursiveCheckpointAdjoint(), diffrax.DirectAdjoint()
    # DirectAdjoint stores every step up to max_steps: sized, as in section 3, to 1.5× the
    # steps of the run from the start profile (the run a fit begins with).
    steps = int(fourier_run(c, harmonics, num_times).num_steps)
    max_steps = int(1.5 * steps)
    fns = {
        "primal": lambda c, o: fourier_loss(c, o, None, harmonics, num_times),
        "grad_rca": jax.grad(lambda c, o: fourier_loss(c, o, rca, harmonics, num_times)),
        "grad_direct": jax.grad(
            lambda c, o: fourier_loss(c, o, direct, harmonics, num_times, max_steps)
        ),
        "jacfwd": jax.jacfwd(lambda c, o: fourier_loss(c, o, None, harmonics, num_times)),
    }
    row = {"parameters": 2 * harmonics, "impact_times": num_times}
    programs = {}
    for name, fn in fns.items():
        programs[name], compile_s, mem = _compile(fn, c, observed)
        row[f"{name}_compile_s"], row[f"{name}_temp_bytes"] = compile_s, mem["temp_bytes"]
    timings, outs = _interleaved(programs, (c, observed), max_repeats)
    grads = {name: np.asarray(out) for name, out in outs.items()}
    for name, st in timings.items():
        row[f"{name}_min_s"], row[f"{name}_median_s"] = st["min_s"], st["median_s"]
        log(
            f"  many ({2 * harmonics} params): {name} {st['min_s'] * 1e3:.1f} ms "
            f"(compile {row[f'{name}_compile_s']:.1f} s)"
        )
    row["steps"], row["direct_max_steps"] = steps, max_steps
    row["grad_over_primal"] = row["grad_rca_min_s"] / row["primal_min_s"]
    row["direct_over_primal"] = row["grad_direct_min_s"] / row["primal_min_s"]
    row["jacfwd_over_primal"] = row["jacfwd_min_s"] / row["primal_min_s"]
    row["forward_over_reverse"] = row["jacfwd_min_s"] / row["grad_rca_min_s"]
    row["forward_over_direct"] = row["jacfwd_min_s"] / row["grad_direct_min_s"]
    ref = grads["jacfwd"]
    row["grad_vs_jacfwd_rel"] = float(
        max(np.max(np.abs(grads[k] - ref)) for k in ("grad_rca", "grad_direct")) / np.max(np.abs(ref))
    )
    return row


def _write_csv(path, rows):
    with open(path, "w", newline="") as f:
        # (rows may lack some columns: the union, in order of appearance)
        writer = csv.DictWriter(f, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
        writer.writeheader()
        writer.writerows(rows)


def _markdown(data):
    cpus = data.get("cpus")
    on = f"; the process on CPU {cpus[0]} only" if cpus and len(cpus) == 1 else ""
    lines = [f"Gradient benchmark ({data['mode']}); {SHARED_MACHINE_NOTE}{on}.", ""]
    lines += ["**Cost over the primal run** (min times), forced impact oscillator, 7 inputs:", ""]
    sizes = sorted({r["target_impacts"] for r in data["impacts"]})
    lines.append("| mode | temp memory | " + " | ".join(f"{n} impacts" for n in sizes) + " |")
    lines.append("|---|---|" + "---|" * len(sizes))
    memory = {m["mode"]: m["temp_bytes"] for m in data["memory"]}
    for mode in dict.fromkeys(r["mode"] for r in data["impacts"]):
        cells = []
        for n in sizes:
            r = next(r for r in data["impacts"] if r["mode"] == mode and r["target_impacts"] == n)
            cells.append(
                f"{r['min_s'] * 1e3:.1f} ms" if mode == "primal" else f"{r['ratio_to_primal']:.2f}×"
            )
        lines.append(f"| {mode} | {memory[mode] / 2**20:.1f} MiB | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"grad (every checkpoint count) vs jacfwd at 10 impacts: max relative "
        f"difference {data['agreement']:.1e}.",
        "",
    ]
    lines += [
        "**A bound on the steps** (max_steps = 1.5× the steps needed): "
        "`RecursiveCheckpointAdjoint(checkpoints=max_steps)` (every step stored: its "
        "linearisation where small, else its carry) and `DirectAdjoint()`; each gradient's "
        "largest difference from `jax.jacfwd`'s, relative to its largest entry:",
        "",
        "| impacts | steps | every step stored grad/primal | temp memory | vs jacfwd | "
        "DirectAdjoint grad/primal | temp memory | vs jacfwd |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in data["direct"]:
        direct = (f"{r['ratio_to_primal']:.2f}× | {r['grad_direct_temp_bytes'] / 2**20:.1f} MiB"
                  f" | {r['direct_vs_jacfwd_rel']:.1e}" if "ratio_to_primal" in r else "– | – | –")
        lines.append(
            f"| {r['target_impacts']} | {r['steps']} | {r['every_step_ratio_to_primal']:.2f}× | "
            f"{r['grad_rca_every_step_temp_bytes'] / 2**20:.1f} MiB | "
            f"{r['every_step_vs_jacfwd_rel']:.1e} | {direct} |"
        )
    lines += [
        "",
        "**Many parameters**: Fourier forcing, loss over the first impact times:",
        "",
        "| parameters | impact times | primal | grad, RecursiveCheckpointAdjoint | "
        "grad, DirectAdjoint | jacfwd (forward) | forward / reverse (RCA, Direct) | "
        "grads vs jacfwd |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in data["many"]:
        lines.append(
            f"| {m['parameters']} | {m['impact_times']} | {m['primal_min_s'] * 1e3:.1f} ms | "
            f"{m['grad_rca_min_s'] * 1e3:.1f} ms ({m['grad_over_primal']:.1f}×) | "
            f"{m['grad_direct_min_s'] * 1e3:.1f} ms ({m['direct_over_primal']:.1f}×) | "
            f"{m['jacfwd_min_s'] * 1e3:.1f} ms ({m['jacfwd_over_primal']:.1f}×) | "
            f"**{m['forward_over_reverse']:.1f}×, {m['forward_over_direct']:.1f}×** | "
            f"{m['grad_vs_jacfwd_rel']:.1e} |"
        )
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--all-cores", action="store_true",
                        help="do not pin the process to one core (see the module)")
    # The tests (CI): every section once at a tiny size (10 impacts, one checkpoint count,
    # 3 harmonics, one repeat), to check that the script runs; its numbers mean little.
    parser.add_argument("--smoke", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
    )
    parser.add_argument(
        "--many-only", type=int, nargs="+", metavar="HARMONICS",
        help="only the many-parameter section, at these numbers of harmonics (2 parameters "
        "each): writes gradients_many_sizes.json/.csv",
    )
    ns = parser.parse_args(argv)
    quick = ns.quick or ns.smoke
    os.makedirs(ns.out, exist_ok=True)
    if ns.many_only:
        return _many_only(ns.many_only, ns.out)
    checkpoints = (
        (None,) if ns.smoke else (30, 447, None) if quick else (10, 30, 100, 447, None, 1000, 4000)
    )
    repeats = 1 if ns.smoke else 3 if quick else 7
    sizes = (10,) if ns.smoke else (10, 100, 1000)
    t_start = time.perf_counter()
    log("impacts: gradient vs primal")
    impacts, memory, programs = section_impacts(sizes, checkpoints, repeats)
    log("agreement of the modes")
    agreement = section_agreement(programs)
    log("direct adjoint")
    direct = section_direct(sizes, repeats, (10,) if quick else (10, 100))
    log("many parameters")
    harmonics = (3,) if ns.smoke else (50,) if quick else (50, 200)
    many = [section_many(h, 20, repeats) for h in harmonics]
    data = {
        "mode": "smoke" if ns.smoke else "quick" if quick else "full",
        "tolerances": TOL,
        "impacts": impacts,
        "memory": memory,
        "agreement": agreement,
        "direct": direct,
        "many": many,
        "machine": machine(),
        "versions": versions(),
        "note": SHARED_MACHINE_NOTE,
        "cpus": sorted(os.sched_getaffinity(0)),
        "wall_s": time.perf_counter() - t_start,
    }
    with open(os.path.join(ns.out, "gradients.json"), "w") as f:
        json.dump(data, f, indent=1)
    _write_csv(os.path.join(ns.out, "gradients_impacts.csv"), impacts)
    _write_csv(os.path.join(ns.out, "gradients_direct.csv"), direct)
    _write_csv(os.path.join(ns.out, "gradients_many.csv"), many)
    table = _markdown(data)
    with open(os.path.join(ns.out, "gradients.md"), "w") as f:
        f.write(table)
    print(table)
    log(f"done in {data['wall_s']:.0f} s; results in {ns.out}")
    return 0


def _many_only(harmonics, out):
    """Reverse vs forward mode as the number of parameters grows (20 impact times)."""
    rows = [section_many(h, 20, 5) for h in harmonics]
    with open(os.path.join(out, "gradients_many_sizes.json"), "w") as f:
        json.dump({"many": rows, "machine": machine(), "versions": versions(),
                   "note": SHARED_MACHINE_NOTE}, f, indent=1)
    _write_csv(os.path.join(out, "gradients_many_sizes.csv"), rows)
    print("| parameters | primal | grad RCA / primal | grad Direct / primal | jacfwd / primal "
          "| forward / reverse (RCA, Direct) | grads vs jacfwd |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['parameters']} | {r['primal_min_s'] * 1e3:.1f} ms | "
              f"{r['grad_over_primal']:.1f}× | {r['direct_over_primal']:.1f}× | "
              f"{r['jacfwd_over_primal']:.1f}× | {r['forward_over_reverse']:.1f}×, "
              f"{r['forward_over_direct']:.1f}× | {r['grad_vs_jacfwd_rel']:.1e} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
