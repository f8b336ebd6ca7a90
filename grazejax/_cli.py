"""The `grazejax` command line: `grazejax reproduce` and `grazejax bench`.

`main(argv)` returns the exit status (0 success, 1 failure while running, 2 bad usage:
unknown figure name, unwritable output folder) instead of raising, so that it can be
called in-process; the console script (`grazejax = grazejax._cli:main`) passes it to
`sys.exit`.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
from pathlib import Path

from ._compilation_cache import CACHE_ENV, enable_compilation_cache

BENCH_SCRIPT = Path("benchmarks") / "bench_suite.py"
BENCH_SCRIPTS = {
    "suite": "bench_suite.py",
    "core": "bench_core.py",
    "sweep": "bench_sweep.py",
    "gradients": "bench_gradients.py",
}


def _figure_help() -> str:
    from .paper import CLAIM_GROUPS
    from .paper.figures import FIGURES
    from .paper.reproduce import CLAIMS

    lines = []
    for name, spec in FIGURES.items():
        lines.append(f"  {name:<20} {spec.title} [paper: {spec.paper_figure}]")
    rows = sum(len(group.claims) for group in CLAIM_GROUPS.values())
    return (
        "figures:\n" + "\n".join(lines) + "\n\nother parts:\n"
        f"  {CLAIMS:<20} table of the paper's claims ({rows} rows): printed value, grazejax's "
        f"value, an\n  {'':<20} independent check and a verdict (about 2-3 minutes)"
    )


def _build_parser() -> argparse.ArgumentParser:
    from .paper.reproduce import DEFAULT_OUT

    parser = argparse.ArgumentParser(
        prog="grazejax",
        description="grazejax: differentiable simulation of impact systems with grazing.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    rep = sub.add_parser(
        "reproduce",
        help="recompute the paper's figures and write a report",
        description=(
            "Recompute the figures of Akhmet & Kivilcim, 'Discontinuous dynamics with\n"
            "grazing points', as PNG files, plus report.md and report.json (starts,\n"
            "impacts, final states, checks of the paper's printed values).\n\n"
            f"Output folder: ./{DEFAULT_OUT}/ in the current directory unless --out is given.\n"
            "All figures take about a minute on a laptop CPU, the claims table 2-3 more.\n\n"
            "Compiled programs are kept between runs in ~/.cache/grazejax/jax (JAX's\n"
            f"persistent compilation cache): set {CACHE_ENV} to another folder, or to\n"
            "'off' to compile afresh."
        ),
        epilog=_figure_help()
        + "\n\nAn example name (orbex2, exnonaxial, ex1dof, smalldisc) selects all its figures."
        + "\nWithout --only: every figure and the claims table.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    rep.add_argument(
        "--out", metavar="DIR", default=None,
        help="output folder, created if needed (default: ./grazejax-output/ in the current "
             "directory)",
    )
    rep.add_argument(
        "--only", metavar="NAME", nargs="+", action="extend", default=None,
        help="only these parts (figure names, example names, or 'claims'; repeatable)",
    )
    rep.add_argument("--list", action="store_true",
                     help="list the figure names and the claims part, and exit")
    rep.add_argument("--quiet", action="store_true", help="no progress lines")
    rep.set_defaults(subparser=rep)

    bench = sub.add_parser(
        "bench",
        help="run the benchmark suite (source checkout only)",
        description=(
            f"Run the benchmark suite ({BENCH_SCRIPT}) from the grazejax source checkout:\n"
            "work-precision against SciPy and heyoka, the cost of grazing and of each effect,\n"
            "compile times and scaling. It writes suite.json, CSV files, PNG plots, summary.md\n"
            "and headline.md into the output folder. The benchmarks are not installed with the\n"
            "package. The peers come with the `bench` extra (pip install -e '.[bench]'); the\n"
            "suite runs with whichever are installed (it needs mpmath) and says which it skips.\n\n"
            "--quick takes under 2 minutes on a 2-core CPU, the full run about 8 minutes.\n"
            "Arguments after `--` go to the script unchanged (e.g. `-- --only grazing`)."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    bench.add_argument("--quick", action="store_true",
                       help="fewer tolerances, solvers, repeats and sizes (< 2 minutes)")
    bench.add_argument("--out", metavar="DIR", default=None,
                       help="output folder (default: bench-output/ in the source checkout)")
    bench.add_argument("--script", choices=sorted(BENCH_SCRIPTS), default="suite",
                       help="which benchmark to run: the suite (default), the older "
                            "bench_core.py / bench_sweep.py, or bench_gradients.py (reverse "
                            "mode's cost; writes benchmarks/results/ unless --out)")
    bench.add_argument("--smoke", action="store_true", help=argparse.SUPPRESS)  # for the tests
    bench.add_argument("bench_args", nargs=argparse.REMAINDER, help="arguments for the script")
    return parser


def _find_bench_script() -> Path | None:
    here = Path(__file__).resolve().parent.parent  # the folder holding the package
    for root in (here, Path.cwd()):
        candidate = root / BENCH_SCRIPT
        if candidate.is_file():
            return candidate
    return None


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ImportError:  # a parent package that fails to import, or an import blocker
        return False


# What the benchmark scripts import beyond grazejax. The suite needs only mpmath (its
# closed-form ground truths): it skips the peers that are missing (SciPy, heyoka), says so
# in one line, and replaces heyoka's long-double ex1dof reference by SciPy at rtol 1e-13.
# The older scripts (core, sweep, gradients) still need every peer.
BENCH_MODULES = ("scipy", "mpmath", "heyoka")
SUITE_MODULES = ("mpmath",)
BENCH_INSTALL = 'pip install -e ".[bench]"'


def _missing_bench_modules(script: str) -> list[str]:
    needed = SUITE_MODULES if script == "suite" else BENCH_MODULES
    return [m for m in needed if not _installed(m)]


def _bench(ns) -> int:
    script = _find_bench_script()
    if script is None:
        print(
            f"grazejax bench: {BENCH_SCRIPT} not found. The benchmarks live in the grazejax "
            "source checkout (they are not installed with the package): clone the repository "
            "and run `grazejax bench` (or `python benchmarks/bench_suite.py`) from its root.",
            file=sys.stderr,
        )
        return 1
    missing = _missing_bench_modules(ns.script)
    if missing:
        what = ("The suite's ground truths are closed forms in mpmath" if ns.script == "suite"
                else f"bench_{ns.script}.py compares grazejax with SciPy and heyoka (which also "
                     "computes its ground truth); only the suite runs without them")
        print(
            f"grazejax bench: {', '.join(missing)} not installed. {what}: install them with "
            f"`{BENCH_INSTALL}` from the source checkout, then run `grazejax bench` again.",
            file=sys.stderr,
        )
        return 1
    script = script.parent / BENCH_SCRIPTS[ns.script]
    args = []
    if ns.quick:
        args.append("--quick")
    if ns.smoke:
        args.append("--smoke")
    if ns.out is not None:  # relative to where the command was typed, not to the checkout
        args += ["--out", str(Path(ns.out).resolve())]
    args += [a for a in ns.bench_args if a != "--"]
    return subprocess.call([sys.executable, str(script), *args], cwd=script.parent.parent)


def _reproduce(ns, parser) -> int:
    from .paper import reproduce as rp

    if ns.list:
        print(_figure_help())
        return 0
    from ._memory import retain_freed_memory

    # A second run loads its simulators instead of compiling them again (compiling is most
    # of a short run's time); $GRAZEJAX_COMPILATION_CACHE moves the folder or turns it off.
    # Not for `grazejax bench`: it measures cold compile times.
    enable_compilation_cache()
    retain_freed_memory()  # its own process: no fresh pages for each run's results
    try:
        names = rp.resolve_names(ns.only)
        out = rp.prepare_output(ns.out if ns.out is not None else rp.DEFAULT_OUT)
    except rp.ReproduceError as error:
        parser.print_usage(sys.stderr)
        print(f"grazejax reproduce: error: {error}", file=sys.stderr)
        return 2
    report = rp.reproduce(out, names, progress=None if ns.quiet else _say)
    failed = [n for n, fig in report["figures"].items() if "error" in fig]
    if failed:
        print(f"grazejax reproduce: {len(failed)} figure(s) failed: {', '.join(failed)}",
              file=sys.stderr)
    errors = [r["id"] for r in report.get("claims", {}).get("rows", []) if r["verdict"] == "error"]
    if errors:
        print(f"grazejax reproduce: {len(errors)} claim(s) could not be computed: "
              f"{', '.join(errors)}", file=sys.stderr)
    stale = report.get("claims", {}).get("summary", {}).get("reasons_inconsistent")
    if stale:  # the numbers changed a verdict: the typed-in reason needs a look
        print(f"grazejax reproduce: the typed-in reason does not fit the computed verdict in "
              f"{', '.join(stale)}", file=sys.stderr)
    return 1 if failed or errors else 0


def _say(message: str) -> None:
    print(message, flush=True)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `grazejax` command. Returns the exit status."""
    parser = _build_parser()
    try:
        ns = parser.parse_args(argv)
    except SystemExit as exit_:  # argparse: --help (0) or a usage error (2)
        return exit_.code if isinstance(exit_.code, int) else 0
    if ns.command == "reproduce":
        return _reproduce(ns, ns.subparser)
    if ns.command == "bench":
        return _bench(ns)
    parser.print_help()
    return 2


if __name__ == "__main__":
    sys.exit(main())
