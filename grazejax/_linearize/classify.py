"""The paper's point types (§2): α, β, γ on Γ_i and α′, β′, γ′ on its image Γ̃_i
(`grazejax.classify_point`)."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from .._compiler import single_run_jit
from .._geometry import boundary_tol, closed_piece, gap_rates, inverse_jump, on_piece
from .._scene import Scene
from .._status import ImpactKind
from .common import DerivativeStatus, prepare_point, raise_if_undefined, tree_finite


class PointType(eqx.Module):
    r"""Result of `grazejax.classify_point`: the paper's point types (§2).

    **Fields:**

    - `kind`: an `grazejax.ImpactKind`: α (Γ_i \ ∂Γ_i, transversal), β (∂Γ_i,
      transversal), γ (tangential), or the primes for the image surface Γ̃_i = J_i(Γ_i)
      (gap Φ̃_i = Φ_i ∘ J_i⁻¹); `NONE` if the point is on neither.
    - `on_surface`, `on_image`, `on_boundary`: membership of Γ_i, Γ̃_i, and of the boundary
      (∂Γ_i or ∂Γ̃_i) of the piece the point was classified on.
    - `approach_rate`: ∂Φ/∂t + ∇Φ·f (or the same for Φ̃ on Γ̃).
    - `normal`: ∇Φ_i (or ∇Φ̃_i) at the point.
    - `axial`: for a tangential point, whether some coordinate of the normal is zero
      (Definition grazingpoint); False otherwise.
    - `status`: a `grazejax.DerivativeStatus` code (`UNDEFINED` if Φ or f is not finite;
      on Γ̃ also if J⁻¹ could not be solved).
    """

    kind: Int[Array, ""]
    on_surface: Bool[Array, ""]
    on_image: Bool[Array, ""]
    on_boundary: Bool[Array, ""]
    approach_rate: Float[Array, ""]
    normal: Float[Array, " n"]
    axial: Bool[Array, ""]
    status: Int[Array, ""]


def _classify_core(scene: Scene, i: int, t, x, args, rtol) -> PointType:
    surface = scene.surfaces[i]
    fx = scene.vector_field(t, x, args)
    where_x = None
    if surface.where is not None:
        where_x = lambda z: closed_piece(surface.where, t, z, args, boundary_tol)  # noqa: E731
    _, _, curvature = gap_rates(surface.phi, scene.vector_field, t, x, args)
    on_s, bd_s, rate_s, grad_s, tan_s, def_s = on_piece(
        surface.phi, where_x, t, x, args, fx, rtol, curvature
    )

    # The image Γ̃ = J(Γ): y ∈ Γ̃ iff z = J⁻¹(y) ∈ Γ; Φ̃ = Φ ∘ J⁻¹. Where J⁻¹ cannot be
    # solved (J not invertible: the paper's (C2) fails) the point is not put on Γ̃.
    z, inv_ok = inverse_jump(surface, t, x, args)
    z = jnp.where(inv_ok, z, x)

    def image_gap(t_, y_, args_):
        zz, _ = inverse_jump(surface, t_, y_, args_)
        return surface.phi(t_, zz, args_)

    where_img = None
    if surface.where is not None:
        where_img = lambda y: closed_piece(surface.where, t, z, args, boundary_tol)  # noqa: E731
    on_i, bd_i, rate_i, grad_i, tan_i, def_i = on_piece(image_gap, where_img, t, x, args, fx, rtol)
    on_i = on_i & inv_ok & def_i & ~on_s

    on_boundary = jnp.where(on_s, bd_s, bd_i & on_i)
    tangential = jnp.where(on_s, tan_s, tan_i) & (on_s | on_i)
    normal = jnp.where(on_i, grad_i, grad_s)
    rate = jnp.where(on_i, rate_i, rate_s)
    base = jnp.where(tangential, 2, jnp.where(on_boundary, 1, 0))
    kind = jnp.where(on_s, base, jnp.where(on_i, base + 3, int(ImpactKind.NONE)))
    scale = jnp.max(jnp.abs(normal))
    axial = tangential & jnp.any(jnp.abs(normal) <= 1e-12 * scale)
    defined = def_s & tree_finite(fx)
    status = jnp.where(
        ~defined,
        int(DerivativeStatus.UNDEFINED),
        jnp.where(tangential, int(DerivativeStatus.GRAZING), int(DerivativeStatus.OK)),
    )
    return PointType(kind, on_s, on_i, on_boundary, rate, normal, axial, status)


_classify_jit = single_run_jit(_classify_core)


def classify_point(
    scene: Scene, surface_index: int, t, x, args=None, *, rtol: float = 1e-10
) -> PointType:
    r"""Classify a point as α, β, γ (on Γ_i) or α′, β′, γ′ (on Γ̃_i = J_i(Γ_i)), paper §2.

    - On the surface: |Φ_i(t, x)| within a few contact floors of `simulate` (64 ulps of
      the gap's scale at 1 + ‖x‖∞; `POINT_SLACK` of them, for the round-off a logged
      point carries from its flight) and `where_i` true on the closed piece.
    - On the boundary ∂Γ_i: `where_i` changes value within 1e-10·(1 + ‖x‖∞) of x in
      some coordinate direction; pieces without `where` have no boundary.
    - Tangential (γ): |∂Φ/∂t + ∇Φ·f| ≤ `rtol`·(|∇Φ|·|f| + |∂Φ/∂t|) + floor, or the
      simulator's own test on Γ_i (the parabola Φ + Φ̇s + Φ̈s²/2 through the point dips at
      most one floor: Φ̇² ≤ 2|Φ̈|·floor), so that contacts `simulate` logs as γ are γ here
      too (tests/test_agreement.py). We follow
      docs/semantics.md: a tangential contact is γ even at an interior point (the paper's
      Definition grazingpoint puts grazing points on ∂Γ; an interior tangency violates
      its (C4), which `grazejax.check_conditions` reports).
    - On the image Γ̃_i: the same tests for Φ̃_i = Φ_i ∘ J_i⁻¹ (J⁻¹ from `inverse_jump`,
      else Newton), with ∂Γ̃_i = J(∂Γ_i).
    - Axial grazing (Definition grazingpoint): some coordinate of the normal is zero. The
      paper writes ∇Φ̃ for both Γ and Γ̃; we use the gradient of the gap of the surface the
      point is on (∇Φ on Γ): at the paper's grazing points DJ is singular, so ∇Φ̃ = DJ⁻ᵀ∇Φ
      does not exist there.

    **Returns:** a `grazejax.PointType`. Its status is GRAZING for a tangential point.
    """
    i, t, x, args = prepare_point(scene, surface_index, t, x, args)
    result = _classify_jit(scene, i, t, x, args, rtol)
    raise_if_undefined(result, scene, i, t, x, args, "classify_point")
    return result
