"""The rows of the claims table: the values printed in the paper, facts and verdicts.

One row per numeric or qualitative claim of the paper. Each row holds:

- `paper`: the value as printed (the only numbers typed in from the paper, kept in
  `PRINTED`; a printed formula such as 0.001 − 1.8·e^{0.00025π} is evaluated as printed);
- `grazejax`: the value computed at run time by grazejax's public functions;
- `check`: the same quantity computed independently in the claims modules (a closed form,
  SciPy's solve_ivp, the paper's own formula evaluated) and `consistent`: whether the two
  agree to a tolerance tied to the solver tolerance (`difference` ≤ `tolerance`);
- `facts` (`fact`): each printed fact of the claim next to grazejax's computed value;
- `verdict`: "agrees" or "differs" with the paper, computed from `facts` (`claim_verdict`:
  numbers agree iff max |printed − computed| ≤ tolerance, the printed precision or a
  multiple of rtol; structural facts iff equal), and `reason` (typo, first-order
  approximation, inconsistent formula, different convention, ambiguity + our reading),
  typed in, shown only when the row differs (`reason_consistent` flags a mismatch);
- optionally `paper_formula` (the paper's own formula or system, evaluated: where its
  printed number comes from, or that it does not) and `corrected` (what the theory
  predicts once the parameters that make the claim false are corrected).

A group of rows that raises becomes error rows (verdict "error"), never a crash.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

CLAIM_TOL = {"rtol": 1e-10, "atol": 1e-12}  # one tolerance: each compiled program once
RTOL = CLAIM_TOL["rtol"]
SQRT_HALF = 1 / math.sqrt(2)
C_ORBEX2 = math.exp(0.00025 * math.pi)  # the wall position y1 = e^{0.00025π}, as printed

# Values printed in the paper (LaTeX labels in brackets). Nothing else is typed in.
PRINTED = {
    "orbex2_Wx": np.array([[-1.0, 0.0], [0.001 - 1.8 * C_ORBEX2, 0.0]]),  # derW_8
    "orbex2_B2": np.array([[math.exp(-0.0005 * math.pi), 0.0], [0.001, 0.0]]),  # B_2, Ex. linear
    "orbex2_rho": (1.0, 0.8551, 1.0, 0.0),  # ρ1⁽¹⁾, ρ2⁽¹⁾, ρ1⁽²⁾, ρ2⁽²⁾ [Example ex1]
    "exnonaxial_Wx": np.array([[(-math.sqrt(2) + 0.22) / (2 * math.sqrt(2)),
                                (math.sqrt(2) + 0.22) / (2 * math.sqrt(2))],
                               [(math.sqrt(2) + 0.22) / (2 * math.sqrt(2)),
                                (-math.sqrt(2) + 0.22) / (2 * math.sqrt(2))]]),  # derW_555
    "exnonaxial_point": (0.5, 0.5),  # x* as printed
    "exnonaxial_rho": (1.0, 1.0, 1.0, -0.15),  # inside ρ⁽¹⁾, outside ρ⁽²⁾
    "ex1dof_Wx": np.array([[-1.0, 0.0], [0.0003 * 0.9, 0.0]]),  # derW_99 with R = 0.9
    "ex1dof_monodromy1": np.array([[0.939, -0.0001407], [-0.0003165, 1.0]]),  # monodromy1
    "ex1dof_monodromy2": np.array([[0.939, -0.00052], [-0.000427, 1.0]]),  # monodromy2
    "ex1dof_rho": (1.0, 0.939, 1.0, 0.912),  # ρ1⁽¹⁾, ρ2⁽¹⁾, ρ1⁽²⁾, ρ2⁽²⁾
    "ex1dof_A6_continuous": np.array([[0.0, -0.061], [1.0, -0.0003165]]),  # last1 = 0.061
    "ex1dof_A6_impacting": np.array([[0.0, -0.0006], [1.0, 0.0009]]),  # smallexoneoneone111
    "ex1dof_A6_impacting_det": -0.0006,  # the value printed after that matrix
    "orbex2_psi_residual": 0.0,  # Ψ is a solution: Ψ' − f(Ψ) = 0 [eq. per]
    # What the text asserts (structural facts), compared for equality.
    "orbex2_ystar": ("GAMMA", True),  # y* is γ-type and axial [Example exdds]
    "orbex2_psi_contact": "GAMMA",  # the orbit of Ψ grazes Γ1 at y* [eq. per]
    "orbex2_psi_return": 1.0,  # Ψ(π) = (0, 1): y2 after the Γ2 jump [eq. per]
    "orbex2_cycle": True,  # Ψ is a periodic orbit [Example ex1]
    "Wx_limit": True,  # W_x exists at the grazing point [derW_8, derW_555, derW_99]
    "B_N1_finite": True,  # B_i = O on the (N1) side [eq. beta]
    "A2": True,  # (A2) holds
    "A3": True,  # (A3) holds
    "exnonaxial_axial": False,  # x* is non-axial
    "ex1dof_period": 2 * math.pi,  # Ψ_μ is 2π-periodic [eq. periodic1]
    "ex1dof_psi0_contact": ("GAMMA", True, (0.0, 0.0)),  # γ, axial, at x* = (0, 0)
    "ex1dof_A6_nonzero": True,  # (A6): the determinant is non-zero
    "ex1dof_branches": 2,  # (A4): m = 2 branches
    "ex1dof_A5": True,  # (A5) holds
    "ex1dof_cycles": (True, True),  # μ = ±0.2: an impacting cycle exists, is stable
    "ex1dof_mu_star": 0.0,  # the grazing bifurcation is at μ = 0
    "ex1dof_two_cycles_up_to": 0.0,  # two cycles for all small μ < 0: up to μ = 0
    "conditions": True,  # (C1)-(C7) (orbex2: -(C10)) hold for the three examples
    "smalldisc_cycle": True,  # μ = 0.05: orbits approach a periodic solution near Ψ
}


def printed_tol(value, exact: float = 1e3 * RTOL) -> float:
    """The precision of a printed number or matrix: half a unit in the last printed digit
    of its coarsest entry (0.939 → 5e-4). Whole numbers (0, 1, −1) are taken as exact; a
    value printed exactly is compared at `exact` (a multiple of the solver tolerance)."""
    units = [half_unit(f"{float(v):g}") for v in np.ravel(value) if float(v) != round(float(v))]
    return max(units) if units else exact


def compact(a, digits: int = 5) -> str:
    """A vector or matrix in compact text: [[a, b], [c, d]]."""
    a = np.asarray(a)
    if a.ndim == 0:
        return f"{complex(a).real:.{digits}g}" if np.iscomplexobj(a) else f"{float(a):.{digits}g}"
    return "[" + ", ".join(compact(v, digits) for v in a) + "]"


def relative_difference(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))


def half_unit(printed: str) -> float:
    """Half a unit in the last digit of a number as printed ("0.939" → 5e-4): the printed
    value agrees with any number that rounds to it."""
    mantissa = printed.strip().lstrip("+-−").lower().split("e")[0]
    decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
    exponent = int(printed.lower().split("e")[1]) if "e" in printed.lower() else 0
    return 0.5 * 10.0 ** (exponent - decimals)


def fact(name: str, printed, computed, tolerance: float | None = None) -> dict:
    """One fact a claim is about: the value as printed against grazejax's computed value.

    Numbers (scalars, vectors, matrices; `tolerance` given): they agree iff the largest
    entry of |printed − computed| is ≤ `tolerance` (shapes must match; NaN never agrees).
    Structural facts (booleans, counts, names, "exists"; `tolerance` None): they agree iff
    printed == computed.
    """
    if tolerance is None:
        if isinstance(computed, (np.generic, np.ndarray)):
            computed = computed.item()
        return {"name": name, "paper": printed, "grazejax": computed, "difference": None,
                "tolerance": None, "agrees": bool(printed == computed)}
    p, c = np.asarray(printed, float), np.asarray(computed, float)
    if p.shape != c.shape:
        difference = math.inf
    else:
        difference = float(np.max(np.abs(p - c))) if p.size else 0.0
        if not np.isfinite(difference):
            difference = math.inf
    return {"name": name, "paper": p.tolist(), "grazejax": c.tolist(),
            "difference": difference, "tolerance": float(tolerance),
            "agrees": bool(difference <= tolerance)}


def claim_verdict(facts: Sequence[dict]) -> str:
    """"agrees" iff every fact of the claim agrees (see `fact`), else "differs"."""
    if not facts:
        raise ValueError("a claim needs at least one fact to compare with the paper")
    return "agrees" if all(f["agrees"] for f in facts) else "differs"


def fact_text(item: dict) -> str:
    """A fact (`fact`) in one line: what was compared and how (for report.md)."""
    if item["tolerance"] is None:
        sign = "=" if item["agrees"] else "≠"
        return f"{item['name']}: {item['paper']} {sign} {item['grazejax']}"
    sign = "≤" if item["agrees"] else ">"
    return (f"{item['name']}: |printed − computed| = {item['difference']:.2g} {sign} "
            f"{item['tolerance']:.2g}")


def claim_row(id_: str, example: str, claim: str, *, paper: str, grazejax: str, check: str,
           check_method: str, difference: float | None, tolerance: float | None,
           facts: Sequence[dict] = (), reason: str = "", source: str = "",
           verdict: str | None = None, **extra) -> dict:
    """One row. `difference`/`tolerance`: grazejax vs the independent check (`consistent`).
    `facts` (`fact`): the printed values vs grazejax's; the verdict follows from them
    (`claim_verdict`). `reason` says why the paper differs: it is shown only when the
    verdict is "differs", and `reason_consistent` is False when a reason is given for a row
    that agrees or missing for one that differs (a stale row: the numbers changed)."""
    consistent = None
    if difference is not None and tolerance is not None:
        consistent = bool(np.isfinite(difference) and difference <= tolerance)
    if verdict is None:
        verdict = claim_verdict(facts)
    row = {
        "id": id_, "example": example, "claim": claim, "source": source, "paper": paper,
        "grazejax": grazejax, "check": check, "check_method": check_method,
        "difference": None if difference is None else float(difference),
        "tolerance": None if tolerance is None else float(tolerance),
        "consistent": consistent, "verdict": verdict,
        "reason": reason if verdict != "agrees" else "",
        "reason_consistent": verdict == "error" or bool(reason) == (verdict == "differs"),
        "facts": list(facts),
    }
    if verdict == "agrees" and reason:
        row["unused_reason"] = reason
    row.update(extra)
    return row


@dataclass(frozen=True)
class ClaimGroup:
    """Rows of the claims table computed together (they share runs and orbits)."""

    name: str
    example: str
    claims: tuple[str, ...]  # the row ids it produces (error rows use them)
    make: Callable[[dict], list[dict]]


def claim_group(name: str, example: str, *claims: str):
    """Decorator: the function `make(ctx) -> rows` becomes the `ClaimGroup` `name`, which
    produces the rows `claims` (`ctx`: results shared between groups, see `cached`)."""

    def group(make: Callable[[dict], list[dict]]) -> ClaimGroup:
        return ClaimGroup(name, example, claims, make)

    return group


def cached(ctx: dict, key: str, fn: Callable[[], object]):
    """Results shared between groups (an orbit, a one-sided limit), computed once."""
    if key not in ctx:
        try:
            ctx[key] = fn()
        except Exception as error:  # noqa: BLE001 - re-raised in every group that needs it
            ctx[key] = error
    if isinstance(ctx[key], Exception):
        raise RuntimeError(f"prerequisite {key!r} failed: {ctx[key]}") from ctx[key]
    return ctx[key]

