"""One contact geometry: what "on the surface", "tangential", "the floor" and J⁻¹ mean.

Each concept is defined here once and used by the simulator (`_loop`) and by
the analysis modules, so that a point the simulator calls a grazing contact is the point the
analysis calls one, to the same floor.

- `gap_floor`: the round-off floor of a gap value (contacts within it are touches, γ).
- `closed_piece`: is a point in the closed piece Γ_i (to within the state's accuracy), and on
  its boundary ∂Γ_i?
- `gap_rates`: Φ, Φ̇, Φ̈ along a vector field (in either time direction).
- `is_tangential`: the tangency test: the depth Φ̇²/(2|Φ̈|) of the parabola through the
  contact is within the floor.
- `newton_inverse`, `inverse_jump`: J⁻¹ by Newton's method with an implicit-function JVP
  (NaN on failure), or the surface's own `inverse_jump`; `inverse_jump` also says whether it
  succeeded.
- `project_to_surface`: a point moved onto Φ = 0 by minimum-norm Newton steps
  (`newton_step_to_surface`: one of them).
- `on_surface`, `on_piece`: is a given point on Φ = 0 (to within the floor, or a stated
  multiple of it), on the piece, on its boundary, and is it tangential there?
- `Piece`, `forward_piece`, `backward_piece`: a surface as the loop sees it (Γ_i forward,
  the image Γ̃_i = J_i(Γ_i) with J_i⁻¹ backward).
- `contact_frame`, `project_to_contact`: the sliding geometry on M = {Φ = 0, Φ̇ = 0}.
"""

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.lax as lax
import jax.numpy as jnp

from ._roots import safe_divide
from ._scene import Surface

# Contacts whose depth is below this many ulps of the gap's natural scale are "touches":
# reported as grazing (γ). See `gap_floor`.
FLOOR_ULPS = 64.0


def gap_floor(gap, t, x, args, x_scale=None):
    """Round-off floor of a gap value at (t, x): 64 ulps of Σ_k |∂Φ/∂x_k|·|x_k| + |∂Φ/∂t|·|t|.

    This is the documented resolution of contact detection: an excursion deeper than the
    floor is always an impact, a miss by more than the floor never is, and anything in
    between is reported as a grazing contact (γ). It scales with the problem's units.
    `x_scale` overrides |x| per coordinate (the loop passes the largest magnitudes met in
    the current flight, and adds a term for the length of the step).
    """
    t, x = jax.lax.stop_gradient((t, x))
    dphi_dt, dphi_dx = jax.grad(lambda t_, x_: gap(t_, x_, args), argnums=(0, 1))(t, x)
    eps = jnp.finfo(x.dtype).eps
    # Per coordinate: Σ_k |∂Φ/∂x_k|·scale_k, so that a large velocity does not inflate the
    # floor of a gap that depends on positions only (units with L/T ≫ L).
    x_abs = jnp.abs(x) if x_scale is None else jax.lax.stop_gradient(x_scale)
    scale = jnp.sum(jnp.abs(dphi_dx) * x_abs) + jnp.abs(dphi_dt * t)
    return jax.lax.stop_gradient(FLOOR_ULPS * eps * scale + jnp.finfo(x.dtype).tiny)


def closed_piece(where, t, x, args, tol=None):
    """Evaluate `where` on the closure of the piece, to within the state's accuracy.

    Returns `(inside, on_boundary)`. A point counts as inside if `where` holds at it or
    at one of its 2n neighbours x ± δ_k e_k, with δ_k = max(1e3 ulps of ‖x‖∞, tol(x)_k)
    (the loop passes ten times the solver tolerance); it is on the boundary ∂Γ (a β or γ
    point in the paper) if those evaluations disagree. This makes the paper's closed
    pieces (e.g. `x2 <= 0`) robust to the last bits of a computed state: a contact
    exactly at ∂Γ is not lost to x2 = +1e-12.
    """
    if where is None:
        return jnp.array(True), jnp.array(False)
    x = jax.lax.stop_gradient(x)
    n = x.shape[0]
    eps = jnp.finfo(x.dtype).eps
    delta = 1e3 * eps * (jnp.abs(x) + jnp.max(jnp.abs(x)) + jnp.finfo(x.dtype).tiny)
    if tol is not None:
        delta = jnp.maximum(delta, jax.lax.stop_gradient(tol(x)))
    offsets = jnp.concatenate(
        [jnp.zeros((1, n), x.dtype), jnp.diag(delta), -jnp.diag(delta)], axis=0
    )
    values = jax.vmap(lambda dx: jnp.asarray(where(t, x + dx, args), bool))(offsets)
    inside = jnp.any(values)
    on_boundary = inside & ~jnp.all(values)
    return inside, on_boundary



@dataclass(frozen=True)
class Piece:
    """A surface as the loop sees it, in the loop's own (possibly reversed) time."""

    gap: Callable  # gap(t, x, args): Φ_i, or Φ̃_i = Φ_i ∘ J_i⁻¹ in backward time
    jump: Callable  # J_i, or J_i⁻¹
    inside: Callable  # inside(t, x, args) -> (in closed piece, on boundary)
    signs: tuple[int, ...]  # +1: impact on downward crossings; (+1, -1): either way
    check_jump_side: bool  # forward, impenetrable surfaces: J must land on the free side
    floor: Callable  # floor(t, x, args, x_scale): the contact floor of `gap` (see gap_floor)


def newton_inverse(surface: Surface) -> Callable:
    """J⁻¹ by Newton's method, with a hand-written implicit-function-theorem JVP.

    Why not `optx.root_find`: its implicit differentiation calls `lineax.linear_solve`,
    which *raises* on a singular Jacobian (a jump that is not invertible, e.g. v → 0·v),
    killing a whole vmapped batch. Here a failed or singular solve gives a NaN preimage —
    no impact is detected through it — and never an exception.
    """

    def jump_jacobian(t, z, args):
        return jax.jacfwd(lambda zz: surface.jump(t, zz, args))(z)

    def solve(t, x, args):
        t, x, args = jax.lax.stop_gradient((t, x, args))

        def cond(carry):
            z, it, converged = carry
            return (it < 50) & ~converged & jnp.all(jnp.isfinite(z))

        def body(carry):
            z, it, _ = carry
            step = jnp.linalg.solve(jump_jacobian(t, z, args), surface.jump(t, z, args) - x)
            z = z - step
            converged = jnp.max(jnp.abs(step)) <= 1e-14 * (1 + jnp.max(jnp.abs(z)))
            return z, it + 1, converged

        guess = 2 * x - surface.jump(t, x, args)
        z, _, _ = lax.while_loop(cond, body, (guess, jnp.array(0), jnp.array(False)))
        residual = jnp.max(jnp.abs(surface.jump(t, z, args) - x))
        ok = jnp.all(jnp.isfinite(z)) & (residual <= 1e-10 * (1 + jnp.max(jnp.abs(x))))
        return jnp.where(ok, z, jnp.nan)

    @jax.custom_jvp
    def inverse(t, x, args):
        return solve(t, x, args)

    @inverse.defjvp
    def inverse_jvp(primals, tangents):
        # J(t, z, args) = x  ⇒  D_zJ dz = dx − D_tJ dt − D_argsJ dargs.
        t, x, args = primals
        dt, dx, dargs = tangents
        z = solve(t, x, args)
        _, dJ = jax.jvp(lambda tt, aa: surface.jump(tt, z, aa), (t, args), (dt, dargs))
        dz = jnp.linalg.solve(jump_jacobian(t, z, args), dx - dJ)
        return z, dz

    return inverse


def inverse_jump(surface: Surface, t, y, args):
    """`(J⁻¹(y), ok)`: the surface's `inverse_jump`, else `newton_inverse`; y where not ok."""
    inverse = surface.inverse_jump or newton_inverse(surface)
    z = inverse(t, y, args)
    ok = jnp.all(jnp.isfinite(z))
    return jnp.where(ok, z, y), ok


def analysis_scale(x):
    """|x| per coordinate for the floor of a *given* point: 1 + ‖x‖∞ in every coordinate.

    The loop knows the magnitudes met in its flight; an analysis has one point only, and
    the paper's boundaries and grazing points often lie at x = 0, where |x_k| would give a
    zero floor.
    """
    return jnp.full_like(x, 1.0 + jnp.max(jnp.abs(x)))


def on_surface(gap, t, x, args, slack=1.0):
    """|Φ(t, x)| within `slack` floors (`gap_floor` at `analysis_scale`): on Φ = 0."""
    return jnp.abs(gap(t, x, args)) <= slack * gap_floor(gap, t, x, args, analysis_scale(x))


def newton_step_to_surface(gap, t, x, args):
    """One minimum-norm Newton step of x towards Φ(t, ·) = 0, x − Φ∇Φ/|∇Φ|² (none where
    ∇Φ = 0)."""
    g, grad = jax.value_and_grad(gap, argnums=1)(t, x, args)
    norm2 = grad @ grad
    return x - safe_divide(g, norm2, norm2 > 0) * grad


def project_to_surface(gap, t, x, args, iterations: int = 60):
    """x moved onto Φ(t, ·) = 0 by minimum-norm Newton steps along ∇Φ (none where ∇Φ = 0)."""
    return lax.fori_loop(0, iterations, lambda _, x_: newton_step_to_surface(gap, t, x_, args), x)


# A given point is on ∂Γ if `where` changes within this relative distance of it.
# closed_piece's own default (1e3 ulps of |x|) vanishes at x = 0, where the paper's
# boundaries lie.
BOUNDARY_RTOL = 1e-10


def boundary_tol(x):
    return jnp.full_like(x, BOUNDARY_RTOL) * (1.0 + jnp.max(jnp.abs(x)))


# A given point is on Φ = 0 within this many floors at `analysis_scale`: a point the
# simulator logged carries the round-off of the flight that reached it, which the loop's
# floor measures by the flight's largest magnitudes and the step's length (a touch at
# x ≈ 0 after a flight from |x| = 2 sat 1.1 floors of the point's own scale off Φ = 0).
POINT_SLACK = 4.0


def on_piece(gap, where, t, x, args, fx, rtol, curvature=None):
    """A given point against {gap = 0} ∩ piece, with the simulator's floor.

    Returns `(on, on_boundary, rate, normal, tangential, defined)`: on the closed piece,
    on its boundary, the approach rate ∂Φ/∂t + ∇Φ·f, ∇Φ, tangency, and whether Φ and its
    derivatives are finite. Tangency: |rate| within `rtol` of its terms' size plus the
    floor, or — given the curvature Φ̈ along the flow — the simulator's own test
    (`is_tangential`: the parabola through the point dips at most one floor), so that a
    contact the simulator logs as γ is classified γ.
    `where(x) -> (inside, on_boundary)` or None (the whole zero set).
    """
    g = gap(t, x, args)
    g_t, grad = jax.jacfwd(gap, argnums=(0, 1))(t, x, args)
    rate = g_t + grad @ fx
    floor = gap_floor(gap, t, x, args, analysis_scale(x))
    on = jnp.abs(g) <= POINT_SLACK * floor
    if where is None:
        inside, boundary = jnp.array(True), jnp.array(False)
    else:
        inside, boundary = where(x)
    size = jnp.abs(grad) @ jnp.abs(fx) + jnp.abs(g_t)
    tangential = jnp.abs(rate) <= rtol * size + floor
    if curvature is not None:
        tangential = tangential | is_tangential(rate, curvature, floor)
    leaves = jnp.stack([jnp.all(jnp.isfinite(v)) for v in (g, g_t, grad)])
    return on & inside, boundary & on & inside, rate, grad, tangential, jnp.all(leaves)


def forward_piece(surface: Surface) -> Piece:
    def inside(t, x, args, tol):
        return closed_piece(surface.where, t, x, args, tol)

    def floor(t, x, args, x_scale):
        return gap_floor(surface.phi, t, x, args, x_scale)

    return Piece(surface.phi, surface.jump, inside, (1,), surface.impenetrable, floor)


def backward_piece(surface: Surface, vector_field) -> Piece:
    inverse = surface.inverse_jump or newton_inverse(surface)

    def gap(t, x, args):
        return surface.phi(t, inverse(t, x, args), args)

    def inside(t, x, args, tol):
        # x ∈ Γ̃ is an impact point in backward time iff z = J⁻¹(x) is a forward impact
        # point: inside the piece, and met while Φ was not increasing.
        z = jax.lax.stop_gradient(inverse(t, x, args))
        in_piece, on_boundary = closed_piece(surface.where, t, z, args, tol)
        _, approach = jax.jvp(
            lambda t_, z_: surface.phi(t_, z_, args),
            (t, z),
            (jnp.ones_like(t), vector_field(t, z, args)),
        )
        floor = gap_floor(surface.phi, t, z, args)
        scale = jnp.sqrt(floor * jnp.max(jnp.abs(vector_field(t, z, args))) + floor)
        ok = in_piece & (approach <= scale) & jnp.all(jnp.isfinite(z))
        return ok, on_boundary

    def floor(t, x, args, x_scale):
        # The floor of Φ at the preimage z: no derivative through the Newton inverse,
        # whose Jacobian may be singular where the jump is not invertible.
        z = jax.lax.stop_gradient(inverse(t, x, args))
        return gap_floor(surface.phi, t, z, args, x_scale)

    return Piece(gap, inverse, inside, (1, -1), False, floor)


def gap_rates(gap, field, t, x, args, sign=1.0, time_sign=1.0):
    """`(g, ġ, g̈)` of g = sign·Φ along the flow of `field`, in the time direction `time_sign`.

    Derivatives are with respect to the loop's clock s, t = t0 + time_sign·s: backward
    runs see the flow of −f.
    """
    ones = time_sign * jnp.ones_like(t)

    def rate(t_, x_):
        return jax.jvp(
            lambda tt, xx: sign * gap(tt, xx, args), (t_, x_), (ones, time_sign * field(t_, x_, args))
        )

    (g, gd), (_, gdd) = jax.jvp(rate, (t, x), (ones, time_sign * field(t, x, args)))
    return g, gd, gdd


def is_tangential(rate, curvature, floor):
    """Tangency within round-off: the parabola g + ġ s + g̈ s²/2 dips at most `floor` deep
    (ġ² ≤ 2|g̈|·floor), so the contact cannot be told from a touch."""
    return rate**2 <= 2 * jnp.abs(curvature) * floor


def contact_frame(gap, jump, field, t, y, args):
    """Φ, Φ̇, Φ̈ along the free flow; ∇Φ, ∇Φ̇; the contact force direction d.

    d is the direction in which the jump law applies its impulses: (DJ − I)∇Φ̇ with its ∇Φ
    component removed (for Newton's law on a mechanical system, the normal on the
    velocities); the least-norm ∇Φ̇ direction where the jump applies no impulse (DJ = I).
    """
    ones = jnp.ones_like(t)

    def phi(t_, y_):
        return gap(t_, y_, args)

    def phi_dot(t_, y_):
        return jax.jvp(phi, (t_, y_), (ones, field(t_, y_, args)))[1]

    g, grad_phi = jax.value_and_grad(phi, argnums=1)(t, y)
    gd, gdd = jax.jvp(phi_dot, (t, y), (ones, field(t, y, args)))
    grad_gd = jax.grad(phi_dot, argnums=1)(t, y)
    norm2 = jnp.sum(grad_phi**2)

    def tangent(v):  # the part of v along which Φ does not change
        return v - safe_divide(jnp.dot(v, grad_phi), norm2, norm2 > 0) * grad_phi

    impulse = jax.jacfwd(lambda y_: jump(t, y_, args))(y) - jnp.eye(y.shape[0], dtype=y.dtype)
    d_impulse = tangent(impulse @ grad_gd)
    d_least = tangent(grad_gd)
    usable = jnp.abs(jnp.dot(grad_gd, d_impulse)) > 1e-8 * jnp.sqrt(
        jnp.sum(grad_gd**2) * jnp.sum(d_impulse**2)
    )
    d = jnp.where(usable, d_impulse, d_least)
    return g, gd, gdd, grad_phi, grad_gd, d


def project_to_contact(gap, jump, field, t, y, args):
    """The nearby point of M = {Φ = 0, Φ̇ = 0}: Φ removed along ∇Φ, then Φ̇ along d."""
    g, _, _, grad_phi, _, _ = contact_frame(gap, jump, field, t, y, args)
    norm2 = jnp.sum(grad_phi**2)
    y = y - safe_divide(g, norm2, norm2 > 0) * grad_phi
    _, gd, _, _, grad_gd, d = contact_frame(gap, jump, field, t, y, args)
    gain = jnp.dot(grad_gd, d)
    return y - safe_divide(gd, gain, gain != 0) * d
