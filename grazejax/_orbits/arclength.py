r"""Pseudo-arclength continuation of a curve F(Y) = 0, F: ℝ^{k+1} → ℝ^k: the one engine
under `continue_orbit` (periodic orbits, across grazing), `continue_grazing` (grazing
orbits) and `continue_bifurcation` (bifurcation points), and the corrector's pieces they
share (`bordered_newton`, `next_tangent`, `continuation_settings`).

The engine knows nothing of orbits. A front end gives it `correct`, Newton's method on
[F(Y); tangent·(Y − Y_pred)] = 0 followed by the new point's tangent and diagnostics (a
point with `Y`, `tangent` and Newton's `steps`, or None where it fails), and the engine
predicts, accepts, adapts the step and stops (a `grazejax.ContinuationStatus`):

- at `stop` on the coordinate `index` of Y, exactly (a last correction whose bordered row
  fixes that coordinate);
- where `in_range(Y)` fails (`LEFT_RANGE`), the step falls under `ds_min`
  (`STEP_TOO_SMALL`) or after `max_points` (`MAX_POINTS`).

A front end whose curve has events of its own (`continue_orbit`: the impact count changes
at grazing, a family ends, special points between points) answers the engine's hooks
(`Front`): whether a corrected point is accepted, what it sees on an accepted point, what
to do when a step is refused or the step is at its smallest. A hook may move the run
(`Run`: points, current point, step) to another family and let the engine go on.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from .._status import ContinuationStatus
from .period_map import SolverSettings, atol_for, newton_root, orbit_scale, solver_name


class CurvePoint(NamedTuple):
    """One point of a curve: the unknowns `Y`, the unit `tangent` there (oriented along
    the curve's direction of travel), Newton's `steps`, and the front end's `data`."""

    Y: np.ndarray
    tangent: np.ndarray
    steps: int
    data: Any


@dataclasses.dataclass(frozen=True)
class Steps:
    """The arclength step: initial `ds`, bounds `ds_min`, `ds_max`; at most `max_points`."""

    ds: float
    ds_min: float
    ds_max: float
    max_points: int

    def __post_init__(self):
        if not (self.ds_min > 0 and self.ds_max >= self.ds >= self.ds_min):
            raise ValueError("need 0 < ds_min <= ds <= ds_max")


def step_accepted(Y_new, tangent_new, Y_pred, tangent, h) -> bool:
    """A corrected point continues the same curve: its tangent turned by less than 60°
    and it lies within 3h of the prediction (otherwise the corrector jumped elsewhere)."""
    return (float(jnp.dot(tangent_new, tangent)) > 0.5
            and float(jnp.linalg.norm(Y_new - Y_pred)) <= 3 * h)


def grown_step(h, newton_steps, ds_max):
    """Grow by 1.5 (up to `ds_max`) after an easy correction (≤ 3 Newton steps)."""
    return min(1.5 * h, ds_max) if int(newton_steps) <= 3 else h


@dataclasses.dataclass
class Run:
    """The engine's state, which a front end's hooks may change: the `points` so far, the
    `current` point (the predictor's origin) and the step `h`."""

    points: list
    current: Any
    h: float


# A hook's answer for "nothing of mine here: do what the engine does".
FALL_THROUGH = object()


class Front:
    """A front end of the engine: `correct` plus hooks, whose defaults here are those of a
    curve without events of its own (`Front(correct)`)."""

    def __init__(self, correct: Callable | None = None):
        self._correct = correct

    def correct(self, run: Run, Y_pred, tangent):
        """The corrected point from the prediction (None where Newton fails)."""
        return self._correct(Y_pred, tangent, np.asarray(run.current.Y))

    def land(self, run: Run, guess, e_stop):
        """The last point, on `stop` exactly (`e_stop`: the bordered row fixing `index`), or
        None to take an ordinary step instead."""
        return self.correct(run, guess, e_stop)

    def accepts(self, run: Run, new, Y_pred, tangent) -> bool:
        """Whether the corrected point continues the curve."""
        return new is not None and step_accepted(new.Y, new.tangent, Y_pred, tangent, run.h)

    def accepted(self, run: Run, new) -> None:
        """Called on an accepted point before the engine appends it."""

    def rejected(self, run: Run, tangent):
        """A refused step: a status to stop with, None to go on (the run moved), or
        FALL_THROUGH (the engine halves the step)."""
        return FALL_THROUGH

    def stuck(self, run: Run, tangent):
        """The step fell under `ds_min`: a status, or None to go on (the run moved)."""
        return ContinuationStatus.STEP_TOO_SMALL


def trace(front: Front, first, *, index: int, stop: float, direction: float, steps: Steps,
          in_range: Callable = lambda Y: True, progress=None):
    """Follow the curve from `first` (its tangent pointing the way to go) until the
    coordinate `index` of Y reaches `stop` (`direction`: the sign of stop − start):
    `(points, status)`. `progress(point, h)` is called on every accepted point."""
    run = Run([first], first, float(steps.ds))
    e_stop = np.zeros(np.shape(first.Y))
    e_stop[index] = 1.0
    while len(run.points) < steps.max_points:
        Y = np.asarray(run.current.Y)
        if (Y[index] - stop) * direction >= 0:
            return run.points, ContinuationStatus.REACHED_STOP
        if not in_range(Y):
            return run.points, ContinuationStatus.LEFT_RANGE
        tangent = np.asarray(run.current.tangent)
        Y_pred = Y + run.h * tangent
        if (Y_pred[index] - stop) * direction > 0 and tangent[index] * direction > 0:
            # Land on `stop` exactly: the bordered row fixes that coordinate.
            guess = Y + (stop - Y[index]) / (Y_pred[index] - Y[index]) * run.h * tangent
            guess[index] = stop
            last = front.land(run, guess, e_stop)
            if last is not None:
                run.points.append(last)
                return run.points, ContinuationStatus.REACHED_STOP
        new = front.correct(run, Y_pred, tangent)
        if front.accepts(run, new, Y_pred, tangent):
            front.accepted(run, new)
            run.points.append(new)
            run.current = new
            run.h = grown_step(run.h, new.steps, steps.ds_max)
            if progress is not None:
                progress(new, run.h)
            continue
        outcome = front.rejected(run, tangent)
        if outcome is FALL_THROUGH:
            run.h *= 0.5
            if run.h >= steps.ds_min:
                continue
            outcome = front.stuck(run, tangent)
        if outcome is not None:
            return run.points, outcome
    return run.points, ContinuationStatus.MAX_POINTS


@contextlib.contextmanager
def progress_bar(enabled: bool, total: int, desc: str, *coordinates):
    """A tqdm bar of points (the first already computed) for `trace`'s `progress`, showing
    the `(name, index)` coordinates of each accepted point and the step; None if not
    `enabled`."""
    if not enabled:
        yield None
        return
    from tqdm.auto import tqdm

    bar = tqdm(total=total, desc=desc, unit="pt")
    bar.update(1)

    def report(point: CurvePoint, h):
        bar.update(1)
        shown = {name: f"{float(point.Y[index]):.5g}" for name, index in coordinates}
        bar.set_postfix(**shown, ds=f"{h:.2g}")

    try:
        yield report
    finally:
        bar.close()


def write_text(text: str, path) -> str:
    """`text`, also written to `path` if given (the `to_csv`/`to_json` exports)."""
    if path is not None:
        with open(path, "w", newline="") as f:
            f.write(text)
    return text


def continuation_settings(orbit, rtol, atol, solver, newton_tol, max_newton_steps):
    """The simulate keywords, `grazejax.SolverSettings` and state scale of a
    continuation from `orbit` (`atol=None`: scaled to the orbit's size)."""
    scale = (orbit.settings.state_scale if orbit.settings is not None
             else orbit_scale(np.asarray(orbit.x0)))
    atol = atol_for(orbit, rtol, atol)
    kw = dict(solver=solver, rtol=float(rtol), atol=float(atol), max_impacts=64,
              max_solver_steps=50_000)
    settings = SolverSettings(
        solver=solver_name(solver), rtol=float(rtol), atol=float(atol),
        newton_rtol=float(newton_tol), newton_atol=float(newton_tol) * scale,
        max_newton_steps=int(max_newton_steps), max_solver_steps=50_000, max_impacts=64,
        state_scale=scale,
    )
    return kw, settings, scale


def next_tangent(J, tangent):
    """The null vector of the (k × k+1) Jacobian `J`, oriented along the previous
    `tangent` (solves [J; tᵀ] τ = e_last), normalised: the next pseudo-arclength tangent."""
    A = np.vstack([J, np.asarray(tangent)[None]])
    rhs = np.zeros(A.shape[0])
    rhs[-1] = 1.0
    new_tangent = np.linalg.solve(A, rhs)
    return new_tangent / np.linalg.norm(new_tangent)


def eigvals_descending(matrix) -> np.ndarray:
    """A concrete matrix's eigenvalues by modulus, descending (complex; numpy on the host),
    for the continuation's per-point diagnostics."""
    w = np.linalg.eigvals(np.asarray(matrix))
    return w[np.argsort(-np.abs(w), kind="stable")].astype(complex)


def bordered_newton(rows_of, root_finder, max_newton_steps, Y_pred, tangent):
    """Newton (`newton_root`) on [rows(Y); tangent·(Y − Y_pred)] = 0: the
    pseudo-arclength corrector. Returns (Y, converged, number of steps)."""

    def bordered(Y, _):
        return jnp.concatenate([rows_of(Y), jnp.dot(tangent, Y - Y_pred)[None]])

    return newton_root(bordered, root_finder, Y_pred, None, max_newton_steps)
