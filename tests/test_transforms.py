"""Layer 3: simulate under jit, vmap and jacfwd, and event accuracy for every solver offered."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import grazejax as gj
from grazejax import examples as ex

from .helpers import central_differences, scipy_reference

BALL = ex.bouncing_ball()
BALL_ARGS = {"g": jnp.asarray(9.81), "e": jnp.asarray(0.8)}


@pytest.fixture(scope="module")
def ball_final():
    return jax.jit(
        lambda x0, args: gj.simulate(BALL, x0, 0.0, 1.5, args, rtol=1e-12, atol=1e-12)
    )


def test_jit_vmap_over_x0_and_args_equals_loop(ball_final):
    x0s = jnp.stack([jnp.linspace(0.3, 2.0, 6), jnp.linspace(-1.0, 1.0, 6)], axis=1)
    es = jnp.linspace(0.5, 0.9, 6)
    batched = jax.vmap(lambda x0, e: ball_final(x0, {"g": BALL_ARGS["g"], "e": e}))(x0s, es)
    for i in range(6):
        single = ball_final(x0s[i], {"g": BALL_ARGS["g"], "e": es[i]})
        assert int(batched.num_impacts[i]) == int(single.num_impacts)
        # XLA may vectorise the batched program differently (FMA, fusion): equal to
        # round-off, not bit for bit. Impact counts, surfaces and statuses are exact.
        np.testing.assert_allclose(batched.x_final[i], single.x_final, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(batched.impact_times[i], single.impact_times, rtol=1e-13, atol=0)
        np.testing.assert_array_equal(batched.impact_surface[i], single.impact_surface)
        assert int(batched.status[i]) == int(single.status)
    assert not np.any(np.isnan(np.asarray(batched.x_final)))


@settings(max_examples=15, deadline=None)
@given(
    h=st.floats(0.05, 3.0),
    v=st.floats(-3.0, 3.0),
    e=st.floats(0.3, 0.95),
)
def test_property_batch_equals_loop(ball_final, h, v, e):
    x0 = jnp.array([h, v])
    other = jnp.array([1.0, 0.0])
    pair = jax.vmap(lambda x: ball_final(x, {"g": BALL_ARGS["g"], "e": jnp.asarray(e)}))(
        jnp.stack([x0, other])
    )
    single = ball_final(x0, {"g": BALL_ARGS["g"], "e": jnp.asarray(e)})
    # Round-off differences between the batched and single programs grow through a Zeno
    # sequence (dozens of bounces): equal to the solver tolerance (1e-12), counts exact.
    np.testing.assert_allclose(pair.x_final[0], single.x_final, rtol=1e-10, atol=1e-12)
    assert int(pair.num_impacts[0]) == int(single.num_impacts)
    assert int(pair.status[0]) == int(single.status)


def _saltation_flow(h, e, g, T):
    """Closed-form Jacobian d x(T) / d x0 for one impact, from (h, 0) (falling ball)."""
    t1 = np.sqrt(2 * h / g)
    v = -g * t1
    a = -g
    # Flow Jacobians of the free fall over [0, t1] and [t1, T]; saltation at the floor
    # (paper's S = DJ + (f+ − DJ f−) ∇Φᵀ / (∇Φ·f−)) = [[−e, 0], [(a + e a)/v, −e]].
    phi1 = np.array([[1, t1], [0, 1]])
    s = T - t1
    phi2 = np.array([[1, s], [0, 1]])
    S = np.array([[-e, 0.0], [(a + e * a) / v, -e]])
    return phi2 @ S @ phi1


def test_jacfwd_equals_saltation_and_finite_differences():
    h, e, g, T = 1.0, 0.8, 9.81, 0.6
    run = lambda x0: gj.simulate(BALL, x0, 0.0, T, {"g": g, "e": e}, rtol=1e-12, atol=1e-12).x_final
    J = jax.jacfwd(run)(jnp.array([h, 0.0]))
    np.testing.assert_allclose(J, _saltation_flow(h, e, g, T), rtol=1e-9, atol=1e-9)
    step = 1e-6
    fd = central_differences(lambda x0: run(jnp.asarray(x0)), [h, 0.0], step)
    np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-6)


def test_jacfwd_with_respect_to_args_matches_closed_form():
    """d(t_n)/d(e) for the bouncing ball: t_n = t_1 + 2 w Σ_{k=1}^{n-1} e^k / g."""
    h, g, e = 1.0, 9.81, 0.8

    def times(e_):
        sol = gj.simulate(BALL, jnp.array([h, 0.0]), 0.0, 2.0, {"g": g, "e": e_}, rtol=1e-12, atol=1e-12)
        return sol.impact_times[:3]

    dt_de = jax.jacfwd(times)(jnp.asarray(e))
    w = np.sqrt(2 * g * h)
    exact = [0.0, 2 * w / g, 2 * w / g * (1 + 2 * e)]
    np.testing.assert_allclose(dt_de, exact, rtol=1e-8, atol=1e-10)


SOLVERS = {
    "Tsit5": diffrax.Tsit5(),
    "Dopri5": diffrax.Dopri5(),
    "Dopri8": diffrax.Dopri8(),
    "Kvaerno5": diffrax.Kvaerno5(),
}


@pytest.mark.parametrize("name", list(SOLVERS))
@pytest.mark.parametrize("rtol", [1e-8, 1e-10])
def test_event_accuracy_for_every_solver(name, rtol):
    """Impact times within ~tolerance of an independent reference, for each solver.

    diffrax's own `Event` returned wrong times for Dopri8 here (its interpolant is only
    ~5th order); grazejax takes the event state from a real step, so every solver is
    accurate to its tolerance.
    """
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    x0 = np.array([0.5, 1.2])
    sol = gj.simulate(scene, x0, 0.0, 25.0, args, solver=SOLVERS[name], rtol=rtol, atol=rtol)
    ref_t, _, ref_post, _ = _ex1dof_reference()
    k = int(sol.num_impacts)
    assert k == len(ref_t)
    # Global error after several flights: ~100 x tolerance is the method's honest bound.
    np.testing.assert_allclose(sol.impact_times[:k], ref_t, atol=300 * rtol)
    np.testing.assert_allclose(sol.impact_post[:k], ref_post, atol=300 * rtol)


_REF = {}


def _ex1dof_reference():
    if not _REF:
        scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
        _REF["v"] = scipy_reference(scene, np.array([0.5, 1.2]), 0.0, 25.0, args, max_impacts=50)
    return _REF["v"]
