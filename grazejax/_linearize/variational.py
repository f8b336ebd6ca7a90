"""The paper's variational system (eq. lin1) along a solution with impacts: flights of
u' = A(t) u and jumps by the saltation matrices (`grazejax.variational_transition`)."""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._compiler import single_run_jit
from .._flow import free_flow
from .._scene import Scene
from .._simulate import simulate
from .._solution import Solution
from .common import DerivativeStatus, prepare_run, simulation_ok, tree_finite
from .saltation import saltation_core


class Variational(eqx.Module):
    r"""Result of `grazejax.variational_transition`: the paper's system (lin1) solved.

    u' = A(t) u with A = ∂f/∂x along the solution, Δu = B_i u at each impact θ_i, with
    B_i = S_i − I (S_i the saltation matrix at the logged pre-impact state).

    **Fields:**

    - `transition`: U(t1) with U(t0) = I: equal to ∂x(t1)/∂x0 (tested against `jacfwd`).
    - `x_final`: the run's final state.
    - `saltations`: S_i per impact, shape `(max_impacts, n, n)` (identity past `num_impacts`).
    - `jump_matrices`: B_i = S_i − I, same shape.
    - `trace_integral`: ∫ tr A(t) dt over the run (Liouville: det U = Π det S_i · e^∫trA,
      for a scene without `project`: with one, U's flights are projected as the run's are,
      U ↦ DP(x) U after each step, and U is singular across the manifold).
    - `impact_times`, `num_impacts`: from the run.
    - `status`: a `grazejax.DerivativeStatus` code (GRAZING if an impact was tangential:
      its B_i is O, the (N2) value).
    - `solution`: the `grazejax.Solution` of the run.
    """

    transition: Float[Array, "n n"]
    x_final: Float[Array, " n"]
    saltations: Float[Array, "max_impacts n n"]
    jump_matrices: Float[Array, "max_impacts n n"]
    trace_integral: Float[Array, ""]
    impact_times: Float[Array, " max_impacts"]
    num_impacts: Int[Array, ""]
    status: Int[Array, ""]
    solution: Solution


class _Augmented(eqx.Module):
    """(x, U, ∫ tr A)' = (f, A U, tr A), A = ∂f/∂x(t, x): the paper's u' = A(t) u."""

    vector_field: Any = eqx.field(static=True)

    def __call__(self, t, z, args):
        n = _variational_state_size(z.shape[0])
        x, U = z[:n], z[n : n + n * n].reshape(n, n)
        fx, A = self.vector_field(t, x, args), jax.jacfwd(self.vector_field, argnums=1)(t, x, args)
        return jnp.concatenate([fx, (A @ U).reshape(-1), jnp.trace(A)[None]])


class _AugmentedProjection(eqx.Module):
    """A scene's `project` P on the augmented state: (x, U, ∫ tr A) → (P(x), DP(x) U,
    ∫ tr A), the map a step's tangents go through where the run itself is projected
    (`jax.jacfwd` of `simulate` applies DP(x) to them after each step)."""

    project: Any = eqx.field(static=True)

    def __call__(self, t, z, args):
        n = _variational_state_size(z.shape[0])
        x, U = z[:n], z[n : n + n * n].reshape(n, n)
        x1, dU = jax.vmap(lambda u: jax.jvp(lambda y: self.project(t, y, args), (x,), (u,)),
                          in_axes=1, out_axes=(None, 1))(U)
        return jnp.concatenate([x1, dU.reshape(-1), z[n + n * n :]])


def _variational_state_size(m: int) -> int:
    # m = n + n² + 1
    n = int(round((-1 + math.sqrt(1 + 4 * (m - 1))) / 2))
    assert n + n * n + 1 == m
    return n


@single_run_jit
def _variational_impl(scene, x0, t0, t1, args, kw):
    sol = simulate(scene, x0, t0, t1, args, **kw)
    n = x0.shape[0]
    max_impacts = sol.impact_times.shape[0]
    k = sol.num_impacts
    rows = jnp.arange(max_impacts)
    logged = rows < k
    # Segment j runs from start_j to end_j; segments past the last impact are empty.
    ends = jnp.where(logged, sol.impact_times, sol.t_final)
    ends = jnp.concatenate([ends, sol.t_final[None]])
    starts = jnp.concatenate([t0[None], ends[:-1]])
    posts = jnp.where(logged[:, None], sol.impact_post, x0)
    x_starts = jnp.concatenate([x0[None], posts], axis=0)
    pres = jnp.where(logged[:, None], sol.impact_pre, x0)
    surfaces = jnp.where(logged, sol.impact_surface, 0)

    branches = [
        (lambda t_, x_, j=j: saltation_core(scene, j, t_, x_, args))
        for j in range(len(scene.surfaces))
    ]

    def saltation_of(j):
        t_ = jnp.where(logged[j], sol.impact_times[j], t0)
        result = jax.lax.switch(surfaces[j], branches, t_, pres[j])
        S = jnp.where(logged[j], result.matrix, jnp.eye(n, dtype=x0.dtype))
        grazing = logged[j] & (result.status == int(DerivativeStatus.GRAZING))
        undefined = logged[j] & (result.status == int(DerivativeStatus.UNDEFINED))
        return S, grazing, undefined

    saltations, grazing, undefined = jax.vmap(saltation_of)(rows)
    project = None if scene.project is None else _AugmentedProjection(scene.project)
    augmented = Scene(_Augmented(scene.vector_field), project=project)

    def segment(carry, j):
        U, trace = carry
        z0 = jnp.concatenate([x_starts[j], U.reshape(-1), jnp.zeros((1,), x0.dtype)])
        z1, status = free_flow(augmented, z0, starts[j], ends[j], args, kw)
        # The segments past the last impact are empty, and start from a placeholder state
        # (x0): they leave U as it is (a projection would map it onto x0's tangent space).
        z1 = jnp.where(starts[j] == ends[j], z0, z1)
        U1 = z1[n : n + n * n].reshape(n, n)
        trace = trace + z1[-1]
        apply = j < max_impacts
        S = jnp.where(
            apply, saltations[jnp.minimum(j, max_impacts - 1)], jnp.eye(n, dtype=x0.dtype)
        )
        return (S @ U1, trace), status

    (U, trace), statuses = jax.lax.scan(
        segment, (jnp.eye(n, dtype=x0.dtype), jnp.zeros((), x0.dtype)), jnp.arange(max_impacts + 1)
    )
    flights_ok = jnp.all(simulation_ok(statuses))
    status = jnp.where(
        jnp.any(undefined),
        int(DerivativeStatus.UNDEFINED),
        jnp.where(
            ~simulation_ok(sol.status) | ~flights_ok,
            int(DerivativeStatus.SIMULATION_FAILED),
            jnp.where(
                jnp.any(grazing),
                int(DerivativeStatus.GRAZING),
                jnp.where(
                    tree_finite(U), int(DerivativeStatus.OK), int(DerivativeStatus.NONFINITE)
                ),
            ),
        ),
    )
    eye = jnp.eye(n, dtype=x0.dtype)
    return Variational(
        U, sol.x_final, saltations, saltations - eye, trace, sol.impact_times, k, status, sol
    )


def variational_transition(scene: Scene, x0, t0, t1, args=None, **simulate_kwargs) -> Variational:
    r"""Solve the paper's variational system (eq. lin1) along a solution with impacts.

    u' = A(t) u with A(t) = ∂f/∂x(t, x(t)) between impacts, and Δu|_{θ_i} = B_i u(θ_i) at
    each impact, with B_i = S_i − I from the closed-form saltation matrix
    (`grazejax.saltation_matrix`) at the logged pre-impact state (the paper's W_{ix} at an α
    point, eq. derw). The solution is computed by `simulate`; each flight of the variational
    system restarts from the logged post-impact state. The transition matrix equals
    `flow_jacobian(...).jacobian` (the tests check this), and det U = Π det S_i · e^{∫ tr A}.

    Forward time only (`t1 > t0`). Simultaneous impacts are composed in log order.

    **Returns:** a `grazejax.Variational`. At a tangential (γ) impact B_i = O (the (N2)
    value) and the status is GRAZING.
    """
    x0, t0, t1, args, kw = prepare_run(scene, x0, t0, t1, args, "x0", simulate_kwargs)
    if kw["direction"] != 1:
        raise ValueError("variational_transition runs forward in time only (t1 > t0)")
    return _variational_impl(scene, x0, t0, t1, args, kw)
