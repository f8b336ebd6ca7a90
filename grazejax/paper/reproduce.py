"""`grazejax reproduce`: recompute the figures of the seed paper and its claims table,
with a report.

Akhmet & Kıvılcım, *Discontinuous dynamics with grazing points* (the LaTeX labels of its
figures are given as `paper_figure`). Each figure has one function (`FIGURES`): it simulates
what the paper's caption describes, draws a PNG, and returns a dict of the numbers it
computed (starts, impacts, final states, checks). `reproduce` runs the selected figures and
the claims table (`compute_claims`) and writes `report.md` and `report.json` next to the
PNGs.

Conventions of the report:

- Values printed in the paper are kept under the key `paper` (or said to be "printed in
  the paper"); every other number is computed by this code at run time. Nothing computed
  is typed in by hand.
- Our readings of ambiguous equations are those of docs/design.md (*The paper's examples*)
  and `grazejax.examples`.
- Horizons are chosen to show the approach within a few minutes on two CPU cores (the long
  runs of `ex1dof`: `grazejax.paper.runs`).
"""

from __future__ import annotations

import datetime
import os
import platform
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax

from .claims import compute_claims
from .figures import FIGURES
from .report import claims_tally, write_report

DEFAULT_OUT = "grazejax-output"
CLAIMS = "claims"  # the name that selects the claims table (`--only claims`)


class ReproduceError(ValueError):
    """Bad input to `reproduce` (unknown figure name, unusable output folder)."""


def figure_names() -> list[str]:
    return list(FIGURES)


def resolve_names(names: Sequence[str] | None) -> list[str]:
    """Parts selected by `names`: figure names, scene names (all their figures) and
    `"claims"` (the claims table). None or empty: every figure and the claims table."""
    if not names:
        return [*figure_names(), CLAIMS]
    scenes = sorted({spec.scene for spec in FIGURES.values()})
    chosen, unknown = [], []
    for name in names:
        if name in FIGURES or name == CLAIMS:
            hits = [name]
        else:
            hits = [f for f, spec in FIGURES.items() if spec.scene == name]
        if not hits:
            unknown.append(name)
        chosen += [h for h in hits if h not in chosen]
    if unknown:
        raise ReproduceError(
            f"unknown figure or example name(s): {', '.join(repr(u) for u in unknown)}. "
            f"Valid figure names: {', '.join(FIGURES)}. "
            f"Valid example names (select all their figures): {', '.join(scenes)}. "
            f"'{CLAIMS}' selects the table of the paper's claims."
        )
    return [f for f in FIGURES if f in chosen] + ([CLAIMS] if CLAIMS in chosen else [])


def prepare_output(out_dir) -> Path:
    """Create `out_dir` if needed and check that files can be written there."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".grazejax-write-test-{os.getpid()}"
        probe.write_text("ok")
        probe.unlink()
    except OSError as error:
        reason = error.strerror or str(error)
        raise ReproduceError(f"cannot write to output folder '{out}': {reason}") from None
    return out


def reproduce(out_dir=DEFAULT_OUT, only: Sequence[str] | None = None,
              progress: Callable[[str], None] | None = print) -> dict:
    """Recompute the selected figures (and the claims table) into `out_dir`; write
    report.md and report.json.

    `only`: figure names, example names, or `"claims"` (default: all figures and the
    claims table, see `compute_claims`). Returns the report dict. Raises `ReproduceError`
    for an unknown name or an unwritable folder (before any work).
    """
    from .. import __version__

    names = resolve_names(only)
    out = prepare_output(out_dir)
    say = progress or (lambda _msg: None)
    start = time.perf_counter()
    figures = {}
    figure_list = [n for n in names if n in FIGURES]
    for k, name in enumerate(figure_list, 1):
        spec = FIGURES[name]
        say(f"[{k}/{len(figure_list)}] {name}: {spec.title}")
        t0 = time.perf_counter()
        try:
            result = spec.make(out)
        except Exception as error:  # noqa: BLE001 - one failing figure must not stop the rest
            result = {"error": f"{type(error).__name__}: {error}"}
            say(f"      FAILED: {result['error']}")
        seconds = time.perf_counter() - t0
        figures[name] = {"title": spec.title, "scene": spec.scene,
                         "paper_figure": spec.paper_figure, "seconds": seconds, **result}
        if "error" not in result:
            say(f"      done in {seconds:.1f} s -> {out / result['file']}")
    claims = None
    if CLAIMS in names:
        context = {}
        brute = figures.get("ex1dof-bifurcation", {})
        if "checks" in brute:
            context["figure:ex1dof-bifurcation"] = brute["checks"]
        claims = compute_claims(context=context, progress=say)
        say(f"      claims: {claims['seconds']:.1f} s")
    report = {
        "grazejax_version": __version__,
        "jax_version": jax.__version__,
        "python": platform.python_version(),
        "created_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M:%S UTC"),
        "wall_seconds": time.perf_counter() - start,
        "out_dir": str(out),
        "figures": figures,
    }
    if claims is not None:
        report["claims"] = claims
    write_report(out, report)
    say(f"report: {out / 'report.md'} and {out / 'report.json'} "
        f"({report['wall_seconds']:.1f} s)")
    if claims is not None:
        say(claims_tally(claims["summary"]))
    return report
