"""The period map, the floor of the orbit package: one flight of `simulate` over a
period, its linearization, sampling, the (A5) verdict, the tolerance conventions and the
Newton solve (`newton_root`) with its implicit derivative.

`grazejax.find_periodic_orbit`, `grazejax.continue_orbit`, the bifurcation systems
and `grazejax.continue_grazing` all solve for fixed points of this map with the same
tolerance scaling; every orbit module reaches `simulate` through it.
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import Any

import equinox as eqx
import jax
import jax.lax as lax
import jax.numpy as jnp
import numpy as np

from .._compiler import single_run_jit
from .._deprecated import NEWTON_STEPS
from .._flow import short_free_flow
from .._geometry import gap_rates
from .._scene import Scene
from .._simulate import simulate
from .._status import Status


@dataclasses.dataclass(frozen=True)
class SolverSettings:
    """The settings an `grazejax.Orbit` or `grazejax.Branch` was computed with.

    - `solver`: the Diffrax solver's class name (`"default"` for `simulate`'s own choice).
    - `rtol`, `atol`: the simulation's tolerances, `atol` as actually used (after scaling
      by `state_scale` when it was left to default).
    - `newton_rtol`, `newton_atol`: the root finder's tolerances (NaN for a user's
      `root_finder` without them).
    - `max_newton_steps`: Newton iterations allowed; `max_solver_steps`, `max_impacts`: for
      `simulate`.
    - `state_scale`: the orbit's size used to scale absolute tolerances (max |x|).
    """

    solver: str
    rtol: float
    atol: float
    newton_rtol: float
    newton_atol: float
    max_newton_steps: int
    max_solver_steps: int
    max_impacts: int
    state_scale: float

    @property
    def max_steps(self) -> int:
        """Deprecated name of `max_newton_steps`."""
        warnings.warn("SolverSettings.max_steps is renamed max_newton_steps (" + NEWTON_STEPS
                      + ")", DeprecationWarning, stacklevel=2)
        return self.max_newton_steps


# Default absolute tolerances, relative to rtol × the orbit's size: atol = 1e-2 · rtol · size
# (1e-12 for rtol = 1e-10 and an orbit of size 1, the former fixed default).
ATOL_PER_RTOL = 1e-2


def orbit_scale(*arrays) -> float:
    """max |x| over concrete arrays (1 if they are all zero or not finite)."""
    values = [np.max(np.abs(np.asarray(a, float))) for a in arrays if np.size(a)]
    values = [v for v in values if np.isfinite(v)]
    s = max(values) if values else 0.0
    return float(s) if s > 0 else 1.0


def jacobian_in_one_pass(fn):
    """`fn(y, args)` for `optx.root_find`, whose JVP in `y` computes ∂fn/∂y in one pass.

    Why: optimistix's Newton takes `jax.linearize` of the residual, and JAX linearizes a
    `while_loop` by running it once for the primal values and once more, whole, for the
    tangents (it cannot split one loop's body into known and unknown parts: jax-ml/jax
    `_while_partial_eval`). Each Newton program then held the impact loop twice — the
    primal loop and its JVP loop — in its compiled code and in every iteration. Here the
    JVP in `y` alone (Newton's case) is `J ẏ` with `(fn, J)` from one `jax.jacfwd` pass:
    the loop is traced, compiled and run once per iteration. Tangents in `args` take the
    plain JVP, so that the rule is right for any tangent (`newton_root`, its one caller,
    differentiates the solution by its own rule: no tangent in `args` reaches Newton).
    """
    from jax.custom_derivatives import SymbolicZero, zero_from_primal

    def call(y, args):
        # The rule must not close over tracers (JAX may trace it after the trace that
        # built it has ended): every array the residual reads, closed over or in `args`,
        # becomes an explicit input.
        converted = eqx.filter_closure_convert(fn, y, args)
        dynamic, static = eqx.partition((converted, args), eqx.is_array)

        def plain(y, dynamic):
            converted, args = eqx.combine(dynamic, static)
            return converted(y, args)

        def jvp(primals, tangents):
            y, dynamic = primals
            y_dot, dynamic_dot = tangents
            zero = lambda v: isinstance(v, SymbolicZero)  # noqa: E731
            if not zero(y_dot) and all(map(zero, jax.tree.leaves(dynamic_dot, is_leaf=zero))):
                jac, value = jax.jacfwd(lambda z: (plain(z, dynamic),) * 2, has_aux=True)(y)
                return value, jac @ y_dot
            dense = jax.tree.map(lambda d, p: zero_from_primal(p) if zero(d) else d,
                                 (y_dot, dynamic_dot), primals, is_leaf=zero)
            return jax.jvp(plain, primals, dense)

        residual = jax.custom_jvp(plain)
        residual.defjvp(jvp, symbolic_zeros=True)
        return residual(y, dynamic)

    return call


def newton_root(residual, root_finder, y0, params, max_newton_steps):
    """`optx.root_find` of `residual(y, params) = 0` from y0 (`throw=False`):
    `(y, converged, num_steps)`, differentiable in `params` and in every array `residual`
    closes over by the implicit function theorem, ẏ = −(∂r/∂y)⁻¹ ṙ at the root.

    Why not optimistix's implicit adjoint: it solves with `lineax.linear_solve`, which checks
    the solve by `eqx.error_if`, a host callback, and JAX writes no program holding a host
    callback to its persistent compilation cache: each derivative of an orbit, a
    bifurcation or a grazing point compiled again in every process. Here the solve is
    `jnp.linalg.solve` (LU, as lineax's for a square system): a singular ∂r/∂y gives
    non-finite derivatives, never an exception that would end a whole vmapped batch. The
    guess y0 has no derivative (the root does not depend on it); nor have `converged` and
    `num_steps`.
    """
    import optimistix as optx

    # Every array the solve reads is an explicit input of the custom_jvp function: JAX
    # traces the rule when the enclosing program is differentiated, after that program's
    # trace has ended, so a closed-over tracer would have leaked out of it by then.
    converted = eqx.filter_closure_convert(residual, y0, params)
    dynamic, static = eqx.partition((converted, params, root_finder), eqx.is_array)

    def value(y, dynamic):
        converted, params, _ = eqx.combine(dynamic, static)
        return converted(y, params)

    def solve(dynamic, y0):
        converted, params, root_finder = eqx.combine(dynamic, static)
        solution = optx.root_find(jacobian_in_one_pass(converted), root_finder, y0, params,
                                  max_steps=max_newton_steps, throw=False)
        return (solution.value, solution.result == optx.RESULTS.successful,
                solution.stats["num_steps"])

    @jax.custom_jvp
    def root(dynamic, y0):
        return solve(dynamic, y0)

    @root.defjvp
    def root_jvp(primals, tangents):
        dynamic, y0 = primals
        dynamic_dot, _ = tangents
        dynamic = jax.tree.map(jnp.asarray, dynamic)  # (JAX passes a Python float as it is)
        y, converged, num_steps = solve(dynamic, y0)
        jac = jax.jacfwd(value)(y, dynamic)
        _, value_dot = jax.jvp(lambda d: value(y, d), (dynamic,), (dynamic_dot,))
        y_dot = -jnp.linalg.solve(jac, value_dot)
        no_tangent = [np.zeros(jnp.shape(v), jax.dtypes.float0) for v in (converged, num_steps)]
        return (y, converged, num_steps), (y_dot, *no_tangent)

    return root(dynamic, y0)


def newton_for(newton_tol, scale):
    """Newton's method with the tolerances `newton_tol` (relative) and `newton_tol · scale`.

    The tolerances are arrays: `eqx.filter_jit` traces arrays but treats Python floats as
    static, and the absolute tolerance follows each orbit's size, so with floats every
    orbit, continuation start and grazing point would compile its own Newton program.
    """
    import optimistix as optx

    rtol, atol = newton_tolerances(newton_tol, scale)
    return optx.Newton(rtol=jnp.asarray(rtol, float), atol=jnp.asarray(atol, float))


def newton_tolerances(newton_tol, scale):
    """The default Newton's `(rtol, atol)`: `newton_tol` relative, `newton_tol · scale`
    absolute (host values where the inputs are: `find_periodic_orbit` reports them)."""
    return newton_tol, newton_tol * scale


def atol_for(orbit, rtol, atol) -> float:
    """`atol`, or (None) the default scaled to the orbit's size."""
    if atol is not None:
        return float(atol)
    settings = getattr(orbit, "settings", None)
    scale = settings.state_scale if settings is not None else orbit_scale(orbit.x0)
    return ATOL_PER_RTOL * float(rtol) * scale


def solver_name(solver) -> str:
    return "default" if solver is None else type(solver).__name__


def a5_holds(multipliers, fixed_period: bool):
    modulus = jnp.abs(multipliers)
    if fixed_period:
        return jnp.all(modulus < 1) & jnp.all(jnp.isfinite(modulus))
    # Leave out the multiplier nearest to 1 (the trivial one, along f).
    trivial = jnp.argmin(jnp.abs(multipliers - 1.0), axis=-1)
    others = jnp.where(
        jnp.arange(multipliers.shape[-1]) == trivial[..., None], 0.0, modulus
    )
    return jnp.all(others < 1, axis=-1) & jnp.all(jnp.isfinite(modulus), axis=-1)


class PeriodMap(eqx.Module):
    """x0 ↦ P(x0, T) for one scene and one choice of where the period ends (all static)."""

    scene: Scene = eqx.field(static=True)
    end_impacts: int = eqx.field(static=True)  # 0: time-T map; k: ends just after impact k
    solver: Any = eqx.field(static=True)
    # The tolerances are inputs of the compiled kernels (arrays), not part of their key: a
    # new rtol, or the atol scaled to a new orbit's size, reuses the programs.
    rtol: Any = eqx.field(converter=lambda v: jnp.asarray(v, float))
    atol: Any = eqx.field(converter=lambda v: jnp.asarray(v, float))
    max_impacts: int = eqx.field(static=True)
    max_solver_steps: int = eqx.field(static=True)
    adjoint: Any = eqx.field(static=True, default=None)  # simulate's; Newton's runs only

    def run(self, x0, t0, t1, args, max_impacts):
        return simulate(
            self.scene, x0, t0, t1, args, solver=self.solver, rtol=self.rtol, atol=self.atol,
            max_impacts=max_impacts, max_steps=self.max_solver_steps, direction=1,
            adjoint=self.adjoint,
        )

    def __call__(self, x0, t0, T, args):
        """Returns `(x_end, ok, solution)`."""
        if self.end_impacts == 0:
            sol = self.run(x0, t0, t0 + T, args, self.max_impacts)
            ok = sol.status == Status.SUCCESS
            return sol.x_final, ok, sol
        # Run to the k-th impact (stops right after it), then move along the post-impact
        # flow by what is left of T: exact at the solution, smooth in (x0, T) there. The
        # horizon 2T only bounds a run whose closing impact never comes.
        sol = self.run(x0, t0, t0 + 2 * jnp.abs(T), args, self.end_impacts)
        ok = sol.status == Status.MAX_IMPACTS
        theta = sol.t_final
        x_end = short_free_flow(self.scene.vector_field, theta, sol.x_final, t0 + T - theta, args)
        return x_end, ok, sol


def orbit_kernel(fn):
    """`eqx.filter_jit(fn)`, compiled once per configuration whatever the callers pass, with
    the options for one trajectory (`_compiler.single_run_jit`).

    `jit` keys its programs on weak types too, and the same time or state reached these
    kernels weak-typed from one caller (`jnp.asarray(0.0)`, a Python float's result) and
    strong from another, and each kernel compiled twice. Weak-typed arrays are made strong
    first (the orbit code works in the float64 its inputs are converted to, so the
    promotion rules do not change).
    """
    jitted = single_run_jit(fn)

    @functools.wraps(fn)
    def call(*args):
        return jitted(*jax.tree.map(_strongly_typed, args))

    call.single = jitted  # (tests count its compiled programs: `call.single.jitted`)
    return call


def _strongly_typed(leaf):
    if isinstance(leaf, jax.Array) and jax.typeof(leaf).weak_type:
        return lax.convert_element_type(leaf, leaf.dtype)
    return leaf


@orbit_kernel
def run_period_map(pmap: PeriodMap, x0, t0, t1, args):
    return pmap.run(x0, t0, t1, args, pmap.max_impacts)


def linearize(pmap: PeriodMap, x, t0, T, args, args_dot=None):
    """P(x, T) with ∂P/∂x (the monodromy), ∂P/∂T, the derivative along `args_dot` in
    parameter space (continuation's ∂P/∂μ; zero if not given), and the run behind it.

    One compiled program per period map, shared by the phase refinement, the diagnostics
    of a solve, the Floquet factors, the grazing branches and continuation.
    """
    if args_dot is None:
        args_dot = jax.tree.map(jnp.zeros_like, args)
    x_end, jac_x, jac_T, jac_args, ok, sol = _linearize_all(pmap, x, t0, T, args, args_dot)
    return x_end, jac_x, jac_T, ok, sol, jac_args


@orbit_kernel
def _linearize_all(pmap: PeriodMap, x, t0, T, args, args_dot):
    x, T, args, args_dot = lax.stop_gradient((x, T, args, args_dot))
    return period_map_jacobian(pmap, x, t0, T, args, args_dot)


def period_map_jacobian(pmap: PeriodMap, x, t0, T, args, args_dot):
    """`(x_end, ∂x_end/∂x, ∂x_end/∂T, ∂x_end/∂args·args_dot, ok, sol)` of the period map,
    differentiable in its inputs (a derivative of it is a second derivative of the flow)."""
    n = x.shape[0]

    def period_map(z):
        # One batch of n + 2 tangents: x, T and the parameter direction, in one program.
        a = jax.tree.map(lambda p, d: p + z[n + 1] * d, args, args_dot)
        x_end, ok, sol = pmap(z[:n], t0, z[n], a)
        return x_end, (x_end, ok, sol)

    z = jnp.concatenate([x, jnp.asarray(T, x.dtype)[None], jnp.zeros((1,), x.dtype)])
    jac, (x_end, ok, sol) = jax.jacfwd(period_map, has_aux=True)(z)
    return x_end, jac[:, :n], jac[:, n], jac[:, n + 1], ok, sol


@orbit_kernel
def sampled_states(pmap: PeriodMap, x0, t0, t1, args, ts):
    sol = simulate(
        pmap.scene, x0, t0, t1, args, solver=pmap.solver, rtol=pmap.rtol, atol=pmap.atol,
        max_impacts=pmap.max_impacts, max_steps=pmap.max_solver_steps, direction=1, saveat=ts,
    )
    return sol


@orbit_kernel
def gap_rates_at(gap, field, t, x, args):
    """`gap_rates` for the host-side diagnostics, as one compiled program per surface: run
    op by op, each of its nested JVP's operations would compile a program of its own."""
    return gap_rates(gap, field, t, x, args)


def state_at(pmap: PeriodMap, x0, t0, t, args):
    """x(t) (left-continuous) on the trajectory from (t0, x0)."""
    if t <= t0:
        return np.asarray(x0, float)
    sol = run_period_map(pmap, jnp.asarray(x0, float), jnp.asarray(t0, float), jnp.asarray(t, float), args)
    return np.asarray(sol.x_final)
