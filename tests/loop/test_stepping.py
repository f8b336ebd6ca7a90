"""The loop's default step-size controller (`_loop.stepping.IntegralController`) against
Diffrax's `PIDController` with the same tolerances: the same decisions, the next step and
the controller's state to an ulp or so, including failed steps (error 0, inf) and NaN
candidates."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex
from grazejax._loop.stepping import IntegralController, loop_controller

EPS = float(np.finfo(np.float64).eps)


@pytest.mark.parametrize("case", ["random", "zero error", "infinite error", "nan candidate"])
def test_same_decisions_as_diffrax(case):
    rng = np.random.default_rng(["random", "zero error", "infinite error", "nan candidate"].index(case))
    for _ in range(40):
        rtol = 10.0 ** rng.uniform(-13, -4)
        atol = rtol * 10.0 ** rng.uniform(-3, 1)
        order = int(rng.choice([4, 5, 8, 9]))
        y0 = jnp.asarray(rng.normal(size=3))
        y1 = y0 + 0.1 * jnp.asarray(rng.normal(size=3))
        error = jnp.asarray(rng.normal(size=3)) * atol * 10.0 ** rng.uniform(-4, 3)
        if case == "zero error":
            error = jnp.zeros(3)
        elif case == "infinite error":
            error = jnp.full(3, jnp.inf)
        elif case == "nan candidate":
            y1 = y1.at[0].set(jnp.nan)
        state = (jnp.asarray(rng.uniform(0.1, 3)), jnp.asarray(rng.uniform(0.1, 3)),
                 jnp.asarray(False))
        theirs = diffrax.PIDController(rtol=rtol, atol=atol).adapt_step_size(
            0.3, 0.5, y0, y1, None, error, order, state)
        ours = IntegralController(rtol=rtol, atol=atol).adapt_step_size(
            0.3, 0.5, y0, y1, None, error, order, state)
        assert bool(ours[0]) == bool(theirs[0])
        assert float(ours[1]) == float(theirs[1])
        np.testing.assert_allclose(float(ours[2]), float(theirs[2]), rtol=8 * EPS)
        # An integral controller's decisions read no history: Diffrax records the last two
        # inverse errors for its P and D terms; ours passes its state through unchanged
        # (a carry that nothing reads, which the pool's nested loops could not drop).
        for a, b in zip(jax.tree.leaves(ours[4]), jax.tree.leaves(state), strict=True):
            assert np.array_equal(a, b)


def test_other_settings_run_diffrax_own_rule():
    """A PID with other coefficients or step bounds is Diffrax's code path, unchanged."""
    y0, y1, error = jnp.ones(2), jnp.ones(2) * 1.1, jnp.full(2, 1e-9)
    state = (jnp.asarray(1.0), jnp.asarray(1.0), jnp.asarray(False))
    for kw in (dict(pcoeff=0.3, icoeff=0.4), dict(dtmax=0.05)):
        ours = IntegralController(rtol=1e-8, atol=1e-8, **kw).adapt_step_size(
            0.0, 0.1, y0, y1, None, error, 5, state)
        theirs = diffrax.PIDController(rtol=1e-8, atol=1e-8, **kw).adapt_step_size(
            0.0, 0.1, y0, y1, None, error, 5, state)
        assert float(ours[2]) == float(theirs[2])


def test_default_is_the_integral_controller_and_a_given_one_is_kept():
    solver = diffrax.Tsit5()
    default = loop_controller(None, solver, rtol=1e-8, atol=1e-9, dt0=None, has_error_estimate=True)
    assert isinstance(default, IntegralController)
    assert (default.rtol, default.atol) == (1e-8, 1e-9)
    given = diffrax.PIDController(rtol=1e-6, atol=1e-6, pcoeff=0.2, icoeff=0.5)
    kept = loop_controller(given, solver, rtol=1e-8, atol=1e-9, dt0=None, has_error_estimate=True)
    assert type(kept) is diffrax.PIDController and kept.pcoeff == 0.2


def test_runs_match_diffrax_controller_to_tolerance():
    """A whole run with the default against one with Diffrax's controller: the same steps,
    impact times within the tolerance's reach."""
    args, x0 = ex.ex1dof_args(0.2), jnp.array([0.0, 0.04])
    kw = dict(rtol=1e-10, atol=1e-10, max_impacts=5, solver=diffrax.Dopri8())
    ours = gj.simulate(ex.ex1dof(), x0, 0.0, 40.0, args, **kw)
    theirs = gj.simulate(ex.ex1dof(), x0, 0.0, 40.0, args,
                         stepsize_controller=diffrax.PIDController(rtol=1e-10, atol=1e-10), **kw)
    assert int(ours.num_steps) == int(theirs.num_steps)
    np.testing.assert_allclose(ours.impact_times, theirs.impact_times, rtol=0, atol=1e-11)


@pytest.mark.parametrize("n", [1, 2, 3, 8, 9])
def test_error_norm_is_the_rms_norm(n):
    """The error norm written out term by term is optimistix's `rms_norm` to an ulp, also
    at 0, inf and NaN, batched or not."""
    import optimistix as optx

    from grazejax._loop.stepping import error_norm

    rng = np.random.default_rng(n)
    ratios = rng.normal(size=(200, n)) * 10.0 ** rng.uniform(-12, 3, size=(200, 1))
    ratios[0] = 0.0
    ratios[1, 0] = np.inf
    ratios[2, -1] = np.nan
    ratios = jnp.asarray(ratios)
    ours = jax.jit(jax.vmap(lambda r: error_norm(optx.rms_norm, r)))(ratios)
    theirs = jax.vmap(optx.rms_norm)(ratios)
    np.testing.assert_allclose(ours, theirs, rtol=2 * EPS)
    assert float(ours[0]) == 0.0 and np.isinf(ours[1]) and np.isnan(ours[2])
    single = jax.jit(lambda r: error_norm(optx.rms_norm, r))
    np.testing.assert_allclose([float(single(ratios[i])) for i in range(3, 20)], ours[3:20],
                               rtol=2 * EPS)
    # derivatives do not see it (its callers use it for decisions only)
    tangent = jax.jvp(lambda r: error_norm(optx.rms_norm, r), (ratios[0],), (ratios[3],))[1]
    assert n > 8 or float(tangent) == 0.0
