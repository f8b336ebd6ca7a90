"""Contacts inside one long step whose end slopes do not bracket a minimum (closed forms)."""

import math

import diffrax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj

SOLVERS = {"Tsit5": None, "Dopri5": diffrax.Dopri5(), "Dopri8": diffrax.Dopri8(), "Vern9": gj.Vern9()}
T_HIT = math.acos(-0.99)  # 0.99 + cos(u) reaches 0 decreasing at u = arccos(−0.99)


@pytest.mark.parametrize("tol", [1e-10, 1e-13])
@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_a_curved_surface_crossed_by_long_exact_steps(name, tol):
    """x' = 1 is exact for every step length, so the steps grow to several units and hold
    several minima of Φ = 0.99 + cos x; the jump x → x − 1 brings each impact back. Exact:
    impacts at arccos(−0.99) + k, six in [0, 9]."""
    wall = gj.Surface(phi=lambda t, x, a: 0.99 + jnp.cos(x[0]), jump=lambda t, x, a: x - 1.0)
    scene = gj.Scene(lambda t, x, a: jnp.ones_like(x), [wall])
    sol = gj.simulate(scene, jnp.array([0.0]), 0.0, 9.0, None, solver=SOLVERS[name],
                      rtol=tol, atol=tol)
    assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
    assert int(sol.num_impacts) == 6
    want = T_HIT + np.arange(6)
    np.testing.assert_allclose(sol.impact_times[:6], want, rtol=0, atol=1e3 * tol * 9)


@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_a_moving_wall_reaches_a_body_at_rest_inside_one_step(name):
    """A body at rest (x' = 0, exact: the steps grow tenfold per step) and a wall
    Φ = x + 0.99 + cos t that reaches it at t = arccos(−0.99), with end slopes of the long
    step around it not (−, +). The jump x → x + 1 leaves Φ > 0 for ever: one impact."""
    wall = gj.Surface(phi=lambda t, x, a: x[0] + 0.99 + jnp.cos(t),
                      jump=lambda t, x, a: x + 1.0)
    scene = gj.Scene(lambda t, x, a: jnp.zeros_like(x), [wall])
    sol = gj.simulate(scene, jnp.array([0.0]), 0.0, 20.0, None, solver=SOLVERS[name],
                      rtol=1e-10, atol=1e-10)
    assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
    assert int(sol.num_impacts) == 1
    assert abs(float(sol.impact_times[0]) - T_HIT) < 1e-8
    np.testing.assert_allclose(sol.x_final, [1.0], rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", sorted(SOLVERS))
def test_a_hump_out_of_the_surface_and_back_inside_one_step(name):
    """The mirror of a dip: from Φ = cos x − 0.99 < 0 (x0 = π) under the exact x' = 1, the
    gap rises above 0 only for x ∈ 2π ∓ arccos(0.99) and comes back down through Φ = 0:
    an impact at t = π + arccos(0.99), inside one long step whose ends are both in Φ < 0
    with end slopes (+, −)."""
    wall = gj.Surface(phi=lambda t, x, a: jnp.cos(x[0]) - 0.99, jump=lambda t, x, a: x + 2.0)
    scene = gj.Scene(lambda t, x, a: jnp.ones_like(x), [wall])
    sol = gj.simulate(scene, jnp.array([math.pi]), 0.0, 9.0, None, solver=SOLVERS[name],
                      rtol=1e-10, atol=1e-10, max_impacts=1)
    assert gj.Status(int(sol.status)) == gj.Status.MAX_IMPACTS
    assert abs(float(sol.impact_times[0]) - (math.pi + math.acos(0.99))) < 1e-8


def test_a_fast_wall_beside_a_slow_body_every_impact():
    """A wall oscillating much faster than the body's flow (Φ = x − 0.3 sin(40 t), the
    body x' = −0.05 drifting towards it from x = 0.5): the first contact is where
    0.5 − 0.05 t = 0.3 sin(40 t) first holds, found on a fine grid and refined."""
    wall = gj.Surface(phi=lambda t, x, a: x[0] - 0.3 * jnp.sin(40.0 * t),
                      jump=lambda t, x, a: x + 1.0)
    scene = gj.Scene(lambda t, x, a: jnp.full_like(x, -0.05), [wall])
    sol = gj.simulate(scene, jnp.array([0.5]), 0.0, 10.0, None, solver=diffrax.Dopri8(),
                      rtol=1e-10, atol=1e-10, max_impacts=1)
    gap = lambda t: 0.5 - 0.05 * t - 0.3 * np.sin(40.0 * t)  # noqa: E731
    grid = np.linspace(0.0, 10.0, 2_000_001)
    first = np.argmax(gap(grid) <= 0)
    from scipy.optimize import brentq

    t_star = brentq(gap, grid[first - 1], grid[first], xtol=1e-15)
    assert int(sol.num_impacts) == 1
    assert abs(float(sol.impact_times[0]) - t_star) < 1e-8


def test_a_field_nan_at_x0_is_nonfinite():
    """Every step from x0 is NaN (the controller's first step too): NONFINITE at t0, not
    MAX_STEPS after rejecting every step."""
    floor = gj.Surface(phi=lambda t, x, a: x[0], jump=lambda t, x, a: x.at[1].set(-0.8 * x[1]))
    scene = gj.Scene(lambda t, x, a: jnp.array([x[1], jnp.sqrt(x[0] - 1.0)]), [floor])
    sol = gj.simulate(scene, jnp.array([0.5, 0.0]), 0.0, 1.0, None, max_steps=1000)
    assert gj.Status(int(sol.status)) == gj.Status.NONFINITE
    assert int(sol.num_steps) < 10 and float(sol.t_final) == 0.0


def test_the_far_screen_is_stricter_than_the_clearance_rule():
    """`is_far` skips the resolution verdict on a step: it must accept only gaps that
    every sample and slope say cannot reach Φ = 0 (a dip between samples needs a slope
    FAR times larger than any seen), and refuse the shapes of the missed cases."""
    from grazejax._loop.events import FAR, is_far

    # A straight approach from 1 to 0.9 with step·slope 0.1: far (1 > 8·0.2 is false).
    assert not bool(is_far((1.0, 0.95, 0.9), (-0.1, -0.1, -0.1)))
    assert bool(is_far((10.0, 9.95, 9.9), (-0.1, -0.1, -0.1)))
    # At the boundary: lowest = FAR·(spread + steepest) is not far.
    assert not bool(is_far((FAR * 0.2, FAR * 0.2 + 0.1), (0.1, 0.1)))
    # The missed impact of x = t, Φ = 0.99 + cos x on a long exact step: values and slopes of
    # order 1 beside a minimum of 0.99: never far.
    t = np.array([0.0, 0.2071, 0.5, 0.809, 1.0]) * 6.0
    assert not bool(is_far(tuple(0.99 + np.cos(t)), tuple(-6.0 * np.sin(t))))
    # Non-finite samples are not far.
    assert not bool(is_far((jnp.nan, 5.0, 5.0), (0.0, 0.0, 0.0)))


def _samples(gap, slope):
    """A gap's samples as `is_clear` reads them on [0, 1]: values and slopes in θ."""
    from grazejax._loop.events import CHECK_FRACTIONS

    g = tuple(float(gap(u)) for u in (0.0, 0.5, 1.0))
    d = tuple(float(slope(u)) for u in (0.0, 0.5, 1.0))
    checks = tuple((float(gap(u)), float(slope(u))) for u in CHECK_FRACTIONS)
    return g, d, checks


def test_the_model_screen_bounds_the_cubic_between_its_ends():
    """`is_clear` skips the verdict where the step's cubic model, with its error read at
    the midpoint and the check points, stays clear of Φ = 0. A quadratic is its own
    model: clear where its minimum is positive, whatever its ends say."""
    from grazejax._loop.events import is_clear

    def quadratic(depth):
        return _samples(lambda u: (u - 0.5) ** 2 + depth, lambda u: 2 * (u - 0.5))

    assert bool(is_clear(*quadratic(0.01)))
    # Ends at 0.24 above a minimum of −0.01: the chord bound sees the dip.
    assert not bool(is_clear(*quadratic(-0.01)))
    # The missed impact of x = t, Φ = 0.99 + cos x on a step of length 6.
    assert not bool(is_clear(*_samples(lambda u: 0.99 + np.cos(6 * u),
                                       lambda u: -6 * np.sin(6 * u))))
    # An oscillation with a node at every sample of the ends and the midpoint, values and
    # slopes: only the check points see it.
    assert not bool(is_clear(*_samples(lambda u: 1.0 + 2.0 * np.cos(4 * np.pi * u),
                                       lambda u: -8.0 * np.pi * np.sin(4 * np.pi * u))))
    g, d, checks = quadratic(0.01)
    assert not bool(is_clear((jnp.nan, *g[1:]), d, checks))


def test_the_model_screen_never_clears_a_gap_that_reaches_the_surface():
    """Random smooth gaps on a step, a cubic plus an oscillation of random frequency:
    wherever `is_clear` skips the verdict, the gap's minimum on a fine grid is positive."""
    from grazejax._loop.events import is_clear

    rng = np.random.default_rng(20261129)
    grid = np.linspace(0.0, 1.0, 4001)
    cleared = 0
    for _ in range(3000):
        c = rng.normal(size=4) * rng.choice([0.01, 0.1, 1.0], size=4)
        amp, freq, phase = rng.choice([0.0, 1e-3, 1e-2, 0.1]), rng.uniform(0, 40), rng.uniform(0, 7)
        c[0] = rng.uniform(-0.2, 1.0)

        def gap(u, c=c, amp=amp, freq=freq, phase=phase):
            return np.polyval(c[::-1], u) + amp * np.sin(freq * u + phase)

        def slope(u, c=c, amp=amp, freq=freq, phase=phase):
            return np.polyval(np.polyder(c[::-1]), u) + amp * freq * np.cos(freq * u + phase)

        if bool(is_clear(*_samples(gap, slope))):
            cleared += 1
            assert gap(grid).min() > 0
    assert cleared > 300  # the screen does clear most gaps that are far


def test_a_hop_off_a_moving_wall_that_returns_inside_half_a_step():
    """The samples of a step found by the fuzz campaign (mech2, Vern9): a body leaves a fast
    moving wall (restart, ġ > 0), the wall catches it 0.019 later and it is inside the
    wall at the first half's check point (g = −5.4e-3), back out at the midpoint. The cubic
    through the half's ends fits that check point within `SHAPE` of its spread, and both
    ends and the slopes there are positive, so no end test flags the half: only the order
    of the samples' signs (+, −, +) shows the contact. Values are the gap and h·ġ at
    θ = 0, ½, 1 and the check points, from an rtol 1e-13 DOP853 solution."""
    from grazejax._loop.events import gap_resolution

    f = lambda *v: tuple(jnp.asarray(x, jnp.float64) for x in v)  # noqa: E731
    g = f(4.163336e-16, 7.246791e-02, 2.633892e-01)
    d = f(6.794866e-02, 5.592070e-01, -2.598236e-02)
    checks = (f(-5.428675e-03, -1.501351e-02), f(2.399973e-01, 3.200496e-01))
    no = jnp.asarray(False)
    resolved, shrink = gap_resolution(g, d, checks, (no, no), *f(1e-14), jnp.asarray(True),
                                      *f(1e-12, 6.794866e-02 / 0.2046))
    assert not bool(resolved) and float(shrink) < 1.0
    # The same samples with the check point outside the wall are resolved.
    checks = (f(5.428675e-03, 1.501351e-02), checks[1])
    resolved, _ = gap_resolution(g, d, checks, (no, no), *f(1e-14), jnp.asarray(True),
                                 *f(1e-12, 6.794866e-02 / 0.2046))
    assert bool(resolved)
