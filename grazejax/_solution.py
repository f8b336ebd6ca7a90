"""`Solution`: what one run (or one batch of runs) of `simulate` returns."""

import equinox as eqx
import jax
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._status import ImpactKind, Status


class ImpactLog(eqx.Module):
    r"""The impact log that `grazejax.Solution` and `grazejax.Orbit` both carry.

    At an impact time θ, `impact_pre` is x(θ) and `impact_post` is x(θ+) = J(x(θ)) (the
    paper's left-continuous convention). The log has `max_impacts` rows; rows past
    `num_impacts` are padded with NaN (times, states), `-1` (surface) and
    `ImpactKind.NONE`.

    **Fields:**

    - `num_impacts`: number of rows used.
    - `impact_times`: the times θ.
    - `impact_pre`, `impact_post`: the states before and after each jump.
    - `impact_surface`: the index of the surface piece in `scene.surfaces`.
    - `impact_kind`: an `grazejax.ImpactKind` code (transversal, grazing, ...).
    """

    num_impacts: Int[Array, ""]
    impact_times: Float[Array, " max_impacts"]
    impact_pre: Float[Array, "max_impacts n"]
    impact_post: Float[Array, "max_impacts n"]
    impact_surface: Int[Array, " max_impacts"]
    impact_kind: Int[Array, " max_impacts"]


class Solution(ImpactLog):
    r"""The result of `grazejax.simulate`. Under `jax.vmap` every field gains a
    leading batch axis.

    Solutions are left-continuous (the paper's convention): at an impact time θ,
    `impact_pre` is x(θ) and `impact_post` is x(θ+) = J(x(θ)). The impact log
    (`grazejax.ImpactLog`'s fields) has `max_impacts` rows; rows past `num_impacts` are
    padded with NaN (times, states), `-1` (surface) and `ImpactKind.NONE`.

    **Fields:**

    - `t_final`, `x_final`: where the run stopped: `t1` and x(t1) on `SUCCESS`; the time
      and post-impact state of the last impact on `MAX_IMPACTS` and `ZENO`. A failed run
      (any other status, e.g. a failed lane of `grazejax.sweep`) holds the last state
      it reached, never a state at `t1`: the last accepted step (`MAX_STEPS`,
      `STEP_SIZE_UNDERFLOW`, `NONFINITE` from the vector field); the event time and the
      state its jump produced (`BAD_JUMP`, `FIELD_DISCONTINUITY`; the state before the
      jump if the jump returned NaN/inf); `t0` and `x0` for a run that did not start
      (`BAD_START`, `BAD_TIMES`, non-finite `x0` or `args`). Check `status` before using
      them.
    - `num_impacts`: number of rows used in the impact log: impacts applied (simultaneous
      impacts count once each) plus, with `zeno="stick"`, the starts and ends of sliding
      (kinds `STICK`, `RELEASE`; count impacts with `impact_kind <= GAMMA_PRIME`).
      Simultaneous impacts that overflow `max_impacts` are counted (and applied: `x_final`
      is after all of them) but not logged: the log keeps the first `max_impacts` rows.
    - `impact_times`, `impact_pre`, `impact_post`, `impact_surface`, `impact_kind`: the log.
      In backward time (`t1 < t0`) "pre" is the state met first (on Γ̃) and "post" the
      state after the inverse jump; kinds are the primed ones.
    - `status`: a `grazejax.Status` code.
    - `zeno_time`: estimated accumulation time when `status == ZENO` (with
      `zeno="stick"`: of the last Zeno sequence before sliding), else NaN.
    - `num_steps`, `num_accepted_steps`: solver steps (all / accepted), for cost accounting.
    - `ts`, `xs`: saved times and states, only when `saveat` was given (else `None`).
    """

    t_final: Float[Array, ""]
    x_final: Float[Array, " n"]
    status: Int[Array, ""]
    zeno_time: Float[Array, ""]
    num_steps: Int[Array, ""]
    num_accepted_steps: Int[Array, ""]
    ts: Float[Array, " num_saves"] | None = None
    xs: Float[Array, "num_saves n"] | None = None

    @property
    def succeeded(self) -> Bool[Array, ""]:
        return self.status == Status.SUCCESS

    @property
    def ys(self) -> Float[Array, "num_saves n"] | None:
        """The saved states under Diffrax's name: the same array as `xs` (grazejax names
        states x, as the paper does). Diffrax's `result` is `status` here."""
        return self.xs

    def summary(self, max_lanes: int = 10, max_impact_lines: int = 10) -> str:
        """A short human-readable account of the run (outside `jit`).

        For one run: the status, the final time and state, then one line per logged
        impact; with more than `max_impact_lines` impacts, only that many, the first and
        the last (5 and 5 by default), with a line "... N more impacts ..." between, so
        that a run of hundreds of impacts fits a screen.

        For a batch (from `jax.vmap` or `grazejax.sweep`): the number of lanes with each
        status, the ranges of `t_final`, `num_impacts` and `num_steps`, then one line per
        lane for the first `max_lanes` lanes.
        """
        if isinstance(self.status, jax.core.Tracer):
            raise TypeError("Solution.summary() reads values: call it outside jit/vmap")
        if np.ndim(self.status) > 0:
            return _batch_summary(self, max_lanes)
        status = Status(int(self.status))
        k = int(self.num_impacts)
        lines = [
            f"status: {status.name} ({status.message}); t_final = {float(self.t_final):.17g}",
            f"x_final = {np.asarray(self.x_final)}",
            f"{k} impact(s); {int(self.num_accepted_steps)} accepted of {int(self.num_steps)} steps",
        ]
        rows = min(k, len(self.impact_times))  # (impacts past a full log are not logged)
        shown = list(range(rows))
        limit = max(0, max_impact_lines)
        if rows > limit:
            tail = limit // 2
            shown = [*range(limit - tail), None, *range(rows - tail, rows)]
        for i in shown:
            if i is None:
                lines.append(f"  ... {rows - limit} more impacts ...")
                continue
            kind = ImpactKind(int(self.impact_kind[i]))
            lines.append(
                f"  #{i}: t = {float(self.impact_times[i]):.15g}  surface {int(self.impact_surface[i])}"
                f"  {kind.name}  pre = {np.asarray(self.impact_pre[i])}  post = {np.asarray(self.impact_post[i])}"
            )
        if status == Status.ZENO:
            lines.append(f"estimated accumulation time: {float(self.zeno_time):.15g}")
        return "\n".join(lines)


def _batch_summary(sol: Solution, max_lanes: int) -> str:
    status = np.asarray(sol.status).reshape(-1)
    t_final = np.asarray(sol.t_final).reshape(-1)
    impacts = np.asarray(sol.num_impacts).reshape(-1)
    steps = np.asarray(sol.num_steps).reshape(-1)
    counts = ", ".join(
        f"{Status(code).name} {int(np.sum(status == code))}" for code in np.unique(status)
    )
    lines = [
        f"{status.size} lanes: {counts}",
        f"t_final in [{t_final.min():.6g}, {t_final.max():.6g}]; impacts per lane in "
        f"[{impacts.min()}, {impacts.max()}]; steps per lane in [{steps.min()}, {steps.max()}]",
    ]
    shown = min(status.size, max(0, max_lanes))
    for i in range(shown):
        x_final = np.asarray(sol.x_final).reshape(status.size, -1)[i]
        lines.append(
            f"  lane {i}: {Status(int(status[i])).name}  t_final = {t_final[i]:.15g}  "
            f"{impacts[i]} impact(s)  x_final = {x_final}"
        )
    if shown < status.size:
        lines.append(f"  ... {status.size - shown} more lane(s) (summary(max_lanes=...))")
    return "\n".join(lines)


# The fix for a field written with sign(·) on an event surface (also raised eagerly).
FIELD_FIX = (
    "write the field with one mode per side: grazejax.PiecewiseScene(modes, transitions=... or "
    "switching=[grazejax.SwitchingSurface(phi, minus=..., plus=..., sliding=...)]) "
    "(docs/piecewise.md), or keep the side as a state component that the jump flips; "
    "simulate(..., check_field_jumps=False) silences this check"
)

# What to do about each way a run can fail (named by `throw=True` errors).
_FIXES = {
    Status.MAX_STEPS: "raise max_steps, or loosen rtol/atol",
    Status.NONFINITE: "the vector field or a jump returned NaN/inf: check them (and x0, args) "
    "near x_final",
    Status.STEP_SIZE_UNDERFLOW: "the flow is stiff or singular near x_final: try an implicit "
    "solver (diffrax.Kvaerno5) or looser tolerances",
    Status.BAD_JUMP: "a jump law leaves the state inside an impenetrable surface (its own or "
    "another): check the jumps, or mark the surface impenetrable=False if Φ < 0 is allowed",
    Status.BAD_START: "start on the free side Φ >= 0 of every impenetrable surface (on one: "
    "moving out, e.g. the post-impact state of a pre-impact start)",
    Status.FIELD_DISCONTINUITY: FIELD_FIX,
    Status.BAD_TIMES: "pass direction=+1 for t1 > t0 and -1 for t1 < t0; forward and backward "
    "runs are different programs, so a batch with both needs one call for each",
}

# Statuses that `throw=True` accepts: the run ended the way it was asked to, or at a
# physical accumulation.
ACCEPTED = (Status.SUCCESS, Status.MAX_IMPACTS, Status.ZENO)


def failure_message(status: Status) -> str:
    """What `throw=True` says about a run that ended with `status`."""
    return (
        f"grazejax.simulate: the run ended with status {status.name} ({status.message}). "
        f"Fix: {_FIXES.get(status, 'see grazejax.Status')}. "
        "Pass throw=False to get the Solution and read Solution.status."
    )


class SimulationError(RuntimeError):
    """Raised by `simulate(..., throw=True)` (and `sweep`) outside `jit` when a run does not
    end with `SUCCESS`, `MAX_IMPACTS` or `ZENO`.

    **Attributes:**

    - `solution`: the whole `grazejax.Solution` (every lane, for a batch).
    - `status`: the `grazejax.Status` of the (first) failing run.
    - `lanes`: for a batch, the indices of the failing lanes; `None` for a single run.
    """

    def __init__(self, solution: Solution):
        status = np.asarray(solution.status).reshape(-1)
        failed = np.flatnonzero(~np.isin(status, [int(s) for s in ACCEPTED]))
        self.solution = solution
        self.status = Status(int(status[failed[0]]))
        self.lanes = failed if np.ndim(solution.status) > 0 else None
        message = failure_message(self.status)
        if self.lanes is not None:
            others = ", ".join(
                f"{Status(code).name} {int(np.sum(status[failed] == code))}"
                for code in np.unique(status[failed])
            )
            message = (
                f"{len(failed)} of {status.size} lanes failed ({others}); the first is lane "
                f"{failed[0]}: " + message + " The failing lanes are in error.lanes."
            )
        super().__init__(message + " The Solution is attached as error.solution.")


class FailedLanesWarning(UserWarning):
    """Warned by `grazejax.sweep` (with `throw=False`, the default) when some lanes end
    in a failure, a status other than `SUCCESS`, `MAX_IMPACTS` or `ZENO`. The message counts
    the failing lanes by status; each lane's own `status` says which they are, and the
    other lanes' results are unaffected.

    A sweep that expects failing lanes silences it with the standard `warnings` filters:

    ```python
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", gj.FailedLanesWarning)
        out = gj.sweep(scene, x0s, t0, t1, args)
    ```
    """


def failed_lanes_message(status) -> str | None:
    """What `sweep` warns about a batch's statuses: the failing lanes counted by status
    name, or None if no lane failed."""
    status = np.asarray(status).reshape(-1)
    failed = status[~np.isin(status, [int(s) for s in ACCEPTED])]
    if failed.size == 0:
        return None
    counts = ", ".join(
        f"{Status(int(code)).name} {int(np.sum(failed == code))}" for code in np.unique(failed)
    )
    return (
        f"grazejax.sweep: {failed.size} of {status.size} lanes failed ({counts}); their "
        "x_final and t_final hold the state where they stopped, not the state at t1. Read "
        "Solution.status (Solution.summary() counts the statuses), or pass throw=True to "
        "raise a SimulationError that names the failing lanes."
    )
