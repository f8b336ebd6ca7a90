"""Flow Jacobians and gradients of a run with impacts, by autodiff through `simulate`
(`grazejax.flow_jacobian`, `grazejax.scalar_gradient`)."""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._adjoint import loop_kinds
from .._compiler import single_run_jit
from .._scene import Scene
from .._simulate import simulate
from .._solution import Solution
from .._status import ImpactKind
from .common import DerivativeStatus, prepare_run, simulation_ok, tree_finite


class FlowJacobian(eqx.Module):
    """Result of `grazejax.flow_jacobian`.

    **Fields:**

    - `x_final`: x(t1) (or where the run stopped, see `grazejax.Solution`).
    - `jacobian`: ∂x_final/∂x0, shape `(n, n)`, or ∂x_final/∂args (a pytree like `args`
      whose leaves have a leading axis of size n).
    - `status`: a `grazejax.DerivativeStatus` code.
    - `solution`: the `grazejax.Solution` of the run (impact log, simulator status).
    """

    x_final: Float[Array, " n"]
    jacobian: Any
    status: Int[Array, ""]
    solution: Solution


class ScalarGradient(eqx.Module):
    """Result of `grazejax.scalar_gradient`: `value` = loss(solution), `grad` (shaped
    like `x0` or `args`), `status` (`grazejax.DerivativeStatus`) and the `solution`."""

    value: Float[Array, ""]
    grad: Any
    status: Int[Array, ""]
    solution: Solution


def _run_status(sol: Solution, derivative):
    rows = jnp.arange(sol.impact_kind.shape[0]) < sol.num_impacts
    tangential = (sol.impact_kind == int(ImpactKind.GAMMA)) | (
        sol.impact_kind == int(ImpactKind.GAMMA_PRIME)
    )
    grazing = jnp.any(rows & tangential)
    return jnp.where(
        ~simulation_ok(sol.status),
        int(DerivativeStatus.SIMULATION_FAILED),
        jnp.where(
            grazing,
            int(DerivativeStatus.GRAZING),
            jnp.where(
                tree_finite(derivative), int(DerivativeStatus.OK), int(DerivativeStatus.NONFINITE)
            ),
        ),
    )


@single_run_jit
def flow_jacobian_impl(scene, x0, t0, t1, args, wrt, kw):
    def run(x0_, args_):
        sol = simulate(scene, x0_, t0, t1, args_, **kw)
        return sol.x_final, sol

    # Forward mode where the loop supports it: n tangents for n outputs and inputs alike.
    jacobian = jax.jacfwd if loop_kinds(kw.get("adjoint")).forward else jax.jacrev
    if wrt == "x0":
        jac, sol = jacobian(lambda z: run(z, args), has_aux=True)(x0)
    else:
        jac, sol = jacobian(lambda a: run(x0, a), has_aux=True)(args)
    return FlowJacobian(sol.x_final, jac, _run_status(sol, jac), sol)


def flow_jacobian(
    scene: Scene, x0, t0, t1, args=None, *, wrt: str = "x0", **simulate_kwargs
) -> FlowJacobian:
    r"""Jacobian of the final state of a run with impacts, by autodiff through `simulate`.

    It is the exact derivative of the discrete scheme, i.e. the product of the flow
    Jacobians of the flights and the saltation matrices of the impacts (docs/design.md, *Derivatives*),
    to the solver's tolerance. Compiled once per scene and options: pass numbers as
    arrays (`x0`, `t0`, `t1` and `args` are traced).

    **Arguments:**

    - `scene`, `x0`, `t0`, `t1`, `args`: as for `grazejax.simulate`.
    - `wrt`: `"x0"` for ∂x(t1)/∂x0, shape `(n, n)`; `"args"` for ∂x(t1)/∂args (a pytree
      like `args`, each leaf with a leading axis of size n; leaves must be floats).
    - `**simulate_kwargs`: passed to `simulate` (`rtol`, `atol`, `solver`, `max_impacts`,
      `adjoint`, ...). Use tight tolerances (1e-12) for derivatives. The Jacobian is
      `jax.jacfwd` unless `adjoint` is reverse-only
      (`diffrax.RecursiveCheckpointAdjoint()`): then `jax.jacrev`.

    **Returns:** a `grazejax.FlowJacobian`; its `status` is GRAZING if some impact of
    the run was tangential (the derivative does not exist there). A run that stops early
    (`MAX_IMPACTS`, e.g. `max_impacts=1`) ends at the last impact time, which itself depends
    on x0: the Jacobian is then that of the post-impact state at the (moving) impact time.

    **Example:**

    ```python
    ball = grazejax.examples.bouncing_ball()
    r = grazejax.flow_jacobian(ball, [1.0, 0.0], 0.0, 0.6, {"g": 9.81, "e": 0.8}, rtol=1e-12, atol=1e-12)
    r.jacobian  # = Φ(0.6, t1) S Φ(t1, 0), S = [[−e, 0], [(a⁺ + e a⁻)/v⁻, −e]]
    ```
    """
    x0, t0, t1, args, kw = prepare_run(scene, x0, t0, t1, args, wrt, simulate_kwargs)
    return flow_jacobian_impl(scene, x0, t0, t1, args, wrt, kw)


@single_run_jit
def _scalar_gradient_impl(loss, scene, x0, t0, t1, args, wrt, kw):
    def run(x0_, args_):
        sol = simulate(scene, x0_, t0, t1, args_, **kw)
        value = loss(sol)
        return value, (value, sol)

    # One backward pass for any number of inputs where the loop can be reversed; else one
    # tangent per input.
    gradient = jax.grad if loop_kinds(kw.get("adjoint")).reverse else jax.jacfwd
    if wrt == "x0":
        grad, (value, sol) = gradient(lambda z: run(z, args), has_aux=True)(x0)
    else:
        grad, (value, sol) = gradient(lambda a: run(x0, a), has_aux=True)(args)
    return ScalarGradient(value, grad, _run_status(sol, grad), sol)


def scalar_gradient(
    loss, scene: Scene, x0, t0, t1, args=None, *, wrt: str = "x0", **simulate_kwargs
) -> ScalarGradient:
    r"""Gradient of a scalar loss of a run, in the mode that `adjoint` allows.

    With the default adjoint (`diffrax.ForwardMode()`) `jax.grad` through `simulate` raises
    (the impact loop is a `lax.while_loop`): this computes the same gradient with
    `jax.jacfwd`, one tangent per coordinate of `x0` or scalar in `args`. With
    `adjoint=diffrax.RecursiveCheckpointAdjoint()` or `diffrax.DirectAdjoint()` it uses
    `jax.grad`: one backward pass, the choice for many parameters (a forcing profile, a
    restitution law per contact).

    **Arguments:**

    - `loss`: `loss(solution) -> scalar`, a JAX function of the `grazejax.Solution`
      (e.g. `lambda s: s.impact_times[2]` or `lambda s: s.x_final @ s.x_final`). It is a
      static part of the compiled program: define it once, not as a fresh lambda per call.
    - `scene`, `x0`, `t0`, `t1`, `args`, `**simulate_kwargs`: as for `grazejax.simulate`
      (`adjoint` picks the mode, see above).
    - `wrt`: `"x0"` or `"args"`.

    **Returns:** a `grazejax.ScalarGradient` (`value`, `grad`, `status`, `solution`).

    **Example** (∂t_3/∂e of a bouncing ball, closed form 2w(1 + 2e)/g):

    ```python
    third = lambda sol: sol.impact_times[2]
    r = grazejax.scalar_gradient(third, ball, [1.0, 0.0], 0.0, 2.0, {"g": 9.81, "e": 0.8}, wrt="args")
    r.grad["e"]
    ```
    """
    if not callable(loss):
        raise TypeError("loss must be a callable loss(solution) -> scalar")
    x0, t0, t1, args, kw = prepare_run(scene, x0, t0, t1, args, wrt, simulate_kwargs)
    return _scalar_gradient_impl(loss, scene, x0, t0, t1, args, wrt, kw)
