r"""Two-parameter curves of bifurcation points: a period-doubling, fold or Neimark–Sacker
point followed in (μ, ν).

The defining system of `locate_bifurcation` (`bifurcation.DefiningSystem`: the orbit is periodic
and the kind's test function vanishes) has one unknown more when ν is free too,
Y = (x, μ, ν) or (T, x, μ, ν): its solutions form a curve, followed by the pseudo-arclength
engine (`arclength.py`) with a secant predictor (the tangent of the last two points:
a tangent from the system's Jacobian would need the third derivatives of the flow).

Along the curve the multipliers other than the critical ones are watched; where one of
their test functions changes sign between two points, the curve meets another bifurcation
there, a codimension-two point (`Codim2Point`):

- a period-doubling curve: `"fold-flip"` (a multiplier 1 as well), `"1:2 resonance"` (a
  second multiplier −1), `"flip-neimark-sacker"` (a complex pair on the unit circle);
- a fold curve: `"fold-flip"`, `"1:1 resonance"` (a second multiplier 1),
  `"fold-neimark-sacker"`;
- a Neimark–Sacker curve, whose critical pair is e^{±iθ}: the strong resonances
  `"1:1 resonance"` (θ = 0), `"1:2 resonance"` (θ = π), `"1:3 resonance"` (θ = 2π/3),
  `"1:4 resonance"` (θ = π/2), and `"fold-neimark-sacker"`, `"flip-neimark-sacker"`;
- any curve: `"grazing"`, where the number of impacts per period changes (the orbit
  grazes a surface: the curve meets a grazing curve, and the defining system, smooth on
  each side, is not across it).

A codimension-two point is located by linear interpolation of its test function between
the two points around it (`Codim2Point.mu`, `.nu`), not solved.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._scene import Scene
from .._status import ContinuationStatus
from .arclength import (
    CurvePoint,
    Front,
    Steps,
    bordered_newton,
    eigvals_descending,
    progress_bar,
    trace,
)
from .bifurcation import DefiningSystem, defining_system
from .grazing_curve import GrazingCurve, continue_grazing
from .locate import is_grazing
from .period_map import newton_for, orbit_kernel, period_map_jacobian


class Codim2Point(NamedTuple):
    """Where a curve of bifurcation points meets another bifurcation
    (`grazejax.continue_bifurcation`): its `kind` (the module's list), `mu`, `nu`
    (linear interpolation of its test function between the curve's points `after − 1`
    and `after`), and `after`."""

    kind: str
    mu: float
    nu: float
    after: int


class BifurcationCurve(eqx.Module):
    r"""A curve of bifurcation points in two parameters
    (`grazejax.continue_bifurcation`). NumPy arrays, one row per point, in order of
    computation.

    **Fields:**

    - `kind`: `"period-doubling"`, `"fold"` or `"neimark-sacker"`.
    - `mu`, `nu`: the two parameters.
    - `x0`, `t0`, `period`: the orbit (`x0` at phase `t0`).
    - `multipliers`: of its monodromy, modulus descending.
    - `num_impacts`: impacts per period.
    - `codim2`: the codimension-two points met (`grazejax.Codim2Point`).
    - `status`: a `grazejax.ContinuationStatus` (shown by name; equal to its
      integer code); `message` reads it.
    """

    kind: str = eqx.field(static=True)
    mu: Any
    nu: Any
    t0: Any
    x0: Any
    period: Any
    multipliers: Any
    num_impacts: Any
    codim2: tuple = eqx.field(static=True)
    status: ContinuationStatus = eqx.field(static=True, converter=ContinuationStatus)

    @property
    def message(self) -> str:
        status = ContinuationStatus(self.status)
        if status == ContinuationStatus.REACHED_STOP:
            return "reached nu_stop"
        if status == ContinuationStatus.LEFT_RANGE:
            return "mu left mu_range"
        return status.message

    def __len__(self) -> int:
        return len(self.mu)


class _Diagnostics(NamedTuple):
    t0: float
    period: float
    multipliers: np.ndarray
    num_impacts: int


@orbit_kernel
def _curve_point(system: DefiningSystem, root_finder, max_newton_steps: int, Y_pred, tangent, params):
    """The bordered Newton corrector on the defining system with ν free, then the
    corrected orbit's monodromy, period, impact count and whether its run succeeded."""
    c, t0, T_fixed = params

    def rows(Y):
        return system.residual(Y[:-1], (Y[-1], c, t0, T_fixed))

    Y, converged, steps = bordered_newton(rows, root_finder, max_newton_steps, Y_pred, tangent)
    x, T, mu = system.split(Y[:-1])
    nu = Y[-1]
    if system.fixed_period:
        T = system.period(T_fixed, mu, nu)
    args = system.args_of(mu, nu)
    zeros = jax.tree.map(jnp.zeros_like, args)
    _, monodromy, _, _, ok, sol = period_map_jacobian(system.pmap, x, t0, T, args, zeros)
    return Y, converged & ok, steps, monodromy, T, sol.num_impacts


def _corrector(system, root_finder, max_newton_steps, t0, T_fixed):
    """`correct(Y_pred, tangent, origin)` for the engine: the secant from `origin` (the
    previous point) as the new tangent (`tangent` itself at the first point)."""
    x_index = 1 if not system.fixed_period else 0

    def correct(Y_pred, tangent, origin=None):
        Y_pred = np.asarray(Y_pred, float)
        # The phase condition's value moves with the curve: x_j of the previous point.
        c = 0.0 if system.fixed_period else float((Y_pred if origin is None else origin)[
            x_index + system.j])
        params = (jnp.asarray(c), jnp.asarray(t0), jnp.asarray(T_fixed))
        Y, good, steps, monodromy, T, k = _curve_point(
            system, root_finder, max_newton_steps, jnp.asarray(Y_pred), jnp.asarray(tangent, float),
            params)
        Y = np.asarray(Y)
        if not (bool(good) and np.all(np.isfinite(Y)) and np.all(np.isfinite(monodromy))):
            return None
        if origin is None:
            new_tangent = np.asarray(tangent, float)
        else:
            chord = Y - np.asarray(origin)
            norm = float(np.linalg.norm(chord))
            new_tangent = chord / norm if norm > 0 else np.asarray(tangent, float)
        data = _Diagnostics(float(t0), float(T), eigvals_descending(monodromy), int(k))
        return CurvePoint(Y, new_tangent, int(steps), data)

    return correct


# --------------------------------------------------------------------------------------
# Codimension-two points
# --------------------------------------------------------------------------------------


def _drop_nearest(rho: list, target: complex) -> None:
    rho.pop(int(np.argmin(np.abs(np.asarray(rho) - target))))


def _watched(kind: str, fixed_period: bool, multipliers) -> dict[str, float]:
    """The test functions of the codimension-two points of a `kind` curve at one point:
    each changes sign where the curve meets that point (module docstring)."""
    rho = list(np.asarray(multipliers, complex))
    if not fixed_period:
        _drop_nearest(rho, 1.0)  # the trivial multiplier
    tests = {}
    if kind == "period-doubling":
        _drop_nearest(rho, -1.0)
        names = {"fold": "fold-flip", "flip": "1:2 resonance", "ns": "flip-neimark-sacker"}
    elif kind == "fold":
        _drop_nearest(rho, 1.0)
        names = {"fold": "1:1 resonance", "flip": "fold-flip", "ns": "fold-neimark-sacker"}
    else:
        # The critical pair: ρ_a ρ_b closest to 1. κ = (ρ_a + ρ_b)/2 is cos θ on the circle
        # (and beyond ±1 for a real pair ρ, 1/ρ): the strong resonances are its levels.
        pairs = list(itertools.combinations(range(len(rho)), 2))
        a, b = min(pairs, key=lambda p: abs(rho[p[0]] * rho[p[1]] - 1))
        kappa = float(np.real(rho[a] + rho[b])) / 2
        for name, level in (("1:1 resonance", 1.0), ("1:2 resonance", -1.0),
                            ("1:3 resonance", -0.5), ("1:4 resonance", 0.0)):
            tests[name] = kappa - level
        rho = [r for m, r in enumerate(rho) if m not in (a, b)]
        names = {"fold": "fold-neimark-sacker", "flip": "flip-neimark-sacker", "ns": None}
    rest = np.asarray(rho, complex)
    tests[names["fold"]] = float(np.real(np.prod(rest - 1)))
    tests[names["flip"]] = float(np.real(np.prod(rest + 1)))
    if names["ns"] is not None:
        products = [rest[i] * rest[j] - 1 for i, j in itertools.combinations(range(len(rest)), 2)]
        tests[names["ns"]] = float(np.real(np.prod(products))) if products else 1.0
    return tests


def _codim2_points(kind: str, fixed_period: bool, points) -> tuple[Codim2Point, ...]:
    """Sign changes of the watched test functions, and changes of the impact count,
    between consecutive points."""
    found = []
    tests = [_watched(kind, fixed_period, p.data.multipliers) for p in points]
    for i in range(1, len(points)):
        (mu_a, nu_a), (mu_b, nu_b) = (points[i - 1].Y[-2:], points[i].Y[-2:])
        for name, before in tests[i - 1].items():
            after = tests[i][name]
            if before * after < 0:
                w = before / (before - after)
                found.append(Codim2Point(name, float(mu_a + w * (mu_b - mu_a)),
                                         float(nu_a + w * (nu_b - nu_a)), i))
        if points[i].data.num_impacts != points[i - 1].data.num_impacts:
            found.append(Codim2Point("grazing", float((mu_a + mu_b) / 2),
                                     float((nu_a + nu_b) / 2), i))
    return tuple(found)


# --------------------------------------------------------------------------------------
# continue_bifurcation
# --------------------------------------------------------------------------------------


def continue_bifurcation(
    scene: Scene,
    point,
    args_of: Callable[[Any, Any], Any],
    mu_start: float,
    nu_start: float,
    nu_stop: float,
    *,
    kind: str | None = None,
    fixed_period: bool | None = None,
    period_of: Callable[[Any, Any], Any] | None = None,
    fix: int | None = None,
    mu_range: tuple[float, float] = (-math.inf, math.inf),
    ds: float = 0.02,
    ds_min: float | None = None,
    ds_max: float = 0.1,
    max_points: int = 200,
    progress: bool = True,
    rtol: float = 1e-10,
    atol: float | None = None,
    solver: diffrax.AbstractSolver | None = None,
    newton_tol: float = 1e-9,
    max_newton_steps: int = 12,
) -> BifurcationCurve | GrazingCurve:
    r"""Follow a period-doubling, fold, Neimark–Sacker or grazing point in two parameters
    (μ, ν): from ν = `nu_start` to `nu_stop`, μ free.

    **Arguments:**

    - `scene`: a `grazejax.Scene`.
    - `point`: where to start: a `grazejax.SpecialPoint` (from
      `grazejax.continue_orbit`), a `grazejax.BifurcationPoint`, or any object
      with `mu`, `x0`, `t0`, `period` (and `kind` unless given). It only needs to be
      close: the first point is solved at ν = `nu_start` with μ free.
    - `args_of(mu, nu) -> args`: traceable; pass the same function object across calls
      to reuse the compiled programs.
    - `mu_start`, `nu_start`: the parameters at `point` (`mu_start` is the guess of μ).
    - `nu_stop`: the curve is followed from `nu_start` towards `nu_stop` (the first step
      moves ν that way) and ends there exactly, unless it stops earlier.
    - `kind`: default `point.kind` (`"grazing"` for a `grazejax.GrazingPoint`).
    - `fixed_period`: forced orbits, of period `period_of(mu, nu)` (default: the point's
      period, fixed); `False`: autonomous ones (phase condition on x_j, `fix` = j as in
      `grazejax.locate_bifurcation`). Default: `point.fixed_period`, else True.
    - `mu_range`: `(lo, hi)`: stop when μ leaves it.
    - `ds`, `ds_min` (default `1e-3 * ds`), `ds_max`, `max_points`, `progress`: the
      arclength steps in (x0, μ, ν) (and T), as in `grazejax.continue_grazing`.
    - `rtol`, `atol`, `solver`: for `grazejax.simulate` (`atol=None`: scaled to the
      orbit's size); `newton_tol`, `max_newton_steps`: the corrector.

    A grazing point (a `grazejax.GrazingPoint`, or `kind="grazing"` with an
    `grazejax.Orbit` near grazing as `point`) is followed by
    `grazejax.continue_grazing`, which continues in its first parameter: here it is
    given (ν, μ) ↦ `args_of(μ, ν)` and returns its `grazejax.GrazingCurve` with `mu`
    and `nu` as here (`mu_range` bounds μ; `fixed_period` and `fix` are not used: the
    point's orbit says whether it is forced).

    **Returns:** a `grazejax.BifurcationCurve`, with the codimension-two points met
    in `codim2`.

    **Example** (the ball on a vibrating table: the period-doubling point of its period-1
    orbit, Γ_PD(e) = √(c² + (1 + r²)²) with r = (1 − e)/(1 + e), c = πr, followed in the
    restitution e; the guess is the orbit at its apex):

    ```python
    import math
    from types import SimpleNamespace
    from grazejax import examples as ex

    table, omega, g = ex.vibrating_table(), 2 * math.pi, 9.81
    def args_of(gamma, e):
        return dict(g=g, e=e, A=gamma * g / omega**2, omega=omega)
    gamma, e = 1.53, 0.5
    phi = math.acos(math.pi * (1 - e) / (1 + e) / gamma)
    guess = SimpleNamespace(kind="period-doubling", mu=gamma, period=1.0,
                            t0=phi / omega + 0.5,
                            x0=[args_of(gamma, e)["A"] * math.sin(phi) + g / 8, 0.0])
    curve = gj.continue_bifurcation(table, guess, args_of, gamma, e, 1.1, rtol=1e-11)
    print(curve.codim2)   # the 1:2 resonance near (Γ, e) = (1, 1)
    ```
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if not callable(args_of):
        raise TypeError("args_of must be a function (mu, nu) -> args")
    if nu_start == nu_stop:
        raise ValueError("nu_start == nu_stop: nothing to continue")
    if is_grazing(point, kind):
        return _grazing_case(scene, point, args_of, mu_start, nu_start, nu_stop,
                             period_of=period_of, mu_range=mu_range, ds=ds, ds_min=ds_min,
                             ds_max=ds_max, max_points=max_points, progress=progress,
                             rtol=rtol, atol=atol, solver=solver, newton_tol=newton_tol,
                             max_newton_steps=max_newton_steps)
    kind = getattr(point, "kind", None) if kind is None else kind
    steps = Steps(float(ds), 1e-3 * float(ds) if ds_min is None else float(ds_min),
                  float(ds_max), int(max_points))
    fixed = bool(getattr(point, "fixed_period", True) if fixed_period is None else fixed_period)
    t0, T_guess = float(point.t0), float(point.period)
    system, x_guess, scale = defining_system(
        scene, point, kind, fixed, args_of, period_of, fix, mu_start, nu_start,
        dict(solver=solver, rtol=float(rtol), atol=atol, max_impacts=64,
             max_solver_steps=50_000))
    n = x_guess.shape[0]
    correct = _corrector(system, newton_for(newton_tol, max(scale, 1.0)),
                         int(max_newton_steps), t0, T_guess)
    direction = 1.0 if nu_stop > nu_start else -1.0
    head = [] if fixed else [T_guess]
    Y0 = np.concatenate([head, x_guess, [float(mu_start), float(nu_start)]])
    e_nu = np.zeros(Y0.shape[0])
    e_nu[-1] = 1.0
    first = correct(Y0, direction * e_nu)
    points, status = [], ContinuationStatus.START_FAILED
    if first is not None:
        # The first tangent: the chord to the point at ν = nu_start + ds (μ free).
        second = correct(first.Y + direction * steps.ds * e_nu, e_nu, first.Y)
        if second is not None:
            first = first._replace(tangent=second.tangent)
        with progress_bar(progress, steps.max_points, "grazejax.continue_bifurcation",
                          ("mu", -2), ("nu", -1)) as report:
            points, status = trace(Front(correct), first, index=-1, stop=float(nu_stop),
                                   direction=direction, steps=steps, progress=report,
                                   in_range=lambda Y: mu_range[0] <= Y[-2] <= mu_range[1])
    return _curve(kind, fixed, points, status, n, len(head))


class _Swapped(eqx.Module):
    """`fn` with its two parameters swapped, (ν, μ) ↦ fn(μ, ν). A Module: the same `fn`
    gives equal wrappers, which share their compiled programs."""

    fn: Callable = eqx.field(static=True)

    def __call__(self, nu, mu):
        return self.fn(mu, nu)


def _grazing_case(scene, point, args_of, mu_start, nu_start, nu_stop, *, period_of,
                  mu_range, **options) -> GrazingCurve:
    """A grazing point followed in ν with μ free: `continue_grazing` with the parameters'
    roles swapped (it continues in its first parameter), its curve swapped back."""
    curve = continue_grazing(
        scene, point, _Swapped(args_of), float(nu_start), float(mu_start), float(nu_stop),
        nu_range=mu_range, period_of=None if period_of is None else _Swapped(period_of),
        **options)
    return dataclasses.replace(curve, mu=curve.nu, nu=curve.mu)


def _curve(kind, fixed, points, status, n, head) -> BifurcationCurve:
    Ys = np.stack([p.Y for p in points]) if points else np.zeros((0, head + n + 2))

    def col(name, dtype=float):
        return np.asarray([getattr(p.data, name) for p in points], dtype)

    multipliers = (np.stack([p.data.multipliers for p in points]) if points
                   else np.zeros((0, n), complex))
    return BifurcationCurve(
        kind=kind, mu=Ys[:, -2], nu=Ys[:, -1], t0=col("t0"), x0=Ys[:, head:head + n],
        period=col("period"), multipliers=multipliers, num_impacts=col("num_impacts", int),
        codim2=_codim2_points(kind, fixed, points), status=int(status),
    )
