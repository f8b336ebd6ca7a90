"""Error paths of the public API that no other test triggers (issue 44's test audit).

Each test calls `grazejax` the way a user does and checks the exception type and a
distinctive part of its message. Nearly all of them raise before anything is compiled;
the few that need a run (the scene-function wrappers, a periodic-orbit guess without an
impact) use the smallest scenes. The raise sites already covered elsewhere are listed in
the audit report, not tested twice.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex

BALL = ex.bouncing_ball()
ARGS = {"g": 9.81, "e": 0.8}
X0 = [1.0, 0.0]


def _surface(**kw):
    base = dict(phi=lambda t, x, a: x[0], jump=lambda t, x, a: x.at[1].set(-x[1]))
    base.update(kw)
    return gj.Surface(**base)


def _fall(t, x, a):
    return jnp.stack([x[1], -9.81 * jnp.ones_like(x[0])])


def _orbit(status=gj.OrbitStatus.SUCCESS, n=2):
    """A hand-made `gj.Orbit` (no solve): enough for the checks that read only its status,
    x0 and settings before doing any work."""
    nan = jnp.full((4,), jnp.nan)
    return gj.Orbit(
        x0=jnp.ones(n),
        t0=jnp.asarray(0.0),
        period=jnp.asarray(2 * np.pi),
        num_impacts=jnp.asarray(0),
        impact_times=nan,
        impact_pre=jnp.full((4, n), jnp.nan),
        impact_post=jnp.full((4, n), jnp.nan),
        impact_surface=jnp.full((4,), -1),
        impact_kind=jnp.full((4,), -1),
        monodromy=jnp.eye(n),
        multipliers=jnp.ones(n, complex),
        poincare_matrix=jnp.eye(n),
        poincare_determinant=jnp.asarray(1.0),
        residual=jnp.asarray(0.0),
        status=jnp.asarray(int(status)),
        fix=jnp.asarray(-1),
        num_steps=jnp.asarray(0),
        fixed_period=True,
    )


def _args_of(mu):
    return ex.ex1dof_args(mu)


# --------------------------------------------------------------- simulate: inputs ------


def test_simulate_needs_a_scene():
    with pytest.raises(TypeError, match="scene must be a grazejax.Scene, got dict"):
        gj.simulate({"not": "a scene"}, X0, 0.0, 1.0, ARGS)


@pytest.mark.parametrize("value", [0, -1, 10.5])
def test_simulate_max_steps_must_be_positive_int(value):
    with pytest.raises(ValueError, match="max_steps must be an integer >= 1"):
        gj.simulate(BALL, X0, 0.0, 1.0, ARGS, max_steps=value)


def test_simulate_refuses_to_run_in_float32_when_x64_is_off():
    # A list x0 has no dtype of its own: the check that names jax_enable_x64 is reached.
    jax.config.update("jax_enable_x64", False)
    try:
        with pytest.raises(RuntimeError, match="jax_enable_x64 is off"):
            gj.simulate(BALL, X0, 0.0, 1.0, ARGS)
    finally:
        jax.config.update("jax_enable_x64", True)


def test_simulate_rejects_complex_x0():
    with pytest.raises(TypeError, match="x0 must be real, got a complex array"):
        gj.simulate(BALL, np.array([1.0 + 0j, 0.0]), 0.0, 1.0, ARGS)


@pytest.mark.parametrize(
    "t0,t1,match",
    [
        (0.0, np.array([1.0, 2.0]), r"t0 and t1 must be scalars, got shapes \(\) and \(2,\)"),
        (np.inf, 1.0, "t0 must be finite, got inf"),
        (-np.inf, 1.0, "t0 must be finite, got -inf"),
        (0.0, np.nan, "t1 is NaN"),
    ],
)
def test_simulate_bad_times(t0, t1, match):
    with pytest.raises(ValueError, match=match):
        gj.simulate(BALL, X0, t0, t1, ARGS)


@pytest.mark.parametrize("t0,t1,direction", [(0.0, 1.0, -1), (1.0, 0.0, 1)])
def test_simulate_direction_must_agree_with_the_times(t0, t1, direction):
    with pytest.raises(ValueError, match=f"direction={direction} disagrees with t0="):
        gj.simulate(BALL, X0, t0, t1, ARGS, direction=direction)


@pytest.mark.parametrize(
    "saveat,match",
    [
        (np.array([]), r"saveat must be a non-empty 1-D array of times, got shape \(0,\)"),
        (np.array([[0.1, 0.2]]), r"non-empty 1-D array of times, got shape \(1, 2\)"),
        (np.array([0.5, 0.2]), "saveat times must be monotone"),
        (np.array([0.5, 1.5]), "saveat times must lie between t0 and t1"),
        (np.array([-0.1, 0.5]), "saveat times must lie between t0 and t1"),
        (diffrax.SaveAt(t1=True, controller_state=True), r"SaveAt\(controller_state=True\)"),
        (diffrax.SaveAt(t1=True, made_jump=True), r"SaveAt\(made_jump=True\)"),
    ],
)
def test_simulate_bad_saveat(saveat, match):
    with pytest.raises(ValueError, match=match):
        gj.simulate(BALL, X0, 0.0, 1.0, ARGS, saveat=saveat)


def test_simulate_saveat_monotone_backward():
    # Backward in time the save times must decrease: increasing ones are out of order.
    with pytest.raises(ValueError, match="monotone in the direction of integration"):
        gj.simulate(BALL, X0, 1.0, 0.0, ARGS, saveat=np.array([0.2, 0.5]))


# ---------------------------------------------------- simulate: scene functions -------


def test_phi_must_return_a_float():
    scene = gj.Scene(_fall, [_surface(phi=lambda t, x, a: jnp.int32(1))])
    with pytest.raises(TypeError, match="surface Γ1: phi must return a float, got int32"):
        gj.simulate(scene, X0, 0.0, 1.0)


def test_inverse_jump_must_keep_the_shape():
    scene = gj.Scene(_fall, [_surface(inverse_jump=lambda t, x, a: x[:1])])
    with pytest.raises(ValueError, match="surface Γ1: inverse_jump must return a state of shape"):
        gj.simulate(scene, X0, 0.0, 1.0)


def test_an_error_inside_a_scene_function_is_rethrown_with_context():
    # The same exception type, its message prefixed with the function and the state shape.
    scene = gj.Scene(_fall, [_surface(jump=lambda t, x, a: x.at[1].set(-a["e"] * x[1]))])
    with pytest.raises(KeyError, match=r"jump\(t, x, args\) failed on a state of shape \(2,\)"):
        gj.simulate(scene, X0, 0.0, 1.0, {"g": 9.81})


class _TwoPartError(Exception):
    """An exception that cannot be rebuilt from a message alone."""

    def __init__(self, code, detail):
        super().__init__(f"{code}: {detail}")
        self.code = code


def test_an_error_that_cannot_be_rebuilt_gets_a_note():
    def field(t, x, a):
        raise _TwoPartError(7, "boom")

    scene = gj.Scene(field, [_surface()])
    with pytest.raises(_TwoPartError) as info:
        gj.simulate(scene, X0, 0.0, 1.0)
    assert info.value.code == 7
    notes = getattr(info.value, "__notes__", [])
    assert any("vector_field(t, x, args) failed on a state of shape (2,)" in n for n in notes)


# ------------------------------------------------------------------------ sweep ---------


@pytest.mark.parametrize(
    "x0s,args,kwargs,match",
    [
        # args_batched with the wrong number of leaves
        (
            np.zeros((3, 2)),
            {"g": 9.81, "e": 0.8},
            dict(args_batched={"g": False}),
            "args_batched must have the structure of args",
        ),
        # a scalar leaf marked batched
        (
            np.zeros((3, 2)),
            {"g": 9.81, "e": 0.8},
            dict(args_batched={"g": True, "e": False}),
            "args leaf 1 is marked batched but is a scalar",
        ),
        # nothing carries a batch axis
        (np.array([1.0, 0.0]), None, {}, "nothing to sweep"),
        (
            np.array([1.0, 0.0]),
            {"g": 9.81, "e": 0.8},
            dict(args_batched={"g": False, "e": False}),
            "nothing to sweep",
        ),
        # one x0 for all lanes, and args leaves of two different lengths
        (
            np.array([1.0, 0.0]),
            {"g": np.full(3, 9.81), "e": np.full(4, 0.8)},
            {},
            r"cannot infer which args leaves are batched \(leading sizes \[3, 4\]\)",
        ),
        (np.ones((3, 2)), ARGS, dict(devices=[]), "devices is empty"),
    ],
)
def test_sweep_bad_batch(x0s, args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        gj.sweep(BALL, x0s, 0.0, 1.0, args, progress=False, **kwargs)


def test_sweep_nothing_to_sweep_with_scalar_args():
    with pytest.raises(ValueError, match="nothing to sweep"):
        gj.sweep(BALL, np.array([1.0, 0.0]), 0.0, 1.0, ARGS, progress=False)


def test_sweep_sets_direction_itself():
    with pytest.raises(TypeError, match="sweep sets direction itself"):
        gj.sweep(BALL, np.ones((3, 2)), 0.0, 1.0, ARGS, progress=False, direction=1)


def test_sweep_t0_equals_t1():
    with pytest.raises(ValueError, match="t0 == t1 == 1.0: nothing to simulate"):
        gj.sweep(BALL, np.ones((3, 2)), 1.0, 1.0, ARGS, progress=False)


# ----------------------------------------------------------- find_periodic_orbit -------


@pytest.mark.parametrize(
    "scene,x0,kwargs,error,match",
    [
        ("ex1dof", [2.0, 0.0], {}, TypeError, "scene must be a grazejax.Scene, got str"),
        (None, [[2.0, 0.0]], {}, ValueError, r"x0 must be a state vector of shape \(n,\)"),
        (None, [2.0, 0.0], dict(max_newton_steps=0), ValueError,
         "max_newton_steps must be a positive integer"),
        (
            None,
            [2.0, 0.0],
            dict(num_impacts=-1),
            ValueError,
            "num_impacts must be a non-negative integer",
        ),
        (
            None,
            [2.0, 0.0],
            dict(num_impacts=1.0),
            ValueError,
            "num_impacts must be a non-negative integer",
        ),
        (None, [np.nan, 0.0], {}, ValueError, "x0 contains NaN or inf"),
    ],
)
def test_find_periodic_orbit_bad_input(scene, x0, kwargs, error, match):
    scene = ex.ex1dof() if scene is None else scene
    with pytest.raises(error, match=match):
        gj.find_periodic_orbit(scene, x0, 6.0, ex.ex1dof_args(0.0), **kwargs)


def test_max_steps_of_find_periodic_orbit_is_renamed_max_newton_steps():
    # `max_steps` is simulate's solver steps; the orbit solvers' Newton iterations are
    # `max_newton_steps` (as in the continuation functions). The old keyword still works,
    # with a warning.
    with pytest.warns(DeprecationWarning, match="'max_steps' is renamed 'max_newton_steps'"):
        with pytest.raises(ValueError, match="max_newton_steps must be a positive integer"):
            gj.find_periodic_orbit(ex.ex1dof(), [2.0, 0.0], 6.0, ex.ex1dof_args(0.0),
                                   max_steps=0)


@pytest.mark.parametrize("function", ["find_periodic_orbit", "locate_bifurcation",
                                      "locate_grazing"])
def test_the_old_and_new_names_together_are_an_error(function):
    with pytest.raises(TypeError, match="got both 'max_steps' and 'max_newton_steps'"):
        getattr(gj, function)(None, None, None, None, max_steps=3, max_newton_steps=3)


def test_solver_settings_max_steps_is_a_deprecated_alias():
    settings = gj.SolverSettings(solver="default", rtol=1e-10, atol=1e-12, newton_rtol=1e-8,
                                 newton_atol=1e-8, max_newton_steps=7, max_solver_steps=10,
                                 max_impacts=4, state_scale=1.0)
    with pytest.warns(DeprecationWarning, match="renamed max_newton_steps"):
        assert settings.max_steps == 7


def test_start_at_impact_without_an_impact_near_the_period():
    # A harmonic oscillator far from its wall: the guess trajectory never impacts, so
    # start_at_impact=True cannot find the impact that closes the period.
    wall = _surface(phi=lambda t, x, a: x[0] + 10.0)
    scene = gj.Scene(lambda t, x, a: jnp.stack([x[1], -x[0]]), [wall])
    with pytest.raises(
        ValueError,
        match="start_at_impact=True but the guess trajectory has no "
        "impact near t0 \\+ T: pass num_impacts",
    ):
        gj.find_periodic_orbit(scene, [1.0, 0.0], 2 * np.pi, None, start_at_impact=True)


# ---------------------------------------------------------------- continue_orbit --------


@pytest.mark.parametrize(
    "scene,args_of,orbit,kwargs,error,match",
    [
        ("scene", _args_of, None, {}, TypeError, "scene must be a grazejax.Scene, got str"),
        (None, {"mu": 0.0}, None, {}, TypeError, "args_of must be a function mu -> args"),
        (
            None,
            _args_of,
            gj.OrbitStatus.NO_CONVERGENCE,
            {},
            ValueError,
            "the starting orbit did not converge: ",
        ),
        (
            None,
            _args_of,
            gj.OrbitStatus.SUCCESS,
            dict(ds=0.5, ds_max=0.1),
            ValueError,
            "need 0 < ds_min <= ds <= ds_max",
        ),
        (
            None,
            _args_of,
            gj.OrbitStatus.SUCCESS,
            dict(ds=0.01, ds_min=0.02),
            ValueError,
            "need 0 < ds_min <= ds <= ds_max",
        ),
        (
            None,
            _args_of,
            gj.OrbitStatus.SUCCESS,
            dict(mu_stop=0.0),
            ValueError,
            "mu_start == mu_stop: nothing to continue",
        ),
    ],
)
def test_continue_orbit_bad_input(scene, args_of, orbit, kwargs, error, match):
    scene = ex.ex1dof() if scene is None else scene
    orbit = _orbit(gj.OrbitStatus.SUCCESS if orbit is None else orbit)
    mu_stop = kwargs.pop("mu_stop", 0.3)
    with pytest.raises(error, match=match):
        gj.continue_orbit(scene, orbit, args_of, 0.0, mu_stop, progress=False, **kwargs)


def test_period_doubled_orbit_needs_a_period_doubling_point():
    fold = gj.SpecialPoint(
        kind="fold",
        mu=0.5,
        x0=np.array([1.0, 0.0]),
        t0=0.0,
        period=2.0,
        multipliers=np.array([1.0, 0.1], complex),
        num_impacts=1,
        eigenvector=np.array([1.0, 0.0]),
    )
    with pytest.raises(ValueError, match="needs a period-doubling SpecialPoint"):
        gj.period_doubled_orbit(ex.impact_oscillator(), fold, ex.impact_oscillator_args())
    # A period-doubling point without its eigenvector cannot start the branch either.
    bare = gj.SpecialPoint(
        kind="period-doubling",
        mu=0.5,
        x0=np.array([1.0, 0.0]),
        t0=0.0,
        period=2.0,
        multipliers=np.array([-1.0, 0.1], complex),
        num_impacts=1,
    )
    with pytest.raises(ValueError, match="needs a period-doubling SpecialPoint"):
        gj.period_doubled_orbit(ex.impact_oscillator(), bare, ex.impact_oscillator_args())


def test_bifurcation_diagram_measure():
    branch = gj.Branch(
        mu=np.array([0.4, 0.5]),
        period=np.full(2, 2.0),
        x0=np.ones((2, 2)),
        t0=np.zeros(2),
        multipliers=np.full((2, 2), 0.5, complex),
        num_impacts=np.ones(2, int),
        stable=np.array([True, True]),
        x_min=-np.ones((2, 2)),
        x_max=np.ones((2, 2)),
        poincare_determinant=np.ones(2),
        grazing=(),
        status=int(gj.ContinuationStatus.REACHED_STOP),
        special_points=(),
    )
    with pytest.raises(ValueError, match="measure must be 'max', 'min' or 'amplitude', got 'mean'"):
        gj.plot_bifurcation_diagram(branch, measure="mean")


# -------------------------------------------------------------- continue_grazing --------


def _args_of2(mu, nu):
    return ex.ex1dof_args(mu)


@pytest.mark.parametrize(
    "scene,args_of,kwargs,error,match",
    [
        ("scene", _args_of2, {}, TypeError, "scene must be a grazejax.Scene, got str"),
        (None, {"mu": 0.0}, {}, TypeError, r"args_of must be a function \(mu, nu\) -> args"),
        (None, _args_of2, dict(ds=0.5, ds_max=0.1), ValueError, "need 0 < ds_min <= ds <= ds_max"),
        (None, _args_of2, dict(ds_min=0.0), ValueError, "need 0 < ds_min <= ds <= ds_max"),
        (
            None,
            _args_of2,
            dict(mu_stop=0.0),
            ValueError,
            "mu_start == mu_stop: nothing to continue",
        ),
    ],
)
def test_continue_grazing_bad_input(scene, args_of, kwargs, error, match):
    scene = ex.ex1dof() if scene is None else scene
    mu_stop = kwargs.pop("mu_stop", 0.3)
    with pytest.raises(error, match=match):
        gj.continue_grazing(scene, _orbit(), args_of, 0.0, 0.0, mu_stop, progress=False, **kwargs)


def test_continue_grazing_point_must_be_a_grazing_point_or_an_orbit():
    with pytest.raises(
        TypeError, match="point must be a grazejax.GrazingPoint or a grazejax.Orbit"
    ):
        gj.continue_grazing(ex.ex1dof(), np.zeros(2), _args_of2, 0.0, 0.0, 0.3, progress=False)


def test_continue_grazing_starting_point():
    scene = ex.ex1dof()
    with pytest.raises(ValueError, match="the starting orbit did not converge"):
        gj.continue_grazing(
            scene, _orbit(gj.OrbitStatus.DIVERGED), _args_of2, 0.0, 0.0, 0.3, progress=False
        )
    point = gj.GrazingPoint(
        mu=0.0,
        orbit=_orbit(),
        surface=0,
        time=0.0,
        point=np.zeros(2),
        depth=0.0,
        impacts_before=0,
        impacts_after=1,
        kind="persistence",
    )
    with pytest.raises(ValueError, match="the grazing point is on surface 0, not 1"):
        gj.continue_grazing(scene, point, _args_of2, 0.0, 0.0, 0.3, surface=1, progress=False)


def test_continue_grazing_from_an_orbit_without_a_contact_on_the_surface():
    # The orbit's contacts are computed (one small compiled run): the harmonic oscillator's
    # circle passes its wall at depth 9 but has nothing on surface 1 (the scene has one).
    wall = _surface(phi=lambda t, x, a: x[0] + 10.0)
    scene = gj.Scene(lambda t, x, a: jnp.stack([x[1], -x[0]]), [wall])
    with pytest.raises(ValueError, match=r"the orbit has no contact \(impact or close pass\)"):
        gj.continue_grazing(
            scene, _orbit(), lambda mu, nu: None, 0.0, 0.0, 1.0, surface=1, progress=False
        )


# ---------------------------------------------------------------- linearization ---------


def test_point_functions_check_the_scene_and_the_point():
    with pytest.raises(TypeError, match="scene must be a grazejax.Scene, got list"):
        gj.saltation_matrix([], 0, 0.0, X0, ARGS)
    with pytest.raises(ValueError, match=r"surface_index must be an integer in \[0, 1\), got 0.0"):
        gj.classify_point(BALL, 0.0, 0.0, X0, ARGS)
    with pytest.raises(
        ValueError,
        match=r"x must be a state vector of shape \(n,\), got shape "
        r"\(1, 2\)",
    ):
        gj.saltation_matrix(BALL, 0, 0.0, [X0], ARGS)
    with pytest.raises(ValueError, match=r"t must be a scalar, got shape \(2,\)"):
        gj.classify_point(BALL, 0, [0.0, 1.0], X0, ARGS)


@pytest.mark.parametrize(
    "call,error,match",
    [
        (
            lambda: gj.flow_jacobian(BALL, X0, 0.0, 1.0, ARGS, wrt="t0"),
            ValueError,
            'wrt must be "x0" or "args", got \'t0\'',
        ),
        (
            lambda: gj.flow_jacobian("ball", X0, 0.0, 1.0, ARGS),
            TypeError,
            "scene must be a grazejax.Scene, got str",
        ),
        (
            lambda: gj.flow_jacobian(BALL, X0, 0.0, 1.0, None, wrt="args"),
            ValueError,
            'wrt="args" needs args',
        ),
        (
            lambda: gj.flow_jacobian(BALL, X0, 0.0, 1.0, ARGS, throw=True),
            ValueError,
            "throw=True is not supported here",
        ),
        (
            lambda: gj.scalar_gradient("not callable", BALL, X0, 0.0, 1.0, ARGS),
            TypeError,
            "loss must be a callable loss",
        ),
        (
            lambda: gj.scalar_gradient(lambda s: s.t_final, BALL, X0, 0.0, 1.0, ARGS, wrt="dt"),
            ValueError,
            'wrt must be "x0" or "args"',
        ),
        (
            lambda: gj.variational_transition(BALL, X0, 1.0, 0.0, ARGS),
            ValueError,
            r"variational_transition runs forward in time only \(t1 > t0\)",
        ),
        (
            lambda: gj.variational_transition(BALL, X0, 0.0, 1.0, ARGS, direction=-1),
            ValueError,
            "variational_transition runs forward in time only",
        ),
    ],
)
def test_run_functions_check_their_options(call, error, match):
    with pytest.raises(error, match=match):
        call()


def test_run_functions_need_direction_for_traced_times():
    run = jax.jit(lambda t1: gj.flow_jacobian(BALL, jnp.array(X0), 0.0, t1, ARGS).jacobian)
    with pytest.raises(
        ValueError,
        match=r"t0/t1 are traced \(inside jit/vmap\): pass "
        "direction=\\+1 or -1",
    ):
        run(1.0)


@pytest.mark.parametrize("function", ["one_sided_jacobians", "a2_diagnostic"])
@pytest.mark.parametrize(
    "kwargs,match",
    [
        (
            dict(direction=[0.0, 0.0]),
            r"direction must be a non-zero finite vector, got \[0.0, 0.0\]",
        ),
        (dict(direction=[np.nan, 1.0]), "direction must be a non-zero finite vector"),
        (
            dict(direction=[1.0, 0.0], distances=[1e-2, 1e-3]),
            "distances must be at least 3 positive numbers",
        ),
        (
            dict(direction=[1.0, 0.0], distances=[1e-2, 1e-3, -1e-4]),
            "distances must be at least 3 positive numbers",
        ),
    ],
)
def test_one_sided_limits_check_direction_and_distances(function, kwargs, match):
    with pytest.raises(ValueError, match=match):
        getattr(gj, function)(BALL, 0, 0.0, [0.0, 0.0], ARGS, window=0.1, **kwargs)
