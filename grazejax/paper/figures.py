"""The figures of `grazejax reproduce`, in the order they run and are reported.

Each figure simulates what the paper's caption describes, draws a PNG, and returns a dict of
the numbers it computed (starts, impacts, final states, checks); `FIGURES[name].make(out)`
draws `out/<name>.png`.
"""

from __future__ import annotations

from . import figures_ex1dof, figures_exnonaxial, figures_orbex2, figures_smalldisc
from .drawing import FigureSpec

FIGURES: dict[str, FigureSpec] = {
    spec.name: spec
    for spec in (
        figures_orbex2.fig_orbex2_region,
        figures_orbex2.fig_orbex2_grazing,
        figures_orbex2.fig_orbex2_stability,
        figures_exnonaxial.fig_exnonaxial,
        figures_ex1dof.fig_ex1dof_grazing,
        figures_ex1dof.fig_ex1dof_negative,
        figures_ex1dof.fig_ex1dof_positive,
        figures_smalldisc.fig_smalldisc,
        figures_ex1dof.fig_ex1dof_bifurcation,
    )
}
