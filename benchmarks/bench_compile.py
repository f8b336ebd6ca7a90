"""Compile times, each in a fresh process with no compilation cache (issue 14's targets).

    python benchmarks/bench_compile.py [--repeats N] [--smoke] [--out DIR]   (default: results/)

Writes DIR/compile.json and DIR/compile.md. Every case runs in a new Python process with
JAX's persistent compilation cache off, so nothing compiled before serves it: the first
call's wall time (trace, lower, XLA compile and the run) and the second call's (the run
alone); their difference is the compile time. The min over `--repeats` processes is
reported (the machine is shared; compile times move by ~20% between runs).

Cases (ex1dof at μ = 0.2 from (0.5, 1.2), default solver and tolerances, t1 = 20, 20-row log):
`simulate` called directly (outside `jit`: grazejax's own cached program; its second call
has a new start and a new μ), `simulate` and `jax.jacfwd` of its final state in a user's
`jax.jit` (each also compiled with
`gj.compiler_options(batched=False)`, XLA:CPU's quicker emitters for one trajectory, which
grazejax's own orbit and Jacobian programs use), `jax.vmap` over 64 starts, and the README's
periodic-orbit example: `find_periodic_orbit` (impacting cycle from its impact) and then
`continue_orbit` from it over μ 0.2 → 0.15 (its first call after the solve, which has
compiled the programs the two share). Targets (issue 14): simulate ≤ 1.5 s, jacfwd ≤ 4 s,
find_periodic_orbit ≤ 8 s, continue_orbit ≤ 10 s.

The base, measured the same way: `diffrax.diffeqsolve` of the same field from the same start
over the same time, with the same solver (Tsit5) and controller tolerances (a PID controller,
rtol 1e-8, atol 1e-10), no events, and its `jax.jacfwd` (`adjoint=diffrax.ForwardMode()`).
Every case's compile time is reported as a ratio to it (`jacfwd` cases to the `jacfwd`
base): the price of the impact loop over a plain solve of the flow.
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import time
from pathlib import Path

# The bases: Diffrax's own solve of the flow, without events (see the module docstring).
BASES = ("diffeqsolve", "diffeqsolve jacfwd")
TARGETS_S = {"diffeqsolve": None, "diffeqsolve jacfwd": None, "simulate": 1.5, "simulate (one-run options)": 1.5,
             "simulate (outside jit)": 1.5, "jacfwd": 4.0,
             "jacfwd (one-run options)": 4.0, "vmap": None, "find_periodic_orbit": 8.0,
             "continue_orbit": 10.0}


def _case(name: str) -> dict:
    """Run one case in this process: first and second call wall times, in seconds."""
    import jax
    import jax.numpy as jnp

    import grazejax as gj
    from grazejax import examples as ex

    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    x0 = jnp.array([0.5, 1.2])

    def final(x):
        return gj.simulate(scene, x, 0.0, 20.0, args, max_impacts=20).x_final

    def flow_final(x):
        import diffrax

        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(scene.vector_field), diffrax.Tsit5(), 0.0, 20.0, None, x, args,
            stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-10),
            adjoint=diffrax.ForwardMode(), max_steps=100_000)
        return sol.ys[-1]

    starts = jnp.stack([jnp.full(64, 0.5), jnp.linspace(0.8, 1.4, 64)], axis=1)
    runs = {"simulate": (final, x0), "jacfwd": (jax.jacfwd(final), x0),
            "vmap": (jax.vmap(final), starts), "diffeqsolve": (flow_final, x0),
            "diffeqsolve jacfwd": (jax.jacfwd(flow_final), x0)}
    # The same programs compiled with the options for one trajectory (`gj.compiler_options`).
    one_run = " (one-run options)"
    if name == "simulate (outside jit)":
        # `gj.simulate` called directly: its own cached program. The second call has a new
        # start and a new μ (a Python float in args): inputs, not a new program.
        calls = iter([(x0, args), (x0 + 0.01, ex.ex1dof_args(0.21))])

        def call():
            x, a = next(calls)
            return gj.simulate(scene, x, 0.0, 20.0, a, max_impacts=20)
    elif name.removesuffix(one_run) in runs:
        fn, inputs = runs[name.removesuffix(one_run)]
        options = gj.compiler_options(batched=False) if name.endswith(one_run) else {}
        # (jit keeps the compiled program: the 2nd call runs it)
        call = functools.partial(jax.jit(fn, compiler_options=options), inputs)
    else:
        def orbit():
            return gj.find_periodic_orbit(scene, [0.0, 0.0384], 6.2, args)

        if name == "find_periodic_orbit":
            call = orbit
        else:
            start = orbit()
            call = lambda: gj.continue_orbit(scene, start, ex.ex1dof_args, 0.2, 0.15)  # noqa: E731
    times = []
    for _ in range(2):
        t = time.perf_counter()
        jax.block_until_ready([a for a in jax.tree.leaves(call()) if isinstance(a, jax.Array)])
        times.append(time.perf_counter() - t)
    return {"case": name, "first_s": times[0], "second_s": times[1],
            "compile_s": times[0] - times[1]}


def _fresh_process(name: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    env.update(JAX_ENABLE_COMPILATION_CACHE="false", GRAZEJAX_COMPILATION_CACHE="off")
    out = subprocess.run([sys.executable, __file__, "--case", name], env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def base_of(case: str) -> str:
    """The Diffrax base a case's compile time is compared with."""
    return "diffeqsolve jacfwd" if case.startswith("jacfwd") else "diffeqsolve"


def table(rows) -> str:
    compile_s = {r["case"]: r["compile_s"] for r in rows}
    lines = ["| case | first call (cold process) | second call | compile (difference) "
             "| vs diffeqsolve | target |", "|---|---:|---:|---:|---:|---:|"]
    for r in rows:
        target = TARGETS_S.get(r["case"])
        goal = f"≤ {target:.1f} s" if target else "—"
        base = compile_s.get(base_of(r["case"]))
        ratio = "—" if r["case"] in BASES or not base else f"{r['compile_s'] / base:.2f}×"
        lines.append(f"| `{r['case']}` | {r['first_s']:.2f} s | {r['second_s'] * 1e3:.1f} ms | "
                     f"{r['compile_s']:.2f} s | {ratio} | {goal} |")
    return "\n".join(lines)


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--smoke", action="store_true", help="simulate only, one process")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results"))
    ns = parser.parse_args(argv)
    if ns.case:
        print(json.dumps(_case(ns.case)))
        return []
    cases = ["diffeqsolve", "simulate"] if ns.smoke else list(TARGETS_S)
    repeats = 1 if ns.smoke else ns.repeats
    runs = [_fresh_process(name) for _ in range(repeats) for name in cases]
    rows = [min((r for r in runs if r["case"] == name), key=lambda r: r["first_s"])
            for name in cases]
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "compile.json").write_text(json.dumps({"repeats": repeats, "runs": runs}, indent=1))
    text = (f"Compile times, fresh process each, no compilation cache (min of {repeats}):\n\n"
            + table(rows) + "\n")
    (out / "compile.md").write_text(text)
    print(text)
    return rows


if __name__ == "__main__":
    main()
