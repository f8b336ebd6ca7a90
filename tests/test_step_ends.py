"""The step-end gap rates of the event test: the dense output at a constant fraction θ of
the step (weights folded at compile time) against the jvp through `evaluate` at the traced
time, for Diffrax's solvers (explicit, wrapped by `UnrolledERK` as `simulate` does, and
implicit)."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from grazejax._events import LIFT_FRACTION
from grazejax._loop.detect import _at_fraction, _fraction_time
from grazejax._unrolled import UnrolledERK, unrollable

EPS = float(np.finfo(np.float64).eps)

SOLVERS = {
    "Tsit5": diffrax.Tsit5(),
    "Dopri5": diffrax.Dopri5(),
    "Dopri8": diffrax.Dopri8(),
    "Bosh3": diffrax.Bosh3(),
    "Heun": diffrax.Heun(),
    "Euler": diffrax.Euler(),
    # (its root finder given tolerances, as `simulate` gives it the controller's)
    "Kvaerno5": diffrax.Kvaerno5(root_finder=diffrax.VeryChord(rtol=1e-10, atol=1e-10)),
}


def _interpolation(solver, sa, sb):
    """The dense output of one step of a damped, forced oscillator from sa to sb."""
    if unrollable(solver):
        solver = UnrolledERK(solver)
    term = diffrax.ODETerm(lambda t, y, args: jnp.stack([y[1], -y[0] - 0.3 * y[1] + jnp.cos(2 * t)]))
    y0 = jnp.array([0.7, -0.4])
    state = solver.init(term, sa, sb, y0, None)
    _, _, dense_info, _, _ = solver.step(term, sa, sb, y0, None, state, False)
    return solver.interpolation_cls(t0=sa, t1=sb, **dense_info)


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
