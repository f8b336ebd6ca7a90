"""Zeno accumulation, chatter, sticking and release.

By default (`zeno="stop"`) a run ends with `Status.ZENO` when impact times accumulate
(geometric tail: `zeno_time` is the extrapolated accumulation time) or when a restart is
tangential with the flow pushing into the surface (sticking): these tests check that it
ends that way, at the right time, without tunnelling. With `zeno="stick"` the state slides
on the surface under its contact force and is released when the free flow pulls away:
checked against closed forms (release times of a ball on a vibrating table, the particle
leaving a vertical loop at cos θ = (2gR − v0²)/(3gR)) and a 13-digit pendulum reference.
"""

import math

import jax
import jax.numpy as jnp
import mpmath
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import grazejax as gj
from grazejax import examples as ex

from ..helpers import central_differences
from ._common import EPS, f64, f64_args, record, runner, status

ZENO_RTOL = 1e-6  # simulate's default zeno_rtol


# ------------------------------------------------------------- bouncing ball -----------


@settings(max_examples=20, deadline=None, derandomize=True)
@given(
    h0=st.floats(1e-3, 10.0),
    v0=st.floats(-5.0, 5.0),
    log_g=st.floats(-1, 2),
    e=st.floats(0.05, 0.95),
)
def test_bouncing_ball_zeno_time_and_no_tunnelling(h0, v0, log_g, e):
    """Random drop height, throw, gravity and restitution: the run ends ZENO, every impact
    time matches t_1 + 2w Σ e^k / g, and zeno_time the closed-form accumulation time."""
    g = 10.0**log_g
    sol = runner("ball", "tight", max_impacts=1000)(f64([h0, v0]), f64(0.0), f64(1e4), f64_args(g=g, e=e))
    assert status(sol) == gj.Status.ZENO
    k = int(sol.num_impacts)
    exact, t_inf = ex.bouncing_ball_impact_times(h0, v0, g, e, k)
    w = math.sqrt(v0 * v0 + 2 * g * h0)
    # Impact times: round-off only (free fall is exact): a few ulps of t per impact.
    err_t = np.max(np.abs(np.asarray(sol.impact_times[:k]) - exact))
    assert err_t <= 1e-12 * t_inf
    # The run stops with a tail of at most zeno_rtol·t left; the estimate is exact for a
    # geometric tail up to the round-off of the last intervals.
    assert k >= 3
    err_z = abs(float(sol.zeno_time) - t_inf)
    assert err_z <= 1e-10 * t_inf
    assert float(sol.t_final) <= t_inf + 4 * EPS * t_inf
    assert t_inf - float(sol.t_final) <= ZENO_RTOL * t_inf * 1.05 + 2 * e**k * w / g
    # No tunnelling: every state the run reports is on or above the floor.
    scale = 64 * EPS * max(h0 + v0 * v0 / (2 * g), w)
    assert float(np.min(np.asarray(sol.impact_pre[:k, 0]))) >= -scale
    assert float(sol.x_final[0]) >= -scale
    record("ball Zeno: impact time error / t_inf", err_t / t_inf)
    record("ball Zeno: zeno_time error / t_inf", err_z / t_inf)


# ------------------------------------------------------------- vibrating table ---------


def table_reference(h0, g, e, A, omega, max_impacts=400):
    """An independent chatter sequence in 60-digit arithmetic.

    Below the lift-off threshold (A ω² < g) the gap between ball and table is strictly
    concave in every flight (G'' = −g + A ω² sin ωt < 0), so each flight has exactly one
    landing, bracketed in (0, 2 v_rel/(g − Aω²)]: found by a bracketed solver on G(s)/s,
    which removes the root at the take-off. Returns impact times, pre-impact velocities and
    the accumulation time (geometric extrapolation of intervals ~1e-25).
    """
    with mpmath.workdps(60):
        g, e, A, omega = (mpmath.mpf(v) for v in (g, e, A, omega))
        w = lambda t: A * mpmath.sin(omega * t)  # noqa: E731
        w_dot = lambda t: A * omega * mpmath.cos(omega * t)  # noqa: E731
        lift = g - A * omega**2
        solve = dict(solver="illinois", verify=False)
        hi = mpmath.sqrt(2 * (h0 + A) / lift) + 1
        t = mpmath.findroot(lambda t: h0 - g * t * t / 2 - w(t), (mpmath.mpf(0), hi), **solve)
        v = -g * t
        times, pres = [t], [v]
        while len(times) < max_impacts:
            vp = w_dot(t) - e * (v - w_dot(t))
            s_max = 2 * (vp - w_dot(t)) / lift
            tk, xk = t, w(t)

            def G(s, tk=tk, xk=xk, vp=vp):
                return (xk + vp * s - g * s * s / 2 - w(tk + s)) / s

            s = mpmath.findroot(G, (s_max * mpmath.mpf(10) ** -15, s_max), **solve)
            t, v = tk + s, vp - g * s
            times.append(t)
            pres.append(v)
            if s < mpmath.mpf(10) ** -25:
                break
        d1, d2 = times[-1] - times[-2], times[-2] - times[-3]
        r = d1 / d2
        t_inf = times[-1] + d1 * r / (1 - r)
        return np.array([float(x) for x in times]), np.array([float(x) for x in pres]), float(t_inf)


@settings(max_examples=10, deadline=None, derandomize=True)
@given(
    h0=st.floats(0.05, 0.5),
    e=st.floats(0.3, 0.7),
    A=st.floats(0.002, 0.05),
    omega=st.floats(5.0, 20.0),
)
def test_vibrating_table_chatter_ends_zeno_at_the_accumulation_time(h0, e, A, omega):
    """Below the lift-off threshold the ball chatters to rest on the table. grazejax ends
    the run ZENO; impact times and zeno_time match a 60-digit reference."""
    g = 9.81
    if A * omega**2 > 0.8 * g:
        A = 0.8 * g / omega**2
    sol = runner("table", "tight", max_impacts=500)(
        f64([h0, 0.0]), f64(0.0), f64(100.0), f64_args(g=g, e=e, A=A, omega=omega)
    )
    assert status(sol) == gj.Status.ZENO
    times, pres, t_inf = table_reference(h0, g, e, A, omega)
    k = int(sol.num_impacts)
    assert 3 <= k < len(times)
    err_t = np.max(np.abs(np.asarray(sol.impact_times[:k]) - times[:k]))
    err_v = np.max(np.abs(np.asarray(sol.impact_pre[:k, 1]) - pres[:k]))
    assert err_t <= 1e-10 and err_v <= 1e-9
    # zeno_time: the run stops when the tail left is below zeno_rtol·t; the geometric
    # extrapolation of that tail must be accurate to 1% of it.
    err_z = abs(float(sol.zeno_time) - t_inf)
    assert err_z <= 1e-2 * ZENO_RTOL * t_inf + 1e-10
    # No tunnelling: at every impact and at the end the ball is not below the table.
    t_log = np.asarray(sol.impact_times[:k])
    gaps = np.asarray(sol.impact_pre[:k, 0]) - A * np.sin(omega * t_log)
    end_gap = float(sol.x_final[0]) - A * math.sin(omega * float(sol.t_final))
    assert np.min(gaps) >= -1e-12 and end_gap >= -1e-12
    record("table chatter: impact time error vs 60-digit reference", err_t)
    record("table chatter: zeno_time error / tail left (zeno_rtol*t)", err_z / (ZENO_RTOL * t_inf))


def _first_table_impact(h0, g, A, omega):
    with mpmath.workdps(40):
        gap = lambda t: h0 - g * t * t / 2 - A * mpmath.sin(omega * t)  # noqa: E731
        hi = math.sqrt(2 * (h0 + A) / g) * 1.5 + 0.5
        return mpmath.findroot(gap, (mpmath.mpf(0), mpmath.mpf(hi)), solver="illinois", verify=False)


@pytest.mark.parametrize("A,omega", [(0.05, 10.0), (0.1, 12.0)], ids=["below-lift-off", "above-lift-off"])
def test_zero_restitution_on_the_table_sticks_at_the_impact(A, omega):
    """e = 0: the ball lands and moves with the table; the table's acceleration at the
    landing is below g, so it sticks at once: one impact, ZENO, zeno_time = landing time."""
    g, h0 = 9.81, 0.3
    sol = runner("table", "tight", max_impacts=500)(
        f64([h0, 0.0]), f64(0.0), f64(5.0), f64_args(g=g, e=0.0, A=A, omega=omega)
    )
    t_hit = _first_table_impact(h0, g, A, omega)
    assert float(-g + A * omega**2 * mpmath.sin(omega * t_hit)) < 0  # pushed into the table
    assert status(sol) == gj.Status.ZENO
    assert int(sol.num_impacts) == 1
    err = abs(float(sol.zeno_time) - float(t_hit))
    assert err <= 1e-11
    t = float(t_hit)
    np.testing.assert_allclose(
        sol.x_final, [A * math.sin(omega * t), A * omega * math.cos(omega * t)], atol=1e-10
    )
    record("table e=0: sticking time error", err)


def _kinds(sol):
    k = int(sol.num_impacts)
    return [gj.ImpactKind(int(v)) for v in np.asarray(sol.impact_kind[:k])]


def test_after_chatter_the_ball_rides_the_table_below_lift_off():
    """Release phase, below the lift-off threshold (Aω² < g): the chatter ends in a STICK
    at the accumulation, the ball then rides the table for good and the run reaches t1
    with x(t1) = (A sin ωt1, Aω cos ωt1)."""
    g, h0, e, A, omega, t1 = 9.81, 0.3, 0.5, 0.05, 10.0, 3.0
    sol = runner("table", "tight", max_impacts=500, zeno="stick")(
        f64([h0, 0.0]), f64(0.0), f64(t1), f64_args(g=g, e=e, A=A, omega=omega)
    )
    assert status(sol) == gj.Status.SUCCESS
    kinds = _kinds(sol)
    assert kinds[-1] == gj.ImpactKind.STICK and gj.ImpactKind.RELEASE not in kinds
    assert kinds.count(gj.ImpactKind.STICK) == 1 and len(kinds) >= 4
    # Sliding starts where the chatter accumulates (the 60-digit reference), the skipped
    # tail being at most zeno_rtol·t.
    _, _, t_inf = table_reference(h0, g, e, A, omega)
    t_stick = float(sol.impact_times[len(kinds) - 1])
    assert 0 <= t_inf - t_stick <= 1.05 * ZENO_RTOL * t_inf + 1e-12
    err = np.max(np.abs(np.asarray(sol.x_final) - [A * math.sin(omega * t1), A * omega * math.cos(omega * t1)]))
    assert err <= 1e-9
    record("table below lift-off: riding state error at t1", err)


def _release_times(A, omega, g, after, count):
    """Times where the table's acceleration −Aω² sin ωt falls through −g (sin rising)."""
    base = math.asin(g / (A * omega**2))
    m = math.ceil((omega * after - base) / (2 * math.pi))
    return [(base + 2 * math.pi * (m + j)) / omega for j in range(count)]


def test_stuck_ball_releases_when_the_table_decelerates_faster_than_g():
    """Release phase, above the threshold (A ω² > g), e = 0: the ball sticks at its landing
    t_s, rides the table, and leaves it when the table's acceleration −Aω² sin ωt falls
    below −g: at ω t_r = asin(g/(Aω²)) + 2πm, the first such time after t_s. Then it flies
    freely: x(t) = w(t_r) + w'(t_r)(t − t_r) − g (t − t_r)²/2."""
    g, h0, A, omega = 9.81, 0.3, 0.1, 12.0
    t_s = float(_first_table_impact(h0, g, A, omega))
    (t_r,) = _release_times(A, omega, g, t_s, 1)
    t1 = t_r + 0.05  # still in the air (the relative gap grows like s³ at first)
    sol = runner("table", "tight", max_impacts=500, zeno="stick")(
        f64([h0, 0.0]), f64(0.0), f64(t1), f64_args(g=g, e=0.0, A=A, omega=omega)
    )
    w, w_dot = A * math.sin(omega * t_r), A * omega * math.cos(omega * t_r)
    s = t1 - t_r
    assert w + w_dot * s - g * s * s / 2 > A * math.sin(omega * t1)  # in the air at t1
    assert status(sol) == gj.Status.SUCCESS
    assert _kinds(sol) == [gj.ImpactKind.ALPHA, gj.ImpactKind.STICK, gj.ImpactKind.RELEASE]
    times = np.asarray(sol.impact_times[:3])
    assert abs(times[0] - t_s) <= 1e-11 and times[1] == times[0]
    err_r = abs(times[2] - t_r)
    assert err_r <= 1e-10
    np.testing.assert_allclose(sol.impact_post[2], [w, w_dot], atol=1e-10)
    err_x = np.max(np.abs(np.asarray(sol.x_final) - [w + w_dot * s - g * s * s / 2, w_dot - g * s]))
    assert err_x <= 1e-9
    record("table release time error (closed form)", err_r)


@settings(max_examples=6, deadline=None, derandomize=True)
@given(
    e=st.floats(0.0, 0.4),
    lift=st.floats(1.1, 1.5),
    omega=st.floats(8.0, 16.0),
)
def test_chatter_stick_release_cycles_on_the_table(e, lift, omega):
    """Just above lift-off (Aω² = lift·g), low restitution: impacts, chatter, sticking and
    release repeat. Every RELEASE is at a closed-form release time, with the state of the
    table there; every STICK is on the table with its velocity; the ball never goes below
    the table. (Stronger forcing or livelier balls may bounce for ever without sticking.)"""
    g, h0 = 9.81, 0.3
    A = lift * g / omega**2
    sol = runner("table", "tight", max_impacts=500, zeno="stick")(
        f64([h0, 0.0]), f64(0.0), f64(4.0), f64_args(g=g, e=e, A=A, omega=omega)
    )
    assert status(sol) in (gj.Status.SUCCESS, gj.Status.MAX_IMPACTS)
    kinds = np.array([int(k) for k in _kinds(sol)])
    times = np.asarray(sol.impact_times[: len(kinds)])
    post = np.asarray(sol.impact_post[: len(kinds)])
    releases = times[kinds == gj.ImpactKind.RELEASE]
    assert len(releases) >= 1
    base = math.asin(g / (A * omega**2))
    phase = (omega * releases - base) / (2 * math.pi)
    err_r = np.max(np.abs(phase - np.round(phase))) * 2 * math.pi / omega
    assert err_r <= 1e-10
    table = np.stack([A * np.sin(omega * times), A * omega * np.cos(omega * times)], axis=1)
    on = (kinds == gj.ImpactKind.STICK) | (kinds == gj.ImpactKind.RELEASE)
    err_on = np.max(np.abs(post[on] - table[on]))
    assert err_on <= 1e-9
    gaps = np.asarray(sol.impact_pre[: len(kinds), 0]) - table[:, 0]
    assert np.min(gaps) >= -1e-12
    record("table stick/release cycles: release time error", err_r)
    record("table stick/release cycles: state on the table", err_on)


def _point_mass_in_gravity(t, x, a):
    """x = (qx, qy, vx, vy): free flight under gravity −g ŷ."""
    return jnp.stack([x[2], x[3], jnp.zeros_like(x[2]), -a["g"] * jnp.ones_like(x[3])])


def _loop_jump(t, x, a):
    q, v = x[:2], x[2:]
    n = q / jnp.linalg.norm(q)
    return jnp.concatenate([q, v - (1 + a["e"]) * jnp.dot(v, n) * n])


# A particle inside a vertical circle of radius R (gravity −g ŷ), Newton restitution e.
LOOP = gj.Scene(
    _point_mass_in_gravity,
    [gj.Surface(phi=lambda t, x, a: a["R"] ** 2 - x[0] ** 2 - x[1] ** 2, jump=_loop_jump, name="loop")],
)


def _run_loop(x0, t1, args):
    return gj.simulate(LOOP, x0, 0.0, t1, args, rtol=1e-12, atol=1e-14, max_impacts=8, zeno="stick",
                       direction=1)


_run_loop = jax.jit(_run_loop)


def _pendulum_release(g, R, v0):
    """Independent reference: the pendulum θ'' = −(g/R) sin θ until the normal force
    m(v²/R + g cos θ) vanishes, i.e. cos θ = (2gR − v0²)/(3gR) (energy conservation)."""
    from scipy.integrate import solve_ivp

    c_r = (2 * g * R - v0**2) / (3 * g * R)
    event = lambda t, y: math.cos(y[0]) - c_r  # noqa: E731
    event.terminal = True
    sol = solve_ivp(lambda t, y: [y[1], -(g / R) * math.sin(y[0])], (0, 100), [0, v0 / R],
                    events=event, rtol=1e-13, atol=1e-14, method="DOP853")
    (t_r,), ((theta, omega),) = sol.t_events[0], sol.y_events[0]
    q = R * np.array([math.sin(theta), -math.cos(theta)])
    v = R * omega * np.array([math.cos(theta), math.sin(theta)])
    return t_r, q, v


@pytest.mark.parametrize("g,R,v0sq", [(1.0, 1.0, 3.5), (9.81, 0.3, 2.7 * 9.81 * 0.3), (2.0, 5.0, 4.4 * 10.0)])
def test_particle_slides_in_a_loop_and_leaves_where_the_normal_force_vanishes(g, R, v0sq):
    """A curved surface: a particle launched along the bottom of a vertical circle slides
    (a pendulum held by the normal force) and leaves the circle above the horizontal,
    where v²/R = −g cos θ. Sliding starts at t0 (a tangential start pushed in); release
    time, state and angle are checked against the pendulum reference and the closed-form
    angle; the flight then lands where the parabola meets the circle again."""
    v0 = math.sqrt(v0sq)
    args = f64_args(g=g, R=R, e=0.5)
    sol = _run_loop(f64([0.0, -R, v0, 0.0]), 30.0 * math.sqrt(R / g), args)
    kinds = _kinds(sol)
    assert kinds[:3] == [gj.ImpactKind.STICK, gj.ImpactKind.RELEASE, gj.ImpactKind.ALPHA]
    t_r, q_r, v_r = _pendulum_release(g, R, v0)
    err_t = abs(float(sol.impact_times[1]) - t_r) / math.sqrt(R / g)
    err_x = np.max(np.abs(np.asarray(sol.impact_post[1]) - np.concatenate([q_r, v_r]))) / math.sqrt(g * R)
    cos_closed = (2 * g * R - v0sq) / (3 * g * R)
    q = np.asarray(sol.impact_post[1, :2])
    err_cos = abs(-q[1] / R - cos_closed)
    assert err_t <= 1e-10 and err_x <= 1e-10 and err_cos <= 1e-10
    # Free flight from the release: parabola meets the circle (bracketed root).
    from scipy.optimize import brentq

    def gap(s):
        p = q_r + v_r * s + np.array([0.0, -g * s * s / 2])
        return R * R - p @ p

    s_lo = 1e-3 * math.sqrt(R / g)  # past the cubic touch at the release point
    s_hi = s_lo
    while gap(s_hi) > 0:
        s_hi *= 1.5
    s_hit = brentq(gap, s_lo, s_hi, xtol=1e-15)
    err_hit = abs(float(sol.impact_times[2]) - (t_r + s_hit)) / math.sqrt(R / g)
    assert err_hit <= 1e-9
    record("loop: release time error / sqrt(R/g)", err_t)
    record("loop: release angle cos error", err_cos)
    record("loop: next impact time error / sqrt(R/g)", err_hit)


def test_ball_at_rest_on_the_floor():
    """A start at rest on the floor, pushed in by gravity: "stick" rests there until t1,
    its position exactly (each sliding step ends projected onto Φ = x = 0), its velocity to
    round-off. ("stop" keeps the paper's event semantics: Φ < 0 is not forbidden, a start
    on Γ never impacts, so the flight starts downward: tests/hard/test_grazing.py.)
    (The velocity is not asserted bit for bit: whether the sliding field's cancellation
    leaves a residual depends on XLA's fusion; with the quicker emitters the state ends at
    (0, −2.5e-32), and before sliding steps were projected onto the contact, at −8.9e-16
    in both coordinates.)"""
    args = f64_args(g=9.81, e=0.5)
    stick = runner("ball", "tight", max_impacts=5, zeno="stick")(f64([0.0, 0.0]), f64(0.0), f64(2.0), args)
    assert status(stick) == gj.Status.SUCCESS and _kinds(stick) == [gj.ImpactKind.STICK]
    assert float(stick.x_final[0]) == 0.0 and abs(float(stick.x_final[1])) <= EPS, stick.x_final
    # A bouncing ball (fixed floor) ends its Zeno sequence resting on the floor.
    bounce = runner("ball", "tight", max_impacts=500, zeno="stick")(f64([1.0, 0.0]), f64(0.0), f64(5.0), args)
    assert status(bounce) == gj.Status.SUCCESS and _kinds(bounce)[-1] == gj.ImpactKind.STICK
    _, t_inf = ex.bouncing_ball_impact_times(1.0, 0.0, 9.81, 0.5, 3)
    assert abs(float(bounce.impact_times[int(bounce.num_impacts) - 1]) - t_inf) <= 1.05 * ZENO_RTOL * t_inf
    assert np.max(np.abs(np.asarray(bounce.x_final))) <= 1e-12


def test_a_ball_at_rest_stays_on_its_floor_over_long_horizons():
    """The sliding field f + λd cancels the normal acceleration only to rounding, so an
    uncorrected sliding state drifts off the contact like t²: with `simulate` outside
    `jit` (XLA's quicker emitters round the cancellation differently from a user's `jit`)
    a ball resting on its floor sank 2.2e-8 into it by t = 1e4, and a ball that bounced
    to rest 2.2e-6 by t = 1e5, with SUCCESS. Every sliding step now ends on the contact
    manifold {Φ = 0, Φ̇ = 0} (`_loop/policies.py: hold_on_contact`)."""
    args, ball = f64_args(g=9.81, e=0.5), ex.bouncing_ball()
    for x0, t1 in (([0.0, 0.0], 1e4), ([1.0, 0.0], 1e5)):  # (one program: t1 is an input)
        sol = gj.simulate(ball, f64(x0), 0.0, t1, args, rtol=1e-10, atol=1e-10,
                          max_impacts=500, zeno="stick")
        assert status(sol) == gj.Status.SUCCESS and _kinds(sol)[-1] == gj.ImpactKind.STICK
        assert np.max(np.abs(np.asarray(sol.x_final))) <= EPS, (x0, t1, sol.x_final)


def test_release_time_and_landing_are_differentiable():
    """jacfwd through sliding and release: d(release time)/d(v0) and d(next impact time)/d(v0)
    of the loop particle against central differences of the pendulum reference (the
    release time's tangent comes from a Newton step on Φ̈, as impact times' do on Φ)."""
    g, R = 1.0, 1.0
    args = f64_args(g=g, R=R, e=0.5)

    def times(v0):
        sol = _run_loop(jnp.stack([0.0, -R, v0, 0.0]), f64(30.0), args)
        return sol.impact_times[1:3]

    v0 = math.sqrt(3.5)
    jac = np.asarray(jax.jacfwd(times)(f64(v0)))
    h = 1e-5
    ref = central_differences(lambda v: _pendulum_release(g, R, float(v))[0], v0, h)
    assert abs(jac[0] - ref) <= 1e-6 * abs(ref)
    fd = central_differences(lambda v: times(f64(v)), v0, h)
    np.testing.assert_allclose(jac, fd, rtol=1e-6)
    record("loop: d(release time)/dv0 vs reference FD (relative)", abs(jac[0] - ref) / abs(ref))


@pytest.mark.parametrize("omega,r,A,sigma", [(0.5, 0.5, 1.0, 0.2), (0.3, 0.3, 2.0, 0.5)])
def test_forced_oscillator_chatters_sticks_to_the_stop_and_releases(omega, r, A, sigma):
    """The forced impact oscillator (x'' = −2ζx' − x + A cos ωt, stop at x = σ) at low
    frequency: chatter, then the mass rests on the stop while the forcing pushes it in,
    and leaves when A cos ωt falls to σ (closed form: ω t_r = acos(σ/A) + 2πm). Every
    STICK/RELEASE state is (σ, 0)."""
    args = ex.impact_oscillator_args(zeta=0.05, A=A, omega=omega, sigma=sigma, r=r)
    sol = runner("oscillator", "tight", max_impacts=400, zeno="stick")(f64([0.0, 0.0]), f64(0.0), f64(60.0), args)
    assert status(sol) == gj.Status.SUCCESS
    kinds = np.array([int(k) for k in _kinds(sol)])
    times = np.asarray(sol.impact_times[: len(kinds)])
    releases = times[kinds == gj.ImpactKind.RELEASE]
    assert len(releases) >= 2 and np.sum(kinds == gj.ImpactKind.STICK) >= len(releases)
    phase = (omega * releases - math.acos(sigma / A)) / (2 * math.pi)
    err_r = np.max(np.abs(phase - np.round(phase))) * 2 * math.pi / omega
    assert err_r <= 1e-10
    on = (kinds == gj.ImpactKind.STICK) | (kinds == gj.ImpactKind.RELEASE)
    err_on = np.max(np.abs(np.asarray(sol.impact_post[: len(kinds)])[on] - [sigma, 0.0]))
    assert err_on <= 1e-12
    record("oscillator stick/release: release time error (closed form)", err_r)


# A point mass on a floor (y = 0) with a wall at x = L; restitution e on both.
FLOOR_AND_WALL = gj.Scene(_point_mass_in_gravity, [
    gj.Surface(phi=lambda t, x, a: x[1], jump=lambda t, x, a: x.at[3].set(-a["e"] * x[3]), name="floor"),
    gj.Surface(phi=lambda t, x, a: a["L"] - x[0], jump=lambda t, x, a: x.at[2].set(-a["e"] * x[2]), name="wall"),
])


@pytest.mark.parametrize("y0,vx", [(0.0, 1.0), (0.2, 0.3)])
def test_sliding_mass_hits_a_wall_and_keeps_sliding(y0, vx):
    """Sliding on the floor (from t0, or after a bounce-chatter sequence) into a wall: the
    wall impact is an ordinary impact, the mass keeps sliding on the floor (it used to fall
    through it: the sliding drift is above the round-off floor) and comes back at −e·vx.
    Horizontal motion is uniform: wall hit at L/vx, x(t1) = L − e·vx·(t1 − L/vx)."""
    g, e, L, t1 = 9.81, 0.5, 1.0, 1.5 / vx
    sol = gj.simulate(FLOOR_AND_WALL, [0.0, y0, vx, 0.0], 0.0, t1, {"g": g, "e": e, "L": L},
                      rtol=1e-12, atol=1e-12, max_impacts=200, zeno="stick")
    assert status(sol) == gj.Status.SUCCESS
    k = int(sol.num_impacts)
    surfaces = np.asarray(sol.impact_surface[:k])
    kinds = _kinds(sol)
    (wall,) = np.flatnonzero(surfaces == 1)
    assert kinds[wall] == gj.ImpactKind.ALPHA and kinds[wall + 1] == gj.ImpactKind.STICK
    assert kinds[-1] == gj.ImpactKind.STICK
    assert abs(float(sol.impact_times[wall]) - L / vx) <= 1e-12 * t1
    expected = [L - e * vx * (t1 - L / vx), 0.0, -e * vx, 0.0]
    np.testing.assert_allclose(sol.x_final, expected, atol=1e-10)
