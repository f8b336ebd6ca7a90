r"""Differentiable analysis through impacts: flow Jacobians, saltation, τ_i, W_i, B_i.

Everything here is built on [`grazejax.simulate`][] and JAX's forward-mode autodiff: no
derivative of a flow is written by hand. `simulate` locates each event with one Newton
step on the time, so `jax.jacfwd` through it carries the implicit-function-theorem
tangent of every impact time, and the Jacobian of a run with impacts is the product of
flow Jacobians and saltation matrices (docs/design.md, *Derivatives*). The closed forms below (the
saltation matrix, eqs. dert and derw of the paper) are evaluated from derivatives of f,
Φ and J *at a point* and from Jacobians of impact-free flows: they are the independent
checks of the autodiff results, and the tests compare the two.

Paper objects (Akhmet & Kıvılcım, *Discontinuous dynamics with grazing points*, §2.1, §3):

- the meeting time τ_i(x): when the flow of x' = f from (θ, x) reaches Γ_i
  ([`grazejax.meeting_time`][], gradient eq. dert);
- the B-equivalence map W_i(x) = ψ(θ) − x (eq. W-map): flow to Γ_i, jump, flow back to
  θ ([`grazejax.w_map`][], Jacobian eq. derw), with W_i = 0 when the flow does not meet
  Γ_i near θ;
- the linearization u' = A(t) u, Δu = B_i u (eq. lin1) along a solution
  ([`grazejax.variational_transition`][]), with B_i = W_{ix} = S_i − I at α points;
- the bivalued B_i at β/γ points, as one-sided limits over impacting (N1) and
  non-impacting (N2) neighbours ([`grazejax.one_sided_jacobians`][]), and the (A2)
  diagnostic, the growth exponent of ‖W_x‖ at a grazing point ([`grazejax.a2_diagnostic`][]).

**Reverse mode.** [`grazejax.flow_jacobian`][] and [`grazejax.scalar_gradient`][] take
`simulate`'s `adjoint=`: with the default (`diffrax.ForwardMode()`) they differentiate in
forward mode (one tangent per input coordinate, cheap for small state and parameter
spaces); with `diffrax.RecursiveCheckpointAdjoint()` or `diffrax.DirectAdjoint()`,
`scalar_gradient` uses `jax.grad` (one backward pass, whatever the number of parameters)
and `flow_jacobian` uses `jax.jacrev` where forward mode is unavailable. The pointwise
analyses below (τ_i, W_i, classification) are forward mode only.

**Every result has a status.** Every result carries a [`grazejax.DerivativeStatus`][]. Near
grazing ∇Φ·f → 0 and the true derivatives grow without bound (like 1/(∇Φ·f)); they are
returned as computed. At an exactly tangential contact the derivative does not exist: the
pointwise analyses (τ_i, W_i) hold the (N2) one-sided value (no jump: B = O, S = I), a run's
flow Jacobian and gradient are NaN (the event time of a touch has no derivative: `simulate`
gives it a NaN tangent), each with the status `GRAZING`; use
[`grazejax.one_sided_jacobians`][] for the one-sided linearizations. Divisions by ∇Φ·f use
the double-`where` so that no NaN reaches a tangent elsewhere. Values are otherwise NaN only
together with the status `UNDEFINED` (Φ_i, f or J_i, or their derivatives, are not finite at
the point: outside `jit` this raises a `ValueError` instead) or `SIMULATION_FAILED`.
"""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._adjoint import loop_kinds
from ._compiler import single_run_jit
from ._flow import flight_kwargs, free_flow
from ._geometry import boundary_tol, closed_piece, gap_rates, inverse_jump, on_piece
from ._roots import safe_divide
from ._scene import Scene
from ._simulate import simulate
from ._solution import Solution
from ._status import ImpactKind, Status, StatusCode
from ._validate import is_concrete

# --------------------------------------------------------------------------------------
# Status
# --------------------------------------------------------------------------------------


class DerivativeStatus(StatusCode):
    """How trustworthy a derivative is. Stored as an integer array in each result's `status`.

    Inside `jax.jit` / `jax.vmap` nothing raises: `DerivativeStatus(int(r.status))` reads it.
    """

    OK = 0, "derivative of a run with transversal contacts only"
    """A derivative of a run whose contacts are all transversal (α, β)."""
    GRAZING = 1, "tangential contact (γ): derivative does not exist; (N2) value returned"
    """A contact is tangential (γ): the derivative does not exist there. The result holds
    the (N2) one-sided value (no jump); the (N1) side diverges like 1/(∇Φ·f)."""
    NO_CONTACT = 2, "the flow does not meet the surface in the window (W = 0)"
    """The flow does not meet Γ_i within the search window: τ_i = inf, W_i = 0 and W_{ix} = 0
    (the paper's convention for (N2) neighbours)."""
    SIMULATION_FAILED = 3, "simulate did not reach t1 (see the solution's status)"
    """`simulate` ended with a status other than SUCCESS / MAX_IMPACTS (see `solution`)."""
    UNDEFINED = 4, "Φ, f or J (or a first derivative) is not finite at the point"
    """Φ_i, f or J_i (or their first derivatives) are not finite at the point."""
    NONFINITE = 5, "the derivative is not finite"
    """The derivative itself came out non-finite."""



# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------


class FlowJacobian(eqx.Module):
    """Result of [`grazejax.flow_jacobian`][].

    **Fields:**

    - `x_final`: x(t1) (or where the run stopped, see [`grazejax.Solution`][]).
    - `jacobian`: ∂x_final/∂x0, shape `(n, n)`, or ∂x_final/∂args (a pytree like `args`
      whose leaves have a leading axis of size n).
    - `status`: a [`grazejax.DerivativeStatus`][] code.
    - `solution`: the [`grazejax.Solution`][] of the run (impact log, simulator status).
    """

    x_final: Float[Array, " n"]
    jacobian: Any
    status: Int[Array, ""]
    solution: Solution


class ScalarGradient(eqx.Module):
    """Result of [`grazejax.scalar_gradient`][]: `value` = loss(solution), `grad` (shaped
    like `x0` or `args`), `status` ([`grazejax.DerivativeStatus`][]) and the `solution`."""

    value: Float[Array, ""]
    grad: Any
    status: Int[Array, ""]
    solution: Solution


class Saltation(eqx.Module):
    r"""Result of [`grazejax.saltation_matrix`][].

    **Fields:**

    - `matrix`: S = DJ + (f⁺ − DJ f⁻ − ∂J/∂t) ∇Φᵀ / (∂Φ/∂t + ∇Φ·f⁻), shape `(n, n)`.
      At an exactly tangential contact: the identity (the (N2) value) with status GRAZING.
    - `x_post`: J(t, x_pre).
    - `approach_rate`: dΦ/dt = ∂Φ/∂t + ∇Φ·f⁻ at the contact (< 0 for an impact).
    - `status`: a [`grazejax.DerivativeStatus`][] code.
    """

    matrix: Float[Array, "n n"]
    x_post: Float[Array, " n"]
    approach_rate: Float[Array, ""]
    status: Int[Array, ""]


class Meeting(eqx.Module):
    r"""Result of [`grazejax.meeting_time`][]: the paper's τ_i(x) and its gradient.

    **Fields:**

    - `tau`: the meeting time τ_i (the start time t where `met` is False).
    - `x_meet`: ξ(τ_i), the pre-jump state on Γ_i (x where `met` is False).
    - `grad`: ∇τ_i(x), shape `(n,)`, by `jax.jacfwd` through the event (eq. dert).
    - `x_meet_jacobian`: dξ(τ_i(x))/dx = X + f ∇τᵀ, shape `(n, n)`.
    - `kind`: the [`grazejax.ImpactKind`][] of the meeting point (α, β or γ).
    - `met`: whether the flow meets Γ_i within `[t − lookback, t + horizon]`.
    - `status`: a [`grazejax.DerivativeStatus`][] code.
    """

    tau: Float[Array, ""]
    x_meet: Float[Array, " n"]
    grad: Float[Array, " n"]
    x_meet_jacobian: Float[Array, "n n"]
    kind: Int[Array, ""]
    met: Bool[Array, ""]
    status: Int[Array, ""]


class WMap(eqx.Module):
    r"""Result of [`grazejax.w_map`][]: the paper's W_i(x) (eq. W-map) and W_{ix} (eq. derw).

    **Fields:**

    - `value`: W_i(x) = ψ(θ) − x, where ψ is the flow started from J_i(ξ(τ_i)) at τ_i and
      θ = `t`; 0 when the flow does not meet Γ_i in the window.
    - `jacobian`: W_{ix}, shape `(n, n)`, by `jax.jacfwd`. The linearization's jump matrix
      is B_i = W_{ix}; the full map x ↦ x + W_i(x) has Jacobian I + W_{ix} (= S at α points
      on the orbit).
    - `tau`, `x_meet`, `kind`, `met`: as in [`grazejax.Meeting`][].
    - `status`: a [`grazejax.DerivativeStatus`][] code.
    """

    value: Float[Array, " n"]
    jacobian: Float[Array, "n n"]
    tau: Float[Array, ""]
    x_meet: Float[Array, " n"]
    kind: Int[Array, ""]
    met: Bool[Array, ""]
    status: Int[Array, ""]


class ClosedForm(eqx.Module):
    r"""Result of [`grazejax.closed_form_linearization`][]: eqs. dert and derw.

    With X = ∂φ(τ; t, x)/∂x and Y = ∂φ(t; τ, y)/∂y at y = J(ξ(τ)) (Jacobians of
    impact-free flows at *fixed* times, no event differentiated):

    - `grad_tau` = −Xᵀ∇Φ / (∂Φ/∂t + ∇Φ·f⁻) (eq. dert),
    - `w_jacobian` = Y S X − I (eq. derw; it reduces to S − I when τ = t),
    - `saltation`: the [`grazejax.Saltation`][] at ξ(τ),
    - `status`: a [`grazejax.DerivativeStatus`][] code.
    """

    grad_tau: Float[Array, " n"]
    w_jacobian: Float[Array, "n n"]
    saltation: Saltation
    status: Int[Array, ""]


class PointType(eqx.Module):
    r"""Result of [`grazejax.classify_point`][]: the paper's point types (§2).

    **Fields:**

    - `kind`: an [`grazejax.ImpactKind`][]: α (Γ_i \ ∂Γ_i, transversal), β (∂Γ_i,
      transversal), γ (tangential), or the primes for the image surface Γ̃_i = J_i(Γ_i)
      (gap Φ̃_i = Φ_i ∘ J_i⁻¹); `NONE` if the point is on neither.
    - `on_surface`, `on_image`, `on_boundary`: membership of Γ_i, Γ̃_i, and of the boundary
      (∂Γ_i or ∂Γ̃_i) of the piece the point was classified on.
    - `approach_rate`: ∂Φ/∂t + ∇Φ·f (or the same for Φ̃ on Γ̃).
    - `normal`: ∇Φ_i (or ∇Φ̃_i) at the point.
    - `axial`: for a tangential point, whether some coordinate of the normal is zero
      (Definition grazingpoint); False otherwise.
    - `status`: a [`grazejax.DerivativeStatus`][] code (`UNDEFINED` if Φ or f is not finite;
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


class Variational(eqx.Module):
    r"""Result of [`grazejax.variational_transition`][]: the paper's system (lin1) solved.

    u' = A(t) u with A = ∂f/∂x along the solution, Δu = B_i u at each impact θ_i, with
    B_i = S_i − I (S_i the saltation matrix at the logged pre-impact state).

    **Fields:**

    - `transition`: U(t1) with U(t0) = I: equal to ∂x(t1)/∂x0 (tested against `jacfwd`).
    - `x_final`: the run's final state.
    - `saltations`: S_i per impact, shape `(max_impacts, n, n)` (identity past `num_impacts`).
    - `jump_matrices`: B_i = S_i − I, same shape.
    - `trace_integral`: ∫ tr A(t) dt over the run (Liouville: det U = Π det S_i · e^∫trA).
    - `impact_times`, `num_impacts`: from the run.
    - `status`: a [`grazejax.DerivativeStatus`][] code (GRAZING if an impact was tangential:
      its B_i is O, the (N2) value).
    - `solution`: the [`grazejax.Solution`][] of the run.
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


class OneSidedLimit(eqx.Module):
    r"""W_{ix} along one sequence of neighbours x* + s·d_k·v, d_k → 0 (NumPy arrays).

    **Fields:**

    - `distances`: the d_k (decreasing).
    - `jacobians`: W_{ix} at each neighbour, shape `(k, n, n)`.
    - `met`: whether each neighbour's flow meets Γ_i (N1) or not (N2).
    - `condition`: `"N1"` (all meet), `"N2"` (none meets) or `"mixed"`.
    - `norm_exponent`: q in ‖W_{ix}‖ ≈ C d^q (least squares on the smallest half of the
      distances); 0 for a bounded sequence, −1/2 for Nordmark's square-root singularity.
    - `limit`: the extrapolated limit (NaN when the sequence diverges).
    - `error`: estimated error of `limit` (difference of the last two Richardson
      extrapolations).
    - `converged`: whether a limit exists to within `error` ≤ 1e-6·(1 + ‖limit‖).
    - `note`: how the limit was obtained, in words.
    """

    distances: Any
    jacobians: Any
    met: Any
    condition: str
    norm_exponent: float
    limit: Any
    error: float
    converged: bool
    note: str


class OneSidedLinearization(eqx.Module):
    r"""Result of [`grazejax.one_sided_jacobians`][]: the bivalued B_i at a β/γ point.

    `plus` and `minus` are the [`grazejax.OneSidedLimit`][]s along x* ± d·v. `n1` and
    `n2` are the same two, sorted by which side meets Γ_i (None if neither/both do):
    B_i = `n1.limit` for impacting neighbours (N1), `n2.limit` (= O) for the others (N2).
    """

    point: Any
    direction: Any
    plus: OneSidedLimit
    minus: OneSidedLimit
    n1: OneSidedLimit | None
    n2: OneSidedLimit | None


class A2Diagnostic(eqx.Module):
    r"""Result of [`grazejax.a2_diagnostic`][]: is W_i differentiable at a grazing point?

    **Fields:**

    - `distances`: the d_k; the neighbours are x* + d_k·v (impacting side, N1).
    - `w_norms`: ‖W_{ix}‖₂ at each neighbour; `w_exponent`: the fitted q in ‖W_{ix}‖ ∝ d^q.
    - `flow_norms`: ‖∂x(t + h)/∂x(t − h)‖₂ of the full system from the neighbour's
      upstream point (the time-synchronised flow Jacobian across the impact);
      `flow_exponent`: its fitted exponent.
    - `approach_rates`: ∂Φ/∂t + ∇Φ·f at each neighbour's meeting point.
    - `w_jacobians`, `flow_jacobians`: the matrices, shape `(k, n, n)`.
    - `verdict`: the reading of the exponent, in words.
    """

    point: Any
    direction: Any
    distances: Any
    w_norms: Any
    w_exponent: float
    flow_norms: Any
    flow_exponent: float
    approach_rates: Any
    w_jacobians: Any
    flow_jacobians: Any
    verdict: str


# --------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------


def _float_array(x):
    # An explicit dtype: Python scalars would otherwise give weakly-typed arrays, and a
    # weak and a strong float64 are different signatures to jit (a silent recompile).
    x = jnp.asarray(x)
    dtype = x.dtype if jnp.issubdtype(x.dtype, jnp.inexact) else jnp.float64
    return jnp.asarray(x, dtype=dtype)


def _args_arrays(args):
    """Numbers in `args` become arrays, so that changing them never recompiles."""
    if args is None:
        return None
    return jax.tree.map(
        lambda leaf: (
            _float_array(leaf)
            if isinstance(leaf, (int, float, np.ndarray, np.generic, jax.Array))
            and not isinstance(leaf, bool)
            else leaf
        ),
        args,
    )


def _simulation_ok(status):
    return (status == int(Status.SUCCESS)) | (status == int(Status.MAX_IMPACTS))


def _tree_finite(tree):
    leaves = [jnp.all(jnp.isfinite(leaf)) for leaf in jax.tree.leaves(tree)]
    return jnp.all(jnp.stack(leaves)) if leaves else jnp.array(True)


def _direction(t0, t1, kw):
    if kw.get("direction") is not None:
        return int(kw["direction"])
    if not is_concrete(t0, t1):
        raise ValueError(
            "t0/t1 are traced (inside jit/vmap): pass direction=+1 or -1 (as for simulate)"
        )
    return 1 if float(t1) > float(t0) else -1


def _check_surface_index(scene, surface_index):
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if not isinstance(surface_index, (int, np.integer)) or not (
        0 <= surface_index < len(scene.surfaces)
    ):
        raise ValueError(
            f"surface_index must be an integer in [0, {len(scene.surfaces)}), got {surface_index!r}"
        )
    return int(surface_index)


def _raise_if_undefined(result, scene, surface_index, t, x, args, what):
    """Outside jit, an undefined point is a usage error: say exactly what is undefined."""
    if not is_concrete(result.status, t, x, args):
        return
    if int(result.status) != DerivativeStatus.UNDEFINED:
        return
    surface = scene.surfaces[surface_index]
    label = scene.surface_name(surface_index)
    checks = [
        ("Φ", lambda: surface.phi(t, x, args)),
        ("∇Φ", lambda: jax.jacfwd(surface.phi, argnums=(0, 1))(t, x, args)),
        ("f", lambda: scene.vector_field(t, x, args)),
        ("∂f/∂x", lambda: jax.jacfwd(scene.vector_field, argnums=1)(t, x, args)),
        ("J", lambda: surface.jump(t, x, args)),
        ("DJ", lambda: jax.jacfwd(surface.jump, argnums=(0, 1))(t, x, args)),
    ]
    bad = [name for name, fn in checks if not bool(_tree_finite(fn()))]
    names = ", ".join(bad) if bad else "a derived quantity (J⁻¹, or Φ̃ on the image surface)"
    raise ValueError(
        f"{what}: {names} of surface {label} not finite at t = {float(t)!r}, "
        f"x = {np.asarray(x).tolist()}: the derivative is undefined there"
    )


def _prepare_point(scene, surface_index, t, x, args):
    i = _check_surface_index(scene, surface_index)
    x = _float_array(x)
    if x.ndim != 1:
        raise ValueError(f"x must be a state vector of shape (n,), got shape {x.shape}")
    t = _float_array(t)
    if t.ndim != 0:
        raise ValueError(f"t must be a scalar, got shape {t.shape}")
    return i, t, x, _args_arrays(args)


# --------------------------------------------------------------------------------------
# Flow Jacobians and forward-mode gradients
# --------------------------------------------------------------------------------------


def _run_status(sol: Solution, derivative):
    rows = jnp.arange(sol.impact_kind.shape[0]) < sol.num_impacts
    tangential = (sol.impact_kind == int(ImpactKind.GAMMA)) | (
        sol.impact_kind == int(ImpactKind.GAMMA_PRIME)
    )
    grazing = jnp.any(rows & tangential)
    return jnp.where(
        ~_simulation_ok(sol.status),
        int(DerivativeStatus.SIMULATION_FAILED),
        jnp.where(
            grazing,
            int(DerivativeStatus.GRAZING),
            jnp.where(
                _tree_finite(derivative), int(DerivativeStatus.OK), int(DerivativeStatus.NONFINITE)
            ),
        ),
    )


def _prepare_run(scene, x0, t0, t1, args, wrt, kw):
    if wrt not in ("x0", "args"):
        raise ValueError(f'wrt must be "x0" or "args", got {wrt!r}')
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if wrt == "args" and args is None:
        raise ValueError('wrt="args" needs args')
    kw = dict(kw)
    kw["direction"] = _direction(t0, t1, kw)
    if kw.pop("throw", False):
        raise ValueError("throw=True is not supported here: read the result's status")
    return _float_array(x0), _float_array(t0), _float_array(t1), _args_arrays(args), kw


@single_run_jit
def _flow_jacobian_impl(scene, x0, t0, t1, args, wrt, kw):
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

    - `scene`, `x0`, `t0`, `t1`, `args`: as for [`grazejax.simulate`][].
    - `wrt`: `"x0"` for ∂x(t1)/∂x0, shape `(n, n)`; `"args"` for ∂x(t1)/∂args (a pytree
      like `args`, each leaf with a leading axis of size n; leaves must be floats).
    - `**simulate_kwargs`: passed to `simulate` (`rtol`, `atol`, `solver`, `max_impacts`,
      `adjoint`, ...). Use tight tolerances (1e-12) for derivatives. The Jacobian is
      `jax.jacfwd` unless `adjoint` is reverse-only
      (`diffrax.RecursiveCheckpointAdjoint()`): then `jax.jacrev`.

    **Returns:** a [`grazejax.FlowJacobian`][]; its `status` is GRAZING if some impact of
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
    x0, t0, t1, args, kw = _prepare_run(scene, x0, t0, t1, args, wrt, simulate_kwargs)
    return _flow_jacobian_impl(scene, x0, t0, t1, args, wrt, kw)


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

    - `loss`: `loss(solution) -> scalar`, a JAX function of the [`grazejax.Solution`][]
      (e.g. `lambda s: s.impact_times[2]` or `lambda s: s.x_final @ s.x_final`). It is a
      static part of the compiled program: define it once, not as a fresh lambda per call.
    - `scene`, `x0`, `t0`, `t1`, `args`, `**simulate_kwargs`: as for [`grazejax.simulate`][]
      (`adjoint` picks the mode, see above).
    - `wrt`: `"x0"` or `"args"`.

    **Returns:** a [`grazejax.ScalarGradient`][] (`value`, `grad`, `status`, `solution`).

    **Example** (∂t_3/∂e of a bouncing ball, closed form 2w(1 + 2e)/g):

    ```python
    third = lambda sol: sol.impact_times[2]
    r = grazejax.scalar_gradient(third, ball, [1.0, 0.0], 0.0, 2.0, {"g": 9.81, "e": 0.8}, wrt="args")
    r.grad["e"]
    ```
    """
    if not callable(loss):
        raise TypeError("loss must be a callable loss(solution) -> scalar")
    x0, t0, t1, args, kw = _prepare_run(scene, x0, t0, t1, args, wrt, simulate_kwargs)
    return _scalar_gradient_impl(loss, scene, x0, t0, t1, args, wrt, kw)


# --------------------------------------------------------------------------------------
# Saltation (closed form at a point: the independent check)
# --------------------------------------------------------------------------------------


def _saltation_core(scene: Scene, i: int, t, x, args) -> Saltation:
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
    defined = _tree_finite((surface.phi(t, x, args), phi_t, grad, f_minus, x_post, J_t, DJ, f_plus))
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


_saltation_jit = single_run_jit(_saltation_core)


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

    **Returns:** a [`grazejax.Saltation`][]. When ∂Φ/∂t + ∇Φ·f⁻ vanishes to round-off
    (tangential contact) `matrix` is the identity, the (N2) value, and the status GRAZING:
    the (N1) value grows like 1/(∇Φ·f⁻). Outside `jit`, a point where Φ, f or J (or their
    derivatives) is not finite raises a `ValueError`.
    """
    i, t, x, args = _prepare_point(scene, surface_index, t, x_pre, args)
    result = _saltation_jit(scene, i, t, x, args)
    _raise_if_undefined(result, scene, i, t, x, args, "saltation_matrix")
    return result


# --------------------------------------------------------------------------------------
# Point types
# --------------------------------------------------------------------------------------


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
    defined = def_s & _tree_finite(fx)
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
      its (C4), which [`grazejax.check_conditions`][] reports).
    - On the image Γ̃_i: the same tests for Φ̃_i = Φ_i ∘ J_i⁻¹ (J⁻¹ from `inverse_jump`,
      else Newton), with ∂Γ̃_i = J(∂Γ_i).
    - Axial grazing (Definition grazingpoint): some coordinate of the normal is zero. The
      paper writes ∇Φ̃ for both Γ and Γ̃; we use the gradient of the gap of the surface the
      point is on (∇Φ on Γ): at the paper's grazing points DJ is singular, so ∇Φ̃ = DJ⁻ᵀ∇Φ
      does not exist there.

    **Returns:** a [`grazejax.PointType`][]. Its status is GRAZING for a tangential point.
    """
    i, t, x, args = _prepare_point(scene, surface_index, t, x, args)
    result = _classify_jit(scene, i, t, x, args, rtol)
    _raise_if_undefined(result, scene, i, t, x, args, "classify_point")
    return result


# --------------------------------------------------------------------------------------
# Meeting time τ_i and the W-map
# --------------------------------------------------------------------------------------


def _meet(scene: Scene, i: int, t, x, args, lookback: float, horizon, kw):
    """τ_i(x), ξ(τ_i) by simulate on Γ_i alone with J = id; differentiable in x."""
    surface = scene.surfaces[i]
    # Only Γ_i, and a jump that changes nothing: the run stops (max_impacts=1) exactly at
    # the first contact, with simulate's IFT tangent of the contact time.
    probe = Scene(
        scene.vector_field,
        [surface.probe()],
    )
    if lookback > 0:
        # Search from t − lookback: the meeting may lie before t (a neighbour already past
        # Γ_i), and a run never impacts at its start time, so a point *on* Γ_i needs a
        # start upstream of it to have its τ = t found.
        t_start = t - lookback
        y, flow_status = free_flow(scene.vector_field, x, t, t_start, args, kw)
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
    status = jnp.where(_simulation_ok(flow_status), sol.status, flow_status)
    # A search that runs out of steps without a meeting (horizon = inf) is a non-meeting.
    reached = _simulation_ok(status) | ((status == int(Status.MAX_STEPS)) & ~met)
    return tau, x_meet, kind, met, reached & _simulation_ok(flow_status), status


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
                        _tree_finite(derivative),
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
    return on & tangential, ~(defined & _tree_finite(fx))


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
    [`grazejax.closed_form_linearization`][] gives eq. dert independently.

    **Arguments:**

    - `scene`, `surface_index`: the scene and the index i of Γ_i.
    - `t`, `x`: the start (θ_i and a point near x_0(θ_i) in the paper).
    - `args`: the scene's parameters.
    - `lookback`: search also this far *before* t (a static float). Needed for points on Γ_i
      (a run never impacts at its start time, so τ = t is found only from upstream) and for
      neighbours that have already crossed Γ_i (τ < t).
    - `horizon`: search until t + horizon (default inf: until the meeting, or `max_steps`).
    - `**simulate_kwargs`: tolerances, solver, `max_steps` for the flights.

    **Returns:** a [`grazejax.Meeting`][]; `tau` is inf and the status NO_CONTACT when the
    flow does not meet Γ_i in the window. At a tangential meeting (γ) ∇τ does not exist
    (it grows like 1/(∇Φ·f) on the (N1) side): `grad` is 0 and the status GRAZING.
    """
    i, t, x, args = _prepare_point(scene, surface_index, t, x, args)
    kw = dict(simulate_kwargs)
    result, _ = _analyse_jit(scene, i, t, x, args, float(lookback), _float_array(horizon), kw)
    _raise_if_undefined(result, scene, i, t, x, args, "meeting_time")
    return result


def _w_value(scene, i, t, x, args, lookback, horizon, kw):
    surface = scene.surfaces[i]
    tau, x_meet, kind, met, ok_run, _ = _meet(scene, i, t, x, args, lookback, horizon, kw)
    x_post = surface.jump(tau, x_meet, args)
    # ψ: from (τ, J(ξ(τ))) back to θ = t, without impacts (eq. W-map).
    back, back_status = free_flow(scene.vector_field, x_post, tau, t, args, kw)
    value = jnp.where(met, back - x, jnp.zeros_like(x))
    ok_run = ok_run & (_simulation_ok(back_status) | ~met)
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
    Γ_i): see [`grazejax.closed_form_linearization`][].

    **Arguments:** as for [`grazejax.meeting_time`][] (`lookback`, `horizon` bound the
    search window around θ; use `lookback > 0` for points on Γ_i or past it).

    **Returns:** a [`grazejax.WMap`][]. Status NO_CONTACT: W = 0, W_x = O (the (N2)
    value). Status GRAZING (x, or its meeting point, is a tangential contact): W = 0 and
    W_x = O, the (N2) value; the (N1) side has no limit in general: see
    [`grazejax.one_sided_jacobians`][] and [`grazejax.a2_diagnostic`][].
    """
    i, t, x, args = _prepare_point(scene, surface_index, t, x, args)
    kw = dict(simulate_kwargs)
    _, result = _analyse_jit(scene, i, t, x, args, float(lookback), _float_array(horizon), kw)
    _raise_if_undefined(result, scene, i, t, x, args, "w_map")
    return result


@single_run_jit
def _closed_form_impl(scene, i, t, x, tau, args, kw):
    surface = scene.surfaces[i]
    f = scene.vector_field

    def to_tau(x_):
        x1, status = free_flow(f, x_, t, tau, args, kw)
        return x1, (x1, status)

    X, (xi, status_a) = jax.jacfwd(to_tau, has_aux=True)(x)
    salt = _saltation_core(scene, i, tau, xi, args)

    def back(y_):
        y1, status = free_flow(f, y_, tau, t, args, kw)
        return y1, (y1, status)

    Y, (_, status_b) = jax.jacfwd(back, has_aux=True)(salt.x_post)
    _, grad = jax.jacfwd(surface.phi, argnums=(0, 1))(tau, xi, args)
    ok = salt.status == int(DerivativeStatus.OK)
    grad_tau = -safe_divide(X.T @ grad, salt.approach_rate, ok)
    n = x.shape[0]
    w_jac = jnp.where(
        ok, Y @ salt.matrix @ X - jnp.eye(n, dtype=x.dtype), jnp.zeros((n, n), x.dtype)
    )
    runs_ok = _simulation_ok(status_a) & _simulation_ok(status_b)
    status = jnp.where(runs_ok, salt.status, int(DerivativeStatus.SIMULATION_FAILED))
    return ClosedForm(grad_tau, w_jac, salt, status)


def closed_form_linearization(
    scene: Scene, surface_index: int, t, x, tau, args=None, **simulate_kwargs
) -> ClosedForm:
    r"""Eqs. dert and derw in closed form, given the meeting time τ (the independent check).

    With X = ∂φ(τ; t, x)/∂x (the flow Jacobian from t to the *fixed* time τ), ξ = φ(τ; t, x),
    S the [saltation matrix][grazejax.saltation_matrix] at (τ, ξ) and
    Y = ∂φ(t; τ, y)/∂y at y = J(ξ):

    ∇τ = −Xᵀ∇Φ / (∂Φ/∂t + ∇Φ·f⁻)   (eq. dert),
    W_x = Y S X − I                 (eq. derw; S − I when τ = t).

    Only impact-free flows are differentiated here, so this is independent of the event
    tangents that [`grazejax.meeting_time`][] and [`grazejax.w_map`][] rely on.

    **Arguments:** `t`, `x` the start (θ and the point), `tau` its meeting time with Γ_i
    (e.g. `meeting_time(...).tau`); the rest as for [`grazejax.w_map`][].

    **Returns:** a [`grazejax.ClosedForm`][] (status GRAZING with zero matrices when the
    meeting is tangential).
    """
    i, t, x, args = _prepare_point(scene, surface_index, t, x, args)
    return _closed_form_impl(scene, i, t, x, _float_array(tau), args, dict(simulate_kwargs))


# --------------------------------------------------------------------------------------
# The variational system along a solution
# --------------------------------------------------------------------------------------


class _Augmented(eqx.Module):
    """(x, U, ∫ tr A)' = (f, A U, tr A), A = ∂f/∂x(t, x): the paper's u' = A(t) u."""

    vector_field: Any = eqx.field(static=True)

    def __call__(self, t, z, args):
        n = _variational_state_size(z.shape[0])
        x, U = z[:n], z[n : n + n * n].reshape(n, n)
        fx, A = self.vector_field(t, x, args), jax.jacfwd(self.vector_field, argnums=1)(t, x, args)
        return jnp.concatenate([fx, (A @ U).reshape(-1), jnp.trace(A)[None]])


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
        (lambda t_, x_, j=j: _saltation_core(scene, j, t_, x_, args))
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
    augmented = _Augmented(scene.vector_field)

    def segment(carry, j):
        U, trace = carry
        z0 = jnp.concatenate([x_starts[j], U.reshape(-1), jnp.zeros((1,), x0.dtype)])
        z1, status = free_flow(augmented, z0, starts[j], ends[j], args, kw)
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
    flights_ok = jnp.all(_simulation_ok(statuses))
    status = jnp.where(
        jnp.any(undefined),
        int(DerivativeStatus.UNDEFINED),
        jnp.where(
            ~_simulation_ok(sol.status) | ~flights_ok,
            int(DerivativeStatus.SIMULATION_FAILED),
            jnp.where(
                jnp.any(grazing),
                int(DerivativeStatus.GRAZING),
                jnp.where(
                    _tree_finite(U), int(DerivativeStatus.OK), int(DerivativeStatus.NONFINITE)
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
    each impact, with B_i = S_i − I from the closed-form [saltation matrix]
    [grazejax.saltation_matrix] at the logged pre-impact state (the paper's W_{ix} at an α
    point, eq. derw). The solution is computed by `simulate`; each flight of the variational
    system restarts from the logged post-impact state. The transition matrix equals
    `flow_jacobian(...).jacobian` (the tests check this), and det U = Π det S_i · e^{∫ tr A}.

    Forward time only (`t1 > t0`). Simultaneous impacts are composed in log order.

    **Returns:** a [`grazejax.Variational`][]. At a tangential (γ) impact B_i = O (the (N2)
    value) and the status is GRAZING.
    """
    x0, t0, t1, args, kw = _prepare_run(scene, x0, t0, t1, args, "x0", simulate_kwargs)
    if kw["direction"] != 1:
        raise ValueError("variational_transition runs forward in time only (t1 > t0)")
    return _variational_impl(scene, x0, t0, t1, args, kw)


# --------------------------------------------------------------------------------------
# One-sided limits at β/γ points and the (A2) diagnostic
# --------------------------------------------------------------------------------------


def _w_maps(scene, i, t, xs, args, window, kw):
    """W-maps at several neighbours, one call of the cached single-point program each.

    A Python loop on purpose: it reuses the program that `w_map` and `meeting_time`
    compile (same scene, window and options), where a `vmap` would compile another one;
    a dozen neighbours cost milliseconds each.
    """
    horizon = _float_array(window)
    results = [
        _analyse_jit(scene, i, t, _float_array(x_), args, float(window), horizon, kw)[1]
        for x_ in xs
    ]
    return jax.tree.map(lambda *leaves: np.stack([np.asarray(leaf) for leaf in leaves]), *results)


def _fit_exponent(d, values):
    """Least-squares slope of log(values) against log(d) over the smallest half of d."""
    d, values = np.asarray(d, float), np.asarray(values, float)
    keep = (values > 0) & np.isfinite(values)
    if keep.sum() < 2:
        return 0.0, 0.0
    d, values = d[keep], values[keep]
    order = np.argsort(d)
    half = order[: max(2, (len(order) + 1) // 2)]
    slope, intercept = np.polyfit(np.log(d[half]), np.log(values[half]), 1)
    return float(slope), float(math.exp(intercept))


def _extrapolate(d, jacobians, met) -> OneSidedLimit:
    d = np.asarray(d, float)
    W = np.asarray(jacobians, float)
    met = np.asarray(met, bool)
    condition = "N1" if met.all() else ("N2" if not met.any() else "mixed")
    norms = np.linalg.norm(W, axis=(1, 2))
    exponent, _ = _fit_exponent(d, norms)
    if condition == "mixed":
        return OneSidedLimit(
            d,
            W,
            met,
            condition,
            exponent,
            np.full_like(W[0], np.nan),
            math.inf,
            False,
            "neighbours on this side both meet and miss Γ_i: no one-sided limit",
        )
    diffs = np.diff(W, axis=0)
    delta = np.linalg.norm(diffs, axis=(1, 2))
    scale = 1.0 + norms[-1]
    if delta[-1] <= 1e-10 * scale:
        return OneSidedLimit(
            d,
            W,
            met,
            condition,
            exponent,
            W[-1],
            float(delta[-1]),
            True,
            "constant to round-off over the last distances",
        )
    growing = exponent < -0.1 and norms[-1] > 2 * norms[0]
    if growing:
        return OneSidedLimit(
            d,
            W,
            met,
            condition,
            exponent,
            np.full_like(W[0], np.nan),
            math.inf,
            False,
            f"diverges: ‖W_x‖ grows like d^{exponent:.3f}",
        )
    # Richardson: if W(d) = L + C d^p then successive differences shrink like d^p.
    p, _ = _fit_exponent(d[1:], delta)
    if p > 0.05:
        # W(d) = L + C d^p: L = W_{k+1} + Δ_k ρ/(1 − ρ), ρ = (d_{k+1}/d_k)^p. The error
        # estimate is the disagreement of the last two such extrapolations.
        def richardson(k):
            rho = (d[k + 1] / d[k]) ** p
            return W[k + 1] + diffs[k] * rho / (1 - rho)

        limit = richardson(len(d) - 2)
        error = float(np.linalg.norm(limit - richardson(len(d) - 3)))
        converged = error <= 1e-6 * (1 + np.linalg.norm(limit))
        return OneSidedLimit(
            d,
            W,
            met,
            condition,
            exponent,
            limit,
            error,
            bool(converged),
            f"converges like d^{p:.3f}; Richardson-extrapolated",
        )
    return OneSidedLimit(
        d,
        W,
        met,
        condition,
        exponent,
        W[-1],
        float(delta[-1]),
        False,
        "no convergence detected (differences do not shrink)",
    )


def _unit(v):
    v = np.asarray(v, float)
    norm = np.linalg.norm(v)
    if not np.isfinite(norm) or norm == 0:
        raise ValueError(f"direction must be a non-zero finite vector, got {v.tolist()}")
    return v / norm


def _default_distances(distances):
    d = np.geomspace(1e-2, 1e-8, 13) if distances is None else np.asarray(distances, float)
    if d.ndim != 1 or len(d) < 3 or np.any(d <= 0):
        raise ValueError("distances must be at least 3 positive numbers")
    return np.sort(d)[::-1]


def one_sided_jacobians(
    scene: Scene,
    surface_index: int,
    t,
    x,
    args=None,
    *,
    direction,
    window: float,
    distances=None,
    **simulate_kwargs,
) -> OneSidedLinearization:
    r"""The bivalued linearization B_i at a β or γ point, as one-sided limits (paper §3).

    At a boundary point x* = x_0(θ_i) ∈ ∂Γ_i, neighbours either meet Γ_i near θ_i (the
    paper's (N1)) or do not (N2), and B_i = W_{ix} takes one value per case (eq. beta).
    This computes W_{ix} at x* ± d_k v for decreasing d_k (one vectorised, compiled
    [`grazejax.w_map`][] call per side), classifies each side as N1/N2 by whether its
    neighbours meet Γ_i, and extrapolates each side's limit (Richardson on the successive
    differences), reporting the growth exponent of ‖W_{ix}‖ and whether it converged.

    At a β point the (N1) limit is S − I (finite) and the (N2) limit is O. At a γ point the
    (N2) limit is O, and the (N1) side diverges unless DJ f = f at x* (then the 1/(∇Φ·f)
    term of S cancels): see [`grazejax.a2_diagnostic`][].

    **Arguments:**

    - `scene`, `surface_index`, `t`, `x`, `args`: the point x* on ∂Γ_i at time θ = `t`.
    - `direction`: the displacement v (normalised here). Choose it so that one side meets
      Γ_i and the other does not (e.g. ±∇Φ at a γ point, along Γ_i across ∂Γ_i at a β point).
    - `window`: the search window [t − window, t + window] for the meeting (static).
    - `distances`: the d_k (default 13 values from 1e-2 to 1e-8).
    - `**simulate_kwargs`: tolerances (use 1e-12), solver.

    **Returns:** a [`grazejax.OneSidedLinearization`][] (`n1.limit`, `n2.limit` are B_i).
    """
    i, t, x, args = _prepare_point(scene, surface_index, t, x, args)
    v = _unit(direction)
    d = _default_distances(distances)
    kw = dict(simulate_kwargs)
    sides = []
    for sign in (1.0, -1.0):
        xs = np.asarray(x)[None, :] + sign * d[:, None] * v[None, :]
        result = _w_maps(scene, i, t, xs, args, window, kw)
        if np.any(np.asarray(result.status) == DerivativeStatus.UNDEFINED):
            raise ValueError("one_sided_jacobians: Φ or f undefined at some neighbour")
        sides.append(_extrapolate(d, result.jacobian, result.met))
    plus, minus = sides
    n1 = next((s for s in sides if s.condition == "N1"), None)
    n2 = next((s for s in sides if s.condition == "N2"), None)
    return OneSidedLinearization(np.asarray(x), v, plus, minus, n1, n2)


@single_run_jit
def _upstream(scene, x, t, window, args, kw):
    return free_flow(scene.vector_field, x, t, t - window, args, kw)


def a2_diagnostic(
    scene: Scene,
    surface_index: int,
    t,
    x,
    args=None,
    *,
    window: float,
    direction=None,
    distances=None,
    **simulate_kwargs,
) -> A2Diagnostic:
    r"""Test the paper's (A2) — W_i differentiable at a grazing point — by measurement.

    Along impacting neighbours x* + d v (d → 0) of a grazing point x* (at time θ = `t`),
    measure ‖W_{ix}‖ (the B-equivalence map's Jacobian, [`grazejax.w_map`][]) and the norm
    of the time-synchronised flow Jacobian ∂x(θ + h)/∂x(θ − h) of the full system through
    the impact (h = `window`), and fit the exponent q of ‖·‖ ∝ d^q. q ≈ 0: bounded, as
    (A2) requires; q ≈ −1/2: Nordmark's square-root singularity (the saltation matrix's
    1/(∇Φ·f) with ∇Φ·f ∝ √d for a displacement normal to Γ_i); q ≈ −1: ∇Φ·f ∝ d (a
    displacement along Γ_i).

    For a grazing contact with J(x*) = x* (C6), S − I = (DJ − I) + (f⁺ − DJ f⁻)∇Φᵀ/(∇Φ·f⁻)
    and the singular term's numerator tends to (I − DJ) f at x*: W_i is differentiable at x*
    only if DJ(x*) f(x*) = f(x*).

    **Arguments:**

    - `scene`, `surface_index`, `t`, `x`, `args`: the grazing point x* at time θ.
    - `window`: h: the meeting search window and the half-length of the flow Jacobian's
      interval. Keep it short enough that no other surface is met within it.
    - `direction`: v (default −∇Φ(x*), normal into Φ < 0: those neighbours have crossed
      Γ_i shortly before θ, the (N1) side).
    - `distances`: the d_k (default 13 values from 1e-2 to 1e-8).

    **Returns:** an [`grazejax.A2Diagnostic`][].
    """
    i, t, x, args = _prepare_point(scene, surface_index, t, x, args)
    if direction is None:
        grad = jax.jacfwd(scene.surfaces[i].phi, argnums=1)(t, x, args)
        direction = -np.asarray(grad)
    v = _unit(direction)
    d = _default_distances(distances)
    xs = np.asarray(x)[None, :] + d[:, None] * v[None, :]
    kw = dict(simulate_kwargs)
    w = _w_maps(scene, i, t, xs, args, window, kw)
    met = np.asarray(w.met)
    if not met.all():
        raise ValueError(
            f"a2_diagnostic: the neighbours at d = {d[~met].tolist()} along `direction` do not "
            "meet the surface in the window: they are (N2) points, or touch it within the "
            "contact floor (a displacement along Γ_i gives a depth ∝ d², which falls below the "
            "floor for d ≲ 1e-7). Choose the impacting side, larger distances or a larger window."
        )
    rates = np.array(
        [
            float(_saltation_jit(scene, i, jnp.asarray(tau), jnp.asarray(xm), args).approach_rate)
            for tau, xm in zip(w.tau, w.x_meet, strict=True)
        ]
    )
    # The time-synchronised flow Jacobian of the *full* system across the impact: from the
    # neighbour's upstream point at t − h to t + h (flow_jacobian's cached program).
    flow_kw = dict(flight_kwargs(kw), direction=1)
    t_start, t_end = t - window, t + window
    flow_jac = []
    for x_ in xs:
        z, _ = _upstream(scene, jnp.asarray(x_), t, window, args, kw)
        flow_jac.append(
            np.asarray(_flow_jacobian_impl(scene, z, t_start, t_end, args, "x0", flow_kw).jacobian)
        )
    flow_jac = np.stack(flow_jac)
    w_norms = np.linalg.norm(w.jacobian, ord=2, axis=(1, 2))
    flow_norms = np.linalg.norm(flow_jac, ord=2, axis=(1, 2))
    q_w, c_w = _fit_exponent(d, w_norms)
    q_f, _ = _fit_exponent(d, flow_norms)
    if q_w > -0.1:
        verdict = f"bounded (‖W_x‖ ∝ d^{q_w:.3f}): consistent with (A2)"
    elif abs(q_w + 0.5) < 0.1:
        verdict = (
            f"square-root singularity: ‖W_x‖ ≈ {c_w:.3g}·d^{q_w:.3f} (Nordmark, −1/2): "
            "W_i is not differentiable at the point, (A2) fails"
        )
    elif abs(q_w + 1) < 0.1:
        verdict = f"‖W_x‖ ≈ {c_w:.3g}·d^{q_w:.3f}: 1/d singularity, (A2) fails"
    else:
        verdict = f"singular, ‖W_x‖ ∝ d^{q_w:.3f}: (A2) fails"
    return A2Diagnostic(
        np.asarray(x),
        v,
        d,
        w_norms,
        q_w,
        flow_norms,
        q_f,
        rates,
        w.jacobian,
        flow_jac,
        verdict,
    )


prepare_point = _prepare_point
w_maps = _w_maps
