"""One-sided limits of W_{ix} at β/γ points (`grazejax.one_sided_jacobians`) and the
(A2) diagnostic at a grazing point (`grazejax.a2_diagnostic`): many W-maps at
neighbours approaching the point, their growth exponent and extrapolated limits."""

from __future__ import annotations

import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._compiler import single_run_jit
from .._flow import flight_kwargs, free_flow
from .._scene import Scene
from .common import DerivativeStatus, prepare_point
from .jacobians import flow_jacobian_impl
from .meeting import w_maps
from .saltation import saltation_jit


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
    r"""Result of `grazejax.one_sided_jacobians`: the bivalued B_i at a β/γ point.

    `plus` and `minus` are the `grazejax.OneSidedLimit`s along x* ± d·v. `n1` and
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
    r"""Result of `grazejax.a2_diagnostic`: is W_i differentiable at a grazing point?

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

    def found(limit, error, converged, note):
        return OneSidedLimit(d, W, met, condition, exponent, limit, error, converged, note)

    if condition == "mixed":
        return found(
            np.full_like(W[0], np.nan),
            math.inf,
            False,
            "neighbours on this side both meet and miss Γ_i: no one-sided limit",
        )
    diffs = np.diff(W, axis=0)
    delta = np.linalg.norm(diffs, axis=(1, 2))
    scale = 1.0 + norms[-1]
    if delta[-1] <= 1e-10 * scale:
        return found(W[-1], float(delta[-1]), True, "constant to round-off over the last distances")
    growing = exponent < -0.1 and norms[-1] > 2 * norms[0]
    if growing:
        return found(
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
        return found(
            limit, error, bool(converged), f"converges like d^{p:.3f}; Richardson-extrapolated"
        )
    return found(
        W[-1], float(delta[-1]), False, "no convergence detected (differences do not shrink)"
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
    `grazejax.w_map` call per side), classifies each side as N1/N2 by whether its
    neighbours meet Γ_i, and extrapolates each side's limit (Richardson on the successive
    differences), reporting the growth exponent of ‖W_{ix}‖ and whether it converged.

    At a β point the (N1) limit is S − I (finite) and the (N2) limit is O. At a γ point the
    (N2) limit is O, and the (N1) side diverges unless DJ f = f at x* (then the 1/(∇Φ·f)
    term of S cancels): see `grazejax.a2_diagnostic`.

    **Arguments:**

    - `scene`, `surface_index`, `t`, `x`, `args`: the point x* on ∂Γ_i at time θ = `t`.
    - `direction`: the displacement v (normalised here). Choose it so that one side meets
      Γ_i and the other does not (e.g. ±∇Φ at a γ point, along Γ_i across ∂Γ_i at a β point).
    - `window`: the search window [t − window, t + window] for the meeting (static).
    - `distances`: the d_k (default 13 values from 1e-2 to 1e-8).
    - `**simulate_kwargs`: tolerances (use 1e-12), solver.

    **Returns:** a `grazejax.OneSidedLinearization` (`n1.limit`, `n2.limit` are B_i).
    """
    i, t, x, args = prepare_point(scene, surface_index, t, x, args)
    v = _unit(direction)
    d = _default_distances(distances)
    kw = dict(simulate_kwargs)
    sides = []
    for sign in (1.0, -1.0):
        xs = np.asarray(x)[None, :] + sign * d[:, None] * v[None, :]
        result = w_maps(scene, i, t, xs, args, window, kw)
        if np.any(np.asarray(result.status) == DerivativeStatus.UNDEFINED):
            raise ValueError("one_sided_jacobians: Φ or f undefined at some neighbour")
        sides.append(_extrapolate(d, result.jacobian, result.met))
    plus, minus = sides
    n1 = next((s for s in sides if s.condition == "N1"), None)
    n2 = next((s for s in sides if s.condition == "N2"), None)
    return OneSidedLinearization(np.asarray(x), v, plus, minus, n1, n2)


@single_run_jit
def _upstream(scene, x, t, window, args, kw):
    return free_flow(scene, x, t, t - window, args, kw)


def _synchronised_flow_jacobians(scene, t, xs, args, window, kw):
    """The time-synchronised flow Jacobian of the *full* system across the impact: from each
    neighbour's upstream point at t − h to t + h (flow_jacobian's cached program)."""
    flow_kw = dict(flight_kwargs(kw), direction=1)
    t_start, t_end = t - window, t + window
    flow_jac = []
    for x_ in xs:
        z, _ = _upstream(scene, jnp.asarray(x_), t, window, args, kw)
        flow_jac.append(
            np.asarray(flow_jacobian_impl(scene, z, t_start, t_end, args, "x0", flow_kw).jacobian)
        )
    return np.stack(flow_jac)


def _a2_verdict(q_w, c_w) -> str:
    """The reading of the fitted exponent q of ‖W_x‖ ≈ c·d^q, in words."""
    if q_w > -0.1:
        return f"bounded (‖W_x‖ ∝ d^{q_w:.3f}): consistent with (A2)"
    if abs(q_w + 0.5) < 0.1:
        return (
            f"square-root singularity: ‖W_x‖ ≈ {c_w:.3g}·d^{q_w:.3f} (Nordmark, −1/2): "
            "W_i is not differentiable at the point, (A2) fails"
        )
    if abs(q_w + 1) < 0.1:
        return f"‖W_x‖ ≈ {c_w:.3g}·d^{q_w:.3f}: 1/d singularity, (A2) fails"
    return f"singular, ‖W_x‖ ∝ d^{q_w:.3f}: (A2) fails"


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
    measure ‖W_{ix}‖ (the B-equivalence map's Jacobian, `grazejax.w_map`) and the norm
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

    **Returns:** an `grazejax.A2Diagnostic`.
    """
    i, t, x, args = prepare_point(scene, surface_index, t, x, args)
    if direction is None:
        grad = jax.jacfwd(scene.surfaces[i].phi, argnums=1)(t, x, args)
        direction = -np.asarray(grad)
    v = _unit(direction)
    d = _default_distances(distances)
    xs = np.asarray(x)[None, :] + d[:, None] * v[None, :]
    kw = dict(simulate_kwargs)
    w = w_maps(scene, i, t, xs, args, window, kw)
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
            float(saltation_jit(scene, i, jnp.asarray(tau), jnp.asarray(xm), args).approach_rate)
            for tau, xm in zip(w.tau, w.x_meet, strict=True)
        ]
    )
    flow_jac = _synchronised_flow_jacobians(scene, t, xs, args, window, kw)
    w_norms = np.linalg.norm(w.jacobian, ord=2, axis=(1, 2))
    flow_norms = np.linalg.norm(flow_jac, ord=2, axis=(1, 2))
    q_w, c_w = _fit_exponent(d, w_norms)
    q_f, _ = _fit_exponent(d, flow_norms)
    verdict = _a2_verdict(q_w, c_w)
    return A2Diagnostic(
        np.asarray(x), v, d, w_norms, q_w, flow_norms, q_f, rates, w.jacobian, flow_jac, verdict
    )
