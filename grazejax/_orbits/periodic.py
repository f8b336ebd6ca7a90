r"""Periodic orbits of impact systems: shooting, monodromy, Floquet multipliers, (A6).

Paper objects (Akhmet & Kıvılcım, *Discontinuous dynamics with grazing points*, §4–§5):

- the Poincaré criterion S(T, ζ) = x(T; ζ) − ζ = 0 with one coordinate ζ_j fixed
  (eq. periodpar), solved by Newton's method (`grazejax.find_periodic_orbit`);
- its Jacobian at the solution, the (A6) matrix [∂S/∂T, ∂S/∂ζ_k (k ≠ j)], and the
  monodromy matrix U(ω) of the variational system (eq. graz1lin1);
- the Floquet multipliers and the (A5) verdict, computed stably from per-impact factors
  (`grazejax.floquet_multipliers`);
- at a grazing orbit, the (up to 2^l) one-sided variational systems of (A4), impacting or
  not at each grazing contact (`grazejax.grazing_branches`).

**The period map and where the period ends.** Solutions are left-continuous (docs/semantics.md).
If x0 is away from the orbit's impacts the period map is the time-T map
P(x0, T) = x(t0 + T; t0, x0) of `grazejax.simulate`. The paper starts its cycles *at*
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

**Differentiation.** Newton runs in `optx.root_find`, and `period_map.newton_root` gives
derivatives of the orbit (x0, period) with respect to `args` by the implicit function
theorem; `jax.jacfwd` works, and `jax.grad` with `adjoint=diffrax.DirectAdjoint()` (the
residual's derivative in `args` then runs backward through `simulate`). Diagnostics
(monodromy, multipliers, (A6), impacts) are evaluated at the solution without derivatives
and given their true ones (second derivatives of the flow) only when differentiated
(`_differentiable_diagnostics`); the residual differentiates to NaN.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import diffrax
import equinox as eqx
import jax
import jax.lax as lax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Complex, Float, Int

from .._adjoint import loop_kinds, require_forward_mode
from .._deprecated import NEWTON_STEPS, renamed_keyword
from .._geometry import FLOOR_ULPS, on_surface
from .._scene import Scene
from .._solution import ImpactLog
from .._status import Status, StatusCode
from .._tangents import with_forward_tangents, without_derivative
from .._validate import is_concrete
from .period_map import (
    ATOL_PER_RTOL,
    PeriodMap,
    SolverSettings,
    a5_holds,
    linearize,
    newton_for,
    newton_root,
    newton_tolerances,
    orbit_kernel,
    orbit_scale,
    period_map_jacobian,
    run_period_map,
    solver_name,
)

# --------------------------------------------------------------------------------------
# Status
# --------------------------------------------------------------------------------------


class OrbitStatus(StatusCode):
    """How a periodic-orbit solve ended. Stored as an integer array in `Orbit.status`.

    Inside `jax.jit` / `jax.vmap` nothing raises: `OrbitStatus(int(orbit.status))` reads it,
    and `.message` says what to try.
    """

    SUCCESS = 0, "converged to an isolated periodic orbit"
    """Newton converged to a periodic orbit with a regular (A6) matrix."""
    NO_CONVERGENCE = (
        1,
        "Newton did not converge within max_newton_steps: improve the guess (x0, period) or loosen "
        "newton_tol (it cannot beat the simulation's accuracy)",
    )
    """The root finder used `max_newton_steps` iterations without meeting `newton_tol`."""
    DIVERGED = (
        2,
        "Newton diverged (non-finite iterates): the guess is too far from a periodic orbit, or "
        "the iteration left the region where the period map is defined",
    )
    """The Newton iterates became non-finite (the guess is far from any orbit, or the
    iteration left the region where the period map is defined)."""
    SIMULATION_FAILED = (
        3,
        "simulate did not complete one period at the result (Zeno, max steps, non-finite state,"
        " or more impacts than max_impacts)",
    )
    """`simulate` did not complete the period at the result (Zeno, max steps, NaN, or more
    impacts than `max_impacts`)."""
    SINGULAR = (
        4,
        "the (A6) matrix of the Poincaré criterion is singular or ill-conditioned: the orbit is"
        " not isolated (fold, multiplier 1 of a forced system, or fixed_period=True on an "
        "autonomous system)",
    )
    """The (A6) matrix is singular or ill-conditioned: the orbit is not isolated (a fold,
    a multiplier at 1 of a forced system, or `fixed_period=True` on an autonomous system)."""
    FIX_TANGENT = (
        5,
        "the flow is tangent to the fixed coordinate x_fix = const (f_fix(x0) = 0): choose "
        "another `fix` (default: the largest |f_j(x0)|)",
    )
    """The flow is tangent to the fixed coordinate (f_j = 0): x_j = const is not a section."""
    EQUILIBRIUM = 6, "the guess or the result is an equilibrium (f(x0) = 0), not a cycle"
    """The guess or the result is an equilibrium (f(x0) = 0), not a cycle: every T is a
    'period' and the phase condition is undefined."""
    BAD_PERIOD = 7, "the period came out zero or negative"
    """The period came out zero or negative."""
    IMPACT_COUNT = 8, "the orbit found does not have num_impacts impacts per period"
    """The orbit found does not have the requested number of impacts per period."""
    NO_END_IMPACT = (
        9,
        "x0 lies on a surface and was read as a post-impact state, but the impact that closes "
        "the period was not reached",
    )
    """x0 was read as a post-impact state, but the period-closing impact was not reached."""
    LOOSE_ATOL = (
        10,
        "atol is larger than 10·rtol times the orbit's size: the simulation controls its error "
        "in absolute terms only, so the orbit and its multipliers are not accurate to rtol; "
        "pass atol=None (scaled to the orbit) or a smaller atol",
    )
    """Newton converged, but the simulation's `atol` exceeds 10 × `rtol` × the orbit's size:
    the period map (and so the orbit and its multipliers) is only as accurate as
    atol / size, not `rtol`. Pass `atol=None` (scaled to the orbit) or a smaller `atol`."""
    NOT_DOUBLED = (
        11,
        "every start converged to the period-1 orbit run twice: no period-doubled orbit near "
        "the flip point at these args (try the other side of the flip point, or args closer to "
        "it)",
    )
    """`period_doubled_orbit` found only the period-1 orbit run twice from every start
    (past the flip point on the wrong side, or too far from it)."""



# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------


class Orbit(ImpactLog):
    r"""A periodic orbit found by `grazejax.find_periodic_orbit`.

    **Fields:**

    - `x0`: the orbit's state at `t0` (post-impact if the orbit starts at an impact).
    - `t0`: start time (matters for forced systems).
    - `period`: the period T (the paper's 𝒯, or ω).
    - `num_impacts`: impacts per period.
    - `impact_times`, `impact_pre`, `impact_post`, `impact_surface`, `impact_kind`: the
      impacts in (t0, t0 + T], an `grazejax.ImpactLog` (NaN-padded to `max_impacts`).
    - `monodromy`: U(T), the Jacobian of the period map x0 ↦ P(x0, T) (module docstring).
    - `multipliers`: eigenvalues of `monodromy`, complex, sorted by modulus, descending.
      For an autonomous orbit one of them is the trivial multiplier 1.
    - `poincare_matrix`: the (A6) matrix. Autonomous: columns ∂S/∂T first, then ∂S/∂ζ_k
      for the free coordinates k ≠ `fix` in increasing order (eq. periodpar; n × n).
      Forced (`fixed_period=True`): ∂S/∂ζ = U − I.
    - `poincare_determinant`: its determinant; (A6) asks for it to be non-zero.
    - `residual`: ‖P(x0, T) − x0‖∞ at the result.
    - `status`: an `grazejax.OrbitStatus` code; `message` reads it.
    - `fix`: the fixed coordinate j (−1 for `fixed_period=True`).
    - `num_steps`: Newton iterations taken.
    - `start_at_impact`: whether x0 is a post-impact state and the period ends just after
      an impact (static).
    - `fixed_period`: whether T was held fixed (forced systems; static).
    - `settings`: the `grazejax.SolverSettings` it was computed with (static).

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
        return a5_holds(self.multipliers, self.fixed_period) & self.succeeded

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

    Works under `jit` and `vmap` on every backend (`_eigensystem`). Forward-mode
    derivative of a simple eigenvalue: dλ_k = w_k dA v_k (v_k, w_k its right and left
    eigenvectors with w_k v_k = 1); at a repeated eigenvalue of a defective matrix it is
    not finite, as the eigenvalue is not differentiable there.
    """
    return _eigensystem(jnp.asarray(matrix), vectors=False)


@eigvals_sorted.defjvp
def _eigvals_sorted_jvp(primals, tangents):
    (matrix,), (matrix_dot,) = primals, tangents
    w, right, left = _eigensystem(jnp.asarray(matrix), vectors=True)
    dA = jnp.asarray(matrix_dot).astype(jnp.complex128)
    w_dot = jnp.einsum("...ki,...ij,...jk->...k", left, dA, right)
    return w, w_dot


def _eigensystem(matrix, vectors: bool):
    """`w`, or `(w, V, W)` with `vectors` (as `_host_eigensystem`), of a traced matrix.

    On the CPU, LAPACK's eigensolver compiled into the program (`jnp.linalg.eig`): a
    program that calls back to the host is never written to JAX's persistent compilation
    cache (its callbacks are baked into it), and every orbit, bifurcation and
    continuation program holds this solve, so with a callback each of them was compiled
    again in every process. JAX's `eig` is CPU-only: other backends run NumPy's on the
    host (`jax.pure_callback`).
    """
    if jax.default_backend() != "cpu":
        return _host_callback_eigensystem(matrix, vectors)
    finite = jnp.all(jnp.isfinite(matrix), axis=(-2, -1))
    # (LAPACK is not asked about a matrix that is not finite: NaN, as on the host)
    safe = jnp.where(finite[..., None, None], matrix, 0.0)
    w, v = (a.astype(jnp.complex128) for a in jnp.linalg.eig(safe))
    order = jnp.argsort(-jnp.abs(w), axis=-1, stable=True)
    nan = jnp.asarray(jnp.nan + 0j, jnp.complex128)
    w = jnp.where(finite[..., None], jnp.take_along_axis(w, order, axis=-1), nan)
    if not vectors:
        return w
    v = jnp.take_along_axis(v, order[..., None, :], axis=-1)
    v = jnp.where(finite[..., None, None], v, nan)
    # (a defective matrix's V is singular or nearly so: its derivative is not meaningful,
    # as with NumPy's inverse on the host)
    return w, v, jnp.linalg.inv(v)


def _host_callback_eigensystem(matrix, vectors: bool):
    values = jax.ShapeDtypeStruct(matrix.shape[:-1], jnp.complex128)
    if not vectors:
        return jax.pure_callback(_host_eigvals, values, matrix, vmap_method="sequential")
    shapes = (values, *(jax.ShapeDtypeStruct(matrix.shape, jnp.complex128),) * 2)
    return jax.pure_callback(_host_eigensystem, shapes, matrix, vmap_method="sequential")


def _snap(x, j, c):
    """x with x_j = c exactly (j may be traced)."""
    return jnp.where(jnp.arange(x.shape[0]) == j, c, x)


def _free_columns(n, j):
    """Indices 0..n-1 without j, in increasing order (j may be traced)."""
    idx = jnp.arange(n - 1)
    return idx + (idx >= j)


@orbit_kernel
def _newton(pmap: PeriodMap, fixed_period: bool, root_finder, max_newton_steps: int, y0, t0,
            T_fixed, args, j, c):
    """Newton (`newton_root`) on the Poincaré criterion; differentiable in `args`."""
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

    return newton_root(residual, root_finder, y0, args, max_newton_steps)


def _phase_condition(pmap: PeriodMap, x_guess, t0, T_guess, args, fix, fixed_period):
    """(j, c) of the phase condition x_j = c, and the guess run's linearization."""
    lin = linearize(pmap, x_guess, t0, T_guess, args)
    j, c, f_guess = _phase_index(pmap, fixed_period, x_guess, t0, args, fix, lin[4].impact_surface)
    return j, c, f_guess, lin


# The small computations between the compiled period-map programs are kernels too: run
# op by op, each of their operations would compile a program of its own.
@orbit_kernel
def _phase_index(pmap: PeriodMap, fixed_period: bool, x_guess, t0, args, fix, impact_surface):
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


def _refine_period(pmap: PeriodMap, x_guess, t0, T_guess, args, j, c, lin):
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
            x_end, _, jac_T, ok, _ = linearize(pmap, x_guess, t0, T, args)[:5]
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


def diagnostics_map(pmap: PeriodMap, adjoint) -> PeriodMap:
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

    (Under `jit` the default Newton's tolerances, arrays from `newton_for`, are tracers
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


def _detect_start(pmap: PeriodMap, x0, t0, period, args) -> tuple[bool, int]:
    """From a concrete guess: does the period end at an impact, and how many per period?

    x0 starts at an impact when it lies on a surface that the guess trajectory meets
    again near t0 + T; the period then ends with that impact (index k).
    """
    scene = pmap.scene
    on = _on_surfaces(scene, t0, x0, args)
    x0_, t0_ = jnp.asarray(x0, float), jnp.asarray(t0, float)
    if on:
        # (the period may end at an impact: the orbit's period map is then another one)
        sol = run_period_map(pmap, x0_, t0_, jnp.asarray(t0 + 1.5 * abs(period), float), args)
    else:
        # The period map is this time-T map: its linearization's program, which the phase
        # condition compiles next, gives the run (its tangents cost microseconds here),
        # and a primal program of its own would be one more of the loop's size to
        # compile. Its inputs as the phase condition passes them: the same program.
        sol = linearize(pmap, x0_, t0_, jnp.asarray(1.5 * abs(period), float),
                        lax.stop_gradient(args))[4]
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


@renamed_keyword("max_steps", "max_newton_steps", NEWTON_STEPS)
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
    max_newton_steps: int = 40,
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

    - `scene`: a `grazejax.Scene`.
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
    - `rtol`, `atol`, `solver`, `max_solver_steps`: passed to `grazejax.simulate`.
      The orbit cannot be more accurate than the simulation; in weakly contracting
      directions (multiplier ρ near 1) the error is that of one period divided by |1 − ρ|.
      `atol=None` (default) scales it to the orbit: `1e-2 · rtol · s` with s = max |x0| of
      the guess, and once more from the result if that is 10× larger or smaller (a state
      of size 1e-9 then gets atol ≈ 1e-21, not 1e-12, which would leave it 0.1% accurate).
      An explicit `atol` above `10 · rtol · s` (s the result's size) ends in status
      `LOOSE_ATOL`: the orbit is not accurate to `rtol`.
    - `root_finder`: an `optimistix` root finder (default `optx.Newton(newton_tol,
      newton_tol · s)`: the residual and the step are judged relative to the orbit's size).
    - `max_newton_steps`: Newton iterations.
    - `newton_tol`: relative tolerance on the residual and the Newton step.
    - `max_impacts`: size of the impact log (impacts per period must not exceed it).
    - `adjoint`: `grazejax.simulate`'s, for the runs that Newton's method solves.
      The default (`diffrax.ForwardMode()`) lets `jax.jacfwd` differentiate the orbit with
      respect to `args` (implicit function theorem); `diffrax.DirectAdjoint()` also lets
      `jax.grad` do it. Newton linearises in forward mode, so the reverse-only
      `diffrax.RecursiveCheckpointAdjoint()` is a `ValueError`.

    **Returns:** an `grazejax.Orbit` (with the `grazejax.SolverSettings` used).
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
    x_guess = jnp.asarray(x0, dtype=float)
    _check_arguments(scene, x_guess, period, fix, max_newton_steps, num_impacts, adjoint)
    n = x_guess.shape[0]
    # Absolute tolerances scale with the orbit (a guess that is traced counts as size 1).
    scale = orbit_scale(x_guess) if is_concrete(x_guess) else 1.0
    scaled_atol = atol is None
    atol_used = ATOL_PER_RTOL * float(rtol) * scale if scaled_atol else float(atol)
    pmap = PeriodMap(
        scene=scene, end_impacts=0, solver=solver, rtol=float(rtol), atol=atol_used,
        max_impacts=int(max_impacts), max_solver_steps=int(max_solver_steps),
    )
    start_at_impact, num_impacts = _impact_start(pmap, x_guess, t0, period, args,
                                                 start_at_impact, num_impacts)
    pmap = dataclasses.replace(pmap, end_impacts=int(num_impacts) if start_at_impact else 0)
    user_root_finder = root_finder is not None
    if root_finder is None:
        root_finder = newton_for(newton_tol, scale)
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
        dataclasses.replace(pmap, adjoint=adjoint), fixed_period, root_finder, int(max_newton_steps),
        y0, t0_live, T_fixed, args, j, c,
    )
    x0, T, finite_y = _solution_point(fixed_period, value, y0, T_fixed, j, c)
    x_const, T_const = lax.stop_gradient((x0, T))
    lin = linearize(pmap, x_const, t0, T_const, args_const)
    out = _assess(pmap, fixed_period, n, j, fix_arg, f_guess, x_guess, x_const, T_const, t0,
                  args_const, converged, finite_y, lin, requested)
    out = _differentiable_diagnostics(diagnostics_map(pmap, adjoint), fixed_period, n, out,
                                      x0, T, t0_live, args, j)
    t0 = t0_live
    settings = _settings_used(solver, rtol, atol_used, root_finder if user_root_finder else None,
                              newton_tol, scale, max_newton_steps, max_solver_steps, max_impacts)
    orbit = Orbit(x0=x0, t0=t0, period=T, num_steps=num_steps,
                  start_at_impact=bool(start_at_impact), fixed_period=fixed_period,
                  settings=settings, **out)
    if scaled_atol and not user_root_finder and is_concrete(orbit.x0, orbit.status):
        # The guess's size may be far from the orbit's (a poor guess, or x0 near 0 in a
        # small orbit): solve once more, from the result, with tolerances of its size.
        k = int(orbit.num_impacts)
        size = orbit_scale(orbit.x0, np.asarray(orbit.impact_pre)[:k],
                            np.asarray(orbit.impact_post)[:k])
        usable = int(orbit.status) in (OrbitStatus.SUCCESS, OrbitStatus.LOOSE_ATOL)
        if usable and not (0.1 * scale <= size <= 10 * scale):
            return find_periodic_orbit(
                scene, orbit.x0, orbit.period, args, t0=t0, fix=int(orbit.fix) if int(orbit.fix) >= 0 else None,
                fixed_period=fixed_period, num_impacts=int(orbit.num_impacts),
                start_at_impact=bool(start_at_impact), rtol=rtol, atol=ATOL_PER_RTOL * float(rtol) * size,
                solver=solver, max_newton_steps=max_newton_steps, newton_tol=newton_tol,
                max_impacts=max_impacts, max_solver_steps=max_solver_steps, adjoint=adjoint,
            )
    return orbit


def _check_arguments(scene, x_guess, period, fix, max_newton_steps, num_impacts, adjoint):
    """`find_periodic_orbit`'s argument checks (those that need concrete values only where
    the values are concrete)."""
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if x_guess.ndim != 1:
        raise ValueError(f"x0 must be a state vector of shape (n,), got shape {x_guess.shape}")
    n = x_guess.shape[0]
    if fix is not None and not (isinstance(fix, (int, np.integer)) and 0 <= fix < n):
        raise ValueError(f"fix must be a coordinate index in [0, {n}), got {fix!r}")
    if not isinstance(max_newton_steps, (int, np.integer)) or max_newton_steps < 1:
        raise ValueError(f"max_newton_steps must be a positive integer, got {max_newton_steps!r}")
    if num_impacts is not None and (not isinstance(num_impacts, (int, np.integer)) or num_impacts < 0):
        raise ValueError(f"num_impacts must be a non-negative integer, got {num_impacts!r}")
    if is_concrete(period) and not (np.isfinite(float(period)) and float(period) > 0):
        raise ValueError(f"period must be a positive finite number, got {float(period)}")
    if is_concrete(x_guess) and not np.all(np.isfinite(np.asarray(x_guess))):
        raise ValueError(f"x0 contains NaN or inf: {np.asarray(x_guess)}")

    require_forward_mode(adjoint, "find_periodic_orbit", "the period map")


def _impact_start(pmap, x_guess, t0, period, args, start_at_impact, num_impacts):
    """`(start_at_impact, num_impacts)`, detected from the guess trajectory where not given
    (x0 on a surface that the guess meets again near t0 + T)."""
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
    return start_at_impact, num_impacts


def _settings_used(solver, rtol, atol, root_finder, newton_tol, scale, max_newton_steps,
                   max_solver_steps, max_impacts) -> SolverSettings:
    """The `grazejax.SolverSettings` of a solve: a user's root finder reports its own
    tolerances (NaN where it has none), the default ones are scaled to the orbit."""
    if root_finder is not None:
        newton_rtol, newton_atol = (_host_float(getattr(root_finder, name, math.nan))
                                    for name in ("rtol", "atol"))
    else:
        newton_rtol, newton_atol = map(float, newton_tolerances(newton_tol, scale))
    return SolverSettings(
        solver=solver_name(solver), rtol=float(rtol), atol=atol,
        newton_rtol=newton_rtol, newton_atol=newton_atol,
        max_newton_steps=int(max_newton_steps),
        max_solver_steps=int(max_solver_steps), max_impacts=int(max_impacts), state_scale=scale,
    )
