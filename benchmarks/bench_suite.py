"""Benchmark suite: what accuracy costs in time, side by side with SciPy and heyoka.

    python benchmarks/bench_suite.py [--quick] [--out DIR]      (or: grazejax bench [--quick])

Writes into DIR (default bench-output/):

- `suite.json`: every number (each plotted point is a row there), the cases, how each
  ground truth was obtained, the machine and package versions;
- CSV files, one per table (`work_precision.csv`, `grazing.csv`, `effects.csv`,
  `compile.csv`, `scaling_impacts.csv`, `scaling_batch.csv`, `floquet.csv` if run);
- PNG plots: `wp_<case>.png` (work-precision: error vs wall time, vs right-hand-side
  evaluations, vs tolerance), `grazing.png`, `effects.png`, `scaling.png`, `headline.png`;
- `summary.md` (all tables and findings) and `headline.md` (the table for the README).

Sections (see benchmarks/README.md for the methods):

1. work-precision on five problems with known answers (closed forms in 40-digit mpmath,
   or heyoka in long double), grazejax Tsit5/Dopri5/Dopri8 (Kvaerno5 on the stiff case)
   vs SciPy solve_ivp (RK45, DOP853; Radau, LSODA) and heyoka, tolerances 1e-3…1e-13;
2. the cost of grazing: one impact of depth δ → 0 (the √δ loss of impact-time accuracy,
   missed impacts, steps);
3. the cost of each effect (impact log, dense output, Jacobian, batch, an unused surface),
   as ratios to a final-state-only run, and what unrequested options cost (HLO size);
4. compile times of the public entry points;
5. scaling with the number of impacts and the batch size (fitted exponents);
6. Floquet multipliers, if `grazejax.find_periodic_orbit` exists;
7. the headline plot and table.

One process, one thing at a time. `--quick` (< 2 minutes on a shared 2-core machine) runs
fewer tolerances, solvers, repeats and sizes; the full run about 8 minutes.
Timings come from a shared 2-core CPU machine unless stated otherwise: read ratios.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import _cases as C  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from _cases import log  # noqa: E402
from suite.common import (  # noqa: E402
    HAVE_HEYOKA,
    HAVE_SCIPY,
    HEADLINE_CASE,
    extra_versions,
    settings,
)
from suite.compile_times import section_compile  # noqa: E402
from suite.effects import section_effects  # noqa: E402
from suite.floquet import section_floquet  # noqa: E402
from suite.grazing import section_grazing  # noqa: E402
from suite.plots import (  # noqa: E402
    plot_effects,
    plot_floquet,
    plot_grazing,
    plot_headline,
    plot_scaling,
    plot_wp,
)
from suite.report import findings, headline_table, write_outputs  # noqa: E402
from suite.scaling import section_scaling  # noqa: E402
from suite.work_precision import section_work_precision  # noqa: E402

import grazejax as gj  # noqa: E402


def parse_args(argv):
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--quick", action="store_true", help="fewer tolerances, solvers, repeats (< 2 min)"
    )
    ap.add_argument("--smoke", action="store_true", help=argparse.SUPPRESS)  # tests: one tiny case
    ap.add_argument("--out", default="bench-output", help="output folder (default bench-output/)")
    ap.add_argument(
        "--only",
        nargs="+",
        default=None,
        choices=["work_precision", "grazing", "effects", "compile", "scaling", "floquet"],
        help="run only these sections",
    )
    return ap.parse_args(argv)


def new_results(mode, S, sections):
    """The result record before any section has run: mode, machine, versions, settings."""
    return {
        "mode": mode,
        "machine": C.machine(),
        "versions": extra_versions(),
        "note": C.SHARED_MACHINE_NOTE,
        "settings": {k: v for k, v in S.items()},
        "sections": list(sections),
        "have_heyoka": HAVE_HEYOKA,
        "have_scipy": HAVE_SCIPY,
        "missing_peers": C.missing_peers_line(),
        "api": {
            n: hasattr(gj, n)
            for n in (
                "flow_jacobian",
                "find_periodic_orbit",
                "floquet_multipliers",
                "continue_orbit",
            )
        },
    }


def run_sections(cases, S, res, sections):
    """Each requested section in order, its wall time in res["section_wall_s"]."""
    effects_rows = None
    walls = res["section_wall_s"] = {}

    def run_section(name, fn):
        t = time.perf_counter()
        out = fn()
        walls[name] = time.perf_counter() - t
        log(f"   [{name}: {walls[name]:.0f} s]")
        return out

    if "work_precision" in sections:
        run_section("work_precision", lambda: section_work_precision(cases, S, res))
    if "grazing" in sections:
        run_section("grazing", lambda: section_grazing(cases, S, res))
    if "effects" in sections:
        effects_rows = run_section("effects", lambda: section_effects(cases, S, res))
    if "compile" in sections:
        run_section("compile", lambda: section_compile(cases, S, res, effects_rows))
    if "scaling" in sections:
        run_section("scaling", lambda: section_scaling(cases, S, res))
    if "floquet" in sections:
        run_section("floquet", lambda: section_floquet(cases, S, res))


def write_plots(res, out):
    """The PNG plots of the sections that ran, and the headline table (headline.md)."""
    log("plots")
    if "work_precision" in res:
        rows = res["work_precision"]["rows"]
        for name, ci in res["work_precision"]["cases"].items():
            plot_wp(name, ci, rows, os.path.join(out, f"wp_{name}.png"))
        if HEADLINE_CASE in res["work_precision"]["cases"]:
            plot_headline(
                rows,
                res["work_precision"]["cases"][HEADLINE_CASE],
                os.path.join(out, "headline.png"),
            )
            res["headline"], res["headline_md"] = headline_table(res)
            with open(os.path.join(out, "headline.md"), "w") as fh:
                fh.write(res["headline_md"] + "\n![headline](headline.png)\n")
    if "grazing" in res:
        plot_grazing(res["grazing"], os.path.join(out, "grazing.png"))
    if "effects" in res:
        plot_effects(res["effects"], os.path.join(out, "effects.png"))
    if "scaling" in res:
        plot_scaling(res["scaling"], os.path.join(out, "scaling.png"))
    if res.get("floquet", {}).get("rows"):
        plot_floquet(res["floquet"], os.path.join(out, "floquet.png"))


def main(argv=None):
    opts = parse_args(argv)
    mode = "smoke" if opts.smoke else ("quick" if opts.quick else "full")
    S = settings(mode)
    sections = tuple(opts.only) if opts.only else S["sections"]
    os.makedirs(opts.out, exist_ok=True)
    if C.missing_peers_line():
        log(C.missing_peers_line())
    t_start = time.perf_counter()
    res = new_results(mode, S, sections)
    jnp.ones(3).block_until_ready()
    jax.jit(lambda x: x + 1)(1.0).block_until_ready()
    cases = C.make_cases(include_ball="ball" in S["cases"])
    run_sections(cases, S, res, sections)
    write_plots(res, opts.out)
    res["machine"]["loadavg_end"] = list(os.getloadavg())
    res["total_wall_s"] = time.perf_counter() - t_start
    res["findings"] = findings(res)
    write_outputs(res, opts.out)
    log(
        f"wrote {opts.out}/suite.json, summary.md, CSV and PNG files in {res['total_wall_s']:.0f} s ({mode} mode)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
