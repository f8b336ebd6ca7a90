r"""Bifurcation points of periodic orbits solved by their defining systems.

A special point of a family of periodic orbits is not interpolated between branch points
here: it is the solution of one nonlinear system in the orbit and the parameter μ,

    P(x, T; μ, ν) − x = 0,   [x_j − c = 0, free period],   τ(μ, ν, x, T) = 0,

with the test function τ of its kind on the monodromy U = ∂P/∂x:

- period doubling: det(U + I) (a multiplier −1);
- fold: det(U − I) with a fixed period, det of the (A6) matrix [∂P/∂T, (U − I) without
  column j] with a free one (a second multiplier 1 beside the trivial one);
- Neimark–Sacker: det(U ⊙ U − I), U ⊙ U the bialternate product (the action of U on
  Λ²ℝⁿ, eigenvalues ρ_i ρ_j, i < j): a pair with ρ_i ρ_j = 1, a complex pair on the unit
  circle. (A real pair ρ, 1/ρ, a neutral saddle, solves it too: `multipliers` tells them
  apart.)

The system is solved by Newton's method (`optx.root_find`); its Jacobian holds derivatives
of U, second derivatives of the flow, which are exact through impacts (the event time's
curvature terms, `_loop/land.py`). The point is a function of the second parameter ν by the
implicit function theorem: `jax.jacfwd`, and `jax.grad` with
`adjoint=diffrax.DirectAdjoint()`, differentiate it without differentiating Newton's
iterations.
"""

from __future__ import annotations

import itertools
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Complex, Float, Int

from .._adjoint import require_forward_mode
from .._scene import Scene
from .._tangents import without_derivative
from .._validate import is_concrete
from .forced_period import PERIOD_OF_FIX, require_period_fixed_in
from .period_map import (
    ATOL_PER_RTOL,
    PeriodMap,
    newton_for,
    newton_root,
    orbit_kernel,
    orbit_scale,
    period_map_jacobian,
)
from .periodic import OrbitStatus, diagnostics_map, eigvals_sorted, poincare_matrix

KINDS = ("period-doubling", "fold", "neimark-sacker")


class BifurcationPoint(eqx.Module):
    r"""A bifurcation point solved by its defining system (`grazejax.locate_bifurcation`).

    **Fields:**

    - `kind`: `"period-doubling"`, `"fold"` or `"neimark-sacker"`, or `"grazing"` from
      `grazejax.locate_grazing` (static).
    - `mu`, `nu`: the first parameter (solved for) and the second (given).
    - `x0`, `t0`, `period`: the orbit there (`x0` at phase `t0`).
    - `multipliers`: of its monodromy, modulus descending.
    - `test_value`: the kind's test function at the solution (≈ 0).
    - `residual`: max |P(x0) − x0| at the solution (no derivative: NaN).
    - `num_impacts`: impacts per period of the orbit.
    - `status`: an `grazejax.OrbitStatus` code (`SUCCESS`, `NO_CONVERGENCE`,
      `DIVERGED`, `SIMULATION_FAILED`); `num_steps`: Newton iterations.

    `mu`, `x0`, `period` and `multipliers` are differentiable in ν (and in anything
    `args_of` closes over) by the implicit function theorem.
    """

    kind: str = eqx.field(static=True)
    mu: Float[Array, ""]
    nu: Float[Array, ""]
    x0: Float[Array, " n"]
    t0: Float[Array, ""]
    period: Float[Array, ""]
    multipliers: Complex[Array, " n"]
    test_value: Float[Array, ""]
    residual: Float[Array, ""]
    num_impacts: Int[Array, ""]
    status: Int[Array, ""]
    num_steps: Int[Array, ""]

    @property
    def message(self) -> str:
        return OrbitStatus(int(self.status)).name


def bialternate_square(U):
    """U ⊙ U: the action of U on Λ²ℝⁿ in the basis e_i ∧ e_j (i < j), whose eigenvalues are
    the products ρ_i ρ_j (i < j) of U's."""
    n = U.shape[0]
    pairs = list(itertools.combinations(range(n), 2))
    if not pairs:
        return jnp.zeros((0, 0), U.dtype)
    i, j = (np.array(p) for p in zip(*pairs, strict=True))
    # (U∧U)_{(i,j),(k,l)} = U_ik U_jl − U_il U_jk
    return (U[i[:, None], i[None, :]] * U[j[:, None], j[None, :]]
            - U[i[:, None], j[None, :]] * U[j[:, None], i[None, :]])


def test_function(kind: str, fixed_period: bool, monodromy, jac_T, j):
    """τ of `kind` on the monodromy (module docstring)."""
    n = monodromy.shape[0]
    eye = jnp.eye(n, dtype=monodromy.dtype)
    if kind == "period-doubling":
        return jnp.linalg.det(monodromy + eye)
    if kind == "fold":
        return jnp.linalg.det(poincare_matrix(fixed_period, n, j, monodromy, jac_T))
    if kind == "neimark-sacker":
        square = bialternate_square(monodromy)
        return jnp.linalg.det(square - jnp.eye(square.shape[0], dtype=square.dtype))
    raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")


class DefiningSystem(eqx.Module):
    """The defining system's static parts: `residual(y, (nu, c, t0, T))` with y = (x, μ)
    (fixed period) or (T, x, μ) (free period, phase condition x_j = c). Static but for the
    tolerances: equal systems (the same scene, kind and parameter functions) share their
    compiled programs, whatever their tolerances."""

    pmap: PeriodMap  # (its tolerances are arrays, inputs of the compiled programs)
    kind: str = eqx.field(static=True)
    fixed_period: bool = eqx.field(static=True)
    args_of: Any = eqx.field(static=True)
    period_of: Any = eqx.field(static=True)  # None: the period T of the parameters
    j: int = eqx.field(static=True)

    def split(self, y):
        if self.fixed_period:
            return y[:-1], None, y[-1]
        return y[1:-1], y[0], y[-1]

    def period(self, T, mu, nu):
        """A forced orbit's period at (μ, ν): `period_of`'s, else the fixed T."""
        return T if self.period_of is None else self.period_of(mu, nu)

    def residual(self, y, params):
        nu, c, t0, T_fixed = params
        x, T, mu = self.split(y)
        if self.fixed_period:
            T = self.period(T_fixed, mu, nu)
        args = self.args_of(mu, nu)
        zeros = jax.tree.map(jnp.zeros_like, args)
        x_end, monodromy, jac_T, _, ok, _ = period_map_jacobian(self.pmap, x, t0, T, args,
                                                                zeros)
        tau = test_function(self.kind, self.fixed_period, monodromy, jac_T, self.j)
        rows = [x_end - x]
        if not self.fixed_period:
            rows.append((x[self.j] - c)[None])
        rows.append(tau[None])
        return jnp.where(ok, jnp.concatenate(rows), jnp.nan)


def locate_special(
    scene: Scene,
    point,
    args_of,
    nu,
    *,
    kind: str | None = None,
    fixed_period: bool = True,
    period_of=None,
    fix: int | None = None,
    rtol: float = 1e-10,
    atol: float | None = None,
    solver: diffrax.AbstractSolver | None = None,
    newton_tol: float = 1e-9,
    max_newton_steps: int = 30,
    max_impacts: int = 64,
    max_solver_steps: int = 50_000,
    adjoint=None,
) -> BifurcationPoint:
    """A period-doubling, fold or Neimark–Sacker point solved by its defining system at ν
    (`grazejax.locate_bifurcation` of those kinds: its arguments)."""
    kind = getattr(point, "kind", None) if kind is None else kind
    require_forward_mode(adjoint, "locate_bifurcation", "the defining system")
    mu_guess, t0, T_guess = float(point.mu), float(point.t0), float(point.period)
    if fixed_period and period_of is None:
        require_period_fixed_in(
            scene, lambda p: args_of(mu_guess, p), nu, t0, point.x0, T_guess,
            caller="locate_bifurcation", parameter="ν", fix=PERIOD_OF_FIX)
    system, x_guess, scale = defining_system(
        scene, point, kind, bool(fixed_period), args_of, period_of, fix, mu_guess, nu,
        dict(solver=solver, rtol=float(rtol), atol=atol, max_impacts=int(max_impacts),
             max_solver_steps=int(max_solver_steps), adjoint=adjoint))
    j = system.j
    head = [] if fixed_period else [T_guess]
    y0 = np.concatenate([head, x_guess, [mu_guess]])
    params = (jnp.asarray(nu, float), jnp.asarray(x_guess[j] if j >= 0 else 0.0),
              jnp.asarray(t0), jnp.asarray(T_guess))
    root_finder = newton_for(newton_tol, max(scale, 1.0))
    return _solve(system, root_finder, int(max_newton_steps), jnp.asarray(y0), params)


def defining_system(scene, point, kind, fixed_period: bool, args_of, period_of, fix, mu, nu,
                    simulate_kw: dict):
    """The `DefiningSystem` of `kind` around the guess `point` (its x0 at phase t0) at (μ, ν), the
    guess's state and its scale: `(system, x_guess, scale)`. Checks `kind`, `point.x0` and
    `fix`; `simulate_kw["atol"] = None` scales with the guess; a free period's phase index
    is `fix`, else the largest |f_j| at the guess (ν must then be concrete)."""
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    x_guess = np.asarray(point.x0, dtype=float)
    if x_guess.ndim != 1:
        raise ValueError(f"point.x0 must be a state vector, got shape {x_guess.shape}")
    n = x_guess.shape[0]
    if fix is not None and not (isinstance(fix, (int, np.integer)) and 0 <= fix < n):
        raise ValueError(f"fix must be a coordinate index in [0, {n}), got {fix!r}")
    scale = orbit_scale(x_guess)
    kw = dict(simulate_kw)
    if kw["atol"] is None:
        kw["atol"] = ATOL_PER_RTOL * kw["rtol"] * scale
    pmap = PeriodMap(scene=scene, end_impacts=0, **dict(kw, atol=float(kw["atol"])))
    if fixed_period:
        j = -1
    elif fix is None:
        if not is_concrete(nu):
            raise ValueError("locate_bifurcation: inside jit/vmap (traced nu) pass fix")
        f0 = scene.vector_field(float(point.t0), jnp.asarray(x_guess), args_of(mu, nu))
        j = int(np.argmax(np.abs(np.asarray(jax.lax.stop_gradient(f0)))))
    else:
        j = int(fix)
    return DefiningSystem(pmap, kind, fixed_period, args_of, period_of, j), x_guess, scale


@orbit_kernel
def _solve(system: DefiningSystem, root_finder, max_newton_steps: int, y0, params):
    """Newton on the defining system, then the point's diagnostics (one program per
    system: the same scene, kind and parameter functions reuse it)."""
    y, converged, finite, num_steps = newton(system.residual, root_finder, y0, params,
                                             max_newton_steps)
    nu, _, t0, T_fixed = params
    x, T, mu = system.split(y)
    if system.fixed_period:
        T = system.period(T_fixed, mu, nu)
    return _assess(system, x, t0, T, mu, nu, converged, finite, num_steps)


def newton(residual, root_finder, y0, params, max_newton_steps):
    """Newton (`newton_root`) on `residual(y, params)` from y0, differentiable in `params` by
    the implicit function theorem: `(y, converged, finite, num_steps)`, y0 where the
    iterate is not finite."""
    y, converged, num_steps = newton_root(residual, root_finder, y0, params, max_newton_steps)
    finite = jnp.all(jnp.isfinite(jax.lax.stop_gradient(y)))
    return jnp.where(finite, y, y0), converged, finite, num_steps


def _assess(system: DefiningSystem, x, t0, T, mu, nu, converged, finite, num_steps):
    """The point's diagnostics, with derivatives where they have them."""

    def tau(monodromy, jac_T):
        return test_function(system.kind, system.fixed_period, monodromy, jac_T, system.j)

    return assessed_point(system.kind, system.pmap, system.args_of, x, t0, T, mu, nu, tau,
                          converged, finite, num_steps)


def assessed_point(kind, pmap, args_of, x, t0, T, mu, nu, test_of, converged, finite,
                   num_steps) -> BifurcationPoint:
    """The `BifurcationPoint` of a solved defining system: the orbit's monodromy and
    multipliers (their derivatives where they have them), `test_of(monodromy, ∂P/∂T)`, the
    residual (no derivative) and the status."""
    args = args_of(mu, nu)
    zeros = jax.tree.map(jnp.zeros_like, args)
    x_end, monodromy, jac_T, _, ok, sol = period_map_jacobian(
        diagnostics_map(pmap, pmap.adjoint), x, t0, T, args, zeros)
    residual = jnp.max(jnp.abs(jax.lax.stop_gradient(x_end - x)))
    S = OrbitStatus
    status = jnp.select([~finite, ~ok, ~converged], [S.DIVERGED, S.SIMULATION_FAILED,
                                                     S.NO_CONVERGENCE], S.SUCCESS)
    return BifurcationPoint(
        kind=kind, mu=mu, nu=nu, x0=x, t0=t0, period=T,
        multipliers=eigvals_sorted(monodromy), test_value=test_of(monodromy, jac_T),
        residual=without_derivative(residual, (x, mu, nu)),
        num_impacts=jnp.asarray(sol.num_impacts, jnp.int32),
        status=status.astype(jnp.int32), num_steps=jnp.asarray(num_steps),
    )
