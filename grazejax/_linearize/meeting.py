"""The meeting time τ_i(x) and the B-equivalence map W_i(x) with their derivatives, by
autodiff through the located event (`grazejax.meeting_time`, `grazejax.w_map`), and
the paper's eqs. dert and derw in closed form (`grazejax.closed_form_linearization`)."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._compiler import single_run_jit
from .._flow import flight_kwargs, free_flow
from .._geometry import closed_piece, on_piece
from .._roots import safe_divide
from .._scene import Scene
from .._simulate import simulate
from .._status import ImpactKind, Status
from .common import (
    DerivativeStatus,
    float_array,
    prepare_point,
    raise_if_undefined,
    simulation_ok,
    tree_finite,
)
from .saltation import Saltation, saltation_core


class Meeting(eqx.Module):
    r"""Result of `grazejax.meeting_time`: the paper's τ_i(x) and its gradient.

    **Fields:**

    - `tau`: the meeting time τ_i (the start time t where `met` is False).
    - `x_meet`: ξ(τ_i), the pre-jump state on Γ_i (x where `met` is False).
    - `grad`: ∇τ_i(x), shape `(n,)`, by `jax.jacfwd` through the event (eq. dert).
    - `x_meet_jacobian`: dξ(τ_i(x))/dx = X + f ∇τᵀ, shape `(n, n)`.
    - `kind`: the `grazejax.ImpactKind` of the meeting point (α, β or γ).
    - `met`: whether the flow meets Γ_i within `[t − lookback, t + horizon]`.
    - `status`: a `grazejax.DerivativeStatus` code.
    """

    tau: Float[Array, ""]
    x_meet: Float[Array, " n"]
    grad: Float[Array, " n"]
    x_meet_jacobian: Float[Array, "n n"]
    kind: Int[Array, ""]
    met: Bool[Array, ""]
    status: Int[Array, ""]


class WMap(eqx.Module):
    r"""Result of `grazejax.w_map`: the paper's W_i(x) (eq. W-map) and W_{ix} (eq. derw).

    **Fields:**

    - `value`: W_i(x) = ψ(θ) − x, where ψ is the flow started from J_i(ξ(τ_i)) at τ_i and
      θ = `t`; 0 when the flow does not meet Γ_i in the window.
    - `jacobian`: W_{ix}, shape `(n, n)`, by `jax.jacfwd`. The linearization's jump matrix
      is B_i = W_{ix}; the full map x ↦ x + W_i(x) has Jacobian I + W_{ix} (= S at α points
      on the orbit).
    - `tau`, `x_meet`, `kind`, `met`: as in `grazejax.Meeting`.
    - `status`: a `grazejax.DerivativeStatus` code.
    """

    value: Float[Array, " n"]
    jacobian: Float[Array, "n n"]
    tau: Float[Array, ""]
    x_meet: Float[Array, " n"]
    kind: Int[Array, ""]
    met: Bool[Array, ""]
    status: Int[Array, ""]


class ClosedForm(eqx.Module):
    r"""Result of `grazejax.closed_form_linearization`: eqs. dert and derw.

    With X = ∂φ(τ; t, x)/∂x and Y = ∂φ(t; τ, y)/∂y at y = J(ξ(τ)) (Jacobians of
    impact-free flows at *fixed* times, no event differentiated):

    - `grad_tau` = −Xᵀ∇Φ / (∂Φ/∂t + ∇Φ·f⁻) (eq. dert),
    - `w_jacobian` = Y S X − I (eq. derw; it reduces to S − I when τ = t),
    - `saltation`: the `grazejax.Saltation` at ξ(τ),
    - `status`: a `grazejax.DerivativeStatus` code.
    """

    grad_tau: Float[Array, " n"]
    w_jacobian: Float[Array, "n n"]
    saltation: Saltation
    status: Int[Array, ""]


def _meet(scene: Scene, i: int, t, x, args, lookback: float, horizon, kw):
    """τ_i(x), ξ(τ_i) by simulate on Γ_i alone with J = id; differentiable in x."""
    surface = scene.surfaces[i]
    # Only Γ_i, and a jump that changes nothing: the run stops (max_impacts=1) exactly at
    # the first contact, with simulate's IFT tangent of the contact time.
    probe = scene.with_surfaces([surface.probe()])
    if lookback > 0:
        # Search from t − lookback: the meeting may lie before t (a neighbour already past
        # Γ_i), and a run never impacts at its start time, so a point *on* Γ_i needs a
        # start upstream of it to have its τ = t found.
        t_start = t - lookback
        y, flow_status = free_flow(scene, x, t, t_start, args, kw)
    else:
        t_start, y, flow_status = t, x, jnp.array(int(Status.SUCCESS))
    sol = simulate(
        probe, y, t_start, t + horizon, args, max_impacts=1, direction=1, **flight_kwargs(kw)
    )
    met = sol.num_impacts > 0
    # Double where: where nothing was met the log rows are NaN; never let them into the
    # arithmetic below (their tangents would be NaN too).
    tau = jnp.where(met, sol.impact_times[0], t)
    x_meet = jnp.where(met, sol.impact_pre[0], x)
    kind = jnp.where(met, sol.impact_kind[0], int(ImpactKind.NONE))
    status = jnp.where(simulation_ok(flow_status), sol.status, flow_status)
    # A search that runs out of steps without a meeting (horizon = inf) is a non-meeting.
    reached = simulation_ok(status) | ((status == int(Status.MAX_STEPS)) & ~met)
    return tau, x_meet, kind, met, reached & simulation_ok(flow_status), status


def _point_status(met, kind, ok_run, derivative, start_tangential, undefined):
    grazing = (kind == int(ImpactKind.GAMMA)) | start_tangential
    return jnp.where(
        undefined,
        int(DerivativeStatus.UNDEFINED),
        jnp.where(
            ~ok_run,
            int(DerivativeStatus.SIMULATION_FAILED),
            jnp.where(
                grazing,
                int(DerivativeStatus.GRAZING),
                jnp.where(
                    ~met,
                    int(DerivativeStatus.NO_CONTACT),
                    jnp.where(
                        tree_finite(derivative),
                        int(DerivativeStatus.OK),
                        int(DerivativeStatus.NONFINITE),
                    ),
                ),
            ),
        ),
    )


def _start_checks(scene, i, t, x, args):
    """Is x itself a tangential point of Γ_i (exact grazing), and is Φ or f undefined there?"""
    surface = scene.surfaces[i]
    fx = scene.vector_field(t, x, args)
    where_x = None
    if surface.where is not None:
        where_x = lambda z: closed_piece(surface.where, t, z, args)  # noqa: E731
    on, _, _, _, tangential, defined = on_piece(surface.phi, where_x, t, x, args, fx, 1e-10)
    return on & tangential, ~(defined & tree_finite(fx))


def _analyse_core(scene, i, t, x, args, lookback, horizon, kw):
    """τ_i, ∇τ_i, W_i, W_ix at one point: one compiled program serves both
    `meeting_time` and `w_map` (the W flights add run time, not compile time)."""

    def fn(x_):
        value, (tau, x_meet, kind, met, ok_run) = _w_value(
            scene, i, t, x_, args, lookback, horizon, kw
        )
        return (tau, x_meet, value), (tau, x_meet, value, kind, met, ok_run)

    (grad, x_jac, w_jac), (tau, x_meet, value, kind, met, ok_run) = jax.jacfwd(fn, has_aux=True)(x)
    tangential, undefined = _start_checks(scene, i, t, x, args)
    status = _point_status(met, kind, ok_run, (grad, w_jac), tangential, undefined)
    # GRAZING / NO_CONTACT: ∇τ = 0 and W_x = O, the (N2) values; never return the
    # meaningless tangent of a touch (simulate takes no Newton step on a tangential contact).
    keep = status == int(DerivativeStatus.OK)
    zero = lambda a: jnp.where(keep, a, jnp.zeros_like(a))  # noqa: E731
    value = jnp.where(met & ~tangential, value, jnp.zeros_like(value))
    tau = jnp.where(met, tau, jnp.inf)
    meeting = Meeting(tau, x_meet, zero(grad), zero(x_jac), kind, met, status)
    return meeting, WMap(value, zero(w_jac), tau, x_meet, kind, met, status)


_analyse_jit = single_run_jit(_analyse_core)


def meeting_time(
    scene: Scene,
    surface_index: int,
    t,
    x,
    args=None,
    *,
    lookback: float = 0.0,
    horizon: float = math.inf,
    **simulate_kwargs,
) -> Meeting:
    r"""The paper's meeting time τ_i(x) and its gradient (eq. dert), through `simulate`.

    τ_i(x) is the first time the solution of x' = f (no impacts) from (t, x) reaches Γ_i
    (paper §2.1: ξ(t) = x(t, θ_i, x), τ_i its meeting time with Γ_i). It is found by
    `simulate` on Γ_i alone with the jump replaced by the identity and `max_impacts=1`,
    searching `[t − lookback, t + horizon]`; ∇τ_i comes from `jax.jacfwd` through the
    located event (simulate's Newton step carries the implicit-function tangent).
    `grazejax.closed_form_linearization` gives eq. dert independently.

    **Arguments:**

    - `scene`, `surface_index`: the scene and the index i of Γ_i.
    - `t`, `x`: the start (θ_i and a point near x_0(θ_i) in the paper).
    - `args`: the scene's parameters.
    - `lookback`: search also this far *before* t (a static float). Needed for points on Γ_i
      (a run never impacts at its start time, so τ = t is found only from upstream) and for
      neighbours that have already crossed Γ_i (τ < t).
    - `horizon`: search until t + horizon (default inf: until the meeting, or `max_steps`).
    - `**simulate_kwargs`: tolerances, solver, `max_steps` for the flights.

    **Returns:** a `grazejax.Meeting`; `tau` is inf and the status NO_CONTACT when the
    flow does not meet Γ_i in the window. At a tangential meeting (γ) ∇τ does not exist
    (it grows like 1/(∇Φ·f) on the (N1) side): `grad` is 0 and the status GRAZING.
    """
    i, t, x, args = prepare_point(scene, surface_index, t, x, args)
    kw = dict(simulate_kwargs)
    result, _ = _analyse_jit(scene, i, t, x, args, float(lookback), float_array(horizon), kw)
    raise_if_undefined(result, scene, i, t, x, args, "meeting_time")
    return result


def _w_value(scene, i, t, x, args, lookback, horizon, kw):
    surface = scene.surfaces[i]
    tau, x_meet, kind, met, ok_run, _ = _meet(scene, i, t, x, args, lookback, horizon, kw)
    x_post = surface.jump(tau, x_meet, args)
    # ψ: from (τ, J(ξ(τ))) back to θ = t, without impacts (eq. W-map).
    back, back_status = free_flow(scene, x_post, tau, t, args, kw)
    value = jnp.where(met, back - x, jnp.zeros_like(x))
    ok_run = ok_run & (simulation_ok(back_status) | ~met)
    return value, (tau, x_meet, kind, met, ok_run)


def w_map(
    scene: Scene,
    surface_index: int,
    t,
    x,
    args=None,
    *,
    lookback: float = 0.0,
    horizon: float = math.inf,
    **simulate_kwargs,
) -> WMap:
    r"""The B-equivalence map W_i(x) (eq. W-map) and its Jacobian W_{ix} (eq. derw).

    W_i(x) = ψ(θ) − x: flow x' = f from (θ, x) (θ = `t`) to Γ_i at τ_i(x), jump to
    J_i(ξ(τ_i)), flow back (without impacts) to θ (paper §2.1). It is the jump of the
    B-equivalent system with *fixed* impact moments (eq. graz2), and its Jacobian is the
    jump matrix B_i = W_{ix} of the linearization (eq. lin1). W_i = 0 when the flow does not
    meet Γ_i in the window (paper: "If ξ(t) does not intersect Γ near θ_i then W_i(x) = 0").

    W_{ix} is `jax.jacfwd` of this composition (through the located event and both
    flights). At α points it equals Y S X − I (S the saltation matrix; S − I when x is on
    Γ_i): see `grazejax.closed_form_linearization`.

    **Arguments:** as for `grazejax.meeting_time` (`lookback`, `horizon` bound the
    search window around θ; use `lookback > 0` for points on Γ_i or past it).

    **Returns:** a `grazejax.WMap`. Status NO_CONTACT: W = 0, W_x = O (the (N2)
    value). Status GRAZING (x, or its meeting point, is a tangential contact): W = 0 and
    W_x = O, the (N2) value; the (N1) side has no limit in general: see
    `grazejax.one_sided_jacobians` and `grazejax.a2_diagnostic`.
    """
    i, t, x, args = prepare_point(scene, surface_index, t, x, args)
    kw = dict(simulate_kwargs)
    _, result = _analyse_jit(scene, i, t, x, args, float(lookback), float_array(horizon), kw)
    raise_if_undefined(result, scene, i, t, x, args, "w_map")
    return result


@single_run_jit
def _closed_form_impl(scene, i, t, x, tau, args, kw):
    surface = scene.surfaces[i]

    def to_tau(x_):
        x1, status = free_flow(scene, x_, t, tau, args, kw)
        return x1, (x1, status)

    X, (xi, status_a) = jax.jacfwd(to_tau, has_aux=True)(x)
    salt = saltation_core(scene, i, tau, xi, args)

    def back(y_):
        y1, status = free_flow(scene, y_, tau, t, args, kw)
        return y1, (y1, status)

    Y, (_, status_b) = jax.jacfwd(back, has_aux=True)(salt.x_post)
    _, grad = jax.jacfwd(surface.phi, argnums=(0, 1))(tau, xi, args)
    ok = salt.status == int(DerivativeStatus.OK)
    grad_tau = -safe_divide(X.T @ grad, salt.approach_rate, ok)
    n = x.shape[0]
    w_jac = jnp.where(
        ok, Y @ salt.matrix @ X - jnp.eye(n, dtype=x.dtype), jnp.zeros((n, n), x.dtype)
    )
    runs_ok = simulation_ok(status_a) & simulation_ok(status_b)
    status = jnp.where(runs_ok, salt.status, int(DerivativeStatus.SIMULATION_FAILED))
    return ClosedForm(grad_tau, w_jac, salt, status)


def closed_form_linearization(
    scene: Scene, surface_index: int, t, x, tau, args=None, **simulate_kwargs
) -> ClosedForm:
    r"""Eqs. dert and derw in closed form, given the meeting time τ (the independent check).

    With X = ∂φ(τ; t, x)/∂x (the flow Jacobian from t to the *fixed* time τ), ξ = φ(τ; t, x),
    S the saltation matrix (`grazejax.saltation_matrix`) at (τ, ξ) and
    Y = ∂φ(t; τ, y)/∂y at y = J(ξ):

    ∇τ = −Xᵀ∇Φ / (∂Φ/∂t + ∇Φ·f⁻)   (eq. dert),
    W_x = Y S X − I                 (eq. derw; S − I when τ = t).

    Only impact-free flows are differentiated here, so this is independent of the event
    tangents that `grazejax.meeting_time` and `grazejax.w_map` rely on.

    **Arguments:** `t`, `x` the start (θ and the point), `tau` its meeting time with Γ_i
    (e.g. `meeting_time(...).tau`); the rest as for `grazejax.w_map`.

    **Returns:** a `grazejax.ClosedForm` (status GRAZING with zero matrices when the
    meeting is tangential).
    """
    i, t, x, args = prepare_point(scene, surface_index, t, x, args)
    return _closed_form_impl(scene, i, t, x, float_array(tau), args, dict(simulate_kwargs))


def w_maps(scene, i, t, xs, args, window, kw):
    """W-maps at several neighbours, one call of the cached single-point program each.

    A Python loop on purpose: it reuses the program that `w_map` and `meeting_time`
    compile (same scene, window and options), where a `vmap` would compile another one;
    a dozen neighbours cost milliseconds each.
    """
    horizon = float_array(window)
    results = [
        _analyse_jit(scene, i, t, float_array(x_), args, float(window), horizon, kw)[1] for x_ in xs
    ]
    return jax.tree.map(lambda *leaves: np.stack([np.asarray(leaf) for leaf in leaves]), *results)
