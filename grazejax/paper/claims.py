"""The claims table: every group of claims, and `compute_claims`, which runs them."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

from . import (
    claims_conditions,
    claims_ex1dof,
    claims_exnonaxial,
    claims_grazing,
    claims_orbex2,
    claims_smalldisc,
)
from .table import CLAIM_TOL, ClaimGroup, claim_row

# In the order they run and are reported: by example, cheapest first within an example.
CLAIM_GROUPS: dict[str, ClaimGroup] = {
    group.name: group
    for group in (
        claims_orbex2.claims_orbex2_psi,
        claims_orbex2.claims_orbex2_corrected,
        claims_grazing.claims_orbex2_grazing,
        claims_grazing.claims_exnonaxial_grazing,
        claims_grazing.claims_ex1dof_grazing,
        claims_exnonaxial.claims_exnonaxial,
        claims_ex1dof.claims_ex1dof_continuous,
        claims_ex1dof.claims_ex1dof_branches,
        claims_ex1dof.claims_ex1dof_impacting,
        claims_ex1dof.claims_ex1dof_bifurcation,
        claims_conditions.claims_conditions,
        claims_smalldisc.claims_smalldisc,
    )
}


def compute_claims(groups: Sequence[str] | None = None, *, context: dict | None = None,
                   progress: Callable[[str], None] | None = None) -> dict:
    """Compute the claims table: one row per claim of the paper (the fields of a
    row: [the paper audit](audit.md)).

    `groups`: names from `CLAIM_GROUPS` (default: all). `context`: results shared with the
    figures (e.g. `"figure:ex1dof-bifurcation"`: that figure's checks). A group that raises
    gives one error row per claim it checks. Returns `{"rows", "seconds", "tolerance",
    "summary"}`.
    """
    say = progress or (lambda _msg: None)
    names = list(CLAIM_GROUPS) if not groups else list(groups)
    ctx = dict(context or {})
    rows, timings = [], {}
    start = time.perf_counter()
    for k, name in enumerate(names, 1):
        group = CLAIM_GROUPS[name]
        say(f"[claims {k}/{len(names)}] {name}: {len(group.claims)} claim(s)")
        t0 = time.perf_counter()
        try:
            new = group.make(ctx)
        except Exception as error:  # noqa: BLE001 - one failing group must not stop the rest
            message = f"{type(error).__name__}: {error}"
            new = [claim_row(cid, group.example, cid, paper="", grazejax="", check="",
                          check_method="", difference=None, tolerance=None, verdict="error",
                          reason=message, error=message) for cid in group.claims]
            say(f"      FAILED: {message}")
        seconds = time.perf_counter() - t0
        timings[name] = seconds
        for row in new:
            row["group"] = name
        rows += new
        # Only what needs a look, per group: how many printed values differ is expected
        # (the paper's own numbers are often wrong) and is said once, by `claims_tally`.
        bad = sum(r["consistent"] is False for r in new)
        stale = [r["id"] for r in new if not r["reason_consistent"]]
        if not any(r["verdict"] == "error" for r in new):
            say(f"      done in {seconds:.1f} s"
                + (f"; {bad} check(s) NOT consistent" if bad else "")
                + (f"; reason does not fit the computed verdict in {', '.join(stale)}"
                   if stale else ""))
    summary = {
        "rows": len(rows),
        "agrees": sum(r["verdict"] == "agrees" for r in rows),
        "differs": sum(r["verdict"] == "differs" for r in rows),
        "errors": sum(r["verdict"] == "error" for r in rows),
        "checks_consistent": sum(r["consistent"] is True for r in rows),
        "checks_inconsistent": sum(r["consistent"] is False for r in rows),
        "reasons_inconsistent": [r["id"] for r in rows if not r["reason_consistent"]],
    }
    return {"rows": rows, "seconds": time.perf_counter() - start, "group_seconds": timings,
            "tolerance": dict(CLAIM_TOL), "summary": summary}

