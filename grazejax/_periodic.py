r"""Periodic orbits of impact systems: shooting, monodromy, Floquet multipliers, (A6).

Paper objects (Akhmet & Kıvılcım, *Discontinuous dynamics with grazing points*, §4–§5):

- the Poincaré criterion S(T, ζ) = x(T; ζ) − ζ = 0 with one coordinate ζ_j fixed
  (eq. periodpar), solved by Newton's method ([`grazejax.find_periodic_orbit`][]);
- its Jacobian at the solution, the (A6) matrix [∂S/∂T, ∂S/∂ζ_k (k ≠ j)], and the
  monodromy matrix U(ω) of the variational system (eq. graz1lin1);
- the Floquet multipliers and the (A5) verdict, computed stably from per-impact factors
  ([`grazejax.floquet_multipliers`][]);
- at a grazing orbit, the (up to 2^l) one-sided variational systems of (A4), impacting or
  not at each grazing contact ([`grazejax.grazing_branches`][]).

**The period map and where the period ends.** Solutions are left-continuous (docs/semantics.md).
If x0 is away from the orbit's impacts the period map is the time-T map
P(x0, T) = x(t0 + T; t0, x0) of [`grazejax.simulate`][]. The paper starts its cycles *at*
an impact (x1 = 0 in ex1dof and smalldisc). Then x0 is read as the post-impact state
x(θ+) (a flight that starts on a surface never impacts at its start, so the flight from
x(θ+) is the orbit's), and the period ends **just after** the impact that closes it:
P(x0, T) = x((t0 + T)+). Taking x((t0 + T)−) instead would compare a pre-impact state with
a post-impact one, and the time-T map would jump at the solution. Numerically P runs to the
k-th impact (k impacts per period) and moves along the post-impact flow by the remaining
time: P(x0, T) = x(θ_k+) + (t0 + T − θ_k)·f(θ_k, x(θ_k+)), which is exact at the solution
(θ_k = t0 + T) and smooth in T there. The monodromy is the Jacobian of the map that is
solved: with an impact at the end, its last factor is that impact's saltation matrix
S = DJ + (f⁺ − DJ f⁻)∇Φᵀ/(∇Φ·f⁻), i.e. U = S_k Φ(θ_k, θ_{k−1}) ⋯ S_1 Φ(θ_1, t0).

**Differentiation.** Newton runs in `optx.root_find`, whose implicit adjoint gives
derivatives of the orbit (x0, period) with respect to `args` by the implicit function
theorem; `jax.jacfwd` works, and `jax.grad` with `adjoint=diffrax.DirectAdjoint()` (the
residual's derivative in `args` then runs backward through `simulate`). Diagnostics
(monodromy, multipliers, (A6), impacts) are evaluated at the solution without derivatives
and given their true ones (second derivatives of the flow) only when differentiated
(`_differentiable_diagnostics`); the residual differentiates to NaN.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.lax as lax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Complex, Float, Int

from ._adjoint import loop_kinds
from ._compiler import single_run_jit
from ._flow import short_free_flow
from ._geometry import FLOOR_ULPS, gap_rates, on_surface
from ._linearize import saltation_matrix
from ._orbit_common import (
    _ATOL_PER_RTOL,
    SolverSettings,
    _a5,
    _atol_for,
    _linearize,
    _newton_for,
    _newton_tolerances,
    _PeriodMap,
    _run,
    _sampled,
    _solver_name,
    _state_at,
    _state_scale,
    gap_rates_at,
    jacobian_in_one_pass,
    orbit_kernel,
    period_map_jacobian,
)
from ._scene import Scene
from ._status import Status
from ._tangents import with_forward_tangents, without_derivative
from ._validate import is_concrete

# --------------------------------------------------------------------------------------
# Status
# --------------------------------------------------------------------------------------


class OrbitStatus(enum.IntEnum):
    """How a periodic-orbit solve ended. Stored as an integer array in `Orbit.status`.

    Inside `jax.jit` / `jax.vmap` nothing raises: `OrbitStatus(int(orbit.status))` reads it,
    and `.message` says what to try.
    """

    SUCCESS = 0
    """Newton converged to a periodic orbit with a regular (A6) matrix."""
    NO_CONVERGENCE = 1
    """The root finder used `max_steps` iterations without meeting `newton_tol`."""
    DIVERGED = 2
    """The Newton iterates became non-finite (the guess is far from any orbit, or the
    iteration left the region where the period map is defined)."""
    SIMULATION_FAILED = 3
    """`simulate` did not complete the period at the result (Zeno, max steps, NaN, or more
    impacts than `max_impacts`)."""
    SINGULAR = 4
    """The (A6) matrix is singular or ill-conditioned: the orbit is not isolated (a fold,
    a multiplier at 1 of a forced system, or `fixed_period=True` on an autonomous system)."""
    FIX_TANGENT = 5
    """The flow is tangent to the fixed coordinate (f_j = 0): x_j = const is not a section."""
    EQUILIBRIUM = 6
    """The guess or the result is an equilibrium (f(x0) = 0), not a cycle: every T is a
    'period' and the phase condition is undefined."""
    BAD_PERIOD = 7
    """The period came out zero or negative."""
    IMPACT_COUNT = 8
    """The orbit found does not have the requested number of impacts per period."""
    NO_END_IMPACT = 9
    """x0 was read as a post-impact state, but the period-closing impact was not reached."""
    LOOSE_ATOL = 10
    """Newton converged, but the simulation's `atol` exceeds 10 × `rtol` × the orbit's size:
    the period map (and so the orbit and its multipliers) is only as accurate as
    atol / size, not `rtol`. Pass `atol=None` (scaled to the orbit) or a smaller `atol`."""
    NOT_DOUBLED = 11
    """`period_doubled_orbit` found only the period-1 orbit run twice from every start
    (past the flip point on the wrong side, or too far from it)."""

    @property
    def message(self) -> str:
        return _MESSAGES[self]


_MESSAGES = {
    OrbitStatus.SUCCESS: "converged to an isolated periodic orbit",
    OrbitStatus.NO_CONVERGENCE: "Newton did not converge within max_steps: improve the guess "
    "(x0, period) or loosen newton_tol (it cannot beat the simulation's accuracy)",
    OrbitStatus.DIVERGED: "Newton diverged (non-finite iterates): the guess is too far from a "
    "periodic orbit, or the iteration left the region where the period map is defined",
    OrbitStatus.SIMULATION_FAILED: "simulate did not complete one period at the result "
    "(Zeno, max steps, non-finite state, or more impacts than max_impacts)",
    OrbitStatus.SINGULAR: "the (A6) matrix of the Poincaré criterion is singular or "
    "ill-conditioned: the orbit is not isolated (fold, multiplier 1 of a forced system, or "
    "fixed_period=True on an autonomous system)",
    OrbitStatus.FIX_TANGENT: "the flow is tangent to the fixed coordinate x_fix = const "
    "(f_fix(x0) = 0): choose another `fix` (default: the largest |f_j(x0)|)",
    OrbitStatus.EQUILIBRIUM: "the guess or the result is an equilibrium (f(x0) = 0), not a cycle",
    OrbitStatus.BAD_PERIOD: "the period came out zero or negative",
    OrbitStatus.IMPACT_COUNT: "the orbit found does not have num_impacts impacts per period",
    OrbitStatus.NO_END_IMPACT: "x0 lies on a surface and was read as a post-impact state, "
    "but the impact that closes the period was not reached",
    OrbitStatus.LOOSE_ATOL: "atol is larger than 10·rtol times the orbit's size: the "
    "simulation controls its error in absolute terms only, so the orbit and its multipliers "
    "are not accurate to rtol; pass atol=None (scaled to the orbit) or a smaller atol",
    OrbitStatus.NOT_DOUBLED: "every start converged to the period-1 orbit run twice: no "
    "period-doubled orbit near the flip point at these args (try the other side of the "
    "flip point, or args closer to it)",
}


# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------


class Orbit(eqx.Module):
    r"""A periodic orbit found by [`grazejax.find_periodic_orbit`][].

    **Fields:**

    - `x0`: the orbit's state at `t0` (post-impact if the orbit starts at an impact).
    - `t0`: start time (matters for forced systems).
    - `period`: the period T (the paper's 𝒯, or ω).
    - `num_impacts`: impacts per period.
    - `impact_times`, `impact_pre`, `impact_post`, `impact_surface`, `impact_kind`: the
      impacts in (t0, t0 + T], as in [`grazejax.Solution`][] (NaN-padded to `max_impacts`).
    - `monodromy`: U(T), the Jacobian of the period map x0 ↦ P(x0, T) (module docstring).
    - `multipliers`: eigenvalues of `monodromy`, complex, sorted by modulus, descending.
      For an autonomous orbit one of them is the trivial multiplier 1.
    - `poincare_matrix`: the (A6) matrix. Autonomous: columns ∂S/∂T first, then ∂S/∂ζ_k
      for the free coordinates k ≠ `fix` in increasing order (eq. periodpar; n × n).
      Forced (`fixed_period=True`): ∂S/∂ζ = U − I.
    - `poincare_determinant`: its determinant; (A6) asks for it to be non-zero.
    - `residual`: ‖P(x0, T) − x0‖∞ at the result.
    - `status`: an [`grazejax.OrbitStatus`][] code; `message` reads it.
    - `fix`: the fixed coordinate j (−1 for `fixed_period=True`).
    - `num_steps`: Newton iterations taken.
    - `start_at_impact`: whether x0 is a post-impact state and the period ends just after
      an impact (static).
    - `fixed_period`: whether T was held fixed (forced systems; static).
    - `settings`: the [`grazejax.SolverSettings`][] it was computed with (static).

    Only a converged orbit (`status == SUCCESS`) is a periodic orbit: for any other status
    `x0`, `period`, `monodromy` and `multipliers` describe the last Newton iterate, and
    `stable` is False (no stability verdict).

    `x0` and `period` are differentiable with respect to `args`, `t0`, a fixed period
    and the phase condition's value (implicit function theorem); so are `monodromy`,
    `multipliers` (where simple), `poincare_matrix`, `poincare_determinant` and the
    impact log, as functions of the orbit (second derivatives of the flow, computed only
    when differentiated). `residual` differentiates to NaN.
    """

    x0: Float[Array, " n"]
    t0: Float[Array, ""]
    period: Float[Array, ""]
    num_impacts: Int[Array, ""]
    impact_times: Float[Array, " max_impacts"]
    impact_pre: Float[Array, "max_impacts n"]
    impact_post: Float[Array, "max_impacts n"]
    impact_surface: Int[Array, " max_impacts"]
    impact_kind: Int[Array, " max_impacts"]
    monodromy: Float[Array, "n n"]
    multipliers: Complex[Array, " n"]
    poincare_matrix: Float[Array, "n n"]
    poincare_determinant: Float[Array, ""]
    residual: Float[Array, ""]
    status: Int[Array, ""]
    fix: Int[Array, ""]
    num_steps: Int[Array, ""]
    start_at_impact: bool = eqx.field(static=True, default=False)
    fixed_period: bool = eqx.field(static=True, default=False)
    settings: SolverSettings | None = eqx.field(static=True, default=None)

    @property
    def succeeded(self) -> Bool[Array, ""]:
        return self.status == OrbitStatus.SUCCESS

    @property
    def message(self) -> str:
        """The status as text (outside jit, unbatched)."""
        return OrbitStatus(int(self.status)).message

    @property
    def stable(self) -> Bool[Array, ""]:
        """(A5) for a converged orbit: all non-trivial multipliers strictly inside the unit
        circle. False whenever the solve did not succeed (no verdict: see `message`).

        For an autonomous orbit the multiplier closest to 1 is the trivial one and is
        left out; for a forced orbit (`fixed_period=True`) all multipliers count.
        """
        return _a5(self.multipliers, self.fixed_period) & self.succeeded

    def summary(self) -> str:
        """A short human-readable account (outside jit, unbatched)."""
        status = OrbitStatus(int(self.status))
        k = int(self.num_impacts)
        rho = ", ".join(_fmt_complex(z) for z in np.asarray(self.multipliers))
        if status == OrbitStatus.SUCCESS:
            what = ""
            verdict = f"(A5) {'holds' if bool(self.stable) else 'fails'}"
        else:
            what = "NOT CONVERGED (the last iterate, not a verified periodic orbit): "
            verdict = "no (A5) verdict"
        lines = [
            f"status: {status.name} ({status.message})",
            f"{what}period = {float(self.period):.15g}, x0 = {np.asarray(self.x0)} at "
            f"t0 = {float(self.t0):g}" + (" (post-impact)" if self.start_at_impact else ""),
            f"{k} impact(s) per period; residual {float(self.residual):.2e}; "
            f"{int(self.num_steps)} Newton step(s)",
            f"multipliers: {rho}; {verdict}",
            f"(A6) determinant = {float(self.poincare_determinant):.6g}"
            + ("" if status == OrbitStatus.SUCCESS else " (at the last iterate)"),
        ]
        if self.settings is not None:
            st = self.settings
            lines.append(f"settings: solver {st.solver}, rtol {st.rtol:.1e}, atol {st.atol:.1e}, "
                         f"Newton rtol {st.newton_rtol:.1e}, atol {st.newton_atol:.1e}")
        return "\n".join(lines)


def _fmt_complex(z) -> str:
    z = complex(z)
    if abs(z.imag) <= 1e-14 * max(1.0, abs(z)):
        return f"{z.real:.10g}"
    return f"{z.real:.8g}{z.imag:+.8g}j"


# --------------------------------------------------------------------------------------
# The period map
# --------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------
# The solve (one compiled program per period map and options)
# --------------------------------------------------------------------------------------


def _host_eigvals(matrix):
    """Eigenvalues sorted by modulus, descending (numpy on the host: works on any backend)."""
    return _host_eigensystem(matrix)[0]


def _host_eigensystem(matrix):
    """`(w, V, W)`: eigenvalues by modulus descending, right eigenvectors as V's columns
    and left ones as W's rows, normalised so that W V = I (W = V⁻¹)."""
    m = np.asarray(matrix, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        nan = np.full(m.shape, np.nan + 0j, dtype=np.complex128)
        return np.full(m.shape[:-1], np.nan + 0j, dtype=np.complex128), nan, nan
    w, v = np.linalg.eig(m)
    idx = np.argsort(-np.abs(w), axis=-1, kind="stable")
    w = np.take_along_axis(w, idx, axis=-1).astype(np.complex128)
    v = np.take_along_axis(v, idx[..., None, :], axis=-1).astype(np.complex128)
    with np.errstate(all="ignore"):
        try:
            left = np.linalg.inv(v)
        except np.linalg.LinAlgError:  # defective: no derivative (NaN, below)
            left = np.full(v.shape, np.nan + 0j, dtype=np.complex128)
    return w, v, left


@jax.custom_jvp
def eigvals_sorted(matrix) -> Array:
    """Eigenvalues of a real square matrix, complex, by modulus descending.

    Runs NumPy's eigensolver through `jax.pure_callback`, so it works under `jit` and
    `vmap` on every backend (JAX's own `eig` is CPU-only). Forward-mode derivative of a
    simple eigenvalue: dλ_k = w_k dA v_k (v_k, w_k its right and left eigenvectors with
    w_k v_k = 1); at a repeated eigenvalue of a defective matrix it is not finite, as the
    eigenvalue is not differentiable there.
    """
    matrix = jnp.asarray(matrix)
    shape = jax.ShapeDtypeStruct(matrix.shape[:-1], jnp.complex128)
    return jax.pure_callback(_host_eigvals, shape, matrix, vmap_method="sequential")


@eigvals_sorted.defjvp
def _eigvals_sorted_jvp(primals, tangents):
    (matrix,), (matrix_dot,) = primals, tangents
    matrix = jnp.asarray(matrix)
    vectors = jax.ShapeDtypeStruct(matrix.shape, jnp.complex128)
    shapes = (jax.ShapeDtypeStruct(matrix.shape[:-1], jnp.complex128), vectors, vectors)
    w, right, left = jax.pure_callback(_host_eigensystem, shapes, matrix,
                                       vmap_method="sequential")
    dA = jnp.asarray(matrix_dot).astype(jnp.complex128)
    w_dot = jnp.einsum("...ki,...ij,...jk->...k", left, dA, right)
    return w, w_dot


def _snap(x, j, c):
    """x with x_j = c exactly (j may be traced)."""
    return jnp.where(jnp.arange(x.shape[0]) == j, c, x)


def _free_columns(n, j):
    """Indices 0..n-1 without j, in increasing order (j may be traced)."""
    idx = jnp.arange(n - 1)
    return idx + (idx >= j)


@orbit_kernel
def _newton(pmap: _PeriodMap, fixed_period: bool, root_finder, max_steps: int, y0, t0,
            T_fixed, args, j, c):
    """Newton (`optx.root_find`) on the Poincaré criterion; differentiable in `args`."""
    n = y0.shape[0] - (0 if fixed_period else 1)
    e_j = jax.nn.one_hot(j, n, dtype=y0.dtype)

    if fixed_period:
        def residual(y, a):
            x_end, ok, _ = pmap(y, t0, T_fixed, a)
            return jnp.where(ok, x_end - y, jnp.nan)
    else:
        def residual(y, a):
            T, x = y[0], y[1:]
            # The period map sees x_j = c exactly (not c plus Newton's round-off): a start
            # on a coordinate surface must be *on* it, or a tiny positive gap with an
            # inward velocity re-triggers the impact at t0 (a simulate issue, see docs).
            x_end, ok, _ = pmap(_snap(x, j, c), t0, T, a)
            r = jnp.concatenate([x_end - x, (jnp.dot(x, e_j) - c)[None]])
            return jnp.where(ok, r, jnp.nan)

    solution = optx.root_find(jacobian_in_one_pass(residual), root_finder, y0, args,
                              max_steps=max_steps, throw=False)
    return solution.value, solution.result == optx.RESULTS.successful, solution.stats["num_steps"]


def _phase_condition(pmap: _PeriodMap, x_guess, t0, T_guess, args, fix, fixed_period):
    """(j, c) of the phase condition x_j = c, and the guess run's linearization."""
    lin = _linearize(pmap, x_guess, t0, T_guess, args)
    j, c, f_guess = _phase_index(pmap, fixed_period, x_guess, t0, args, fix, lin[4].impact_surface)
    return j, c, f_guess, lin


# The small computations between the compiled period-map programs are kernels too: run
# op by op, each of their operations would compile a program of its own.
@orbit_kernel
def _phase_index(pmap: _PeriodMap, fixed_period: bool, x_guess, t0, args, fix, impact_surface):
    f_guess = pmap.scene.vector_field(t0, x_guess, args)
    if fixed_period:
        return jnp.asarray(-1), jnp.asarray(0.0, x_guess.dtype), f_guess
    if pmap.end_impacts > 0 and pmap.scene.surfaces:
        # Start at an impact: by default fix the coordinate along the surface normal (the
        # paper's ζ1 = 0 for Γ = {x1 = 0}), so that x0 stays on the surface.
        closing = jnp.clip(impact_surface[pmap.end_impacts - 1], 0, None)
        normals = jnp.stack([
            jax.grad(lambda y, s=s: s.phi(t0, y, args))(x_guess) for s in pmap.scene.surfaces
        ])
        j_auto = jnp.argmax(jnp.abs(normals[closing]))
    else:
        j_auto = jnp.argmax(jnp.abs(f_guess))
    j = jnp.where(fix >= 0, fix, j_auto)
    return j, x_guess[j], f_guess


def _refine_period(pmap: _PeriodMap, x_guess, t0, T_guess, args, j, c, lin):
    """Fix the phase before Newton.

    A time-T residual is dominated by the phase error f·ΔT, whose curvature (second order
    in ΔT) Newton then explains with the weakly contracting directions: for a weakly
    attracting cycle (ex1dof: multiplier 1 − 6e-4) a 1% error in T sends the first iterate
    to the equilibrium. Three scalar Newton steps on x_j(t0 + T) = c remove it. When the
    period ends at an impact, that impact's time fixes T.
    """
    x_end, _, jac_T, ok, sol = lin[:5]
    if pmap.end_impacts > 0:
        return _period_at_impact(ok, sol.t_final, t0, T_guess)
    T = jnp.asarray(T_guess, x_guess.dtype)
    for i in range(3):
        if i:
            x_end, _, jac_T, ok, _ = _linearize(pmap, x_guess, t0, T, args)[:5]
        T = _period_step(x_end, jac_T, ok, j, c, T)
    return T


@orbit_kernel
def _period_at_impact(ok, t_final, t0, T_guess):
    return jnp.where(ok, t_final - t0, T_guess)


@orbit_kernel
def _period_step(x_end, jac_T, ok, j, c, T):
    """One scalar Newton step on x_j(t0 + T) = c, at most a quarter period long."""
    slope = jac_T[j]
    dT = -(x_end[j] - c) / jnp.where(slope == 0, 1.0, slope)
    dT = jnp.clip(dT, -0.25 * jnp.abs(T), 0.25 * jnp.abs(T))
    return jnp.where(ok & jnp.isfinite(dT) & (slope != 0), T + dT, T)


@orbit_kernel
def _solution_point(fixed_period: bool, value, y0, T_guess, j, c):
    """(x0, T, finite) from Newton's value: a diverged solve hands back its start, never NaN."""
    finite_y = jnp.all(jnp.isfinite(lax.stop_gradient(value)))
    y = jnp.where(finite_y, value, y0)
    if fixed_period:
        return y, T_guess, finite_y
    return _snap(y[1:], j, c), y[0], finite_y


def diagnostics_map(pmap: _PeriodMap, adjoint) -> _PeriodMap:
    """The period map for the diagnostics' derivatives: the orbit's adjoint where it reverses
    (`jax.grad` of a multiplier transposes them), else the forward-mode loop."""
    return dataclasses.replace(pmap, adjoint=adjoint if loop_kinds(adjoint).reverse else None)


def poincare_matrix(fixed_period, n, j, monodromy, jac_T):
    """The (A6) matrix: U − I, or [∂P/∂T, (U − I) without column j] with a free period."""
    if fixed_period:
        return monodromy - jnp.eye(n)
    return jnp.concatenate([jac_T[:, None], (monodromy - jnp.eye(n))[:, _free_columns(n, j)]],
                           axis=1)


# The fields of `_assess` that are functions of the orbit (x0, T, t0, args), with their
# forward-mode derivatives (`_differentiable_diagnostics`); `residual` has none.
_DIFFERENTIABLE = ("monodromy", "multipliers", "poincare_matrix", "poincare_determinant",
                   "impact_times", "impact_pre", "impact_post")


def _differentiable_diagnostics(pmap, fixed_period, n, out, x0, T, t0, args, j):
    """`out` (computed on constants) with true derivatives for the fields that have them
    (a second derivative of the flow, computed only when asked for) and NaN for the
    residual, so that no diagnostic differentiates to a silent 0."""
    primals = (x0, T, t0, args, j)
    jvp = functools.partial(_live_diagnostics_jvp, pmap, fixed_period, n)
    values = with_forward_tangents(jvp, {k: out[k] for k in _DIFFERENTIABLE}, primals)
    residual = without_derivative(out["residual"], primals[:4])
    return {**out, **values, "residual": residual}


def _live_diagnostics(pmap, fixed_period, n, x0, T, t0, args, j):
    """The `_DIFFERENTIABLE` diagnostics as functions of the orbit."""
    zeros = jax.tree.map(jnp.zeros_like, args)
    _, monodromy, jac_T, _, _, sol = period_map_jacobian(pmap, x0, t0, T, args, zeros)
    a6 = poincare_matrix(fixed_period, n, j, monodromy, jac_T)
    return dict(monodromy=monodromy, multipliers=eigvals_sorted(monodromy),
                poincare_matrix=a6, poincare_determinant=jnp.linalg.det(a6),
                impact_times=sol.impact_times, impact_pre=sol.impact_pre,
                impact_post=sol.impact_post)


@orbit_kernel
def _live_diagnostics_jvp(pmap, fixed_period, n, primals, tangents):
    # (one compiled program: outside jit, a jacfwd would run the JVP op by op)
    return jax.jvp(functools.partial(_live_diagnostics, pmap, fixed_period, n), primals,
                   tangents)


@orbit_kernel
def _assess(pmap, fixed_period, n, j, fix, f_guess, x_guess, x0, period, t0, args, converged,
            finite_y, lin, requested_impacts):
    """Diagnostics at the result and the status, most specific reason first."""
    eps = jnp.finfo(x0.dtype).eps
    x_end, monodromy, jac_T, ok, sol = lin[:5]
    x_fixed = lax.stop_gradient(x0)
    gap = x_end - x_fixed
    a6 = poincare_matrix(fixed_period, n, j, monodromy, jac_T)
    j_out = jnp.array(-1) if fixed_period else j
    f_scale = jnp.max(jnp.abs(f_guess))
    f_end = pmap.scene.vector_field(t0, x_fixed, lax.stop_gradient(args))
    at_rest = jnp.array(False) if fixed_period else (
        f_scale <= 1e3 * jnp.finfo(x0.dtype).tiny + 1e-14 * jnp.max(jnp.abs(x_guess))
    )
    fix_tangent = jnp.array(False) if fixed_period else (
        (fix >= 0) & (jnp.abs(f_guess[j]) <= 1e-8 * f_scale)
    )
    # Singular (A6): judged with the columns scaled to unit size, so that the units of T
    # and x do not count as ill-conditioning.
    col = jnp.max(jnp.abs(a6), axis=0)
    scaled = a6 / jnp.where(col > 0, col, 1.0)
    cond = jnp.linalg.cond(jnp.where(jnp.isfinite(scaled), scaled, 0.0))
    singular = ~(cond < 1e-3 / eps) | jnp.any(col == 0)
    tangent_at_end = jnp.array(False) if fixed_period else (
        jnp.abs(f_end[j]) <= 1e-8 * jnp.max(jnp.abs(f_end))
    )
    equilibrium = jnp.array(False) if fixed_period else (
        jnp.max(jnp.abs(f_end)) <= 1e-8 * jnp.maximum(f_scale, jnp.finfo(x0.dtype).tiny)
    )
    wrong_count = (requested_impacts >= 0) & (sol.num_impacts != requested_impacts)
    # The orbit's size: x0 and its impact states (x0 alone may sit near 0 in a coordinate).
    impact_states = jnp.concatenate([sol.impact_pre, sol.impact_post])
    size = jnp.maximum(jnp.max(jnp.abs(x_fixed)),
                       jnp.max(jnp.where(jnp.isfinite(impact_states), jnp.abs(impact_states), 0.0)))
    loose_atol = pmap.atol > 10 * pmap.rtol * size
    if pmap.end_impacts > 0:
        sim_failed = ~ok & (sol.status != Status.SUCCESS)
        no_end_impact = ~ok & (sol.status == Status.SUCCESS)
    else:
        sim_failed, no_end_impact = ~ok, jnp.array(False)
    S = OrbitStatus
    status = jnp.select(
        [at_rest, fix_tangent, ~finite_y, no_end_impact, sim_failed,
         jnp.array(not fixed_period) & (lax.stop_gradient(period) <= 0), equilibrium,
         tangent_at_end, ~converged, singular, wrong_count, loose_atol],
        [S.EQUILIBRIUM, S.FIX_TANGENT, S.DIVERGED, S.NO_END_IMPACT, S.SIMULATION_FAILED,
         S.BAD_PERIOD, S.EQUILIBRIUM, S.FIX_TANGENT, S.NO_CONVERGENCE, S.SINGULAR,
         S.IMPACT_COUNT, S.LOOSE_ATOL],
        S.SUCCESS,
    )
    return dict(
        num_impacts=sol.num_impacts, impact_times=sol.impact_times,
        impact_pre=sol.impact_pre, impact_post=sol.impact_post,
        impact_surface=sol.impact_surface, impact_kind=sol.impact_kind,
        monodromy=monodromy, multipliers=eigvals_sorted(monodromy), poincare_matrix=a6,
        poincare_determinant=jnp.linalg.det(a6), residual=jnp.max(jnp.abs(gap)),
        status=status.astype(jnp.int32), fix=jnp.asarray(j_out),
    )


# --------------------------------------------------------------------------------------
# find_periodic_orbit
# --------------------------------------------------------------------------------------


# A guess is "on" a surface to 1e-9 relative: about 7e4 contact floors.
_GUESS_SLACK = 1e-9 / (FLOOR_ULPS * float(np.finfo(np.float64).eps))


def _host_float(value) -> float:
    """A user's root-finder tolerance as a Python float for `SolverSettings`; NaN if traced.

    (Under `jit` the default Newton's tolerances, arrays from `_newton_for`, are tracers
    too: `float()` of them raised, so `find_periodic_orbit` failed inside `jit`/`vmap`;
    their settings now come from `newton_tol` and the scale, known on the host.)
    """
    return float(value) if is_concrete(value) else math.nan


def _on_surfaces(scene: Scene, t0, x0, args) -> list[int]:
    """Indices of the surfaces whose zero set contains the guess x0 (see `_GUESS_SLACK`)."""
    on = _surfaces_containing(scene, jnp.asarray(t0, float), jnp.asarray(x0, float), args)
    return [i for i, on_i in enumerate(on) if bool(on_i)]


@orbit_kernel
def _surfaces_containing(scene: Scene, t, x, args):
    return [on_surface(s.phi, t, x, args, _GUESS_SLACK) for s in scene.surfaces]


def _detect_start(pmap: _PeriodMap, x0, t0, period, args) -> tuple[bool, int]:
    """From a concrete guess: does the period end at an impact, and how many per period?

    x0 starts at an impact when it lies on a surface that the guess trajectory meets
    again near t0 + T; the period then ends with that impact (index k).
    """
    scene = pmap.scene
    on = _on_surfaces(scene, t0, x0, args)
    horizon = t0 + 1.5 * abs(period)
    sol = _run(pmap, jnp.asarray(x0, float), jnp.asarray(t0, float), jnp.asarray(horizon, float), args)
    k = int(sol.num_impacts)
    times = np.asarray(sol.impact_times[:k])
    surfaces = np.asarray(sol.impact_surface[:k])
    if on and k:
        end = t0 + period
        near = [i for i in range(k) if surfaces[i] in on and abs(times[i] - end) <= 0.25 * abs(period)]
        if near:
            best = min(near, key=lambda i: abs(times[i] - end))
            return True, best + 1
    return False, int(np.sum(times <= t0 + period))


def find_periodic_orbit(
    scene: Scene,
    x0,
    period,
    args=None,
    *,
    t0=0.0,
    fix: int | None = None,
    fixed_period: bool = False,
    num_impacts: int | None = None,
    start_at_impact: bool | None = None,
    rtol: float = 1e-10,
    atol: float | None = None,
    solver: diffrax.AbstractSolver | None = None,
    root_finder: optx.AbstractRootFinder | None = None,
    max_steps: int = 40,
    newton_tol: float = 1e-8,
    max_impacts: int = 64,
    max_solver_steps: int = 50_000,
    adjoint=None,
) -> Orbit:
    r"""Find a periodic orbit near a guess: Newton's method on the Poincaré criterion.

    Solves S(T, ζ) = P(ζ, T) − ζ = 0 (paper eq. periodpar) for the period T and the
    initial state ζ, with one coordinate ζ_j held at its given value (the phase
    condition), or for ζ alone with T fixed (`fixed_period=True`, forced systems).

    **Arguments:**

    - `scene`: a [`grazejax.Scene`][].
    - `x0`: guess of the orbit's state at `t0`. It may lie on a surface: if the orbit
      impacts there, x0 is read as the *post-impact* state and the period ends just after
      the closing impact (module docstring).
    - `period`: guess of the period (the exact period when `fixed_period=True`).
    - `args`: the scene's parameters.
    - `t0`: start time (forced systems: the phase of x0).
    - `fix`: the coordinate j kept at `x0[j]` (autonomous systems). Default: the j with the
      largest |f_j(x0)|, so that x_j = x0[j] is a good section; when x0 starts at an impact,
      the j with the largest |∂Φ/∂x_j| (the paper's ζ1 = 0 for Γ = {x1 = 0}).
    - `fixed_period`: hold T fixed and solve for all of x0 (forced, non-autonomous systems).
    - `num_impacts`: impacts per period, if known. The result must have exactly this many
      (else status `IMPACT_COUNT`); with `start_at_impact` it says which impact closes the
      period. Default: counted on the guess trajectory.
    - `start_at_impact`: whether x0 is a post-impact state (see above). Default: detected
      from the guess (x0 on a surface that the guess trajectory meets again near t0 + T).
      Under `jit`/`vmap`/`jacfwd` (traced inputs) pass it, and `num_impacts` if True.
    - `rtol`, `atol`, `solver`, `max_solver_steps`: passed to [`grazejax.simulate`][].
      The orbit cannot be more accurate than the simulation; in weakly contracting
      directions (multiplier ρ near 1) the error is that of one period divided by |1 − ρ|.
      `atol=None` (default) scales it to the orbit: `1e-2 · rtol · s` with s = max |x0| of
      the guess, and once more from the result if that is 10× larger or smaller (a state
      of size 1e-9 then gets atol ≈ 1e-21, not 1e-12, which would leave it 0.1% accurate).
      An explicit `atol` above `10 · rtol · s` (s the result's size) ends in status
      `LOOSE_ATOL`: the orbit is not accurate to `rtol`.
    - `root_finder`: an `optimistix` root finder (default `optx.Newton(newton_tol,
      newton_tol · s)`: the residual and the step are judged relative to the orbit's size).
    - `max_steps`: Newton iterations.
    - `newton_tol`: relative tolerance on the residual and the Newton step.
    - `max_impacts`: size of the impact log (impacts per period must not exceed it).
    - `adjoint`: [`grazejax.simulate`][]'s, for the runs that Newton's method solves.
      The default (`diffrax.ForwardMode()`) lets `jax.jacfwd` differentiate the orbit with
      respect to `args` (implicit function theorem); `diffrax.DirectAdjoint()` also lets
      `jax.grad` do it. Newton linearises in forward mode, so the reverse-only
      `diffrax.RecursiveCheckpointAdjoint()` is a `ValueError`.

    **Returns:** an [`grazejax.Orbit`][] (with the [`grazejax.SolverSettings`][] used).
    Failure is a status (`orbit.message`), never an exception inside `jit`; a diverged
    solve returns its starting point (the guess, after the phase refinement) with the
    diagnostics there, never NaN, and `orbit.stable` is then False (no verdict).

    **Example:** the continuous cycle Ψ_μ of ex1dof at μ = −0.2 (period 2π):

    ```python
    import grazejax as gj
    from grazejax import examples as ex

    orbit = gj.find_periodic_orbit(ex.ex1dof(), [1.8, 0.0], 6.2, ex.ex1dof_args(-0.2), fix=1)
    print(orbit.summary())   # period 6.283185307..., multipliers 1 and exp(−2π·1e-4·0.64)
    ```
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    x_guess = jnp.asarray(x0, dtype=float)
    if x_guess.ndim != 1:
        raise ValueError(f"x0 must be a state vector of shape (n,), got shape {x_guess.shape}")
    n = x_guess.shape[0]
    if fix is not None and not (isinstance(fix, (int, np.integer)) and 0 <= fix < n):
        raise ValueError(f"fix must be a coordinate index in [0, {n}), got {fix!r}")
    if not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    if num_impacts is not None and (not isinstance(num_impacts, (int, np.integer)) or num_impacts < 0):
        raise ValueError(f"num_impacts must be a non-negative integer, got {num_impacts!r}")
    if is_concrete(period) and not (np.isfinite(float(period)) and float(period) > 0):
        raise ValueError(f"period must be a positive finite number, got {float(period)}")
    if is_concrete(x_guess) and not np.all(np.isfinite(np.asarray(x_guess))):
        raise ValueError(f"x0 contains NaN or inf: {np.asarray(x_guess)}")

    if not loop_kinds(adjoint).forward:
        raise ValueError(
            "find_periodic_orbit: Newton's method linearises the period map in forward mode, "
            "which adjoint=diffrax.RecursiveCheckpointAdjoint() does not support; pass "
            "adjoint=diffrax.DirectAdjoint() to differentiate the orbit with jax.grad"
        )
    # Absolute tolerances scale with the orbit (a guess that is traced counts as size 1).
    scale = _state_scale(x_guess) if is_concrete(x_guess) else 1.0
    scaled_atol = atol is None
    atol_used = _ATOL_PER_RTOL * float(rtol) * scale if scaled_atol else float(atol)
    pmap = _PeriodMap(
        scene=scene, end_impacts=0, solver=solver, rtol=float(rtol), atol=atol_used,
        max_impacts=int(max_impacts), max_solver_steps=int(max_solver_steps),
    )
    if start_at_impact is None or (start_at_impact and num_impacts is None):
        if not is_concrete(x_guess, period, args, t0):
            raise ValueError(
                "inside jit/vmap/jacfwd (traced x0, period, args or t0) pass "
                "start_at_impact (and num_impacts when True): they select the compiled "
                "period map, and detecting them needs a concrete guess"
            )
        detected_start, detected_k = _detect_start(pmap, x_guess, float(t0), float(period), args)
        if start_at_impact is None:
            start_at_impact = detected_start
        if num_impacts is None and start_at_impact:
            num_impacts = detected_k if detected_start else None
        if start_at_impact and not num_impacts:
            raise ValueError(
                "start_at_impact=True but the guess trajectory has no impact near t0 + T: "
                "pass num_impacts"
            )
    pmap = dataclasses.replace(pmap, end_impacts=int(num_impacts) if start_at_impact else 0)
    user_root_finder = root_finder is not None
    if root_finder is None:
        root_finder = _newton_for(newton_tol, scale)
    requested = jnp.asarray(-1 if num_impacts is None else int(num_impacts))
    fixed_period = bool(fixed_period)
    t0 = jnp.asarray(t0, float)
    T_guess = jnp.asarray(period, float)
    fix_arg = jnp.asarray(-1 if fix is None else fix)
    # Newton carries the derivatives of the orbit (implicit function theorem) in what
    # defines it: args, t0, the fixed period and the phase condition's value x_j = c. The
    # guess and the diagnostics see constants (the diagnostics get their derivatives
    # below, only when asked for).
    t0_live, T_live, x_live = t0, T_guess, x_guess
    x_guess, t0, T_guess, args_const = lax.stop_gradient((x_guess, t0, T_guess, args))
    j, c, f_guess, lin = _phase_condition(pmap, x_guess, t0, T_guess, args_const, fix_arg,
                                          fixed_period)
    if fixed_period:
        y0 = x_guess
    else:
        T_start = _refine_period(pmap, x_guess, t0, T_guess, args_const, j, c, lin)
        y0 = jnp.concatenate([T_start[None], x_guess])
        c = c + (x_live[j] - lax.stop_gradient(x_live[j]))  # (c's derivative, if any)
    T_fixed = T_live if fixed_period else T_guess
    # Only Newton's runs carry the adjoint: the diagnostics are evaluated without
    # derivatives, on the (faster) forward-mode loop.
    value, converged, num_steps = _newton(
        dataclasses.replace(pmap, adjoint=adjoint), fixed_period, root_finder, int(max_steps),
        y0, t0_live, T_fixed, args, j, c,
    )
    x0, T, finite_y = _solution_point(fixed_period, value, y0, T_fixed, j, c)
    x_const, T_const = lax.stop_gradient((x0, T))
    lin = _linearize(pmap, x_const, t0, T_const, args_const)
    out = _assess(pmap, fixed_period, n, j, fix_arg, f_guess, x_guess, x_const, T_const, t0,
                  args_const, converged, finite_y, lin, requested)
    out = _differentiable_diagnostics(diagnostics_map(pmap, adjoint), fixed_period, n, out,
                                      x0, T, t0_live, args, j)
    t0 = t0_live
    if user_root_finder:
        newton_rtol, newton_atol = (_host_float(getattr(root_finder, name, math.nan))
                                    for name in ("rtol", "atol"))
    else:
        newton_rtol, newton_atol = map(float, _newton_tolerances(newton_tol, scale))
    settings = SolverSettings(
        solver=_solver_name(solver), rtol=float(rtol), atol=atol_used,
        newton_rtol=newton_rtol, newton_atol=newton_atol,
        max_steps=int(max_steps),
        max_solver_steps=int(max_solver_steps), max_impacts=int(max_impacts), state_scale=scale,
    )
    orbit = Orbit(x0=x0, t0=t0, period=T, num_steps=num_steps,
                  start_at_impact=bool(start_at_impact), fixed_period=fixed_period,
                  settings=settings, **out)
    if scaled_atol and not user_root_finder and is_concrete(orbit.x0, orbit.status):
        # The guess's size may be far from the orbit's (a poor guess, or x0 near 0 in a
        # small orbit): solve once more, from the result, with tolerances of its size.
        k = int(orbit.num_impacts)
        size = _state_scale(orbit.x0, np.asarray(orbit.impact_pre)[:k],
                            np.asarray(orbit.impact_post)[:k])
        usable = int(orbit.status) in (OrbitStatus.SUCCESS, OrbitStatus.LOOSE_ATOL)
        if usable and not (0.1 * scale <= size <= 10 * scale):
            return find_periodic_orbit(
                scene, orbit.x0, orbit.period, args, t0=t0, fix=int(orbit.fix) if int(orbit.fix) >= 0 else None,
                fixed_period=fixed_period, num_impacts=int(orbit.num_impacts),
                start_at_impact=bool(start_at_impact), rtol=rtol, atol=_ATOL_PER_RTOL * float(rtol) * size,
                solver=solver, max_steps=max_steps, newton_tol=newton_tol,
                max_impacts=max_impacts, max_solver_steps=max_solver_steps, adjoint=adjoint,
            )
    return orbit


# --------------------------------------------------------------------------------------
# Floquet multipliers, stably
# --------------------------------------------------------------------------------------


class Floquet(eqx.Module):
    r"""Floquet multipliers of an orbit from per-impact factors ([`grazejax.floquet_multipliers`][]).

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

    The matrix of [`grazejax.saltation_matrix`][] (one implementation for the package):
    S = DJ + (f⁺ − DJ f⁻ − ∂J/∂t) ∇Φᵀ / (∂Φ/∂t + ∇Φ·f⁻). It diverges like 1/(∇Φ·f⁻) near a
    grazing contact; exactly at one it is the (N2) value, the identity.
    """
    return saltation_matrix(scene, surface_index, t, x_pre, args).matrix


@orbit_kernel
def _flights_to_impact(pmap_impact: _PeriodMap, starts, t_starts, durations, nudges, args):
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


def _flight_factor(pmap_time: _PeriodMap, x, t, duration, args, tau=0.0):
    """Time-fixed Jacobian of the flight from (t, x) over `duration`, after a free nudge τ."""
    if float(tau) == 0.0:
        return _linearize(pmap_time, x, t, duration, args)[1]
    f = pmap_time.scene.vector_field
    x1 = short_free_flow(f, t, jnp.asarray(x), tau, args)
    nudge = _nudge_jacobian(f, t, jnp.asarray(x), tau, args)
    return _linearize(pmap_time, x1, t + tau, duration - tau, args)[1] @ nudge


def _nudge_times(durations, period):
    """How far to move along the free flow before restarting from a post-impact state."""
    return np.minimum(1e-3 * np.asarray(durations), 1e-3 * period)


@single_run_jit
def _traces(scene: Scene, ts, xs, args):
    f = scene.vector_field
    return jax.vmap(lambda t, x: jnp.trace(jax.jacfwd(lambda y: f(t, y, args))(x)))(ts, xs)


def _trace_integral(pmap: _PeriodMap, x0, t0, period, boundaries, args, num_nodes=400):
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
    sol = _sampled(pmap, jnp.asarray(x0), jnp.asarray(t0), jnp.asarray(t0 + period), args,
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
    [`grazejax.simulate`][]), the closed-form saltation matrices S_i, and the last flight;
    U = Φ_last S_k Φ_k ⋯ S_1 Φ_1. The multipliers are the eigenvalues of that product by a
    periodic-Schur sweep (`product_eigenvalues`), which keeps tiny
    multipliers (near grazing, det S_i ∝ v → 0) that the eigenvalues of the formed
    monodromy lose to cancellation.

    The determinant identity det U = Π det S_i · exp(∫ tr ∂f/∂x dt) is checked with the
    closed-form saltation matrices and the trace integrated along the orbit.

    Run outside `jit` (it loops over impacts in Python). Use the same `rtol`, `atol`,
    `solver` as the orbit solve (`atol=None`: scaled to the orbit's size as there).
    """
    atol = _atol_for(orbit, rtol, atol)
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
        pmap_impact = _PeriodMap(scene=scene, end_impacts=1, **common)
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
        pmap_time = _PeriodMap(scene=scene, end_impacts=0, **common)
        tau = float(_nudge_times([end - last], float(orbit.period))[0]) if k else 0.0
        factors.append(np.asarray(_flight_factor(
            pmap_time, jnp.asarray(x_last), jnp.asarray(last), jnp.asarray(end - last), args,
            jnp.asarray(tau),
        )))
    factors = np.stack(factors)
    multipliers = product_eigenvalues(factors)

    pmap_time = _PeriodMap(scene=scene, end_impacts=0, **common)
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
        stable=_a5(jnp.asarray(multipliers), orbit.fixed_period),
    )


# --------------------------------------------------------------------------------------
# Contacts along an orbit: impacts and near-grazing passes
# --------------------------------------------------------------------------------------


class Contacts(eqx.Module):
    r"""Where an orbit meets or nearly meets its surfaces ([`grazejax.orbit_contacts`][]).

    One row per impact and per local minimum of a gap Φ_i along a flight (inside the
    closed piece), sorted by time. NumPy arrays.

    **Fields:**

    - `times`, `points`: time and state of the contact (pre-impact state for impacts;
      the state at the minimum of Φ_i for passes).
    - `surfaces`: surface index.
    - `is_impact`: True for impacts, False for passes without an impact.
    - `depth`: the signed *virtual depth*, a grazing indicator continuous across grazing:
      for a pass, the minimum of Φ_i (≥ 0: the clearance); for an impact, −v²/(2a), the
      minimum the flight would reach without the impact (v = dΦ/dt < 0 and a = d²Φ/dt² at
      the pre-impact state; −inf if a ≤ 0). depth = 0 is a grazing contact (γ).
    - `speed`, `acceleration`: dΦ/dt and d²Φ/dt² at the contact.
    """

    times: Any
    points: Any
    surfaces: Any
    is_impact: Any
    depth: Any
    speed: Any
    acceleration: Any

    def grazing(self, tol: float) -> np.ndarray:
        """Boolean mask of the contacts with |depth| ≤ tol."""
        return np.abs(np.asarray(self.depth)) <= tol


@single_run_jit
def _gap_table(scene: Scene, ts, xs, args):
    """Φ_i, dΦ_i/dt, d²Φ_i/dt² and `where_i` at many (t, x), for every surface."""
    rows = []
    for i, surface in enumerate(scene.surfaces):
        g, gd, gdd = jax.vmap(lambda t, x, i=i: gap_rates(scene.surfaces[i].phi, scene.vector_field, t, x, args))(ts, xs)
        if surface.where is None:
            inside = jnp.ones_like(g, dtype=bool)
        else:
            inside = jax.vmap(lambda t, x, s=surface: jnp.asarray(s.where(t, x, args), bool))(ts, xs)
        rows.append((g, gd, gdd, inside))
    return rows


def _refine_minimum(pmap, scene, i, x0, t0, t_guess, args, lo, hi):
    """One Newton step on dΦ/dt = 0 from t_guess, with the exact state there."""
    t_guess = float(np.clip(t_guess, lo, hi))
    x = _state_at(pmap, x0, t0, t_guess, args)
    g, gd, gdd = (float(v) for v in gap_rates_at(scene.surfaces[i].phi, scene.vector_field, jnp.asarray(t_guess), jnp.asarray(x), args))
    if gdd > 0:
        dt = float(np.clip(-gd / gdd, lo - t_guess, hi - t_guess))
        t_min = t_guess + dt
        depth = g + gd * dt + 0.5 * gdd * dt * dt
        x_min = _state_at(pmap, x0, t0, t_min, args)
        return t_min, x_min, depth, gd + gdd * dt, gdd
    return t_guess, x, g, gd, gdd


def orbit_contacts(scene: Scene, orbit: Orbit, args=None, *, num_samples: int = 400,
                   max_depth: float = 0.05, solver=None, rtol: float = 1e-10,
                   atol: float | None = None) -> Contacts:
    r"""The impacts of an orbit and its near-grazing passes, with a grazing indicator.

    Passes are local minima of Φ_i along the flights, found on `num_samples` samples of
    one period and refined by a Newton step on dΦ/dt = 0 with the exact state; only those
    inside the closed piece with |min Φ_i| ≤ `max_depth` are kept. See [`grazejax.Contacts`][]
    for the signed depth (the indicator used to locate grazing bifurcations).
    `atol=None`: scaled to the orbit's size, as in [`grazejax.find_periodic_orbit`][].
    """
    atol = _atol_for(orbit, rtol, atol)
    pmap = _PeriodMap(scene=scene, end_impacts=0, solver=solver, rtol=float(rtol),
                      atol=float(atol), max_impacts=64, max_solver_steps=50_000)
    t0, T = float(orbit.t0), float(orbit.period)
    x0 = np.asarray(orbit.x0, float)
    k = int(orbit.num_impacts)
    rows = []  # (time, point, surface, is_impact, depth, speed, accel)
    times = np.asarray(orbit.impact_times[:k], float)
    for m in range(k):
        i = int(orbit.impact_surface[m])
        pre = np.asarray(orbit.impact_pre[m], float)
        g, gd, gdd = (float(v) for v in gap_rates_at(scene.surfaces[i].phi, scene.vector_field, jnp.asarray(times[m]), jnp.asarray(pre), args))
        depth = -gd * gd / (2 * gdd) if gdd > 0 else -math.inf
        rows.append((times[m], pre, i, True, depth, gd, gdd))
    if scene.surfaces:
        ts = t0 + T * (np.arange(num_samples) + 0.5) / num_samples
        sol = _sampled(pmap, jnp.asarray(x0), jnp.asarray(t0), jnp.asarray(t0 + T), args, jnp.asarray(ts))
        xs = np.asarray(sol.xs)
        table = _gap_table(scene, jnp.asarray(ts), jnp.asarray(xs), args)
        h = T / num_samples
        # Samples whose neighbourhood contains an impact see a jump, not a minimum.
        near_impact = np.zeros(num_samples, bool)
        for tm in times:
            near_impact |= np.abs(ts - tm) <= 1.5 * h
        for i, (g, _, _, inside) in enumerate(table):
            g = np.asarray(g)
            for m in range(1, num_samples - 1):
                if near_impact[m] or not (g[m - 1] > g[m] <= g[m + 1]):
                    continue
                # The piece is closed: at a grazing pass on ∂Γ (ex1dof: x2 = 0) the sample
                # nearest the minimum may fall just outside `where`.
                if abs(g[m]) > max_depth or not np.any(np.asarray(inside)[m - 1 : m + 2]):
                    continue
                # Vertex of the parabola through three samples, then one exact Newton step.
                denom = g[m - 1] - 2 * g[m] + g[m + 1]
                shift = 0.5 * (g[m - 1] - g[m + 1]) / denom if denom > 0 else 0.0
                t_min, x_min, depth, speed, accel = _refine_minimum(
                    pmap, scene, i, x0, t0, ts[m] + shift * h, args, ts[m - 1], ts[m + 1]
                )
                rows.append((t_min, x_min, i, False, depth, speed, accel))
    rows.sort(key=lambda r: r[0])
    n = x0.shape[0]

    def col(j, dtype, shape=()):
        return np.array([r[j] for r in rows], dtype=dtype).reshape((len(rows),) + shape)

    return Contacts(times=col(0, float), points=col(1, float, (n,)), surfaces=col(2, int),
                    is_impact=col(3, bool), depth=col(4, float), speed=col(5, float),
                    acceleration=col(6, float))


# --------------------------------------------------------------------------------------
# Branches of the variational system at grazing contacts (A4), (A5)
# --------------------------------------------------------------------------------------


class GrazingBranches(eqx.Module):
    r"""The one-sided linearizations of a grazing orbit ([`grazejax.grazing_branches`][]).

    With l grazing contacts, a neighbouring solution impacts or not at each of them, and
    the paper's (A4) splits the variational system into m ≤ 2^l periodic systems. Row b
    describes branch b. NumPy arrays.

    **Fields:**

    - `contact_times`, `contact_points`, `contact_surfaces`: the l grazing contacts.
    - `impacts`: `(m, l)` bool: whether branch b impacts at each contact.
    - `section_jacobian`: `(m, d, d)` the one-sided limit of the Jacobian of the return
      map to the section Σ through `base_point` (autonomous: d = n − 1, Σ ⟂ f; forced:
      d = n, the time-T map). NaN where the limit is infinite.
    - `monodromy`: `(m, n, n)` the branch monodromy at `base_point`, phase-normalised for
      autonomous orbits (identity along f, `section_jacobian` on Σ; the coupling of Σ into
      the phase, which diverges like 1/v on impacting branches, is dropped), the limit of
      the time-T map's Jacobian for forced ones.
    - `multipliers`: `(m, n)` complex, modulus descending (the trivial 1 included for
      autonomous orbits).
    - `finite`: `(m,)` whether the one-sided limit exists (Nordmark's square-root
      singularity makes it infinite on the impacting side of most grazings).
    - `realized`: `(m,)` whether neighbours with that impact pattern were found.
    - `a5`: `(m,)` the (A5) verdict per branch.
    - `base_time`, `base_point`, `section_basis`: where the Jacobians are taken (a point
      of the orbit away from all contacts) and the orthonormal basis Q of Σ used.
    - `depths`: the neighbour depths δ the limits were extrapolated from.
    """

    contact_times: Any
    contact_points: Any
    contact_surfaces: Any
    impacts: Any
    section_jacobian: Any
    monodromy: Any
    multipliers: Any
    finite: Any
    realized: Any
    a5: Any
    base_time: Any
    base_point: Any
    section_basis: Any
    depths: Any


def _contact_depths(pmap, scene, start, t_start, t_end, contacts, args, window):
    """Signed depth at each contact for the trajectory from (t_start, start).

    Impact near t_c on the contact's surface: −v²/(2a) from the log; else the refined
    minimum of Φ near t_c. Returns (depths, impacted, solution).
    """
    sol = _run(pmap, jnp.asarray(start), jnp.asarray(t_start), jnp.asarray(t_end), args)
    k = int(sol.num_impacts)
    times = np.asarray(sol.impact_times[:k])
    surfaces = np.asarray(sol.impact_surface[:k])
    depths, impacted = [], []
    for (t_c, i), w in zip(contacts, window, strict=True):
        hits = [m for m in range(k) if surfaces[m] == i and abs(times[m] - t_c) <= w]
        if hits:
            m = min(hits, key=lambda m_: abs(times[m_] - t_c))
            g, gd, gdd = (float(v) for v in gap_rates_at(
                scene.surfaces[i].phi, scene.vector_field, jnp.asarray(times[m]), sol.impact_pre[m], args))
            depths.append(-gd * gd / (2 * gdd) if gdd > 0 else -math.inf)
            impacted.append(True)
        else:
            _, _, depth, _, _ = _refine_minimum(pmap, scene, i, start, t_start, t_c, args,
                                                t_c - w, t_c + w)
            depths.append(depth)
            impacted.append(False)
    return np.array(depths), np.array(impacted, bool), sol


def grazing_branches(scene: Scene, orbit: Orbit, args=None, *, contact_tol: float = 1e-6,
                     depths=None, solver=None, rtol: float = 1e-10,
                     atol: float | None = None) -> GrazingBranches:
    r"""Monodromy matrices and multipliers of each branch of a grazing orbit's linearization.

    At a grazing contact the variational system is bivalued (paper eq. beta / betaexi): a
    neighbour that misses the surface sees no jump (B = O), one that impacts sees the
    saltation matrix of an impact with a small normal speed v. With l contacts there are
    up to 2^l branches (assumption (A4)); (A5) asks each to have the multiplier 1 simple
    and all others inside the unit circle.

    **What is computed.** The saltation matrix diverges like 1/v as v → 0, so it cannot
    simply be evaluated on the grazing orbit. Instead, for each impact pattern, we take
    neighbours of the orbit that realize it (each contact's depth set to ±δ through a
    perturbation of the start inside the section Σ), compute the Jacobian of their return
    map to Σ with `jax.jacfwd` through [`grazejax.simulate`][], and extrapolate to δ → 0
    by least squares in (1, √δ, δ) (the impacting side converges like v ∝ √δ). For an
    autonomous orbit the return map to Σ removes the phase: the 1/v divergence of an
    impact is along the flow (a time shift of order √δ) and does not survive the
    projection when the scene's jump law cancels it, as the paper's (A2) requires
    (ex1dof). When the limit still grows like δ^(−1/2) (Nordmark's square-root
    singularity, e.g. any forced impact oscillator with Newtonian restitution), the branch
    is reported with `finite = False` and infinite multipliers: (A5) fails.

    **Arguments:**

    - `scene`, `orbit`, `args`: the orbit (from [`grazejax.find_periodic_orbit`][]).
    - `contact_tol`: contacts with |virtual depth| ≤ this are grazing
      (see [`grazejax.orbit_contacts`][]).
    - `depths`: neighbour depths δ (default 1e-4·4^(−m), m = 0…5, in units of Φ).
    - `solver`, `rtol`, `atol`: for [`grazejax.simulate`][].

    **Returns:** a [`grazejax.GrazingBranches`][]. An orbit without grazing contacts has a
    single branch (its own linearization).
    """
    atol = _atol_for(orbit, rtol, atol)
    depths = np.asarray([1e-4 * 4.0 ** (-m) for m in range(6)] if depths is None else depths, float)
    pmap = _PeriodMap(scene=scene, end_impacts=0, solver=solver, rtol=float(rtol),
                      atol=float(atol), max_impacts=64, max_solver_steps=50_000)
    contacts = orbit_contacts(scene, orbit, args, solver=solver, rtol=rtol, atol=atol)
    graze = contacts.grazing(contact_tol)
    t0, T = float(orbit.t0), float(orbit.period)
    x0 = np.asarray(orbit.x0, float)
    n = x0.shape[0]
    autonomous = not orbit.fixed_period

    # Base point: the middle of the longest stretch between events (impacts, contacts).
    events = np.sort(np.concatenate([np.asarray(contacts.times, float), [t0]]))
    gaps = np.diff(np.concatenate([events, [events[0] + T]]))
    m = int(np.argmax(gaps))
    t_s = events[m] + 0.5 * gaps[m]
    if t_s >= t0 + T:
        t_s -= T
    x_s = _state_at(pmap, x0, t0, t_s, args)
    f_s = np.asarray(scene.vector_field(jnp.asarray(t_s), jnp.asarray(x_s), args), float)
    if autonomous:
        normal = f_s / np.linalg.norm(f_s)
        q, _ = np.linalg.qr(np.column_stack([normal, np.eye(n)]))
        basis = q[:, 1:n]
    else:
        normal = None
        basis = np.eye(n)
    d = basis.shape[1]

    c_times = np.asarray(contacts.times, float)[graze]
    c_times = np.where(c_times < t_s, c_times + T, c_times)  # times on the loop from t_s
    c_surfaces = np.asarray(contacts.surfaces)[graze]
    order = np.argsort(c_times)
    c_times, c_surfaces = c_times[order], c_surfaces[order]
    c_points = np.asarray(contacts.points, float)[graze][order]
    num_contacts = len(c_times)
    all_times = np.sort(np.concatenate([np.asarray(contacts.times, float), [t_s, t_s + T]]))
    window = [0.25 * np.min(np.diff(np.unique(np.concatenate([all_times, all_times + T]))))] * num_contacts
    key = list(zip(c_times, c_surfaces.tolist(), strict=True))

    def return_jacobian(start):
        """Jacobian of the return map to Σ (or of the time-T map) at `start`."""
        tau = T
        if autonomous:
            for _ in range(3):
                end = np.asarray(_run(pmap, jnp.asarray(start), jnp.asarray(t_s),
                                      jnp.asarray(t_s + tau), args).x_final)
                f_end = np.asarray(scene.vector_field(jnp.asarray(t_s + tau), jnp.asarray(end), args))
                tau -= float(normal @ (end - x_s)) / float(normal @ f_end)
        M = np.asarray(_linearize(pmap, jnp.asarray(start), jnp.asarray(t_s), jnp.asarray(tau), args)[1])
        if not autonomous:
            return M
        end = np.asarray(_run(pmap, jnp.asarray(start), jnp.asarray(t_s), jnp.asarray(t_s + tau), args).x_final)
        f_end = np.asarray(scene.vector_field(jnp.asarray(t_s + tau), jnp.asarray(end), args))
        project = np.eye(n) - np.outer(f_end, normal) / float(normal @ f_end)
        return basis.T @ project @ M @ basis

    def measure(delta_vec):
        start = x_s + basis @ delta_vec
        dep, hit, _ = _contact_depths(pmap, scene, start, t_s, t_s + 1.05 * T, key, args, window)
        return dep, hit

    if num_contacts == 0:
        patterns = [()]
        G = np.zeros((0, d))
    else:
        # Depth gradients in Σ, by central differences (depth is continuous across grazing).
        h = 1e-6 * max(1.0, float(np.max(np.abs(x_s))))
        G = np.zeros((num_contacts, d))
        for j in range(d):
            e = np.zeros(d)
            e[j] = h
            G[:, j] = (measure(e)[0] - measure(-e)[0]) / (2 * h)
        patterns = [tuple(bool(b) for b in bits) for bits in np.ndindex(*(2,) * num_contacts)]

    m_branches = len(patterns)
    jac = np.full((m_branches, d, d), np.nan)
    mono = np.full((m_branches, n, n), np.nan)
    mult = np.full((m_branches, n), np.nan + 0j)
    finite = np.zeros(m_branches, bool)
    realized = np.zeros(m_branches, bool)
    for b, pattern in enumerate(patterns):
        if num_contacts == 0:
            samples = [return_jacobian(x_s)]
            used = np.array([0.0])
            realized[b] = True
        else:
            sign = np.array([-1.0 if hit else 1.0 for hit in pattern])
            pinv = np.linalg.pinv(G)
            samples, used = [], []
            for delta in depths:
                target = sign * delta
                dv = pinv @ target
                ok = False
                for _ in range(3):  # correct the linear model with the measured depths
                    dep, hit = measure(dv)
                    if np.array_equal(hit, np.array(pattern)) and np.all(np.sign(dep) == sign):
                        ok = True
                        break
                    dv = dv + pinv @ (target - np.where(np.isfinite(dep), dep, 0.0))
                if ok:
                    samples.append(return_jacobian(x_s + basis @ dv))
                    used.append(delta)
            realized[b] = len(samples) >= 3
        if not realized[b]:
            continue
        samples = np.stack(samples)
        used = np.asarray(used)
        if num_contacts == 0:
            limit, grows = samples[0], False
        else:
            norms = np.array([np.linalg.norm(s) for s in samples])
            slope = np.polyfit(np.log(used[-3:]), np.log(norms[-3:]), 1)[0]
            grows = slope < -0.25
            design = np.column_stack([np.ones_like(used), np.sqrt(used), used])
            coef, *_ = np.linalg.lstsq(design, samples.reshape(len(used), -1), rcond=None)
            limit = coef[0].reshape(d, d)
        if grows or not np.all(np.isfinite(limit)):
            mult[b] = np.inf
            continue
        finite[b] = True
        jac[b] = limit
        if autonomous:
            mono[b] = np.outer(normal, normal) + basis @ limit @ basis.T
            rho = np.concatenate([[1.0 + 0j], np.linalg.eigvals(limit)])
        else:
            mono[b] = limit
            rho = np.linalg.eigvals(limit).astype(complex)
        mult[b] = rho[np.argsort(-np.abs(rho), kind="stable")]
    a5 = np.asarray(_a5(jnp.asarray(mult), orbit.fixed_period)) & finite
    return GrazingBranches(
        contact_times=np.where(c_times >= t0 + T, c_times - T, c_times),
        contact_points=c_points, contact_surfaces=c_surfaces,
        impacts=np.array(patterns, bool).reshape(m_branches, num_contacts), section_jacobian=jac,
        monodromy=mono, multipliers=mult, finite=finite, realized=realized, a5=a5,
        base_time=t_s, base_point=x_s, section_basis=basis, depths=depths,
    )
