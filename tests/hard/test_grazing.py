"""Near-grazing, exact grazing, restarts on the surface, and ex1dof's jump Γ → Γ.

Ground truth is the depth of the *computed* trajectory. For free fall (x'' = a) every
Runge-Kutta method is exact up to round-off, so the depth of the float start state (exact
rational arithmetic) is the depth the solver sees, to ~15 ulps (the Tsit5 tableau's
round-off). For a rotation the solver's own error, ~ the tolerance, adds to the depth:
there we only use depths far above the tolerance (20x the measured radius error), and say so.
"""

import math
from fractions import Fraction

import mpmath
import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

import grazejax as gj

from ..helpers import scipy_field
from ._common import EPS, EX1DOF, FLOOR_ULPS, f64, f64_args, record, runner, status

SWEEP = settings(max_examples=25, deadline=None, derandomize=True)


def _log_between(u, lo, hi):
    return 10 ** (math.log10(lo) + u * (math.log10(hi) - math.log10(lo)))


# ------------------------------------------------------------- free fall sweep ---------


@pytest.mark.parametrize("tol", ["default", "loose"])
@SWEEP
@given(
    log_a=st.floats(-2, 2),
    log_tau=st.floats(-3, 1),
    t0=st.one_of(st.just(0.0), st.floats(0, 100)),
    depth_u=st.floats(0, 1),
    hit=st.booleans(),
)
def test_free_fall_near_grazing_sweep(tol, log_a, log_tau, t0, depth_u, hit):
    """A parabola x(s) = h + v0 s + a s²/2 reaching its minimum −δ at s = τ (random scale a,
    phase τ, start time t0), δ log-uniform from 1e-2 down to 2x the run's contact floor:
    every dip below the floor is one impact at the exact time, every miss is no impact.

    "Floor" here is the largest floor of the run (64 ulps of its largest state); depths
    start at 4 floors because Tsit5's own round-off on a long step of a parabola reaches
    ~150-200 ulps of the state (its tableau is not exact in binary)."""
    a, tau = 10.0**log_a, 10.0**log_tau
    v0 = -a * tau
    # The largest state of the run is at t1 = t0 + 3τ: (2aτ², 2aτ). Its floor bounds the
    # floor of every step (64 ulps of Σ|∂Φ/∂x|·‖x‖∞).
    floor = FLOOR_ULPS * EPS * max(2 * a * tau * tau, 2 * a * tau)
    top = min(1e-2, a * tau * tau / 4)
    assume(top > 8 * floor)
    delta = _log_between(depth_u, 4 * floor, top) * (1 if hit else -1)
    h = v0 * v0 / (2 * a) - delta
    # The exact depth of the float start (what the computed parabola really does).
    true_depth = float(Fraction(v0) ** 2 / (2 * Fraction(a)) - Fraction(h))
    assert abs(true_depth) > 3 * floor
    sol = runner("free_fall", tol)(f64([h, v0]), f64(t0), f64(t0 + 3 * tau), f64_args(a=a))
    assert status(sol) in (gj.Status.SUCCESS, gj.Status.MAX_IMPACTS)
    k = int(sol.num_impacts)
    if not hit:
        assert k == 0, f"false impact on a miss by {-true_depth:.3e} (floor {floor:.3e})"
        record(f"free fall {tol}: smallest miss without a false impact, in floors", -true_depth / floor, "min")
        return
    assert k == 1, f"missed a dip of depth {true_depth:.3e} (floor {floor:.3e})"
    # Exact impact time and speed, in high precision from the float start.
    with mpmath.workdps(50):
        ma, mh, mv = mpmath.mpf(a), mpmath.mpf(h), mpmath.mpf(v0)
        disc = mpmath.sqrt(mv * mv - 2 * ma * mh)
        t_hit = mpmath.mpf(t0) + 2 * mh / (-mv + disc)
        v_hit = float(-disc)
    dt = abs(float(mpmath.mpf(float(sol.impact_times[0])) - t_hit))
    dv = abs(float(sol.impact_pre[0, 1]) - v_hit)
    # Conditioning: a position error of ε moves the root by ε/|v_hit|; ε is within the floor.
    bound_t = floor / abs(v_hit) + 4 * EPS * (t0 + 3 * tau)
    assert dt <= bound_t
    assert dv <= a * bound_t + 4 * EPS * abs(v0)
    kind = gj.ImpactKind(int(sol.impact_kind[0]))
    assert kind == gj.ImpactKind.ALPHA or (kind == gj.ImpactKind.GAMMA and true_depth < 4 * floor)
    record(f"free fall {tol}: shallowest dip found, in floors", true_depth / floor, "min")
    record(f"free fall {tol}: impact time error / (floor/|v|)", dt / bound_t)


@SWEEP
@given(log_a=st.floats(-2, 2), log_tau=st.floats(-3, 1), ratio=st.floats(-2.5, 2.5))
def test_free_fall_within_the_floor_is_reported_consistently(log_a, log_tau, ratio):
    """Inside the floor band (|δ| <= 2.5 floors) touch vs miss is round-off: at most one
    contact; a transversal (α) one only on a true dip; a γ one only within the floor."""
    a, tau = 10.0**log_a, 10.0**log_tau
    v0 = -a * tau
    floor = FLOOR_ULPS * EPS * max(2 * a * tau * tau, 2 * a * tau)
    h = v0 * v0 / (2 * a) - ratio * floor
    true_depth = float(Fraction(v0) ** 2 / (2 * Fraction(a)) - Fraction(h))
    sol = runner("free_fall", "default")(f64([h, v0]), f64(0.0), f64(3 * tau), f64_args(a=a))
    k = int(sol.num_impacts)
    assert k <= 1
    if k == 1:
        kind = gj.ImpactKind(int(sol.impact_kind[0]))
        assert kind in (gj.ImpactKind.ALPHA, gj.ImpactKind.GAMMA)
        if kind == gj.ImpactKind.ALPHA:
            assert true_depth > 0
        else:
            # The simulator's floor also has the step-length term 64 ulps of h·max|ġ|
            # (h at most the run, 3τ; |ġ| = |v| at most 2aτ): γ within that.
            step_term = FLOOR_ULPS * EPS * (3 * tau) * (2 * a * tau)
            assert abs(true_depth) <= floor + step_term
        assert abs(float(sol.impact_times[0]) - tau) <= math.sqrt(8 * floor / a) + 8 * EPS * tau


def _tangency_grid():
    """Exact tangencies: powers of two make h = c + v0²/(2a) exact, so the parabola from
    (h, v0) touches the wall x = c exactly, at s = τ = −v0/a, with v = 0 there."""
    for c in (0.0, 0.5, 1.0):
        for k_a in range(-6, 7):
            for k_v in range(-6, 5):
                a, v0 = 2.0**k_a, -(2.0**k_v)
                h = c + v0 * v0 / (2 * a)
                assert Fraction(h) == Fraction(c) + Fraction(v0) ** 2 / (2 * Fraction(a))
                yield c, a, v0, h, -v0 / a


def _run_tangency(c, a, v0, h, tau):
    return runner("wall_free_fall", "default", max_impacts=2)(
        f64([h, v0]), f64(0.0), f64(3 * tau), f64_args(a=a, c=c)
    )


def test_exact_tangency_contacts_are_grazing_and_on_time():
    """Over 429 exact tangencies (scales a, v0 from 2^-6 to 2^6, three wall heights): every
    contact reported is γ, at the tangency time to within the conditioning √(floor/a) of a
    double root, and all contacts of a run happen at that one instant."""
    counts = {0: 0, 1: 0, 2: 0}
    worst = 0.0
    for c, a, v0, h, tau in _tangency_grid():
        sol = _run_tangency(c, a, v0, h, tau)
        k = int(sol.num_impacts)
        counts[k] += 1
        floor = FLOOR_ULPS * EPS * max(2 * a * tau * tau + abs(c), 2 * a * tau)
        for i in range(k):
            assert gj.ImpactKind(int(sol.impact_kind[i])) == gj.ImpactKind.GAMMA
            dt = abs(float(sol.impact_times[i]) - tau)
            assert dt <= math.sqrt(8 * floor / a) + 8 * EPS * tau
            worst = max(worst, dt / math.sqrt(floor / a))
    record("exact tangency: contact time error / sqrt(floor/a)", worst)
    print(f"exact tangencies: number of contacts -> runs: {counts}")
    assert counts[1] >= 0.9 * sum(counts.values())


def test_exact_tangency_is_one_contact_and_the_run_goes_on():
    bad = []
    for c, a, v0, h, tau in _tangency_grid():
        sol = _run_tangency(c, a, v0, h, tau)
        # With J = id at v = 0 the flight continues on the same parabola to t1 = 3τ.
        exact_final = np.array([c + 2 * a * tau * tau, 2 * a * tau])
        ok = (
            int(sol.num_impacts) == 1
            and status(sol) == gj.Status.SUCCESS
            and np.allclose(sol.x_final, exact_final, rtol=1e-6)
        )
        if not ok:
            bad.append((c, a, v0, int(sol.num_impacts), status(sol).name))
    assert not bad, f"{len(bad)} of 429 exact tangencies: {bad}"


# ------------------------------------------------------------- rotation sweep ----------

# The rotation's computed radius drifts by ~ the tolerance (measured: 4e-9 relative over a
# half turn at rtol 1e-8, 2e-3 over a turn at rtol 1e-3). Depths start 20x above that.
ROTATION_MIN_DEPTH = {"default": 1e-6, "loose": 4e-2}
ROTATION_TIME_SCALE = {"default": 1e-8, "loose": 1e-3}


@pytest.mark.parametrize("tol", ["default", "loose"])
@SWEEP
@given(
    r=st.floats(0.5, 2.0),
    t_min=st.floats(0.5, math.pi),
    depth_u=st.floats(0, 1),
    hit=st.booleans(),
)
def test_rotation_near_grazing_sweep(tol, r, t_min, depth_u, hit):
    """x = r (sin(t+φ), cos(t+φ)) dips δ past the wall x1 = −c (random radius and phase);
    depths from 1e-2 (1e-1 loose) down to 20x the solver's radius error."""
    top = 1e-2 if tol == "default" else 1e-1
    delta = _log_between(depth_u, ROTATION_MIN_DEPTH[tol], top) * r
    c = r - delta if hit else r + delta
    phi = 1.5 * math.pi - t_min  # the minimum of x1 (= −r) is at t = t_min
    x0 = [r * math.sin(phi), r * math.cos(phi)]
    sol = runner("rotation_wall", tol)(f64(x0), f64(0.0), f64(t_min + 0.5), f64_args(c=c))
    k = int(sol.num_impacts)
    with mpmath.workdps(40):
        mx = [mpmath.mpf(v) for v in x0]
        mr = mpmath.sqrt(mx[0] ** 2 + mx[1] ** 2)
        depth = float(mr - c)
        t_bottom = mpmath.fmod(mpmath.mpf(1.5) * mpmath.pi - mpmath.atan2(mx[0], mx[1]), 2 * mpmath.pi)
        t_hit = float(t_bottom - mpmath.acos(c / mr)) if depth > 0 else math.inf
        v_hit = float(mr * mpmath.sin(mpmath.acos(c / mr))) if depth > 0 else 0.0
    if not hit:
        assert k == 0, f"false impact on a miss by {-depth:.3e}"
        return
    assert k == 1, f"missed a dip of depth {depth:.3e}"
    dt = abs(float(sol.impact_times[0]) - t_hit)
    # A radius error ε moves the crossing by ~ε/|v_hit|.
    scale = ROTATION_TIME_SCALE[tol] / v_hit
    assert dt <= 10 * scale
    record(f"rotation {tol}: impact time error / (tol/|v_hit|)", dt / scale)


# ------------------------------------------------------------- restarts ----------------


@settings(max_examples=20, deadline=None, derandomize=True)
@given(log_v=st.floats(-9, 2), g=st.floats(0.1, 100.0), t0=st.floats(0, 100), e=st.floats(0.1, 0.9))
def test_restart_on_the_floor_never_retriggers(log_v, g, t0, e):
    """From the floor moving up at v (1e-9 .. 1e2): no impact at t0; the next at t0 + 2v/g,
    even when that hop is far shorter than a solver step."""
    v = 10.0**log_v
    sol = runner("ball", "default", max_impacts=2)(f64([0.0, v]), f64(t0), f64(t0 + 1e3), f64_args(g=g, e=e))
    assert int(sol.num_impacts) == 2
    times = np.asarray(sol.impact_times[:2]) - t0
    exact = np.array([2 * v / g, 2 * v / g * (1 + e)])
    err = np.max(np.abs(times - exact))
    assert err <= 1e-12 * exact[1] + 64 * EPS * (t0 + 1)
    np.testing.assert_allclose(-np.asarray(sol.impact_pre[:2, 1]), [v, e * v], rtol=1e-11)
    record("restart: hop time error (absolute, t0 <= 100)", err)


@pytest.mark.parametrize("a", [2.0, -2.0])
@pytest.mark.parametrize("v", [-1.0, -1e-7, 0.0])
def test_start_on_the_surface_moving_in_or_tangential_is_no_impact(a, v):
    """x0 on Φ = 0 moving inward (or at rest): no impact at t0. With a > 0 the flight comes
    back up through Φ = 0 (an upward crossing: no impact); with a < 0 it stays below."""
    t1 = 4 * abs(v) / abs(a) + 1.0
    sol = runner("free_fall", "default")(f64([0.0, v]), f64(0.0), f64(t1), f64_args(a=a))
    assert int(sol.num_impacts) == 0
    assert status(sol) == gj.Status.SUCCESS
    np.testing.assert_allclose(sol.x_final, [v * t1 + a * t1 * t1 / 2, v + a * t1], rtol=1e-12)


# ------------------------------------------------------------- ex1dof Γ → Γ ------------


@settings(max_examples=10, deadline=None, derandomize=True)
@given(mu=st.floats(0.02, 0.25), rho=st.floats(1.3, 1.8), theta=st.floats(-0.5, 1.2))
def test_ex1dof_jump_into_gamma_flight_by_flight(mu, rho, theta):
    """ex1dof's jump leaves x2 < 0 on Γ: the flight starts into the wall, must not re-fire,
    passes back up through x1 = 0 and impacts once per turn. Every flight of the log is
    checked against a DOP853 flight at 1e-13 from the logged post-impact state."""
    args = {"mu": mu, "eps": 1e-4, "R": 0.9}
    x0 = [1 + rho * math.sin(theta), rho * math.cos(theta)]  # radius rho about (1, 0)
    sol = runner("ex1dof", "tight", max_impacts=3)(f64(x0), f64(0.0), f64(25.0), f64_args(**args))
    k = int(sol.num_impacts)
    assert k == 3
    post = np.asarray(sol.impact_post[:k])
    times = np.asarray(sol.impact_times[:k])
    assert post[0, 1] < -0.1  # J maps Γ into Γ: the next flight starts into the wall
    assert np.all(np.diff(times) > 5.0)  # one impact per turn (~2π): no re-trigger
    f = scipy_field(EX1DOF, args)
    cross = lambda t, x: x[0]  # noqa: E731
    cross.direction = -1
    worst = 0.0
    for i in range(k - 1):
        out = solve_ivp(f, (times[i], times[i] + 12.0), post[i], method="DOP853", rtol=1e-13,
                        atol=1e-14, events=[cross])
        # Skip the restart root at the start and require x2 <= 0 (the piece).
        hits = [(t, y) for t, y in zip(out.t_events[0], out.y_events[0], strict=True)
                if t > times[i] + 1e-3 and y[1] <= 0]
        t_next, y_next = hits[0]
        err = max(abs(times[i + 1] - t_next), np.max(np.abs(sol.impact_pre[i + 1] - y_next)))
        worst = max(worst, err)
    assert worst < 100 * 1e-12  # 100x the tolerance (rtol = atol = 1e-12)
    record("ex1dof Γ→Γ: per-flight error vs DOP853 (tight)", worst)
