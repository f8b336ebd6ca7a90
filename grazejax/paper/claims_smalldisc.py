"""The claim of smalldisc: orbits approach a periodic solution near Ψ (Fig. figsmall)."""

from __future__ import annotations

import math

import numpy as np

from .. import plot
from .runs import SHORT, as_float, paper_args, run_batch
from .table import (
    PRINTED,
    RTOL,
    claim_group,
    claim_row,
    fact,
)


@claim_group("smalldisc", "smalldisc", "smalldisc.cycle")
def claims_smalldisc(ctx: dict) -> list[dict]:
    mu = 0.05
    args = paper_args("smalldisc", mu)
    sol = run_batch("smalldisc", SHORT, [(0.0, 1.2)], args, 60.0)
    log = plot.impacts_of(plot.lane(sol, 0))
    speeds = np.abs(log["pre"][log["surface"] == 1, 1])
    ratio = float(speeds[-1] / speeds[-2])
    n1 = int((log["surface"] == 0).sum())
    last1 = float(log["times"][log["surface"] == 0][-1]) if n1 else float("nan")
    a, R2, v_ref = as_float(args["a"]), as_float(args["R2"]), as_float(args["v_ref"])
    omega = math.sqrt(1 - a * a / 4)
    # Γ2 law x2 → −(R2 + μ(x2 − v_ref))x2 at x2 = −v, then half a turn of the damped flow.
    v = float(speeds[-2])
    expected = (R2 - mu * (v + v_ref)) * math.exp(-a * math.pi / (2 * omega))
    return [claim_row(
        "smalldisc.cycle", "smalldisc",
        "μ = 0.05: trajectories from (0, 1.2) and (0, 1.5) approach a periodic solution near Ψ",
        source="Fig. figsmall", paper="approach the periodic solution",
        grazejax=f"from (0, 1.2), t ≤ 60: {n1} Γ1 impact(s) (the last at t = {last1:.3f}), "
                 f"{len(speeds)} Γ2 impacts; the Γ2 impact speed shrinks by {ratio:.6f} per "
                 "turn: the orbit spirals into the origin",
        check=f"(R2 − μ(v + e^{{0.001π/2}}))·e^{{−aπ/(2ω)}} at the last impacts = {expected:.6f}",
        check_method="closed form of the Γ2 law and the damped flow between Γ2 impacts",
        difference=abs(ratio - expected), tolerance=1e3 * RTOL,
        facts=[fact("a periodic orbit near Ψ (Γ2 speed ratio 1)", PRINTED["smalldisc_cycle"],
                     bool(abs(ratio - 1) <= 1e3 * RTOL))],
        reason="inconsistent parameters (as for orbex2): with the printed (and our reading of "
               "the unbalanced) Γ2 law the impact factor R2 − μ(v + e^{0.0005π}) < 1, so no "
               "cycle near Ψ; the paper's monodromies (monodromy11, monodromy111) cannot be "
               "checked without a cycle",
    )]

