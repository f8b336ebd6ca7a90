"""Floquet multipliers of a periodic orbit, stably: per-impact factors (flights and
saltation matrices) and their product's eigenvalues (`grazejax.floquet_multipliers`)."""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Complex, Float

from .._compiler import single_run_jit
from .._flow import short_free_flow
from .._linearize import saltation_matrix
from .._scene import Scene
from .._status import Status
from .period_map import (
    PeriodMap,
    a5_holds,
    atol_for,
    linearize,
    orbit_kernel,
    sampled_states,
)
from .periodic import Orbit

# --------------------------------------------------------------------------------------
# Floquet multipliers, stably
# --------------------------------------------------------------------------------------


class Floquet(eqx.Module):
    r"""Floquet multipliers of an orbit from per-impact factors (`grazejax.floquet_multipliers`).

    **Fields:**

    - `multipliers`: the multipliers (complex, modulus descending), as eigenvalues of the
      product A_p ⋯ A_1 computed by a periodic-Schur sweep over the factors (each factor's
      triangular part carries its own scale, so tiny multipliers keep their relative
      accuracy instead of drowning in round-off of the largest one).
    - `multipliers_monodromy`: plain eigenvalues of the orbit's single-shooting monodromy.
    - `factors`: the factors, in time order: for each impact the flight Jacobian Φ_i (at
      fixed time, up to the impact) and the impact's saltation matrix S_i, then the last
      flight; shape `(p, n, n)`. Their product is the monodromy.
    - `saltation_determinants`: det S_i of each impact, from the closed-form saltation
      matrix S = DJ + (f⁺ − DJ f⁻ − ∂J/∂t)∇Φᵀ/(∂Φ/∂t + ∇Φ·f⁻).
    - `trace_integral`: ∫ tr ∂f/∂x dt over one period, along the orbit.
    - `liouville_determinant`: Π det S_i · exp(∫ tr A dt), the determinant identity
      (Liouville's formula across impacts). For an autonomous orbit the trivial multiplier
      is 1, so the product of the others equals it.
    - `determinant_monodromy`, `determinant_product`: det U and Π det A_i.
    - `determinant_error`: |det U − Liouville| / |Liouville|.
    - `stable`: (A5) on `multipliers`.
    """

    multipliers: Complex[Array, " n"]
    multipliers_monodromy: Complex[Array, " n"]
    factors: Float[Array, "p n n"]
    saltation_determinants: Float[Array, " k"]
    trace_integral: Float[Array, ""]
    liouville_determinant: Float[Array, ""]
    determinant_monodromy: Float[Array, ""]
    determinant_product: Float[Array, ""]
    determinant_error: Float[Array, ""]
    stable: Bool[Array, ""]


def saltation(scene: Scene, surface_index: int, t, x_pre, args) -> Array:
    """Closed-form saltation matrix of an impact on surface `surface_index` at (t, x_pre).

    The matrix of `grazejax.saltation_matrix` (one implementation for the package):
    S = DJ + (f⁺ − DJ f⁻ − ∂J/∂t) ∇Φᵀ / (∂Φ/∂t + ∇Φ·f⁻). It diverges like 1/(∇Φ·f⁻) near a
    grazing contact; exactly at one it is the (N2) value, the identity.
    """
    return saltation_matrix(scene, surface_index, t, x_pre, args).matrix


@orbit_kernel
def _flights_to_impact(pmap_impact: PeriodMap, starts, t_starts, durations, nudges, args):
    """Time-fixed Jacobians Φ_i of the flights from each start to its next impact (vmapped).

    From the impact log's tangents: x_pre moves with the impact time θ, so the Jacobian at
    the fixed time θ is d x_pre/dx − f⁻ (dθ/dx)ᵀ. The saltation matrix is not included.
    """
    def one(x, t, d, tau):
        def pre(y):
            # Leave the surface along the free flow first (a restart exactly on a surface
            # with an inward velocity can re-trigger in simulate: see docs/periodic.md).
            y1 = short_free_flow(pmap_impact.scene.vector_field, t, y, tau, args)
            sol = pmap_impact.run(y1, t + tau, t + 2 * d, args, 1)
            out = (sol.impact_pre[0], sol.impact_times[0])
            return out, out

        (jx, jt), (x_pre, theta) = jax.jacfwd(pre, has_aux=True)(x)
        f_minus = pmap_impact.scene.vector_field(theta, x_pre, args)
        return jx - jnp.outer(f_minus, jt)

    return jax.vmap(one)(starts, t_starts, durations, nudges)


@single_run_jit
def _nudge_jacobian(vector_field, t, x, tau, args):
    """x(t + τ) by the free flow (RK4) and its Jacobian."""
    return jax.jacfwd(lambda y: short_free_flow(vector_field, t, y, tau, args), has_aux=False)(x)


def _flight_factor(pmap_time: PeriodMap, x, t, duration, args, tau=0.0):
    """Time-fixed Jacobian of the flight from (t, x) over `duration`, after a free nudge τ."""
    if float(tau) == 0.0:
        return linearize(pmap_time, x, t, duration, args)[1]
    f = pmap_time.scene.vector_field
    x1 = short_free_flow(f, t, jnp.asarray(x), tau, args)
    nudge = _nudge_jacobian(f, t, jnp.asarray(x), tau, args)
    return linearize(pmap_time, x1, t + tau, duration - tau, args)[1] @ nudge


def _nudge_times(durations, period):
    """How far to move along the free flow before restarting from a post-impact state."""
    return np.minimum(1e-3 * np.asarray(durations), 1e-3 * period)


@single_run_jit
def _traces(scene: Scene, ts, xs, args):
    f = scene.vector_field
    return jax.vmap(lambda t, x: jnp.trace(jax.jacfwd(lambda y: f(t, y, args))(x)))(ts, xs)


def _trace_integral(pmap: PeriodMap, x0, t0, period, boundaries, args, num_nodes=400):
    """∫ tr ∂f/∂x dt over one period: Gauss–Legendre panels on each flight.

    The states at the nodes are the orbit's own samples (`saveat`), so the integral is
    independent of the flow Jacobians it checks. `num_nodes` is fixed (one compiled
    sampler, shared with `orbit_contacts`); panels of 8 nodes are spread over the flights
    in proportion to their length.
    """
    nodes, weights = np.polynomial.legendre.leggauss(8)
    edges = np.asarray(boundaries, float)
    lengths = np.diff(edges)
    panels_total = num_nodes // 8
    panels = np.maximum(1, np.floor(panels_total * lengths / lengths.sum()).astype(int))
    while panels.sum() > panels_total:
        panels[np.argmax(panels)] -= 1
    panels[np.argmax(lengths)] += panels_total - panels.sum()
    ts, ws = [], []
    for a, b, m in zip(edges[:-1], edges[1:], panels, strict=True):
        cuts = np.linspace(a, b, m + 1)
        for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
            ts.append(0.5 * (hi - lo) * nodes + 0.5 * (hi + lo))
            ws.append(0.5 * (hi - lo) * weights)
    ts, ws = np.concatenate(ts), np.concatenate(ws)
    sol = sampled_states(pmap, jnp.asarray(x0), jnp.asarray(t0), jnp.asarray(t0 + period), args,
                   jnp.asarray(ts))
    traces = np.asarray(_traces(pmap.scene, jnp.asarray(ts), sol.xs, args))
    return float(np.sum(ws * traces)), bool(sol.status == Status.SUCCESS)


def product_eigenvalues(factors) -> np.ndarray:
    """Eigenvalues of A_p ⋯ A_1 without losing the small ones (periodic Schur sweep).

    The eigenvectors of the product, ordered by modulus, give a unitary Q0 that
    triangularises it (QR of the eigenvector matrix). One sweep A_k Q_{k−1} = Q_k R_k turns
    the product into Q_p R_p ⋯ R_1; with Q_p = Q0 D (D diagonal, unit modulus) the
    eigenvalues are D_ii Π_k (R_k)_ii. Each diagonal entry is accurate relative to its own
    size, whereas an eigenvalue of the formed product is only accurate to eps·‖product‖.
    Three sweeps refine Q0 (orthogonal iteration). Falls back to the plain eigenvalues if
    the product is defective or the sweep does not return to Q0.
    """
    factors = [np.asarray(a, dtype=np.complex128) for a in factors]
    n = factors[0].shape[0]
    product = np.eye(n, dtype=np.complex128)
    for a in factors:
        product = a @ product
    if not np.all(np.isfinite(product)):
        return np.full(n, np.nan + 0j)
    w, v = np.linalg.eig(product)
    order = np.argsort(-np.abs(w), kind="stable")
    w, v = w[order], v[:, order]
    q0, r = np.linalg.qr(v)
    if np.min(np.abs(np.diag(r))) <= 1e-10 * np.max(np.abs(np.diag(r))):
        return w  # (nearly) defective: no better basis to sweep with
    lam = w
    for _ in range(3):
        q = q0
        diag = np.ones(n, dtype=np.complex128)
        for a in factors:
            q, r = np.linalg.qr(a @ q)
            diag = diag * np.diag(r)
        phase = np.diag(q0.conj().T @ q)
        if np.min(np.abs(phase)) < 0.99:
            break  # Q_p is not Q0 up to phases: keep the last good estimate
        lam = phase / np.abs(phase) * diag
        q0 = q
    return lam[np.argsort(-np.abs(lam), kind="stable")]


def floquet_multipliers(scene: Scene, orbit: Orbit, args=None, *, solver=None,
                        rtol: float = 1e-10, atol: float | None = None,
                        max_solver_steps: int = 50_000) -> Floquet:
    r"""Floquet multipliers of a periodic orbit, computed stably, with the determinant identity.

    The period is cut at its impacts (multiple shooting): the factors are the flight
    Jacobians Φ_i from just after impact i−1 to impact i (`jax.jacfwd` through
    `grazejax.simulate`), the closed-form saltation matrices S_i, and the last flight;
    U = Φ_last S_k Φ_k ⋯ S_1 Φ_1. The multipliers are the eigenvalues of that product by a
    periodic-Schur sweep (`product_eigenvalues`), which keeps tiny
    multipliers (near grazing, det S_i ∝ v → 0) that the eigenvalues of the formed
    monodromy lose to cancellation.

    The determinant identity det U = Π det S_i · exp(∫ tr ∂f/∂x dt) is checked with the
    closed-form saltation matrices and the trace integrated along the orbit.

    Run outside `jit` (it loops over impacts in Python). Use the same `rtol`, `atol`,
    `solver` as the orbit solve (`atol=None`: scaled to the orbit's size as there).
    """
    atol = atol_for(orbit, rtol, atol)
    k = int(orbit.num_impacts)
    t0 = float(orbit.t0)
    end = t0 + float(orbit.period)
    common = dict(solver=solver, rtol=float(rtol), atol=float(atol), max_impacts=64,
                  max_solver_steps=int(max_solver_steps))
    times = np.asarray(orbit.impact_times[:k], dtype=float)
    posts = np.asarray(orbit.impact_post[:k], dtype=float)
    pres = np.asarray(orbit.impact_pre[:k], dtype=float)
    surfaces = np.asarray(orbit.impact_surface[:k])
    x0 = np.asarray(orbit.x0, dtype=float)
    factors = []
    salts = []
    if k:
        starts = np.concatenate([x0[None], posts[:-1]], axis=0)
        t_starts = np.concatenate([[t0], times[:-1]])
        durations = times - t_starts
        pmap_impact = PeriodMap(scene=scene, end_impacts=1, **common)
        # The first flight starts at x0 (no nudge unless x0 is itself post-impact).
        nudges = _nudge_times(durations, float(orbit.period))
        if not orbit.start_at_impact:
            nudges[0] = 0.0
        flights = np.asarray(_flights_to_impact(
            pmap_impact, jnp.asarray(starts), jnp.asarray(t_starts), jnp.asarray(durations),
            jnp.asarray(nudges), args
        ))
        salts = [np.asarray(saltation(scene, int(surfaces[i]), times[i], pres[i], args))
                 for i in range(k)]
        # Flight and impact as separate factors: near grazing S has entries ~1/v and a
        # determinant ~v, and keeping them apart is what lets the sweep resolve a tiny
        # multiplier that the formed product S·Φ loses to cancellation.
        for i in range(k):
            factors.extend([flights[i], salts[i]])
    last = times[-1] if k else t0
    closes_at_impact = orbit.start_at_impact and k and abs(end - last) <= 1e-9 * max(1.0, abs(end))
    if not closes_at_impact:
        x_last = posts[-1] if k else x0
        pmap_time = PeriodMap(scene=scene, end_impacts=0, **common)
        tau = float(_nudge_times([end - last], float(orbit.period))[0]) if k else 0.0
        factors.append(np.asarray(_flight_factor(
            pmap_time, jnp.asarray(x_last), jnp.asarray(last), jnp.asarray(end - last), args,
            jnp.asarray(tau),
        )))
    factors = np.stack(factors)
    multipliers = product_eigenvalues(factors)

    pmap_time = PeriodMap(scene=scene, end_impacts=0, **common)
    trace, ok = _trace_integral(pmap_time, x0, t0, float(orbit.period),
                                np.concatenate([[t0], times[times < end], [end]]) if k else [t0, end],
                                args)
    dets = np.array([np.linalg.det(salt) for salt in salts])
    liouville = float(np.prod(dets) * np.exp(float(trace))) if bool(ok) else math.nan
    det_u = float(np.linalg.det(np.asarray(orbit.monodromy)))
    det_product = float(np.prod([np.linalg.det(a) for a in factors]))
    error = abs(det_u - liouville) / abs(liouville) if liouville else math.inf
    return Floquet(
        multipliers=jnp.asarray(multipliers),
        multipliers_monodromy=jnp.asarray(orbit.multipliers),
        factors=jnp.asarray(factors),
        saltation_determinants=jnp.asarray(dets),
        trace_integral=jnp.asarray(float(trace)),
        liouville_determinant=jnp.asarray(liouville),
        determinant_monodromy=jnp.asarray(det_u),
        determinant_product=jnp.asarray(det_product),
        determinant_error=jnp.asarray(error),
        stable=a5_holds(jnp.asarray(multipliers), orbit.fixed_period),
    )
