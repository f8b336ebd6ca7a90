"""Bad input fails before compilation with a message naming the problem."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex

BALL = ex.bouncing_ball()
ARGS = {"g": 9.81, "e": 0.8}


def surface(**kw):
    base = dict(phi=lambda t, x, a: x[0], jump=lambda t, x, a: x.at[1].set(-x[1]))
    base.update(kw)
    return gj.Surface(**base)


def field(t, x, a):
    return jnp.stack([x[1], -9.81 * jnp.ones_like(x[0])])


@pytest.mark.parametrize(
    "x0,match",
    [([np.nan, 0.0], "NaN or inf"), ([np.inf, 0.0], "NaN or inf"), ([[1.0, 0.0]], "1-D"), ([], "empty")],
)
def test_bad_x0(x0, match):
    with pytest.raises(ValueError, match=match):
        gj.simulate(BALL, x0, 0.0, 1.0, ARGS)


@pytest.mark.parametrize(
    "args,match",
    [
        ({"g": 9.81, "e": float("nan")}, r"args\['e'\] contains NaN or inf: nan"),
        ({"g": 9.81, "e": 0.8, "wall": {"c": [1.0, np.inf]}},
         r"args\['wall'\]\['c'\]\[1\] contains NaN or inf: inf"),
    ],
)
def test_nan_args_named_by_their_key_path(args, match):
    with pytest.raises(ValueError, match=match):
        gj.simulate(BALL, [1.0, 0.0], 0.0, 1.0, args)


def test_t0_equals_t1():
    with pytest.raises(ValueError, match="t0 == t1"):
        gj.simulate(BALL, [1.0, 0.0], 1.0, 1.0, ARGS)


@pytest.mark.parametrize("value", [0, -3, 2.5])
def test_max_impacts_must_be_positive_int(value):
    with pytest.raises(ValueError, match="max_impacts"):
        gj.simulate(BALL, [1.0, 0.0], 0.0, 1.0, ARGS, max_impacts=value)


def test_float32_needs_opt_in():
    x0 = jnp.array([1.0, 0.0], dtype=jnp.float32)
    with pytest.raises(TypeError, match="float32"):
        gj.simulate(BALL, x0, 0.0, 1.0, ARGS)


def test_phi_must_be_scalar():
    scene = gj.Scene(field, [surface(phi=lambda t, x, a: x)])
    with pytest.raises(ValueError, match="phi.*scalar"):
        gj.simulate(scene, [1.0, 0.0], 0.0, 1.0)


def test_jump_must_keep_shape():
    scene = gj.Scene(field, [surface(jump=lambda t, x, a: x[:1])])
    with pytest.raises(ValueError, match="jump.*shape"):
        gj.simulate(scene, [1.0, 0.0], 0.0, 1.0)


def test_where_must_be_boolean():
    scene = gj.Scene(field, [surface(where=lambda t, x, a: x[1])])
    with pytest.raises(ValueError, match="where.*boolean"):
        gj.simulate(scene, [1.0, 0.0], 0.0, 1.0)


def test_vector_field_shape():
    scene = gj.Scene(lambda t, x, a: x[:1], [surface()])
    with pytest.raises(ValueError, match="vector_field"):
        gj.simulate(scene, [1.0, 0.0], 0.0, 1.0)


def test_scene_functions_must_be_callable():
    with pytest.raises(TypeError, match="callable"):
        gj.Surface(phi=1.0, jump=lambda t, x, a: x)
    with pytest.raises(TypeError, match="Surface"):
        gj.Scene(field, [lambda t, x, a: x[0]])
    with pytest.raises(TypeError, match="project must be callable"):
        gj.Scene(field, [surface()], project=1.0)


def test_project_must_keep_shape():
    scene = gj.Scene(field, [surface()], project=lambda t, x, a: x[:1])
    with pytest.raises(ValueError, match="project.*shape"):
        gj.simulate(scene, [1.0, 0.0], 0.0, 1.0)


def test_traced_times_need_direction():
    run = jax.jit(lambda t1: gj.simulate(BALL, jnp.array([1.0, 0.0]), 0.0, t1, ARGS).x_final)
    with pytest.raises(ValueError, match="direction"):
        run(1.0)
    run = jax.jit(lambda t1: gj.simulate(BALL, jnp.array([1.0, 0.0]), 0.0, t1, ARGS, direction=1).x_final)
    assert np.all(np.isfinite(run(1.0)))


@pytest.mark.parametrize("zeno", ["stop", "stick"])
def test_traced_t1_behind_direction_does_not_run(zeno):
    """A traced t1 on the other side of t0 from `direction` would run the compiled
    direction's loop the other way (it ran x'' = -g backward through the floor and ended
    BAD_JUMP at x = (-3.9, -7.8)): the lane does not start, with its own status; lanes
    with t1 on the right side, or t1 = t0, run as alone."""
    x0 = jnp.array([0.0, 0.0] if zeno == "stick" else [1.0, 0.0])  # "stick": at rest on it

    def run(t1, direction):
        return gj.simulate(BALL, x0, 0.0, t1, ARGS, direction=direction, zeno=zeno,
                           max_impacts=8)

    cases = [(1, [0.5, -1.0, 0.0], 1), (-1, [-0.5, 1.0, 0.0], 1)]
    for direction, t1s, bad in cases[:1] if zeno == "stick" else cases:  # stick: forward only
        sol = jax.jit(jax.vmap(lambda t1, d=direction: run(t1, d)))(jnp.array(t1s))
        for lane, t1 in enumerate(t1s):
            status = gj.Status(int(sol.status[lane]))
            if lane == bad:
                assert status == gj.Status.BAD_TIMES
                assert int(sol.num_impacts[lane]) == 0 and float(sol.t_final[lane]) == 0.0
                np.testing.assert_array_equal(sol.x_final[lane], x0)
            else:
                assert status != gj.Status.BAD_TIMES
                assert float(sol.t_final[lane]) == t1 or status != gj.Status.SUCCESS
    with pytest.raises(Exception, match=r"BAD_TIMES.*Fix: pass direction"):
        jax.jit(lambda t1: gj.simulate(BALL, jnp.array([1.0, 0.0]), 0.0, t1, ARGS, direction=1,
                                       throw=True).x_final)(-1.0).block_until_ready()


def test_nan_inside_jit_is_a_status_not_a_silent_answer():
    run = jax.jit(lambda x0: gj.simulate(BALL, x0, 0.0, 1.0, ARGS).status)
    assert gj.Status(int(run(jnp.array([jnp.nan, 0.0])))) == gj.Status.NONFINITE


def test_vector_field_producing_nan_ends_with_nonfinite():
    scene = gj.Scene(lambda t, x, a: jnp.stack([x[1], jnp.sqrt(x[0] - 0.5) - 9.81]), [surface()])
    sol = gj.simulate(scene, [1.0, 0.0], 0.0, 2.0, max_impacts=5)
    assert gj.Status(int(sol.status)) in (gj.Status.NONFINITE, gj.Status.STEP_SIZE_UNDERFLOW)
    assert np.all(np.isfinite(np.asarray(sol.x_final)))


def test_jump_to_nan_is_reported():
    scene = gj.Scene(field, [surface(jump=lambda t, x, a: x * jnp.nan)])
    sol = gj.simulate(scene, [1.0, 0.0], 0.0, 2.0)
    assert gj.Status(int(sol.status)) == gj.Status.NONFINITE
    assert int(sol.num_impacts) == 1


def test_jump_into_an_impenetrable_wall_is_reported():
    scene = gj.Scene(field, [surface(jump=lambda t, x, a: x.at[1].set(x[1]), impenetrable=True)])
    sol = gj.simulate(scene, [1.0, 0.0], 0.0, 2.0)
    assert gj.Status(int(sol.status)) == gj.Status.BAD_JUMP


@pytest.mark.parametrize("floor_first", [True, False])
def test_jump_into_another_impenetrable_surface_is_reported(floor_first):
    """A jump on one surface (a penetrable wall at x = 1 that moves the particle back by
    0.5) whose result is inside, or on and moving into, an impenetrable floor y = 0: the
    run ran on under the floor with SUCCESS (x_final y = -0.5). Now BAD_JUMP, whatever the
    surfaces' order; onto the floor moving out (or above it) runs on. The wall's jump
    reads its offsets (dy, dv) from `args`: one program per order runs all four."""
    field_2d = lambda t, x, a: jnp.stack([x[2], x[3], 0.0 * x[2], 0.0 * x[3]])  # noqa: E731
    floor = gj.Surface(phi=lambda t, x, a: x[1], jump=lambda t, x, a: x.at[3].set(-x[3]),
                       impenetrable=True)
    wall = gj.Surface(phi=lambda t, x, a: 1.0 - x[0],
                      jump=lambda t, x, a: jnp.stack(
                          [x[0] - 0.5, x[1] + a["dy"], -x[2], x[3] + a["dv"]]))
    scene = gj.Scene(field_2d, [floor, wall] if floor_first else [wall, floor])
    expected = {(-1.0, 0.0): "BAD_JUMP", (-0.5, -1.0): "BAD_JUMP", (-0.5, 1.0): "SUCCESS",
                (0.0, 0.0): "SUCCESS"}
    for (dy, dv), status in expected.items():
        sol = gj.simulate(scene, jnp.array([0.5, 0.5, 1.0, 0.0]), 0.0, 2.0, {"dy": dy, "dv": dv})
        assert gj.Status(int(sol.status)).name == status, (dy, dv)
        assert int(sol.num_impacts) == 1
        if status == "SUCCESS":
            assert float(sol.x_final[1]) >= 0.0


def test_max_steps_exhausted():
    sol = gj.simulate(BALL, [1.0, 0.0], 0.0, 100.0, {"g": 9.81, "e": 1.0}, max_steps=20)
    assert gj.Status(int(sol.status)) == gj.Status.MAX_STEPS
    assert int(sol.num_steps) == 20


def test_throw_raises_on_failure():
    with pytest.raises(gj.SimulationError, match="MAX_STEPS"):
        gj.simulate(BALL, [1.0, 0.0], 0.0, 100.0, {"g": 9.81, "e": 1.0}, max_steps=20, throw=True)
