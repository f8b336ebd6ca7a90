"""`grazejax.Vern9`, Verner's 9(8) pair with an eighth-order interpolant: the tableau's
conditions, the measured orders of the step and of the dense output against closed forms,
and `simulate` / `jax.grad` through impacts with it."""

import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import _vern9
from grazejax import examples as ex

EPS = float(np.finfo(np.float64).eps)


def test_tableau_conditions():
    """Rows sum to the nodes; the weights integrate θᵏ exactly up to k = 8 (order 9), the
    embedded ones up to k = 7 only (order 8); stage 17 is the FSAL stage (its row is b)."""
    c = np.concatenate([[0.0], _vern9._C])
    for i, row in enumerate(_vern9._A, start=1):
        assert abs(sum(row) - c[i]) < 1e-14
    b = np.asarray(_vern9._B)
    embedded = b + np.asarray(_vern9._B_ERROR)
    for k in range(9):
        assert abs(b @ c[:16] ** k - 1 / (k + 1)) < 1e-15
    for k in range(8):
        assert abs(embedded @ c[:16] ** k - 1 / (k + 1)) < 1e-15
    assert abs(embedded @ c[:16] ** 8 - 1 / 9) > 1e-6
    np.testing.assert_array_equal(np.asarray(_vern9._A[15]), b)
    assert _vern9._TABLEAU.fsal and _vern9._TABLEAU.ssal


def _riccati(t, y, args):
    # y' = 1 + y², y(0) = 0: y = tan t (nonlinear, so every elementary differential counts)
    return 1.0 + y**2


def test_the_step_is_ninth_order():
    """Global error of fixed steps on y' = 1 + y² over [0, 1] against tan 1."""
    term = diffrax.ODETerm(_riccati)
    errors = []
    for n in (3, 6):
        sol = diffrax.diffeqsolve(term, gj.Vern9(), 0.0, 1.0, 1.0 / n, jnp.array([0.0]))
        errors.append(abs(float(sol.ys[-1, 0]) - math.tan(1.0)))
    order = math.log2(errors[0] / errors[1])
    assert errors[1] > 1e3 * EPS  # (still above round-off)
    assert order > 8.5, (errors, order)


def _one_step(h, y0=0.0):
    solver = gj.Vern9()
    term = diffrax.ODETerm(_riccati)
    y0 = jnp.array([y0])
    state = solver.init(term, 0.0, h, y0, None)
    y1, _, dense, _, _ = solver.step(term, 0.0, h, y0, None, state, False)
    return y0, y1, solver.interpolation_cls(t0=0.0, t1=h, **dense)


def test_the_interpolant_is_eighth_order_and_exact_at_the_ends():
    """Local error of the dense output inside one step (from y(0.9) = tan 0.9): O(h⁹)."""
    errors = []
    for h in (0.2, 0.1):
        _, y1, interp = _one_step(h, math.tan(0.9))
        worst = max(
            abs(float(interp.evaluate(theta * h)[0]) - math.tan(0.9 + theta * h))
            for theta in (0.2, 0.5, 0.8)
        )
        errors.append(worst)
        assert float(interp.evaluate(0.0)[0]) == math.tan(0.9)
        assert abs(float(interp.evaluate(h)[0]) - float(y1[0])) <= 8 * EPS * abs(float(y1[0]))
    assert errors[1] > 1e3 * EPS
    assert math.log2(errors[0] / errors[1]) > 8.5, errors


def test_the_dense_output_agrees_with_diffeqsolve_and_in_float32():
    """Usable outside grazejax, with Diffrax's dense output; float32 runs."""
    term = diffrax.ODETerm(_riccati)
    sol = diffrax.diffeqsolve(
        term, gj.Vern9(), 0.0, 1.0, 0.1, jnp.array([0.0]), saveat=diffrax.SaveAt(dense=True),
        stepsize_controller=diffrax.PIDController(rtol=1e-12, atol=1e-12),
    )
    for t in (0.13, 0.5, 0.97):
        assert abs(float(sol.evaluate(t)[0]) - math.tan(t)) < 1e-10
    sol32 = diffrax.diffeqsolve(term, gj.Vern9(), jnp.float32(0), jnp.float32(1), jnp.float32(0.1),
                                jnp.array([0.0], jnp.float32))
    assert sol32.ys.dtype == jnp.float32
    assert abs(float(sol32.ys[-1, 0]) - math.tan(1.0)) < 1e-5


def test_simulate_with_vern9_meets_the_closed_form_ball():
    h0, g, e = 1.0, 9.81, 0.8
    want, _ = ex.bouncing_ball_impact_times(h0, 0.0, g, e, 8)
    sol = gj.simulate(ex.bouncing_ball(), jnp.array([h0, 0.0]), 0.0, 3.5, {"g": g, "e": e},
                      solver=gj.Vern9(), rtol=1e-12, atol=1e-12, max_impacts=8)
    assert int(sol.num_impacts) == 8
    np.testing.assert_allclose(np.asarray(sol.impact_times), want, rtol=0, atol=1e-12)


def test_simulate_with_vern9_agrees_with_dopri8_near_grazing():
    """ex1dof at μ = 0.2 (every impact nearly grazing), 10 impacts: the two solvers' impact
    times agree to their tolerance's global error."""
    kwargs = dict(rtol=1e-12, atol=1e-12, max_impacts=10, direction=1)
    x0, args = jnp.array([0.0, 0.04]), ex.ex1dof_args(0.2)
    a = gj.simulate(ex.ex1dof(), x0, 0.0, jnp.inf, args, solver=gj.Vern9(), **kwargs)
    b = gj.simulate(ex.ex1dof(), x0, 0.0, jnp.inf, args, solver=diffrax.Dopri8(), **kwargs)
    assert int(a.num_impacts) == int(b.num_impacts) == 10
    np.testing.assert_allclose(a.impact_times, b.impact_times, rtol=0, atol=1e-9)


@pytest.mark.parametrize("mode", ["fwd", "rev"])
def test_derivatives_through_impacts_with_vern9(mode):
    """d t_1 / d h0 of the ball, closed form 1/√(2 g h0): jacfwd and grad (the stages are
    straight-line code, so the checkpointed loop differentiates through them)."""
    g, e = 9.81, 0.8
    adjoint = diffrax.RecursiveCheckpointAdjoint() if mode == "rev" else None

    def first_impact(h0):
        sol = gj.simulate(ex.bouncing_ball(), jnp.stack([h0, 0.0]), 0.0, 1.0,
                          {"g": g, "e": e}, solver=gj.Vern9(), rtol=1e-12, atol=1e-12,
                          max_impacts=1, adjoint=adjoint)
        return sol.impact_times[0]

    derivative = (jax.jacfwd if mode == "fwd" else jax.grad)(first_impact)(1.0)
    assert abs(float(derivative) - 1 / math.sqrt(2 * g)) < 1e-9
