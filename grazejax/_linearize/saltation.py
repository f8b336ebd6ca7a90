"""The saltation matrix of a surface at a pre-impact state, in closed form from derivatives
of f, Φ and J at the point (`grazejax.saltation_matrix`): the independent check of the
autodiff results, and the jump factor of the variational system."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int

from .._compiler import single_run_jit
from .._roots import safe_divide
from .._scene import Scene
from .common import DerivativeStatus, prepare_point, raise_if_undefined, tree_finite


class Saltation(eqx.Module):
    r"""Result of `grazejax.saltation_matrix`.

    **Fields:**

    - `matrix`: S = DJ + (f⁺ − DJ f⁻ − ∂J/∂t) ∇Φᵀ / (∂Φ/∂t + ∇Φ·f⁻), shape `(n, n)`.
      At an exactly tangential contact: the identity (the (N2) value) with status GRAZING.
    - `x_post`: J(t, x_pre).
    - `approach_rate`: dΦ/dt = ∂Φ/∂t + ∇Φ·f⁻ at the contact (< 0 for an impact).
    - `status`: a `grazejax.DerivativeStatus` code.
    """

    matrix: Float[Array, "n n"]
    x_post: Float[Array, " n"]
    approach_rate: Float[Array, ""]
    status: Int[Array, ""]


def saltation_core(scene: Scene, i: int, t, x, args) -> Saltation:
    surface = scene.surfaces[i]
    f = scene.vector_field
    phi_t, grad = jax.jacfwd(surface.phi, argnums=(0, 1))(t, x, args)
    f_minus = f(t, x, args)
    x_post = surface.jump(t, x, args)
    J_t, DJ = jax.jacfwd(surface.jump, argnums=(0, 1))(t, x, args)
    f_plus = f(t, x_post, args)
    rate = phi_t + grad @ f_minus
    eps = jnp.finfo(x.dtype).eps
    # Tangential to round-off: 64 ulps of the terms that make up the rate (the same
    # floor idea as simulate's contact floor).
    floor = 64 * eps * (jnp.abs(grad) @ jnp.abs(f_minus) + jnp.abs(phi_t))
    defined = tree_finite((surface.phi(t, x, args), phi_t, grad, f_minus, x_post, J_t, DJ, f_plus))
    tangential = jnp.abs(rate) <= floor
    ok = defined & ~tangential
    n = x.shape[0]
    S = DJ + jnp.outer(f_plus - DJ @ f_minus - J_t, grad) * safe_divide(1.0, rate, ok)
    eye = jnp.eye(n, dtype=x.dtype)
    S = jnp.where(ok, S, jnp.where(defined, eye, jnp.nan))
    status = jnp.where(
        ~defined,
        int(DerivativeStatus.UNDEFINED),
        jnp.where(tangential, int(DerivativeStatus.GRAZING), int(DerivativeStatus.OK)),
    )
    return Saltation(S, x_post, rate, status)


saltation_jit = single_run_jit(saltation_core)


def saltation_matrix(scene: Scene, surface_index: int, t, x_pre, args=None) -> Saltation:
    r"""The saltation matrix of surface Γ_i at a pre-impact state, in closed form.

    S = DJ + (f⁺ − DJ f⁻ − ∂J/∂t) ∇Φᵀ / (∂Φ/∂t + ∇Φ·f⁻), with f⁻ = f(t, x_pre),
    f⁺ = f(t, J(t, x_pre)), and DJ, ∂J/∂t, ∇Φ, ∂Φ/∂t from `jax.jacfwd`/`jax.grad` of the
    scene's functions *at the point* (the ∂Φ/∂t and ∂J/∂t terms are those of moving
    surfaces and time-dependent laws). It maps a perturbation of the pre-impact state,
    synchronised in time, to the post-impact one; W_{ix} = S − I is the paper's eq. derw at
    τ = θ. For a wall Φ = x with restitution r, S = [[−r, 0], [(a⁺ + r a⁻)/v⁻, −r]].

    **Arguments:**

    - `scene`, `surface_index`: the scene and the index i of the surface piece.
    - `t`, `x_pre`: the impact time and the state on Γ_i just before the jump.
    - `args`: the scene's parameters.

    **Returns:** a `grazejax.Saltation`. When ∂Φ/∂t + ∇Φ·f⁻ vanishes to round-off
    (tangential contact) `matrix` is the identity, the (N2) value, and the status GRAZING:
    the (N1) value grows like 1/(∇Φ·f⁻). Outside `jit`, a point where Φ, f or J (or their
    derivatives) is not finite raises a `ValueError`.
    """
    i, t, x, args = prepare_point(scene, surface_index, t, x_pre, args)
    result = saltation_jit(scene, i, t, x, args)
    raise_if_undefined(result, scene, i, t, x, args, "saltation_matrix")
    return result
