"""The report of `grazejax reproduce`: report.json (every number) and report.md (the same,
to read: the claims table, then each figure with its findings, runs and checks)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .table import fact_text


def write_report(out: Path, report: dict) -> None:
    """Write `out/report.json` and `out/report.md`."""
    (out / "report.json").write_text(json.dumps(report, indent=2, default=_json_default,
                                                ensure_ascii=False) + "\n")
    (out / "report.md").write_text(_markdown(report))


def claims_tally(summary: dict) -> str:
    """The claims table in one line, the last one `grazejax reproduce` prints: claims
    checked, independent checks that agree with grazejax, and printed values that differ
    from the computed ones (expected: `reason` explains each row's difference).

    `summary`: `compute_claims(...)["summary"]`.
    """
    s = summary
    checked = s["rows"] - s["errors"]
    no_check = checked - s["checks_consistent"] - s["checks_inconsistent"]
    text = (f"claims: {checked} checked; an independent check agrees with grazejax's value "
            f"in {s['checks_consistent']}")
    if s["checks_inconsistent"]:
        text += f", NOT in {s['checks_inconsistent']}"
    if no_check:
        text += f" ({no_check} without one)"
    text += f"; {s['differs']} differ from the value printed in the paper"
    if s["differs"]:
        text += (" (expected: many of the paper's printed numbers are wrong or approximate; "
                 "report.md gives the reason for each)")
    if s["errors"]:
        text += f"; {s['errors']} could not be computed"
    if s.get("reasons_inconsistent"):
        text += ("; the typed-in reason does not fit the computed verdict in "
                 + ", ".join(s["reasons_inconsistent"]))
    return text + "."


def _md_cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def claims_markdown(claims: dict) -> list[str]:
    s = claims["summary"]
    lines = [
        "## Claims of the paper, checked",
        "",
        f"{s['rows']} claims: {s['agrees']} agree with the paper, {s['differs']} differ, "
        f"{s['errors']} could not be computed. grazejax's value and the independent check "
        f"agree within tolerance in {s['checks_consistent']} rows"
        + (f", **not in {s['checks_inconsistent']}**" if s["checks_inconsistent"] else "")
        + (f"; **the typed-in reason does not fit the computed verdict in "
           f"{', '.join(s['reasons_inconsistent'])}**" if s.get("reasons_inconsistent") else "")
        + f". Solver tolerance rtol = {claims['tolerance']['rtol']:g}, "
        f"atol = {claims['tolerance']['atol']:g}. Time: {claims['seconds']:.1f} s.",
        "",
        "Only the column **paper (printed)** is typed in from the paper; the others are "
        "computed at run time. *check*: an independent computation in the report code "
        "(closed form, SciPy, the paper's own formula); ✓ = it agrees with grazejax within "
        "the tolerance in report.json. The verdict is computed: a claim agrees iff every "
        "printed fact it makes agrees with grazejax's value (numbers: max |printed − "
        "computed| over the entries ≤ the tolerance, half a unit in the last printed digit "
        "or, for values printed exactly, a multiple of rtol; counts, types, yes/no: equal). "
        "Reasons (shown where it differs): typo, first-order approximation, "
        "inconsistent formula, different convention, ambiguity (with our reading).",
        "",
        "| # | claim | paper (printed) | grazejax | independent check | verdict |",
        "|---|---|---|---|---|---|",
    ]
    for row in claims["rows"]:
        if row["verdict"] == "error":
            lines.append(f"| {row['id']} | | | **error** | | **error**: {_md_cell(row['reason'])} |")
            continue
        mark = {True: " ✓", False: " ✗ (check disagrees)", None: ""}[row["consistent"]]
        verdict = f"**{row['verdict']}**" + (f": {row['reason']}" if row["reason"] else "")
        if row.get("facts"):
            verdict += " <br>" + "; ".join(fact_text(f) for f in row["facts"])
        extra = []
        if row.get("note"):
            extra.append(f"note: {row['note']}")
        if row.get("paper_formula"):
            extra.append(f"paper's formula evaluated: {row['paper_formula']}")
        paper = _md_cell(row["paper"]) + (f" <br>*[{_md_cell(row['source'])}]*" if row["source"] else "")
        lines.append(
            f"| {row['id']} | {_md_cell(row['claim'])} | {paper} | "
            f"{_md_cell(row['grazejax'])} | {_md_cell(row['check'])}{mark} "
            f"<br>*{_md_cell(row['check_method'])}* | {_md_cell(verdict)}"
            + (f" <br>{_md_cell('; '.join(extra))}" if extra else "") + " |"
        )
    return lines + [""]



def _json_default(obj):
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    return str(obj)


def _fmt(value) -> str:
    if isinstance(value, float):
        return f"{value:.10g}"
    if isinstance(value, list | tuple) and value and all(isinstance(v, float) for v in value):
        return "(" + ", ".join(f"{v:.8g}" for v in value) + ")"
    if isinstance(value, dict):
        return "; ".join(f"{k}: {_fmt(v)}" for k, v in value.items())
    return str(value)


def _markdown(report: dict) -> str:
    lines = [
        "# grazejax reproduction report",
        "",
        "Figures and claims of Akhmet & Kıvılcım, *Discontinuous dynamics with grazing points*, "
        "recomputed with grazejax. Every number below is computed at run time, except those "
        "under **Printed in the paper** and in the column **paper (printed)**.",
        "",
        f"- grazejax {report['grazejax_version']}, jax {report['jax_version']}, "
        f"Python {report['python']}, {report['created_utc']}",
        f"- total wall time: {report['wall_seconds']:.1f} s",
        "",
    ]
    if "claims" in report:
        lines += claims_markdown(report["claims"])
    for name, fig in report["figures"].items():
        lines += [f"## {name}: {fig['title']}", ""]
        if "error" in fig:
            lines += [f"**Failed:** `{fig['error']}`", ""]
            continue
        lines += [f"Paper figure: `{fig['paper_figure']}`. Time: {fig['seconds']:.1f} s.", "",
                  f"![{name}]({fig['file']})", ""]
        if fig.get("args"):
            lines += ["Parameters: " + ", ".join(f"{k} = {_fmt(v)}" for k, v in fig["args"].items()), ""]
        if fig.get("findings"):
            lines += ["**Findings (computed):**", ""] + [f"- {f}" for f in fig["findings"]] + [""]
        if fig.get("runs"):
            lines += ["| run | status | t_final | impacts | kinds | final state |",
                      "|---|---|---|---|---|---|"]
            for r in fig["runs"]:
                kinds = ", ".join(f"{k} {v}" for k, v in r["impact_kinds"].items()) or "-"
                lines.append(
                    f"| {r['label']} | {r['status']} | {r['t_final']:.6g} | {r['num_impacts']} "
                    f"| {kinds} | {_fmt(r['final_state'])} |"
                )
            lines.append("")
        if fig.get("checks"):
            lines += ["**Checks:**", ""]
            for k, v in fig["checks"].items():
                if isinstance(v, dict) and any(isinstance(x, dict) for x in v.values()):
                    lines.append(f"- {k}:")
                    lines += [f"  - {k2}: {_fmt(v2)}" for k2, v2 in v.items()]
                else:
                    lines.append(f"- {k}: {_fmt(v)}")
            lines.append("")
        if fig.get("paper"):
            lines += ["**Printed in the paper:**", ""]
            lines += [f"- {k}: {_fmt(v)}" for k, v in fig["paper"].items()] + [""]
    return "\n".join(lines) + "\n"

