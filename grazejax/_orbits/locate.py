"""`locate_bifurcation`: a point of any kind solved by its defining system at ν: period
doubling, fold and Neimark–Sacker (`bifurcation`) or grazing (`grazing_curve`)."""

from __future__ import annotations

import diffrax

from .._deprecated import NEWTON_STEPS, renamed_keyword
from .._scene import Scene
from .bifurcation import BifurcationPoint, locate_special
from .branch import GrazingPoint
from .grazing_curve import locate_grazing


def is_grazing(point, kind) -> bool:
    """Whether `point` (with `kind`, if given) asks for the grazing system."""
    return kind == "grazing" or (kind is None and (
        isinstance(point, GrazingPoint) or getattr(point, "kind", None) == "grazing"))


@renamed_keyword("max_steps", "max_newton_steps", NEWTON_STEPS)
def locate_bifurcation(
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
    r"""Solve a bifurcation point of periodic orbits by its defining system, at ν.

    **Arguments:**

    - `scene`: a `grazejax.Scene`.
    - `point`: the guess: a `grazejax.SpecialPoint` or `grazejax.GrazingPoint`
      from `grazejax.continue_orbit`, or any object with `mu`, `x0`, `t0`, `period` and
      (unless `kind` is given) `kind`.
    - `args_of(mu, nu) -> args`: the scene's parameters at (μ, ν).
    - `nu`: the second parameter (may be traced: the result is differentiable in it).
    - `kind`: `"period-doubling"`, `"fold"`, `"neimark-sacker"` or `"grazing"` (default
      `point.kind`; `"grazing"` for a `GrazingPoint`, whose own `kind` says how the branch
      met it).
    - `fixed_period`: a forced orbit of period `period_of(mu, nu)` (default `point.period`
      for every μ, ν), solved for x0 and μ; `False`: an autonomous orbit, solved for its
      period, x0 and μ with x_j held at the guess's value (`fix`: j; default the j with the
      largest |f_j(x0)|).
    - `rtol`, `atol`, `solver`, `max_impacts`, `max_solver_steps`: passed to
      `grazejax.simulate` (`atol=None`: `1e-2 · rtol` times the orbit's size).
    - `newton_tol`, `max_newton_steps`: Newton's relative tolerance and iterations.
    - `adjoint`: `simulate`'s for Newton's runs: the default (`diffrax.ForwardMode()`)
      lets `jax.jacfwd` differentiate the point, `diffrax.DirectAdjoint()` `jax.grad` too.

    **Returns:** a `grazejax.BifurcationPoint`; failure is a status, never an
    exception inside `jit`.

    The orbit starts away from impacts (x0 is not a post-impact state): take `point.t0`
    between impacts, as `grazejax.continue_orbit`'s points are.

    A grazing point is solved by `grazejax.locate_grazing` (its defining system: the
    orbit periodic, Φ = 0 and dΦ/dt = 0 at the contact), with `period_of`, `rtol`, `atol`,
    `solver`, `newton_tol`, `max_newton_steps` and `adjoint` passed on; whether its orbit is
    forced comes from the point's orbit (`fixed_period`, `fix`, `max_impacts` and
    `max_solver_steps` are not used). Its result has kind `"grazing"`.
    """
    if is_grazing(point, kind):
        return locate_grazing(scene, point, args_of, nu, period_of=period_of, rtol=rtol,
                              atol=atol, solver=solver, newton_tol=newton_tol,
                              max_newton_steps=max_newton_steps, adjoint=adjoint)
    return locate_special(scene, point, args_of, nu, kind=kind, fixed_period=fixed_period,
                          period_of=period_of, fix=fix, rtol=rtol, atol=atol, solver=solver,
                          newton_tol=newton_tol, max_newton_steps=max_newton_steps, max_impacts=max_impacts,
                          max_solver_steps=max_solver_steps, adjoint=adjoint)
