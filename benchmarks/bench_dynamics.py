"""Dynamics at scale: time per start of Lyapunov spectra and basins through impacts.

    python benchmarks/bench_dynamics.py [--quick] [--starts N] [--periods P] [--basin-starts M]
                                        [--floor-starts F] [--peer-starts S]
                                        [--out DIR]   (default DIR: results/)

Writes DIR/dynamics.json and DIR/dynamics.md.

1. **Lyapunov spectra** of the forced impact oscillator (ζ 0.05, A 1, ω 1.2, stop σ 0.2,
   r 0.5), k = 2, windows of one forcing period T, rtol 1e-10 / atol 1e-12, from random starts
   near its period-1 orbit: `jax.vmap(gj.lyapunov_spectrum)` over the starts (one program),
   against the fastest SciPy configuration there is for it: `solve_ivp` (DOP853, same
   tolerances) of the state with its variational equations (the field is linear, so the
   tangent flow is exact), a terminal event at the stop, the saltation matrix applied by hand
   at each impact, QR once per period. Both give the same exponents (checked). heyoka has no
   jump maps; its variational equations would still need the saltation by hand: not run.
   Beside it, the maximal exponent alone (`gj.maximal_lyapunov_exponent`, one tangent
   vector) and the floor no tangent method can beat: the trajectory alone
   (`vmap(gj.simulate)` over the same horizon). Peak memory: the resident set after it.
2. **Basins** of a ball on a vibrating table (Γ = 1.05, e = 0.8: period-1 and period-3
   attractors and chattering starts), impact map, 16 points after 60 periods, random starts:
   `gj.basins` per start and its peak memory (resident set, `getrusage`).

Time per start is wall time over the starts of one call of a program compiled ahead of time
for their shape (its compile is reported as the first call); one process, this machine's
cores. The maximal exponent and the trajectory floor run on the first `--floor-starts`
starts and SciPy on the first `--peer-starts`: each figure is a time per start.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import time
from pathlib import Path

import numpy as np

OSC = dict(zeta=0.05, A=1.0, omega=1.2, sigma=0.2, r=0.5)
RTOL, ATOL = 1e-10, 1e-12


def _starts(count, seed=0):
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-0.6, 0.15, count), rng.uniform(-0.5, 0.5, count)], axis=1)


def scipy_spectrum(x0, periods):
    """k = 2 spectrum by DOP853 with variational equations and the saltation matrix."""
    from scipy.integrate import solve_ivp

    z, w, A, s, r = (OSC[k] for k in ("zeta", "omega", "A", "sigma", "r"))
    jac = np.array([[0.0, 1.0], [-1.0, -2 * z]])

    def field(t, x):
        return np.array([x[1], -2 * z * x[1] - x[0] + A * math.cos(w * t)])

    def rhs(t, y):
        return np.concatenate([field(t, y[:2]), (jac @ y[2:].reshape(2, 2)).ravel()])

    def hit(t, y):
        return y[0] - s

    hit.terminal, hit.direction = True, 1
    from grazejax._dynamics.lyapunov import start_frame

    T = 2 * math.pi / w
    # grazejax's starting frame, so that the two compute the same finite-time exponents
    x, Q, logs, t = np.asarray(x0, float), start_frame(2, 2), np.zeros(2), 0.0
    for k in range(periods):
        t_end, Y = (k + 1) * T, Q.copy()
        while True:
            sol = solve_ivp(rhs, (t, t_end), np.concatenate([x, Y.ravel()]), method="DOP853",
                            rtol=RTOL, atol=ATOL, events=hit)
            t, y = sol.t[-1], sol.y[:, -1]
            x, Y = y[:2], y[2:].reshape(2, 2)
            if sol.status != 1:
                break
            pre = np.array([s, x[1]])
            post = np.array([s, -r * x[1]])
            DJ = np.diag([1.0, -r])
            f_pre, f_post = field(t, pre), field(t, post)
            # S = DJ + (f⁺ − DJ f⁻) ∇Φᵀ / (∇Φ·f⁻), Φ = σ − x: ∇Φ = (−1, 0)
            S = DJ + np.outer(f_post - DJ @ f_pre, [-1.0, 0.0]) / (-f_pre[0])
            x, Y = post, S @ Y
        Q, R = np.linalg.qr(Y)
        signs = np.sign(np.diag(R))
        Q, logs = Q * signs, logs + np.log(np.abs(np.diag(R)))
    return np.sort(logs / (periods * T))[::-1]


def _compiled(fn, x):
    """`fn` compiled ahead of time for `x`'s shape, and the seconds that took (tracing,
    lowering, XLA): the first call's cost without running the program twice."""
    t = time.perf_counter()
    compiled = fn.lower(x).compile()
    return compiled, time.perf_counter() - t


def _timed_per_start(compiled, x):
    import jax

    t = time.perf_counter()
    out = jax.block_until_ready(compiled(x))
    return out, (time.perf_counter() - t) / x.shape[0]


def lyapunov_case(starts, periods, floor_starts, peer_starts):
    import jax
    import jax.numpy as jnp

    import grazejax as gj
    from grazejax import examples as ex

    scene, args = ex.impact_oscillator(), ex.impact_oscillator_args(**OSC)
    T = 2 * math.pi / OSC["omega"]

    @jax.jit
    def spectra(x0s):
        return jax.vmap(lambda x0: gj.lyapunov_spectrum(
            scene, x0, 0.0, periods * T, args, renormalize=T, rtol=RTOL, atol=ATOL,
            max_impacts=16))(x0s)

    x = jnp.asarray(starts)
    compiled, first = _compiled(spectra, x)
    out, ours = _timed_per_start(compiled, x)
    peer_x0s = starts[:peer_starts]
    t = time.perf_counter()
    peer = np.stack([scipy_spectrum(x0, periods) for x0 in peer_x0s])
    theirs = (time.perf_counter() - t) / len(peer_x0s)
    ok = np.asarray(out.status) == int(gj.LyapunovStatus.SUCCESS)
    agree = float(np.max(np.abs(np.asarray(out.exponents)[: len(peer_x0s)] - peer)))

    @jax.jit
    def maximal(x0s):
        return jax.vmap(lambda x0: gj.maximal_lyapunov_exponent(
            scene, x0, 0.0, periods * T, args, renormalize=T, rtol=RTOL, atol=ATOL,
            max_impacts=16).exponents)(x0s)

    @jax.jit
    def trajectory(x0s):
        return jax.vmap(lambda x0: gj.simulate(
            scene, x0, 0.0, periods * T, args, rtol=RTOL, atol=ATOL,
            max_impacts=2 * periods + 16, max_steps=1000 * periods).status)(x0s)

    floors, x_floor = {}, x[:floor_starts]
    for name, fn in (("maximal", maximal), ("trajectory", trajectory)):
        result, floors[name] = _timed_per_start(_compiled(fn, x_floor)[0], x_floor)
        if name == "trajectory" and not np.all(np.asarray(result) == int(gj.Status.SUCCESS)):
            raise RuntimeError(f"the trajectories ended with statuses {np.unique(result)}")
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB (Linux: KiB)
    return {"case": "lyapunov", "starts": len(starts), "periods": periods,
            "first_call_s": first, "grazejax_us_per_start": ours * 1e6,
            "floor_starts": int(x_floor.shape[0]),
            "maximal_us_per_start": floors["maximal"] * 1e6,
            "trajectory_us_per_start": floors["trajectory"] * 1e6, "peak_rss_mib": peak,
            "scipy_us_per_start": theirs * 1e6, "scipy_starts": len(peer_x0s),
            "ratio_scipy_over_grazejax": theirs / ours, "succeeded": int(ok.sum()),
            "max_exponent_difference": agree,
            "mean_exponents": np.nanmean(np.asarray(out.exponents)[ok], axis=0).tolist()}


def basins_case(count):
    import grazejax as gj
    from grazejax import examples as ex

    omega, g, e, gamma = 2 * math.pi, 9.81, 0.8, 1.05
    args = dict(g=g, e=e, A=gamma * g / omega**2, omega=omega)
    rng = np.random.default_rng(1)
    starts = np.stack([rng.uniform(0.05, 1.5, count), rng.uniform(-3.0, 3.0, count)], axis=1)
    chunk = min(count, 4096)
    run = dict(surface=0, num_points=16, transient=60.0, max_impacts=200, chunk_size=chunk)
    t = time.perf_counter()  # one chunk: compiles the program the timed call runs
    gj.basins(ex.vibrating_table(), starts[:chunk], 0.0, args, **run)
    first = time.perf_counter() - t
    t = time.perf_counter()
    result = gj.basins(ex.vibrating_table(), starts, 0.0, args, **run)
    per = (time.perf_counter() - t) / count
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # MiB (Linux: KiB)
    return {"case": "basins", "starts": count, "first_call_s": first,
            "grazejax_us_per_start": per * 1e6, "peak_rss_mib": peak,
            "fractions": np.asarray(result.fractions).tolist(),
            "periods": [a.period for a in result.attractors],
            "undecided": int(result.num_undecided)}


def table(rows) -> str:
    lyap, bas = rows
    return "\n".join([
        f"Lyapunov spectra (impact oscillator, k = 2, {lyap['periods']} periods, "
        f"{lyap['starts']} starts; the maximal exponent and the trajectory on "
        f"{lyap['floor_starts']}, SciPy on {lyap['scipy_starts']}):",
        "",
        "| | µs per start | per period | first call |",
        "|---|---:|---:|---:|",
        f"| `vmap(gj.lyapunov_spectrum)` | {lyap['grazejax_us_per_start']:.0f} | "
        f"{lyap['grazejax_us_per_start'] / lyap['periods']:.1f} | {lyap['first_call_s']:.1f} s |",
        f"| `vmap(gj.maximal_lyapunov_exponent)` (k = 1) | {lyap['maximal_us_per_start']:.0f} | "
        f"{lyap['maximal_us_per_start'] / lyap['periods']:.1f} | — |",
        f"| the trajectory alone, `vmap(gj.simulate)` (the floor) | "
        f"{lyap['trajectory_us_per_start']:.0f} | "
        f"{lyap['trajectory_us_per_start'] / lyap['periods']:.1f} | — |",
        f"| SciPy DOP853 + variational equations + saltation | "
        f"{lyap['scipy_us_per_start']:.0f} | {lyap['scipy_us_per_start'] / lyap['periods']:.1f} | — |",
        "",
        f"SciPy / grazejax: {lyap['ratio_scipy_over_grazejax']:.0f}×; largest exponent "
        f"difference {lyap['max_exponent_difference']:.1e}; mean exponents "
        f"{np.round(lyap['mean_exponents'], 5).tolist()} ({lyap['succeeded']} succeeded); "
        f"peak resident memory after the Lyapunov runs {lyap['peak_rss_mib']:.0f} MiB.",
        "",
        f"Basins (vibrating table, Γ = 1.05, e = 0.8, {bas['starts']} starts): "
        f"{bas['grazejax_us_per_start']:.0f} µs per start, peak resident memory "
        f"{bas['peak_rss_mib']:.0f} MiB, first call (one chunk) {bas['first_call_s']:.1f} s; "
        f"attractors of periods {bas['periods']} with basins "
        f"{np.round(bas['fractions'], 4).tolist()}, {bas['undecided']} starts in none "
        "(chattering to rest, or undecided).",
    ])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer starts and periods")
    parser.add_argument("--starts", type=int, help="Lyapunov starts (10,000; --quick 200)")
    parser.add_argument("--periods", type=int, help="Lyapunov periods (1,000; --quick 100)")
    parser.add_argument("--basin-starts", type=int, help="basin starts (100,000; --quick 10,000)")
    parser.add_argument("--floor-starts", type=int, default=1_000,
                        help="starts for the maximal exponent and the trajectory (1,000)")
    parser.add_argument("--peer-starts", type=int, default=40,
                        help="starts SciPy runs (40: its time per start is what is compared)")
    parser.add_argument("--out", default=str(Path(__file__).parent / "results"))
    ns = parser.parse_args(argv)
    starts, periods, count = (200, 100, 10_000) if ns.quick else (10_000, 1_000, 100_000)
    starts, periods = ns.starts or starts, ns.periods or periods
    count = ns.basin_starts or count
    rows = [lyapunov_case(_starts(starts), periods, min(ns.floor_starts, starts),
                      min(ns.peer_starts, starts)), basins_case(count)]
    out = Path(ns.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "dynamics.json").write_text(json.dumps(rows, indent=1))
    text = table(rows) + "\n"
    (out / "dynamics.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
