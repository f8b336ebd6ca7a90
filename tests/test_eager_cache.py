"""`simulate` called outside `jit` compiles its program once per scene and options.

Before, each such call traced and compiled the loop again (~1.5 s for ex1dof); now the run
is one cached compiled program (a `jax.jit` per scene and options) whose inputs are x0, t0,
t1, the array leaves of `args` and its Python floats. The input checks still run on the values (outside the
program), and the results are those of the same run inside a user's `jax.jit` with
`compiler_options(batched=False)` (XLA:CPU's quicker emitters for one trajectory).
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex


def _counting_ball():
    traces = []
    base = ex.bouncing_ball()

    def field(t, x, args):
        traces.append(None)  # runs only while JAX traces the program
        return base.vector_field(t, x, args)

    return gj.Scene(field, base.surfaces), traces


def test_repeated_calls_do_not_retrace():
    scene, traces = _counting_ball()
    first = gj.simulate(scene, jnp.array([1.0, 0.0]), 0.0, 2.0, {"g": 9.81, "e": 0.8})
    traced = len(traces)
    assert traced > 0
    # New values of every input that is not part of the program's structure.
    second = gj.simulate(scene, jnp.array([0.7, 0.3]), 0.5, 3.0, {"g": 9.8, "e": 0.6})
    third = gj.simulate(scene, np.array([2.0, -1.0]), 0, 4, {"g": jnp.asarray(9.81), "e": 0.9})
    assert len(traces) == traced
    # ... and the new values were used: each run equals the closed form.
    for sol, (h0, v0, t0, g, e) in [(first, (1.0, 0.0, 0.0, 9.81, 0.8)),
                                    (second, (0.7, 0.3, 0.5, 9.8, 0.6)),
                                    (third, (2.0, -1.0, 0.0, 9.81, 0.9))]:
        times, _ = ex.bouncing_ball_impact_times(h0, v0, g, e, 3)
        np.testing.assert_allclose(np.asarray(sol.impact_times[:3]), times + t0, rtol=1e-9)
    # A static option (here max_impacts) is a new program.
    gj.simulate(scene, jnp.array([1.0, 0.0]), 0.0, 2.0, {"g": 9.81, "e": 0.8}, max_impacts=7)
    assert len(traces) > traced


def test_eager_run_equals_jitted_run():
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    x0 = jnp.array([0.5, 1.2])
    eager = gj.simulate(scene, x0, 0.0, 20.0, args, max_impacts=20)
    # Outside jit, simulate compiles as grazejax's other one-trajectory programs do.
    jitted = jax.jit(
        lambda x, a, t1: gj.simulate(scene, x, 0.0, t1, a, max_impacts=20, direction=1),
        compiler_options=gj.compiler_options(batched=False),
    )(x0, args, 20.0)
    for field in ("t_final", "x_final", "num_impacts", "impact_times", "status"):
        np.testing.assert_array_equal(getattr(eager, field), getattr(jitted, field), err_msg=field)


def test_eager_checks_still_see_values():
    scene = ex.bouncing_ball()
    with pytest.raises(ValueError, match="nothing to simulate"):
        gj.simulate(scene, jnp.array([1.0, 0.0]), 1.0, 1.0, {"g": 9.81, "e": 0.8})
    with pytest.raises(ValueError, match="inside an impenetrable surface"):
        gj.simulate(scene, jnp.array([-1.0, 0.0]), 0.0, 1.0, {"g": 9.81, "e": 0.8})
    with pytest.raises(gj.SimulationError):
        gj.simulate(scene, jnp.array([1.0, 0.0]), 0.0, 1.0, {"g": 9.81, "e": 0.8},
                    max_steps=3, throw=True)


def test_scene_reading_a_value_in_python_is_a_clear_error():
    """Scene functions are traced (args included): Python control flow on a parameter is
    named as such, with the fix (this was an AttributeError from rebuilding JAX's error)."""
    base = ex.bouncing_ball()
    floor = base.surfaces[0]

    def jump(t, x, args):
        if args["e"] == 0.0:  # Python control flow on a parameter
            return x.at[1].set(0.0)
        return floor.jump(t, x, args)

    scene = gj.Scene(base.vector_field, [gj.Surface(phi=floor.phi, jump=jump, impenetrable=True)])
    with pytest.raises(TypeError, match=r"jump\(t, x, args\) reads a value in Python.*jnp.where"):
        gj.simulate(scene, jnp.array([1.0, 0.0]), 0.0, 2.0, {"g": 9.81, "e": 0.8})


def _counting(base):
    """`base` with a vector field that counts how often JAX traces it."""
    traces = []

    def field(t, x, args):
        traces.append(None)
        return base.vector_field(t, x, args)

    return gj.Scene(field, base.surfaces), traces


def test_new_tolerances_do_not_recompile():
    """rtol, atol, zeno_rtol and dt0 are inputs of the compiled run, Python floats included."""
    scene, traces = _counting(ex.ex1dof())
    args, x0 = ex.ex1dof_args(0.2), jnp.array([0.5, 1.2])
    run = lambda **tols: gj.simulate(scene, x0, 0.0, 20.0, args, max_impacts=20, **tols)  # noqa: E731
    coarse = run(rtol=1e-6, atol=1e-8, dt0=1e-2)  # (dt0 given or not: two programs)
    traced = len(traces)
    fine = run(rtol=1e-10, atol=1e-12, zeno_rtol=1e-7, dt0=1e-3)
    assert len(traces) == traced
    # The new tolerances were used: more steps, and the coarse run's error is about its
    # tolerance (ex1dof's flights are smooth; its 20 impacts amplify errors by ~1e2).
    assert int(fine.num_steps) > int(coarse.num_steps)
    err = np.max(np.abs(np.asarray(fine.x_final) - np.asarray(coarse.x_final)))
    assert 1e-12 < err < 1e-6 * 1e3
    # A constant step reads dt0 in Python: a new one is a new program (not an error).
    gj.simulate(scene, x0, 0.0, 1.0, args, stepsize_controller=diffrax.ConstantStepSize(),
                dt0=0.01)
    assert len(traces) > traced


def test_eager_transforms_reuse_the_program():
    """A second eager `jax.jacfwd` / `jax.grad` of the same call runs without tracing again,
    and each gives the derivative: central differences of the (cached) eager run, and the
    transpose of the forward Jacobian."""
    scene, traces = _counting(ex.bouncing_ball())
    args, t1 = {"g": 9.81, "e": 0.8}, 1.3  # two impacts in [0, t1]
    final = lambda x0: gj.simulate(scene, x0, 0.0, t1, args).x_final  # noqa: E731
    x0 = jnp.array([1.0, 0.5])
    J = jax.jacfwd(final)(x0)
    traced = len(traces)
    J2 = jax.jacfwd(final)(x0 + 0.01)
    assert len(traces) == traced
    # The ball's flights are parabolas (integrated exactly) and its impact times are Newton
    # roots to round-off, so central differences with h = 1e-5 err by ~h² x''' ≈ 1e-9 plus
    # round-off eps/h ≈ 1e-11.
    h = 1e-5
    for J_, at in ((J, x0), (J2, x0 + 0.01)):
        fd = np.stack([(np.asarray(final(at + h * e)) - np.asarray(final(at - h * e))) / (2 * h)
                       for e in np.eye(2)], axis=1)
        np.testing.assert_allclose(np.asarray(J_), fd, rtol=1e-7, atol=1e-7)
    loss = lambda x0: jnp.sum(gj.simulate(  # noqa: E731
        scene, x0, 0.0, t1, args, adjoint=diffrax.RecursiveCheckpointAdjoint()).x_final ** 2)
    grad = jax.grad(loss)(x0)
    traced = len(traces)
    grad2 = jax.grad(loss)(x0 + 0.01)
    assert len(traces) == traced
    for g_, J_, at in ((grad, J, x0), (grad2, J2, x0 + 0.01)):
        np.testing.assert_allclose(np.asarray(g_), 2 * np.asarray(J_).T @ np.asarray(final(at)),
                                   rtol=1e-12, atol=1e-12)


def test_a_sweep_at_new_tolerances_reuses_its_program():
    scene, traces = _counting(ex.bouncing_ball())
    x0s = jnp.array([[1.0, 0.0], [0.5, 1.0], [2.0, -1.0]])
    coarse = gj.sweep(scene, x0s, 0.0, 1.0, {"g": 9.81, "e": 0.8}, rtol=1e-6, progress=False)
    traced = len(traces)
    fine = gj.sweep(scene, x0s, 0.0, 1.0, {"g": 9.81, "e": 0.8}, rtol=1e-11, atol=1e-13,
                    progress=False)
    assert len(traces) == traced
    for lane in range(3):  # each lane's impact times: the closed form, at either tolerance
        h0, v0 = np.asarray(x0s[lane])
        times, _ = ex.bouncing_ball_impact_times(h0, v0, 9.81, 0.8, 1)
        for sol in (coarse, fine):
            np.testing.assert_allclose(sol.impact_times[lane, 0], times[0], rtol=1e-9)
