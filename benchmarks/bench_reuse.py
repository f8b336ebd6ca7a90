"""First call and reuse: what a user waits for, call by call, beside Diffrax.

    python benchmarks/bench_reuse.py [--out DIR] [--case NAME --cache DIR]

Writes DIR/reuse.json and DIR/reuse.md (default DIR: results/). Each case runs in a fresh
Python process with its own empty persistent compilation cache, and is timed (wall clock,
`block_until_ready`) at four calls, as a user makes them, eagerly (no `jax.jit` of the
user's):

1. the first call (tracing, compiling and running);
2. a second call with new numbers (a new start, or a new μ in `args`);
3. a call with a new `rtol` (a Python float);
4. the first call in a second process that finds the first one's persistent cache
   (`gj.enable_compilation_cache(dir)`), import time excluded.

Cases: ex1dof at μ = 0.2 from (0.5, 1.2), Tsit5, t1 = 20, 20-row log: `simulate`,
`jax.jacfwd` of its final state, `jax.grad` of |x(t1)|² (`adjoint=RecursiveCheckpointAdjoint`),
`sweep` of 64 starts, `find_periodic_orbit` (the README's cycle) and `continue_orbit` from it
(μ 0.2 → 0.15, after the solve in the same process). Beside them, Diffrax's `diffeqsolve` of
the same field and solver without events (PID controller, rtol 1e-8, atol 1e-10; its own
`eqx.filter_jit` is its cache): the solve, its `jax.jacfwd` (`ForwardMode`), its `jax.grad`
(`RecursiveCheckpointAdjoint`) and `jax.vmap` over the 64 starts.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CASES = ("simulate", "jacfwd", "grad", "sweep", "find_periodic_orbit", "continue_orbit",
         "diffeqsolve", "diffeqsolve jacfwd", "diffeqsolve grad", "diffeqsolve vmap")
PEER_OF = {"simulate": "diffeqsolve", "jacfwd": "diffeqsolve jacfwd", "grad": "diffeqsolve grad",
           "sweep": "diffeqsolve vmap"}
CALLS = ("first", "new numbers", "new rtol")


def _calls(name: str):
    """The case's three calls: `{call: () -> result}` (built after the cache is set up)."""
    import diffrax
    import jax
    import jax.numpy as jnp

    import grazejax as gj
    from grazejax import examples as ex

    scene, x0 = ex.ex1dof(), jnp.array([0.5, 1.2])
    starts = jnp.stack([jnp.full(64, 0.5), jnp.linspace(0.8, 1.4, 64)], axis=1)
    values = {"first": (x0, 0.2, 1e-8), "new numbers": (x0 + 0.01, 0.21, 1e-8),
              "new rtol": (x0 + 0.01, 0.21, 1e-9)}
    checkpoint, forward = diffrax.RecursiveCheckpointAdjoint(), diffrax.ForwardMode()

    def final(x, mu, rtol, **kw):
        return gj.simulate(scene, x, 0.0, 20.0, ex.ex1dof_args(mu), max_impacts=20, rtol=rtol,
                           **kw).x_final

    def flow(x, mu, rtol, adjoint=forward):
        return diffrax.diffeqsolve(
            diffrax.ODETerm(scene.vector_field), diffrax.Tsit5(), 0.0, 20.0, None, x,
            ex.ex1dof_args(mu), stepsize_controller=diffrax.PIDController(rtol=rtol, atol=1e-10),
            adjoint=adjoint, max_steps=100_000).ys[-1]

    squared = lambda fn, **kw: lambda x, mu, rtol: jnp.sum(fn(x, mu, rtol, **kw) ** 2)  # noqa: E731
    runs = {
        "simulate": final,
        "jacfwd": lambda x, mu, rtol: jax.jacfwd(final)(x, mu, rtol),
        "grad": lambda x, mu, rtol: jax.grad(squared(final, adjoint=checkpoint))(x, mu, rtol),
        "sweep": lambda x, mu, rtol: gj.sweep(scene, starts + (x - x0), 0.0, 20.0,
                                              ex.ex1dof_args(mu), max_impacts=20, rtol=rtol,
                                              progress=False).x_final,
        "diffeqsolve": flow,
        "diffeqsolve jacfwd": lambda x, mu, rtol: jax.jacfwd(flow)(x, mu, rtol),
        "diffeqsolve grad": lambda x, mu, rtol: jax.grad(squared(flow, adjoint=checkpoint))(
            x, mu, rtol),
        "diffeqsolve vmap": lambda x, mu, rtol: jax.vmap(flow, (0, None, None))(
            starts + (x - x0), mu, rtol),
    }
    if name in runs:
        return {call: (lambda v=v: runs[name](*v)) for call, v in values.items()}
    orbit = lambda mu, rtol: gj.find_periodic_orbit(  # noqa: E731
        scene, [0.0, 0.0384], 6.2, ex.ex1dof_args(mu), rtol=rtol * 1e-2)
    if name == "find_periodic_orbit":
        return {call: (lambda v=v: orbit(v[1], v[2])) for call, v in values.items()}
    start = orbit(0.2, 1e-8)  # (compiles the programs continuation shares with the solve)
    return {call: (lambda v=v: gj.continue_orbit(scene, start, ex.ex1dof_args, 0.2, 0.15,
                                                   rtol=v[2] * 1e-2, progress=False))
            for call, v in values.items()}


def _case(name: str, cache: str, calls: tuple) -> dict:
    """Time `calls` of case `name` in this process, with the persistent cache at `cache`."""
    import jax

    import grazejax as gj

    gj.enable_compilation_cache(cache)
    made = _calls(name)
    seconds = {}
    for call in calls:
        t = time.perf_counter()
        jax.block_until_ready([a for a in jax.tree.leaves(made[call]())
                               if isinstance(a, jax.Array)])
        seconds[call] = time.perf_counter() - t
    return seconds


def _process(name: str, cache: str, calls: tuple) -> dict:
    env = {k: v for k, v in os.environ.items()
           if k not in ("JAX_COMPILATION_CACHE_DIR", "GRAZEJAX_COMPILATION_CACHE")}
    out = subprocess.run([sys.executable, __file__, "--case", name, "--cache", cache,
                          "--calls", ",".join(calls)], env=env, check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def measure(name: str) -> dict:
    with tempfile.TemporaryDirectory() as cache:
        row = _process(name, cache, CALLS)
        row["second process"] = _process(name, cache, ("first",))["first"]
    return {"case": name, **row}


def table(rows) -> str:
    lines = ["| case | first call | second call, new numbers | new rtol "
             "| second process, with the cache |", "|---|---:|---:|---:|---:|"]
    for r in rows:
        cells = [r[c] for c in (*CALLS, "second process")]
        lines.append(f"| `{r['case']}` | " + " | ".join(_seconds(c) for c in cells) + " |")
    return "\n".join(lines)


def _seconds(s: float) -> str:
    return f"{s:.2f} s" if s >= 0.1 else f"{s * 1e3:.1f} ms"


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case")
    parser.add_argument("--cache")
    parser.add_argument("--calls", default=",".join(CALLS))
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--out", default=str(Path(__file__).parent / "results"))
    ns = parser.parse_args(argv)
    if ns.case:
        print(json.dumps(_case(ns.case, ns.cache, tuple(ns.calls.split(",")))))
        return []
    rows = [measure(name) for name in ns.cases.split(",")]
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "reuse.json").write_text(json.dumps(rows, indent=1))
    text = ("First call and reuse (eager calls; each case in a fresh process with an empty "
            "persistent cache, then a second process with that cache):\n\n" + table(rows) + "\n")
    (out / "reuse.md").write_text(text)
    print(text)
    return rows


if __name__ == "__main__":
    main()
