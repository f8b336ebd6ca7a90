"""Piecewise-smooth scenes (`PiecewiseScene`): discrete modes, switching surfaces, Filippov
sliding, against closed forms and an independent SciPy computation.

Accuracy bounds are scaled by the solver tolerance: event times within `C · TOL · (1 + t)`.
Each distinct configuration costs one XLA compilation (tens of seconds on a shared CPU), so
the tests share scene objects, options and results: `simulate` outside `jit` compiles once
per scene object and options (t0, t1, x0, args are inputs), and the module's own `jit`s use
the quicker-compiling XLA options that `simulate` uses (`quick_jit`).
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

import grazejax as gj
from grazejax import examples as ex

from .helpers import central_differences, quick_jit

TOL = 1e-10
# Event times carry the solver's error: C · TOL · (1 + t), with C covering the growth of
# perturbations along the flow (the rocking block's saddle grows like e^{pt}).
C = 50.0


# One friction oscillator, saved at the times `check_field_continuity` samples (1001 from
# t0 to t1): its runs below and the continuity check share one compiled program.
FRICTION_TS = np.linspace(0.0, 20.0, 1001)


@functools.cache
def friction_oscillator():
    return ex.friction_oscillator()


def friction_run(y0, mu):
    return gj.simulate(friction_oscillator().scene, y0, 0.0, 20.0, {"mu": mu}, rtol=TOL,
                       atol=TOL, saveat=FRICTION_TS)


def test_friction_oscillator_turns_and_sticks_at_5pi():
    fo = friction_oscillator()
    sol = friction_run(fo.state([1.0, 0.0], "backward"), 0.1)
    assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
    events = fo.events(sol)
    times, points = ex.friction_oscillator_turns(1.0, 0.1)
    np.testing.assert_allclose(times, np.arange(1, 6) * math.pi)
    assert [e.label for e in events] == ["CROSS"] * 4 + ["SLIDE"]
    assert [e.target for e in events] == ["forward", "backward", "forward", "backward", "stick"]
    got = np.array([e.time for e in events])
    assert np.max(np.abs(got - times)) < C * TOL * (1 + times[-1])
    turned = np.array([e.x_pre[0] for e in events])
    assert np.max(np.abs(turned - points)) < C * TOL * (1 + times[-1])
    # At rest after 5π, in the stick band, for good: the Filippov field there is (0, 0).
    # (Checked at every saved time from 5π + 0.5 to 20: 190 of them.)
    after = np.asarray(sol.ts) >= 5 * math.pi + 0.5
    assert after.sum() > 150
    xs, ms = fo.split(np.asarray(sol.xs)[after])
    assert np.all(ms == fo.mode_index("stick"))
    assert np.all(np.abs(xs[:, 0]) <= 0.1)
    assert np.max(np.abs(xs[:, 0] - events[-1].x_pre[0])) < 1e-14
    assert np.max(np.abs(xs[:, 1])) < 1e-14


def test_vmap_sliding_and_free_lanes_equal_single_runs():
    fo = friction_oscillator()
    # Lane 0 sticks at 5π; lane 1 starts in the stick band and sticks at once; lanes 2, 3
    # still swing at t = 20 (they stick after ~50 and ~15 half cycles).
    starts = [1.0, 0.05, 10.0, -3.0]
    # `start` picks the mode a state on Σ moves into: lane 1 slides from t = 0.
    y0 = jnp.stack([fo.start([x, 0.0], "backward", {"mu": 0.1}) for x in starts])
    assert [fo.mode_of(y) for y in y0] == ["backward", "stick", "backward", "forward"]
    batch = quick_jit(jax.vmap(friction_run, in_axes=(0, None)))(y0, 0.1)
    final_modes = [fo.mode_of(y) for y in np.asarray(batch.x_final)]
    assert final_modes[:2] == ["stick", "stick"]
    assert final_modes[2:] != ["stick", "stick"] and "stick" not in final_modes[2:]
    assert not np.any(np.isnan(np.asarray(batch.x_final)))
    for i in range(len(starts)):
        single = friction_run(y0[i], 0.1)
        lane = jax.tree.map(lambda leaf, i=i: leaf[i], batch)
        np.testing.assert_allclose(lane.x_final, single.x_final, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(lane.impact_surface, single.impact_surface)
        assert [e.label for e in fo.events(lane)] == [e.label for e in fo.events(single)]
    lane1 = fo.events(batch, lane=1)
    assert lane1 == []  # it slides from the start, and never leaves


@pytest.mark.slow
def test_rocking_block_impact_times():
    rb = ex.rocking_block()
    args = {"p": 2.0, "alpha": 0.2, "e": 0.9}
    sol = gj.simulate(rb.scene, rb.state([0.1, 0.0], "right"), 0.0, 6.0, args, rtol=TOL,
                      atol=TOL)
    events = rb.events(sol)
    assert len(events) >= 5 and all(e.label == "TRANSITION" for e in events)
    assert [e.target for e in events[:3]] == ["left", "right", "left"]
    got = np.array([e.time for e in events])
    exact = ex.rocking_block_impact_times(0.1, 2.0, 0.2, 0.9, len(got))
    assert np.max(np.abs(got - exact)) < C * TOL * (1 + got[-1])


# One belt and one relay for the module: their runs with the same options share one
# compiled program (`simulate` compiles once per scene object and options).
@functools.cache
def belt_stick_slip():
    return ex.belt_stick_slip()


@pytest.mark.slow
def test_belt_stick_slip_times():
    bs = belt_stick_slip()
    v_b, mu_s, mu_d = 0.5, 0.3, 0.2
    x_stick, stick, slip = ex.belt_stick_slip_cycle(v_b, mu_s, mu_d)
    period = stick + slip
    t1 = 2 * period + stick + 0.5
    sol = gj.simulate(bs.scene, bs.state([x_stick, v_b], "stick"), 0.0, t1,
                      {"v_b": v_b, "mu_s": mu_s, "mu_d": mu_d}, rtol=TOL, atol=TOL)
    events = bs.events(sol)
    assert [e.target for e in events] == ["slow", "stick"] * 2 + ["slow"]
    exact = np.array([stick, period, period + stick, 2 * period, 2 * period + stick])
    got = np.array([e.time for e in events])
    assert np.max(np.abs(got - exact)) < C * TOL * (1 + t1)
    # It slips at x = μ_s and sticks again at x = 2μ_d − μ_s, at the belt's speed.
    np.testing.assert_allclose([e.x_pre[0] for e in events], [mu_s, x_stick] * 2 + [mu_s],
                               atol=C * TOL * (1 + t1))


def relay_half_period_scipy(args):
    """The symmetric orbit of `relay_feedback` by SciPy alone: x(h) = −x(0) on the section
    cᵀx = 0 under x' = Ax + b (exact flow by `scipy.linalg.expm`), solved by `fsolve`."""
    A, b = np.asarray(args["A"]), np.asarray(args["b"])
    shift = np.linalg.solve(A, b)

    def residual(z):
        x0 = np.array([z[0], 0.0])
        return scipy.linalg.expm(A * z[1]) @ (x0 + shift) - shift + x0

    z, info, ok, msg = scipy.optimize.fsolve(residual, [-2.0, 3.0], xtol=1e-14,
                                              full_output=True)
    # ("xtol too small" at a solved system is success at round-off: check the residual.)
    assert ok == 1 or np.max(np.abs(residual(z))) < 1e-13, msg
    return z[0], z[1]


@functools.cache
def relay():
    """The relay scene, its args (ζ = 0.1), SciPy's half period `(x0, h)`."""
    args = ex.relay_feedback_args(zeta=0.1, mu=1.0)
    return ex.relay_feedback(), args, *relay_half_period_scipy(args)


@functools.cache
def relay_orbit():
    """The relay's cycle found by `find_periodic_orbit` from a perturbed guess (default
    tolerances), with the exact state a quarter period in: shared by the orbit test and
    the continuation test, which starts from it."""
    rf, args, x0, h = relay()
    quarter = gj.simulate(rf.scene, rf.state([x0, 0.0], "plus"), 0.0, h / 2, args, rtol=TOL,
                          atol=TOL).x_final
    guess = quarter.at[1].multiply(1.01)  # x[0] is the section (fix=0): keep it
    orbit = gj.find_periodic_orbit(rf.scene, guess, 2 * h * 1.01, args, fix=0,
                                   start_at_impact=False, num_impacts=2)
    return quarter, orbit


@pytest.mark.slow
def test_relay_feedback_orbit_matches_scipy():
    rf, args, x0, h = relay()
    sol = gj.simulate(rf.scene, rf.state([x0, 0.0], "plus"), 0.0, 3.5 * h, args, rtol=TOL,
                      atol=TOL)
    events = rf.events(sol)
    assert [e.label for e in events] == ["CROSS"] * 3
    got = np.array([e.time for e in events])
    assert np.max(np.abs(got - h * np.arange(1, 4))) < C * TOL * (1 + got[-1]) * abs(x0)
    signs = [1, -1, 1]
    for e, s in zip(events, signs, strict=True):
        np.testing.assert_allclose(e.x_pre, [-s * x0, 0.0], atol=C * TOL * (1 + got[-1]) * abs(x0))


def filippov_belt():
    """A mass dragged by a belt with one friction level μ (Filippov: sliding = sticking)."""

    def slip(sign):
        return lambda t, x, a: jnp.stack([x[1], -x[0] + sign * a["mu"]])

    return gj.PiecewiseScene(
        [gj.Mode("slow", slip(1.0)), gj.Mode("fast", slip(-1.0))],
        switching=[gj.SwitchingSurface(lambda t, x, a: x[1] - a["v_b"], minus="slow",
                                       plus="fast", sliding="stick")],
    )


@pytest.mark.slow
def test_jacfwd_through_slide_entry_and_exit():
    belt = filippov_belt()

    def run(p):  # p = (x0, v0, v_b, mu)
        y0 = jnp.concatenate([p[:2], jnp.zeros(1)])  # mode 0 = "slow"
        return gj.simulate(belt.scene, y0, 0.0, 3.0, {"v_b": p[2], "mu": p[3]}, rtol=1e-12,
                           atol=1e-12)

    p = jnp.array([0.0, 0.0, 0.5, 0.6])
    # (The events of the run that `final` is: one program for both, where a `simulate`
    # from belt.state([0, 0], "slow") would compile another.)
    assert belt.mode_of(jnp.concatenate([p[:2], jnp.zeros(1)])) == "slow"
    sol_of = quick_jit(run)
    sol = sol_of(p)
    final = lambda p: sol_of(p).x_final[:2]  # noqa: E731
    assert [e.label for e in belt.events(sol)] == ["SLIDE", "RELEASE"]
    # Closed form: v = μ sin t reaches v_b at t_s, sticks from x_s to x = μ, then swings
    # about μ with amplitude v_b.
    t_s = math.asin(0.5 / 0.6)
    t_e = t_s + (0.6 - 0.6 * (1 - math.cos(t_s))) / 0.5
    exact = [0.6 + 0.5 * math.sin(3.0 - t_e), 0.5 * math.cos(3.0 - t_e)]
    np.testing.assert_allclose(final(p), exact, atol=1e-9)
    jac = np.asarray(quick_jit(jax.jacfwd(lambda p: run(p).x_final[:2]))(p))
    fd = central_differences(lambda q: final(jnp.asarray(q)), np.asarray(p), 1e-5)
    np.testing.assert_allclose(jac, fd, atol=1e-6)
    # Sliding forgets the start: the state leaves Σ at (μ, v_b) whatever x0 was, only
    # earlier or later. So ∂x(t1)/∂x0 = f(x(t1)) ⊗ (−∂t_exit/∂x0) has rank 1, along the
    # slip field f = (v, μ − x) at the end.
    x1, v1 = exact
    along = np.array([v1, 0.6 - x1])
    cross = along[0] * jac[1, :2] - along[1] * jac[0, :2]
    np.testing.assert_allclose(cross, 0.0, atol=1e-8)
    assert np.max(np.abs(jac[:, :2])) > 0.1


def test_sliding_on_a_curved_surface_stays_on_it():
    # f± = rotation ∓ x/2 on either side of the unit circle: from (2, 0) the radius falls
    # as 2e^{−t/2} to 1 at t = 2 ln 2, and the Filippov field on the circle (λ = 1/2) is
    # the rotation: x(t) = (cos t, sin t) for ever. Runge–Kutta steps keep a curved Σ only
    # to their error, so unprojected the radius drifted linearly (−1.8e-8 at t = 10³,
    # −1.8e-7 at 10⁴, at this tolerance); each step's end is now moved back onto Σ.
    rot = lambda x: jnp.stack([-x[1], x[0]])  # noqa: E731
    circle = gj.PiecewiseScene(
        [gj.Mode("in", lambda t, x, a: rot(x) + 0.5 * x),
         gj.Mode("out", lambda t, x, a: rot(x) - 0.5 * x)],
        switching=[gj.SwitchingSurface(lambda t, x, a: x @ x - 1.0, minus="in", plus="out",
                                       sliding="slide")],
    )

    def final(x0, t1):
        y0 = jnp.concatenate([x0, jnp.full(1, circle.mode_index("out"), x0.dtype)])
        sol = gj.simulate(circle.scene, y0, 0.0, t1, None, rtol=TOL, atol=TOL,
                          max_steps=100_000, direction=1)
        return sol.x_final[:2], (sol.status, sol.num_impacts)

    x0 = jnp.array([2.0, 0.0])
    run = quick_jit(final)
    for t1 in (10.0, 1000.0):
        x1, (status, impacts) = run(x0, t1)
        assert int(status) == gj.Status.SUCCESS and int(impacts) == 1
        assert abs(math.hypot(*np.asarray(x1)) - 1.0) <= 4 * np.finfo(float).eps
        # The phase carries each step's error: at most TOL per unit time.
        np.testing.assert_allclose(x1, [math.cos(t1), math.sin(t1)], atol=TOL * t1)
    # Through the projection: x(t1) depends on x0 only through its angle θ0
    # (∂θ0/∂x0 = (0, 1/2) at (2, 0)), so ∂x(t1)/∂x0 = (−sin t1, cos t1) ⊗ (0, 1/2).
    jac = quick_jit(jax.jacfwd(lambda x0: final(x0, 10.0)[0]))(x0)
    exact = np.outer([-math.sin(10.0), math.cos(10.0)], [0.0, 0.5])
    np.testing.assert_allclose(jac, exact, atol=C * TOL * 10.0)


def test_transition_targets_and_names_are_checked():
    f = lambda t, x, a: x  # noqa: E731
    with pytest.raises(ValueError, match="unique"):
        gj.PiecewiseScene([gj.Mode("a", f), gj.Mode("a", f)])
    with pytest.raises(ValueError, match="unknown mode"):
        gj.PiecewiseScene([gj.Mode("a", f)], [gj.Transition("a", "b", lambda t, x, a: x[0])])
    with pytest.raises(ValueError, match="default"):
        gj.PiecewiseScene([gj.Mode("a", f), gj.Mode("b", f)],
                          [gj.Transition("a", [(lambda t, x, a: True, "b")], lambda t, x, a: x[0])])
    pw = ex.belt_stick_slip()
    assert pw.mode_names == ("slow", "fast", "stick")
    y = pw.state([1.0, 2.0], "stick")
    assert pw.mode_of(y) == "stick" and y.shape == (3,)
    # The mode is a constant of the flight: its rate is 0 in every mode.
    for k in range(3):
        assert pw.scene.vector_field(0.0, y.at[2].set(k), {"v_b": 0.5, "mu_s": 0.3,
                                                           "mu_d": 0.2})[2] == 0


def test_sign_formulation_is_detected_and_mode_formulation_passes():
    args = {"mu": 0.1}
    sign_scene = gj.Scene(lambda t, x, a: jnp.stack([x[1], -x[0] - a["mu"] * jnp.sign(x[1])]))
    with pytest.raises(ValueError, match="PiecewiseScene"):
        gj.check_field_continuity(sign_scene, jnp.array([1.0, 0.0]), 0.0, 20.0, args,
                                  rtol=TOL, atol=TOL)
    fo = friction_oscillator()  # (the program of the runs above)
    report = gj.check_field_continuity(fo.scene, fo.state([1.0, 0.0], "backward"), 0.0, 20.0,
                                       args, rtol=TOL, atol=TOL)
    assert report.ok


@pytest.mark.slow
def test_relay_periodic_orbit_with_find_periodic_orbit():
    # The mode is one more coordinate to Newton: its row of the monodromy is 0. Start off Σ
    # (a start on Σ ends its period at a mode change, a different surface of the compiled
    # scene than the one it starts on: pass start_at_impact=True, num_impacts=2 then).
    rf, args, x0, h = relay()
    quarter, orbit = relay_orbit()  # (from the guess quarter·(1, 1.01), period 2h·1.01)
    assert gj.OrbitStatus(int(orbit.status)) == gj.OrbitStatus.SUCCESS, orbit.message
    assert abs(float(orbit.period) - 2 * h) < 1e3 * TOL * 2 * h
    np.testing.assert_allclose(orbit.x0, quarter, atol=1e3 * TOL * abs(x0))
    # Multipliers: 1 (the flow direction), 0 (the mode) and the determinant of the
    # monodromy in x: e^{tr(A) T} times, per crossing, the saltation determinant
    # (dΦ/dt after)/(dΦ/dt before) = (x* + μ)/(x* − μ) at the turning point x* = |x0|.
    floquet = gj.floquet_multipliers(rf.scene, orbit, args)
    mu, trace = 1.0, float(np.trace(np.asarray(args["A"])))
    third = math.exp(trace * 2 * h) * ((abs(x0) + mu) / (abs(x0) - mu)) ** 2
    got = np.sort(np.abs(np.asarray(floquet.multipliers)))
    np.testing.assert_allclose(got, np.sort([0.0, third, 1.0]), atol=1e-6)


@pytest.mark.slow
def test_relay_orbit_continues_in_damping():
    # Continuation on a mode-carrying scene: the relay cycle followed in ζ (an autonomous
    # family, period free), every point's period against SciPy's expm + fsolve orbit.
    # It starts from the orbit of the test above (found from a perturbed guess; one Newton
    # solve less to compile): `continue_orbit` re-phases it and solves it again before the
    # first step. Its atol is the default, scaled to the orbit as `find_periodic_orbit`'s
    # (1e-2·TOL·max|x|, below TOL): the same period map, whose programs (the linearisation)
    # the orbit's solve compiled.
    rf, _, _, _ = relay()
    args_of = lambda zeta: ex.relay_feedback_args(zeta=zeta, mu=1.0)  # noqa: E731
    _, orbit = relay_orbit()
    assert gj.OrbitStatus(int(orbit.status)) == gj.OrbitStatus.SUCCESS, orbit.message
    assert orbit.settings.atol <= TOL
    branch = gj.continue_orbit(rf.scene, orbit, args_of, 0.1, 0.15, progress=False, rtol=TOL)
    assert gj.ContinuationStatus(int(branch.status)) == gj.ContinuationStatus.REACHED_STOP, (
        branch.message)
    assert abs(float(branch.mu[-1]) - 0.15) < 1e-12 and len(branch) >= 3
    periods = np.array([2 * relay_half_period_scipy(args_of(float(z)))[1] for z in branch.mu])
    # (The orbit's error: the flight's, C·TOL per unit time, over one period.)
    np.testing.assert_allclose(branch.period, periods, atol=C * TOL * periods.max())
    assert set(np.asarray(branch.num_impacts).tolist()) == {2}


@pytest.mark.slow
def test_belt_stick_slip_periodic_orbit_is_superstable():
    # COCO's stickslip case: the cycle sticks once per period, and sticking forgets the
    # velocity, so the multipliers are 1 (the flow direction), 0 (sticking) and 0 (the mode).
    bs = belt_stick_slip()  # (`mid`'s run: test_belt_stick_slip_times's program)
    args = {"v_b": 0.5, "mu_s": 0.3, "mu_d": 0.2}
    x_stick, stick, slip = ex.belt_stick_slip_cycle(0.5, 0.3, 0.2)
    mid = gj.simulate(bs.scene, bs.state([0.3, 0.5], "slow"), 0.0, slip / 2, args, rtol=TOL,
                      atol=TOL).x_final
    np.testing.assert_allclose(mid[0], 0.2, atol=1e-9)  # half-way: x = μ_d
    orbit = gj.find_periodic_orbit(bs.scene, mid.at[1].multiply(1.01), (stick + slip) * 1.01,
                                   args, fix=0, start_at_impact=False, num_impacts=2)
    assert gj.OrbitStatus(int(orbit.status)) == gj.OrbitStatus.SUCCESS, orbit.message
    assert abs(float(orbit.period) - (stick + slip)) < C * TOL * (stick + slip)
    np.testing.assert_allclose(orbit.x0, mid, atol=C * TOL * (stick + slip))
    floquet = gj.floquet_multipliers(bs.scene, orbit, args)
    got = np.sort(np.abs(np.asarray(floquet.multipliers)))
    np.testing.assert_allclose(got, [0.0, 0.0, 1.0], atol=1e-8)
