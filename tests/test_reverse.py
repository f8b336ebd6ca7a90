"""Reverse-mode differentiation through impacts: `jax.grad` equals `jax.jacfwd` and the truth.

Every reverse-mode result (`adjoint=diffrax.RecursiveCheckpointAdjoint()` or
`diffrax.DirectAdjoint()`) is compared three ways: with forward mode (the default adjoint),
with a closed form (the bouncing ball's impact times and state, the saltation matrix of a
wall), and with central finite differences.

**Tolerances**, for runs at rtol = atol = TOL = 1e-12:

- reverse vs forward: both are exact derivatives of the *same* discrete scheme (same steps,
  same event times, the event time's tangent from the same Newton step), so they differ by
  the round-off of evaluating one chain rule in two orders: a few hundred ulps of the
  largest term, far below TOL. We allow `MODES = TOL` (relative to the largest entry).
- vs a closed form: the discrete scheme's derivative approximates the true derivative to
  the local tolerance TOL per step, amplified by the condition of the map (the impact
  factor 1/|∇Φ·f| and the flow Jacobian's norm, both O(1)..O(10) here) and accumulated
  over ~10² steps: `EXACT = 100 · TOL` (relative), and `EXACT / |v⁻|` where the impact
  speed v⁻ is small (grazing-near).
- vs central differences with step h: truncation h² |x'''|/6 plus the solver's
  non-smooth error TOL/h. With h = 1e-4 and |x'''| = O(10) both are ~1e-8: `FD = 1e-6`
  leaves a factor of ~30 for the O(10) constants.

Compile time dominates (each new configuration of a reverse-mode run is a program of its
own, tens of seconds to build): each (scene, mode) pair is compiled once and reused by every
check that needs it. One forward-mode program gives both jacfwd and the value
(`jacfwd_and_value`: the value as jacfwd's aux, the forward-mode loop's primal, which central
differences and closed forms are compared with), reverse-mode runs are jitted (a jitted
gradient took ~20% less CPU to build than the same `jax.grad` run op by op), and runs that
differ only in `t1` share one program (`t1` an input).
"""

import functools
import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex

from .helpers import (
    central_differences,
    clockwise,
    dip_start,
    free_fall_scene,
    projected_circle_scene,
)

TOL = 1e-12
TIGHT = dict(rtol=TOL, atol=TOL)
MODES = TOL
EXACT = 100 * TOL
FD, FD_STEP = 1e-6, 1e-4

RCA = diffrax.RecursiveCheckpointAdjoint()
DIRECT = diffrax.DirectAdjoint()
# DirectAdjoint stores every step of a loop bounded by max_steps: keep the bound near
# what the runs below need (a few hundred steps).
DIRECT_STEPS = 4000


def jacfwd_and_value(f):
    """`jit(jacfwd(f))` that also returns `f`'s value (as jacfwd's aux): `(jacobian, value)`
    from one forward-mode program, where a separate primal run would be another program to
    compile."""

    def both(*args):
        value = f(*args)
        return value, value

    return jax.jit(jax.jacfwd(both, has_aux=True))


def assert_close(actual, expected, rtol):
    """Relative to the largest entry of `expected` (entries near zero are not relative)."""
    actual, expected = np.asarray(actual), np.asarray(expected)
    scale = np.max(np.abs(expected))
    assert np.all(np.isfinite(actual)), actual
    err = np.max(np.abs(actual - expected)) / scale
    assert err <= rtol, (err, rtol, actual, expected)


# ----------------------------------------------------------- bouncing ball --------------

BALL = ex.bouncing_ball()
BALL_T = 2.0  # between the third (1.75) and fourth (2.21) impact from (1, 0), e = 0.8
BALL_P = np.array([1.0, 0.0, 9.81, 0.8])  # (h, v0, g, e)


def ball_loss_exact(p):
    """x(T)[0] + x(T)[1]/2 + t_3 in closed form (three impacts before T)."""
    h, v0, g, e = p[0], p[1], p[2], p[3]
    w = jnp.sqrt(v0 * v0 + 2 * g * h)
    t3 = (v0 + w) / g + 2 * w * (e + e * e) / g
    s = BALL_T - t3
    x = e**3 * w * s - g * s * s / 2
    v = e**3 * w - g * s
    return x + v / 2 + t3


def ball_loss(p, adjoint, max_steps=100_000):
    args = {"g": p[2], "e": p[3]}
    sol = gj.simulate(
        BALL, p[:2], 0.0, BALL_T, args, adjoint=adjoint, max_steps=max_steps, max_impacts=8, **TIGHT
    )
    return sol.x_final[0] + sol.x_final[1] / 2 + sol.impact_times[2]


# (jacobian, value): one forward-mode program for jacfwd, the primal and central differences.
ball_fwd = jacfwd_and_value(lambda p: ball_loss(p, None))
ball_rca = jax.jit(jax.grad(lambda p: ball_loss(p, RCA)))


def ball_primal(p):
    return ball_fwd(p)[1]


def test_ball_grad_equals_jacfwd_closed_form_and_differences():
    p = jnp.asarray(BALL_P)
    exact = jax.grad(ball_loss_exact)(p)
    reverse, (forward, value) = ball_rca(p), ball_fwd(p)
    np.testing.assert_allclose(value, ball_loss_exact(p), rtol=EXACT)
    assert_close(reverse, forward, MODES)
    assert_close(reverse, exact, EXACT)
    assert_close(reverse, central_differences(ball_primal, BALL_P, FD_STEP), FD)


def test_ball_direct_adjoint_grad_and_jacfwd():
    """DirectAdjoint supports both modes, with the same values."""
    p = jnp.asarray(BALL_P)
    loss = lambda q: ball_loss(q, DIRECT, DIRECT_STEPS)  # noqa: E731
    reverse = jax.jit(jax.grad(loss))(p)
    forward = jax.jit(jax.jacfwd(loss))(p)
    assert_close(reverse, ball_fwd(p)[0], MODES)
    assert_close(forward, ball_fwd(p)[0], MODES)


def test_ball_grad_under_vmap_and_jit():
    """Lanes with different impact times (three impacts before T in each): each lane's
    gradient is its own."""
    ps = jnp.asarray([BALL_P, [1.2, 0.3, 9.81, 0.8], [0.9, -0.2, 9.5, 0.8]])
    batched = jax.jit(jax.vmap(jax.grad(lambda p: ball_loss(p, RCA))))(ps)
    for lane, p in enumerate(ps):
        assert_close(batched[lane], jax.grad(ball_loss_exact)(p), EXACT)
    assert_close(batched[0], ball_rca(ps[0]), MODES)
    # Every step stored, under vmap (as carries: `storing_limit`; the log in the carry).
    every = diffrax.RecursiveCheckpointAdjoint(checkpoints=DIRECT_STEPS)
    stored = jax.jit(jax.vmap(jax.grad(lambda p: ball_loss(p, every, DIRECT_STEPS))))(ps)
    assert_close(stored, batched, MODES)


# ------------------------------------------------------------- wall saltation -------------

B, R = 0.5, 0.8  # rotation about (B, 0); wall Φ = x1 with restitution R
WALL_X0, WALL_T = np.array([1.0, -1.0]), 2.5  # one impact, at t ≈ 0.93


def _wall_scene():
    def vector_field(t, x, args):
        return jnp.stack([x[1], args["b"] - x[0]])

    wall = gj.Surface(
        phi=lambda t, x, args: x[0],
        jump=lambda t, x, args: x.at[1].set(-args["r"] * x[1]),
        inverse_jump=lambda t, x, args: x.at[1].set(-x[1] / args["r"]),
    )
    return gj.Scene(vector_field, [wall])


WALL = _wall_scene()
WALL_ARGS = {"b": jnp.asarray(B), "r": jnp.asarray(R)}


def rotation(s):
    return np.array([[math.cos(s), math.sin(s)], [-math.sin(s), math.cos(s)]])


def wall_jacobian_exact(x0, T):
    """∂x(T)/∂x0 = R(T − t1) S R(t1), S = [[−r, 0], [(a⁺ + r a⁻)/v⁻, −r]], a± = b at x1 = 0.

    x1(t) − b = ρ cos(t − φ); the impact is the decreasing root of x1 = 0.
    """
    rho = math.hypot(x0[0] - B, x0[1])
    phi = math.atan2(x0[1], x0[0] - B)
    t1 = phi + math.acos(-B / rho)
    v_minus = -rho * math.sin(t1 - phi)
    S = np.array([[-R, 0.0], [(B + R * B) / v_minus, -R]])
    return rotation(T - t1) @ S @ rotation(t1)


def wall_final(x0, adjoint, max_steps=100_000):
    sol = gj.simulate(
        WALL,
        x0,
        0.0,
        WALL_T,
        WALL_ARGS,
        adjoint=adjoint,
        max_steps=max_steps,
        max_impacts=4,
        **TIGHT,
    )
    return sol.x_final


def test_wall_saltation_reverse_forward_exact_differences():
    x0 = jnp.asarray(WALL_X0)
    exact = wall_jacobian_exact(WALL_X0, WALL_T)
    reverse = jax.jit(jax.jacrev(lambda x: wall_final(x, RCA)))(x0)
    # (jacobian, value): the differences below run the same forward-mode program.
    forward_and_value = jacfwd_and_value(lambda x: wall_final(x, None))
    forward = forward_and_value(x0)[0]
    assert_close(reverse, forward, MODES)
    assert_close(reverse, exact, EXACT)
    primal = lambda x: forward_and_value(x)[1]  # noqa: E731
    assert_close(reverse, central_differences(primal, WALL_X0, FD_STEP), FD)


@pytest.mark.slow  # a bounded-loop compile of its own
def test_wall_saltation_direct_adjoint():
    x0 = jnp.asarray(WALL_X0)
    run = lambda x: wall_final(x, DIRECT, DIRECT_STEPS)  # noqa: E731
    exact = wall_jacobian_exact(WALL_X0, WALL_T)
    assert_close(jax.jit(jax.jacrev(run))(x0), exact, EXACT)
    assert_close(jax.jit(jax.jacfwd(run))(x0), exact, EXACT)


# ------------------------------------------------------- projected flow (Scene.project) ----

CIRCLE = projected_circle_scene()
CIRCLE_THETA0, CIRCLE_T = 1.0, 4.0  # one impact, at t = θ0
CIRCLE_P = np.array([math.cos(CIRCLE_THETA0), math.sin(CIRCLE_THETA0), 0.3])  # (x0, α)


def circle_final(p, adjoint):
    sol = gj.simulate(CIRCLE, p[:2], 0.0, CIRCLE_T, {"alpha": p[2]}, adjoint=adjoint,
                      max_impacts=4, **TIGHT)
    return sol.x_final


def test_projected_run_reverse_forward_exact_differences():
    """Through `project` (x/|x| after every step) and an impact: x(t1) = R(−(t1 + α)) x0/|x0|,
    so ∂x(t1)/∂x0 = R(−(t1 + α))(I − x0 x0ᵀ) and ∂x(t1)/∂α = (sin(θ0 − t1 − α),
    −cos(θ0 − t1 − α)) (`projected_circle_scene`)."""
    p = jnp.asarray(CIRCLE_P)
    x0, alpha = CIRCLE_P[:2], CIRCLE_P[2]
    angle = CIRCLE_THETA0 - CIRCLE_T - alpha
    exact = np.column_stack([clockwise(CIRCLE_T + alpha) @ (np.eye(2) - np.outer(x0, x0)),
                             [math.sin(angle), -math.cos(angle)]])
    reverse = jax.jit(jax.jacrev(lambda q: circle_final(q, RCA)))(p)
    forward_and_value = jacfwd_and_value(lambda q: circle_final(q, None))
    forward, value = forward_and_value(p)
    np.testing.assert_allclose(value, clockwise(CIRCLE_T + alpha) @ x0, atol=EXACT)
    assert_close(reverse, forward, MODES)
    assert_close(reverse, exact, EXACT)
    primal = lambda q: forward_and_value(q)[1]  # noqa: E731
    assert_close(reverse, central_differences(primal, CIRCLE_P, FD_STEP), FD)


# ------------------------------------------------------------ forced oscillator -----------

OSC = ex.impact_oscillator()
OSC_NAMES = ("zeta", "A", "omega", "sigma", "r")
OSC_P = np.array([0.05, 1.0, 1.5, 0.2, 0.8])
OSC_T = 12.0


def osc_loss(p, adjoint, max_steps=100_000):
    """Sum of the first three impact times plus the final state, as a function of args."""
    args = dict(zip(OSC_NAMES, p, strict=True))
    sol = gj.simulate(
        OSC,
        jnp.zeros(2),
        0.0,
        OSC_T,
        args,
        adjoint=adjoint,
        max_steps=max_steps,
        max_impacts=16,
        **TIGHT,
    )
    return jnp.sum(sol.impact_times[:3]) + sol.x_final[0] + sol.x_final[1]


def test_forced_oscillator_grad_equals_jacfwd_and_differences():
    p = jnp.asarray(OSC_P)
    reverse = jax.jit(jax.grad(lambda q: osc_loss(q, RCA)))(p)
    # (jacobian, value): the differences below run the same forward-mode program.
    forward_and_value = jacfwd_and_value(lambda q: osc_loss(q, None))
    forward = forward_and_value(p)[0]
    primal = lambda q: forward_and_value(q)[1]  # noqa: E731
    assert_close(reverse, forward, MODES)
    assert_close(reverse, central_differences(primal, OSC_P, FD_STEP), FD)


# -------------------------------------------------------------- harder runs ---------------


@pytest.mark.slow  # three compiles (~35 s on two shared cores)
def test_grazing_near_impact():
    """A parabola dipping δ = 1e-6 below the floor: t_hit = 2h/(−v0 + √(2aδ)), with an impact
    speed √(2aδ) ≈ 1.4e-3, so ∂t_hit/∂x0 ~ 1/|v⁻| ≈ 700: the tolerance scales with it."""
    a, v0, delta = 1.0, -1.0, 1e-6
    scene = free_fall_scene(restitution=0.8)
    x0, t_hit, v_minus = dip_start(delta, a, v0)

    def first_time(x, adjoint):
        sol = gj.simulate(scene, x, 0.0, 2.5, {"a": a}, adjoint=adjoint, max_impacts=4, **TIGHT)
        return sol.impact_times[0]

    def exact(x):
        return 2 * x[0] / (-x[1] + jnp.sqrt(x[1] ** 2 - 2 * a * x[0]))

    x = jnp.asarray(x0)
    # (gradient, value) from one forward-mode program
    forward, value = jacfwd_and_value(lambda y: first_time(y, None))(x)
    np.testing.assert_allclose(value, t_hit, rtol=EXACT / abs(v_minus))
    reverse = jax.jit(jax.grad(lambda y: first_time(y, RCA)))(x)
    assert_close(reverse, forward, MODES / abs(v_minus))
    assert_close(reverse, jax.grad(exact)(x), EXACT / abs(v_minus))


@pytest.mark.slow  # two compiles of the sticking loop
def test_zeno_sticking_run():
    """A ball that comes to rest (zeno="stick"): the first impact times keep their closed-form
    gradients, and reverse equals forward through the sliding phase."""
    T = 6.0  # accumulation at ≈ 4.06 from (1, 0), e = 0.8

    def loss(p, adjoint):
        sol = gj.simulate(
            BALL,
            p[:2],
            0.0,
            T,
            {"g": p[2], "e": p[3]},
            adjoint=adjoint,
            zeno="stick",
            max_impacts=200,
            **TIGHT,
        )
        return jnp.sum(sol.impact_times[:5]) + sol.x_final[0], sol

    def exact(p):
        h, v0, g, e = p[0], p[1], p[2], p[3]
        w = jnp.sqrt(v0 * v0 + 2 * g * h)
        flights = jnp.cumsum(jnp.asarray([0.0] + [2 * w * e**k / g for k in range(1, 5)]))
        return jnp.sum((v0 + w) / g + flights)

    def loss_and_aux(q):  # (value, (value, sol)): jacfwd's aux, from one forward-mode program
        value, sol = loss(q, None)
        return value, (value, sol)

    p = jnp.asarray(BALL_P)
    forward, (value, sol) = jax.jit(jax.jacfwd(loss_and_aux, has_aux=True))(p)
    kinds = np.asarray(sol.impact_kind[: int(sol.num_impacts)])
    assert int(gj.ImpactKind.STICK) in kinds, kinds
    np.testing.assert_allclose(value, exact(p), rtol=EXACT)
    reverse = jax.jit(jax.grad(lambda q: loss(q, RCA)[0]))(p)
    assert_close(reverse, forward, MODES)
    assert_close(reverse, jax.grad(exact)(p), EXACT)


@pytest.mark.slow  # two compiles of the backward loop (~45 s on two shared cores)
def test_backward_time_inverts_the_forward_jacobian():
    """t1 < t0: from x(T) back to t = 0 through the image surface. The Jacobian is the
    inverse of the forward one (closed form, through three impacts)."""

    def forward_map(x0):
        h, v0 = x0[0], x0[1]
        g, e = 9.81, 0.8
        w = jnp.sqrt(v0 * v0 + 2 * g * h)
        s = BALL_T - (v0 + w) / g - 2 * w * (e + e * e) / g
        return jnp.stack([e**3 * w * s - g * s * s / 2, e**3 * w - g * s])

    x0 = jnp.asarray(BALL_P[:2])
    xT = forward_map(x0)
    args = {"g": jnp.asarray(9.81), "e": jnp.asarray(0.8)}

    def back(y, adjoint):
        return gj.simulate(
            BALL, y, BALL_T, 0.0, args, adjoint=adjoint, max_impacts=8, **TIGHT
        ).x_final

    exact = np.linalg.inv(np.asarray(jax.jacfwd(forward_map)(x0)))
    reverse = jax.jit(jax.jacrev(lambda y: back(y, RCA)))(xT)
    forward = jax.jit(jax.jacfwd(lambda y: back(y, None)))(xT)
    assert_close(reverse, forward, MODES)
    assert_close(reverse, exact, EXACT)


# ------------------------------------------------------------- equilibrium ----------------

SPRING = gj.Scene(lambda t, x, args: jnp.stack([x[1], -x[0]]), [])


def test_equilibrium_jacobian_is_identity_in_both_modes():
    """x'' = −x over 2π from the equilibrium: ∂x(2π)/∂x0 = R(2π) = I. The step size must not
    leak state derivatives where the error norm is zero (once [[−16, −3.2], [3.2, −16]])."""

    def final(x, adjoint):
        return gj.simulate(SPRING, x, 0.0, 2 * math.pi, adjoint=adjoint, **TIGHT).x_final

    x0 = jnp.zeros(2)
    # The flow is linear: its Jacobian is R(2π) = I up to the accumulated local error.
    assert_close(jax.jit(jax.jacfwd(lambda x: final(x, None)))(x0), np.eye(2), EXACT)
    assert_close(jax.jit(jax.jacrev(lambda x: final(x, RCA)))(x0), np.eye(2), EXACT)


def test_periodic_orbit_at_an_equilibrium_has_unit_multipliers():
    orbit = gj.find_periodic_orbit(SPRING, [0.0, 0.0], 2 * math.pi, fixed_period=True)
    np.testing.assert_allclose(np.asarray(orbit.multipliers), [1.0, 1.0], atol=EXACT)


# ----------------------------------------------------------------- errors -----------------


def test_default_adjoint_grad_names_the_fix():
    loss = lambda x: gj.simulate(SPRING, x, 0.0, 1.0).x_final[0]  # noqa: E731
    with pytest.raises(RuntimeError, match=r"adjoint=diffrax\.RecursiveCheckpointAdjoint\(\)"):
        jax.grad(loss)(jnp.array([1.0, 0.0]))


def test_unsupported_adjoint_is_a_value_error():
    with pytest.raises(ValueError, match="BacksolveAdjoint"):
        gj.simulate(SPRING, [1.0, 0.0], 0.0, 1.0, adjoint=diffrax.BacksolveAdjoint())


# ------------------------------------------------- the analysis functions' adjoint ---------


def third_impact_time(sol):
    return sol.impact_times[2]


def test_scalar_gradient_and_flow_jacobian_in_reverse_mode():
    """With a reverse-only adjoint both must differentiate backward (jacfwd would raise):
    ∂t_3/∂e = 2w(1 + 2e)/g, and the wall's Jacobian is R(T − t1) S R(t1)."""
    h, g, e = 1.0, 9.81, 0.8
    args = {"g": jnp.asarray(g), "e": jnp.asarray(e)}
    r = gj.scalar_gradient(
        third_impact_time, BALL, [h, 0.0], 0.0, 2.0, args, wrt="args", adjoint=RCA, **TIGHT
    )
    assert int(r.status) == gj.DerivativeStatus.OK
    w = math.sqrt(2 * g * h)
    np.testing.assert_allclose(r.grad["e"], 2 * w * (1 + 2 * e) / g, rtol=EXACT)
    j = gj.flow_jacobian(WALL, WALL_X0, 0.0, WALL_T, WALL_ARGS, adjoint=RCA, **TIGHT)
    assert int(j.status) == gj.DerivativeStatus.OK
    assert_close(j.jacobian, wall_jacobian_exact(WALL_X0, WALL_T), EXACT)


def test_sweep_checks_the_adjoint_and_runs_the_primal():
    x0s = np.array([[1.0, 0.0], [0.7, 0.5]])
    args = {"g": 9.81, "e": 0.8}
    plain = gj.sweep(BALL, x0s, 0.0, 2.0, args, progress=False, max_impacts=8)
    with_adjoint = gj.sweep(BALL, x0s, 0.0, 2.0, args, progress=False, max_impacts=8, adjoint=RCA)
    np.testing.assert_array_equal(with_adjoint.x_final, plain.x_final)
    with pytest.raises(ValueError, match="BacksolveAdjoint"):
        gj.sweep(BALL, x0s, 0.0, 2.0, args, progress=False, adjoint=diffrax.BacksolveAdjoint())


@pytest.mark.slow  # the period map compiled in a bounded loop, then transposed
def test_periodic_orbit_grad_with_direct_adjoint():
    """The forced oscillator's non-impacting orbit (stop far away) is x_p(0) = (a, bω), with
    a = A(1 − ω²)/D: ∂a/∂A = (1 − ω²)/D, by jax.grad through Newton's implicit adjoint."""
    base = ex.impact_oscillator_args(sigma=5.0)
    period = 2 * math.pi / float(base["omega"])

    def start(A, adjoint):
        orbit = gj.find_periodic_orbit(
            OSC,
            [0.8, 0.0],
            period,
            dict(base, A=A),
            fixed_period=True,
            start_at_impact=False,
            adjoint=adjoint,
            rtol=TOL,
            atol=TOL,
        )
        return orbit.x0[0]

    w, z = float(base["omega"]), float(base["zeta"])
    D = (1 - w * w) ** 2 + (2 * z * w) ** 2
    grad = jax.grad(lambda A: start(A, DIRECT))(jnp.asarray(1.0))
    np.testing.assert_allclose(grad, (1 - w * w) / D, rtol=EXACT)
    with pytest.raises(ValueError, match="DirectAdjoint"):
        start(jnp.asarray(1.0), RCA)


def test_saved_states_grad_equals_jacfwd():
    """`saveat` in reverse mode: the saved states' gradient equals jacfwd's and central
    differences, for save times inside flights, at an impact's flight, at t0 and at t1
    (it was NaN: steps without saves evaluated the interpolant at s = -inf, and a zero
    cotangent times an infinite partial is NaN), also under vmap. Four reverse-mode programs
    (the default two levels, every step stored, `DirectAdjoint`, the default batched: each
    a loop of its own); one forward-mode program gives jacfwd, the values the differences
    take, and each lane's jacfwd (the batched gradient is compared lane by lane, relative
    to the lane's own largest entry). Every step stored gives the default schedule's
    gradient (the check `test_checkpoints_at_max_steps_mean_every_step` made with a program
    of its own)."""
    ts = jnp.array([0.0, 0.5, 1.0, 1.6, BALL_T])

    def saved(q, adjoint, max_steps=100_000):
        sol = gj.simulate(BALL, q[:2], 0.0, BALL_T, {"g": q[2], "e": q[3]}, adjoint=adjoint,
                          max_steps=max_steps, max_impacts=8, saveat=ts, **TIGHT)
        return jnp.sum(sol.xs * jnp.array([1.0, 0.5]))

    p = jnp.asarray(BALL_P)
    forward_and_value = jacfwd_and_value(lambda q: saved(q, None))
    forward = forward_and_value(p)[0]
    assert np.all(np.isfinite(forward))
    primal = lambda q: forward_and_value(q)[1]  # noqa: E731
    assert_close(forward, central_differences(primal, BALL_P, FD_STEP), FD)
    every = diffrax.RecursiveCheckpointAdjoint(checkpoints=DIRECT_STEPS)
    reverse = {}
    for name, adjoint, steps in (("default", RCA, 100_000), ("every step", every, DIRECT_STEPS),
                                 ("direct", DIRECT, DIRECT_STEPS)):
        reverse[name] = jax.jit(jax.grad(lambda q, a=adjoint, m=steps: saved(q, a, m)))(p)
        assert_close(reverse[name], forward, MODES)
    # every step stored: the default schedule's gradient (test_checkpoints_at_max_steps...)
    assert_close(reverse["every step"], reverse["default"], MODES)
    ps = jnp.stack([p, p * jnp.array([1.1, 1.0, 1.0, 0.95])])
    batched = jax.jit(jax.vmap(jax.grad(lambda q: saved(q, RCA))))(ps)
    for lane in range(2):
        assert_close(batched[lane], forward_and_value(ps[lane])[0], MODES)


def test_recomputed_steps_replay_the_first_pass():
    """Reverse mode runs steps again from checkpoints (the default two levels, Equinox's
    schedule of `c` checkpoints, `DirectAdjoint`'s nested scans), in another compiled
    program whose fusions round the stages differently in the last bits. The step-size
    controller amplifies that (its error estimate is a difference of nearly equal stage
    sums), so a re-run took other steps and the gradient was that of a trajectory stitched
    from mismatched pieces: on this long impact-free flight grad differed from jacfwd by
    up to 3.3e-8 (default), 5.1e-6 (30 checkpoints) and 7.4e-9 (Direct) relative before
    the re-runs replayed the first pass's step decisions. Now: round-off (`MODES`)."""
    scene = gj.Scene(lambda t, x, a: jnp.stack([x[1], -a["k"] * x[0]]), [])

    def final(p, t1, adjoint):
        sol = gj.simulate(scene, p[:2], 0.0, t1, {"k": p[2]}, adjoint=adjoint,
                          max_steps=4000, direction=-1, **TIGHT)
        return jnp.sum(sol.x_final)

    p = jnp.array([0.1, 0.3, 1.0])
    forward = jax.jit(jax.jacfwd(lambda q, t1: final(q, t1, None)))
    for adjoint in (RCA, diffrax.RecursiveCheckpointAdjoint(30), DIRECT):
        reverse = jax.jit(jax.grad(lambda q, t1, a=adjoint: final(q, t1, a)))
        for t1 in (-10.0, -25.0, -40.0):
            assert_close(reverse(p, t1), forward(p, t1), MODES)
    # Batched, the default's chunks store carries (Equinox's loop) and replay the same way.
    starts = jnp.stack([p, jnp.array([0.2, -0.1, 1.1])])
    batched = jax.jit(jax.vmap(jax.grad(lambda q: final(q, -40.0, RCA))))(starts)
    for lane in range(2):
        assert_close(batched[lane], forward(starts[lane], -40.0), MODES)


def test_simultaneous_impacts_overflowing_the_log():
    """Two walls met at the same instant with room for one log row: the run ends
    MAX_IMPACTS, and reverse mode (whose log is a write-once buffer) gives jacfwd's
    gradient of the logged impact and the final state (the overflowing row is not written
    twice). The status and the logged surface are those of the forward-mode loop (jacfwd's
    aux) and of the reverse-mode loop (the gradient's aux): one program per mode."""
    def field(t, x, a):
        return jnp.stack([x[2], x[3], 0.0 * x[2], -a["g"] + 0.0 * x[3]])

    floor = gj.Surface(phi=lambda t, x, a: x[1], jump=lambda t, x, a: x.at[3].set(-a["e"] * x[3]))
    wall = gj.Surface(phi=lambda t, x, a: x[0], jump=lambda t, x, a: x.at[2].set(-a["e"] * x[2]))
    scene = gj.Scene(field, [floor, wall])
    g, e = 9.81, 0.8
    t_hit = 0.5
    # x reaches 0 at t_hit with speed 1; y falls from g t_hit²/2 and meets 0 at t_hit too.
    x0 = np.array([t_hit, g * t_hit**2 / 2, -1.0, 0.0])

    def loss(p, adjoint):
        sol = gj.simulate(scene, p[:4], 0.0, 2.0, {"g": g, "e": p[4]}, adjoint=adjoint,
                          max_impacts=1, **TIGHT)
        return sol.impact_times[0] + jnp.sum(sol.impact_post[0]), sol

    p = jnp.asarray(np.append(x0, e))
    forward, sol = jax.jit(jax.jacfwd(lambda q: loss(q, None), has_aux=True))(p)
    (_, reverse_sol), reverse = jax.jit(
        jax.value_and_grad(lambda q: loss(q, RCA), has_aux=True))(p)
    for run in (sol, reverse_sol):
        assert gj.Status(int(run.status)) == gj.Status.MAX_IMPACTS
        assert int(run.impact_surface[0]) == 0  # the log keeps the first row (scene order)
    assert_close(reverse, forward, MODES)


def test_checkpoints_at_max_steps_mean_every_step():
    """`checkpoints >= max_steps` stores every one of the loop's max_steps + 1 iterations
    (see `_loop/reverse.py: checkpoint_count`), with the same gradient as the default schedule.

    That last comparison is made in `test_saved_states_grad_equals_jacfwd` (the ball with
    `checkpoints=DIRECT_STEPS` and the default schedule, both programs built there, each
    also compared with jacfwd): here it was a program of its own, the same loop
    (`every_step_stored`, unbatched, the log not staged) without `saveat`. Here: the counts,
    and a run that stops at MAX_STEPS against jacfwd.

    The reverse-mode loop sees the adjoint's `checkpoints` only through `checkpoint_count`
    (`_loop/runners.py: CheckpointedLoop.run`), so `checkpoints=6` and `checkpoints=100` at
    `max_steps=6` build the same program: asserting that both count 7 and differentiating
    one of them checks what differentiating both did (each was a program to build)."""
    from grazejax._loop.reverse import checkpoint_count

    assert checkpoint_count(None, 100) is None
    assert checkpoint_count(30, 100) == 30
    assert checkpoint_count(100, 100) == checkpoint_count(10**6, 100) == 101
    assert checkpoint_count(6, 6) == checkpoint_count(100, 6) == 7
    p = jnp.asarray(BALL_P)

    # A run that stops at MAX_STEPS uses the loop's extra iteration, the one the count adds.
    def state_sum(q, adjoint):
        sol = gj.simulate(BALL, q[:2], 0.0, BALL_T, {"g": q[2], "e": q[3]}, adjoint=adjoint,
                          max_steps=6, max_impacts=8, **TIGHT)
        return jnp.sum(sol.x_final), sol.status

    # (derivative, status) from one program per mode
    forward, status = jax.jit(jax.jacfwd(lambda q: state_sum(q, None), has_aux=True))(p)
    assert int(status) == gj.Status.MAX_STEPS
    adjoint = diffrax.RecursiveCheckpointAdjoint(checkpoints=6)
    (_, status), reverse = jax.jit(
        jax.value_and_grad(lambda q: state_sum(q, adjoint), has_aux=True))(p)
    assert int(status) == gj.Status.MAX_STEPS
    assert_close(reverse, forward, MODES)


# Both ways of storing every step in reverse mode: each step's linearisation (small
# residuals, `_loop/stored.py`) or its carry (Equinox's checkpointed loop), whichever
# `storing_limit` picks for a scene; both must give jacfwd's gradients. JAX's caches are
# cleared around each, as `simulate`'s compiled programs do not depend on the threshold.
@pytest.fixture(params=[True, False], ids=["linearisations", "carries"])
def stores(request, monkeypatch):
    import grazejax._loop.reverse as reverse_module

    jax.clear_caches()
    request.addfinalizer(jax.clear_caches)
    monkeypatch.setattr(reverse_module, "_STORED_RESIDUAL_BYTES",
                        10**9 if request.param else -1)
    return request.param


# Forward-mode results (jacfwd and the forward-mode loop's primal, its aux) do not depend on
# how reverse mode stores its steps: each is computed for the first `stores` parameter and
# reused by the second, which would otherwise trace and compile it again after
# `jax.clear_caches`.
_FORWARD_RESULTS = {}


def forward_once(key, compute):
    if key not in _FORWARD_RESULTS:
        _FORWARD_RESULTS[key] = jax.tree.map(np.asarray, compute())
    return _FORWARD_RESULTS[key]


def _spy_on_stage_log(monkeypatch):
    """The rows of each call of `_loop/reverse.py`'s `stage_log` (made while a reverse-mode
    loop that stages the log is traced: at a jitted program's first call)."""
    import grazejax._loop.reverse as reverse_module

    taken = []
    original = reverse_module.stage_log
    monkeypatch.setattr(
        reverse_module, "stage_log", lambda c, rows: taken.append(rows) or original(c, rows)
    )
    return taken


_SOLUTION_FIELDS = ("t_final", "x_final", "num_impacts", "impact_times", "impact_pre",
                    "impact_kind", "impact_surface", "status")


def test_every_step_checkpoints_with_the_log_staged(monkeypatch, stores):
    """`checkpoints >= max_steps` with a log over 512 bytes: one loop, every step's
    linearisation stored, the log staged (`every_step_stored`: the rows a step staged
    move to the full log, a write-once buffer, after it). The same primal results as the
    forward-mode loop, and jacfwd's gradients: plain impacts, MAX_STEPS, sliding
    (STICK/RELEASE rows) and two rows from one landing (simultaneous impacts).

    What is compared, exactly (bit for bit): the loop without derivatives (the every-step
    adjoint's run, `stored_while_loop`'s primal or Equinox's loop undifferentiated) against
    a plain run of the forward-mode loop, as before; and, from the same programs as the
    gradients (the Solution as aux), the primal of the run the gradient differentiates
    (reverse mode's forward pass, with its extra block writes of the log,
    `_loop/stored.py`) against jacfwd's primal. (The differentiated and the
    undifferentiated runs differ in the last bits at the sliding run's rest state,
    x ≈ 1e-16 against 1e-22, so each is compared with its own kind.) The ball's plain,
    sliding and MAX_STEPS runs share their programs (`zeno="stick"`, `max_steps=150`; `t1`
    and the parameters are inputs): to T = 2 the run has three plain impacts (10 steps);
    to T = 6 it sticks after 64 impacts (136 steps, then no more); with e = 0.85 it still
    bounces at step 150 (it would stick after 182), and stops at MAX_STEPS there. (They
    were three programs: `zeno="stop"` with max_steps 60 and 6, `zeno="stick"` with 2000.)
    Each reverse-mode program stages the log (`taken`, asserted where it is traced, at its
    first call)."""
    taken = _spy_on_stage_log(monkeypatch)
    p = jnp.asarray(BALL_P)

    def ball(q, t1, adjoint, max_steps, zeno):
        return gj.simulate(BALL, q[:2], 0.0, t1, {"g": q[2], "e": q[3]}, adjoint=adjoint,
                           max_steps=max_steps, max_impacts=100, zeno=zeno, direction=1,
                           **TIGHT)

    def walls(q, t1, adjoint, max_steps):
        field = lambda t, x, a: jnp.stack([x[2], x[3], 0.0 * x[2], -a["g"] + 0.0 * x[3]])  # noqa: E731
        floor = gj.Surface(phi=lambda t, x, a: x[1], jump=lambda t, x, a: x.at[3].set(-a["e"] * x[3]))
        wall = gj.Surface(phi=lambda t, x, a: x[0], jump=lambda t, x, a: x.at[2].set(-a["e"] * x[2]))
        return gj.simulate(gj.Scene(field, [floor, wall]), q[:4], 0.0, t1,
                           {"g": 9.81, "e": q[4]}, adjoint=adjoint, max_steps=max_steps,
                           max_impacts=40, direction=1, **TIGHT)

    bouncier = p.at[3].set(0.85)
    programs = [  # (run, max_steps, [(name, inputs, t1, status), ...])
        (functools.partial(ball, zeno="stick"), 150,
         [("plain", p, BALL_T, gj.Status.SUCCESS), ("sliding", p, 6.0, gj.Status.SUCCESS),
          ("max steps", bouncier, 6.0, gj.Status.MAX_STEPS)]),
        (walls, 100, [("simultaneous", jnp.array([0.5, 9.81 * 0.5**2 / 2, -1.0, 0.0, 0.8]),
                       0.8, gj.Status.SUCCESS)]),
    ]
    for run, max_steps, ends in programs:
        every = diffrax.RecursiveCheckpointAdjoint(checkpoints=max_steps)

        def loss(z, t1, adjoint, run=run, max_steps=max_steps):
            sol = run(z, t1, adjoint, max_steps)
            return jnp.nansum(sol.impact_times) + jnp.sum(sol.x_final), sol

        jacfwd = jax.jit(jax.jacfwd(lambda z, t1, loss=loss: loss(z, t1, None), has_aux=True))
        reverse = jax.jit(jax.value_and_grad(lambda z, t1, loss=loss, every=every:
                                             loss(z, t1, every), has_aux=True))
        for call, (name, q, t1, status) in enumerate(ends):
            # (plain runs: one compiled program per run, `q` and `t1` among its inputs)
            (jacobian, differentiated), plain = forward_once(
                ("staged", name),
                lambda jacfwd=jacfwd, run=run, q=q, t1=t1, m=max_steps: (
                    jacfwd(q, t1), run(q, t1, None, m)))
            assert gj.Status(int(plain.status)) == status
            kinds = plain.impact_kind[: int(plain.num_impacts)]
            # sliding: STICK rows; the others: plain impacts only (max steps: before sticking)
            assert (int(gj.ImpactKind.STICK) in kinds) == (name == "sliding"), kinds
            taken.clear()
            checkpointed = run(q, t1, every, max_steps)
            assert bool(taken) or call > 0  # the staged every-step loop (traced at call 0)
            taken.clear()
            (_, checkpointed_differentiated), gradient = reverse(q, t1)
            assert bool(taken) or call > 0
            for field in _SOLUTION_FIELDS:
                np.testing.assert_array_equal(getattr(checkpointed, field),
                                              getattr(plain, field))
                np.testing.assert_array_equal(getattr(checkpointed_differentiated, field),
                                              getattr(differentiated, field))
            assert_close(gradient, jacobian, MODES)


def test_default_checkpoints_two_levels(monkeypatch, stores):
    """`RecursiveCheckpointAdjoint()` runs two levels of loops, chunks of ~√max_steps
    steps that store their steps' linearisations (`two_level_checkpointed`; with a log over 512 bytes its
    outer iterations also end at each landing with rows, the log staged). Small `max_steps` so that chunks end inside flights: gradients equal
    jacfwd's, also for runs that end at MAX_STEPS and at MAX_IMPACTS.

    Two programs per `stores` parameter, the log staged or not, each run to two ends (`t1`
    an input): to T = 2 the run takes 10 steps and 3 impacts (SUCCESS, chunks of 4 steps);
    to T = 3 the staged program stops at MAX_STEPS (its 12 steps end at the fourth
    landing, 2.214), to T = 2.5 the unstaged program's 4-row log fills at that landing
    (MAX_IMPACTS). (These were four programs: max_steps = 6 for MAX_STEPS, max_impacts = 8
    and 2 for the unstaged SUCCESS and MAX_IMPACTS; each end is reached the same way here.)
    Both the forward-mode and the reverse-mode runs' statuses are checked."""
    taken = _spy_on_stage_log(monkeypatch)  # the staging log's rows, each time it is traced

    def loss(q, t1, adjoint, max_steps, impacts):
        sol = gj.simulate(BALL, q[:2], 0.0, t1, {"g": q[2], "e": q[3]}, adjoint=adjoint,
                          max_steps=max_steps, max_impacts=impacts, direction=1, throw=False,
                          **TIGHT)
        return sol.x_final[0] + sol.x_final[1] / 2 + jnp.nansum(sol.impact_times), sol.status

    p = jnp.asarray(BALL_P)
    programs = [  # (max_steps, max_impacts, staged, [(t1, status), ...])
        (12, 100, True,  # chunks of 4 steps; a 1600-byte log
         [(BALL_T, gj.Status.SUCCESS), (3.0, gj.Status.MAX_STEPS)]),
        (12, 4, False,  # a 64-byte log, not staged
         [(BALL_T, gj.Status.SUCCESS), (2.5, gj.Status.MAX_IMPACTS)]),
    ]
    for max_steps, impacts, staged, ends in programs:
        bound = dict(max_steps=max_steps, impacts=impacts)
        forward = jax.jit(jax.jacfwd(lambda q, t1, b=bound: loss(q, t1, None, **b),
                                     has_aux=True))
        reverse = jax.jit(jax.value_and_grad(lambda q, t1, b=bound: loss(q, t1, RCA, **b),
                                             has_aux=True))
        for call, (t1, status) in enumerate(ends):
            jacobian, plain_status = forward_once(
                ("two levels", max_steps, impacts, t1),
                lambda forward=forward, t1=t1: forward(p, t1))
            assert gj.Status(int(plain_status)) == status
            taken.clear()  # (the forward-mode runs above stage their logs too)
            (_, reverse_status), gradient = reverse(p, t1)
            if call == 0:  # traced at the first call only
                assert bool(taken) == staged
            assert gj.Status(int(reverse_status)) == status
            assert_close(gradient, jacobian, MODES)
