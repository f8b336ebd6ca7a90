"""Core benchmark of grazejax against SciPy and heyoka (issue: "how fast is it?").

    python benchmarks/bench_core.py [--quick] [--out DIR]      (default DIR: bench-output/)

Writes DIR/core.json (every number, with machine info) and DIR/core.md (Markdown tables).
What is measured, and how accuracy is matched, is explained in benchmarks/README.md.

Problem: ex1dof (grazejax.examples.ex1dof) at mu = 0.2, 10 impacts, from a start on the
attracting impacting cycle (found by a transient run from (0, 0.1)); tolerances are
rtol = atol for every tool. Reference: heyoka in 80-bit long double (tol 1e-19).

One process, one thing at a time; --quick takes about a minute, the full run a few
minutes (more repeats, the full rtol sweep, more SciPy runs over the batch starts).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from importlib import metadata
from typing import NamedTuple

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import diffrax  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from peers import HeyokaImpactRunner, ScipyImpactRunner  # noqa: E402

import grazejax as gj  # noqa: E402  (turns float64 on)
from grazejax import examples  # noqa: E402

MU = 0.2
N_IMPACTS = 10
RTOL = 1e-10
T1_PEER = 1e4  # peers need a finite t1; every run stops on its 10th impact long before
# solve_ivp only sees sign changes at step ends: on this cycle the flight spends only
# ~0.08 time units in x1 < 0 after a missed crossing, so DOP853's long steps (~0.3 at
# rtol 1e-10) jump over impacts. max_step below that dip makes it reliable (see README).
SCIPY_MAX_STEP = 0.05
HEYOKA_DEFAULT_TOL = float(np.finfo(float).eps)  # heyoka's own default tolerance
BATCH = 1000


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


def log(msg):
    print(msg, flush=True)


def stats(samples):
    a = np.asarray(samples, dtype=float)
    return {"min_s": float(a.min()), "median_s": float(np.median(a)), "repeats": int(a.size)}


def time_calls(fn, repeats, warmup=1):
    for _ in range(warmup):
        fn()
    samples = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t)
    return stats(samples)


def first_minus_second(fn):
    """Compile time of a jitted fn: first call minus second call (both blocked)."""
    t = time.perf_counter()
    jax.block_until_ready(fn())
    first = time.perf_counter() - t
    t = time.perf_counter()
    jax.block_until_ready(fn())
    second = time.perf_counter() - t
    return {"compile_s": first - second, "first_call_s": first, "second_call_s": second}


def errors(times, post, ref):
    """Max abs error of the impact times and post-impact states against the reference."""
    times, post = np.asarray(times, float), np.asarray(post, float)
    if times.shape != ref["impact_times"].shape or not np.all(np.isfinite(times)):
        return {"err_t": math.inf, "err_x": math.inf, "err": math.inf, "impacts": int(np.sum(np.isfinite(times)))}
    et = float(np.max(np.abs(times - ref["impact_times"])))
    ex = float(np.max(np.abs(post - ref["impact_post"])))
    return {"err_t": et, "err_x": ex, "err": max(et, ex), "impacts": int(times.size)}


def versions():
    out = {"python": platform.python_version()}
    for name in ("jax", "jaxlib", "diffrax", "equinox", "optimistix", "numpy", "scipy", "heyoka"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    out["grazejax"] = gj.__version__
    try:
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        rev = subprocess.run(["git", "-C", root, "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "-C", root, "status", "--porcelain", "--", "grazejax"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        out["grazejax_git"] = rev + ("+dirty" if dirty else "")
    except Exception:  # noqa: BLE001
        out["grazejax_git"] = None
    return out


def machine():
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = None
    cpu_model = platform.processor()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu_model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {
        "platform": platform.platform(),
        "machine": platform.machine(),
        "cpu_model": cpu_model,
        "cpu_count": os.cpu_count(),
        "cpu_affinity": affinity,
        "jax_backend": jax.default_backend(),
        "jax_devices": [str(d) for d in jax.devices()],
        "loadavg_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


# --------------------------------------------------------------------------------------
# grazejax runs (every jitted function takes its numbers as arguments)
# --------------------------------------------------------------------------------------

SCENE = examples.ex1dof()
ARGS = examples.ex1dof_args(mu=MU)


def make_run(solver=None):
    """jit(x0, args, rtol) -> Solution of a 10-impact run; rtol (= atol) is traced."""

    def run(x0, args, rtol):
        return gj.simulate(SCENE, x0, 0.0, jnp.inf, args, solver=solver, rtol=rtol, atol=rtol,
                           max_impacts=N_IMPACTS)

    return run


def check_solution(sol, label):
    status = np.asarray(sol.status)
    ok = np.all(status == int(gj.Status.MAX_IMPACTS))
    if not ok:
        bad = {gj.Status(int(s)).name: int(np.sum(status == s)) for s in np.unique(status)}
        log(f"  WARNING {label}: statuses {bad}")
    return bool(ok)


def cycle_start():
    """A state on the attracting impacting cycle at mu = 0.2 (after a transient)."""
    sol = gj.simulate(SCENE, jnp.array([0.0, 0.1]), 0.0, jnp.inf, ARGS, rtol=1e-12, atol=1e-12,
                      max_impacts=30)
    assert int(sol.status) == gj.Status.MAX_IMPACTS, sol.summary()
    post = np.asarray(sol.impact_post)
    # Leave the transient: successive post-impact velocities agree to round-off.
    drift = abs(post[-1, 1] - post[-2, 1])
    # Start exactly on the wall (x1 = 0) moving away from it: armed for every tool.
    return np.array([0.0, post[-1, 1]]), {"transient_impacts": 30, "x2_drift_last": float(drift)}


def batch_starts(x_star, n, seed=0):
    """n starts near the cycle: on circles about (1, 0) (the eps = 0 flow) at random phases
    (away from the wall), radii within +1% of the cycle's; all on the free side x1 > 0."""
    rng = np.random.default_rng(seed)
    r_star = math.hypot(x_star[0] - 1.0, x_star[1])
    r = r_star * (1.0 + 0.01 * rng.random(n))
    theta = rng.uniform(0.2, 2 * math.pi - 0.2, n)
    x1 = 1.0 - r * np.cos(theta)
    x2 = r * np.sin(theta)
    xs = np.stack([x1, x2], axis=1)
    assert np.all(xs[:, 0] > 0)
    return xs


# --------------------------------------------------------------------------------------
# settings and what the sections share
# --------------------------------------------------------------------------------------

PEER_ARGS = {"mu": MU}  # the problem's parameters, as the peers take them


class Repeats(NamedTuple):
    """How often each thing is timed, and the points of the rtol sweeps."""

    grazejax: int  # repeats of a ~ms grazejax run
    scipy: int  # repeats of a ~50 ms SciPy run
    heyoka: int  # repeats of a ~0.1 ms heyoka run
    batch: int
    scipy_batch: int  # SciPy runs over the batch starts
    sweep: list[float]  # grazejax rtols for matched accuracy
    heyoka_sweep: list[float]  # heyoka tols for matched accuracy


def repeats(quick):
    """--quick: fewer repeats and decade-spaced sweeps; full: half-decades as well."""
    if quick:
        sweep = [10.0 ** -k for k in range(6, 16)]
    else:
        sweep = sorted({float(f"{c}e-{k}") for k in range(6, 16) for c in (1, 3)}, reverse=True)
        sweep = [r for r in sweep if r >= 1e-15]
    return Repeats(grazejax=10 if quick else 30, scipy=3 if quick else 10,
                   heyoka=50 if quick else 300, batch=2 if quick else 5,
                   scipy_batch=10 if quick else 100, sweep=sweep,
                   heyoka_sweep=[10.0 ** -k for k in range(6, 16)])


class Context(NamedTuple):
    """What sections 2-4 share: the start, the reference, the primal run, the repeats."""

    quick: bool
    rep: Repeats
    x_star: np.ndarray  # the start on the cycle, as the peers take it
    x0: jax.Array  # the same start, as grazejax takes it
    ref: dict  # long-double heyoka run from x_star: every error is measured against it
    ref_runner: HeyokaImpactRunner  # its runner, for the batch lanes and finite differences
    run_tsit5: Callable  # jit(x0, args, rtol): the primal run (Tsit5), compiled in section 1
    tsit5_compile: dict  # its compile time (first_minus_second)


class Orbex2(NamedTuple):
    """The compile-time problem with two surfaces: scene, args and start."""

    scene: gj.Scene
    args: dict
    x0: jax.Array


def orbex2_case():
    return Orbex2(examples.orbex2(), examples.orbex2_args(), jnp.array([0.0, 1.0]))


def orbex2_jit(orb):
    """A fresh jit of a 10-impact orbex2 run: its first call compiles."""
    return jax.jit(lambda x0, args: gj.simulate(orb.scene, x0, 0.0, jnp.inf, args, max_impacts=N_IMPACTS,
                                                rtol=RTOL, atol=RTOL))


# --------------------------------------------------------------------------------------
# main
# --------------------------------------------------------------------------------------


def parse_args(argv):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer repeats and sweep points (< 2 min)")
    ap.add_argument("--out", default="bench-output", help="output folder (default bench-output/)")
    return ap.parse_args(argv)


def header(quick):
    """The result dict's first entries: mode, machine (load at start), versions, problem."""
    return {"mode": "quick" if quick else "full", "machine": machine(), "versions": versions(),
            "note": "timings taken on a shared 2-core machine (other jobs running): "
                    "compare ratios from the same run, not absolute numbers across runs",
            "problem": {"scene": "ex1dof", "mu": MU, "eps": 1e-4, "R": 0.9, "impacts": N_IMPACTS,
                        "tolerances": "rtol = atol for every tool"}}


def start_backend():
    """Backend start-up, not counted as compile time."""
    jnp.ones(3).block_until_ready()
    jax.jit(lambda x: x + 1)(1.0).block_until_ready()


def main(argv=None):
    opts = parse_args(argv)
    os.makedirs(opts.out, exist_ok=True)
    t_start = time.perf_counter()
    res = header(opts.quick)
    start_backend()

    orb = orbex2_case()
    res["compile"], x_star, cycle_info, run_tsit5 = compile_times(orb)
    ref_runner, ref = reference(x_star)
    res["start"] = start_record(x_star, cycle_info, ref)
    ctx = Context(quick=opts.quick, rep=repeats(opts.quick), x_star=x_star, x0=jnp.asarray(x_star),
                  ref=ref, ref_runner=ref_runner, run_tsit5=run_tsit5,
                  tsit5_compile=res["compile"]["ex1dof"])
    per_run, hy_runner = time_per_run(ctx)
    res.update(per_run)
    res["batch"] = batch_throughput(ctx, hy_runner)
    res["jacobian"] = jacobian_cost(ctx)
    res["compile"]["orbex2_warm"] = orbex2_warm_compile(orb)

    res["machine"]["loadavg_end"] = list(os.getloadavg()) if hasattr(os, "getloadavg") else None
    res["total_wall_s"] = time.perf_counter() - t_start
    write_outputs(res, opts.out)
    return 0


def write_outputs(res, out):
    with open(os.path.join(out, "core.json"), "w") as fh:
        json.dump(res, fh, indent=1, default=float)
    md = render_md(res)
    with open(os.path.join(out, "core.md"), "w") as fh:
        fh.write(md)
    log("\n" + md)
    log(f"wrote {out}/core.json, {out}/core.md in {res['total_wall_s']:.0f} s")


# --------------------------------------------------------------------------------------
# 1. compile times, and the reference
# --------------------------------------------------------------------------------------


def compile_times(orb):
    """First call minus second call of jitted orbex2 and ex1dof runs.

    Returns res["compile"], the start on the cycle (`cycle_start`) with its info, and the
    jitted Tsit5 run of ex1dof. The start is found between the two compiles, so that orbex2's
    is timed in a process that has compiled nothing yet.
    """
    log("1) compile times (first call minus second call of a jitted function)")
    orb_run = orbex2_jit(orb)
    c_orb = first_minus_second(lambda: orb_run(orb.x0, orb.args))
    c_orb["status"] = gj.Status(int(orb_run(orb.x0, orb.args).status)).name
    log(f"   orbex2 (two surfaces): {c_orb['compile_s']:.2f} s")

    x_star, cycle_info = cycle_start()
    x0 = jnp.asarray(x_star)
    run_tsit5 = jax.jit(make_run(diffrax.Tsit5()))
    c_ex = first_minus_second(lambda: run_tsit5(x0, ARGS, RTOL))
    log(f"   ex1dof: {c_ex['compile_s']:.2f} s")
    return {"orbex2": c_orb, "ex1dof": c_ex, "goal_s": 5.0}, x_star, cycle_info, run_tsit5


def reference(x_star):
    """heyoka in 80-bit long double at tol 1e-19 from x_star: the runner and its run."""
    log("   reference: heyoka long double, tol 1e-19")
    ref_runner = HeyokaImpactRunner("ex1dof", tol=1e-19, fp_type=np.longdouble)
    ref = ref_runner.run(x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
    assert len(ref["impact_times"]) == N_IMPACTS
    return ref_runner, ref


def start_record(x_star, cycle_info, ref):
    return {"x0": x_star.tolist(), **cycle_info,
            "reference_impact_times": ref["impact_times"].tolist(),
            "reference_impact_post": ref["impact_post"].tolist()}


# --------------------------------------------------------------------------------------
# 2. time per run, and matched accuracy
# --------------------------------------------------------------------------------------


def time_per_run(ctx):
    """Every tool at rtol 1e-10, the rtol sweeps, and each row's match at equal accuracy.

    Returns res's "reference_check", "sweep", "heyoka_sweep" and "per_run" (in that order),
    and heyoka's runner at tol 1e-10 (timed again over the batch starts).
    """
    log(f"2) time per run, ex1dof mu={MU}, {N_IMPACTS} impacts")
    rows, fns = grazejax_rows(ctx)
    rows += scipy_rows(ctx)
    hy_rows, hy_runner = heyoka_rows(ctx)
    rows += hy_rows
    check = reference_check(ctx)
    sweep_rows = grazejax_sweep(ctx, fns)
    hy_sweep_rows = heyoka_sweep(ctx)
    add_matches(rows, sweep_rows, hy_sweep_rows)
    return {"reference_check": check, "sweep": sweep_rows, "heyoka_sweep": hy_sweep_rows,
            "per_run": rows}, hy_runner


def gj_row(ctx, label, fn, solver_name, rtol, repeats, compile_info=None):
    """One grazejax row: fn(x0, ARGS, rtol) checked, scored against the reference, timed."""
    x0 = ctx.x0
    sol = fn(x0, ARGS, rtol)
    ok = check_solution(sol, label)
    e = errors(sol.impact_times, sol.impact_post, ctx.ref)
    t = time_calls(lambda: jax.block_until_ready(fn(x0, ARGS, rtol)), repeats)
    row = {"tool": "grazejax", "config": label, "solver": solver_name, "rtol": rtol, **t, **e,
           "steps": int(sol.num_steps), "ok": ok}
    if compile_info is not None:
        row["compile_s"] = compile_info["compile_s"]
    return row


def grazejax_rows(ctx):
    """Tsit5 (the primal, first row), Dopri5 and Dopri8 at RTOL; also the jitted runs."""
    x0 = ctx.x0
    solvers = {"Tsit5": (ctx.run_tsit5, ctx.tsit5_compile)}
    for name, solver in (("Dopri5", diffrax.Dopri5()), ("Dopri8", diffrax.Dopri8())):
        fn = jax.jit(make_run(solver))
        c = first_minus_second(lambda fn=fn: fn(x0, ARGS, RTOL))
        solvers[name] = (fn, c)
    rows = []
    for name, (fn, c) in solvers.items():
        row = gj_row(ctx, f"{name} rtol {RTOL:.0e}", fn, name, RTOL, ctx.rep.grazejax, c)
        rows.append(row)
        log(f"   grazejax {name:<7}: {1e3 * row['median_s']:8.3f} ms  err {row['err']:.1e}  "
            f"steps {row['steps']}  (compile {c['compile_s']:.1f} s)")
    return rows, {name: fn for name, (fn, _) in solvers.items()}


def sp_row(ctx, method, max_step):
    x_star = ctx.x_star
    runner = ScipyImpactRunner("ex1dof", method, RTOL, RTOL, max_step=max_step)
    r = runner.run(x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
    e = errors(r["impact_times"], r["impact_post"], ctx.ref)
    t = time_calls(lambda: runner.run(x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS), ctx.rep.scipy)
    ms = "" if max_step == np.inf else f", max_step {max_step}"
    return {"tool": "scipy", "config": f"{method} rtol {RTOL:.0e}{ms}", "solver": method,
            "rtol": RTOL, "max_step": None if max_step == np.inf else max_step, **t, **e,
            "steps": r["nfev"], "steps_kind": "nfev", "ok": e["err"] < 1e-6}


def scipy_rows(ctx):
    """DOP853 and RK45 with SCIPY_MAX_STEP, and DOP853 without (which misses impacts)."""
    rows = []
    for method, max_step in (("DOP853", SCIPY_MAX_STEP), ("RK45", SCIPY_MAX_STEP), ("DOP853", np.inf)):
        row = sp_row(ctx, method, max_step)
        rows.append(row)
        flag = "" if row["ok"] else "  WRONG (missed impacts)"
        log(f"   scipy {row['config']:<32}: {1e3 * row['median_s']:8.3f} ms  err {row['err']:.1e}{flag}")
    return rows


def heyoka_rows(ctx):
    """heyoka at tol RTOL and at its default; compile_s is the runner's build (LLVM).

    Returns the rows and the runner at tol RTOL.
    """
    x_star = ctx.x_star
    rows, runners = [], {}
    for tol, label in ((RTOL, f"tol {RTOL:.0e}"), (HEYOKA_DEFAULT_TOL, "tol eps (default)")):
        t = time.perf_counter()
        hr = HeyokaImpactRunner("ex1dof", tol=tol)
        build = time.perf_counter() - t
        runners[tol] = hr
        r = hr.run(x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
        e = errors(r["impact_times"], r["impact_post"], ctx.ref)
        tm = time_calls(lambda hr=hr: hr.run(x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS), ctx.rep.heyoka)
        rows.append({"tool": "heyoka", "config": label, "solver": "taylor", "rtol": tol, **tm, **e,
                     "steps": r["nfev"], "steps_kind": "taylor steps", "compile_s": build,
                     "ok": e["err"] < 1e-6})
        log(f"   heyoka {label:<18}: {1e3 * tm['median_s']:8.3f} ms  err {e['err']:.1e}  (build {build:.2f} s)")
    return rows, runners[RTOL]


def reference_check(ctx):
    """Reference sanity: independent double-precision solutions vs the long-double one."""
    x_star, ref = ctx.x_star, ctx.ref
    hy15 = HeyokaImpactRunner("ex1dof", tol=1e-15).run(x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
    sp13 = ScipyImpactRunner("ex1dof", "DOP853", 1e-13, 1e-13, max_step=SCIPY_MAX_STEP).run(
        x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
    return {
        "heyoka_double_tol1e-15": errors(hy15["impact_times"], hy15["impact_post"], ref),
        "scipy_DOP853_1e-13_max_step": errors(sp13["impact_times"], sp13["impact_post"], ref),
        "ulp_of_last_impact_time": float(np.spacing(ref["impact_times"][-1])),
    }


def grazejax_sweep(ctx, fns):
    """rtol sweep (work-precision) of Tsit5 and Dopri8, for matched accuracy."""
    sweep = ctx.rep.sweep
    log(f"   rtol sweep for matched accuracy ({len(sweep)} points x Tsit5, Dopri8)")
    rows = []
    for name in ("Tsit5", "Dopri8"):
        for rtol in sweep:
            rows.append(gj_row(ctx, f"{name} rtol {rtol:.0e}", fns[name], name, rtol,
                               max(3, ctx.rep.grazejax // 2)))
    return rows


def heyoka_sweep(ctx):
    """tol sweep of heyoka, for the grazejax rows' matched accuracy."""
    x_star = ctx.x_star
    log(f"   heyoka tol sweep ({len(ctx.rep.heyoka_sweep)} points)")
    rows = []
    for tol in ctx.rep.heyoka_sweep:
        hr_s = HeyokaImpactRunner("ex1dof", tol=tol)
        r = hr_s.run(x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
        e = errors(r["impact_times"], r["impact_post"], ctx.ref)
        tm = time_calls(lambda hr_s=hr_s: hr_s.run(x_star, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS),
                        ctx.rep.heyoka // 2)
        rows.append({"tool": "heyoka", "config": f"tol {tol:.0e}", "rtol": tol, **tm, **e,
                     "steps": r["nfev"], "ok": e["err"] < 1e-3})
    return rows


def matched_heyoka(grazejax_row, hy_sweep_rows):
    """Cheapest swept heyoka run with error <= this grazejax run's error."""
    good = [r for r in hy_sweep_rows if r["ok"] and r["err"] <= grazejax_row["err"]]
    if not good:
        return None
    m = max(good, key=lambda r: r["rtol"])  # loosest tol that meets the error
    return {"reached": True, "config": "heyoka " + m["config"], "rtol": m["rtol"], "err": m["err"],
            "median_s": m["median_s"], "min_s": m["min_s"],
            "ratio_grazejax_over_peer": grazejax_row["min_s"] / m["min_s"]}


def matched(peer_row, sweep_rows):
    """Cheapest grazejax run with error <= the peer's: per solver the LOOSEST swept rtol
    that meets the error (cost grows with 1/rtol; picking the fastest timing among all
    qualifying rtols would chase timing noise), then the faster of the two solvers."""
    good = []
    for name in ("Tsit5", "Dopri8"):
        ok_rows = [r for r in sweep_rows if r["solver"] == name and r["ok"]
                   and r["err"] <= peer_row["err"]]
        if ok_rows:
            good.append(max(ok_rows, key=lambda r: r["rtol"]))
    if not good:
        best = min(sweep_rows, key=lambda r: r["err"])
        return {"reached": False, "best_err": best["err"], "best_config": best["config"],
                "best_median_s": best["median_s"], "best_min_s": best["min_s"]}
    m = min(good, key=lambda r: r["min_s"])
    return {"reached": True, "config": m["config"], "solver": m["solver"], "rtol": m["rtol"],
            "err": m["err"], "median_s": m["median_s"], "min_s": m["min_s"],
            "ratio_grazejax_over_peer": m["min_s"] / peer_row["min_s"]}


def add_matches(rows, sweep_rows, hy_sweep_rows):
    """In place: grazejax rows get their heyoka match; correct peer rows their grazejax
    match, and every peer row the primal's (rows[0]) time over its own."""
    primal = rows[0]
    for row in rows:
        if row["tool"] == "grazejax":
            row["matched"] = matched_heyoka(row, hy_sweep_rows)
            continue
        row["ratio_grazejax_over_peer"] = primal["min_s"] / row["min_s"]
        if row["ok"]:
            row["matched"] = matched(row, sweep_rows)


# --------------------------------------------------------------------------------------
# 3. batch throughput
# --------------------------------------------------------------------------------------


def batch_throughput(ctx, hy_runner):
    """jax.vmap over BATCH starts near the cycle: time, lane accuracy, and the peers' time
    per run over the same starts (heyoka: hy_runner). Returns res["batch"]."""
    log(f"3) batch: jax.vmap over {BATCH} starts near the cycle")
    starts = batch_starts(ctx.x_star, BATCH)
    xs = jnp.asarray(starts)
    batched = jax.jit(jax.vmap(make_run(diffrax.Tsit5()), in_axes=(0, None, None)))
    c_b = first_minus_second(lambda: batched(xs, ARGS, RTOL))
    sol_b = batched(xs, ARGS, RTOL)
    ok_b = check_solution(sol_b, "batch")
    tb = time_calls(lambda: jax.block_until_ready(batched(xs, ARGS, RTOL)), ctx.rep.batch)
    scaling = {} if ctx.quick else smaller_batches(batched, xs, ctx.rep.batch)
    lane_err = lane_errors(ctx, starts, sol_b)
    hy_mean, sp_mean = peers_same_starts(ctx, starts, hy_runner)
    per_lane = tb["min_s"] / BATCH
    log(f"   {1e3 * tb['min_s']:.0f} ms total (min), {1e6 * per_lane:.1f} us/lane "
        f"(compile {c_b['compile_s']:.1f} s); heyoka {1e6 * hy_mean:.1f} us/run, "
        f"scipy {1e3 * sp_mean:.1f} ms/run on the same starts")
    return {
        "lanes": BATCH, **tb, "per_lane_median_s": tb["median_s"] / BATCH, "per_lane_min_s": per_lane,
        "compile_s": c_b["compile_s"], "all_max_impacts": ok_b,
        "steps_max": int(np.max(sol_b.num_steps)), "steps_mean": float(np.mean(sol_b.num_steps)),
        "lane_err_max": float(np.max(lane_err)), "lane_err_median": float(np.median(lane_err)),
        "heyoka_tol1e-10_mean_per_run_same_starts_s": hy_mean,
        "scipy_DOP853_mean_per_run_same_starts_s": sp_mean, "scipy_runs": ctx.rep.scipy_batch,
        "ratio_per_lane_over_heyoka_same_starts": per_lane / hy_mean,
        "ratio_per_lane_over_scipy_same_starts": per_lane / sp_mean,
        "smaller_batches": scaling,
    }


def smaller_batches(batched, xs, repeats):
    """Per-lane cost at a smaller batch (one more compile each); full mode only."""
    scaling = {}
    for nb in (100,):
        c_nb = first_minus_second(lambda nb=nb: batched(xs[:nb], ARGS, RTOL))
        t_nb = time_calls(lambda nb=nb: jax.block_until_ready(batched(xs[:nb], ARGS, RTOL)), repeats * 2)
        scaling[nb] = {**t_nb, "per_lane_min_s": t_nb["min_s"] / nb, "compile_s": c_nb["compile_s"]}
    return scaling


def lane_errors(ctx, starts, sol_b):
    """Accuracy of the lanes against long-double references (all lanes: ~1 ms each)."""
    t_ref = time.perf_counter()
    lane_err = []
    for i in range(BATCH):
        r = ctx.ref_runner.run(starts[i], 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
        lane_err.append(errors(np.asarray(sol_b.impact_times[i]), np.asarray(sol_b.impact_post[i]), r)["err"])
    log(f"   lane references: {time.perf_counter() - t_ref:.1f} s")
    return lane_err


def peers_same_starts(ctx, starts, hy_runner):
    """Mean time per run of the peers over the batch starts (heyoka: all; SciPy DOP853: the
    first rep.scipy_batch). Returns (heyoka mean, SciPy mean)."""
    t = time.perf_counter()
    for i in range(BATCH):
        hy_runner.run(starts[i], 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
    hy_mean = (time.perf_counter() - t) / BATCH
    n_sp = ctx.rep.scipy_batch
    sp_runner = ScipyImpactRunner("ex1dof", "DOP853", RTOL, RTOL, max_step=SCIPY_MAX_STEP)
    t = time.perf_counter()
    for i in range(n_sp):
        sp_runner.run(starts[i], 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)
    sp_mean = (time.perf_counter() - t) / n_sp
    return hy_mean, sp_mean


# --------------------------------------------------------------------------------------
# 4. Jacobian, and orbex2's compile in a warm process
# --------------------------------------------------------------------------------------


def x_final(x0, args, rtol):
    return make_run(diffrax.Tsit5())(x0, args, rtol).x_final


def jacobian_cost(ctx):
    """jax.jacfwd of x_final w.r.t. x0: time against the primal's, and against finite
    differences of the reference. Returns res["jacobian"]."""
    log("4) jax.jacfwd of x_final w.r.t. x0")
    x0, run_tsit5 = ctx.x0, ctx.run_tsit5
    jac = jax.jit(jax.jacfwd(x_final))
    c_j = first_minus_second(lambda: jac(x0, ARGS, RTOL))
    J = np.asarray(jac(x0, ARGS, RTOL))
    # Primal and Jacobian timed in alternation, so that load from other jobs hits both.
    tp_s, tj_s = [], []
    jax.block_until_ready(run_tsit5(x0, ARGS, RTOL))
    jax.block_until_ready(jac(x0, ARGS, RTOL))
    for _ in range(ctx.rep.grazejax):
        tp_s.append(time_calls(lambda: jax.block_until_ready(run_tsit5(x0, ARGS, RTOL)), 1, 0)["min_s"])
        tj_s.append(time_calls(lambda: jax.block_until_ready(jac(x0, ARGS, RTOL)), 1, 0)["min_s"])
    tj, tp = stats(tj_s), stats(tp_s)
    fd = reference_fd_row2(ctx)
    fd_rel = float(np.max(np.abs(J[1] - fd) / np.abs(fd)))
    out = {**tj, "compile_s": c_j["compile_s"], "jacobian": J.tolist(),
           "fd_row2_reference": fd.tolist(), "fd_rel_diff": fd_rel,
           "primal_median_s": tp["median_s"], "primal_min_s": tp["min_s"],
           "ratio_over_primal": tj["median_s"] / tp["median_s"],
           "ratio_over_primal_min": tj["min_s"] / tp["min_s"], "goal_ratio": 3.0}
    log(f"   {1e3 * tj['median_s']:.3f} ms = {out['ratio_over_primal']:.2f} x primal "
        f"(compile {c_j['compile_s']:.1f} s)")
    return out


def reference_fd_row2(ctx):
    """Finite differences of the long-double reference's x2_final w.r.t. x0: central in
    x0[1]; one-sided (into the free side) in x0[0], which starts on the wall. (The first row
    is not checked: x1_final is 0, on the wall.)"""
    x_star = ctx.x_star

    def ref_x2(x):
        return ctx.ref_runner.run(x, 0.0, T1_PEER, N_IMPACTS, **PEER_ARGS)["x_final"][1]

    e0, e1 = np.array([1e-4, 0.0]), np.array([0.0, 1e-3])
    return np.array([(ref_x2(x_star + e0) - ref_x2(x_star)) / 1e-4,
                     (ref_x2(x_star + e1) - ref_x2(x_star - e1)) / 2e-3])


def orbex2_warm_compile(orb):
    """orbex2 again, in a fresh jit, now that JAX/Diffrax's one-time costs are paid."""
    orb_run = orbex2_jit(orb)
    c = first_minus_second(lambda: orb_run(orb.x0, orb.args))
    log(f"   orbex2 compile again (warm process): {c['compile_s']:.2f} s")
    return c


# --------------------------------------------------------------------------------------
# Markdown
# --------------------------------------------------------------------------------------


def _ms(s):
    return f"{1e3 * s:.3g}" if s >= 1e-3 else f"{1e3 * s:.2g}"


def _e(x):
    return "—" if x is None else ("inf" if not math.isfinite(x) else f"{x:.1e}")


def render_md(res):
    return "\n".join(_md_intro(res) + _md_per_run(res["per_run"]) + _md_key_figures(res))


def _md_intro(res):
    m, v = res["machine"], res["versions"]
    return [
        f"# grazejax core benchmark ({res['mode']})",
        "",
        f"ex1dof, μ = {MU}, {N_IMPACTS} impacts from x0 = ({res['start']['x0'][0]:g}, "
        f"{res['start']['x0'][1]:.6f}) on the attracting impacting cycle; rtol = atol; errors are "
        "max |Δ| of the 10 impact times (err t) and post-impact states (err x) against heyoka "
        "in long double (tol 1e-19).",
        "",
        f"**Timings taken on a shared {m['cpu_count']}-core machine** (other jobs running; load "
        f"average {m['loadavg_start'][0]:.1f} at start, {m['loadavg_end'][0]:.1f} at end): read "
        "ratios within one run, not absolute numbers across runs.",
        "",
        f"Machine: {m['platform']}, {m['cpu_model']}, {m['cpu_count']} CPUs, JAX backend "
        f"{m['jax_backend']}. Versions: jax {v['jax']}, diffrax {v['diffrax']}, scipy {v['scipy']}, "
        f"heyoka {v['heyoka']}, numpy {v['numpy']}, grazejax {v['grazejax']} ({v['grazejax_git']}).",
        "",
    ]


def _md_per_run(per):
    lines = [
        "## Time per run (after compilation)",
        "",
        "| tool | config | median ms | min ms | err t | err x | steps | grazejax/peer | matched accuracy: grazejax config, ms, ratio |",
        "|---|---|---:|---:|---:|---:|---:|---:|---|",
    ]
    for r in per:
        ratio = f"{r['ratio_grazejax_over_peer']:.3g}" if "ratio_grazejax_over_peer" in r else ""
        mt = r.get("matched")
        if mt is None:
            mtxt = "—" if r["tool"] == "grazejax" else "wrong result (missed impacts)"
        elif mt["reached"]:
            mtxt = f"{mt['config']}, {_ms(mt['min_s'])} ms, **{mt['ratio_grazejax_over_peer']:.3g}**"
        else:
            mtxt = f"not reached (best {mt['best_config']}: err {_e(mt['best_err'])})"
        steps = f"{r['steps']}" + (" fev" if r.get("steps_kind") == "nfev" else "")
        cfg = r["config"] + ("" if r["ok"] else " ⚠")
        lines.append(
            f"| {r['tool']} | {cfg} | {_ms(r['median_s'])} | {_ms(r['min_s'])} | {_e(r['err_t'])} "
            f"| {_e(r['err_x'])} | {steps} | {ratio} | {mtxt} |"
        )
    return lines


def _md_key_figures(res):
    per, b, j, c = res["per_run"], res["batch"], res["jacobian"], res["compile"]
    primal = per[0]
    hy = next(r for r in per if r["tool"] == "heyoka")
    sp = next(r for r in per if r["tool"] == "scipy")
    return [
        "",
        f"Ratios use min times (the least disturbed by other jobs). grazejax/peer = grazejax "
        f"Tsit5 at rtol {RTOL:.0e} over the peer's time (< 1: grazejax faster). Matched accuracy, peer rows: the cheapest grazejax run of the rtol sweep (Tsit5 "
        "and Dopri8, rtol 1e-6…1e-15; per solver the loosest rtol) whose error (max of err t, "
        "err x) is ≤ the peer's, and grazejax/peer at that point; grazejax rows: heyoka at the "
        "loosest tol of a sweep (1e-6…1e-15) with error ≤ grazejax's, and grazejax/heyoka. heyoka steps are Taylor steps, SciPy's "
        "function evaluations (fev), grazejax's solver steps (incl. rejected and landing steps).",
        "",
        "## Key figures",
        "",
        "| measure | value | goal |",
        "|---|---:|---|",
        f"| compile, orbex2 (2 surfaces) | {c['orbex2']['compile_s']:.2f} s | < 5 s |",
        f"| compile, orbex2, again in a warm process | {c['orbex2_warm']['compile_s']:.2f} s | < 5 s |",
        f"| compile, ex1dof | {c['ex1dof']['compile_s']:.2f} s | < 5 s |",
        f"| grazejax per run (Tsit5, rtol {RTOL:.0e}), min / median | {_ms(primal['min_s'])} / "
        f"{_ms(primal['median_s'])} ms | |",
        f"| grazejax / scipy {sp['config']} per run | {sp['ratio_grazejax_over_peer']:.3g} | |",
        f"| grazejax / heyoka {hy['config']} per run | {hy['ratio_grazejax_over_peer']:.3g} | |",
        f"| batch: vmap × {b['lanes']} (Tsit5, rtol {RTOL:.0e}), total / per lane (min) | "
        f"{_ms(b['min_s'])} ms / {1e3 * b['per_lane_min_s']:.3g} ms (max lane err "
        f"{_e(b['lane_err_max'])}; compile {b['compile_s']:.1f} s) | |",
        f"| per lane / scipy DOP853 max_step {SCIPY_MAX_STEP} per run (mean over the first "
        f"{b['scipy_runs']} starts: "
        f"{_ms(b['scipy_DOP853_mean_per_run_same_starts_s'])} ms) | "
        f"{b['ratio_per_lane_over_scipy_same_starts']:.3g} | |",
        f"| per lane / heyoka tol 1e-10 per run (mean over the {b['lanes']} starts: "
        f"{1e6 * b['heyoka_tol1e-10_mean_per_run_same_starts_s']:.3g} µs) | "
        f"{b['ratio_per_lane_over_heyoka_same_starts']:.3g} | |",
        *[f"| batch: vmap × {nb}, per lane (min) | {1e3 * d['per_lane_min_s']:.3g} ms | |"
          for nb, d in b["smaller_batches"].items()],
        f"| jacfwd(x_final w.r.t. x0) per run, min / median | {_ms(j['min_s'])} / "
        f"{_ms(j['median_s'])} ms | |",
        f"| jacfwd / primal (mins; medians) | {j['ratio_over_primal_min']:.2f}; "
        f"{j['ratio_over_primal']:.2f} | ≤ 3 |",
        f"| jacfwd compile | {j['compile_s']:.2f} s | |",
        f"| jacfwd vs finite differences of the reference (max rel. diff, ∂x2/∂x0) | "
        f"{j['fd_rel_diff']:.1e} | |",
        "",
        f"Reference check (double-precision solutions vs the long-double reference): heyoka tol "
        f"1e-15 err {_e(res['reference_check']['heyoka_double_tol1e-15']['err'])}, SciPy DOP853 "
        f"1e-13 err {_e(res['reference_check']['scipy_DOP853_1e-13_max_step']['err'])}; one ulp "
        f"of the last impact time is {_e(res['reference_check']['ulp_of_last_impact_time'])}. "
        f"Total wall time {res['total_wall_s']:.0f} s ({res['mode']} mode).",
        "",
    ]


if __name__ == "__main__":
    sys.exit(main())
