"""The same ex1dof runs timed for several git revisions, in alternating processes.

    python benchmarks/bench_revisions.py [REV ...] [--rounds R] [--core N] [--out DIR]

What a change to the impact loop costs or saves, measured as `benchmarks/README.md` asks:
each revision runs in a process of its own (a `git worktree` of it, `.` for the working
tree; default: `HEAD~1 .`), the revisions take turns for `--rounds` rounds, every process is
pinned to one core (`--core`, with `taskset` where there is one), and each case is the
least CPU time of its repeats. The cases are those of the in-step search's cost tables:
ex1dof at μ = 0.2 with 10 impacts from a random phase of its cycle, one `jax.jit(simulate)`
run with Dopri8 at rtol = atol = 2e-12 and with Tsit5 at 1e-10, and `bench_phases.runner`
sweeps (Dopri8 2e-12) of 512 and 2048 lanes in phase and at random phases, and the
corrugated-floor campaign's lanes (`tests/hard/campaign_corrugated.py`, 1,024 systems).

Writes DIR/revisions.json (every round's value) and DIR/revisions.md (the rounds side by
side, and each revision's least value over the first revision's). The benchmark helpers
(`bench_phases`) are this checkout's; the package is each revision's own (its worktree is
put first on `PYTHONPATH`, and the child checks where `grazejax` came from).
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def measure(smoke: bool) -> dict:
    """Least CPU time of every case, in µs (per trajectory for sweeps), in this process."""
    sys.path.insert(0, str(HERE))
    import bench_phases as bp
    import diffrax
    import jax
    import jax.numpy as jnp

    import grazejax as gj
    from grazejax import examples as ex

    jax.config.update("jax_enable_x64", True)
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    x0 = jnp.asarray(bp.starts(8)["random"][3])
    single_repeats, sweep_repeats, rounds = (2, 1, 1) if smoke else (40, 3, 3)
    cases = {}
    for name, solver, tol in (("one run, Dopri8 2e-12", diffrax.Dopri8(), 2e-12),
                              ("one run, Tsit5 1e-10", diffrax.Tsit5(), 1e-10)):
        run = jax.jit(lambda x, solver=solver, tol=tol: gj.simulate(
            scene, x, 0.0, jnp.inf, args, solver=solver, rtol=tol, atol=tol,
            max_impacts=bp.IMPACTS, direction=1))
        cases[name] = (lambda run=run: run(x0), single_repeats, 1)
    sweep = bp.runner(diffrax.Dopri8(), 2e-12)
    for lanes in (8,) if smoke else (512, 2048):
        starts = bp.starts(lanes)
        for kind, label in (("in_phase", "in phase"), ("random", "random phases")):
            xs = jnp.asarray(starts[kind])
            cases[f"sweep {lanes} {label}"] = (lambda xs=xs: sweep(xs), sweep_repeats, lanes)
    if not smoke:
        cases.update(_corrugated_cases())
    for fn, _, _ in cases.values():
        jax.block_until_ready(fn())
    best = dict.fromkeys(cases, float("inf"))
    for _ in range(rounds):
        for name, (fn, repeats, per) in cases.items():
            best[name] = min(best[name], bp.cpu_seconds(fn, repeats) / per * 1e6)
    return {"package": gj.__file__, "us": best}


def _corrugated_cases() -> dict:
    """The corrugated-floor campaign's lanes (this checkout's `tests/hard`, the revision's
    package): 1,024 systems, 2-D and 3-D floors, Tsit5 and Dopri8 at 1e-10, per system. Its
    exact flights make long steps that the in-step search must resolve (docs/hard_cases.md)."""
    import importlib.util

    import jax.numpy as jnp

    path = HERE.parent / "tests" / "hard" / "campaign_corrugated.py"
    spec = importlib.util.spec_from_file_location("campaign_corrugated", path)
    C = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(C)
    x0, p = C.draw_mixed(1024, 11)
    x0, p = jnp.asarray(x0), {key: jnp.asarray(value) for key, value in p.items()}
    cases = {}
    for name in ("Tsit5", "Dopri8"):
        run = C.runner(name, 1e-10)
        cases[f"corrugated floors 1024, {name} 1e-10"] = (lambda run=run: run(x0, p), 1, len(x0))
    return cases


def _worktree(rev: str, parent: Path) -> Path:
    if rev == ".":
        return HERE.parent
    path = parent / rev.replace("/", "_").replace("~", "-").replace("^", "-")
    subprocess.run(["git", "-C", str(HERE.parent), "worktree", "add", "--detach", str(path),
                    rev], check=True, capture_output=True)
    return path


def _run_child(tree: Path, out: Path, core, smoke: bool) -> dict:
    command = [sys.executable, str(Path(__file__).resolve()), "--measure", str(out)]
    if smoke:
        command.append("--smoke")
    if core is not None and shutil.which("taskset"):
        command = ["taskset", "-c", str(core), *command]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(tree), *filter(None, [os.environ.get("PYTHONPATH")])]))
    subprocess.run(command, check=True, cwd=tree, env=env)
    result = json.loads(out.read_text())
    if not Path(result["package"]).resolve().is_relative_to(tree.resolve()):
        raise RuntimeError(f"{tree}: grazejax was imported from {result['package']}")
    return result["us"]


def render_md(revs, results) -> str:
    header = ["case", *(f"`{r}`" for r in revs), *(f"`{r}` / `{revs[0]}`" for r in revs[1:])]
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    for case in results[revs[0]][0]:
        cells = [" / ".join(f"{run[case]:.1f}" for run in results[r]) for r in revs]
        base = min(run[case] for run in results[revs[0]])
        ratios = [f"{min(run[case] for run in results[r]) / base:.2f}×" for r in revs[1:]]
        lines.append("| " + " | ".join([case, *cells, *ratios]) + " |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("revisions", nargs="*", default=None)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--core", type=int, default=1)
    parser.add_argument("--out", default="bench-output")
    parser.add_argument("--smoke", action="store_true", help="the working tree, 8 lanes")
    parser.add_argument("--measure", metavar="JSON", help=argparse.SUPPRESS)
    opts = parser.parse_args(argv)
    if opts.measure:
        Path(opts.measure).write_text(json.dumps(measure(opts.smoke)))
        return None
    revs = opts.revisions or (["."] if opts.smoke else ["HEAD~1", "."])
    rounds = 1 if opts.smoke else opts.rounds
    core = opts.core if opts.core < (os.cpu_count() or 1) else None
    out_dir = Path(opts.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    results = {rev: [] for rev in revs}
    with tempfile.TemporaryDirectory() as scratch:
        trees = {rev: _worktree(rev, Path(scratch)) for rev in revs}
        try:
            for r in range(rounds):
                for i, rev in enumerate(revs):
                    out = Path(scratch) / f"{i}-{r}.json"
                    results[rev].append(_run_child(trees[rev], out, core, opts.smoke))
        finally:
            for rev, tree in trees.items():
                if rev != ".":
                    subprocess.run(["git", "-C", str(HERE.parent), "worktree", "remove",
                                    "--force", str(tree)], check=False, capture_output=True)
    (out_dir / "revisions.json").write_text(json.dumps(
        {"revisions": revs, "rounds": results, "core": core}, indent=1))
    table = render_md(revs, results)
    (out_dir / "revisions.md").write_text(table)
    print(table)
    return results


if __name__ == "__main__":
    main()
