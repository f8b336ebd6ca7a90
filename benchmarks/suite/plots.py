"""The suite's PNG plots: work-precision per case, grazing, effects, scaling, Floquet and the
headline."""

from __future__ import annotations

import _cases as C
import matplotlib
import matplotlib.ticker
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)

from .common import HAVE_HEYOKA, HEADLINE_CASE, METRICS

STYLE = {
    ("grazejax", "Tsit5"): dict(color="#1f77b4", marker="o", ls="-"),
    ("grazejax", "Dopri5"): dict(color="#17becf", marker="s", ls="-"),
    ("grazejax", "Dopri8"): dict(color="#2ca02c", marker="D", ls="-"),
    ("grazejax", "Kvaerno5"): dict(color="#9467bd", marker="P", ls="-"),
    ("scipy", "RK45"): dict(color="#ff7f0e", marker="v", ls="--"),
    ("scipy", "DOP853"): dict(color="#d62728", marker="^", ls="--"),
    ("scipy", "Radau"): dict(color="#8c564b", marker="<", ls="--"),
    ("scipy", "LSODA"): dict(color="#e377c2", marker=">", ls="--"),
    ("heyoka", "taylor"): dict(color="black", marker="*", ls=":"),
}
FLOOR = 1e-17  # errors of exactly 0 are drawn here


def style_of(tool, method):
    if tool == "grazejax-batch":
        base = STYLE[("grazejax", method.split()[0])]
        if "in phase" in method:
            return {
                **base,
                "color": "#bcbd22" if "Dopri8" in method else "#8c6d31",
                "ls": "-.",
                "marker": "P",
            }
        return {**base, "ls": "-.", "marker": "x"}
    if tool == "heyoka-batch":
        return {**STYLE[("heyoka", "taylor")], "ls": "-.", "marker": "x"}
    return STYLE.get((tool, method), dict(color="gray", marker=".", ls="-"))


def series(rows):
    """Group rows into plot series: (tool, method, max_step) → rows sorted by tol."""
    out = {}
    for r in rows:
        if r.get("time_min_s") is None:
            continue
        out.setdefault((r["tool"], r["method"], r.get("max_step")), []).append(r)
    for v in out.values():
        v.sort(key=lambda r: -r["tol"])
    return out


def label_of(tool, method, max_step):
    tool_name = {"grazejax-batch": "grazejax", "heyoka-batch": "heyoka"}.get(tool, tool)
    lab = f"{tool_name} {method}"
    if tool == "grazejax-batch":
        lab = f"grazejax {method}, per lane"
    if tool == "heyoka-batch":
        lab = "heyoka, per run (mean over the random-phase batch starts)"
    if max_step is not None:
        lab += f" (max_step {max_step})"
    return lab


def plot_wp(case_name, ci, rows, path):
    rows = [r for r in rows if r["case"] == case_name]
    fig, axes = plt.subplots(3, 3, figsize=(16, 13.5))
    ser = series(rows)
    xkeys = [
        ("time_min_s", "wall time per run [s] (min of repeats)"),
        ("evals", "right-hand-side evaluations (units: see legend note)"),
        ("tol", "tolerance (rtol = atol; heyoka: tol)"),
    ]
    handles = {}
    for i, (xk, xl) in enumerate(xkeys):
        for j, (mk, ml) in enumerate(METRICS.items()):
            ax = axes[i, j]
            for (tool, method, ms), rs in ser.items():
                pts = [
                    (r[xk], max(r[mk], FLOOR))
                    for r in rs
                    if r.get("ok") and r.get(xk) and r.get(mk) is not None
                ]
                bad = [r for r in rs if not r.get("ok")]
                st = style_of(tool, method)
                if pts:
                    xs, ys = zip(*pts, strict=True)
                    (h,) = ax.loglog(
                        xs,
                        ys,
                        color=st["color"],
                        marker=st["marker"],
                        ls=st["ls"],
                        ms=5,
                        lw=1.3,
                        mfc="none" if ms is not None else st["color"],
                    )
                    handles[label_of(tool, method, ms)] = h
                for r in bad:  # wrong impact count: marked at the top edge
                    if r.get(xk):
                        ax.plot(
                            [r[xk]],
                            [1.0],
                            marker="X",
                            color=st["color"],
                            ms=8,
                            ls="none",
                            clip_on=False,
                        )
            if xk == "tol":
                lo, hi = 1e-14, 2e-3
                ax.loglog([lo, hi], [lo, hi], color="gray", lw=0.8, ls=":")
                ax.invert_xaxis()
            ax.set_ylim(3e-18, 3.0)
            ax.grid(True, which="major", alpha=0.3)
            ax.set_xlabel(xl)
            if j == 0:
                ax.set_ylabel("max abs error")
            if i == 0:
                ax.set_title(f"error in {ml}")
    kv = [r for r in rows if r["method"] == "Kvaerno5"]
    kv_note = (
        ""
        if not kv
        else "; Kvaerno5: f calls counted"
        if any(r.get("evals") for r in kv)
        else "; Kvaerno5: not counted in quick mode"
    )
    note = (
        f"Evaluations: grazejax = solver steps × stages per step (Tsit5/Dopri5 6, Dopri8 13{kv_note}); "
        "SciPy = f calls counted (incl. finite-difference Jacobians); "
        "heyoka = Taylor steps (one Taylor jet each, a different unit).  "
        "X at the top: wrong number of impacts.  Hollow markers: SciPy with max_step.  "
        "Errors of exactly 0 drawn at 1e-17."
    )
    fig.suptitle(f"Work-precision: {ci['title']}\nground truth: {ci['truth_method']}", fontsize=12)
    fig.legend(
        list(handles.values()),
        list(handles.keys()),
        loc="lower center",
        ncol=4,
        fontsize=9,
        frameon=False,
        bbox_to_anchor=(0.5, 0.035),
    )
    fig.text(
        0.5, 0.012, note + "  " + C.SHARED_MACHINE_NOTE + ".", ha="center", fontsize=7.5, wrap=True
    )
    fig.tight_layout(rect=(0, 0.09, 1, 0.95))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_grazing(g, path):
    setups = list(g["setups"])
    fig, axes = plt.subplots(len(setups), 3, figsize=(18, 5.0 * len(setups)), squeeze=False)
    for row_i, setup in enumerate(setups):
        spec = g["setups"][setup]
        rows = [r for r in g["rows"] if r["setup"] == setup and r["depth"] > 0]
        ax_e, ax_s, ax_t = axes[row_i]
        _grazing_series(ax_e, ax_s, ax_t, rows)
        _grazing_decor(ax_e, ax_s, ax_t, g, setup, spec)
    fig.suptitle(
        f"The cost of grazing: one impact at depth δ → 0, every tool at tol {g['tol']:g} "
        "(truth: closed forms; X at the top: wrong number of impacts; grey band: see the note in it). "
        + C.SHARED_MACHINE_NOTE.split(":")[0],
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _grazing_series(ax_e, ax_s, ax_t, rows):
    """Each tool's impact-time error, steps (grazejax) and time against the depth; wrong
    impact counts as X at the top."""
    for tool, method in sorted({(r["tool"], r["method"]) for r in rows}):
        rs = sorted(
            [r for r in rows if (r["tool"], r["method"]) == (tool, method)],
            key=lambda r: -r["depth"],
        )
        st = (
            style_of(tool, method.split()[0])
            if tool != "heyoka"
            else STYLE[("heyoka", "taylor")]
        )
        mfc = "none" if "max_step" in method else st["color"]
        lab = f"{tool} {method}"
        ok = [r for r in rs if r.get("ok")]
        if ok:
            ax_e.loglog(
                [r["depth"] for r in ok],
                [max(r["err_t"], FLOOR) for r in ok],
                marker=st["marker"],
                color=st["color"],
                ls=st["ls"],
                mfc=mfc,
                label=lab,
            )
            ax_t.loglog(
                [r["depth"] for r in ok],
                [r["time_min_s"] for r in ok],
                marker=st["marker"],
                color=st["color"],
                ls=st["ls"],
                mfc=mfc,
                label=lab,
            )
        miss = [r for r in rs if not r.get("ok")]
        if miss:  # at the top, one height per tool so that they do not hide each other
            y_miss = 1.0 if tool == "grazejax" else (0.08 if "max_step" in method else 0.28)
            ax_e.plot(
                [r["depth"] for r in miss],
                [y_miss] * len(miss),
                marker="X",
                ls="none",
                color=st["color"],
                mfc=mfc,
                ms=8,
                label=f"{lab}: wrong impact count",
            )
        if tool == "grazejax":
            ax_s.semilogx(
                [r["depth"] for r in rs],
                [r["steps"] for r in rs],
                marker=st["marker"],
                color=st["color"],
                label=f"{lab}",
            )


def _grazing_decor(ax_e, ax_s, ax_t, g, setup, spec):
    """The δ^(−1/2) and √(2δ) guides, the band below the solver's resolution, labels, legends."""
    d = np.logspace(-14, -1, 20)
    c0 = g["tol"] if setup == "rotation" else 1e-16
    ax_e.loglog(d, c0 / np.sqrt(d), color="gray", ls=":", label=f"{c0:g} · δ^(−1/2)")
    ax_e.loglog(
        d,
        np.sqrt(2 * d),
        color="gray",
        ls="--",
        lw=0.8,
        label="√(2δ): a contact placed at the minimum",
    )
    band = 100 * g["tol"] if setup == "rotation" else 1e-13
    for ax in (ax_e, ax_s, ax_t):
        ax.axvspan(band, 1e-15, color="0.9", zorder=0)
    ax_e.text(
        band,
        3e-17,
        " computed orbit's own error ≳ δ"
        if setup == "rotation"
        else " within grazejax's contact floor (γ)",
        fontsize=7,
        va="bottom",
    )
    ax_e.set_ylabel("impact-time error")
    ax_e.set_ylim(1e-17, 3)
    ax_e.set_title(spec["title"], fontsize=9)
    ax_s.set_ylabel("solver steps (incl. rejected, landing)")
    ax_s.set_title("grazejax steps vs depth (cost of the in-step dip search)", fontsize=9)
    ax_s.set_ylim(bottom=0)
    ax_t.set_ylabel("wall time per run [s]")
    ax_t.set_title("time per run", fontsize=9)
    for ax in (ax_e, ax_s, ax_t):
        ax.set_xlabel("depth δ of the excursion beyond Γ")
        ax.grid(True, alpha=0.3)
        ax.invert_xaxis()
    handles, labels = ax_e.get_legend_handles_labels()
    ax_t.legend(
        handles,
        labels,
        fontsize=7.5,
        loc="upper left",
        bbox_to_anchor=(1.02, 1.0),
        frameon=False,
    )
    ax_s.legend(fontsize=8)


def plot_effects(e, path):
    rows = e["rows"]
    fig, axes = plt.subplots(1, 3, figsize=(19, 6.5), sharey=True)
    labels = [r["effect"] for r in rows]
    y = np.arange(len(rows))[::-1]
    colors = {
        "base": "#1f77b4",
        "unrelated": "#7f7f7f",
        "effect": "#ff7f0e",
        "reference": "#2ca02c",
    }
    for ax, key, title in (
        (axes[0], "ratio_time", "run time / base (min of repeats; batch: per lane)"),
        (axes[1], "ratio_compiled_hlo", "optimized HLO size / base (.lower().compile().as_text())"),
        (axes[2], "ratio_hlo", "traced HLO size / base (.lower().as_text())"),
    ):
        vals = [r[key] for r in rows]
        ax.barh(y, [0 if v is None else v for v in vals], color=[colors[r["kind"]] for r in rows])
        for yi, v in zip(y, vals, strict=True):
            ax.text(
                0 if v is None else v,
                yi,
                " not timed (quick mode)" if v is None else f" {v:.2f}",
                va="center",
                fontsize=8,
            )
        ax.axvline(1.0, color="k", lw=0.8)
        ax.set_title(title, fontsize=10)
        ax.set_xlim(0, max(v for v in vals if v is not None) * 1.25)
    axes[0].set_yticks(y)
    axes[0].set_yticklabels(labels, fontsize=9)
    fig.suptitle(
        f"The cost of each effect ({e['scene']}, rtol {e['tol']:g}); grey: options that change "
        "nothing the run needs; green: diffrax alone, no events",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_scaling(s, path):
    fig, axes = plt.subplots(1, 2, figsize=(18, 5.2))
    rn = s["impacts"]["rows"]
    for key, lab, st in (
        ("grazejax_s", "grazejax Tsit5, final state", STYLE[("grazejax", "Tsit5")]),
        (
            "grazejax_log_s",
            "grazejax Tsit5, with impact log",
            {**STYLE[("grazejax", "Tsit5")], "ls": "--", "marker": "s"},
        ),
        ("heyoka_s", "heyoka", STYLE[("heyoka", "taylor")]),
        ("scipy_s", "scipy DOP853", STYLE[("scipy", "DOP853")]),
    ):
        pts = [(r["impacts"], r[key]) for r in rn if key in r]
        if pts:
            fit = s["impacts"]["fits"].get(key)
            lab2 = lab + (f" (∝ N^{fit['exponent']:.2f})" if fit else "")
            axes[0].loglog(
                *zip(*pts, strict=True),
                marker=st["marker"],
                color=st["color"],
                ls=st["ls"],
                label=lab2,
            )
    axes[0].set_xlabel("number of impacts N (t1 between impacts N and N+1)")
    axes[0].set_ylabel("wall time per run [s]")
    axes[0].set_title(
        f"cost vs number of impacts (forced impact oscillator, Tsit5, tol {s['impacts']['tol']:g})",
        fontsize=9,
    )
    rb = s["batch"]["rows"]
    bs = [r["batch"] for r in rb]
    fit = s["batch"]["fit"]
    axes[1].loglog(
        bs,
        [r["grazejax_s"] for r in rb],
        marker="o",
        label="grazejax vmap, total" + (f" (∝ B^{fit['exponent']:.2f})" if fit else ""),
    )
    axes[1].loglog(bs, [r["per_lane_s"] for r in rb], marker="s", label="grazejax vmap, per lane")
    if s["batch"]["heyoka_per_run_same_starts_s"]:
        h = s["batch"]["heyoka_per_run_same_starts_s"]
        axes[1].loglog(
            bs, [h * b for b in bs], color="black", ls=":", label="heyoka, B runs in a loop"
        )
        axes[1].axhline(h, color="black", ls="--", lw=0.8, label="heyoka per run")
    axes[1].loglog(
        bs,
        [rb[0]["grazejax_s"] * b / bs[0] for b in bs],
        color="gray",
        ls=":",
        lw=0.8,
        label=f"linear from B = {bs[0]}",
    )
    axes[1].set_xlabel("batch size B (exnonaxial, 17 impacts per lane)")
    axes[1].xaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
    axes[1].xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    axes[1].set_xticks(bs)
    axes[1].set_ylabel("wall time [s]")
    axes[1].set_title(f"cost vs batch size (Tsit5, tol {s['batch']['tol']:g})", fontsize=9)
    for ax in axes:
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    fig.suptitle("Scaling. " + C.SHARED_MACHINE_NOTE, fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_floquet(f, path):
    rows = sorted(f["rows"], key=lambda r: -r["tol"])
    tols = [r["tol"] for r in rows]
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(13, 4.8))
    ax.loglog(
        tols,
        [max(r["err_multipliers"], FLOOR) for r in rows],
        marker="o",
        label="Floquet multipliers",
    )
    ax.loglog(tols, [max(r["err_x0"], FLOOR) for r in rows], marker="s", label="orbit state x0")
    ax.loglog(tols, tols, color="gray", ls=":", lw=0.8, label="error = tol")
    ax.invert_xaxis()
    ax.set_xlabel("tolerance (rtol = atol)")
    ax.set_ylabel("max abs error")
    ax.set_title("accuracy (truth: closed-form stroboscopic map, 40 digits)", fontsize=9)
    bx.loglog(tols, [r["find_s"] for r in rows], marker="o", label="find_periodic_orbit (compiled)")
    bx.loglog(
        tols, [r["floquet_s"] for r in rows], marker="s", label="floquet_multipliers (compiled)"
    )
    bx.loglog(
        tols,
        [r["first_call_find_s"] + r["first_call_floquet_s"] for r in rows],
        marker="^",
        ls="--",
        label="both, first call at a new tolerance (compiles)",
    )
    bx.invert_xaxis()
    bx.set_xlabel("tolerance (rtol = atol)")
    bx.set_ylabel("wall time [s]")
    bx.set_title("cost per call", fontsize=9)
    for a in (ax, bx):
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle(
        "Floquet multipliers of the forced oscillator's period-1 impacting orbit (fixed period 2π/ω). "
        + C.SHARED_MACHINE_NOTE.split(":")[0],
        fontsize=9.5,
    )
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_headline(rows, ci, path):
    rows = [r for r in rows if r["case"] == HEADLINE_CASE]
    fig, ax = plt.subplots(figsize=(11.5, 6))
    ser = series(rows)
    for (tool, method, ms), rs in ser.items():
        if tool == "scipy" and ms is None and not any(r.get("ok") for r in rs):
            continue
        pts = [
            (r["time_min_s"], max(r["err_t"], FLOOR))
            for r in rs
            if r.get("ok") and r.get("err_t") is not None
        ]
        if not pts:
            continue
        st = style_of(tool, method)
        ax.loglog(
            *zip(*pts, strict=True),
            color=st["color"],
            marker=st["marker"],
            ls=st["ls"],
            ms=6,
            lw=1.5,
            mfc="none" if ms is not None else st["color"],
            label=label_of(tool, method, ms),
        )
    ax.set_xlabel("wall time per run (batch: per lane) [s]")
    ax.set_ylabel("max error of the 10 impact times")
    ax.set_title(
        f"ex1dof (paper), μ = {C.EX1DOF_MU}: 10 nearly grazing impacts, tolerances 1e-3…1e-13\n"
        "truth: "
        + ("heyoka in long double" if HAVE_HEYOKA else "SciPy DOP853 at rtol 1e-13 (no heyoka)")
        + "; " + C.SHARED_MACHINE_NOTE.split(":")[0],
        fontsize=9.5,
    )
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8.5, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    wrong = {}
    for r in rows:
        if r["tool"] == "scipy" and r.get("time_min_s") and not r.get("ok"):
            wrong.setdefault(
                r["method"] + ("" if r.get("max_step") is None else f" max_step {r['max_step']}"),
                [],
            ).append(f"{r['tol']:.0e}")
    if wrong:
        fig.text(
            0.985,
            0.03,
            "Wrong number of impacts (not shown):\n"
            + "\n".join(f"SciPy {k} at tol {', '.join(v)}" for k, v in wrong.items()),
            ha="right",
            fontsize=7.5,
            color="#d62728",
        )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
