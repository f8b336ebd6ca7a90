"""One family of periodic orbits as the continuation corrects it: the unknown Y = ((T,) x, μ),
the Poincaré criterion, the compiled Newton corrector and a corrected point's diagnostics
(`BranchPoint`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .arclength import (
    bordered_newton,
    eigvals_descending,
    next_tangent,
)
from .period_map import (
    PeriodMap,
    a5_holds,
    gap_rates_at,
    linearize,
    orbit_kernel,
    sampled_states,
)


class OrbitFamily(eqx.Module):
    pmap: PeriodMap  # (its tolerances are arrays, inputs of the compiled programs)
    args_of: Callable = eqx.field(static=True)
    period_of: Callable | None = eqx.field(static=True)
    fixed_period: bool = eqx.field(static=True)
    root_finder: Any  # (its tolerances are arrays: see `newton_for`)
    max_newton_steps: int = eqx.field(static=True)


def unpack_family(fam: OrbitFamily, Y, T_fixed):
    mu = Y[-1]
    if fam.fixed_period:
        T = T_fixed if fam.period_of is None else fam.period_of(mu)
        x = Y[:-1]
    else:
        T, x = Y[0], Y[1:-1]
    return T, x, mu


def poincare_criterion(fam: OrbitFamily, Y, t0, e_j, c, T_fixed):
    """The Poincaré criterion F(Y) (plus the phase row), and the run behind it."""
    T, x, mu = unpack_family(fam, Y, T_fixed)
    x_end, ok, sol = fam.pmap(x, t0, T, fam.args_of(mu))
    rows = x_end - x
    if not fam.fixed_period:
        rows = jnp.concatenate([rows, (jnp.dot(x, e_j) - c)[None]])
    return jnp.where(ok, rows, jnp.nan), (ok, sol)


class BranchPoint(NamedTuple):
    """One corrected point of a branch, with what the tracer needs of it.

    `Y` is the corrector's unknown ((x, μ) for a fixed period, (T, x, μ) otherwise) and
    `tangent` the unit tangent there (the predictor's when `good` is False). A point the
    corrector could not place (`good` False, `num_impacts` −1) carries only those and the
    Newton step count; the diagnostics after `steps` are None for it.
    """

    Y: Any
    tangent: Any
    good: bool
    num_impacts: int
    steps: Any
    monodromy: Any = None
    multipliers: Any = None
    stable: Any = None
    a6: Any = None  # det of the (A6) matrix: the Jacobian of the Poincaré criterion
    x_min: Any = None  # extremes of the state along the orbit (amplitude)
    x_max: Any = None
    f_x: Any = None  # the vector field at the point's start (the phase condition's normal)
    period: Any = None
    impact_speed: float = math.inf  # the smallest normal impact speed (grazing monitor)


@orbit_kernel
def family_corrector(fam: OrbitFamily, Y_pred, tangent, t0, e_j, c, T_fixed):
    """Newton on [F(Y); tangent·(Y − Y_pred)] = 0 (the only program compiled for continuation)."""
    return bordered_newton(lambda Y: poincare_criterion(fam, Y, t0, e_j, c, T_fixed)[0],
                            fam.root_finder, fam.max_newton_steps, Y_pred, tangent)


def correct_point(fam: OrbitFamily, Y_pred, tangent, t0, e_j, c, T_fixed, ts_unit):
    """Corrector, then the point's diagnostics from programs shared with `find_periodic_orbit`.

    ∂F/∂(T, x) and the monodromy come from the period map's linearization; ∂F/∂μ, needed
    only for the next tangent, from central differences of the period map.
    """
    # `c` as an array: `filter_jit` treats a Python float as static, and the phase value
    # x_j changes at every step of an autonomous family (a recompilation per point).
    Y, converged, steps = family_corrector(fam, jnp.asarray(Y_pred), jnp.asarray(tangent), t0, e_j,
                                     jnp.asarray(c, float), T_fixed)
    Y_np = np.asarray(Y)
    n = Y_np.shape[0] - (1 if fam.fixed_period else 2)
    T, x, mu = (np.asarray(v) for v in unpack_family(fam, Y, T_fixed))
    bad = BranchPoint(Y=Y, tangent=jnp.asarray(tangent), good=False, num_impacts=-1, steps=steps)
    if not (bool(converged) and np.all(np.isfinite(Y_np)) and float(T) > 0):
        return bad
    args, args_dot = jax.jvp(fam.args_of, (jnp.asarray(mu),), (jnp.ones(()),))
    x_end, M, dP_dT, ok, sol, dP_dargs = linearize(fam.pmap, jnp.asarray(x), t0, jnp.asarray(T),
                                                     args, args_dot)
    M, dP_dT = np.asarray(M), np.asarray(dP_dT)
    if not bool(ok) or not np.all(np.isfinite(M)):
        return bad
    dP_dmu = np.asarray(dP_dargs)
    if fam.fixed_period and fam.period_of is not None:
        dP_dmu = dP_dmu + dP_dT * float(jax.jvp(fam.period_of, (jnp.asarray(mu),), (jnp.ones(()),))[1])
    e = np.asarray(e_j)
    if fam.fixed_period:
        J = np.column_stack([M - np.eye(n), dP_dmu])
        a6 = M - np.eye(n)
    else:
        top = np.column_stack([dP_dT, M - np.eye(n), dP_dmu])
        J = np.vstack([top, np.concatenate([[0.0], e, [0.0]])])
        j = int(np.argmax(e))
        free = [k for k in range(n) if k != j]
        a6 = np.column_stack([dP_dT, (M - np.eye(n))[:, free]])
    new_tangent = next_tangent(J, tangent)
    multipliers = eigvals_descending(M)
    # Extremes along the orbit (amplitude), from samples plus the impact states.
    ts = t0 + float(T) * ts_unit
    samples = sampled_states(fam.pmap, jnp.asarray(x), t0, t0 + jnp.asarray(T), args, ts)
    k = int(sol.num_impacts)
    states = np.concatenate([np.asarray(samples.xs), np.asarray(sol.impact_pre[:k]),
                             np.asarray(sol.impact_post[:k])], axis=0)
    f_x = np.asarray(fam.pmap.scene.vector_field(t0, jnp.asarray(x), args))
    # The grazing monitor of an impacting orbit: the smallest normal impact speed |∇Φ·f⁻|
    # (→ 0 at grazing; the family is smooth in it, Nordmark's normal form).
    speed = math.inf
    for m in range(k):
        phi = fam.pmap.scene.surfaces[int(sol.impact_surface[m])].phi
        _, rate, _ = gap_rates_at(phi, fam.pmap.scene.vector_field, sol.impact_times[m],
                               sol.impact_pre[m], args)
        speed = min(speed, abs(float(rate)))
    return BranchPoint(
        Y=Y, tangent=jnp.asarray(new_tangent), good=bool(np.all(np.isfinite(new_tangent))),
        num_impacts=k, monodromy=M, multipliers=multipliers,
        stable=bool(a5_holds(jnp.asarray(multipliers), fam.fixed_period)), a6=float(np.linalg.det(a6)),
        x_min=states.min(axis=0), x_max=states.max(axis=0), f_x=f_x, steps=steps, period=float(T),
        impact_speed=speed,
    )


def x_of(Y, fixed):
    Y = np.asarray(Y)
    return Y[:-1] if fixed else Y[1:-1]


def record_point(point: BranchPoint) -> BranchPoint:
    """The point with host arrays (what the branch keeps)."""
    return BranchPoint(*(None if v is None else np.asarray(v) for v in point))


def natural_corrector(fam, point, phase_of, j, fixed, t0, T_fixed, ts_unit):
    """`Y ↦ ` the corrector at fixed μ = Y[-1], with the phase condition of `point`."""
    e_j, c, _ = phase_of(np.asarray(x_of(point.Y, fixed)), point.f_x, j)

    def natural(Y_guess):
        e, cc = e_j, c
        if not fixed:  # the section through the guess itself
            cc = float(np.asarray(Y_guess)[1:-1] @ np.asarray(e_j))
        return natural_point(fam, jnp.asarray(Y_guess), t0, e, cc, T_fixed, ts_unit)

    return natural


def natural_point(fam: OrbitFamily, Y_guess, t0, e_j, c, T_fixed, ts_unit):
    """Newton at fixed μ (the last component of Y_guess): the corrector with the bordered
    row (Y − Y_guess)·e_μ = 0. Same compiled program as `correct_point`."""
    e_mu = jnp.zeros_like(Y_guess).at[-1].set(1.0)
    return correct_point(fam, Y_guess, e_mu, t0, e_j, c, T_fixed, ts_unit)

