"""Default-job value checks for topics whose full tests run only in the slow job.

Issue 44's audit: belt stick–slip, relay feedback, sliding Jacobians, reverse mode through
sticking and period-doubled orbits were checked against a truth only under `-m slow`.
Each test here is a small version of its slow counterpart (named in its docstring): a
short horizon, one compiled program where possible, and a value checked against an
independent truth (a closed form, or SciPy), within a bound scaled by the solver
tolerance. Each takes about 5-15 s, mostly compilation.
"""

import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg
import scipy.optimize

import grazejax as gj
from grazejax import examples as ex

from .orbits.test_continuation import _osc_08, _scipy_period_map
from .orbits.test_periodic import period_one_closed_form
from .test_piecewise import filippov_belt, relay_half_period_scipy

TOL = 1e-10
# Event times carry the solver's error, C · TOL · (1 + t) (as in test_piecewise).
C = 50.0


def test_belt_stick_slip_one_cycle():
    """Small test_piecewise::test_belt_stick_slip_times: one stick–slip cycle (not two and a
    half) against `belt_stick_slip_cycle`'s closed form: slip at x = μ_s after 2(μ_s − μ_d)/v_b
    of sticking, stick again at x = 2μ_d − μ_s after the arc π + 2 atan2(v_b, μ_s − μ_d)."""
    bs = ex.belt_stick_slip()
    v_b, mu_s, mu_d = 0.5, 0.3, 0.2
    x_stick, stick, slip = ex.belt_stick_slip_cycle(v_b, mu_s, mu_d)
    t1 = stick + slip + 0.25 * stick  # ends while sticking again
    args = {"v_b": v_b, "mu_s": mu_s, "mu_d": mu_d}
    sol = gj.simulate(
        bs.scene, bs.state([x_stick, v_b], "stick"), 0.0, t1, args, rtol=TOL, atol=TOL
    )
    assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
    events = bs.events(sol)
    assert [e.target for e in events] == ["slow", "stick"]
    bound = C * TOL * (1 + t1)
    np.testing.assert_allclose([e.time for e in events], [stick, stick + slip], rtol=0, atol=bound)
    np.testing.assert_allclose([e.x_pre[0] for e in events], [mu_s, x_stick], rtol=0, atol=bound)
    # Sticking again: riding the belt, x' = v_b, from x_stick.
    x_end, mode = bs.split(np.asarray(sol.x_final))
    assert int(mode) == bs.mode_index("stick")
    np.testing.assert_allclose(x_end, [x_stick + v_b * (t1 - stick - slip), v_b], atol=bound)


def test_relay_feedback_half_period():
    """Small test_piecewise::test_relay_feedback_orbit_matches_scipy: from the symmetric
    orbit's point on Σ (SciPy: expm + fsolve), the run crosses Σ once, at the half period h,
    at −x0 (one crossing instead of three)."""
    rf = ex.relay_feedback()
    args = ex.relay_feedback_args(zeta=0.1, mu=1.0)
    x0, h = relay_half_period_scipy(args)
    t1 = 1.5 * h
    sol = gj.simulate(rf.scene, rf.state([x0, 0.0], "plus"), 0.0, t1, args, rtol=TOL, atol=TOL)
    assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
    events = rf.events(sol)
    assert [e.label for e in events] == ["CROSS"]
    bound = C * TOL * (1 + t1) * abs(x0)
    assert abs(events[0].time - h) < bound
    np.testing.assert_allclose(events[0].x_pre, [-x0, 0.0], rtol=0, atol=bound)
    # Half a period more of "minus" mode: x(t1) by the exact flow of x' = Ax − b from −x0.
    A, b = np.asarray(args["A"]), np.asarray(args["b"])
    shift = np.linalg.solve(A, b)  # the equilibrium of x' = Ax − b
    exact = scipy.linalg.expm(A * (t1 - h)) @ (np.array([-x0, 0.0]) - shift) + shift
    x_end, mode = rf.split(np.asarray(sol.x_final))
    assert int(mode) == rf.mode_index("minus")
    np.testing.assert_allclose(x_end, exact, rtol=0, atol=bound)


def _belt_final_exact(p, T):
    """x(T) of `filippov_belt` from (x0, v0) in mode "slow", in closed form (p = x0, v0,
    v_b, μ): x − μ = A cos t + B sin t until x' = v_b at t_s (x = x_s), sliding at v_b up
    to x = μ (t_e), then the arc x = μ + v_b sin(t − t_e). Differentiable in p."""
    x0, v0, v_b, mu = p[0], p[1], p[2], p[3]
    a, b = x0 - mu, v0
    radius, phase = jnp.sqrt(a * a + b * b), jnp.arctan2(a, b)  # x' = R cos(t + phase)
    t_s = -jnp.arccos(v_b / radius) - phase  # x' rises through v_b
    t_s = jnp.where(t_s < 0, t_s + 2 * jnp.pi, t_s)
    x_s = mu + a * jnp.cos(t_s) + b * jnp.sin(t_s)
    t_e = t_s + (mu - x_s) / v_b
    return jnp.stack([mu + v_b * jnp.sin(T - t_e), v_b * jnp.cos(T - t_e)])


def test_jacfwd_through_slide_entry_and_exit_closed_form():
    """Small test_piecewise::test_jacfwd_through_slide_entry_and_exit: one compiled jacfwd
    (primal as its aux) instead of three programs, against the closed form's derivative
    (not central differences) at the slow test's point and at a moved start."""
    belt = filippov_belt()
    T, tol = 3.0, 1e-12

    def final(p):
        y0 = jnp.concatenate([p[:2], jnp.zeros(1)])  # mode 0 = "slow"
        sol = gj.simulate(belt.scene, y0, 0.0, T, {"v_b": p[2], "mu": p[3]}, rtol=tol, atol=tol)
        return sol.x_final[:2], sol

    jac_and_run = jax.jit(jax.jacfwd(final, has_aux=True))
    for p in ([0.0, 0.0, 0.5, 0.6], [0.1, -0.2, 0.5, 0.6]):
        p = jnp.asarray(p)
        jac, sol = jac_and_run(p)
        assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
        assert [e.label for e in belt.events(sol)] == ["SLIDE", "RELEASE"]
        # Values and derivatives carry the tolerance, amplified by O(1) flow constants and
        # the event-time derivatives (1/|ẍ| at the slide entry, 1/v_b at the exit).
        np.testing.assert_allclose(sol.x_final[:2], _belt_final_exact(p, T), rtol=0, atol=1e3 * tol)
        exact = jax.jacfwd(_belt_final_exact)(p, T)
        np.testing.assert_allclose(jac, exact, rtol=0, atol=1e4 * tol)
        assert np.max(np.abs(exact[:, :2])) > 0.1  # the start matters (through t_e)


def test_reverse_mode_through_sticking_closed_form():
    """Small test_reverse::test_zeno_sticking_run: one compiled jax.grad (reverse mode,
    RecursiveCheckpointAdjoint) through a ball that comes to rest (zeno="stick"), lower
    restitution and a shorter run (rest at 3·√(2/g) ≈ 1.35 with e = 1/2, not 4.06), against
    the closed-form gradient of its first five impact times (forward mode is not compiled)."""
    ball, tol = ex.bouncing_ball(), 1e-12
    T = 2.0

    def loss(p):
        sol = gj.simulate(
            ball,
            p[:2],
            0.0,
            T,
            {"g": p[2], "e": p[3]},
            zeno="stick",
            max_impacts=100,
            adjoint=diffrax.RecursiveCheckpointAdjoint(),
            rtol=tol,
            atol=tol,
        )
        return jnp.sum(sol.impact_times[:5]) + sol.x_final[0], sol

    def exact(p):
        h, v0, g, e = p[0], p[1], p[2], p[3]
        w = jnp.sqrt(v0 * v0 + 2 * g * h)
        flights = jnp.cumsum(jnp.asarray([0.0] + [2 * w * e**k / g for k in range(1, 5)]))
        return jnp.sum((v0 + w) / g + flights)

    p = jnp.array([1.0, 0.0, 9.81, 0.5])
    grad, sol = jax.jit(jax.grad(loss, has_aux=True))(p)
    kinds = np.asarray(sol.impact_kind[: int(sol.num_impacts)])
    assert int(gj.ImpactKind.STICK) in kinds, kinds
    assert abs(float(sol.x_final[0])) < 1e-15  # at rest on the floor
    # As test_reverse's EXACT: 100 · TOL relative to the largest entry.
    truth = np.asarray(jax.grad(exact)(p))
    assert np.max(np.abs(np.asarray(grad) - truth)) <= 100 * tol * np.max(np.abs(truth))


def _period_one_orbit(args, T):
    """The one-impact orbit of the forced oscillator (test_periodic's closed form), read
    half a period after its impact: (t0, x0, multipliers, eigenvectors at t0). Its impact
    phase is the root of the closed form's phase equation with an impact speed v > 0 whose
    flight stays below the stop."""
    M = np.array([[0.0, 1.0], [-1.0, -2 * float(args["zeta"])]])
    sigma, r, zeta = float(args["sigma"]), float(args["r"]), float(args["zeta"])
    E, half = scipy.linalg.expm(M * T), scipy.linalg.expm(M * T / 2)
    for guess in np.linspace(0.0, T, 24, endpoint=False):
        try:
            theta, v, _ = period_one_closed_form(args, guess)
        except ValueError:  # no sign change of the phase equation in this bracket
            continue
        if v <= 0:
            continue
        jump = np.array([sigma, -r * v]) - ex.linear_response(theta, args)

        def state(t, theta=theta, jump=jump):
            return ex.linear_response(t, args) + scipy.linalg.expm(M * (t - theta)) @ jump

        if max(state(t)[0] for t in theta + np.linspace(0.0, T, 60)[1:-1]) >= sigma:
            continue  # that "orbit" would pass through the stop
        # The monodromy after the impact, U = S E (period_one_closed_form's docstring), and
        # from t0 = θ + T/2: E_h S E_h, whose eigenvectors are E_h times those of S E.
        forcing = float(args["A"]) * math.cos(float(args["omega"]) * theta) - sigma
        a_minus, a_plus = forcing - 2 * zeta * v, forcing + 2 * zeta * r * v
        S = np.array([[-r, 0.0], [(a_plus + r * a_minus) / v, -r]])
        values, vectors = np.linalg.eig(S @ E)
        t0 = theta + T / 2
        return t0, state(t0), values, np.real(half @ vectors)
    raise AssertionError("no one-impact orbit found")


def test_period_doubled_orbit_from_a_closed_form_flip_point():
    """Small test_continuation::test_forced_oscillator_period_doubling_and_the_period_two_
    orbit: no continuation; the flip (a multiplier −1 of the one-impact orbit, σ ≈ 1.93) is
    located on the closed form, and `period_doubled_orbit` switches to the period-2 orbit
    0.005 past it, as the slow test does. SciPy's own period map (DOP853, event at the stop)
    checks the result: P(P(x0)) = x0 while P(x0) ≠ x0."""
    T = 2 * math.pi / 0.8

    def flip(sigma):
        return float(np.min(_period_one_orbit(_osc_08(sigma), T)[2].real)) + 1.0

    sigma_pd = scipy.optimize.brentq(flip, 1.85, 2.0, xtol=1e-12)
    t0, x0, rho, vectors = _period_one_orbit(_osc_08(sigma_pd), T)
    k = int(np.argmin(rho.real))
    np.testing.assert_allclose(rho[k], -1.0, atol=1e-9)
    # The one-impact orbit is a fixed point of SciPy's period map too (a check of the closed
    # form the flip point comes from).
    np.testing.assert_allclose(_scipy_period_map(sigma_pd, x0, t0, T), x0, rtol=0, atol=1e-9)
    point = gj.SpecialPoint(
        kind="period-doubling",
        mu=sigma_pd,
        x0=x0,
        t0=t0,
        period=T,
        multipliers=rho.astype(complex),
        num_impacts=1,
        eigenvector=vectors[:, k],
    )
    sigma = sigma_pd + 0.005
    two = gj.period_doubled_orbit(
        ex.impact_oscillator(), point, _osc_08(sigma), rtol=1e-12, atol=1e-13
    )
    assert gj.OrbitStatus(int(two.status)) == gj.OrbitStatus.SUCCESS, two.message
    np.testing.assert_allclose(float(two.period), 2 * T, rtol=1e-14)
    assert int(two.num_impacts) == 2 and bool(two.stable)
    start, x_two = float(two.t0), np.asarray(two.x0)
    half = _scipy_period_map(sigma, x_two, start, T)
    back = _scipy_period_map(sigma, half, start + T, T)
    assert np.max(np.abs(half - x_two)) > 1e-3  # period 2, not the period-1 orbit
    # The orbit's error (Newton to 1e-12 relative, one period's integration error, amplified
    # by 1/|1 − ρ| with ρ near 1 this close to the flip) and SciPy's own: within 1e-7.
    np.testing.assert_allclose(back, x_two, rtol=0, atol=1e-7)


def test_period_doubled_orbit_on_the_wrong_side_says_so():
    """From a point that is not a flip point (the one-impact orbit at σ = 2.0, labelled as
    one: 0.07 past the flip, where its starts converge back to the period-1 orbit), every
    start finds the period-1 orbit run twice: that is reported as NOT_DOUBLED, never as
    SUCCESS (it was SUCCESS with the period-1 orbit's x0 and multipliers ρ²)."""
    T = 2 * math.pi / 0.8
    t0, x0, rho, vectors = _period_one_orbit(_osc_08(2.0), T)
    k = int(np.argmin(rho.real))
    point = gj.SpecialPoint(
        kind="period-doubling", mu=2.0, x0=x0, t0=t0, period=T,
        multipliers=rho.astype(complex), num_impacts=1, eigenvector=vectors[:, k],
    )
    two = gj.period_doubled_orbit(ex.impact_oscillator(), point, _osc_08(2.0),
                                  rtol=1e-12, atol=1e-13)
    assert gj.OrbitStatus(int(two.status)) == gj.OrbitStatus.NOT_DOUBLED
    assert "period-1 orbit run twice" in two.message
