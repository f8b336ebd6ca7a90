"""Shared pieces of the benchmark suite: test cases with their ground truths, and helpers.

The timing and machine helpers (`stats`, `first_minus_second`, `machine`, `versions`,
`batch_starts`) are those of `bench_core.py`, re-exported here so that every script
measures the same way; this module adds what the suite needs on top:

- `measure`: adaptive repeats within a time budget (min and median of the calls);
- `time_interleaved`: several functions timed side by side, in rounds;

- `Case`: one impact problem, given three times over: a grazejax `Scene`, a peer
  `ImpactSystem` (benchmarks/peers.py: SciPy and heyoka loops with the same event
  semantics), and a ground truth (impact times, pre/post-impact states, the state at t1);
- ground truths: closed forms evaluated in 40-digit arithmetic (mpmath) where the flow is
  linear (`exnonaxial`: a rotation; the forced impact oscillators: matrix exponentials
  through an eigendecomposition, with the impact times as roots found by mpmath), and a
  heyoka run in 80-bit long double at tol 1e-19 where it is not (`ex1dof`; without heyoka,
  SciPy's DOP853 at rtol 1e-13 with max_step 0.01 instead, stated in `truth_method`);
- `HAVE_HEYOKA`, `HAVE_SCIPY`, `missing_peers_line`: which peers are installed (the suite
  skips the others and says how to install them);
- `errors`: the three accuracy measures of a run against its truth.

Every solver is run with rtol = atol (grazejax's `rtol`/`atol`, SciPy's `rtol`/`atol`,
heyoka's `tol`).
"""

from __future__ import annotations

import importlib.util
import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import jax.numpy as jnp  # noqa: E402
import mpmath  # noqa: E402
from bench_core import (  # noqa: E402,F401  (re-exported: one way of measuring for all scripts)
    batch_starts,
    first_minus_second,
    machine,
    stats,
    versions,
)
from peers import SYSTEMS, HeyokaImpactRunner, ImpactSystem  # noqa: E402

import grazejax as gj  # noqa: E402  (turns float64 on)
from grazejax import examples  # noqa: E402


def _installed(module: str) -> bool:
    """Whether `module` can be imported (False also where an import hook blocks it)."""
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


# The peers are optional (the `bench` extra): whatever is missing is skipped.
HAVE_HEYOKA = _installed("heyoka")
HAVE_SCIPY = _installed("scipy.integrate")
BENCH_INSTALL = 'pip install -e ".[bench]"'


def missing_peers_line() -> str | None:
    """One line naming the peers that are not installed and how to install them."""
    missing = [name for name, ok in (("heyoka", HAVE_HEYOKA), ("SciPy", HAVE_SCIPY)) if not ok]
    if not missing:
        return None
    return (f"peers not installed: {', '.join(missing)} (their rows are skipped; grazejax's "
            f"rows run). Install them with `{BENCH_INSTALL}`.")


DPS = 40  # digits of the closed-form references
SHARED_MACHINE_NOTE = (
    "timings taken on a shared 2-core CPU machine (other jobs running): read ratios "
    "within one run (from min times), not absolute numbers across runs"
)


def log(msg: str) -> None:
    print(msg, flush=True)


def measure(fn, budget_s: float, max_repeats: int, min_repeats: int = 1):
    """Time `fn` (already compiled, if it is a JAX function): about `budget_s` of calls.

    The first call returns the result and counts as a sample (nothing is compiled or
    cached by it: compilation is measured and paid separately); more calls follow while
    they fit in the budget, up to `max_repeats` calls in all and at least `min_repeats`.
    Returns (result of the first call, dict with min_s, median_s, repeats, first_s).
    """
    t = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t
    more = int(min(max_repeats, max(min_repeats, budget_s // max(first, 1e-7)))) - 1
    samples = [first]
    if more > 0:
        samples += _samples(fn, more)
    return out, {**stats(samples), "first_s": first}


def time_interleaved(fns, repeats):
    """Time several functions side by side: a first call of each (outside the timings),
    then `repeats` rounds with one call of each, so that the machine's load falls on all
    alike and their ratios are what to read.

    Returns `(timings, first_results)`: per name, `min_s`, `median_s`, `first_call_s` and
    `repeats`; and what each function's first call returned.
    """
    first, results = {}, {}
    for name, fn in fns.items():
        t = time.perf_counter()
        results[name] = fn()
        first[name] = time.perf_counter() - t
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    timings = {
        name: {"min_s": min(v), "median_s": float(np.median(v)), "first_call_s": first[name],
               "repeats": len(v)}
        for name, v in times.items()
    }
    return timings, results


def _samples(fn, repeats):
    samples = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        samples.append(time.perf_counter() - t)
    return samples


# --------------------------------------------------------------------------------------
# Accuracy
# --------------------------------------------------------------------------------------


def errors(impact_times, impact_post, x_final, truth) -> dict:
    """Max abs errors of impact times (err_t), post-impact states (err_post) and the state
    at t1 (err_final) against `truth`. A run with a different number of impacts than the
    truth gets inf errors and `impacts_found` says how many it found."""
    times = np.asarray(impact_times, float).reshape(-1)
    n = np.asarray(x_final).shape[-1]
    post = np.asarray(impact_post, float).reshape(len(times), n)
    k_true = len(truth["impact_times"])
    out = {"impacts_found": int(len(times)), "impacts_expected": int(k_true)}
    if len(times) != k_true or not np.all(np.isfinite(times)):
        return {
            **out,
            "err_t": math.inf,
            "err_post": math.inf,
            "err_final": math.inf,
            "err": math.inf,
            "ok": False,
        }
    et = float(np.max(np.abs(times - truth["impact_times"]))) if k_true else 0.0
    ep = float(np.max(np.abs(post - truth["impact_post"]))) if k_true else 0.0
    ef = float(np.max(np.abs(np.asarray(x_final, float) - truth["x_final"])))
    return {
        **out,
        "err_t": et,
        "err_post": ep,
        "err_final": ef,
        "err": max(et, ep, ef),
        "ok": bool(np.isfinite(ef)),
    }


# --------------------------------------------------------------------------------------
# Cases
# --------------------------------------------------------------------------------------


@dataclass
class Case:
    """One benchmark problem: grazejax scene + args, the peer system + params, a start, t1,
    the ground truth and how it was obtained."""

    name: str
    title: str
    scene: gj.Scene
    args: dict
    peer_system: ImpactSystem
    peer_params: dict
    x0: np.ndarray
    t1: float
    max_impacts: int  # grazejax impact-log size (static): above the expected count
    truth_method: str
    truth_fn: Callable  # truth_fn(x0, t1) -> dict(impact_times, impact_pre, impact_post, x_final)
    stiff: bool = False
    scipy_methods: tuple = ("RK45", "DOP853")
    grazejax_solvers: tuple = ("Tsit5", "Dopri5", "Dopri8")
    # solve_ivp sees sign changes only at step ends; if it misses impacts at a tolerance,
    # the suite reruns it with this max_step (and reports both).
    scipy_max_step: float | None = None
    notes: str = ""
    _truth: dict | None = field(default=None, repr=False)

    def truth(self) -> dict:
        if self._truth is None:
            t = time.perf_counter()
            self._truth = self.truth_fn(self.x0, self.t1)
            self._truth["seconds"] = time.perf_counter() - t
        return self._truth


# ---- exnonaxial: a rotation, closed form --------------------------------------------


def exnonaxial_truth(x0, t1, K=0.11, max_impacts=10**6):
    """Impacts of exnonaxial (x' = Rx, Γ: x1 + x2 = √2) from the closed form, in mpmath.

    On the circle of radius r through x, x1 + x2 = √2 r sin(t + φ + π/4); the impact
    (downward Φ = √2 − x1 − x2) is at √2 r sin θ = √2 with cos θ > 0. The jump lands on the
    diagonal at its maximum of x1 + x2, so the next impact is one turn minus a bit later.

    The constants are those every tool computes with: √2 and 1/√2 rounded to double
    (√2 − fl(√2) ≈ 1e-16 moves near-grazing impact times by ~1e-16/√depth).
    """
    with mpmath.workdps(DPS):
        x1, x2 = mpmath.mpf(float(x0[0])), mpmath.mpf(float(x0[1]))
        t, t1m, Km = mpmath.mpf(0), mpmath.mpf(float(t1)), mpmath.mpf(K)
        line, c0 = mpmath.mpf(math.sqrt(2.0)), mpmath.mpf(1 / math.sqrt(2.0))
        two_pi = 2 * mpmath.pi
        times, pre, post = [], [], []
        while len(times) < max_impacts:
            r = mpmath.sqrt(x1 * x1 + x2 * x2)
            phi = mpmath.atan2(x1, x2)
            level = line / (mpmath.sqrt(2) * r)  # sin θ at the line
            if level < 1:
                theta0 = phi + mpmath.pi / 4
                dt = mpmath.fmod(mpmath.asin(level) - theta0, two_pi)
                if dt < 0:
                    dt += two_pi
                if dt == 0:  # on the line at the start: not an impact (no re-trigger)
                    dt = two_pi
            else:
                dt = mpmath.inf
            if t + dt > t1m:
                s = t1m - t
                xf = (r * mpmath.sin(s + phi), r * mpmath.cos(s + phi))
                break
            t += dt
            a, b = r * mpmath.sin(dt + phi), r * mpmath.cos(dt + phi)
            times.append(t)
            pre.append((a, b))
            c = c0 + Km * (b - a) ** 2
            post.append((c, c))
            x1, x2 = c, c
        else:
            xf = (x1, x2)
        return _as_truth(times, pre, post, xf)


def _as_truth(times, pre, post, xf):
    n = len(xf)
    return {
        "impact_times": np.array([float(v) for v in times], float),
        "impact_pre": np.array([[float(c) for c in row] for row in pre], float).reshape(-1, n),
        "impact_post": np.array([[float(c) for c in row] for row in post], float).reshape(-1, n),
        "x_final": np.array([float(c) for c in xf], float),
    }


# ---- forced linear oscillators with a stop: matrix exponentials ----------------------


class LinearStopTruth:
    """y' = M y + e A cos(ω t), stop Φ = σ − y[0] (free side y[0] < σ), jump y[1] → −r y[1].

    Each flight is y(t) = p(t) + V e^{Λ (t − t0)} V⁻¹ (y0 − p(t0)) (eigendecomposition of M,
    40 digits), with the particular solution p(t) = Re(P e^{iωt}), P = (iω − M)⁻¹ e A. The
    impact times are the first downward zeros of Φ after each restart: bracketed on a grid
    of spacing `h` in double precision (local minima of the samples with Φ below 1e-2 are
    refined in mpmath, so that a dip shorter than the grid is not missed), then solved by
    mpmath's bracketing root finder to 40 digits.
    """

    def __init__(self, M, e, A, omega, sigma, r, h=0.01):
        self.n = len(M)
        with mpmath.workdps(DPS):
            self.M = mpmath.matrix([[mpmath.mpf(float(v)) for v in row] for row in M])
            self.e = mpmath.matrix([mpmath.mpf(float(v)) for v in e])
            self.A, self.w = mpmath.mpf(float(A)), mpmath.mpf(float(omega))
            self.sigma, self.r = mpmath.mpf(float(sigma)), mpmath.mpf(float(r))
            lam, V = mpmath.eig(self.M)
            self.lam, self.V, self.Vinv = lam, V, mpmath.inverse(V)
            iw = mpmath.mpc(0, self.w)
            self.P = mpmath.lu_solve(iw * mpmath.eye(self.n) - self.M, self.e * self.A)
        self.h = h
        self._lam_c = np.array([complex(v) for v in lam])
        self._V_c = np.array([[complex(V[i, j]) for j in range(self.n)] for i in range(self.n)])
        self._P_c = np.array([complex(self.P[i]) for i in range(self.n)])

    def _p(self, t):
        z = mpmath.expjpi(t * self.w / mpmath.pi)  # e^{iωt}
        return mpmath.matrix([mpmath.re(self.P[i] * z) for i in range(self.n)])

    def _coef(self, t0, y0):
        return self.Vinv * (y0 - self._p(t0))

    def _y(self, t, t0, c):
        ex = mpmath.matrix([c[j] * mpmath.exp(self.lam[j] * (t - t0)) for j in range(self.n)])
        hom = self.V * ex
        p = self._p(t)
        return mpmath.matrix([p[i] + mpmath.re(hom[i]) for i in range(self.n)])

    def _y_np(self, ts, t0, c):
        cc = np.array([complex(c[j]) for j in range(self.n)])
        s = ts - float(t0)
        ex = np.exp(np.outer(s, self._lam_c)) * cc  # (k, n)
        hom = (ex @ self._V_c.T).real
        part = (np.exp(1j * float(self.w) * ts)[:, None] * self._P_c).real
        return hom + part

    def _first_impact(self, t0, y0, t_end):
        """First downward zero of Φ = σ − y0(t) in (t0, t_end], or None."""
        c = self._coef(t0, y0)

        def gap(t):
            return self.sigma - self._y(t, t0, c)[0]

        def gap_dot(t):
            y = self._y(t, t0, c)
            dy = self.M * y + self.e * (self.A * mpmath.cos(self.w * t))
            return -dy[0]

        t0f, t_endf = float(t0), float(t_end)
        k = max(2, int(math.ceil((t_endf - t0f) / self.h)) + 1)
        ts = np.linspace(t0f, t_endf, k)
        g = float(self.sigma) - self._y_np(ts, t0, c)[:, 0]
        g[0] = max(g[0], 0.0)  # the start is on or off the surface, never an impact
        brackets = []
        neg = np.nonzero(g[1:] <= 0)[0]
        if neg.size:
            i = neg[0] + 1  # first sample at or below the surface
            brackets.append((ts[i - 1], ts[i]))
        # Dips between samples: interior local minima of the samples close to 0.
        mins = (
            np.nonzero((g[1:-1] <= g[:-2]) & (g[1:-1] <= g[2:]) & (g[1:-1] > 0) & (g[1:-1] < 1e-2))[
                0
            ]
            + 1
        )
        for j in mins:
            a, b = mpmath.mpf(ts[j - 1]), mpmath.mpf(ts[j + 1])
            if not (gap_dot(a) < 0 < gap_dot(b)):
                continue
            t_min = mpmath.findroot(gap_dot, (a, b), solver="anderson", verify=False)
            if gap(t_min) <= 0:
                brackets.append((ts[j - 1], t_min))
        if not brackets:
            return None
        a, b = min(brackets, key=lambda ab: float(ab[0]))
        a, b = mpmath.mpf(a), mpmath.mpf(b)
        if gap(b) == 0:
            return b
        if not gap(a) > 0 > gap(b):  # pragma: no cover - grid start exactly on a root
            raise RuntimeError(f"bracket failed at t in [{a}, {b}]")
        return mpmath.findroot(gap, (a, b), solver="anderson", verify=False)

    def run_mp(self, y0, t1, max_impacts=10**6):
        """Impacts from the mpmath state y0 (a list) at t = 0 up to t1: lists of mpmath
        numbers (times, pre, post) and the state at t1 (or after the last impact)."""
        t = mpmath.mpf(0)
        y = mpmath.matrix(list(y0))
        t1m = mpmath.mpf(t1)
        times, pre, post = [], [], []
        while len(times) < max_impacts:
            th = self._first_impact(t, y, t1m)
            if th is None:
                xf = self._y(t1m, t, self._coef(t, y))
                break
            yp = self._y(th, t, self._coef(t, y))
            yq = yp.copy()
            yq[1] = -self.r * yp[1]
            times.append(th)
            pre.append(list(yp))
            post.append(list(yq))
            t, y = th, yq
        else:
            xf = y
        return times, pre, post, list(xf)

    def __call__(self, x0, t1, max_impacts=10**6):
        with mpmath.workdps(DPS):
            y0 = [mpmath.mpf(float(v)) for v in x0]
            return _as_truth(*self.run_mp(y0, mpmath.mpf(float(t1)), max_impacts))


def _oscillator_matrix(zeta):
    return [[0.0, 1.0], [-1.0, -2.0 * zeta]]


# ---- a stiff forced oscillator with a stop -------------------------------------------


def stiff_scene() -> gj.Scene:
    """The impact oscillator with a fast first-order element z (a stiff lag):

    x' = v, v' = −x − 2ζ v − κ (x − z) + A cos(ω t), z' = −λ (z − x);
    stop at x = σ (Φ = σ − x), v → −r v (z is not changed by the impact).
    Eigenvalues ≈ −λ and a lightly damped pair near ±i: stiffness ratio ~λ.
    """

    def vector_field(t, y, a):
        x, v, z = y[0], y[1], y[2]
        return jnp.stack(
            [
                v,
                -x - 2 * a["zeta"] * v - a["kappa"] * (x - z) + a["A"] * jnp.cos(a["omega"] * t),
                -a["lam"] * (z - x),
            ]
        )

    stop = gj.Surface(
        phi=lambda t, y, a: a["sigma"] - y[0],
        jump=lambda t, y, a: y.at[1].set(-a["r"] * y[1]),
        inverse_jump=lambda t, y, a: y.at[1].set(-y[1] / a["r"]),
        name="stop",
        impenetrable=True,
    )
    return gj.Scene(vector_field, [stop])


STIFF_SYSTEM = ImpactSystem(
    name="stiff_oscillator",
    n=3,
    rhs=lambda t, x, p, lib: [
        x[1],
        -x[0] - 2.0 * p["zeta"] * x[1] - p["kappa"] * (x[0] - x[2]) + p["A"] * lib.cos(p["w"] * t),
        -p["lam"] * (x[2] - x[0]),
    ],
    phi=lambda t, x, p, lib: p["sigma"] - x[0],
    phidot=lambda t, x, p, lib: -x[1],
    where=lambda t, x, p: True,
    jump=lambda t, x, p: np.array([x[0], -p["r"] * x[1], x[2]]),
    flow_params=("zeta", "kappa", "lam", "A", "w", "sigma"),
    defaults={
        "zeta": None,
        "kappa": None,
        "lam": None,
        "A": None,
        "w": None,
        "sigma": None,
        "r": None,
    },
)


def counted_system(system: ImpactSystem, counter: list) -> ImpactSystem:
    """The same peer system with its right-hand side counting its calls in counter[0]
    (SciPy: every evaluation, including finite-difference Jacobian columns)."""
    rhs = system.rhs

    def counting_rhs(t, x, p, lib):
        counter[0] += 1
        return rhs(t, x, p, lib)

    return replace(system, rhs=counting_rhs)


# ---- ex1dof: no closed form; heyoka in long double -----------------------------------


EX1DOF_MU = 0.2
# Post-impact state of ex1dof's attracting impacting cycle at μ = 0.2 (bench_core.py finds
# it by a transient run; its precision does not matter, the reference starts there too).
EX1DOF_CYCLE_START = np.array([0.0, 0.0384224329])
EX1DOF_REF_TOL = 1e-19


EX1DOF_SCIPY_REF = {"rtol": 1e-13, "atol": 1e-15, "max_step": 0.01}


def scipy_reference(system, x0, t1, params, max_impacts=10**6):
    """The fallback reference without heyoka: SciPy DOP853 at rtol 1e-13 with max_step 0.01
    (the near-grazing dips of ex1dof need the step bound). On ex1dof it agrees with the
    long-double heyoka reference to 1.3e-13 in the impact times (measured; a test checks)."""
    from peers import ScipyImpactRunner

    runner = ScipyImpactRunner(system, "DOP853", EX1DOF_SCIPY_REF["rtol"],
                               EX1DOF_SCIPY_REF["atol"], max_step=EX1DOF_SCIPY_REF["max_step"])
    r = runner.run(np.asarray(x0, float), 0.0, float(t1), max_impacts, **params)
    return {key: r[key] for key in ("impact_times", "impact_pre", "impact_post", "x_final")}


def ex1dof_truth_source() -> tuple[Callable | None, str]:
    """ex1dof's reference (no closed form): heyoka in long double, else SciPy at rtol 1e-13,
    else none (the suite then skips ex1dof)."""
    if HAVE_HEYOKA:
        return heyoka_reference, (
            f"heyoka Taylor integrator in 80-bit long double, tol {EX1DOF_REF_TOL:g}, jumps "
            "in long double (no closed form: nonlinear flow)")
    if HAVE_SCIPY:
        ref = EX1DOF_SCIPY_REF
        return scipy_reference, (
            f"SciPy DOP853 at rtol {ref['rtol']:g}, atol {ref['atol']:g}, max_step "
            f"{ref['max_step']:g} (heyoka not installed: the long-double reference is "
            "replaced; it agrees with it to ~1e-13)")
    return None, "none: neither heyoka nor SciPy is installed"


def heyoka_reference(system, x0, t1, params, max_impacts=10**6):
    runner = HeyokaImpactRunner(system, tol=EX1DOF_REF_TOL, fp_type=np.longdouble)
    r = runner.run(np.asarray(x0, float), 0.0, float(t1), max_impacts, **params)
    return {
        "impact_times": r["impact_times"],
        "impact_pre": r["impact_pre"],
        "impact_post": r["impact_post"],
        "x_final": r["x_final"],
    }


# ---- bouncing ball: polynomial flow ---------------------------------------------------


def ball_truth(x0, t1, g=9.81, e=0.8):
    with mpmath.workdps(DPS):
        g, e = mpmath.mpf(g), mpmath.mpf(e)
        h, v, t, t1m = (
            mpmath.mpf(float(x0[0])),
            mpmath.mpf(float(x0[1])),
            mpmath.mpf(0),
            mpmath.mpf(t1),
        )
        times, pre, post = [], [], []
        while True:
            s = (v + mpmath.sqrt(v * v + 2 * g * h)) / g if h > 0 else 2 * v / g
            if t + s > t1m:
                s = t1m - t
                return _as_truth(times, pre, post, (h + v * s - g * s * s / 2, v - g * s))
            t += s
            w = v - g * s
            times.append(t)
            pre.append((mpmath.mpf(0), w))
            post.append((mpmath.mpf(0), -e * w))
            h, v = mpmath.mpf(0), -e * w


# ---- the case catalogue ----------------------------------------------------------------


OSC_PARAMS = dict(zeta=0.05, A=1.0, omega=1.5, sigma=0.2, r=0.8)
STIFF_PARAMS = dict(zeta=0.05, kappa=2.0, lam=1e3, A=1.0, omega=1.5, sigma=0.2, r=0.8)


def _jax_args(d):
    return {k: jnp.asarray(v, float) for k, v in d.items()}


def make_cases(include_ball: bool = False) -> dict[str, Case]:
    """The suite's cases. Without heyoka and SciPy, ex1dof (no closed form) is left out."""
    cases = {}
    ex1dof_fn, ex1dof_method = ex1dof_truth_source()
    cases["exnonaxial"] = Case(
        name="exnonaxial",
        title="exnonaxial (rotation, line x1 + x2 = √2; impacts approach grazing)",
        scene=examples.exnonaxial(),
        args=examples.exnonaxial_args(),
        peer_system=SYSTEMS["exnonaxial"],
        peer_params={"K": 0.11},
        x0=np.array([0.0, 1.2]),
        t1=100.0,
        max_impacts=32,
        truth_method="closed form (rotation: impacts at sin θ = 1/r), 40-digit mpmath",
        truth_fn=lambda x0, t1: exnonaxial_truth(x0, t1),
        notes="17 impacts; each jump shrinks the circle toward the grazing unit circle "
        "(r − 1 ≈ 0.62× per impact), so later impacts are near-grazing.",
    )
    osc = LinearStopTruth(
        _oscillator_matrix(OSC_PARAMS["zeta"]),
        [0.0, 1.0],
        OSC_PARAMS["A"],
        OSC_PARAMS["omega"],
        OSC_PARAMS["sigma"],
        OSC_PARAMS["r"],
    )
    cases["oscillator"] = Case(
        name="oscillator",
        title="forced impact oscillator (ζ 0.05, A 1, ω 1.5, stop σ 0.2, r 0.8)",
        scene=examples.impact_oscillator(),
        args=examples.impact_oscillator_args(**OSC_PARAMS),
        peer_system=SYSTEMS["impact_oscillator"],
        peer_params={"zeta": 0.05, "A": 1.0, "w": 1.5, "sigma": 0.2, "r": 0.8},
        x0=np.array([0.0, 0.0]),
        t1=100.0,
        max_impacts=48,
        truth_method="closed form (eigendecomposition of the linear flow + particular "
        "solution, impact times by mpmath root finding), 40 digits",
        truth_fn=lambda x0, t1: osc(x0, t1),
        notes="24 transversal impacts, settling on a period-1 impacting orbit.",
    )
    cases["ex1dof"] = Case(
        name="ex1dof",
        title=f"ex1dof (paper), μ = {EX1DOF_MU}, on the nearly grazing impacting cycle",
        scene=examples.ex1dof(),
        args=examples.ex1dof_args(mu=EX1DOF_MU),
        peer_system=SYSTEMS["ex1dof"],
        peer_params={"mu": EX1DOF_MU},
        x0=EX1DOF_CYCLE_START.copy(),
        t1=65.0,
        max_impacts=32,
        truth_method=ex1dof_method,
        truth_fn=lambda x0, t1: ex1dof_fn("ex1dof", x0, t1, {"mu": EX1DOF_MU}),
        scipy_max_step=0.05,
        notes="10 impacts at speed ≈ 0.042 (nearly grazing); after a missed crossing the "
        "flight spends only ≈ 0.08 in x1 < 0, so solve_ivp needs max_step 0.05.",
    )
    if ex1dof_fn is None:  # no reference to measure errors against
        del cases["ex1dof"]
    stiff = LinearStopTruth(
        [
            [0.0, 1.0, 0.0],
            [-1.0 - STIFF_PARAMS["kappa"], -2.0 * STIFF_PARAMS["zeta"], STIFF_PARAMS["kappa"]],
            [STIFF_PARAMS["lam"], 0.0, -STIFF_PARAMS["lam"]],
        ],
        [0.0, 1.0, 0.0],
        STIFF_PARAMS["A"],
        STIFF_PARAMS["omega"],
        STIFF_PARAMS["sigma"],
        STIFF_PARAMS["r"],
    )
    sp = dict(STIFF_PARAMS)
    sp["w"] = sp.pop("omega")
    cases["stiff"] = Case(
        name="stiff",
        title=f"stiff forced impact oscillator (fast lag λ = {STIFF_PARAMS['lam']:g})",
        scene=stiff_scene(),
        args=_jax_args(STIFF_PARAMS),
        peer_system=STIFF_SYSTEM,
        peer_params=sp,
        x0=np.array([0.0, 0.0, 0.5]),
        t1=40.0,
        max_impacts=32,
        truth_method="closed form (eigendecomposition of the 3×3 linear flow, impact times "
        "by mpmath root finding), 40 digits",
        truth_fn=lambda x0, t1: stiff(x0, t1),
        stiff=True,
        scipy_methods=("Radau", "LSODA"),
        grazejax_solvers=("Kvaerno5", "Tsit5"),
        notes="z starts off x (a fast transient), eigenvalues ≈ −λ and −0.05 ± 1.7i.",
    )
    if include_ball:
        cases["ball"] = Case(
            name="ball",
            title="bouncing ball (g 9.81, e 0.8; polynomial flow)",
            scene=examples.bouncing_ball(),
            args={"g": jnp.asarray(9.81), "e": jnp.asarray(0.8)},
            peer_system=SYSTEMS["bouncing_ball"],
            peer_params={"g": 9.81, "e": 0.8},
            x0=np.array([1.0, 0.0]),
            t1=3.0,
            max_impacts=16,
            truth_method="closed form (parabolas), 40-digit mpmath",
            truth_fn=lambda x0, t1: ball_truth(x0, t1),
            notes="every Runge-Kutta method integrates a parabola exactly: errors are event "
            "location and round-off only, whatever the tolerance.",
        )
    return cases


# ---- a parabola: the exact-flow grazing test ---------------------------------------------


def parabola_scene() -> gj.Scene:
    """x' = v, v' = a (a > 0: the floor Φ = x is approached and left again), v → −e v.
    Every Runge-Kutta method integrates it exactly (up to round-off), so the depth of an
    excursion below the floor is that of the float start: the cleanest test of grazing
    detection, free of the solver's own error."""

    def vector_field(t, x, a):
        return jnp.stack([x[1], a["a"] * jnp.ones_like(x[0])])

    floor = gj.Surface(
        phi=lambda t, x, a: x[0], jump=lambda t, x, a: x.at[1].set(-a["e"] * x[1]), name="floor"
    )
    return gj.Scene(vector_field, [floor])


PARABOLA_SYSTEM = ImpactSystem(
    name="parabola",
    n=2,
    rhs=lambda t, x, p, lib: [x[1], p["a"] + 0.0 * x[0]],
    phi=lambda t, x, p, lib: x[0],
    phidot=lambda t, x, p, lib: x[1],
    where=lambda t, x, p: True,
    jump=lambda t, x, p: np.array([x[0], -p["e"] * x[1]]),
    flow_params=("a",),
    defaults={"a": 1.0, "e": 0.8},
)


def parabola_grazing_start(depth, a=1.0, e=0.8, tau=1.0, t1=3.0):
    """Start (h, v0) of x = h + v0 t + a t²/2 with minimum −depth at t = tau.

    Returns (x0, exact depth of the float start, truth up to t1 from mpmath): one impact at
    the first root if the float start dips below 0, then the ball leaves for good."""
    v0 = -a * tau
    h = v0 * v0 / (2 * a) - depth
    x0 = np.array([h, v0])
    with mpmath.workdps(DPS):
        H, V, A, E = (mpmath.mpf(float(v)) for v in (h, v0, a, e))
        T1 = mpmath.mpf(t1)
        exact_depth = V * V / (2 * A) - H
        times, pre, post = [], [], []
        if exact_depth > 0:
            ts = (-V - mpmath.sqrt(V * V - 2 * A * H)) / A
            w = V + A * ts
            times, pre, post = [ts], [(mpmath.mpf(0), w)], [(mpmath.mpf(0), -E * w)]
            s = T1 - ts
            xf = (-E * w * s + A * s * s / 2, -E * w + A * s)
        else:
            xf = (H + V * T1 + A * T1 * T1 / 2, V + A * T1)
        return x0, float(exact_depth), _as_truth(times, pre, post, xf)


def exnonaxial_grazing_start(depth, t_graze=3.0):
    """A start on the circle of radius r = 1 + depth/√2 whose closest approach to the line
    Γ comes at t ≈ t_graze, with Φ = −depth there (a dip of depth `depth` beyond Γ if
    depth > 0, a near miss if depth < 0).

    Returns (x0, exact depth of the float x0, truth up to t1 = 2 t_graze from mpmath);
    the truth is that of the float start, which is what every tool is given.
    """
    with mpmath.workdps(DPS):
        r = 1 + mpmath.mpf(depth) / mpmath.sqrt(2)
        phi0 = mpmath.pi / 4 - t_graze
        x0 = np.array([float(r * mpmath.sin(phi0)), float(r * mpmath.cos(phi0))])
        r_float = mpmath.sqrt(mpmath.mpf(x0[0]) ** 2 + mpmath.mpf(x0[1]) ** 2)
        exact_depth = float(mpmath.sqrt(2) * r_float - mpmath.mpf(math.sqrt(2.0)))
    return x0, exact_depth, exnonaxial_truth(x0, 2 * t_graze, max_impacts=1)
