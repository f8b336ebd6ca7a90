"""Explicit Runge–Kutta steps with unrolled stages (`grazejax._loop.unrolled`) against Diffrax's
own step (its stage loop, `scan_kind="lax"`): the same step to rounding, for every
explicit tableau Diffrax ships (FSAL or not, with and without a jump), in float64 and
float32, and differentiable in both modes."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex
from grazejax._loop.unrolled import UnrolledERK, unrollable

EXPLICIT = (diffrax.Heun, diffrax.Midpoint, diffrax.Ralston, diffrax.Bosh3, diffrax.Tsit5,
            diffrax.Dopri5, diffrax.Dopri8)


def field(t, y, args):
    # nonlinear and time-dependent, so every stage's time and state matter
    return jnp.stack([y[1], -args * jnp.sin(y[0]) + 0.3 * jnp.cos(1.7 * t) * y[1] ** 2])


def two_steps(solver, dtype, made_jump, y0=(0.7, -0.4)):
    """Two consecutive steps (the second reads the FSAL state of the first), then the dense
    output of the second at three interior times."""
    term = diffrax.ODETerm(field)
    y0 = jnp.asarray(y0, dtype)
    args = jnp.asarray(1.3, dtype)
    t0, t1, t2 = (jnp.asarray(v, dtype) for v in (0.1, 0.35, 0.62))
    state = solver.init(term, t0, t1, y0, args)
    y1, _, _, state, _ = solver.step(term, t0, t1, y0, args, state, jnp.asarray(False))
    y2, err, dense, state, _ = solver.step(term, t1, t2, y1, args, state, jnp.asarray(made_jump))
    interp = solver.interpolation_cls(t0=t1, t1=t2, **dense)
    inside = jnp.stack([interp.evaluate(t1 + f * (t2 - t1)) for f in (0.2, 0.5, 0.9)])
    return y2, err, inside, state


@pytest.mark.parametrize("made_jump", [False, True])
@pytest.mark.parametrize("cls", EXPLICIT, ids=lambda c: c.__name__)
def test_unrolled_step_is_diffrax_step(cls, made_jump):
    assert unrollable(cls())
    got = two_steps(UnrolledERK(cls()), jnp.float64, made_jump)
    want = two_steps(cls(scan_kind="lax"), jnp.float64, made_jump)
    for g, w in zip(jax.tree.leaves(got[:3]), jax.tree.leaves(want[:3]), strict=True):
        # the same sums in another order: a few ulps of the largest stage term
        np.testing.assert_allclose(g, w, rtol=0, atol=64 * np.finfo(np.float64).eps)
    if want[3] is not None:
        np.testing.assert_allclose(got[3][1], want[3][1], rtol=0, atol=64 * np.finfo(float).eps)
        assert not bool(got[3][0])


def test_float32_stays_float32():
    y2, err, inside, state = two_steps(UnrolledERK(diffrax.Dopri8()), jnp.float32, False)
    assert y2.dtype == err.dtype == inside.dtype == state[1].dtype == jnp.float32
    want = two_steps(diffrax.Dopri8(scan_kind="lax"), jnp.float32, False)[0]
    np.testing.assert_allclose(y2, want, rtol=0, atol=64 * np.finfo(np.float32).eps)


def test_what_is_unrolled():
    assert not unrollable(diffrax.Kvaerno5())  # implicit stages need their root finds
    assert not unrollable(diffrax.Euler())  # not a tableau method
    assert not unrollable(diffrax.Tsit5(scan_kind="checkpointed"))  # the user's choice
    assert not unrollable(diffrax.Dopri5(scan_kind="lax"))


def test_step_differentiates_in_both_modes():
    """Straight-line stages: jax.jacfwd and jax.grad of a step agree (the stage loop
    supports one mode per kind)."""
    solver = UnrolledERK(diffrax.Tsit5())

    def y2(y0):
        return two_steps(solver, jnp.float64, False, y0)[0]

    y0 = jnp.array([0.7, -0.4])
    forward = jax.jacfwd(y2)(y0)
    reverse = jnp.stack([jax.grad(lambda y, i=i: y2(y)[i])(y0) for i in range(2)])
    np.testing.assert_allclose(reverse, forward, rtol=1e-14, atol=1e-14)


def test_simulate_unrolled_matches_stage_loop():
    """The whole impact loop with unrolled stages against the stage loop: the same impacts,
    and times that differ by rounding only — far less than either differs from a tight
    reference (the method's own error). The unrolled sums are taken relative to the first
    stage, so the two round differently and the impacts amplify it."""
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    x0 = jnp.array([0.0, 0.0384224329])

    def times(solver, tol):
        sol = gj.simulate(scene, x0, 0.0, jnp.inf, args, solver=solver, rtol=tol, atol=tol,
                          max_impacts=10, direction=1)
        assert int(sol.num_impacts) == 10
        return np.asarray(sol.impact_times)

    unrolled = times(diffrax.Dopri8(), 1e-10)
    stage_loop = times(diffrax.Dopri8(scan_kind="lax"), 1e-10)
    reference = times(diffrax.Dopri8(scan_kind="lax"), 1e-14)
    method_error = np.max(np.abs(stage_loop - reference))
    assert method_error > 0
    assert np.max(np.abs(unrolled - stage_loop)) <= 0.01 * method_error