"""Sweep throughput: grazejax.sweep per lane vs SciPy and heyoka per run, and the
slowest-lane problem (balance="none" vs "presort").

    python benchmarks/bench_sweep.py [--quick] [--lanes N] [--out DIR]

Writes DIR/sweep.json and DIR/sweep.md (default DIR: bench-output/). All timings come from
one process on one machine; ratios are what to read (see benchmarks/README.md).

Problem: ex1dof at μ = 0.2 (every impact nearly grazing), 10 impacts per lane
(`max_impacts=10`, `t1=inf`), starts spread around the attracting impacting cycle.
Accuracy is matched: grazejax and SciPy at rtol = atol = 1e-10, heyoka at tol 1e-10; the
error of each against a heyoka long-double reference is reported next to its time.

Slowest lane: ex1dof at μ = −0.2 over a fixed horizon from a grid of starts; lanes inside
the continuous cycle's basin have no impacts, the others many, so per-lane cost varies a lot.
"""

import argparse
import json
import os
import platform
import resource
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
from grazejax import examples as ex

sys.path.insert(0, os.path.dirname(__file__))
import peers  # noqa: E402

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


def throughput(lanes, quick):
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    x0s = starts(lanes)
    kw = dict(rtol=1e-10, atol=1e-10, max_impacts=10, progress=False)

    def run_sweep():
        return gj.sweep(scene, x0s, 0.0, jnp.inf, args, **kw)

    compile_start = time.perf_counter()
    out = run_sweep()
    first_call = time.perf_counter() - compile_start
    assert np.all(out.status == gj.Status.MAX_IMPACTS), np.unique(out.status)
    best, median = time_call(run_sweep, 1 if quick else 3)

    num_ref = 20 if quick else 100
    ref_runner = peers.HeyokaImpactRunner("ex1dof", tol=1e-18, fp_type=np.longdouble, mu=0.2)
    refs = [ref_runner.run(x0s[i], 0.0, 1e6, 10) for i in range(num_ref)]

    def err_of(times, posts, i):
        return max(np.max(np.abs(np.asarray(times) - refs[i]["impact_times"])),
                   np.max(np.abs(np.asarray(posts) - refs[i]["impact_post"])))

    gj_err = max(err_of(out.impact_times[i, :10], out.impact_post[i, :10], i) for i in range(num_ref))

    scipy_runner = peers.ScipyImpactRunner("ex1dof", method="DOP853", rtol=1e-10, atol=1e-10,
                                           max_step=0.05, mu=0.2)
    hey_runner = peers.HeyokaImpactRunner("ex1dof", tol=1e-10, mu=0.2)
    num_scipy = 5 if quick else 20
    t = time.perf_counter()
    sc = [scipy_runner.run(x0s[i], 0.0, 1e6, 10) for i in range(num_scipy)]
    scipy_per_run = (time.perf_counter() - t) / num_scipy
    scipy_err = max(err_of(r["impact_times"], r["impact_post"], i) for i, r in enumerate(sc))
    hey_runner.run(x0s[0], 0.0, 1e6, 10)
    t = time.perf_counter()
    hy = [hey_runner.run(x0s[i], 0.0, 1e6, 10) for i in range(num_ref)]
    hey_per_run = (time.perf_counter() - t) / num_ref
    hey_err = max(err_of(r["impact_times"], r["impact_post"], i) for i, r in enumerate(hy))

    per_lane = best / lanes
    return {
        "lanes": lanes,
        "grazejax_first_call_s": first_call,
        "grazejax_total_s": {"min": best, "median": median},
        "grazejax_per_lane_us": per_lane * 1e6,
        "scipy_dop853_per_run_us": scipy_per_run * 1e6,
        "heyoka_per_run_us": hey_per_run * 1e6,
        "max_error": {"grazejax": gj_err, "scipy": scipy_err, "heyoka": hey_err},
        "speedup_vs_scipy": scipy_per_run / per_lane,
        "speedup_vs_heyoka": hey_per_run / per_lane,
        "peak_rss_MiB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }


def slowest_lane(grid, quick):
    scene, args = ex.ex1dof(), ex.ex1dof_args(-0.2)
    g = np.linspace(-0.9, 0.9, grid)
    X, V = np.meshgrid(g + 1.0, g)
    x0s = np.stack([X.ravel(), V.ravel()], axis=1)
    kw = dict(rtol=1e-8, atol=1e-10, max_impacts=400, progress=False, chunk_size=max(64, grid * grid // 8))
    out = {}
    for balance in ("none", "presort"):
        run = lambda: gj.sweep(scene, x0s, 0.0, 150.0, args, balance=balance, **kw)  # noqa: E731
        res = run()
        best, _ = time_call(run, 1 if quick else 2)
        out[balance] = {"seconds": best, "impacts_min": int(res.num_impacts.min()),
                        "impacts_max": int(res.num_impacts.max()),
                        "steps_min": int(res.num_steps.min()), "steps_max": int(res.num_steps.max())}
    out["gain"] = out["none"]["seconds"] / out["presort"]["seconds"]
    out["lanes"] = len(x0s)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--lanes", type=int, default=None)
    parser.add_argument("--out", default="bench-output")
    opts = parser.parse_args(argv)
    lanes = opts.lanes or (2000 if opts.quick else 20000)
    results = {
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "devices": [str(d) for d in jax.devices()],
                    "versions": {"jax": jax.__version__, "grazejax": gj.__version__}},
        "throughput": throughput(lanes, opts.quick),
        "slowest_lane": slowest_lane(24 if opts.quick else 60, opts.quick),
    }
    os.makedirs(opts.out, exist_ok=True)
    with open(os.path.join(opts.out, "sweep.json"), "w") as f:
        json.dump(results, f, indent=2)
    tp, sl = results["throughput"], results["slowest_lane"]
    md = [
        "# Sweep benchmark", "",
        f"ex1dof μ=0.2, 10 impacts/lane, {tp['lanes']} lanes, rtol=atol=1e-10 ({results['machine']['devices'][0]})", "",
        "| tool | µs per lane/run | max error vs reference |", "|---|---:|---:|",
        f"| grazejax.sweep | {tp['grazejax_per_lane_us']:.1f} | {tp['max_error']['grazejax']:.1e} |",
        f"| scipy DOP853 (max_step 0.05) | {tp['scipy_dop853_per_run_us']:.1f} | {tp['max_error']['scipy']:.1e} |",
        f"| heyoka | {tp['heyoka_per_run_us']:.1f} | {tp['max_error']['heyoka']:.1e} |", "",
        f"grazejax is {tp['speedup_vs_scipy']:.0f}× faster per lane than SciPy per run and "
        f"{tp['speedup_vs_heyoka']:.2f}× heyoka's speed (>1 means faster). Peak RSS {tp['peak_rss_MiB']:.0f} MiB.", "",
        f"Slowest lane (ex1dof μ=−0.2, {sl['lanes']} lanes, impacts per lane {sl['none']['impacts_min']}–{sl['none']['impacts_max']}): "
        f"balance='none' {sl['none']['seconds']:.2f} s, 'presort' {sl['presort']['seconds']:.2f} s, gain ×{sl['gain']:.2f}.",
    ]
    with open(os.path.join(opts.out, "sweep.md"), "w") as f:
        f.write("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()
