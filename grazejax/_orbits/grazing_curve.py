r"""Two-parameter continuation of grazing orbits: curves of grazing points in (μ, ν).

`grazejax.continue_grazing` follows a grazing periodic orbit (an orbit with a
tangential contact with a surface Γ_i: Φ_i = 0 and dΦ_i/dt = 0 at some phase) as two
parameters (μ, ν) vary, as COCO's `hspo` toolbox does for grazing curves. The orbit is
phased to start *at* the contact, so the extended system is

    P(x0, t0, T; μ, ν) − x0 = 0      (n rows: the orbit is periodic)
    Φ_i(t0, x0; μ, ν) = 0            (the contact is on the surface)
    dΦ_i/dt(t0, x0; μ, ν) = 0        (and tangential)

in the unknowns Y = (s, x0, μ, ν), s = t0 for forced systems (the contact's phase, the
period is T(μ, ν)) and s = T for autonomous ones (t0 is arbitrary there). That is n + 2
equations in n + 3 unknowns: a curve, followed by pseudo-arclength continuation (tangent
predictor, `optimistix` Newton corrector bordered by the arclength row).

The period map P is the flow *without* the grazed surface: at the grazing orbit the
surface is only touched, so leaving it out changes nothing there, and it keeps P smooth
(with the surface, P has a square-root singularity at grazing, Nordmark's normal form,
which Newton cannot cross). Other surfaces keep their impacts. Each point reports the
smallest gap Φ_i sampled along the orbit (`min_gap`, ≈ 0 at the contact itself; clearly
negative means the orbit crosses Γ_i elsewhere and the graze is not physical) and the
contact's curvature d²Φ_i/dt² (> 0: a minimum of the gap, a genuine graze).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._adjoint import require_forward_mode
from .._deprecated import NEWTON_STEPS, renamed_keyword
from .._geometry import gap_rates
from .._scene import Scene
from .._status import ContinuationStatus
from .._validate import is_concrete
from .arclength import (
    CurvePoint,
    Front,
    Steps,
    bordered_newton,
    continuation_settings,
    next_tangent,
    progress_bar,
    trace,
    write_text,
)
from .bifurcation import BifurcationPoint, assessed_point, newton
from .branch import GrazingPoint
from .contacts import orbit_contacts
from .forced_period import PERIOD_OF_FIX, require_period_fixed_in
from .period_map import PeriodMap, SolverSettings, newton_for, orbit_kernel, sampled_states
from .periodic import Orbit, OrbitStatus


class GrazingCurve(eqx.Module):
    r"""A curve of grazing orbits in two parameters (`grazejax.continue_grazing`).
    NumPy arrays, one row per point, in order of computation.

    **Fields:**

    - `mu`, `nu`: the two parameters.
    - `t0`, `x0`: the time and state of the grazing contact (Φ = 0, dΦ/dt = 0 there);
      the orbit starts at it: `x0` is its state at phase `t0`.
    - `period`: the orbit's period.
    - `curvature`: d²Φ/dt² at the contact (> 0: the gap has a minimum there).
    - `min_gap`: the smallest gap Φ along the orbit (samples plus the contact): ≈ 0 for a
      physical grazing orbit, clearly negative if the orbit crosses the surface elsewhere.
    - `num_impacts`: impacts per period on the *other* surfaces.
    - `surface`: the index of the grazed surface.
    - `status`: a `grazejax.ContinuationStatus` (shown by name; equal to its
      integer code); `message` reads it.
    - `settings`: the `grazejax.SolverSettings` used.
    """

    mu: Any
    nu: Any
    t0: Any
    x0: Any
    period: Any
    curvature: Any
    min_gap: Any
    num_impacts: Any
    surface: int = eqx.field(static=True)
    status: ContinuationStatus = eqx.field(static=True, converter=ContinuationStatus)
    settings: SolverSettings | None = eqx.field(static=True, default=None)

    @property
    def message(self) -> str:
        return ContinuationStatus(self.status).message

    def __len__(self) -> int:
        return len(self.mu)

    def to_csv(self, path=None) -> str:
        """One row per point: mu, nu, t0, period, x0_i, curvature, min_gap, num_impacts.
        Written to `path` if given."""
        import csv
        import io

        out = io.StringIO()
        w = csv.writer(out)
        n = np.asarray(self.x0).shape[1] if len(self) else 0
        w.writerow(["mu", "nu", "t0", "period"] + [f"x0_{i}" for i in range(n)]
                   + ["curvature", "min_gap", "num_impacts"])
        for i in range(len(self)):
            values = [self.mu[i], self.nu[i], self.t0[i], self.period[i], *self.x0[i],
                      self.curvature[i], self.min_gap[i]]
            w.writerow([repr(float(v)) for v in values] + [int(self.num_impacts[i])])
        return write_text(out.getvalue(), path)


# --------------------------------------------------------------------------------------
# The extended system (compiled once per scene, surface and parameter functions)
# --------------------------------------------------------------------------------------


class _GrazingSystem(eqx.Module):
    pmap: PeriodMap  # the flow without the grazed surface (tolerances: arrays)
    phi: Callable = eqx.field(static=True)
    args_of: Callable = eqx.field(static=True)
    period_of: Callable | None = eqx.field(static=True)
    fixed_period: bool = eqx.field(static=True)
    root_finder: Any  # (its tolerances are arrays: see `newton_for`)
    max_newton_steps: int = eqx.field(static=True)


def _unpack(system: _GrazingSystem, Y, t_fixed, T_fixed):
    """(t0, T, x0, μ, ν) from Y = (s, x0, μ, ν)."""
    mu, nu, x = Y[-2], Y[-1], Y[1:-2]
    if system.fixed_period:
        T = T_fixed if system.period_of is None else system.period_of(mu, nu)
        return Y[0], T, x, mu, nu
    return t_fixed, Y[0], x, mu, nu


def _residual(system: _GrazingSystem, Y, t_fixed, T_fixed):
    """The n + 2 rows of the extended system (NaN where the run failed)."""
    t0, T, x, mu, nu = _unpack(system, Y, t_fixed, T_fixed)
    args = system.args_of(mu, nu)
    x_end, ok, _ = system.pmap(x, t0, T, args)
    phi, rate, _ = gap_rates(system.phi, system.pmap.scene.vector_field, t0, x, args)
    rows = jnp.concatenate([x_end - x, jnp.stack([phi, rate])])
    return jnp.where(ok, rows, jnp.nan)


@orbit_kernel
def _corrector(system: _GrazingSystem, Y_pred, tangent, t_fixed, T_fixed):
    """Newton on [G(Y); tangent·(Y − Y_pred)] = 0."""
    return bordered_newton(lambda Y: _residual(system, Y, t_fixed, T_fixed), system.root_finder,
                            system.max_newton_steps, Y_pred, tangent)


@orbit_kernel
def _jacobian(system: _GrazingSystem, Y, t_fixed, T_fixed):
    """∂G/∂Y, (n + 2) × (n + 3), by forward mode (for the tangent)."""
    return jax.jacfwd(lambda y: _residual(system, y, t_fixed, T_fixed))(Y)


@orbit_kernel
def _diagnostics(system: _GrazingSystem, Y, t_fixed, T_fixed, ts_unit):
    """Curvature d²Φ/dt² at the contact, min Φ along the orbit, impacts on other surfaces."""
    t0, T, x, mu, nu = _unpack(system, Y, t_fixed, T_fixed)
    args = system.args_of(mu, nu)
    _, _, curvature = gap_rates(system.phi, system.pmap.scene.vector_field, t0, x, args)
    sol = sampled_states(system.pmap, x, t0, t0 + T, args, t0 + T * ts_unit)
    gaps = jax.vmap(lambda t, y: system.phi(t, y, args))(t0 + T * ts_unit, sol.xs)
    return curvature, jnp.min(gaps), sol.num_impacts, T


class _Diagnostics(NamedTuple):
    """What a grazing curve reports of each point besides its unknowns."""

    curvature: float  # d²Φ/dt² at the contact
    min_gap: float  # the smallest Φ along the orbit (≤ 0: the contact itself is 0)
    num_impacts: int  # on the other surfaces
    period: float


def _correct(system, Y_pred, tangent, t_fixed, T_fixed, ts_unit) -> CurvePoint | None:
    """Corrector, then the next tangent (null vector of ∂G/∂Y oriented along `tangent`)
    and the point's diagnostics; `None` if the corrector failed."""
    Y, converged, steps = _corrector(system, jnp.asarray(Y_pred), jnp.asarray(tangent), t_fixed,
                                     T_fixed)
    Y_np = np.asarray(Y)
    if not (bool(converged) and np.all(np.isfinite(Y_np))):
        return None
    J = np.asarray(_jacobian(system, Y, t_fixed, T_fixed))
    if not np.all(np.isfinite(J)):
        return None
    new_tangent = next_tangent(J, tangent)
    curvature, min_gap, k, T = (np.asarray(v) for v in _diagnostics(system, Y, t_fixed, T_fixed,
                                                                      ts_unit))
    return CurvePoint(Y_np, new_tangent, int(steps), _Diagnostics(
        float(curvature), min(float(min_gap), 0.0), int(k), float(T)))


# --------------------------------------------------------------------------------------
# continue_grazing
# --------------------------------------------------------------------------------------


def _contact_of(scene, point, args, surface, kw):
    """(surface, t, x, orbit) of the starting contact: the GrazingPoint's own, or the
    contact of an Orbit with the smallest |virtual depth| (on `surface` if given)."""
    if isinstance(point, GrazingPoint):
        if surface is not None and surface != point.surface:
            raise ValueError(f"the grazing point is on surface {point.surface}, not {surface}")
        return point.surface, float(point.time), np.asarray(point.point, float), point.orbit
    if not isinstance(point, Orbit):
        raise TypeError("point must be a grazejax.GrazingPoint or a grazejax.Orbit")
    if int(point.status) != OrbitStatus.SUCCESS:
        raise ValueError(f"the starting orbit did not converge: {point.message}")
    contacts = orbit_contacts(scene, point, args, solver=kw["solver"], rtol=kw["rtol"],
                              atol=kw["atol"], max_depth=math.inf)
    depth = np.abs(np.asarray(contacts.depth, float))
    if surface is not None:
        depth = np.where(np.asarray(contacts.surfaces) == surface, depth, np.inf)
    if depth.size == 0 or not np.isfinite(depth.min()):
        raise ValueError("the orbit has no contact (impact or close pass) to continue")
    m = int(np.argmin(depth))
    return (int(contacts.surfaces[m]), float(contacts.times[m]),
            np.asarray(contacts.points[m], float), point)


def _system_for(scene, surface, args_of, period_of, fixed, newton_tol, scale, max_newton_steps,
                kw) -> _GrazingSystem:
    # The same surfaces minus the grazed one: a Scene hashes by its fields, so repeated
    # calls rebuild an equal scene and reuse the compiled programs.
    others = [s for i, s in enumerate(scene.surfaces) if i != surface]
    pmap = PeriodMap(scene=scene.with_surfaces(others), end_impacts=0, **kw)
    return _GrazingSystem(
        pmap=pmap, phi=scene.surfaces[surface].phi, args_of=args_of, period_of=period_of,
        fixed_period=fixed, root_finder=newton_for(newton_tol, scale),
        max_newton_steps=int(max_newton_steps),
    )


def _curve(points, surface, status, t_fixed, settings, fixed, n) -> GrazingCurve:
    Ys = np.stack([p.Y for p in points]) if points else np.zeros((0, n + 3))
    t0 = Ys[:, 0] if fixed else np.full(len(Ys), t_fixed)

    def col(name, dtype=float):
        return np.asarray([getattr(p.data, name) for p in points], dtype)

    return GrazingCurve(mu=Ys[:, -2], nu=Ys[:, -1], t0=t0, x0=Ys[:, 1:-2], period=col("period"),
                        curvature=col("curvature"), min_gap=col("min_gap"),
                        num_impacts=col("num_impacts", int), surface=int(surface),
                        status=int(status), settings=settings)


def continue_grazing(
    scene: Scene,
    point: GrazingPoint | Orbit,
    args_of: Callable[[Any, Any], Any],
    mu_start: float,
    nu_start: float,
    mu_stop: float,
    *,
    nu_range: tuple[float, float] = (-math.inf, math.inf),
    surface: int | None = None,
    period_of: Callable[[Any, Any], Any] | None = None,
    ds: float = 0.02,
    ds_min: float | None = None,
    ds_max: float = 0.1,
    max_points: int = 200,
    progress: bool = True,
    rtol: float = 1e-10,
    atol: float | None = None,
    solver: diffrax.AbstractSolver | None = None,
    newton_tol: float = 1e-10,
    max_newton_steps: int = 10,
    num_samples: int = 200,
) -> GrazingCurve:
    r"""Follow a grazing orbit in two parameters (μ, ν): the grazing curve.

    **Arguments:**

    - `scene`: a `grazejax.Scene`.
    - `point`: where to start: a `grazejax.GrazingPoint` (from
      `grazejax.continue_orbit`'s `branch.grazing`) or an `grazejax.Orbit` near
      grazing (its contact with the smallest |virtual depth| is used, see
      `grazejax.orbit_contacts`). It only needs to be close: the first point is solved
      at μ = `mu_start` with ν free.
    - `args_of`: `args_of(mu, nu) -> args`, traceable. Pass the same function object
      across calls to reuse the compiled programs.
    - `mu_start`, `nu_start`: the parameters at `point`.
    - `mu_stop`: continuation goes from `mu_start` towards `mu_stop` (the first step's μ
      moves that way) and ends there exactly, unless it stops earlier.
    - `nu_range`: `(lo, hi)`: stop when ν leaves it.
    - `surface`: the grazed surface's index (default: the point's, or the orbit's closest
      contact's).
    - `period_of`: forced systems (`fixed_period` orbits): the period as a function
      `period_of(mu, nu)` (e.g. `lambda omega, sigma: 2 * jnp.pi / omega`); default: the
      orbit's period, fixed.
    - `ds`, `ds_min` (default `1e-3 * ds`), `ds_max`: arclength steps in (s, x0, μ, ν),
      adapted as in `grazejax.continue_orbit`.
    - `max_points`, `progress`: as in `grazejax.continue_orbit`.
    - `rtol`, `atol`, `solver`: for `grazejax.simulate` (`atol=None`: scaled to the
      orbit's size); `newton_tol`, `max_newton_steps`: the corrector (absolute tolerance
      `newton_tol` times the orbit's size).
    - `num_samples`: samples per orbit for `min_gap`.

    **Returns:** a `grazejax.GrazingCurve`.

    **Example** (the forced oscillator x'' + 0.1x' + x = cos(ωt) with a stop at x = σ:
    the grazing curve σ(ω) is the free response's amplitude):

    ```python
    from grazejax import examples as ex
    scene = ex.impact_oscillator()
    def args_of(omega, sigma):
        return ex.impact_oscillator_args(zeta=0.05, omega=omega, sigma=sigma)
    start = args_of(0.8, 3.0)
    orbit = gj.find_periodic_orbit(scene, ex.linear_response(0.0, start), 2 * jnp.pi / 0.8,
                                   start, fixed_period=True)
    curve = gj.continue_grazing(scene, orbit, args_of, 0.8, 3.0, 0.7,
                                period_of=lambda omega, sigma: 2 * jnp.pi / omega)
    ```
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if not callable(args_of):
        raise TypeError("args_of must be a function (mu, nu) -> args")
    steps = Steps(float(ds), 1e-3 * float(ds) if ds_min is None else float(ds_min),
                  float(ds_max), int(max_points))
    if mu_start == mu_stop:
        raise ValueError("mu_start == mu_stop: nothing to continue")
    if not isinstance(point, GrazingPoint | Orbit):
        raise TypeError("point must be a grazejax.GrazingPoint or a grazejax.Orbit")
    orbit = point.orbit if isinstance(point, GrazingPoint) else point
    kw, settings, scale = continuation_settings(orbit, rtol, atol, solver, newton_tol,
                                                 max_newton_steps)
    surface, t_c, x_c, orbit = _contact_of(scene, point, args_of(mu_start, nu_start), surface, kw)
    fixed = bool(orbit.fixed_period)
    n = x_c.shape[0]
    system = _system_for(scene, surface, args_of, period_of, fixed, newton_tol, scale,
                         max_newton_steps, kw)
    t_fixed, T_fixed = jnp.asarray(t_c), jnp.asarray(float(orbit.period))
    ts_unit = jnp.linspace(0.0, 1.0, int(num_samples), endpoint=False)
    direction = 1.0 if mu_stop > mu_start else -1.0

    def correct(Y_pred, tangent, origin=None):
        return _correct(system, Y_pred, tangent, t_fixed, T_fixed, ts_unit)

    # The first point: μ = mu_start exactly (the bordered row fixes μ), ν free.
    Y0 = np.concatenate([[t_c if fixed else float(orbit.period)], x_c, [mu_start, nu_start]])
    e_mu = np.zeros(n + 3)
    e_mu[-2] = 1.0
    first = correct(Y0, e_mu)
    if first is None:
        return _curve([], surface, ContinuationStatus.START_FAILED, t_c, settings, fixed, n)
    # Its tangent comes out with dμ > 0 (oriented along e_μ): turn it towards mu_stop.
    first = first._replace(tangent=direction * first.tangent)
    with progress_bar(progress, steps.max_points, "grazejax.continue_grazing",
                      ("mu", -2), ("nu", -1)) as report:
        points, status = trace(Front(correct), first, index=-2, stop=mu_stop, direction=direction,
                               steps=steps, progress=report,
                               in_range=lambda Y: nu_range[0] <= Y[-1] <= nu_range[1])
    return _curve(points, surface, status, t_c, settings, fixed, n)


# --------------------------------------------------------------------------------------
# locate_grazing: one grazing point, differentiable in ν
# --------------------------------------------------------------------------------------


@renamed_keyword("max_steps", "max_newton_steps", NEWTON_STEPS)
def locate_grazing(
    scene: Scene,
    point: GrazingPoint | Orbit,
    args_of: Callable[[Any, Any], Any],
    nu,
    *,
    mu: float | None = None,
    nu_guess: float | None = None,
    surface: int | None = None,
    period_of: Callable[[Any, Any], Any] | None = None,
    rtol: float = 1e-10,
    atol: float | None = None,
    solver: diffrax.AbstractSolver | None = None,
    newton_tol: float = 1e-10,
    max_newton_steps: int = 30,
    adjoint=None,
) -> BifurcationPoint:
    r"""Solve a grazing orbit by its defining system at ν: the μ at which the orbit
    touches surface Γ_i tangentially, differentiable in ν.

    The system is `grazejax.continue_grazing`'s with ν given: P(x0) − x0 = 0 (the flow
    without the grazed surface), Φ_i(t0, x0) = 0, dΦ_i/dt(t0, x0) = 0, in (t0, x0, μ)
    for forced orbits (period `period_of(mu, nu)`, default the orbit's) or (T, x0, μ) for
    autonomous ones. Newton's method (`optx.root_find`); the point is a function of ν by
    the implicit function theorem: `jax.jacfwd` differentiates it (and `jax.grad` with
    `adjoint=diffrax.DirectAdjoint()`), never Newton's iterations.

    **Arguments:**

    - `point`: a `grazejax.GrazingPoint` or an `grazejax.Orbit` near grazing (its
      contact with the smallest |virtual depth|, on `surface` if given), as in
      `grazejax.continue_grazing`.
    - `args_of(mu, nu) -> args`; `nu` (may be traced); `mu`: the guess of μ (default
      `point.mu`; required for an `Orbit`); `nu_guess`: the ν at which an `Orbit` guess
      was computed (default `nu`; its contact is found at (`mu`, `nu_guess`), so pass it
      when `nu` is traced, e.g. under `jax.jacfwd`).
    - `rtol`, `atol`, `solver`: for `grazejax.simulate`; `newton_tol`, `max_newton_steps`:
      Newton's relative tolerance and iterations; `adjoint`: `simulate`'s for the runs.

    **Returns:** a `grazejax.BifurcationPoint` of kind `"grazing"`: `mu`, `nu`, the
    contact's time `t0` and state `x0` (the orbit starts at it), `period`, the multipliers
    of the flow without the grazed surface, `test_value` = dΦ_i/dt at the contact (≈ 0),
    `num_impacts` on the other surfaces, `status`.
    """
    if not isinstance(point, GrazingPoint | Orbit):
        raise TypeError("point must be a grazejax.GrazingPoint or a grazejax.Orbit")
    require_forward_mode(adjoint, "locate_grazing", "the grazing system")
    if mu is None:
        if not isinstance(point, GrazingPoint):
            raise ValueError("locate_grazing from an Orbit needs mu, the guess of μ")
        mu = point.mu
    nu_guess = nu if nu_guess is None else nu_guess
    if isinstance(point, Orbit) and not is_concrete(nu_guess):
        raise ValueError("locate_grazing: with a traced nu (jit, jacfwd, grad), pass nu_guess, "
                         "the concrete ν of the guess orbit")
    orbit = point.orbit if isinstance(point, GrazingPoint) else point
    kw, _, scale = continuation_settings(orbit, rtol, atol, solver, newton_tol, max_newton_steps)
    # (host work on concrete values, also when called inside `jit`: the guess's contact)
    with jax.ensure_compile_time_eval():
        guess_args = args_of(float(mu), nu_guess) if isinstance(point, Orbit) else None
        surface, t_c, x_c, orbit = _contact_of(scene, point, guess_args, surface, kw)
    fixed = bool(orbit.fixed_period)
    if fixed and period_of is None:
        require_period_fixed_in(
            scene, lambda p: args_of(float(mu), p), nu_guess, t_c, x_c,
            orbit.period, caller="locate_grazing", parameter="ν", fix=PERIOD_OF_FIX)
    system = _system_for(scene, surface, args_of, period_of, fixed, newton_tol, scale,
                         max_newton_steps, dict(kw, adjoint=adjoint))
    head = t_c if fixed else float(orbit.period)
    y0 = jnp.asarray(np.concatenate([[head], x_c, [float(mu)]]))
    params = (jnp.asarray(nu, float), jnp.asarray(t_c), jnp.asarray(float(orbit.period)))
    return _solve_grazing(system, y0, params)


@orbit_kernel
def _solve_grazing(system: _GrazingSystem, y0, params) -> BifurcationPoint:
    """Newton on the grazing system at ν, then the point's diagnostics (with derivatives
    where they have them)."""
    nu, t_fixed, T_fixed = params

    def residual(y, params):
        nu, t_fixed, T_fixed = params
        return _residual(system, jnp.concatenate([y, nu[None]]), t_fixed, T_fixed)

    y, converged, finite, num_steps = newton(residual, system.root_finder, y0, params,
                                             system.max_newton_steps)
    t0, T, x, mu, nu = _unpack(system, jnp.concatenate([y, nu[None]]), t_fixed, T_fixed)

    def rate(monodromy, jac_T):  # dΦ/dt at the contact
        return gap_rates(system.phi, system.pmap.scene.vector_field, t0, x,
                         system.args_of(mu, nu))[1]

    return assessed_point("grazing", system.pmap, system.args_of, x, t0, T, mu, nu, rate,
                          converged, finite, num_steps)
