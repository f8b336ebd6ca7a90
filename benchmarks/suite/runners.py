"""The timed runs of the work-precision section: one compiled grazejax run per (scene,
solver, options), SciPy's and heyoka's sweeps, and the vmapped batch over ex1dof starts;
each appends one row per tolerance."""

from __future__ import annotations

import time

import _cases as C
import jax
import jax.numpy as jnp
import numpy as np
from _cases import errors, first_minus_second, log, measure
from peers import HeyokaImpactRunner, ScipyImpactRunner

import grazejax as gj

from .common import HAVE_HEYOKA, IMPLICIT, METRICS, SOLVERS, fmt_e, stages_per_step

_RUNNERS: dict = {}


def gj_runner(case, solver_name, scene=None, max_impacts=None, output="solution"):
    """jit(x0, t1, args, tol) -> Solution; tol is rtol = atol and traced (no recompiles)."""
    return jit_run(
        case.scene if scene is None else scene,
        solver_name,
        case.max_impacts if max_impacts is None else max_impacts,
        output,
    )


def jit_run(scene, solver_name, max_impacts, output="solution"):
    """jit(x0, t1, args, tol) -> the Solution, or with output="final" only (x_final,
    num_impacts, num_steps) (the impact log is then dead code, removed by XLA). Cached, so
    that sections running the same scene, solver and options share one compilation."""
    key = (id(scene), solver_name, max_impacts, output)
    if key in _RUNNERS:
        return _RUNNERS[key][1]
    solver = SOLVERS[solver_name]()

    def run(x0, t1, args, tol):
        sol = gj.simulate(
            scene,
            x0,
            0.0,
            t1,
            args,
            solver=solver,
            rtol=tol,
            atol=tol,
            max_impacts=max_impacts,
            direction=1,
            max_steps=200_000,
        )
        return sol if output == "solution" else (sol.x_final, sol.num_impacts, sol.num_steps)

    _RUNNERS[key] = (scene, jax.jit(run))  # keep the scene alive: its id is the key
    return _RUNNERS[key][1]


def counting_scene(scene, counter):
    """The scene with a host counter in its vector field (jax.debug.callback): counts the
    calls of f as executed, a vmapped call (a Jacobian column block) counting once."""
    f = scene.vector_field

    def bump(_):
        counter[0] += 1

    def vector_field(t, x, args):
        jax.debug.callback(bump, x[0])
        return f(t, x, args)

    return gj.Scene(vector_field, scene.surfaces)


def sol_errors(sol, truth):
    k = int(sol.num_impacts)
    return errors(
        np.asarray(sol.impact_times)[:k],
        np.asarray(sol.impact_post)[:k],
        np.asarray(sol.x_final),
        truth,
    )


def peer_errors(r, truth):
    return errors(r["impact_times"], r["impact_post"], r["x_final"], truth)


def wp_grazejax(case, solver_name, S, rows, info):
    truth = case.truth()
    run = gj_runner(case, solver_name)
    x0 = jnp.asarray(case.x0)
    c = first_minus_second(lambda: run(x0, case.t1, case.args, S["tols"][0]))
    info.setdefault("compile_s", {})[solver_name] = c["compile_s"]
    count = [0]
    counted = None
    if (solver_name in IMPLICIT and S["count_implicit"]) or S["count_explicit"]:
        counted = gj_runner(case, solver_name, scene=counting_scene(case.scene, count))
    nominal = stages_per_step(solver_name)
    for tol in S["tols"]:
        sol, tm = measure(
            lambda tol=tol: jax.block_until_ready(run(x0, case.t1, case.args, tol)),
            S["budget"],
            S["max_rep"],
        )
        e = sol_errors(sol, truth)
        status = gj.Status(int(sol.status)).name
        steps = int(sol.num_steps)
        row = {
            "case": case.name,
            "tool": "grazejax",
            "method": solver_name,
            "tol": tol,
            "max_step": None,
            "time_min_s": tm["min_s"],
            "time_median_s": tm["median_s"],
            "repeats": tm["repeats"],
            "steps": steps,
            "status": status,
            **e,
        }
        row["ok"] = e["ok"] and status in ("SUCCESS",)
        if counted is not None and (
            solver_name in IMPLICIT or tol in (S["tols"][0], S["tols"][-1])
        ):
            count[0] = 0
            jax.block_until_ready(counted(x0, case.t1, case.args, tol))
            jax.effects_barrier()
            row["f_calls_counted"] = count[0]
        if nominal is None:
            row["evals"] = row.get("f_calls_counted")
            row["evals_kind"] = (
                "f calls counted (jax.debug.callback in f)"
                if counted is not None
                else "not counted in quick mode (one more compilation)"
            )
        else:
            row["evals"] = steps * nominal
            row["evals_kind"] = f"solver steps × {nominal} (stages per step, FSAL)"
        rows.append(row)
        log(
            f"   grazejax {solver_name:<8} tol {tol:.0e}: {1e3 * tm['min_s']:8.2f} ms  steps {steps:6d}  "
            f"err t {fmt_e(e['err_t'])} post {fmt_e(e['err_post'])} final {fmt_e(e['err_final'])}"
            + (
                ""
                if row["ok"]
                else f"  [{status}, {e['impacts_found']}/{e['impacts_expected']} impacts]"
            )
        )


def wp_scipy(case, method, S, rows):
    truth = case.truth()
    count = [0]
    system = C.counted_system(case.peer_system, count)
    bound = S.get("scipy_max_step", {}).get(case.name, case.scipy_max_step)
    max_steps = [None] + ([bound] if bound else [])
    for max_step in max_steps:
        previous = None
        for tol in S["tols"]:
            if tol < 1e-13:  # solve_ivp clips rtol below 100 eps
                continue
            runner = ScipyImpactRunner(
                system, method, tol, tol, max_step=np.inf if max_step is None else max_step
            )

            def go(runner=runner):
                count[0] = 0
                return runner.run(case.x0, 0.0, case.t1, 10**6, **case.peer_params)

            try:
                r, tm = measure(go, S["budget"], max(1, S["max_rep"] // 3), min_repeats=0)
            except Exception as exc:  # noqa: BLE001  (a failure is a result)
                rows.append(
                    {
                        "case": case.name,
                        "tool": "scipy",
                        "method": method,
                        "tol": tol,
                        "max_step": max_step,
                        "ok": False,
                        "status": f"error: {exc}",
                    }
                )
                log(f"   scipy {method} tol {tol:.0e}: error {exc}")
                break
            e = peer_errors(r, truth)
            row = {
                "case": case.name,
                "tool": "scipy",
                "method": method,
                "tol": tol,
                "max_step": max_step,
                "time_min_s": tm["min_s"],
                "time_median_s": tm["median_s"],
                "repeats": tm["repeats"],
                "steps": None,
                "evals": count[0],
                "nfev_reported": r["nfev"],
                "evals_kind": "f calls counted (incl. finite-difference Jacobians)",
                "status": "ok" if e["ok"] else "missed impacts",
                **e,
            }
            rows.append(row)
            ms = "" if max_step is None else f" max_step {max_step}"
            log(
                f"   scipy {method}{ms} tol {tol:.0e}: {1e3 * tm['min_s']:8.2f} ms  nfev {count[0]:7d}  "
                f"err t {fmt_e(e['err_t'])} post {fmt_e(e['err_post'])} final {fmt_e(e['err_final'])}"
                + ("" if e["ok"] else f"  [{e['impacts_found']}/{e['impacts_expected']} impacts]")
            )
            # Stop the sweep before a run that would take longer than the cap (growth
            # predicted from the last two tolerances).
            growth = tm["first_s"] / previous if previous else 1.0
            previous = tm["first_s"]
            if tm["first_s"] * max(growth, 1.0) > S["scipy_cap_s"]:
                log(
                    f"   scipy {method}: next tolerance predicted > {S['scipy_cap_s']:g} s per run; "
                    "tighter tolerances skipped"
                )
                rows.append(
                    {
                        "case": case.name,
                        "tool": "scipy",
                        "method": method,
                        "max_step": max_step,
                        "tol": None,
                        "ok": False,
                        "status": f"tolerances below {tol:.0e} skipped (time cap {S['scipy_cap_s']:g} s)",
                    }
                )
                break


def wp_heyoka(case, S, rows):
    truth = case.truth()
    for tol in S["tols"]:
        t = time.perf_counter()
        runner = HeyokaImpactRunner(case.peer_system, tol=tol)
        build = time.perf_counter() - t
        r, tm = measure(
            lambda runner=runner: runner.run(case.x0, 0.0, case.t1, 10**6, **case.peer_params),
            S["budget"],
            3 * S["max_rep"],
        )
        e = peer_errors(r, truth)
        rows.append(
            {
                "case": case.name,
                "tool": "heyoka",
                "method": "taylor",
                "tol": tol,
                "max_step": None,
                "time_min_s": tm["min_s"],
                "time_median_s": tm["median_s"],
                "repeats": tm["repeats"],
                "steps": r["nfev"],
                "evals": r["nfev"],
                "evals_kind": f"Taylor steps (one jet of order {runner.ta.order} each)",
                "taylor_order": int(runner.ta.order),
                "build_s": build,
                "status": "ok" if e["ok"] else "missed impacts",
                **e,
            }
        )
        log(
            f"   heyoka tol {tol:.0e}: {1e3 * tm['min_s']:8.3f} ms  steps {r['nfev']:6d} (order "
            f"{runner.ta.order})  err t {fmt_e(e['err_t'])} post {fmt_e(e['err_post'])} final {fmt_e(e['err_final'])}"
        )


BATCH_KINDS = ("random phases", "in phase")


def wp_batch(case, solver_name, lanes, S, rows):
    """grazejax vmap over `lanes` starts near ex1dof's cycle: time per lane, and the max
    error over lanes against per-lane long-double references. Two sets of starts, one
    compiled program: "random phases" (bench_core.batch_starts: on circles about (1, 0) at
    random phases, so the lanes' impacts fall in different loop iterations) and "in phase"
    (bench_sweep.starts: all on the wall, x2 within ±0.01 of the cycle's, impacting
    together). heyoka is run over the random-phase starts (mean time per run)."""
    from bench_sweep import starts as in_phase_starts

    start_sets = {
        "random phases": C.batch_starts(case.x0, lanes, seed=1),
        "in phase": in_phase_starts(lanes, seed=1),
    }
    solver = SOLVERS[solver_name]()

    def one(x0, args, tol):
        return gj.simulate(
            case.scene,
            x0,
            0.0,
            case.t1,
            args,
            solver=solver,
            rtol=tol,
            atol=tol,
            max_impacts=case.max_impacts,
            max_steps=200_000,
        )

    batched = jax.jit(jax.vmap(one, in_axes=(0, None, None)))
    c = None
    for kind, starts in start_sets.items():
        refs = [C.heyoka_reference(case.peer_system, s, case.t1, case.peer_params) for s in starts]
        xs = jnp.asarray(starts)
        if c is None:
            c = first_minus_second(lambda xs=xs: batched(xs, case.args, S["tols"][0]))
        for tol in S["tols"]:
            _batch_rows_at(case, solver_name, lanes, kind, batched, xs, refs, c, tol, S, rows)
    _heyoka_over_starts(case, start_sets["random phases"], lanes, S, rows)


def _batch_rows_at(case, solver_name, lanes, kind, batched, xs, refs, c, tol, S, rows):
    """The vmapped run over one set of starts at one tolerance: time per lane, max errors."""
    sol, tm = measure(
        lambda xs=xs, tol=tol: jax.block_until_ready(batched(xs, case.args, tol)),
        S["budget"],
        max(2, S["max_rep"] // 3),
    )
    errs = []
    for i in range(lanes):
        k = int(sol.num_impacts[i])
        errs.append(
            errors(
                np.asarray(sol.impact_times[i])[:k],
                np.asarray(sol.impact_post[i])[:k],
                np.asarray(sol.x_final[i]),
                refs[i],
            )
        )
    agg = {m: max(e[m] for e in errs) for m in METRICS}
    ok = all(e["ok"] for e in errs) and bool(
        np.all(np.asarray(sol.status) == int(gj.Status.SUCCESS))
    )
    rows.append(
        {
            "case": case.name,
            "tool": "grazejax-batch",
            "method": f"{solver_name} vmap×{lanes}, {kind}",
            "batch_starts": kind,
            "tol": tol,
            "max_step": None,
            "time_min_s": tm["min_s"] / lanes,
            "time_median_s": tm["median_s"] / lanes,
            "repeats": tm["repeats"],
            "steps": float(np.mean(sol.num_steps)),
            "steps_max": int(np.max(sol.num_steps)),
            "evals": float(np.mean(sol.num_steps)) * stages_per_step(solver_name),
            "evals_kind": "mean solver steps per lane × stages",
            "lanes": lanes,
            "compile_s": c["compile_s"],
            "ok": ok,
            "status": "ok" if ok else "lane failure",
            "err": max(agg.values()),
            **agg,
            "impacts_expected": int(max(len(r["impact_times"]) for r in refs)),
            "impacts_found": int(np.max(sol.num_impacts)),
        }
    )
    log(
        f"   grazejax {solver_name} vmap×{lanes} ({kind}) tol {tol:.0e}: "
        f"{1e3 * tm['min_s'] / lanes:8.3f} ms/lane  max err t {fmt_e(agg['err_t'])}"
    )


def _heyoka_over_starts(case, starts, lanes, S, rows):
    """heyoka over the random-phase batch starts: mean time per run, max errors."""
    refs = [C.heyoka_reference(case.peer_system, s, case.t1, case.peer_params) for s in starts]
    # heyoka over the same starts, per run.
    if HAVE_HEYOKA:
        for tol in S["tols"]:
            runner = HeyokaImpactRunner(case.peer_system, tol=tol)
            runner.run(starts[0], 0.0, case.t1, 10**6, **case.peer_params)
            t = time.perf_counter()
            rs = [runner.run(s, 0.0, case.t1, 10**6, **case.peer_params) for s in starts]
            dt = (time.perf_counter() - t) / lanes
            errs = [peer_errors(r, ref) for r, ref in zip(rs, refs, strict=True)]
            agg = {m: max(e[m] for e in errs) for m in METRICS}
            rows.append(
                {
                    "case": case.name,
                    "tool": "heyoka-batch",
                    "method": f"taylor, mean over {lanes} random-phase starts",
                    "tol": tol,
                    "max_step": None,
                    "time_min_s": dt,
                    "time_median_s": dt,
                    "repeats": 1,
                    "steps": float(np.mean([r["nfev"] for r in rs])),
                    "evals": float(np.mean([r["nfev"] for r in rs])),
                    "evals_kind": "Taylor steps",
                    "lanes": lanes,
                    "ok": all(e["ok"] for e in errs),
                    "status": "ok",
                    "err": max(agg.values()),
                    **agg,
                }
            )
