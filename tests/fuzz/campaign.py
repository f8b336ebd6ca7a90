"""The fuzz campaign from the command line: `python -m tests.fuzz.campaign --systems N --seed S`.

Prints the counts table (markdown: systems, agreeing, disagreements by class, per family ×
solver and per solver) and the grazejax defects found, with one reproducer line each.
"""

import argparse
import json
import os
import tempfile
import time
from pathlib import Path

_CACHE = Path(tempfile.gettempdir()) / f"grazejax-tests-xla-cache-{os.getuid()}"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_CACHE))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--systems", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--solvers-per-family",
        type=int,
        default=None,
        help="solvers per family (default: all four)",
    )
    parser.add_argument("--families", default=None, help="comma-separated family names")
    parser.add_argument("--tol", type=float, default=None, help="grazejax rtol = atol")
    parser.add_argument("--reproducers", action="store_true", help="print defects' systems")
    opts = parser.parse_args(argv)

    import jax

    jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    from . import compare as C

    pairs = C.plan(opts.solvers_per_family)
    if opts.families:
        wanted = opts.families.split(",")
        pairs = [p for p in pairs if p[0] in wanted]
    lanes = max(1, -(-opts.systems // len(pairs)))
    start = time.perf_counter()

    def progress(name, solver, recs):
        bad = sum(r.outcome != "agree" for r in recs)
        print(
            f"  [{time.perf_counter() - start:6.0f} s] {name:14s} {solver:7s} "
            f"{len(recs)} systems, {bad} disagreements",
            flush=True,
        )

    records = C.campaign(pairs, lanes, opts.seed, tol=opts.tol or C.BASE_TOL, progress=progress)
    print(
        f"\n{len(records)} systems, seed {opts.seed}, grazejax rtol = atol = "
        f"{opts.tol or C.BASE_TOL:g}, {time.perf_counter() - start:.0f} s\n"
    )
    print(C.table(records))
    found = C.defects(records)
    if found:
        print(f"\n{len(found)} grazejax defect(s):")
        for rec in found:
            print(
                f"- {rec.family} / {rec.solver} / lane {rec.lane} (seed {opts.seed}): "
                + "; ".join(rec.reasons)
            )
        if opts.reproducers:
            print("\nreproducers (family, solver, system as JSON):")
            for rec in found:
                print(json.dumps({"family": rec.family, "solver": rec.solver, **rec.system}))
    others = [r for r in records if r.outcome not in ("agree", "grazejax defect")]
    if others:
        print("\nother disagreements:")
        for rec in others:
            print(
                f"- {rec.outcome}: {rec.family} / {rec.solver} / lane {rec.lane}: "
                + "; ".join(rec.reasons[:3])
            )


if __name__ == "__main__":
    main()
