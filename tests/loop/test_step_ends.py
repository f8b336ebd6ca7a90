"""The step-end gap rates of the event test: the dense output at a constant fraction θ of
the step (weights folded at compile time) against the jvp through `evaluate` at the traced
time, for Diffrax's solvers (explicit, wrapped by `UnrolledERK` as `simulate` does, and
implicit) and `Vern9`; the rates at the ends read from the stages; the lift-off test."""

from types import SimpleNamespace

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax._loop.events import CHECK_FRACTIONS, LIFT_FRACTION, step_ends
from grazejax._loop.gaps import at_fraction as _at_fraction
from grazejax._loop.gaps import at_fractions as _at_fractions
from grazejax._loop.gaps import fraction_time as _fraction_time
from grazejax._loop.gaps import rates_at_ends
from grazejax._loop.unrolled import UnrolledERK, unrollable

EPS = float(np.finfo(np.float64).eps)

SOLVERS = {
    "Tsit5": diffrax.Tsit5(),
    "Dopri5": diffrax.Dopri5(),
    "Dopri8": diffrax.Dopri8(),
    "Bosh3": diffrax.Bosh3(),
    "Heun": diffrax.Heun(),
    "Euler": diffrax.Euler(),
    "Vern9": gj.Vern9(),
    # (its root finder given tolerances, as `simulate` gives it the controller's)
    "Kvaerno5": diffrax.Kvaerno5(root_finder=diffrax.VeryChord(rtol=1e-10, atol=1e-10)),
}


def _field(t, y, args):
    return jnp.stack([y[1], -y[0] - 0.3 * y[1] + jnp.cos(2 * t)])


def _interpolation(solver, sa, sb, with_end=False):
    """The dense output of one step of a damped, forced oscillator from sa to sb."""
    if unrollable(solver):
        solver = UnrolledERK(solver)
    term = diffrax.ODETerm(_field)
    y0 = jnp.array([0.7, -0.4])
    state = solver.init(term, sa, sb, y0, None)
    y1, _, dense_info, _, _ = solver.step(term, sa, sb, y0, None, state, False)
    interp = solver.interpolation_cls(t0=sa, t1=sb, **dense_info)
    return (interp, solver, y0, y1, dense_info.get("k")) if with_end else interp


def _traced(interp, theta, sa, sb):
    s = _fraction_time(theta, sa, sb)
    y, dy = jax.jvp(interp.evaluate, (s,), (jnp.ones_like(s),))
    return s, y, dy


@pytest.mark.parametrize("name", sorted(SOLVERS))
@pytest.mark.parametrize("theta", [0.0, LIFT_FRACTION, 1.0])
def test_constant_fraction_matches_the_traced_dense_output(name, theta):
    sa, sb = jnp.float64(3.25), jnp.float64(3.25 + 0.37)

    @jax.jit
    def both(sa, sb):
        interp = _interpolation(SOLVERS[name], sa, sb)
        return _at_fraction(interp)(theta, sa, sb), _traced(interp, theta, sa, sb)

    (s, y, dy), (s_ref, y_ref, dy_ref) = both(sa, sb)
    assert float(s) == float(s_ref)
    # The same polynomial, rounded in another order: a few ulps of the state and of the
    # rate (the rate divides dP/dθ by the step, ~3 here, instead of multiplying by 1/h).
    np.testing.assert_allclose(y, y_ref, rtol=0, atol=16 * EPS)
    np.testing.assert_allclose(dy, dy_ref, rtol=0, atol=64 * EPS)
    if theta == 0.0:
        np.testing.assert_array_equal(y, jnp.array([0.7, -0.4]))  # P(sa) is y0 exactly


@pytest.mark.parametrize("name", ["Tsit5", "Dopri5", "Dopri8", "Vern9"])
def test_one_fraction_is_the_batch_of_one_bit_for_bit(name):
    """`at_fraction` evaluates one fraction without `at_fractions`' batch of fractions (whose
    batch of one cost a copy of each weight vector per step): the same weights and the same
    contraction, so the same bits, in a program of its own as in one step."""
    sa, sb = jnp.float64(3.25), jnp.float64(3.25 + 0.37)
    for theta in (LIFT_FRACTION, *CHECK_FRACTIONS, 0.5):

        @jax.jit
        def one(sa, sb, theta=theta):
            return _at_fraction(_interpolation(SOLVERS[name], sa, sb))(theta, sa, sb)

        @jax.jit
        def batch(sa, sb, theta=theta):
            return _at_fractions(_interpolation(SOLVERS[name], sa, sb), (theta,), sa, sb)[0]

        for a, b in zip(one(sa, sb), batch(sa, sb), strict=True):
            np.testing.assert_array_equal(a, b)


def test_an_empty_step_has_no_rate():
    """sb = sa (a landing on the current time): no slope, as the traced path's guard."""
    sa = jnp.float64(1.0)
    interp = _interpolation(diffrax.Tsit5(), sa, sa)
    _, _, dy = jax.jit(lambda: _at_fraction(interp)(1.0, sa, sa))()
    np.testing.assert_array_equal(dy, jnp.zeros(2))


def test_interpolations_from_elsewhere_take_the_traced_path():
    """A user's own dense output may not rescale by its ends: evaluated at the traced time."""

    class Mine(diffrax.LocalLinearInterpolation):
        pass

    Mine.__module__ = "my_solvers"
    sa, sb = jnp.float64(0.5), jnp.float64(1.5)
    interp = Mine(t0=sa, t1=sb, y0=jnp.array([1.0]), y1=jnp.array([3.0]))
    s, y, dy = _at_fraction(interp)(1.0, sa, sb)
    assert float(s) == 1.5 and float(y[0]) == 3.0 and float(dy[0]) == 2.0


@pytest.mark.parametrize("name", ["Tsit5", "Dopri5", "Dopri8", "Vern9"])
def test_rates_at_the_ends_are_the_field_at_the_states(name):
    """FSAL tableaus: the rates at θ = 0 and 1 come from the first and the FSAL stage, h·f
    divided by h: the vector field at the step's own states to an ulp, and the
    interpolant's rates there to its accuracy."""
    sa, sb = jnp.float64(3.25), jnp.float64(3.25 + 0.37)
    interp, solver, y0, y1, k = _interpolation(SOLVERS[name], sa, sb, with_end=True)
    ends = rates_at_ends(SimpleNamespace(solver=solver), y0, sa, sb, y1, k)
    for theta, s, y in ((0.0, sa, y0), (1.0, sb, y1)):
        s_end, y_end, rate = ends[theta]
        assert float(s_end) == float(s)
        np.testing.assert_array_equal(y_end, y)
        np.testing.assert_allclose(rate, _field(s, y, None), rtol=4 * EPS, atol=4 * EPS)
        _, _, dy_interp = _traced(interp, theta, sa, sb)
        np.testing.assert_allclose(rate, dy_interp, rtol=0, atol=1e-5)


def test_rates_at_the_ends_need_an_fsal_stage():
    """Without an FSAL stage (Heun, an implicit solver) the interpolant's ends are used."""
    sa, sb = jnp.float64(0.0), jnp.float64(0.1)
    for name in ("Heun", "Kvaerno5"):
        interp, solver, y0, y1, k = _interpolation(SOLVERS[name], sa, sb, with_end=True)
        ends = rates_at_ends(SimpleNamespace(solver=solver), y0, sa, sb, y1, k)
        assert ends == {}


@pytest.mark.parametrize("slope_a", [0.0, -1e-17, 2e-17])
def test_a_lift_off_in_round_off_is_judged_after_it_whatever_the_sign(slope_a):
    """After a jump that leaves ġ(sa) = 0 to round-off and g̈ > 0 (restitution 0 on a table
    decelerating faster than gravity) the restart step is judged at the lift-off point,
    whether ġ(sa) reads 0, −1 ulp or +1 ulp (+2e-17 ended a run in ZENO: a root of the
    guarded gap in its round-off at sa was taken for a return)."""
    sa, sb, curvature = jnp.float64(0.0), jnp.float64(0.3), 1.0

    def rate(theta):
        s = sa + (sb - sa) * theta
        if theta == 0.0:
            return jnp.float64(0.0), jnp.float64(slope_a)
        return 0.5 * curvature * (s - sa) ** 2, curvature * (s - sa)

    ends = step_ends(rate, sa, sb, jnp.array(True), jnp.float64(0.0), jnp.float64(0.01))
    assert float(ends.s_start) > float(sa)  # judged from the lift-off point
    assert float(ends.g_start) > 0 and float(ends.slope_start) >= 0


def test_a_rising_restart_is_judged_at_its_start():
    """A bounce that leaves with a speed far above round-off is judged from sa as before."""
    sa, sb = jnp.float64(0.0), jnp.float64(0.3)

    def rate(theta):
        s = sa + (sb - sa) * theta
        return 2.0 * (s - sa) - 0.5 * 9.81 * (s - sa) ** 2, 2.0 - 9.81 * (s - sa)

    ends = step_ends(rate, sa, sb, jnp.array(True), jnp.float64(0.0), jnp.float64(0.15))
    assert float(ends.s_start) == float(sa)
    assert float(ends.g_start) == 2.0
