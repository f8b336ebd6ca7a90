"""Differentiable analysis through impacts (grazejax._linearize), layer by layer.

Every autodiff result is checked against something computed another way: central finite
differences, the closed-form saltation matrix at a point, closed-form flows (free fall,
rotation), the paper's eqs. dert/derw evaluated with impact-free flow Jacobians, and
Liouville's formula. Compile time dominates: scenes are built once per module and the
same options are passed everywhere so that each compiled program is reused.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex
from grazejax._linearize import (
    DerivativeStatus,
    a2_diagnostic,
    classify_point,
    closed_form_linearization,
    flow_jacobian,
    meeting_time,
    one_sided_jacobians,
    saltation_matrix,
    scalar_gradient,
    variational_transition,
    w_map,
)

from .helpers import central_differences, clockwise, free_fall_scene, projected_circle_scene

TIGHT = dict(rtol=1e-12, atol=1e-12)
FREE_FALL = free_fall_scene(restitution=0.8)
BALL = ex.bouncing_ball()
TABLE = ex.vibrating_table()
ORBEX2, ORBEX2_ARGS = ex.orbex2(), ex.orbex2_args()
NONAXIAL, NONAXIAL_ARGS = ex.exnonaxial(), ex.exnonaxial_args()
C = math.exp(0.00025 * math.pi)
R2 = 1 / math.sqrt(2)
LOOKBACK = 0.5  # one value everywhere: w_map compiles once


def shift(s):
    """Flow Jacobian of free fall over a time s (exact)."""
    return np.array([[1.0, s], [0.0, 1.0]])


# ------------------------------------------------------------- saltation ------------


def test_saltation_matrix_wall_closed_form():
    """Wall Φ = x, restitution r, acceleration a: S = [[−r, 0], [(a⁺ + r a⁻)/v⁻, −r]]."""
    r, a, v = 0.8, -2.0, -1.3
    s = saltation_matrix(FREE_FALL, 0, 0.7, [0.0, v], {"a": a})
    expected = np.array([[-r, 0.0], [(a + r * a) / v, -r]])
    np.testing.assert_allclose(s.matrix, expected, rtol=1e-14)
    assert int(s.status) == DerivativeStatus.OK
    np.testing.assert_allclose(s.approach_rate, v)
    np.testing.assert_allclose(s.x_post, [0.0, -r * v])


def test_saltation_at_exact_grazing_is_n2_value_without_nan():
    s = saltation_matrix(FREE_FALL, 0, 0.0, [0.0, 0.0], {"a": 2.0})
    assert int(s.status) == DerivativeStatus.GRAZING
    np.testing.assert_array_equal(s.matrix, np.eye(2))
    # The double-where keeps tangents finite at the singular point too.
    d = jax.jacfwd(lambda x: saltation_matrix(FREE_FALL, 0, 0.0, x, {"a": 2.0}).matrix)(
        jnp.zeros(2)
    )
    assert np.all(np.isfinite(d))


def test_undefined_point_raises_outside_jit_and_is_a_status_inside():
    root = gj.Surface(phi=lambda t, x, a: jnp.sqrt(x[0]), jump=lambda t, x, a: x.at[1].set(-x[1]))
    scene = gj.Scene(lambda t, x, a: jnp.stack([x[1], -1.0 + 0 * x[0]]), [root])
    with pytest.raises(ValueError, match="∇Φ"):
        saltation_matrix(scene, 0, 0.0, [0.0, -1.0])
    with pytest.raises(ValueError, match="surface_index"):
        saltation_matrix(scene, 3, 0.0, [0.0, -1.0])
    inside = jax.jit(lambda x: saltation_matrix(scene, 0, 0.0, x).status)(jnp.array([0.0, -1.0]))
    assert int(inside) == DerivativeStatus.UNDEFINED


# ------------------------------------------------------ flow Jacobians --------------


def boundary_scene():
    """f = (x2 − c, 1); Γ = {x1 = 0, x2 ≤ 0}, J = (x1, (1 − b) x2), J = id on ∂Γ (C6).

    The flows are polynomials (flow Jacobian [[1, s], [0, 1]]), so Runge-Kutta steps are
    exact. The boundary point (0, 0) is a β point for c = 1 (f = (−1, 1):
    S − I = [[0, 0], [−b, −b]]) and a γ point for c = 0 (f = (0, 1), Φ = x1 has a minimum:
    a quadratic graze, as in ex1dof).
    """
    wall = gj.Surface(
        phi=lambda t, x, a: x[0],
        jump=lambda t, x, a: x.at[1].set((1 - a["b"]) * x[1]),
        where=lambda t, x, a: x[1] <= 0,
    )
    return gj.Scene(lambda t, x, a: jnp.stack([x[1] - a["c"], 1.0 + 0 * x[0]]), [wall])


BOUNDARY = boundary_scene()
BETA_ARGS = {"b": jnp.asarray(0.4), "c": jnp.asarray(1.0)}
GAMMA_ARGS = {"b": jnp.asarray(0.4), "c": jnp.asarray(0.0)}


def test_flow_jacobian_single_impact_is_flow_saltation_flow():
    """jacfwd through simulate = Φ(T, θ) S Φ(θ, 0), with S by hand at the logged impact.

    From (1, −1) with c = 1: x1 = 1 − 2t + t²/2 meets Γ at θ = 2 − √2, v = x2 = 1 − √2.
    S = DJ + (f⁺ − DJ f⁻)∇Φᵀ/(∇Φ·f⁻) = [[1 − b v/(v − c), 0], [b/(v − c), 1 − b]].
    """
    T, b, c = 1.0, 0.4, 1.0
    r = flow_jacobian(BOUNDARY, [1.0, -1.0], 0.0, T, BETA_ARGS, **TIGHT)
    assert int(r.status) == DerivativeStatus.OK and int(r.solution.num_impacts) == 1
    theta, v = 2 - math.sqrt(2), 1 - math.sqrt(2)
    np.testing.assert_allclose(r.solution.impact_times[0], theta, rtol=1e-12)
    S = np.array([[1 - b * v / (v - c), 0.0], [b / (v - c), 1 - b]])
    np.testing.assert_allclose(r.jacobian, shift(T - theta) @ S @ shift(theta), rtol=1e-10)
    salt = saltation_matrix(BOUNDARY, 0, theta, r.solution.impact_pre[0], BETA_ARGS)
    np.testing.assert_allclose(salt.matrix, S, rtol=1e-12)


def test_flow_jacobian_at_exact_grazing_reports_status():
    # c = 0, from (1/2, −1): x1 = 1/2 − t + t²/2 touches Γ at (0, 0) ∈ ∂Γ at t = 1, exactly.
    r = flow_jacobian(BOUNDARY, [0.5, -1.0], 0.0, 1.5, GAMMA_ARGS, **TIGHT)
    assert gj.ImpactKind(int(r.solution.impact_kind[0])) == gj.ImpactKind.GAMMA
    assert int(r.status) == DerivativeStatus.GRAZING
    # No derivative exists at the touch: NaN, never a finite number that is neither side's.
    assert np.all(np.isnan(r.jacobian))


def test_moving_surface_saltation_against_simulate():
    """Vibrating table Φ = x − A sin ωt, v⁺ = w' − e(v − w'): S has ∂Φ/∂t and ∂J/∂t terms.

    Checked by hand and against central differences of simulate itself: the flows are
    free fall (exact), so ∂x(T)/∂x0 = Φ(T − θ) S Φ(θ).
    """
    args = {"g": 9.81, "e": 0.7, "A": 0.1, "omega": 7.0}
    T = 0.4
    run = jax.jit(lambda x0: gj.simulate(TABLE, x0, 0.0, T, args, **TIGHT))
    sol = run(jnp.array([0.5, 0.0]))
    theta = float(sol.impact_times[0])
    assert int(sol.num_impacts) == 1 and theta < T
    salt = saltation_matrix(TABLE, 0, theta, sol.impact_pre[0], args)
    # By hand: ∇Φ = (1, 0), ∂Φ/∂t = −w', DJ = diag(1, −e), ∂J/∂t = (0, (1 + e) w''), so
    # S = [[−e, 0], [−(1 + e)(g + w'')/(v − w'), −e]] with the relative speed v − w'.
    e, g, A, om = 0.7, 9.81, 0.1, 7.0
    v = float(sol.impact_pre[0, 1])
    w1, w2 = A * om * math.cos(om * theta), -A * om**2 * math.sin(om * theta)
    by_hand = np.array([[-e, 0.0], [-(1 + e) * (g + w2) / (v - w1), -e]])
    np.testing.assert_allclose(salt.matrix, by_hand, rtol=1e-12)
    np.testing.assert_allclose(salt.approach_rate, v - w1, rtol=1e-12)
    assert abs(w1) > 0.1 and abs(w2) > 1  # the moving-surface terms matter here
    fd = central_differences(lambda x: run(jnp.asarray(x)).x_final, [0.5, 0.0], 1e-6)
    np.testing.assert_allclose(shift(T - theta) @ by_hand @ shift(theta), fd, rtol=1e-6)


@pytest.fixture(scope="module")
def orbex2_run():
    x0 = np.array([0.8, 1.2])
    return x0, flow_jacobian(ORBEX2, x0, 0.0, 10.0, ORBEX2_ARGS, **TIGHT)


def test_flow_jacobian_matches_central_differences(orbex2_run):
    """Seven transversal impacts on two walls: jacfwd vs central differences, ≤ 1e-6."""
    x0, r = orbex2_run
    assert int(r.status) == DerivativeStatus.OK and int(r.solution.num_impacts) == 7
    run = lambda x: flow_jacobian(ORBEX2, x, 0.0, 10.0, ORBEX2_ARGS, **TIGHT).x_final  # noqa: E731
    fd = central_differences(run, x0, 1e-5)
    err = np.linalg.norm(np.asarray(r.jacobian) - fd) / np.linalg.norm(fd)
    assert err <= 1e-6, err


@pytest.mark.slow  # a second compile of the orbex2 run; args are covered by scalar_gradient
def test_flow_jacobian_with_respect_to_args(orbex2_run):
    x0, _ = orbex2_run
    r = flow_jacobian(ORBEX2, x0, 0.0, 10.0, ORBEX2_ARGS, wrt="args", **TIGHT)
    assert set(r.jacobian) == set(ORBEX2_ARGS)
    step = 1e-6
    for name in ("R2", "a"):
        plus = dict(ORBEX2_ARGS, **{name: ORBEX2_ARGS[name] + step})
        minus = dict(ORBEX2_ARGS, **{name: ORBEX2_ARGS[name] - step})
        fd = (
            np.asarray(flow_jacobian(ORBEX2, x0, 0.0, 10.0, plus, **TIGHT).x_final)
            - np.asarray(flow_jacobian(ORBEX2, x0, 0.0, 10.0, minus, **TIGHT).x_final)
        ) / (2 * step)
        np.testing.assert_allclose(r.jacobian[name], fd, rtol=1e-6, atol=1e-6 * np.abs(fd).max())


def test_variational_system_equals_jacfwd_and_liouville(orbex2_run):
    """U' = A U, ΔU = B_i U (eq. lin1) reproduces jacfwd, and det U = Π det S_i e^{∫ tr A}.

    For orbex2, tr A = a = 0.001 and, in closed form, det S = 2 R1² v² on Γ1 (quadratic
    law y2 → −R1 y2²) and R2² on Γ2, with v the logged pre-impact speed.
    """
    x0, r = orbex2_run
    v = variational_transition(ORBEX2, x0, 0.0, 10.0, ORBEX2_ARGS, **TIGHT)
    assert int(v.status) == DerivativeStatus.OK
    np.testing.assert_allclose(
        v.transition, r.jacobian, rtol=1e-8, atol=1e-8 * np.abs(r.jacobian).max()
    )
    np.testing.assert_allclose(v.jump_matrices, v.saltations - np.eye(2))
    k = int(v.num_impacts)
    np.testing.assert_allclose(v.trace_integral, 0.001 * 10.0, rtol=1e-10)
    R1, R2_ = float(ORBEX2_ARGS["R1"]), float(ORBEX2_ARGS["R2"])
    dets = []
    for i in range(k):
        speed = float(r.solution.impact_pre[i, 1])
        dets.append(2 * R1**2 * speed**2 if int(r.solution.impact_surface[i]) == 0 else R2_**2)
    np.testing.assert_allclose(np.linalg.det(np.asarray(v.saltations[:k])), dets, rtol=1e-10)
    expected = np.prod(dets) * math.exp(0.001 * 10.0)
    np.testing.assert_allclose(np.linalg.det(np.asarray(r.jacobian)), expected, rtol=1e-8)


def test_variational_flights_are_projected_as_the_run_is():
    """A scene's `project` acts on the variational system's flights as on the run: on the
    kicked circle (`projected_circle_scene`) U(t1) = R(−(t1 + α))(I − x0 x0ᵀ), the
    projection's Jacobian on the circle after the flow's (unprojected flights would give
    the rotation alone, of rank 2)."""
    theta0, t1, alpha = 1.0, 4.0, 0.3
    x0 = np.array([math.cos(theta0), math.sin(theta0)])
    v = variational_transition(projected_circle_scene(), x0, 0.0, t1,
                               {"alpha": jnp.asarray(alpha)}, **TIGHT)
    assert int(v.status) == DerivativeStatus.OK and int(v.num_impacts) == 1
    np.testing.assert_allclose(v.impact_times[0], theta0, rtol=1e-12)
    np.testing.assert_allclose(v.x_final, clockwise(t1 + alpha) @ x0, atol=1e-11)
    exact = clockwise(t1 + alpha) @ (np.eye(2) - np.outer(x0, x0))
    np.testing.assert_allclose(v.transition, exact, atol=1e-10)


# ------------------------------------------------------ forward-mode gradients -----


def third_impact_time(sol):
    return sol.impact_times[2]


def test_scalar_gradient_bouncing_ball_dtn_de():
    """∂t_3/∂e = 2w(1 + 2e)/g with w = √(2gh) (t_n = t_1 + (2w/g) Σ_{k<n} e^k)."""
    h, g, e = 1.0, 9.81, 0.8
    args = {"g": jnp.asarray(g), "e": jnp.asarray(e)}
    r = scalar_gradient(third_impact_time, BALL, [h, 0.0], 0.0, 2.0, args, wrt="args", **TIGHT)
    w = math.sqrt(2 * g * h)
    assert int(r.status) == DerivativeStatus.OK
    np.testing.assert_allclose(r.grad["e"], 2 * w * (1 + 2 * e) / g, rtol=1e-9)
    times, _ = ex.bouncing_ball_impact_times(h, 0.0, g, e, 3)
    np.testing.assert_allclose(r.value, times[2], rtol=1e-11)
    # ∂t_3/∂g from the closed form, by differences of the closed form itself
    step = 1e-6
    fd = (
        ex.bouncing_ball_impact_times(h, 0.0, g + step, e, 3)[0][2]
        - ex.bouncing_ball_impact_times(h, 0.0, g - step, e, 3)[0][2]
    ) / (2 * step)
    np.testing.assert_allclose(r.grad["g"], fd, rtol=1e-7)


# ------------------------------------------------- meeting time, W-map -------------


def boundary_tau(x, c=1.0):
    """Meeting time of x1 = x1⁰ + (x2⁰ − c)s + s²/2 with x1 = 0 (the downward root)."""
    x1, x2 = x
    return (c - x2) - math.sqrt((x2 - c) ** 2 - 2 * x1)


def boundary_w(x, b=0.4, c=1.0):
    """W(x): to Γ at s = τ, jump x2 → (1 − b) x2, flow back by −s (polynomial flows)."""
    s = boundary_tau(x, c)
    v = (1 - b) * (x[1] + s)
    return np.array([(v - c) * (-s) + s * s / 2, v - s]) - np.asarray(x)


X_OFF = np.array([0.3, -0.5])  # meets Γ at τ ≈ 0.2155 with x2 ≈ −0.28: an α point


def test_meeting_time_and_gradient_eq_dert():
    m = meeting_time(BOUNDARY, 0, 0.0, X_OFF, BETA_ARGS, lookback=LOOKBACK, horizon=2.0, **TIGHT)
    assert int(m.status) == DerivativeStatus.OK and bool(m.met)
    assert gj.ImpactKind(int(m.kind)) == gj.ImpactKind.ALPHA
    np.testing.assert_allclose(m.tau, boundary_tau(X_OFF), rtol=1e-13)
    np.testing.assert_allclose(m.grad, central_differences(boundary_tau, X_OFF, 1e-6), rtol=1e-8)
    cf = closed_form_linearization(BOUNDARY, 0, 0.0, X_OFF, m.tau, BETA_ARGS, **TIGHT)
    np.testing.assert_allclose(m.grad, cf.grad_tau, rtol=1e-12)
    # dξ(τ(x))/dx = X + f ∇τᵀ, with X = [[1, τ], [0, 1]]
    f = np.array([m.x_meet[1] - 1.0, 1.0])
    np.testing.assert_allclose(
        m.x_meet_jacobian - np.outer(f, m.grad), shift(float(m.tau)), atol=1e-12
    )


def test_w_map_eq_derw_off_and_on_the_surface():
    w = w_map(BOUNDARY, 0, 0.0, X_OFF, BETA_ARGS, lookback=LOOKBACK, horizon=2.0, **TIGHT)
    assert int(w.status) == DerivativeStatus.OK
    np.testing.assert_allclose(w.value, boundary_w(X_OFF), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(
        w.jacobian, central_differences(boundary_w, X_OFF, 1e-6), rtol=1e-8, atol=1e-10
    )
    cf = closed_form_linearization(BOUNDARY, 0, 0.0, X_OFF, w.tau, BETA_ARGS, **TIGHT)
    np.testing.assert_allclose(w.jacobian, cf.w_jacobian, rtol=1e-12, atol=1e-14)
    # On Γ (τ = θ): W_x = S − I (eq. derw, with ∂I/∂x = DJ − I).
    x_on = np.array([0.0, -0.3])
    w = w_map(BOUNDARY, 0, 0.0, x_on, BETA_ARGS, lookback=LOOKBACK, horizon=2.0, **TIGHT)
    assert abs(float(w.tau)) < 1e-13
    S = saltation_matrix(BOUNDARY, 0, 0.0, x_on, BETA_ARGS).matrix
    np.testing.assert_allclose(w.jacobian, np.asarray(S) - np.eye(2), rtol=1e-12, atol=1e-14)


def test_w_map_n2_and_exact_grazing_statuses():
    # The parabola from (0.3, 0.5) never reaches x1 = 0 (N2): W = 0, W_x = O, τ = inf.
    w = w_map(BOUNDARY, 0, 0.0, [0.3, 0.5], BETA_ARGS, lookback=LOOKBACK, horizon=2.0, **TIGHT)
    assert int(w.status) == DerivativeStatus.NO_CONTACT and not bool(w.met)
    assert np.isinf(float(w.tau))
    np.testing.assert_array_equal(w.value, 0.0)
    np.testing.assert_array_equal(w.jacobian, 0.0)
    # The grazing point itself (c = 0): status GRAZING, the (N2) value, nothing non-finite.
    m = meeting_time(
        BOUNDARY, 0, 0.0, [0.0, 0.0], GAMMA_ARGS, lookback=LOOKBACK, horizon=2.0, **TIGHT
    )
    w = w_map(BOUNDARY, 0, 0.0, [0.0, 0.0], GAMMA_ARGS, lookback=LOOKBACK, horizon=2.0, **TIGHT)
    assert int(w.status) == int(m.status) == DerivativeStatus.GRAZING
    np.testing.assert_array_equal(w.jacobian, 0.0)
    np.testing.assert_array_equal(m.grad, 0.0)
    assert np.all(np.isfinite(w.value)) and np.all(np.isfinite(m.x_meet_jacobian))


def nonaxial_w(x, t=0.0, K=0.11):
    """W(x) for exnonaxial in closed form: rotate to Γ, jump onto the diagonal, rotate back."""
    tau, xi = ex.exnonaxial_first_impact(x, t)
    a = R2 + K * (xi[1] - xi[0]) ** 2
    s = t - tau  # the flow over a time s is x ↦ R(s) x, R = [[cos, sin], [−sin, cos]]
    rot = np.array([[math.cos(s), math.sin(s)], [-math.sin(s), math.cos(s)]])
    return rot @ np.array([a, a]) - np.asarray(x)


@pytest.mark.slow
def test_exnonaxial_meeting_and_w_map_closed_forms():
    x = np.array([0.3, 1.1])  # r ≈ 1.14: meets Γ transversally after τ ≈ 0.28
    m = meeting_time(NONAXIAL, 0, 0.0, x, NONAXIAL_ARGS, lookback=LOOKBACK, horizon=2.0, **TIGHT)
    tau = lambda z: ex.exnonaxial_first_impact(z, 0.0)[0]  # noqa: E731
    np.testing.assert_allclose(m.tau, tau(x), rtol=1e-11)
    np.testing.assert_allclose(m.grad, central_differences(tau, x, 1e-7), rtol=1e-7)
    w = w_map(NONAXIAL, 0, 0.0, x, NONAXIAL_ARGS, lookback=LOOKBACK, horizon=2.0, **TIGHT)
    np.testing.assert_allclose(w.value, nonaxial_w(x), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(
        w.jacobian, central_differences(nonaxial_w, x, 1e-7), rtol=1e-7, atol=1e-9
    )


# ------------------------------------------------------ point types ----------------


def ball_with_piece():
    """The bouncing ball with Γ = {x = 0, v ≤ 0}: its image Γ̃ = {x = 0, v ≥ 0}."""
    floor = gj.Surface(
        phi=lambda t, x, a: x[0],
        jump=lambda t, x, a: x.at[1].set(-0.8 * x[1]),
        inverse_jump=lambda t, x, a: x.at[1].set(-x[1] / 0.8),
        where=lambda t, x, a: x[1] <= 0,
    )
    return gj.Scene(lambda t, x, a: jnp.stack([x[1], -9.81 + 0 * x[0]]), [floor])


@pytest.mark.parametrize(
    "scene, args, x, kind, axial",
    [
        (ORBEX2, ORBEX2_ARGS, [C, 0.0], gj.ImpactKind.GAMMA, True),
        (ORBEX2, ORBEX2_ARGS, [C, 0.5], gj.ImpactKind.ALPHA, False),
        (NONAXIAL, NONAXIAL_ARGS, [R2, R2], gj.ImpactKind.GAMMA, False),
        (BOUNDARY, BETA_ARGS, [0.0, 0.0], gj.ImpactKind.BETA, False),
        (BOUNDARY, GAMMA_ARGS, [0.0, 0.0], gj.ImpactKind.GAMMA, True),
        (ball_with_piece(), None, [0.0, 2.0], gj.ImpactKind.ALPHA_PRIME, False),
        (ball_with_piece(), None, [0.3, 2.0], gj.ImpactKind.NONE, False),
    ],
)
def test_classify_point(scene, args, x, kind, axial):
    p = classify_point(scene, 0, 0.0, x, args)
    assert gj.ImpactKind(int(p.kind)) == kind
    assert bool(p.axial) == axial


# ------------------------------------------------ one-sided limits, (A2) -----------


def test_one_sided_limits_at_a_beta_point():
    """B_i is bivalued at β: S − I for impacting neighbours (N1), O for the others (N2)."""
    r = one_sided_jacobians(
        BOUNDARY,
        0,
        0.0,
        [0.0, 0.0],
        BETA_ARGS,
        direction=[0.0, -1.0],
        window=0.5,
        distances=np.geomspace(1e-1, 1e-5, 9),
        **TIGHT,
    )
    assert r.plus.condition == "N1" and r.minus.condition == "N2"
    assert r.n1 is r.plus and r.n2 is r.minus
    b = BETA_ARGS["b"]
    np.testing.assert_allclose(r.n1.limit, [[0.0, 0.0], [-b, -b]], atol=1e-8)
    assert r.n1.converged and abs(r.n1.norm_exponent) < 0.05
    np.testing.assert_array_equal(r.n2.limit, 0.0)
    assert r.n2.converged


def test_one_sided_at_a_grazing_point_n1_diverges_n2_is_zero():
    """At γ the (N1) side has no limit: ‖W_x‖ ≈ b/|v| with the meeting speed v = −√(2d).

    (The same happens at the paper's grazing points: docs/linearization.md.)
    """
    r = one_sided_jacobians(
        BOUNDARY,
        0,
        0.0,
        [0.0, 0.0],
        GAMMA_ARGS,
        direction=[-1.0, 0.0],
        window=0.5,
        distances=np.geomspace(1e-2, 1e-8, 9),
        **TIGHT,
    )
    assert r.n1 is r.plus and r.n2 is r.minus
    assert not r.n1.converged and np.all(np.isnan(r.n1.limit))
    assert abs(r.n1.norm_exponent + 0.5) < 0.02, r.n1.norm_exponent
    norms = np.linalg.norm(r.n1.jacobians, ord=2, axis=(1, 2))
    b = GAMMA_ARGS["b"]
    np.testing.assert_allclose(norms[-3:] * np.sqrt(2 * r.n1.distances[-3:]), b, rtol=1e-2)
    np.testing.assert_array_equal(r.n2.limit, 0.0)


@pytest.mark.slow
@pytest.mark.parametrize(
    "make, make_args, x",
    [
        (ex.orbex2, ex.orbex2_args, [C, 0.0]),
        (ex.exnonaxial, ex.exnonaxial_args, [R2, R2]),
        (ex.ex1dof, lambda: ex.ex1dof_args(0.0), [0.0, 0.0]),
    ],
)
def test_a2_fails_at_the_papers_grazing_points(make, make_args, x):
    """docs/linearization.md: ‖W_x‖ and the synchronised flow Jacobian grow like d^{-1/2}."""
    d = a2_diagnostic(make(), 0, 0.0, x, make_args(), window=0.5, **TIGHT)
    assert abs(d.w_exponent + 0.5) < 0.01 and abs(d.flow_exponent + 0.5) < 0.01
    assert "square-root" in d.verdict
    # The asymptote: ‖W_x‖ ≈ |a⁺|/|v| with the meeting speed |v| = √(2 Φ̈ d); for all three
    # examples |a⁺| ≈ Φ̈ ≈ 1 (orbex2: e^{0.00025π}), so ‖W_x‖ √d → 1/√2.
    np.testing.assert_allclose(
        d.w_norms[-4:] * np.sqrt(d.distances[-4:]), 1 / math.sqrt(2), rtol=1e-2
    )
