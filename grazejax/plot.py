"""Matplotlib helpers: phase portraits of impact systems with their surfaces, and
bifurcation diagrams.

Everything here draws on a Matplotlib `Axes` you pass in; nothing opens a window. The
helpers work for any 2-D scene (state of shape `(2,)`):

- `draw_surfaces` draws the surface pieces Γ_i = {Φ_i = 0} ∩ {where_i} inside the
  current axes limits, by sampling the zero set of Φ_i with a contour on a grid, projecting
  the samples onto Φ_i = 0 with two Newton steps, and keeping the samples where `where_i`
  holds. With `images=True` it also draws Γ̃_i = J_i(Γ_i), by mapping those samples through
  the jump.
- `draw_trajectory` draws a run of `grazejax.simulate` from its saved states
  (`saveat`), breaking the line at every impact: the jump x(θ) → x(θ+) is a dotted segment
  from `impact_pre` to `impact_post`, with markers at both ends (a star for grazing, γ).
- `phase_portrait` does both, for one run or a batch of runs (leading batch axis).
- `grazejax.plot_bifurcation_diagram` draws branches of periodic orbits from
  `grazejax.continue_orbit` (amplitude against μ, stability, impacts per period).
- `grazejax.plot_orbit_diagram` draws a brute-force orbit diagram from
  `grazejax.orbit_diagram` (section points against μ, by period), optionally over a panel
  of maximal Lyapunov exponents.
- `grazejax.plot_basins` draws the basins of attraction of a 2-D grid of starts from
  `grazejax.basins` (one colour per attractor, grey where a start is in no basin).

Colours follow the paper's figures: Γ in red, Γ̃ in green.

```python
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import grazejax as gj
from grazejax import examples, plot

scene, args = examples.exnonaxial(), examples.exnonaxial_args()
sol = gj.simulate(scene, [0.0, 1.32], 0.0, 30.0, args, saveat=np.linspace(0, 30, 3001))
fig, ax = plt.subplots()
plot.phase_portrait(ax, scene, args, sol, images=True)
fig.savefig("exnonaxial.png")
```
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ._geometry import project_to_surface
from ._orbits.branch import Branch
from ._scene import Scene
from ._status import ImpactKind

SURFACE_COLORS = ("#d62728",)
"""Colours of the pieces Γ_i, cycled (the paper draws all of Γ in red)."""
IMAGE_COLORS = ("#2ca02c",)
"""Colours of the image pieces Γ̃_i = J_i(Γ_i), cycled (the paper: green)."""


# --------------------------------------------------------------------------------------
# Solutions: batches and windows
# --------------------------------------------------------------------------------------


def num_runs(sol) -> int:
    """Number of runs in a (possibly batched) solution: 1 for an unbatched run."""
    return 1 if np.ndim(sol.t_final) == 0 else int(np.shape(sol.t_final)[0])


def lane(sol, i: int):
    """Run `i` of a batched solution (the solution itself if it is not batched)."""
    if np.ndim(sol.t_final) == 0:
        if i != 0:
            raise IndexError(f"an unbatched solution has only run 0, not {i}")
        return sol
    return jax.tree.map(lambda leaf: leaf[i], sol)


def impacts_of(sol) -> dict:
    """The filled rows of an unbatched run's impact log, as NumPy arrays."""
    k = int(sol.num_impacts)
    return {
        "times": np.asarray(sol.impact_times)[:k],
        "pre": np.asarray(sol.impact_pre)[:k],
        "post": np.asarray(sol.impact_post)[:k],
        "surface": np.asarray(sol.impact_surface)[:k],
        "kind": np.asarray(sol.impact_kind)[:k],
    }


def flight_segments(sol, time_window=None) -> list[np.ndarray]:
    """The saved trajectory of an unbatched run, cut into impact-free flights.

    Each flight is an array of states `(k, n)`: the post-impact state that starts it (if
    any), the saved states strictly after that impact and up to the next impact time, and
    the pre-impact state that ends it. Lines drawn through a flight therefore touch the
    surface exactly, whatever the spacing of `saveat`. `time_window=(a, b)` keeps the
    part of the run with a ≤ t ≤ b (forward runs).
    """
    if sol.ts is None:
        raise ValueError(
            "this solution has no saved states: run simulate with saveat=<array of times>"
        )
    ts, xs = np.asarray(sol.ts), np.asarray(sol.xs)
    ok = np.isfinite(ts) & np.all(np.isfinite(xs), axis=-1)
    ts, xs = ts[ok], xs[ok]
    log = impacts_of(sol)
    backward = ts.size > 1 and ts[-1] < ts[0]
    sign = -1.0 if backward else 1.0
    lo, hi = (-np.inf, np.inf) if time_window is None else map(float, time_window)

    def keep(t):
        return (t >= lo) & (t <= hi)

    edges = np.concatenate([[-np.inf], sign * log["times"], [np.inf]])
    segments = []
    for j in range(len(edges) - 1):
        inside = (sign * ts > edges[j]) & (sign * ts <= edges[j + 1])
        pts, times = [xs[inside]], [ts[inside]]
        if j > 0:  # the flight starts at the post-impact state of impact j - 1
            pts.insert(0, log["post"][j - 1][None])
            times.insert(0, log["times"][j - 1][None])
        if j < len(log["times"]):  # ... and ends at the pre-impact state of impact j
            pts.append(log["pre"][j][None])
            times.append(log["times"][j][None])
        pts, times = np.concatenate(pts), np.concatenate(times)
        mask = keep(times)
        if mask.sum() >= 2:
            segments.append(pts[mask])
    return segments


# --------------------------------------------------------------------------------------
# Surfaces
# --------------------------------------------------------------------------------------


def _contour_lines(x, y, z, level=0.0):
    import contourpy

    gen = contourpy.contour_generator(x=x, y=y, z=z, line_type="Separate")
    return [np.asarray(line) for line in gen.lines(level)]


def _runs(mask: np.ndarray) -> list[slice]:
    """Slices of consecutive True values."""
    padded = np.concatenate([[False], mask, [False]]).astype(int)
    starts = np.flatnonzero(np.diff(padded) == 1)
    stops = np.flatnonzero(np.diff(padded) == -1)
    return [slice(a, b) for a, b in zip(starts, stops, strict=True)]


def surface_samples(
    scene: Scene,
    args,
    index: int,
    xlim: Sequence[float],
    ylim: Sequence[float],
    *,
    t: float = 0.0,
    resolution: int = 300,
    restrict: Callable | None = None,
) -> list[np.ndarray]:
    """Sampled polylines of the piece Γ_index inside the box `xlim × ylim`.

    The zero set of Φ is traced by a contour on a `resolution × resolution` grid; each
    sample is moved onto Φ = 0 by two Newton steps along ∇Φ; samples where `where` is
    false (or `restrict(points) -> bool array` is false) are dropped and the polylines
    split there. Returns a list of arrays of shape `(k, 2)`.
    """
    surface = scene.surfaces[index]
    t = jnp.asarray(t, float)
    span_x, span_y = xlim[1] - xlim[0], ylim[1] - ylim[0]
    # Pad the grid a little so that lines on the axes' edges are found, and shift it by
    # an irrational fraction of a cell so that grid nodes rarely sit exactly on Φ = 0.
    gx = np.linspace(xlim[0] - 0.02 * span_x, xlim[1] + 0.02 * span_x, resolution)
    gy = np.linspace(ylim[0] - 0.02 * span_y, ylim[1] + 0.02 * span_y, resolution)
    gx = gx + (gx[1] - gx[0]) * (np.sqrt(2) - 1) / 3
    gy = gy + (gy[1] - gy[0]) * (np.sqrt(3) - 1) / 5
    X, Y = np.meshgrid(gx, gy)
    points = jnp.asarray(np.stack([X.ravel(), Y.ravel()], axis=-1))

    def phi(x):
        return surface.phi(t, x, args)

    values = np.asarray(jax.vmap(phi)(points)).reshape(X.shape)
    lines = _contour_lines(X, Y, values)
    if not lines:
        return []

    def newton(x):
        return project_to_surface(surface.phi, t, x, args, iterations=2)

    out = []
    for line in lines:
        pts = np.asarray(jax.vmap(newton)(jnp.asarray(line)))
        ok = np.all(np.isfinite(pts), axis=-1)
        if surface.where is not None:
            ok &= np.asarray(jax.vmap(lambda x: surface.where(t, x, args))(jnp.asarray(pts)))
        if restrict is not None:
            ok &= np.asarray(restrict(pts), dtype=bool)
        for run in _runs(ok):
            if run.stop - run.start >= 2:
                out.append(pts[run])
    return out


def image_samples(scene: Scene, args, index: int, lines, *, t: float = 0.0) -> list[np.ndarray]:
    """Map sampled polylines of Γ_index through its jump: samples of Γ̃_index = J(Γ_index)."""
    jump = scene.surfaces[index].jump
    t = jnp.asarray(t, float)
    mapped = []
    for line in lines:
        img = np.asarray(jax.vmap(lambda x: jump(t, x, args))(jnp.asarray(line)))
        ok = np.all(np.isfinite(img), axis=-1)
        for run in _runs(ok):
            if run.stop - run.start >= 1:
                mapped.append(img[run])
    return mapped


def draw_surfaces(
    ax,
    scene: Scene,
    args,
    *,
    t: float = 0.0,
    images: bool = False,
    xlim=None,
    ylim=None,
    resolution: int = 300,
    restrict: Callable | None = None,
    colors: Sequence[str] = SURFACE_COLORS,
    image_colors: Sequence[str] = IMAGE_COLORS,
    linewidth: float = 2.5,
    labels: bool = True,
    which: Sequence[int] | None = None,
):
    """Draw the surface pieces Γ_i (and, with `images=True`, Γ̃_i = J_i(Γ_i)) on `ax`.

    The pieces are sampled inside `xlim × ylim` (default: the axes' current limits, which
    are then kept). `t` is the time at which moving surfaces are drawn. `restrict`
    (points → bool array) bounds the pieces further, e.g. to the paper's bounded Γ_i.
    `which` selects pieces by index. Returns `{"surfaces": [...], "images": [...]}`, the
    sampled polylines per piece.
    """
    xlim = tuple(ax.get_xlim()) if xlim is None else tuple(xlim)
    ylim = tuple(ax.get_ylim()) if ylim is None else tuple(ylim)
    indices = list(range(len(scene.surfaces)) if which is None else which)
    # One legend entry per colour: pieces sharing a colour share an entry.
    names, image_names = {}, {}
    for i in indices:
        names.setdefault(colors[i % len(colors)], []).append(scene.surface_name(i))
        image_names.setdefault(image_colors[i % len(image_colors)], []).append(i)
    surface_label = {c: "; ".join(v) for c, v in names.items()}
    image_label = {
        c: (f"$\\tilde{{\\Gamma}}_{v[0] + 1} = J(\\Gamma_{v[0] + 1})$" if len(v) == 1
            else "$\\tilde{\\Gamma} = J(\\Gamma)$")
        for c, v in image_names.items()
    }
    drawn = {"surfaces": [], "images": []}
    for i in indices:
        lines = surface_samples(
            scene, args, i, xlim, ylim, t=t, resolution=resolution, restrict=restrict
        )
        drawn["surfaces"].append(lines)
        color = colors[i % len(colors)]
        for line in lines:
            ax.plot(
                line[:, 0], line[:, 1], color=color, lw=linewidth,
                solid_capstyle="butt", zorder=2,
                label=(surface_label.pop(color, None) if labels else None),
            )
        if images:
            mapped = image_samples(scene, args, i, lines, t=t)
            drawn["images"].append(mapped)
            image_color = image_colors[i % len(image_colors)]
            for line in mapped:
                style = dict(color=image_color, zorder=2)
                label = image_label.pop(image_color, None) if labels else None
                if len(line) == 1:
                    ax.plot(line[:, 0], line[:, 1], "s", ms=5, label=label, **style)
                else:
                    ax.plot(line[:, 0], line[:, 1], lw=linewidth, ls="-", label=label,
                            solid_capstyle="butt", alpha=0.85, **style)
    ax.set_xlim(xlim)
    ax.set_ylim(ylim)
    return drawn


# --------------------------------------------------------------------------------------
# Trajectories
# --------------------------------------------------------------------------------------


def draw_trajectory(
    ax,
    sol,
    *,
    color="C0",
    label: str | None = None,
    linewidth: float = 1.2,
    alpha: float = 1.0,
    time_window=None,
    jumps: bool = True,
    markers: bool = True,
    start: bool = True,
    coords: tuple[int, int] = (0, 1),
    zorder: float = 3,
):
    """Draw one run (unbatched `Solution` with `saveat`) in the plane of `coords`.

    Lines break at impacts; each jump is a dotted segment from x(θ) to x(θ+), with a filled
    dot at x(θ) (a star if the contact was grazing, γ) and an open circle at x(θ+).
    `time_window=(a, b)` draws only that part of the run. Returns the number of flights
    drawn.
    """
    i, j = coords
    segments = flight_segments(sol, time_window)
    for k, seg in enumerate(segments):
        ax.plot(seg[:, i], seg[:, j], color=color, lw=linewidth, alpha=alpha, zorder=zorder,
                label=(label if k == 0 else None))
    log = impacts_of(sol)
    if time_window is not None:
        lo, hi = map(float, time_window)
        sel = (log["times"] >= lo) & (log["times"] <= hi)
        log = {key: value[sel] for key, value in log.items()}
    if jumps and len(log["times"]):
        for pre, post in zip(log["pre"], log["post"], strict=True):
            ax.plot([pre[i], post[i]], [pre[j], post[j]], ls=":", color=color, lw=1.0,
                    alpha=alpha, zorder=zorder)
    if markers and len(log["times"]):
        grazing = np.array([ImpactKind(int(k)).is_grazing for k in log["kind"]], dtype=bool)
        pre, post = log["pre"], log["post"]
        ax.plot(pre[~grazing, i], pre[~grazing, j], "o", ms=3.5, color=color, alpha=alpha,
                zorder=zorder + 1)
        ax.plot(post[:, i], post[:, j], "o", ms=3.5, mfc="none", mec=color, alpha=alpha,
                zorder=zorder + 1)
        if grazing.any():
            ax.plot(pre[grazing, i], pre[grazing, j], "*", ms=9, mfc=color, mec="k",
                    zorder=zorder + 2)
    if start and segments:
        first = segments[0][0]
        ax.plot(first[i], first[j], "^", ms=6, color=color, mec="k", mew=0.5,
                zorder=zorder + 2)
    return len(segments)


def trajectory_limits(sols, margin: float = 0.08, coords=(0, 1)):
    """Axes limits `(xlim, ylim)` that hold every saved state and impact of `sols`."""
    pts = []
    for sol in sols if isinstance(sols, list | tuple) else [sols]:
        for r in range(num_runs(sol)):
            one = lane(sol, r)
            if one.xs is not None:
                pts.append(np.asarray(one.xs)[:, list(coords)])
            log = impacts_of(one)
            if len(log["times"]):
                pts.append(log["pre"][:, list(coords)])
                pts.append(log["post"][:, list(coords)])
    pts = np.concatenate(pts)
    pts = pts[np.all(np.isfinite(pts), axis=-1)]
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = margin * np.maximum(hi - lo, 1e-9)
    return (lo[0] - pad[0], hi[0] + pad[0]), (lo[1] - pad[1], hi[1] + pad[1])


def phase_portrait(
    ax,
    scene: Scene,
    args,
    sol,
    *,
    colors: Sequence[str] | None = None,
    labels: Sequence[str | None] | None = None,
    surfaces: bool = True,
    images: bool = False,
    t: float = 0.0,
    xlim=None,
    ylim=None,
    time_window=None,
    linewidth: float = 1.2,
    alpha: float = 1.0,
    markers: bool = True,
    start: bool = True,
    restrict: Callable | None = None,
    axis_labels: tuple[str, str] = ("$x_1$", "$x_2$"),
):
    """Phase portrait of a 2-D scene: trajectories of `sol` with the surface pieces.

    `sol` is one run or a batch (leading axis) from `simulate(..., saveat=ts)`. Each run
    is drawn with `draw_trajectory` (lines broken at impacts, dotted jumps, impact
    markers, a triangle at the first drawn state unless `start=False`); then, if `surfaces`,
    the pieces Γ_i (and Γ̃_i with `images=True`) are drawn inside the axes limits (default:
    fitted to the trajectories). Returns `ax`.
    """
    n = num_runs(sol)
    colors = list(colors) if colors is not None else [f"C{k}" for k in range(n)]
    labels = list(labels) if labels is not None else [None] * n
    if xlim is None or ylim is None:
        fx, fy = trajectory_limits(sol)
        xlim = fx if xlim is None else xlim
        ylim = fy if ylim is None else ylim
    ax.set_xlim(xlim)
    ax.set_ylim(ylim)
    for r in range(n):
        draw_trajectory(
            ax, lane(sol, r), color=colors[r % len(colors)], label=labels[r % len(labels)],
            linewidth=linewidth, alpha=alpha, time_window=time_window, markers=markers,
            start=start,
        )
    if surfaces:
        draw_surfaces(ax, scene, args, t=t, images=images, xlim=xlim, ylim=ylim,
                      restrict=restrict)
    ax.set_xlabel(axis_labels[0])
    ax.set_ylabel(axis_labels[1])
    return ax


def plot_bifurcation_diagram(
    branches: Branch | Sequence[Branch],
    path=None,
    *,
    coordinate: int = 0,
    measure: str = "max",
    ax=None,
    title: str | None = None,
    mu_label: str = "μ",
    dpi: int = 150,
):
    r"""Draw branches of periodic orbits: amplitude vs μ, stability, impacts per period.

    **Arguments:**

    - `branches`: one `grazejax.Branch` or several.
    - `path`: if given, the figure is saved there as a PNG.
    - `coordinate`: which state coordinate measures the orbit.
    - `measure`: `"max"` (largest value of the coordinate along the orbit), `"min"`, or
      `"amplitude"` (max − min).
    - `ax`: a Matplotlib `Axes` to draw on (default: a new figure).
    - `title`, `mu_label`, `dpi`: labels and resolution.

    Stable orbits ((A5) holds) are solid lines, unstable ones dashed; the colour and the
    legend give the number of impacts per period; grazing points are black diamonds
    labelled `G` with their kind (persistence, fold, end); special points are labelled
    `PD` (period doubling, square), `LP` (fold, triangle), `NS` (Neimark–Sacker, circle).

    **Returns:** the Matplotlib `Figure`.
    """
    import matplotlib

    if ax is None and path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    if isinstance(branches, Branch):
        branches = [branches]
    if measure not in ("max", "min", "amplitude"):
        raise ValueError(f"measure must be 'max', 'min' or 'amplitude', got {measure!r}")
    if ax is None:
        fig, ax = plt.subplots(figsize=(7.5, 4.8))
    else:
        fig = ax.figure
    counts = sorted({int(k) for b in branches for k in np.asarray(b.num_impacts)})
    cmap = plt.get_cmap("tab10")
    colour = {k: cmap(i % 10) for i, k in enumerate(counts)}

    def value(b, idx):
        lo, hi = np.asarray(b.x_min)[idx, coordinate], np.asarray(b.x_max)[idx, coordinate]
        return {"max": hi, "min": lo, "amplitude": hi - lo}[measure]

    seen = set()
    for b in branches:
        mu = np.asarray(b.mu)
        if len(mu) == 0:
            continue
        k = np.asarray(b.num_impacts)
        stable = np.asarray(b.stable)
        y = value(b, slice(None))
        # One line per run of equal (impacts, stability).
        start = 0
        for i in range(1, len(mu) + 1):
            if i < len(mu) and k[i] == k[start] and stable[i] == stable[start]:
                continue
            seg = slice(start, i + 1 if i < len(mu) and k[i] == k[start] else i)
            label_key = (int(k[start]), bool(stable[start]))
            label = None
            if label_key not in seen:
                seen.add(label_key)
                label = f"{int(k[start])} impact(s)/period, {'stable' if stable[start] else 'unstable'}"
            ax.plot(mu[seg], y[seg], "-" if stable[start] else "--", color=colour[int(k[start])],
                    lw=1.8, label=label, marker="." if i - start < 3 else None)
            start = i
        for g in b.grazing:
            idx = int(np.argmin(np.abs(mu - g.mu)))
            ax.plot([g.mu], [y[idx]], "D", color="k", ms=6, zorder=5)
            ax.annotate(f"G ({g.kind})\nμ = {g.mu:.6g}", (g.mu, y[idx]),
                        textcoords="offset points", xytext=(6, -22), fontsize=8)
        for p in b.special_points:
            idx = int(np.argmin(np.abs(mu - p.mu)))
            ax.plot([p.mu], [y[idx]], {"PD": "s", "LP": "^", "NS": "o"}[p.label], color="k",
                    mfc="w", ms=7, zorder=6)
            ax.annotate(f"{p.label}\nμ = {p.mu:.6g}", (p.mu, y[idx]),
                        textcoords="offset points", xytext=(6, 8), fontsize=8)
    ax.set_xlabel(mu_label)
    ax.set_ylabel({"max": f"max x{coordinate + 1}", "min": f"min x{coordinate + 1}",
                   "amplitude": f"amplitude of x{coordinate + 1}"}[measure])
    if title:
        ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    if path is not None:
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return fig


def plot_orbit_diagram(
    diagram,
    coordinate: int = 0,
    ax=None,
    lyapunov=None,
    *,
    path=None,
    title: str | None = None,
    mu_label: str = "μ",
    dpi: int = 150,
):
    r"""Draw a brute-force orbit diagram (`grazejax.orbit_diagram`): section points vs μ.

    **Arguments:**

    - `diagram`: a `grazejax.OrbitDiagram`.
    - `coordinate`: which state coordinate of the points to draw.
    - `ax`: a Matplotlib `Axes` (without `lyapunov`), or a pair of them (with it): default
      a new figure.
    - `lyapunov`: optional maximal Lyapunov exponents, one per μ (e.g. from
      `grazejax.lyapunov_spectrum`, computed by the caller), drawn in a lower panel with
      the zero line; NaN entries are left out.
    - `path`: if given, the figure is saved there as a PNG.
    - `title`, `mu_label`, `dpi`: labels and resolution.

    Points are coloured by the detected period of their μ (1, 2, 4, ...; grey where none
    was found); μ whose runs failed (status not `SUCCESS`) are marked by red ticks on the
    μ axis, so that a gap in the diagram is never mistaken for an empty attractor.

    **Returns:** the Matplotlib `Figure`.
    """
    import matplotlib

    if ax is None and path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    if ax is None:
        if lyapunov is None:
            fig, top = plt.subplots(figsize=(7.5, 4.8))
        else:
            fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7.5, 6.4),
                                              gridspec_kw={"height_ratios": (3, 1)})
    else:
        top, bottom = (ax, None) if lyapunov is None else tuple(ax)
        fig = top.figure
    _draw_orbit_points(top, diagram, coordinate)
    top.set_ylabel(f"x{coordinate + 1} on the section")
    if title:
        top.set_title(title, fontsize=10)
    if lyapunov is not None:
        lyapunov = np.asarray(lyapunov, dtype=float)
        mu = np.asarray(diagram.mu)
        if lyapunov.shape != mu.shape:
            raise ValueError(f"lyapunov must have one value per μ {mu.shape}, got {lyapunov.shape}")
        bottom.plot(mu, lyapunov, ".-", color="k", lw=0.8, ms=3)
        bottom.axhline(0.0, color="#d62728", lw=0.8)
        bottom.set_ylabel("λ_max")
        bottom.grid(alpha=0.3)
        bottom.set_xlabel(mu_label)
    else:
        top.set_xlabel(mu_label)
    if path is not None:
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return fig


def _draw_orbit_points(ax, diagram, coordinate: int) -> None:
    """The points of each μ, coloured by period, and red ticks at failed μ."""
    mu = np.asarray(diagram.mu)
    values = np.asarray(diagram.points)[..., coordinate]
    period = np.asarray(diagram.period)
    import matplotlib.pyplot as plt

    cmap = plt.get_cmap("tab10")
    for i, p in enumerate(sorted(set(period.tolist()))):
        lanes = period == p
        x = np.repeat(mu[lanes], values.shape[1])
        y = values[lanes].ravel()
        ax.plot(x, y, ".", ms=2, color="0.5" if p == 0 else cmap(i % 10),
                label="no period found" if p == 0 else f"period {p}")
    failed = np.asarray(diagram.status) != 0
    if failed.any():
        ax.plot(mu[failed], np.zeros(failed.sum()), "|", color="#d62728", ms=12,
                transform=ax.get_xaxis_transform(), label="run failed (see status)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best", markerscale=4)



def plot_basins(basins, grid_shape, extent, ax=None, *, path=None, title: str | None = None,
                labels: tuple[str, str] = ("x1(0)", "x2(0)"), dpi: int = 150):
    r"""Draw the basins of attraction of a 2-D grid of starts (`grazejax.basins`).

    **Arguments:**

    - `basins`: a `grazejax.Basins` whose starts were a grid, ordered as
      `np.stack([X.ravel(), Y.ravel()], 1)` with `X, Y = np.meshgrid(xs, ys)`.
    - `grid_shape`: `(len(ys), len(xs))`, the shape of `X`.
    - `extent`: `(x_min, x_max, y_min, y_max)`, the grid's first and last values.
    - `ax`: a Matplotlib `Axes` (default: a new figure).
    - `path`: if given, the figure is saved there as a PNG.
    - `title`, `labels` (axis labels), `dpi`.

    Each basin gets its colour (the legend gives its period and basin stability S ± its
    standard error); starts in no basin (label −1: undecided, diverged or failed) are
    grey, so that a hole in a basin is never mistaken for another attractor's.

    **Returns:** the Matplotlib `Figure`.
    """
    import matplotlib

    if ax is None and path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    grid = np.asarray(basins.labels).reshape(grid_shape)
    if ax is None:
        fig, ax = plt.subplots(figsize=(6.0, 5.0))
    else:
        fig = ax.figure
    count = len(basins.attractors)
    colours = ["0.6", *[plt.get_cmap("tab10")(k % 10) for k in range(count)]]
    x_min, x_max, y_min, y_max = extent
    # Pixel centres on the grid points: pad the extent by half a cell on each side.
    dx = (x_max - x_min) / max(grid.shape[1] - 1, 1) / 2
    dy = (y_max - y_min) / max(grid.shape[0] - 1, 1) / 2
    ax.imshow(grid + 1, origin="lower", cmap=ListedColormap(colours), vmin=-0.5,
              vmax=count + 0.5, extent=(x_min - dx, x_max + dx, y_min - dy, y_max + dy),
              aspect="auto", interpolation="nearest")
    handles = [Patch(color=colours[k + 1],
                     label=f"{k}: period {a.period}, S = {basins.fractions[k]:.3f} ± "
                           f"{basins.standard_errors[k]:.3f}")
               for k, a in enumerate(basins.attractors)]
    handles.append(Patch(color=colours[0], label=f"−1: no attractor ({basins.num_undecided})"))
    ax.legend(handles=handles, fontsize=8, loc="best")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    if title:
        ax.set_title(title, fontsize=10)
    if path is not None:
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return fig
