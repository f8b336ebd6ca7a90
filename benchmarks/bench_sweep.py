"""Sweep throughput: grazejax.sweep per lane vs SciPy and heyoka per run, and the
slowest-lane problem (balance="none" vs "refill", against the ideal bound).

    python benchmarks/bench_sweep.py [--quick] [--lanes N] [--out DIR]
    python benchmarks/bench_sweep.py --tax [--quick] [--out DIR]

Writes DIR/sweep.json and DIR/sweep.md (default DIR: bench-output/). All timings come from
one process on one machine, variants interleaved and repeated, min taken; ratios are what to
read (see benchmarks/README.md).

1. **Throughput** (homogeneous lanes): ex1dof at μ = 0.2 (every impact nearly grazing),
   10 impacts per lane (`max_impacts=10`, `t1=inf`), starts spread around the attracting
   impacting cycle. The same tolerance for all (grazejax Tsit5 and SciPy at rtol = atol =
   1e-10, heyoka at tol 1e-10), and matched accuracy: grazejax Dopri8 at 1e-12, whose error
   reaches heyoka's (Tsit5 at 1e-10 ends ~2e-8 off after 10 near-grazing impacts); the error
   of each against a heyoka long-double reference is reported next to its time. Both balances are timed: here every lane costs the same, so this measures what
   the pool costs when there is nothing to balance.
2. **Slowest lane** (heterogeneous lanes):
   - `table`: a ball on a vibrating table (A = 0.05, ω = 10, g = 9.81: below lift-off, so
     balls come to rest), restitution e ~ U(0.3, 0.95) and drop height ~ U(0.05, 1) per lane,
     t1 = 10, up to 200 impacts: lanes take 12 to 200 impacts (Zeno, max impacts or t1);
   - `oscillator_omega`: the forced impact oscillator from rest over a bifurcation-diagram
     range of forcing frequencies ω ∈ [0.5, 3], t1 = 100, up to 400 impacts: 0 to ~80
     impacts per lane, step counts within a factor ~10 (a milder, common case).

   Variants: `none` (one vmap over the whole batch, the old default), `none_chunk` (vmap
   over chunks of the pool's width), `sorted_chunk` (the same chunks after sorting the lanes
   by their true step count: the best any sort-then-chunk scheme can do, sort not timed),
   `presort_chunk` (full mode: sort by a loose-tolerance probe pass, timed with the probe: the
   dropped `balance="presort"`), and `refill` (the default: the refilling pool).
   **Utilisation** = Σ lane steps / Σ over loop iterations of the vmap width: the fraction
   of lane-steps that do useful work. For the vmap variants it is exact; for the pool it is
   computed by replaying the pool's schedule (`pool_schedule`, which mirrors `grazejax/_loop/pool.py`) on
   the lanes' true step counts. 1 / utilisation(none) is the gain an ideal balancer with the
   same cost per lane-step would get.
3. **Memory**: XLA's buffer assignment for one chunk (`compiled.memory_analysis()`:
   arguments + outputs + temporaries, the device memory a chunk needs) per variant, and the
   process's peak RSS (`resource.getrusage(...).ru_maxrss`: a high-water mark of the whole
   process, including XLA's compiler, so it is not per variant).
4. **The tax** (`--tax`, on its own: DIR/sweep_tax.json and .md): `gj.sweep` (the default
   refilling pool, and `balance="none"`) against a hand-written
   `jax.jit(jax.vmap(simulate))` of the same lanes compiled as `sweep` compiles it
   (`bench_phases.runner`): ex1dof μ = 0.2, 10 impacts, Dopri8 rtol = atol = 2e-12 (the
   setting that reaches 1e-10 against heyoka), lanes in phase and at random phases
   (`bench_phases.starts`), 64 / 512 / 2048 lanes, `progress=False`, one core (the
   process is pinned before JAX starts its thread pool), interleaved, min of the rounds.
   Issue #43's target: `sweep` ≤ 1.05× the hand-written program.
"""

import argparse
import json
import os
import platform
import resource
import sys
import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
import grazejax._loop.pool as _pool
import grazejax._sweep as _sweep
from grazejax import examples as ex

sys.path.insert(0, os.path.dirname(__file__))
import peers  # noqa: E402
from _cases import time_interleaved  # noqa: E402

CYCLE_POST = np.array([0.0, 0.0384224329])  # post-impact state of the μ = 0.2 cycle


def starts(num, seed=0):
    rng = np.random.default_rng(seed)
    x0s = np.tile(CYCLE_POST, (num, 1))
    x0s[:, 1] += rng.uniform(-0.01, 0.01, num)
    return x0s


def time_call(fn, repeats):
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times), float(np.median(times))


def peak_rss_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


def default_width(batch):
    return min(_sweep._DEFAULT_POOL, batch)


# --------------------------------------------------------------------------------------
# Schedules: how many vmap-width × iterations each variant runs, from true step counts
# --------------------------------------------------------------------------------------


def chunk_utilisation(steps, chunk):
    """Σ steps / Σ_chunks (chunk width × the chunk's max steps), padding included."""
    work = sum(chunk * steps[i : i + chunk].max() for i in range(0, len(steps), chunk))
    return float(steps.sum() / work)


def pool_schedule(steps, width):
    """Replay `_pool.run_pool` on lanes that each need `steps[i]` steps (single device).

    Returns the lane-steps paid (Σ width over iterations, both phases) and the iterations.
    """
    steps = np.asarray(steps)
    count = len(steps)
    width = max(1, min(width, count))
    refill_at = max(1, width // _pool.REFILL)
    tail = width // _pool.TAIL if width >= _pool.MIN_TAIL_WIDTH else width
    left = np.zeros(width, int)  # steps left per slot
    lane = np.full(width, -1)
    queue = 0
    iters = [0, 0]

    def draining():
        return tail < width and queue >= count and np.sum((left > 0) & (lane >= 0)) <= tail

    while (np.any(lane >= 0) or queue < count) and not draining():
        # Inner loop: step until refill_at slots have finished (or none runs); in closed
        # form, jump to the k-th smallest remaining count.
        live = left > 0
        finished = np.sum((lane >= 0) & ~live)
        if live.any() and finished < refill_at and not draining():
            need = refill_at - finished
            remaining = np.sort(left[live])
            n = remaining[min(need, len(remaining)) - 1]
            if tail < width and queue >= count:  # stop early when the drain condition hits
                over = len(remaining) - tail  # slots that must finish first
                if over > 0:
                    n = min(n, remaining[over - 1])
                else:
                    n = 0
            iters[0] += int(n)
            left = np.maximum(left - n, 0)
        free = ((lane >= 0) & (left == 0)) | (lane < 0)
        for slot in np.flatnonzero(free):
            if queue < count:
                lane[slot], left[slot] = queue, steps[queue]
                queue += 1
            else:
                lane[slot], left[slot] = -1, 0
    if tail < width:
        iters[1] = int(left.max(initial=0))
    paid = width * iters[0] + tail * iters[1]
    return {"width": width, "tail_width": tail, "iterations": iters, "lane_steps_paid": int(paid),
            "utilisation": float(steps.sum() / paid) if paid else 1.0}


def chunk_memory(scene, x0s, t0, t1, args, width, chunk, **options):
    """XLA's memory for one chunk program (bytes): arguments, outputs, temporaries."""
    flags = _sweep._auto_batched(args, len(x0s))
    runner = _sweep._compiled_chunk(scene, t0, t1, flags, True, jax.devices()[:1], width, options)
    index = np.arange(chunk)
    x = x0s[index]
    a = jax.tree.map(lambda leaf, b: np.asarray(leaf)[index] if b else leaf, args, flags)
    m = runner.lower(x, a, np.ones(chunk, bool)).compile().memory_analysis()
    parts = {"argument": m.argument_size_in_bytes, "output": m.output_size_in_bytes,
             "temp": m.temp_size_in_bytes, "alias": m.alias_size_in_bytes}
    parts["total_MiB"] = (parts["argument"] + parts["output"] + parts["temp"] - parts["alias"]) / 2**20
    return parts


# --------------------------------------------------------------------------------------
# 1. Throughput, homogeneous lanes, against SciPy and heyoka
# --------------------------------------------------------------------------------------


def throughput(lanes, quick):
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    x0s = starts(lanes)
    kw = dict(rtol=1e-10, atol=1e-10, max_impacts=10, progress=False)

    def run(balance):
        return lambda: gj.sweep(scene, x0s, 0.0, jnp.inf, args, balance=balance, **kw)

    out = run("refill")()
    assert np.all(out.status == gj.Status.MAX_IMPACTS), np.unique(out.status)
    # At matched accuracy: Tsit5 at 1e-10 ends ~2e-8 off after 10 near-grazing impacts
    # (global error, not the local tolerance); Dopri8 at 1e-12 reaches heyoka's 1e-10.
    tight = dict(kw, rtol=1e-12, atol=1e-12, solver=diffrax.Dopri8())

    def run_tight():
        return gj.sweep(scene, x0s, 0.0, jnp.inf, args, balance="none", **tight)

    out_tight = run_tight()
    timing, _ = time_interleaved(
        {"none": run("none"), "refill": run("refill"), "dopri8_1e-12": run_tight}, 2 if quick else 4
    )

    num_ref = 20 if quick else 100
    ref_runner = peers.HeyokaImpactRunner("ex1dof", tol=1e-18, fp_type=np.longdouble, mu=0.2)
    refs = [ref_runner.run(x0s[i], 0.0, 1e6, 10) for i in range(num_ref)]

    def err_of(times, posts, i):
        return max(np.max(np.abs(np.asarray(times) - refs[i]["impact_times"])),
                   np.max(np.abs(np.asarray(posts) - refs[i]["impact_post"])))

    gj_err = max(err_of(out.impact_times[i, :10], out.impact_post[i, :10], i) for i in range(num_ref))
    gj_tight_err = max(
        err_of(out_tight.impact_times[i, :10], out_tight.impact_post[i, :10], i) for i in range(num_ref)
    )

    scipy_runner = peers.ScipyImpactRunner("ex1dof", method="DOP853", rtol=1e-10, atol=1e-10,
                                           max_step=0.05, mu=0.2)
    hey_runner = peers.HeyokaImpactRunner("ex1dof", tol=1e-10, mu=0.2)
    num_scipy = 5 if quick else 20
    t = time.perf_counter()
    sc = [scipy_runner.run(x0s[i], 0.0, 1e6, 10) for i in range(num_scipy)]
    scipy_per_run = (time.perf_counter() - t) / num_scipy
    scipy_err = max(err_of(r["impact_times"], r["impact_post"], i) for i, r in enumerate(sc))
    hey_runner.run(x0s[0], 0.0, 1e6, 10)
    hey_times = []
    for _ in range(3):
        t = time.perf_counter()
        hy = [hey_runner.run(x0s[i], 0.0, 1e6, 10) for i in range(num_ref)]
        hey_times.append((time.perf_counter() - t) / num_ref)
    hey_per_run = min(hey_times)
    hey_err = max(err_of(r["impact_times"], r["impact_post"], i) for i, r in enumerate(hy))

    per_lane = {k: v["min_s"] / lanes for k, v in timing.items()}
    return {
        "lanes": lanes,
        "grazejax": timing,
        "grazejax_per_lane_us": {k: v * 1e6 for k, v in per_lane.items()},
        "refill_gain": timing["none"]["min_s"] / timing["refill"]["min_s"],
        "steps_per_lane": {"min": int(out.num_steps.min()), "max": int(out.num_steps.max())},
        "utilisation_none": chunk_utilisation(out.num_steps, lanes),
        "scipy_dop853_per_run_us": scipy_per_run * 1e6,
        "heyoka_per_run_us": hey_per_run * 1e6,
        "max_error": {"grazejax": gj_err, "grazejax_dopri8_1e-12": gj_tight_err, "scipy": scipy_err,
                      "heyoka": hey_err},
        "speedup_vs_scipy": {k: scipy_per_run / v for k, v in per_lane.items()},
        "speedup_vs_heyoka": {k: hey_per_run / v for k, v in per_lane.items()},
        "peak_rss_MiB_so_far": peak_rss_mib(),
    }


# --------------------------------------------------------------------------------------
# 2. The slowest-lane problem, heterogeneous lanes
# --------------------------------------------------------------------------------------


def table_case(lanes):
    rng = np.random.default_rng(0)
    e = rng.uniform(0.3, 0.95, lanes)
    h = rng.uniform(0.05, 1.0, lanes)
    args = dict(g=9.81, e=jnp.asarray(e), A=0.05, omega=10.0)
    x0s = np.stack([h, np.zeros(lanes)], axis=1)
    kw = dict(rtol=1e-8, atol=1e-10, max_impacts=200)
    return "table", ex.vibrating_table(), x0s, 0.0, 10.0, args, kw


def oscillator_case(lanes):
    omega = np.linspace(0.5, 3.0, lanes)
    args = dict(ex.impact_oscillator_args(), omega=jnp.asarray(omega))
    x0s = np.zeros((lanes, 2))
    kw = dict(rtol=1e-8, atol=1e-10, max_impacts=400)
    return "oscillator_omega", ex.impact_oscillator(), x0s, 0.0, 100.0, args, kw


def slowest_lane(case, quick):
    name, scene, x0s, t0, t1, args, kw = case
    batch = len(x0s)
    width = default_width(batch)

    def run(balance, order=None, **extra):
        xs = x0s if order is None else x0s[order]
        a = args if order is None else {k: (v[order] if np.ndim(v) else v) for k, v in args.items()}
        return gj.sweep(scene, xs, t0, t1, a, balance=balance, progress=False, **kw, **extra)

    ref = run("refill")
    steps = np.asarray(ref.num_steps)
    by_cost = np.argsort(steps, kind="stable")

    def presort():
        loose = dict(kw, rtol=1e-4, atol=1e-6)
        cost = gj.sweep(scene, x0s, t0, t1, args, balance="none", chunk_size=width,
                        progress=False, **loose).num_steps
        return run("none", order=np.argsort(cost, kind="stable"), chunk_size=width)

    fns = {"none": lambda: run("none")}
    if width < batch:  # chunked variants (with one chunk they are `none`)
        fns["none_chunk"] = lambda: run("none", chunk_size=width)
        fns["sorted_chunk"] = lambda: run("none", order=by_cost, chunk_size=width)
        if not quick:
            fns["presort_chunk"] = presort
    fns["refill"] = lambda: run("refill")
    timing, _ = time_interleaved(fns, 2 if quick else 3)
    # Same results whatever the variant (statuses and step counts; values: tests/test_sweep.py).
    plain = run("none")
    assert np.array_equal(plain.num_steps, ref.num_steps) and np.array_equal(plain.status, ref.status)

    util = {
        "none": chunk_utilisation(steps, batch),
        "none_chunk": chunk_utilisation(steps, width),
        "sorted_chunk": chunk_utilisation(steps[by_cost], width),
    }
    util = {k: v for k, v in util.items() if k in fns}
    schedule = pool_schedule(steps, width)
    util["refill"] = schedule["utilisation"]
    base = timing["none"]["min_s"]
    memory = {}
    for label, w, chunk in (("none", None, batch), ("none_chunk", None, width), ("refill", width, batch)):
        if label not in fns:
            continue
        try:
            memory[label] = chunk_memory(scene, x0s, t0, t1, args, w, chunk, **kw)
        except Exception as error:  # noqa: BLE001 - memory_analysis is backend-dependent
            memory[label] = {"error": f"{type(error).__name__}: {error}"}
    statuses, counts = np.unique(ref.status, return_counts=True)
    return {
        "case": name,
        "lanes": batch,
        "pool_width": width,
        "impacts": {"min": int(ref.num_impacts.min()), "median": float(np.median(ref.num_impacts)),
                    "max": int(ref.num_impacts.max())},
        "steps": {"min": int(steps.min()), "mean": float(steps.mean()), "max": int(steps.max())},
        "statuses": {gj.Status(int(s)).name: int(c) for s, c in zip(statuses, counts, strict=True)},
        "timing": timing,
        "per_lane_us": {k: v["min_s"] / batch * 1e6 for k, v in timing.items()},
        "gain_vs_none": {k: base / v["min_s"] for k, v in timing.items()},
        "utilisation": util,
        "ideal_gain": 1.0 / util["none"],
        "pool_schedule": schedule,
        "xla_memory_per_chunk": memory,
        "peak_rss_MiB_so_far": peak_rss_mib(),
    }


# --------------------------------------------------------------------------------------
# 4. The tax: sweep against a hand-written jit(vmap(simulate))
# --------------------------------------------------------------------------------------


def sweep_tax(lane_counts, rounds):
    """Per lane count and kind of start: µs per trajectory of `jit(vmap(simulate))`,
    `sweep` and `sweep(balance="none")`, interleaved, and their ratios to the first."""
    import bench_phases

    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    solver, tol = diffrax.Dopri8(), 2e-12
    kw = dict(solver=solver, rtol=tol, atol=tol, max_impacts=bench_phases.IMPACTS, progress=False)
    by_hand = bench_phases.runner(solver, tol)
    rows = []
    for lanes in lane_counts:
        for kind, x0s in bench_phases.starts(lanes).items():
            xs = jnp.asarray(x0s)
            fns = {
                "jit(vmap(simulate))": lambda xs=xs: jax.block_until_ready(by_hand(xs)),
                "sweep": lambda x0s=x0s: gj.sweep(scene, x0s, 0.0, jnp.inf, args, **kw),
                'sweep(balance="none")': lambda x0s=x0s: gj.sweep(
                    scene, x0s, 0.0, jnp.inf, args, balance="none", **kw),
            }
            timing, first = time_interleaved(fns, rounds)
            steps = np.asarray(first["sweep"].num_steps)
            assert np.all(np.asarray(first["sweep"].status) == int(gj.Status.MAX_IMPACTS))
            base = timing["jit(vmap(simulate))"]["min_s"]
            rows.append({
                "lanes": lanes, "starts": kind,
                "steps": {"min": int(steps.min()), "max": int(steps.max()),
                          "mean": float(steps.mean())},
                "us_per_trajectory": {k: v["min_s"] / lanes * 1e6 for k, v in timing.items()},
                "over_jit_vmap": {k: v["min_s"] / base for k, v in timing.items()},
                "timing": timing,
            })
    return rows


def tax_report(rows, rounds):
    md = ["# `sweep` against a hand-written `jit(vmap(simulate))`", "",
          "ex1dof μ = 0.2, 10 impacts, Dopri8 rtol = atol = 2e-12, one core, `progress=False`, "
          f"min of {rounds} interleaved rounds; µs per trajectory (ratio to the hand-written "
          "program).", "",
          "| lanes | starts | steps per lane | `jit(vmap(simulate))` | `sweep` | "
          "`sweep(balance=\"none\")` |", "|---:|---|---|---:|---:|---:|"]
    for r in rows:
        us, over = r["us_per_trajectory"], r["over_jit_vmap"]
        cells = [f"{us[k]:.1f} ({over[k]:.2f}×)" for k in us]
        md.append(f"| {r['lanes']} | {r['starts']} | {r['steps']['min']}–{r['steps']['max']} | "
                  + " | ".join(cells) + " |")
    return "\n".join(md)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--lanes", type=int, default=None)
    parser.add_argument("--out", default="bench-output")
    parser.add_argument("--tax", action="store_true",
                        help="only section 4: sweep against a hand-written jit(vmap(simulate))")
    opts = parser.parse_args(argv)
    if opts.tax:
        rounds = 3 if opts.quick else 8
        rows = sweep_tax((64, 512) if opts.quick else (64, 512, 2048), rounds)
        os.makedirs(opts.out, exist_ok=True)
        with open(os.path.join(opts.out, "sweep_tax.json"), "w") as f:
            json.dump({"rounds": rounds, "cpu": sorted(os.sched_getaffinity(0)), "rows": rows},
                      f, indent=2)
        md = tax_report(rows, rounds)
        with open(os.path.join(opts.out, "sweep_tax.md"), "w") as f:
            f.write(md + "\n")
        print(md)
        return
    lanes = opts.lanes or (2000 if opts.quick else 20000)
    start = time.perf_counter()
    results = {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "load_avg": os.getloadavg(),
                    "devices": [str(d) for d in jax.devices()],
                    "versions": {"jax": jax.__version__, "grazejax": gj.__version__}},
        "throughput": throughput(lanes, opts.quick),
        "slowest_lane": [
            slowest_lane(table_case(2048 if opts.quick else 16384), opts.quick),
            slowest_lane(oscillator_case(1024 if opts.quick else 8192), opts.quick),
        ],
    }
    results["peak_rss_MiB"] = peak_rss_mib()
    results["wall_s"] = time.perf_counter() - start
    os.makedirs(opts.out, exist_ok=True)
    with open(os.path.join(opts.out, "sweep.json"), "w") as f:
        json.dump(results, f, indent=2)
    md = report(results)
    with open(os.path.join(opts.out, "sweep.md"), "w") as f:
        f.write(md + "\n")
    print(md)


def report(results):
    tp = results["throughput"]
    us, sp, hy = tp["grazejax_per_lane_us"], tp["speedup_vs_scipy"], tp["speedup_vs_heyoka"]
    md = [
        "# Sweep benchmark", "",
        f"{results['machine']['devices'][0]}, {results['machine']['cpus']} CPUs, load "
        f"{results['machine']['load_avg'][0]:.1f}; min of interleaved repeats; read the ratios.", "",
        "## Throughput: ex1dof μ=0.2, 10 impacts per lane (homogeneous)", "",
        f"{tp['lanes']} lanes, rtol=atol=1e-10, {tp['steps_per_lane']['min']}–"
        f"{tp['steps_per_lane']['max']} steps per lane.", "",
        "| tool | µs per lane/run | vs SciPy | vs heyoka | max error vs reference |",
        "|---|---:|---:|---:|---:|",
        f"| grazejax.sweep balance='none' | {us['none']:.1f} | {sp['none']:.0f}× | {hy['none']:.2f}× "
        f"| {tp['max_error']['grazejax']:.1e} |",
        f"| grazejax.sweep balance='refill' | {us['refill']:.1f} | {sp['refill']:.0f}× | {hy['refill']:.2f}× "
        f"| (same lanes) |",
        f"| grazejax.sweep Dopri8, rtol=atol=1e-12 (matched accuracy) | {us['dopri8_1e-12']:.1f} "
        f"| {sp['dopri8_1e-12']:.0f}× | {hy['dopri8_1e-12']:.2f}× "
        f"| {tp['max_error']['grazejax_dopri8_1e-12']:.1e} |",
        f"| scipy DOP853 (max_step 0.05) | {tp['scipy_dop853_per_run_us']:.1f} | | "
        f"| {tp['max_error']['scipy']:.1e} |",
        f"| heyoka | {tp['heyoka_per_run_us']:.1f} | | | {tp['max_error']['heyoka']:.1e} |", "",
        "(vs X: X's time per run / grazejax's per lane; > 1 means grazejax is faster.) "
        f"refill / none time ratio: {1 / tp['refill_gain']:.2f} (nothing to balance here).", "",
        "## Slowest lane: heterogeneous sweeps", "",
    ]
    for sl in results["slowest_lane"]:
        md += [
            f"**{sl['case']}**: {sl['lanes']} lanes, impacts per lane {sl['impacts']['min']}–"
            f"{sl['impacts']['max']} (median {sl['impacts']['median']:.0f}), steps "
            f"{sl['steps']['min']}–{sl['steps']['max']} (mean {sl['steps']['mean']:.0f}); "
            f"statuses {sl['statuses']}; pool width {sl['pool_width']} (tail "
            f"{sl['pool_schedule']['tail_width']}). Ideal gain 1/utilisation(none) = "
            f"{sl['ideal_gain']:.2f}.", "",
            "| variant | s (min) | µs per lane | gain vs none | utilisation | XLA memory per chunk (MiB) |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for k, t in sl["timing"].items():
            util = sl["utilisation"].get(k)
            mem = sl["xla_memory_per_chunk"].get(k, {}).get("total_MiB")
            md.append(
                f"| {k} | {t['min_s']:.2f} | {sl['per_lane_us'][k]:.0f} | {sl['gain_vs_none'][k]:.2f} "
                f"| {'' if util is None else f'{util:.2f}'} | {'' if mem is None else f'{mem:.1f}'} |"
            )
        md.append("")
    md.append(f"Peak RSS of the process: {results['peak_rss_MiB']:.0f} MiB (a high-water mark, "
              f"compilers included). Wall time {results['wall_s']:.0f} s.")
    return "\n".join(md)


if __name__ == "__main__":
    if "--tax" in sys.argv:
        from bench_throughput import pin_to_one_core

        pin_to_one_core()  # before JAX starts its thread pool
    main()
