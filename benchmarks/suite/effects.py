"""Section 3, the cost of each effect (impact log, dense output, Jacobian, batch, an unused
surface) on one scene, and the vmapped run it shares with section 5."""

from __future__ import annotations

import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from _cases import first_minus_second, log, measure

import grazejax as gj

EFFECTS_TOL = 1e-8
_BATCH: dict = {}  # the vmapped final-state run of the effects scene, shared with section 5


def effects_setup(cases, max_lanes):
    """exnonaxial from x0 (0, 1.2) to t1 = 100 (17 impacts), Tsit5, rtol = atol = 1e-8; and
    batch starts on circles of radius 1.2…1.212 at random phases (all with 17 impacts)."""
    if "fn" not in _BATCH:
        case = cases["exnonaxial"]

        def final(x, a):
            return gj.simulate(
                case.scene, x, 0.0, case.t1, a, rtol=EFFECTS_TOL, atol=EFFECTS_TOL, max_impacts=32
            ).x_final

        _BATCH["fn"] = jax.jit(jax.vmap(final, in_axes=(0, None)))
        _BATCH["compile_s"] = {}
    if len(_BATCH.get("starts", ())) < max_lanes:
        rng = np.random.default_rng(3)
        r = 1.2 * (1 + 0.01 * rng.random(max_lanes))
        ph = rng.uniform(-0.5, 0.5, max_lanes)
        _BATCH["starts"] = np.stack([r * np.sin(ph), r * np.cos(ph)], axis=1)
    return _BATCH


def batch_timing(cases, lanes, S):
    """Compile (once per batch size) and time the shared vmapped run on `lanes` starts."""
    B = effects_setup(cases, lanes)
    xs = jnp.asarray(B["starts"][:lanes])
    args = cases["exnonaxial"].args
    if lanes not in B["compile_s"]:
        B["compile_s"][lanes] = first_minus_second(lambda: B["fn"](xs, args))["compile_s"]
    _, tm = measure(
        lambda: jax.block_until_ready(B["fn"](xs, args)), 2 * S["budget"], 3 * S["max_rep"], 3
    )
    lowered = B["fn"].lower(xs, args)
    return tm, B["compile_s"][lanes], (len(lowered.as_text()), len(lowered.compile().as_text()))


def section_effects(cases, S, res):
    """The cost of each effect on one scene (exnonaxial, 17 impacts, Tsit5, rtol 1e-8)."""
    case = cases["exnonaxial"]
    tol = EFFECTS_TOL
    t1 = case.t1
    scene, args = case.scene, case.args
    x0 = jnp.asarray(case.x0)
    lanes = S["effects_lanes"]
    sim = _effects_sim(case)
    full = S["effects_full"]
    V = _option_variants(sim, x0, args) + _effect_variants(case, sim, x0, lanes)
    if not full:  # quick: fewer variants (each timed one is one compilation)
        drop = (
            "log (max_impacts 32)",
            "log (max_impacts 48)",
            "x0 and K",
            "log (max_impacts 4096)",
            "max_steps 200000",
        )
        V = [v for v in V if not any(d in v[0] for d in drop)]
    log(f"3) effects: exnonaxial, {case.t1:g} time units, 17 impacts, Tsit5 rtol {tol:g}")
    rows = []
    for label, kind, fn, fargs in V:
        if kind == "batch":
            rows.append(_batch_row(cases, label, lanes, S))
        else:
            rows.append(_variant_row(label, kind, fn, fargs, S, full))
    reference, tm, nsteps = _diffrax_alone(scene, x0, args, t1, tol, S)
    gj_steps = int(
        gj.simulate(scene, x0, 0.0, t1, args, rtol=tol, atol=tol, max_impacts=32).num_steps
    )
    base = rows[0]
    base["steps"] = gj_steps
    rows.append(reference)
    per_step = _ratios_to_base(rows, base, gj_steps, tm, nsteps)
    res["effects"] = {
        "rows": rows,
        "per_step_overhead": per_step,
        "tol": tol,
        "scene": "exnonaxial, x0 (0, 1.2), t1 100 (17 impacts), Tsit5",
    }
    return rows


def _effects_sim(case):
    """`simulate` on the effects scene at EFFECTS_TOL up to t1, max_impacts 32 unless given."""
    tol, t1, scene = EFFECTS_TOL, case.t1, case.scene

    def sim(x0_, a, scene_=scene, **kw):
        kw = {"max_impacts": 32, **kw}
        return gj.simulate(scene_, x0_, 0.0, t1, a, rtol=tol, atol=tol, **kw)

    return sim


def _option_variants(sim, x0, args):
    """The base run (final state only) and options it does not use: (label, kind, fn, args)."""
    unused_args = {**args, "unused": jnp.ones(8)}
    return [
        (
            "base: final state only (max_impacts 32)",
            "base",
            lambda x, a: sim(x, a).x_final,
            (x0, args),
        ),
        (
            "base again, zeno_rtol 1e-5 (unused here)",
            "unrelated",
            lambda x, a: sim(x, a, zeno_rtol=1e-5).x_final,
            (x0, args),
        ),
        (
            "base again, max_steps 200000 (not reached)",
            "unrelated",
            lambda x, a: sim(x, a, max_steps=200_000).x_final,
            (x0, args),
        ),
        (
            "base again, args with an unused leaf",
            "unrelated",
            lambda x, a: sim(x, a).x_final,
            (x0, unused_args),
        ),
        (
            "base again, max_impacts 4096, final state only",
            "unrelated",
            lambda x, a: sim(x, a, max_impacts=4096).x_final,
            (x0, args),
        ),
    ]


def _effect_variants(case, sim, x0, lanes):
    """Each effect a run can ask for, as (label, kind, fn, args); the batch is timed apart."""
    args = case.args
    ts = jnp.linspace(0.0, case.t1, 1000)
    extra = gj.Scene(
        case.scene.vector_field,
        [
            *case.scene.surfaces,
            gj.Surface(
                phi=lambda t, x, a: 10.0 - x[0], jump=lambda t, x, a: x, name="never reached"
            ),
        ],
    )
    return [
        ("+ impact log (max_impacts 32)", "effect", lambda x, a: sim(x, a), (x0, args)),
        (
            "+ impact log (max_impacts 48)",
            "effect",
            lambda x, a: sim(x, a, max_impacts=48),
            (x0, args),
        ),
        (
            "+ impact log (max_impacts 100, the default)",
            "effect",
            lambda x, a: sim(x, a, max_impacts=100),
            (x0, args),
        ),
        (
            "+ impact log (max_impacts 4096)",
            "effect",
            lambda x, a: sim(x, a, max_impacts=4096),
            (x0, args),
        ),
        (
            "+ dense trajectory (saveat, 1000 times)",
            "effect",
            lambda x, a: sim(x, a, saveat=ts).xs,
            (x0, args),
        ),
        (
            "+ Jacobian (jax.jacfwd, ∂x(t1)/∂x0)",
            "effect",
            jax.jacfwd(lambda x, a: sim(x, a).x_final),
            (x0, args),
        ),
        (
            "+ Jacobian w.r.t. x0 and K (3 tangents)",
            "effect",
            lambda x, a: jax.jacfwd(lambda x_, k: sim(x_, {"K": k}).x_final, argnums=(0, 1))(
                x, a["K"]
            ),
            (x0, args),
        ),
        (f"+ batch (jax.vmap × {lanes}), per lane", "batch", None, None),
        (
            "+ a surface piece never reached",
            "effect",
            lambda x, a: sim(x, a, scene_=extra).x_final,
            (x0, args),
        ),
    ]


def _batch_row(cases, label, lanes, S):
    """The shared vmapped run on `lanes` starts, per lane."""
    tm, comp, (hlo, chlo) = batch_timing(cases, lanes, S)
    return {
        "effect": label,
        "kind": "effect",
        "hlo_chars": hlo,
        "compiled_hlo_chars": chlo,
        "compile_s": comp,
        "time_min_s": tm["min_s"] / lanes,
        "time_median_s": tm["median_s"] / lanes,
        "repeats": tm["repeats"],
        "lanes": lanes,
    }


def _variant_row(label, kind, fn, fargs, S, full):
    """One variant lowered, compiled and (unless an unused option in quick mode) timed."""
    # Lower (trace) and compile explicitly: the compile time is that of XLA alone, and the
    # optimized HLO shows what the compiled program really contains (XLA removes outputs
    # nobody asked for, e.g. the impact log of a final-state-only run).
    t = time.perf_counter()
    lowered = jax.jit(fn).lower(*fargs)
    lower_s = time.perf_counter() - t
    t = time.perf_counter()
    compiled = lowered.compile()
    compile_s = time.perf_counter() - t
    row = {
        "effect": label,
        "kind": kind,
        "hlo_chars": len(lowered.as_text()),
        "compiled_hlo_chars": len(compiled.as_text()),
        "lower_s": lower_s,
        "compile_s": compile_s,
        "lanes": 1,
    }
    if kind == "unrelated" and not full:
        # Quick mode: compiled and compared, not timed (same optimized program size).
        row.update(
            {
                "time_min_s": None,
                "time_median_s": None,
                "repeats": 0,
                "note": "not timed (quick mode)",
            }
        )
        return row
    _, tm = measure(
        lambda compiled=compiled, fargs=fargs: jax.block_until_ready(compiled(*fargs)),
        2 * S["budget"],
        3 * S["max_rep"],
        min_repeats=3,
    )
    row.update(
        {"time_min_s": tm["min_s"], "time_median_s": tm["median_s"], "repeats": tm["repeats"]}
    )
    return row


def _diffrax_alone(scene, x0, args, t1, tol, S):
    """The loop's own overhead: diffrax alone on the same flow (no events), per step. Returns
    its row, its timings and its number of steps."""
    term = diffrax.ODETerm(scene.vector_field)
    ctrl = diffrax.PIDController(rtol=tol, atol=tol)

    def plain(x, a):
        s_ = diffrax.diffeqsolve(
            term,
            diffrax.Tsit5(),
            0.0,
            t1,
            None,
            x,
            a,
            stepsize_controller=ctrl,
            saveat=diffrax.SaveAt(t1=True),
            max_steps=100_000,
        )
        return s_.ys[-1], s_.stats["num_steps"]

    lowered = jax.jit(plain).lower(x0, args)
    hlo = len(lowered.as_text())
    t = time.perf_counter()
    jp = lowered.compile()
    c = {"compile_s": time.perf_counter() - t}
    chlo = len(jp.as_text())
    (_, nsteps), tm = measure(
        lambda: jax.block_until_ready(jp(x0, args)), 2 * S["budget"], 3 * S["max_rep"], 3
    )
    row = {
        "effect": "diffrax.diffeqsolve of the flow alone (no events)",
        "kind": "reference",
        "hlo_chars": hlo,
        "compiled_hlo_chars": chlo,
        "compile_s": c["compile_s"],
        "time_min_s": tm["min_s"],
        "time_median_s": tm["median_s"],
        "repeats": tm["repeats"],
        "lanes": 1,
        "steps": int(nsteps),
    }
    return row, tm, nsteps


def _ratios_to_base(rows, base, gj_steps, tm, nsteps):
    """Each row's time and HLO sizes over the base run's, logged; returns grazejax's cost per
    step against diffrax alone (timings `tm` over `nsteps` steps)."""
    for r_ in rows:
        r_["ratio_time"] = (
            None if r_["time_min_s"] is None else r_["time_min_s"] / base["time_min_s"]
        )
        r_["ratio_hlo"] = r_["hlo_chars"] / base["hlo_chars"]
        r_["ratio_compiled_hlo"] = r_["compiled_hlo_chars"] / base["compiled_hlo_chars"]
    per_step = {
        "grazejax_s_per_step": base["time_min_s"] / gj_steps,
        "diffrax_s_per_step": tm["min_s"] / int(nsteps),
        "ratio": (base["time_min_s"] / gj_steps) / (tm["min_s"] / int(nsteps)),
    }
    for r_ in rows:
        tt = "   (HLO only)" if r_["ratio_time"] is None else f"×{r_['ratio_time']:6.2f}"
        cc = "" if r_["compile_s"] is None else f"compile {r_['compile_s']:.2f} s"
        log(
            f"   {r_['effect']:<48} time {tt}  HLO ×{r_['ratio_hlo']:5.2f}  optimized HLO "
            f"×{r_['ratio_compiled_hlo']:5.2f}  {cc}"
        )
    log(
        f"   per step: grazejax/diffrax alone = {per_step['ratio']:.2f} ({gj_steps} vs {int(nsteps)} steps)"
    )
    return per_step
