"""What every figure of `grazejax reproduce` uses: its spec, a blank figure, the PNG file."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class FigureSpec:
    """One figure: `make(out)` draws `out/<name>.png` and returns the numbers it computed."""

    name: str
    scene: str
    paper_figure: str  # LaTeX label in the paper
    title: str
    make: Callable[[Path], dict]


def figure(name: str, scene: str, paper_figure: str, title: str):
    """Decorator: the function `make(out) -> dict` becomes the `FigureSpec` of a figure."""

    def spec(make: Callable[[Path], dict]) -> FigureSpec:
        return FigureSpec(name, scene, paper_figure, title, make)

    return spec


def new_figure(ncols: int = 1, width: float = 6.0, height: float = 5.0, ratios=None):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout="constrained")
    axes = fig.subplots(1, ncols, gridspec_kw=None if ratios is None else {"width_ratios": ratios})
    return fig, (list(axes) if ncols > 1 else [axes])


def save_png(fig, out: Path, name: str) -> str:
    path = out / f"{name}.png"
    fig.savefig(path, dpi=110)
    return path.name


def add_legend(ax, **kw):
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        ax.legend(fontsize=7.5, framealpha=0.85, **kw)
