"""Self-check of the peer implementations in peers.py.

    python benchmarks/check_peers.py

1. scipy (DOP853, rtol=atol=1e-12) vs heyoka (tol=1e-15): first 10 impact
   times for every system (should agree to ~1e-9).
2. Bouncing ball vs the closed form.
3. Timing of ex1dof (mu=0.2, x0=(0, 1.3), 10 impacts), median over repeats
   after a warm-up run (heyoka compile time reported separately).

Single process, a few seconds of CPU in total.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from peers import HeyokaImpactRunner, ScipyImpactRunner  # noqa: E402

N_IMP = 10
TOL_AGREE = 1e-9

# (system, x0, t0, t1, params).  t1 is generous: every case stops on N_IMP.
CASES = [
    ("ex1dof", (0.0, 1.3), 0.0, 1e3, dict(mu=0.2)),
    ("ball", (1.0, 0.0), 0.0, 1e3, dict(g=9.81, e=0.8)),
    ("oscillator", (0.0, 0.0), 0.0, 1e3, dict(zeta=0.05, A=0.7, w=0.8, sigma=0.5, r=0.8)),
    ("exnonaxial", (0.0, 1.32), 0.0, 1e3, dict(K=0.11)),
]


def ball_closed_form(h0, g, e, k):
    """First k impact times of a ball dropped from rest at height h0."""
    t = np.sqrt(2.0 * h0 / g)
    v1 = g * t
    times = [t]
    for j in range(1, k):
        t += 2.0 * e**j * v1 / g
        times.append(t)
    return np.array(times)


def median_us(fn, repeats):
    fn()  # warm-up
    samples = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t)
    return 1e6 * float(np.median(samples))


def main():
    ok = True
    runners = {}

    print(f"1) scipy DOP853 rtol=atol=1e-12 vs heyoka tol=1e-15, first {N_IMP} impacts")
    print(f"   {'system':<11} {'n_sp':>4} {'n_hy':>4} {'max|dt|':>10} {'max|dx+|':>10} "
          f"{'nfev_sp':>8} {'steps_hy':>8}  ok")
    for name, x0, t0, t1, prm in CASES:
        sp = ScipyImpactRunner(name, rtol=1e-12, atol=1e-12).run(x0, t0, t1, N_IMP, **prm)
        hr = HeyokaImpactRunner(name, tol=1e-15)
        runners[name] = hr
        hy = hr.run(x0, t0, t1, N_IMP, **prm)
        n = min(len(sp["impact_times"]), len(hy["impact_times"]))
        dt = np.max(np.abs(sp["impact_times"][:n] - hy["impact_times"][:n]))
        # Relative post-impact state error (ex1dof's x2+ reaches ~5e5).
        scale = np.maximum(1.0, np.abs(hy["impact_post"][:n]))
        dx = np.max(np.abs(sp["impact_post"][:n] - hy["impact_post"][:n]) / scale)
        good = n == N_IMP == len(sp["impact_times"]) == len(hy["impact_times"]) and dt < TOL_AGREE
        ok &= good
        print(f"   {name:<11} {len(sp['impact_times']):>4} {len(hy['impact_times']):>4} "
              f"{dt:10.2e} {dx:10.2e} {sp['nfev']:>8} {hy['nfev']:>8}  {'yes' if good else 'NO'}")

    print(f"\n2) bouncing ball h0=1, g=9.81, e=0.8 vs closed form ({N_IMP} impacts)")
    exact = ball_closed_form(1.0, 9.81, 0.8, N_IMP)
    sp = ScipyImpactRunner("ball", rtol=1e-12, atol=1e-12).run((1.0, 0.0), 0.0, 10.0, N_IMP)
    hy = runners["ball"].run((1.0, 0.0), 0.0, 10.0, N_IMP)
    for label, res in (("scipy 1e-12", sp), ("heyoka 1e-15", hy)):
        err = np.max(np.abs(res["impact_times"] - exact))
        good = len(res["impact_times"]) == N_IMP and err < TOL_AGREE
        ok &= good
        print(f"   {label:<13} max|t - t_exact| = {err:.2e}  {'yes' if good else 'NO'}")

    print("\n3) timing: ex1dof mu=0.2, x0=(0, 1.3), 10 impacts (median, after warm-up)")
    x0, t1, prm = (0.0, 1.3), 1e3, dict(mu=0.2)
    sp_runner = ScipyImpactRunner("ex1dof", rtol=1e-10, atol=1e-10)
    us = median_us(lambda: sp_runner.run(x0, 0.0, t1, N_IMP, **prm), repeats=7)
    nfev = sp_runner.run(x0, 0.0, t1, N_IMP, **prm)["nfev"]
    print(f"   scipy DOP853 rtol=atol=1e-10 : {us:12.1f} us/run   (nfev {nfev})")
    for tol in (1e-10, 1e-15):
        t = time.perf_counter()
        hr = HeyokaImpactRunner("ex1dof", tol=tol)
        compile_s = time.perf_counter() - t
        us = median_us(lambda hr=hr: hr.run(x0, 0.0, t1, N_IMP, **prm), repeats=200)
        steps = hr.run(x0, 0.0, t1, N_IMP, **prm)["nfev"]
        print(f"   heyoka tol={tol:.0e}         : {us:12.1f} us/run   "
              f"(steps {steps}, compile {1e3 * compile_s:.0f} ms)")

    print("\nALL OK" if ok else "\nSOME CHECKS FAILED")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
