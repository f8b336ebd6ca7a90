"""The figure of exnonaxial (the paper's Fig. nonaxialcircle1) and its closed-form return map."""

from __future__ import annotations

import math
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from .. import examples, plot
from .._status import ImpactKind
from .drawing import add_legend, figure, new_figure, save_png
from .runs import SHORT, TWO_PI, as_float, as_list, paper_args, paper_scene, run_batch, run_record


def exnonaxial_next_offset(args, d: float) -> float:
    """The return map d → d' on Γ̃ (post-impact points (a, a), a = 1/√2 + d) of
    exnonaxial, from the closed-form impact time and the scene's jump (no simulator)."""
    s = 1 / math.sqrt(2)
    x0 = np.array([s + d, s + d])
    _, pre = examples.exnonaxial_first_impact(x0)
    post = np.asarray(paper_scene("exnonaxial").surfaces[0].jump(0.0, jnp.asarray(pre), args))
    return float(post[0] - s)


def exnonaxial_return_rate(args) -> float:
    """Derivative at x* of the return map d → d' on Γ̃ (`exnonaxial_next_offset`)."""

    def next_offset(d):
        return exnonaxial_next_offset(args, d)

    h = 1e-6
    return (next_offset(h) - next_offset(h / 2)) / (h / 2)


@figure("exnonaxial-circle", "exnonaxial", "nonaxialcircle1",
        "exnonaxial: non-axial grazing circle with trajectories from (0, 1.32) and (0, 0.96)")
def fig_exnonaxial(out: Path) -> dict:
    args = paper_args("exnonaxial")
    scene = paper_scene("exnonaxial")
    t1 = 60.0
    starts = [(0.0, 1.32), (0.0, 0.96)]
    sol = run_batch("exnonaxial", SHORT, starts, args, t1,
                    saveat=np.linspace(0, t1, SHORT.n_save))
    fig, (ax, bx) = new_figure(2, 11.0, 5.2, ratios=[1.05, 1])
    tt = np.linspace(0, TWO_PI, 400)
    ax.plot(np.sin(tt), np.cos(tt), color="#d62728", lw=2.2, label="Ψ(t) = (sin t, cos t)",
            zorder=1)
    plot.phase_portrait(ax, scene, args, sol, colors=["m", "g"],
                        labels=["from (0, 1.32)", "from (0, 0.96)"], images=True,
                        xlim=(-1.5, 1.5), ylim=(-1.5, 1.5), linewidth=0.9)
    s = 1 / math.sqrt(2)
    ax.plot([s], [s], "*", color="k", ms=10, label="grazing point x*")
    ax.set_aspect("equal")
    ax.set_title(f"exnonaxial, t ∈ [0, {t1:g}] (paper Fig. nonaxialcircle1)", fontsize=10)
    add_legend(ax, loc="lower left")

    outer = plot.impacts_of(plot.lane(sol, 0))
    offsets = np.linalg.norm(outer["post"] - s, axis=-1)
    ratios = offsets[1:] / offsets[:-1]
    rate = exnonaxial_return_rate(args)
    bx.semilogy(np.arange(len(offsets)), offsets, "o-", color="m", ms=4,
                label="|x(θ_k+) − x*| (from (0, 1.32))")
    bx.set_xlabel("impact k")
    bx.set_ylabel("distance of the post-impact point to x*")
    bx.set_title("approach to the grazing point along $\\tilde{\\Gamma}$", fontsize=10)
    add_legend(bx)
    file = save_png(fig, out, "exnonaxial-circle")

    t_exact, x_exact = examples.exnonaxial_first_impact(np.array(starts[0]))
    checks = {
        "first_impact_vs_closed_form": {
            "t_error": float(outer["times"][0] - t_exact),
            "state_error": float(np.max(np.abs(outer["pre"][0] - x_exact))),
        },
        "post_offsets": as_list(offsets),
        "offset_ratio_last": float(ratios[-1]) if len(ratios) else None,
        "return_map_derivative_closed_form": rate,
        "inner_radius_final": float(np.linalg.norm(sol.x_final[1])),
    }
    findings = [
        f"From (0, 1.32): {len(outer['times'])} impacts, all {', '.join(sorted(set(ImpactKind(int(q)).name for q in outer['kind'])))}; "
        f"the post-impact point approaches x* with ratio {checks['offset_ratio_last']:.4f} "
        f"per impact (derivative of the return map at x* from the closed form: {rate:.4f}).",
        f"From (0, 0.96): {int(sol.num_impacts[1])} impacts; radius at t = {t1:g} is "
        f"{checks['inner_radius_final']:.10f} (the flow is a rotation).",
        f"First impact matches the closed form to {abs(checks['first_impact_vs_closed_form']['t_error']):.1e} "
        f"in time and {checks['first_impact_vs_closed_form']['state_error']:.1e} in state.",
    ]
    return {
        "file": file,
        "args": {k_: as_float(v) for k_, v in args.items()},
        "runs": [run_record(sol, i, x0, f"from {x0}", "exnonaxial") for i, x0 in enumerate(starts)],
        "checks": checks,
        "paper": {"multipliers_outside": [1, -0.15], "multipliers_inside": [1, 1],
                  "claim": "outside orbits approach the cycle; (0, 0.96) stays on its circle"},
        "findings": findings,
    }

