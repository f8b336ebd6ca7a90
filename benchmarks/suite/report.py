"""The suite's text outputs: the headline table, summary.md, the findings, and suite.json
with one CSV file per table."""

from __future__ import annotations

import json
import os

import _cases as C

from .common import (
    ERROR_LEVELS,
    HAVE_HEYOKA,
    HAVE_SCIPY,
    HEADLINE_CASE,
    METRICS,
    fmt_e,
    fmt_ms,
    fmt_ratio,
    sanitize,
    write_csv,
)
from .work_precision import front


def headline_table(res):
    """Time to reach an impact-time error level on ex1dof, as ratios to one grazejax run."""
    wp = res["work_precision"]
    rows = [r for r in wp["rows"] if r["case"] == HEADLINE_CASE]
    by = {
        "grazejax": [r for r in rows if r["tool"] == "grazejax"],
        "batch in phase": [
            r for r in rows if r["tool"] == "grazejax-batch" and r.get("batch_starts") == "in phase"
        ],
        "batch random": [
            r
            for r in rows
            if r["tool"] == "grazejax-batch" and r.get("batch_starts") == "random phases"
        ],
        "scipy": [r for r in rows if r["tool"] == "scipy"],
        "heyoka": [r for r in rows if r["tool"] == "heyoka"],
    }
    lanes = next((r["lanes"] for r in by["batch random"]), None)
    levels = [1e-4, 1e-7, 1e-10]
    out = []
    for E in levels:
        f = {k: front(v, "err_t", E) for k, v in by.items()}
        out.append(
            {
                "level": E,
                **{
                    k: (
                        None
                        if v is None
                        else {
                            "method": v["method"],
                            "tol": v["tol"],
                            "max_step": v.get("max_step"),
                            "time_s": v["time_min_s"],
                        }
                    )
                    for k, v in f.items()
                },
            }
        )
    lines = [
        f"ex1dof (the paper's Example 5.2, μ = {C.EX1DOF_MU}): 10 nearly grazing impacts. Time to reach "
        "an impact-time error, **relative to one grazejax run** (< 1: faster than grazejax); each tool "
        "at its best method and loosest sufficient tolerance (rtol = atol), from a sweep 1e-3…1e-13. "
        "CPU, shared 2-core machine: read the ratios, not absolute times.",
        "",
        f"| error ≤ | grazejax, one run | grazejax vmap×{lanes or '–'}, per lane, lanes in phase | "
        f"grazejax vmap×{lanes or '–'}, per lane, random phases | SciPy solve_ivp | heyoka (Taylor) |",
        "|---|---|---|---|---|---|",
    ]
    for row in out:
        g = row["grazejax"]
        gtxt = (
            "not reached"
            if g is None
            else f"1 = {fmt_ms(g['time_s'])} ms ({g['method']}, {g['tol']:.0e})"
        )
        cells = " | ".join(
            _headline_cell(row, k) for k in ("batch in phase", "batch random", "scipy", "heyoka")
        )
        lines.append(f"| {row['level']:.0e} | {gtxt} | {cells} |")
    wrong = sorted(
        {
            f"{r['method']} {r['tol']:.0e}"
            for r in by["scipy"]
            if r.get("time_min_s") and not r.get("ok")
        }
    )
    lines += [
        "",
        (
            "SciPy without `max_step` steps over impacts (wrong impact count) at "
            + ", ".join(wrong)
            + "; with `max_step=0.05` it is always right, at a fixed high cost. "
            if wrong
            else ""
        )
        + ("" if HAVE_HEYOKA else f"heyoka is not installed (`{C.BENCH_INSTALL}`); measured with it: ")
        + "heyoka wins per run: few high-order Taylor steps (order 10–16), compiled by LLVM, at "
        "~1 µs each; a grazejax step costs ~4× a plain diffrax step (the in-step dip search and "
        "landing logic). grazejax's own strengths: batches whose lanes impact together, "
        "derivatives through impacts, and no missed dips. Full tables and plots: summary.md.",
    ]
    return out, "\n".join(lines) + "\n"


def _headline_cell(row, k):
    """Tool k's time at this error level, as a ratio to grazejax's (or why there is none)."""
    g = row["grazejax"]
    v = row[k]
    if v is None and not HAVE_HEYOKA and k != "scipy":  # heyoka, or the batch refs
        return "not run: heyoka not installed"
    if v is None and not HAVE_SCIPY and k == "scipy":
        return "not run: SciPy not installed"
    if v is None:
        return "not reached"
    if g is None:
        return fmt_ms(v["time_s"]) + " ms"
    meth = v["method"].split(" vmap")[0]
    ms = f", max_step {v['max_step']}" if v.get("max_step") else ""
    return f"**{fmt_ratio(v['time_s'] / g['time_s'])}×** ({meth}{ms}, {v['tol']:.0e})"


def render_summary(res):
    S = res["settings"]
    m, v = res["machine"], res["versions"]
    L = [
        f"# grazejax benchmark suite ({res['mode']})",
        "",
        f"**{C.SHARED_MACHINE_NOTE[0].upper() + C.SHARED_MACHINE_NOTE[1:]}.** Load average "
        f"{m['loadavg_start'][0]:.1f} at start, {m['loadavg_end'][0]:.1f} at end; total wall time "
        f"{res['total_wall_s']:.0f} s.",
        "",
        f"Machine: {m['platform']}, {m['cpu_model']}, {m['cpu_count']} CPUs (affinity {m['cpu_affinity']}), "
        f"JAX backend {m['jax_backend']}. Versions: "
        + ", ".join(f"{k} {val}" for k, val in v.items() if val)
        + ".",
        "",
        "Every number below and every plotted point is in `suite.json` (and the CSV files). "
        "rtol = atol for every tool; grazejax times are of a `jax.jit`-compiled call after "
        "compilation, with `block_until_ready`; all times are the minimum of repeats "
        f"(about {S['budget']} s of repeats per point).",
        "",
    ]
    if "headline_md" in res:
        L += ["## Headline", "", res["headline_md"], "![headline](headline.png)", ""]
    for key, part in (
        ("work_precision", _summary_work_precision),
        ("grazing", _summary_grazing),
        ("effects", _summary_effects),
        ("compile", _summary_compile),
        ("scaling", _summary_scaling),
        ("floquet", _summary_floquet),
    ):
        if res.get(key):
            L += part(res[key])
    if res.get("findings"):
        L += ["## Findings", ""] + [f"- {x}" for x in res["findings"]] + [""]
    return "\n".join(L)


def _summary_work_precision(wp):
    """Section 1: the cases and their truths, then one table per case."""
    L = [
        "## 1. Work-precision",
        "",
        "Errors: max abs error of all impact times (err t), of all post-impact states (err post) and "
        "of the state at t1 after all impacts (err final), against the ground truth; a run with a "
        "different number of impacts than the truth counts as failed (shown as X in the plots).",
        "",
        "| case | ground truth (how obtained) | check |",
        "|---|---|---|",
    ]
    for ci in wp["cases"].values():
        chk = (
            ci.get("truth_check_heyoka_longdouble")
            or ci.get("truth_check_heyoka_double_1e-15")
            or {}
        )
        if "max_diff_t" in chk:
            chk_txt = (
                f"heyoka long double agrees: Δt {fmt_e(chk['max_diff_t'])}, Δpost "
                f"{fmt_e(chk['max_diff_post'])}, Δfinal {fmt_e(chk['max_diff_final'])}"
            )
        elif "err_t" in chk:
            chk_txt = (
                f"heyoka double tol 1e-15 vs reference: err t {fmt_e(chk['err_t'])}, post "
                f"{fmt_e(chk['err_post'])}"
            )
        else:
            chk_txt = "—"
        L.append(
            f"| {ci['title']} ({len(ci['truth']['impact_times'])} impacts, t1 = {ci['t1']:g}) | "
            f"{ci['truth_method']} | {chk_txt} |"
        )
    L += [
        "",
        "Units of the evaluation axis: grazejax = solver steps (accepted, rejected and landing "
        "steps) × stages per step (Tsit5, Dopri5: 6; Dopri8: 13; FSAL counted once); Kvaerno5 and SciPy: "
        "calls of f counted (SciPy: including finite-difference Jacobian columns; grazejax: a "
        "`jax.debug.callback` in f, a vmapped Jacobian evaluation counting once); heyoka: Taylor "
        "steps (one Taylor jet of order ~p each: a different unit, shown for scale only).",
    ]
    if wp["evals_calibration"]:
        ratios = [c["counted_over_nominal"] for c in wp["evals_calibration"]]
        L += [
            f"Calibration: counted f calls / (steps × stages) = {min(ratios):.2f}…{max(ratios):.2f} "
            "over the explicit solvers (the extra calls are the Newton correction of each event time "
            "and restarts after jumps)."
        ]
    L += [""]
    for name, ci in wp["cases"].items():
        L += _summary_wp_case(name, ci, wp)
    return L


def _summary_wp_case(name, ci, wp):
    """One case: its runs, and the time to reach each error level."""
    L = [f"### {ci['title']}", "", f"![wp](wp_{name}.png)", "", ci["notes"], ""]
    rows = [r for r in wp["rows"] if r["case"] == name]
    L += [
        "| tool | method | tol | ms/run | evals | err t | err post | err final | impacts |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        meth = r["method"] + (f" max_step {r['max_step']}" if r.get("max_step") else "")
        if r.get("tol") is None or r.get("time_min_s") is None:  # a skipped or failed sweep
            L.append(
                f"| {r['tool']} | {meth} | — | — | — | — | — | — | {r.get('status')} |"
            )
            continue
        ev = r.get("evals")
        ev_txt = "—" if ev is None else f"{ev:.0f}"
        L.append(
            f"| {r['tool']} | {meth} | {r['tol']:.0e} | {fmt_ms(r.get('time_min_s'))} | {ev_txt} | "
            f"{fmt_e(r.get('err_t'))} | {fmt_e(r.get('err_post'))} | {fmt_e(r.get('err_final'))} | "
            f"{r.get('impacts_found')}/{r.get('impacts_expected')}{'' if r.get('ok') else ' ✗'} |"
        )
    L += [
        "",
        "Time to reach each error level (cheapest run with error ≤ level); ratio grazejax/SciPy "
        "and grazejax/heyoka (< 1: grazejax faster):",
        "",
        "| level | "
        + " | ".join(f"{ml}: gj/scipy, gj/heyoka" for ml in METRICS.values())
        + " |",
        "|---|" + "---|" * len(METRICS),
    ]
    dom = ci["dominance"]
    for i, E in enumerate(ERROR_LEVELS):
        cells = []
        for metric in METRICS:
            lv = dom[metric]["levels"][i]
            s_txt = (
                fmt_ratio(lv["grazejax_over_scipy"])
                if lv["grazejax_over_scipy"] is not None
                else (
                    "gj only"
                    if lv["grazejax"] and not lv["scipy"]
                    else ("scipy only" if lv["scipy"] else "neither")
                )
            )
            h_txt = (
                fmt_ratio(lv["grazejax_over_heyoka"])
                if lv["grazejax_over_heyoka"] is not None
                else "—"
            )
            cells.append(f"{s_txt}, {h_txt}")
        L.append(f"| {E:.0e} | " + " | ".join(cells) + " |")
    L += [
        "",
        "SciPy is not installed: not compared."
        if any(d["dominates_scipy_everywhere"] is None for d in dom.values())
        else "grazejax dominates SciPy at every level 1e-3…1e-11: "
        + "; ".join(
            f"{METRICS[k]} **{'yes' if d['dominates_scipy_everywhere'] else 'no'}** (worst gj/scipy "
            f"{fmt_ratio(d['worst_ratio_grazejax_over_scipy'])} at {fmt_e(d['worst_level'], 0)}"
            + (
                f"; ties within ±10% at {', '.join(fmt_e(x, 0) for x in d['ties_within_10pct'])}"
                if d["ties_within_10pct"]
                else ""
            )
            + _not_reached_text(d)
            + ")"
            for k, d in dom.items()
        ),
        "",
    ]
    return L


def _summary_grazing(g):
    """Section 2: the fitted exponents, the depths with a wrong impact count, every run."""
    L = [
        "## 2. The cost of grazing",
        "",
        f"Every tool at tol {g['tol']:g}.",
        "",
        "![grazing](grazing.png)",
        "",
    ]
    for spec in g["setups"].values():
        L += [
            f"**{spec['title']}.** {spec['setup']}.",
            "",
            f"Fitted err_t ∝ δ^p over depths ≥ {spec['fit_min_depth']:g}: "
            + "; ".join(
                f"{k}: p = {v['exponent']:.2f}"
                for k, v in sorted(spec["fits_err_t_vs_depth"].items())
            )
            + ".",
            "Wrong number of impacts (missed or extra) at depths: "
            + "; ".join(
                f"{k}: {', '.join(f'{d:g}' for d in v) if v else 'none'}"
                for k, v in sorted(spec["wrong_impact_count_at_depths"].items())
            )
            + ".",
            "",
        ]
    L += [
        "A tangential approach loses impact-time accuracy as δ^(−1/2): a state error ε moves the "
        "crossing by ~ε/|Φ'|, and |Φ'| at the crossing is √(2δ|Φ''|). In the rotation the solver's "
        "own error (~ the tolerance) perturbs δ itself, so depths below ~100× the tolerance are "
        'decided by the computed orbit, not the exact one (a "miss" there is a miss of the '
        "computed trajectory); the parabola is integrated exactly by every Runge-Kutta method, so "
        "every dip above grazejax's contact floor (~1e-14 here) must be found.",
        "",
        "| setup | δ | tool | method | found/expected | kinds | err t | steps | ms |",
        "|---|---:|---|---|---|---|---:|---:|---:|",
    ]
    for r in g["rows"]:
        L.append(
            f"| {r['setup']} | {r['depth']:+.0e} | {r['tool']} | {r['method']} | "
            f"{r['impacts_found']}/{r['impacts_expected']} | {r.get('kinds', '')} | {fmt_e(r.get('err_t'))} | "
            f"{r.get('steps')} | {fmt_ms(r['time_min_s'])} |"
        )
    L += [""]
    return L


def _summary_effects(e):
    """Section 3: each effect as ratios to the final-state-only run."""
    L = [
        "## 3. The cost of each effect",
        "",
        f"{e['scene']}, rtol = atol = {e['tol']:g}. Time: min of "
        "repeats of the compiled call (batch: per lane). Optimized HLO: the compiled program's text "
        "(`jax.jit(f).lower(...).compile().as_text()`), traced HLO: before XLA's optimizations "
        "(`.lower(...).as_text()`). Compile: XLA's `compile()` alone.",
        "",
        "![effects](effects.png)",
        "",
        "| run | time / base | optimized HLO / base | traced HLO / base | optimized HLO chars | compile s |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for r in e["rows"]:
        rt = "— (HLO only)" if r["ratio_time"] is None else f"{r['ratio_time']:.2f}"
        cs = "—" if r["compile_s"] is None else f"{r['compile_s']:.2f}"
        L.append(
            f"| {r['effect']} | {rt} | {r['ratio_compiled_hlo']:.3f} | {r['ratio_hlo']:.3f} | "
            f"{r['compiled_hlo_chars']} | {cs} |"
        )
    p = e["per_step_overhead"]
    L += [
        "",
        f"Per solver step, grazejax's loop (event search, landing, restart guard) costs "
        f"{p['ratio']:.2f}× a plain `diffrax.diffeqsolve` step of the same flow without events "
        f"({1e6 * p['grazejax_s_per_step']:.2f} vs {1e6 * p['diffrax_s_per_step']:.2f} µs).",
        "",
    ]
    return L


def _summary_compile(c):
    """Section 4: compile time per entry point."""
    L = [
        "## 4. Compile times",
        "",
        c["method"] + f"; goal < {c['goal_s']:g} s. Rows from the "
        "effects section: tracing + lowering plus XLA's compile, timed separately.",
        "",
        "| entry point | compile s |",
        "|---|---:|",
    ]
    for r in c["rows"]:
        val = (
            f"{r['compile_s']:.2f}" if "compile_s" in r else r.get("skipped") or r.get("error")
        )
        L.append(f"| {r['entry']} | {val} |")
    L += [""]
    return L


def _summary_scaling(s):
    """Section 5: time vs impacts and vs batch size, with the fits."""
    L = [
        "## 5. Scaling",
        "",
        s["scene"] + "; batch: " + s["batch"]["scene"] + ".",
        "",
        "![scaling](scaling.png)",
        "",
        "| impacts | steps | grazejax ms (final state) | grazejax ms (with impact log) | heyoka ms | scipy ms |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for r in s["impacts"]["rows"]:
        L.append(
            f"| {r['impacts']} | {r['grazejax_steps']} | {fmt_ms(r['grazejax_s'])} | {fmt_ms(r['grazejax_log_s'])} | "
            f"{fmt_ms(r.get('heyoka_s'))} | {fmt_ms(r.get('scipy_s'))} |"
        )
    L += [
        "",
        "Fitted exponents (time ∝ N^p over N ≥ 16; linear fit a + b N): "
        + "; ".join(
            f"{k.replace('_s', '')}: p = {v['exponent']:.2f}, b = {1e6 * v['linear_per_impact_s']:.1f} µs/impact"
            for k, v in s["impacts"]["fits"].items()
        )
        + ".",
        "",
        "| batch | total ms | ms per lane | compile s |",
        "|---:|---:|---:|---:|",
    ]
    for r in s["batch"]["rows"]:
        L.append(
            f"| {r['batch']} | {fmt_ms(r['grazejax_s'])} | {fmt_ms(r['per_lane_s'])} | {r['compile_s']:.1f} |"
        )
    fb = s["batch"]["fit"]
    h = s["batch"]["heyoka_per_run_same_starts_s"]
    L += [
        "",
        (f"Fitted: total time ∝ B^{fb['exponent']:.2f} over B ≥ 16. " if fb else "")
        + (f"heyoka per run over the same starts: {fmt_ms(h)} ms." if h else ""),
        "",
    ]
    return L


def _summary_floquet(f):
    """Section 6: the multipliers' errors and costs per tolerance (or why skipped)."""
    L = ["## 6. Floquet multipliers", ""]
    if "rows" in f:
        L += [
            f"Truth: {f['truth_method']}; multipliers {f['truth']['multipliers']}. Peers: {f['peers']}.",
            "",
            "Both functions take rtol/atol as static values: every new tolerance compiles again "
            "(first-call column).",
            "",
            "![floquet](floquet.png)",
            "",
            "| tol | find_periodic_orbit ms | floquet_multipliers ms | first calls s (compiling) | multiplier error | orbit error |",
            "|---:|---:|---:|---:|---:|---:|",
        ]
        for r in f["rows"]:
            L.append(
                f"| {r['tol']:.0e} | {fmt_ms(r['find_s'])} | {fmt_ms(r['floquet_s'])} | "
                f"{r['first_call_find_s']:.1f} + {r['first_call_floquet_s']:.1f} | {fmt_e(r['err_multipliers'])} | "
                f"{fmt_e(r['err_x0'])} |"
            )
    else:
        L += [f.get("skipped") or ("failed: " + f.get("error", "?"))]
    L += [""]
    return L


def _not_reached_text(d):
    nr = d.get("not_reached_by_grazejax") or []
    if not nr:
        return ""
    return "; not reached by grazejax at tol ≥ 1e-13: " + ", ".join(
        f"{fmt_e(x['level'], 0)} (SciPy {x['method']}"
        + (f" max_step {x['max_step']}" if x.get("max_step") else "")
        + f", {fmt_ms(x['time_s'])} ms)"
        for x in nr
    )


def findings(res):
    """Plain statements derived from the numbers: who wins where, and by how much."""
    out = []
    for key, part in (
        ("work_precision", _findings_work_precision),
        ("effects", _findings_effects),
        ("scaling", _findings_scaling),
        ("grazing", _findings_grazing),
    ):
        if res.get(key):
            out += part(res[key])
    return out


def _findings_work_precision(wp):
    """Per case: against SciPy and heyoka, wrong impact counts; then what batching gains."""
    out = []
    for name, ci in wp["cases"].items():
        d = ci["dominance"]
        if any(v["dominates_scipy_everywhere"] is None for v in d.values()):
            out.append(f"**{name}**: not compared with SciPy (not installed).")
            continue
        verdict = "; ".join(
            f"{METRICS[k]}: {'yes' if v['dominates_scipy_everywhere'] else 'no'} (worst gj/scipy "
            f"{fmt_ratio(v['worst_ratio_grazejax_over_scipy'])} at {fmt_e(v['worst_level'], 0)}"
            f"{_not_reached_text(v)})"
            for k, v in d.items()
        )
        out.append(
            f"**{name}**: grazejax (single runs, best solver) faster than SciPy at every error "
            f"level 1e-3…1e-11 — {verdict}."
        )
        hy = [
            lv["grazejax_over_heyoka"]
            for lv in d["err_t"]["levels"]
            if lv["grazejax_over_heyoka"]
        ]
        if hy:
            out.append(
                f"**{name}**: heyoka is faster per run at equal impact-time error: grazejax/heyoka "
                f"= {min(hy):.2g}…{max(hy):.2g}."
            )
        missed = sorted(
            {
                f"{r['method']} tol {r['tol']:.0e}"
                for r in wp["rows"]
                if r["case"] == name
                and r["tool"] in ("grazejax", "scipy")
                and r.get("tol")
                and r.get("time_min_s")
                and not r.get("ok")
            }
        )
        if missed:
            out.append(
                f"**{name}**: wrong number of impacts: {', '.join(missed)}. (grazejax at loose "
                "tolerances: the computed orbit's own error exceeds the depth of near-grazing dips, "
                "so it does not dip; SciPy: steps over dips it has computed.)"
            )
    hb = [r for r in wp["rows"] if r["tool"] == "grazejax-batch"]
    if hb:

        def per_lane(kind):
            return {r["tol"]: r["time_min_s"] for r in hb if r.get("batch_starts") == kind}

        single = {
            r["tol"]: r["time_min_s"]
            for r in wp["rows"]
            if r["case"] == HEADLINE_CASE
            and r["tool"] == "grazejax"
            and r["method"] == hb[0]["method"].split()[0]
        }
        ip, rp = per_lane("in phase"), per_lane("random phases")
        g_ip = [single[t] / ip[t] for t in ip if t in single]
        g_rp = [single[t] / rp[t] for t in rp if t in single]
        if g_ip and g_rp:
            out.append(
                f"Batching ({hb[0]['lanes']} lanes, ex1dof): per-lane speed-up over single runs "
                f"{min(g_ip):.1f}…{max(g_ip):.1f}× when the lanes impact in phase, only "
                f"{min(g_rp):.1f}…{max(g_rp):.1f}× at random phases (same step counts): under vmap "
                "an iteration pays for the landing/impact work whenever any lane needs it."
            )
    return out


def _findings_effects(e):
    """What the impact log costs, and a grazejax step against a plain diffrax step."""
    out = []
    rows = {r["effect"]: r for r in e["rows"]}
    logs = [r for k, r in rows.items() if k.startswith("+ impact log") and r["ratio_time"]]
    if logs:
        out.append(
            "The impact log is not free: "
            + ", ".join(
                f"{r['effect'][len('+ impact log ') :]} ×{r['ratio_time']:.2f}" for r in logs
            )
            + " the final-state-only run, although the optimized programs differ by < 1% in size (the cost "
            "is in carrying the log buffers through the loop, not in extra code).",
        )
    out.append(
        f"Per solver step grazejax costs {e['per_step_overhead']['ratio']:.1f}× a plain diffrax "
        "step of the same flow (event search with the dense interpolant, landing and restart logic)."
    )
    return out


def _findings_scaling(s):
    """The fitted exponents in the number of impacts and the batch size."""
    out = []
    f = s["impacts"]["fits"]
    if "grazejax_s" in f and "grazejax_log_s" in f:
        out.append(
            f"Cost vs impacts: ∝ N^{f['grazejax_s']['exponent']:.2f} for the final state, "
            f"N^{f['grazejax_log_s']['exponent']:.2f} when the impact log is returned (per-step cost "
            "grows with the rows written). heyoka "
            + (f"N^{f['heyoka_s']['exponent']:.2f}" if "heyoka_s" in f else "—")
            + "."
        )
    fb = s["batch"]["fit"]
    if fb:
        out.append(
            f"Cost vs batch size: ∝ B^{fb['exponent']:.2f} over B = {fb['over']} (sub-linear: per-lane "
            "cost falls as lanes share iterations)"
            + (
                f", ∝ B^{fb['exponent_largest3']:.2f} over B = {fb['over_largest3']}"
                if "exponent_largest3" in fb
                else ""
            )
            + "."
        )
    return out


def _findings_grazing(g):
    """The impact-time error exponents in the depth, and grazejax's wrong impact counts."""
    out = []
    for setup, spec in g["setups"].items():
        fits = "; ".join(
            f"{k} {v['exponent']:.2f}" for k, v in sorted(spec["fits_err_t_vs_depth"].items())
        )
        gj_wrong = {
            k: v
            for k, v in spec["wrong_impact_count_at_depths"].items()
            if k.startswith("grazejax") and v
        }
        out.append(
            f"Grazing ({setup}): impact-time error exponents {fits} (√δ loss: −0.5). grazejax wrong "
            f"impact counts: {gj_wrong or 'none'}."
        )
    return out


# The columns of each CSV file (one row per entry of the section's rows in suite.json).
WP_COLUMNS = [
    "case",
    "tool",
    "method",
    "tol",
    "max_step",
    "time_min_s",
    "time_median_s",
    "repeats",
    "evals",
    "evals_kind",
    "steps",
    "f_calls_counted",
    "nfev_reported",
    "taylor_order",
    "impacts_found",
    "impacts_expected",
    "err_t",
    "err_post",
    "err_final",
    "ok",
    "status",
    "lanes",
]


GRAZING_COLUMNS = [
    "setup",
    "depth",
    "depth_exact",
    "tool",
    "method",
    "tol",
    "time_min_s",
    "steps",
    "accepted",
    "kinds",
    "impacts_found",
    "impacts_expected",
    "err_t",
    "err_post",
    "err_final",
    "ok",
]


EFFECTS_COLUMNS = [
    "effect",
    "kind",
    "time_min_s",
    "time_median_s",
    "repeats",
    "lanes",
    "ratio_time",
    "hlo_chars",
    "ratio_hlo",
    "compiled_hlo_chars",
    "ratio_compiled_hlo",
    "lower_s",
    "compile_s",
    "steps",
]


COMPILE_COLUMNS = [
    "entry",
    "compile_s",
    "trace_lower_s",
    "xla_compile_s",
    "first_call_s",
    "second_call_s",
    "skipped",
    "error",
]


SCALING_IMPACTS_COLUMNS = [
    "impacts",
    "t1",
    "grazejax_s",
    "grazejax_log_s",
    "grazejax_found",
    "grazejax_steps",
    "heyoka_s",
    "scipy_s",
]


SCALING_BATCH_COLUMNS = [
    "batch",
    "grazejax_s",
    "per_lane_s",
    "compile_s",
]


FLOQUET_COLUMNS = [
    "tol",
    "time_min_s",
    "err_multipliers",
    "err_x0",
]


def write_outputs(res, out):
    clean = sanitize(res)
    with open(os.path.join(out, "suite.json"), "w") as fh:
        json.dump(clean, fh, indent=1, allow_nan=False)
    if "work_precision" in res:
        write_csv(
            os.path.join(out, "work_precision.csv"), clean["work_precision"]["rows"], WP_COLUMNS
        )
    if "grazing" in res:
        write_csv(os.path.join(out, "grazing.csv"), clean["grazing"]["rows"], GRAZING_COLUMNS)
    if "effects" in res:
        write_csv(os.path.join(out, "effects.csv"), clean["effects"]["rows"], EFFECTS_COLUMNS)
    if "compile" in res:
        write_csv(os.path.join(out, "compile.csv"), clean["compile"]["rows"], COMPILE_COLUMNS)
    if "scaling" in res:
        scaling = clean["scaling"]
        write_csv(
            os.path.join(out, "scaling_impacts.csv"),
            scaling["impacts"]["rows"],
            SCALING_IMPACTS_COLUMNS,
        )
        write_csv(
            os.path.join(out, "scaling_batch.csv"), scaling["batch"]["rows"], SCALING_BATCH_COLUMNS
        )
    if res.get("floquet", {}).get("rows"):
        write_csv(os.path.join(out, "floquet.csv"), clean["floquet"]["rows"], FLOQUET_COLUMNS)
    with open(os.path.join(out, "summary.md"), "w") as fh:
        fh.write(render_summary(res))
