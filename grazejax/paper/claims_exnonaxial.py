"""The claims of exnonaxial: its grazing point and its multipliers inside and outside."""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from .. import plot
from .._linearize import (
    classify_point,
    flow_jacobian,
)
from .._status import ImpactKind
from .figures_exnonaxial import exnonaxial_next_offset, exnonaxial_return_rate
from .runs import SHORT, TWO_PI, paper_args, paper_scene, run_batch
from .table import (
    CLAIM_TOL,
    PRINTED,
    RTOL,
    SQRT_HALF,
    claim_group,
    claim_row,
    compact,
    fact,
    printed_tol,
    relative_difference,
)


@claim_group("exnonaxial", "exnonaxial", "exnonaxial.grazing-point", "exnonaxial.multipliers")
def claims_exnonaxial(ctx: dict) -> list[dict]:
    scene, args = paper_scene("exnonaxial"), paper_args("exnonaxial")
    printed_point = PRINTED["exnonaxial_point"]
    at_printed = classify_point(scene, 0, 0.0, list(printed_point), args)
    at_true = classify_point(scene, 0, 0.0, [SQRT_HALF, SQRT_HALF], args)
    x_psi = np.array([math.sin(math.pi / 4), math.cos(math.pi / 4)])
    rows = [claim_row(
        "exnonaxial.grazing-point", "exnonaxial",
        "x* = Ψ(π/4) is a non-axial grazing point of Γ = {x1 + x2 = √2}",
        source="Example (non-axial)", paper=f"x* = {compact(printed_point)}, "
                                           "⟨∇τ(x*), f(x*)⟩ = ⟨(1, 1), (1/2, −1/2)⟩ = 0",
        grazejax=f"(1/2, 1/2): {ImpactKind(int(at_printed.kind)).name} (not on Γ); "
                 f"(1/√2, 1/√2): {ImpactKind(int(at_true.kind)).name}, axial = "
                 f"{bool(at_true.axial)}",
        check=f"Ψ(π/4) = {compact(x_psi, 8)}; x1 + x2 − √2 = {x_psi.sum() - math.sqrt(2):.1e}; "
              "∇Φ·f = −(x2 − x1) = 0",
        check_method="closed form of the rotation",
        difference=float(np.max(np.abs(x_psi - SQRT_HALF))), tolerance=1e-15,
        facts=[fact("x* = (1/2, 1/2) is a γ point", True,
                     ImpactKind(int(at_printed.kind)) == ImpactKind.GAMMA),
               fact("x* is axial", PRINTED["exnonaxial_axial"], bool(at_true.axial))],
        reason="typo: the grazing point is (1/√2, 1/√2) (Ψ(π/4)), not (1/2, 1/2), and the test "
               "is ⟨∇Φ, f⟩, not ⟨∇τ, f⟩; the point is non-axial: agrees",
    )]
    # Inside: the rotation, no impact (N2): monodromy I. Outside: the return map on Γ̃.
    inside = flow_jacobian(scene, jnp.asarray([0.0, 0.96]), 0.0, TWO_PI, args, **CLAIM_TOL)
    inside_eigs = np.sort(np.linalg.eigvals(np.asarray(inside.jacobian)).real)
    sol = run_batch("exnonaxial", SHORT, [(0.0, 1.32)], args, 60.0)
    log = plot.impacts_of(plot.lane(sol, 0))
    offsets = np.linalg.norm(log["post"] - SQRT_HALF, axis=-1)
    ratio = float(offsets[-1] / offsets[-2])
    d_last = float(offsets[-2] / math.sqrt(2))  # post-impact points lie on the diagonal
    ratio_exact = exnonaxial_next_offset(args, d_last) / d_last
    rate = exnonaxial_return_rate(args)
    D = PRINTED["exnonaxial_Wx"]
    paper_eigs = np.sort(np.linalg.eigvals(np.eye(2) + D).real)
    printed = PRINTED["exnonaxial_rho"]
    rows.append(claim_row(
        "exnonaxial.multipliers", "exnonaxial",
        "multipliers: inside orbits ρ⁽¹⁾ = (1, 1); outside (impacting) ρ⁽²⁾ = (1, −0.15): "
        "orbitally stable from outside",
        source="Example (non-axial), eq. exnonaxiallin", paper=f"ρ⁽¹⁾ = ({printed[0]:g}, "
        f"{printed[1]:g}); ρ⁽²⁾ = ({printed[2]:g}, {printed[3]:g})",
        grazejax=f"inside: monodromy {compact(inside.jacobian, 6)}, ρ = {compact(inside_eigs, 10)}; "
                 f"outside: the post-impact offset from x* shrinks by {ratio:.8f} at the last "
                 f"impact (offset {d_last:.2e}, {len(offsets)} impacts from (0, 1.32)); "
                 f"→ {rate:.4f} as the offset → 0",
        check=f"inside: I (rotation by 2π); outside: the return map on Γ̃ at the same offset: "
              f"{ratio_exact:.8f}",
        check_method="closed forms: rotation; impact time of the rotation and the jump "
                     "(the 1-D return map on Γ̃; its derivative at x* by a difference quotient)",
        difference=max(relative_difference(inside.jacobian, np.eye(2)), abs(ratio - ratio_exact)),
        tolerance=1e3 * RTOL,
        facts=[fact("ρ⁽¹⁾", printed[:2], inside_eigs, 1e3 * RTOL),
               fact("ρ2⁽²⁾ (outside, offset → 0)", printed[3], rate, printed_tol(printed[3]))],
        reason="inside agrees; outside the orbits approach the cycle monotonically (factor "
               f"≈ {rate:.3f}, not −0.15): orbital stability agrees, the multiplier differs; the "
               "paper's own (exnonaxiallin) with D⁽²⁾ = derW_555 gives eigenvalues "
               f"{compact(paper_eigs, 4)} of I + D⁽²⁾",
        paper_formula=f"eig(I + D⁽²⁾) = {compact(paper_eigs, 5)}",
    ))
    return rows

