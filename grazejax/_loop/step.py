"""One solver step and the step-size controller's verdict on it."""

from typing import Any, NamedTuple

import diffrax
import jax
import jax.numpy as jnp
from jaxtyping import PyTree

from .._custom_types import BoolScalar, RealScalar, State
from .compact import if_any_lane
from .context import LoopContext
from .gaps import GapSamples, sample_gaps
from .replay import decision, replay_decisions
from .state import LoopState
from .stepping import error_or_zero


class Step(NamedTuple):
    """A step [sa, sb] just taken from `c.y`, and what the controller made of it."""

    sa: RealScalar
    sb: RealScalar
    s_end: RealScalar  # local time of t1
    y1: State
    interp: diffrax.AbstractLocalInterpolation  # the step's dense output, in the local clock
    stages: Any  # the Runge–Kutta stages h·f (`dense_info["k"]`), or None
    keep: BoolScalar  # accepted (and finite)
    finite: BoolScalar  # y1 is finite
    h_next: RealScalar
    solver_state: PyTree[Any]
    controller_state: PyTree[Any]
    gaps: GapSamples | None  # the surfaces' gaps along the step, or None (not searched)


def take_step(ctx: LoopContext, c: LoopState, slides: bool = True, forced=None,
              search: bool = True) -> Step:
    """One solver step from c.s: to the located contact on a landing, else by c.h (never
    past t1). `slides=False`: no lane slides (the free field, no per-step test).
    `forced`: the decisions `(h_next, keep)` of this step in an earlier pass, to replay
    (`replay.replay_decisions`), or None. `search=False`: the step is known to be a
    landing (its gaps are not sampled).

    A step the controller accepts is still retaken, shorter, where its samples do not
    resolve a surface's gap (`events.gap_resolution`): the contact tests would not be
    complete on it."""
    solver, controller = ctx.solver, ctx.controller
    targs = (c.args, c.t_hi, c.t_lo, c.stick)
    s_end = ctx.s_end_of(c.t_hi, c.t_lo)
    sa = c.s
    sb = jnp.where(c.landing, c.target, jnp.minimum(sa + c.h, s_end))

    def step_with(term):
        return solver.step(term, sa, sb, c.y, targs, c.solver_state, c.made_jump)

    y1, y_error, dense_info, solver_state1, _ = ctx.policy.solver_step(ctx, c, step_with, slides, sb)
    if ctx.project is not None:  # the scene's map back onto its invariant manifold
        t1_abs = ctx.abs_time(sb, c.t_hi, c.t_lo)
        y1 = jnp.asarray(ctx.project(t1_abs, y1, c.args), y1.dtype)
    # A NaN error estimate must reject the step, not poison the controller (diffrax #143).
    y_error = error_or_zero(y_error, y1)
    y_error = jnp.where(jnp.isnan(y_error), jnp.inf, y_error)
    y_error = equilibrium_probe(ctx, sa, sb, c.y, y1, y_error, targs)
    keep, _, tnext, _, controller_state1, _ = controller.adapt_step_size(
        sa, sb, c.y, y1, targs, y_error, ctx.error_order, c.controller_state
    )
    finite1 = jnp.all(jnp.isfinite(y1))
    keep = keep & finite1
    h_next = jax.lax.stop_gradient(tnext - jnp.where(keep, sb, sa))
    interp = solver.interpolation_cls(t0=sa, t1=sb, **dense_info)
    stages = dense_info.get("k")
    gaps = None
    if search and ctx.m > 0:
        checking = keep & ~c.landing & ~c.done
        gaps = sample_gaps(ctx, c, sa, sb, y1, interp, stages, batched=ctx.batched,
                           checking=checking)
        retake = checking & ~gaps.resolved
        keep = keep & ~retake
        # (no derivative through a step size: see `program.init`)
        h_next = jnp.where(retake, jax.lax.stop_gradient(gaps.shrink * (sb - sa)), h_next)
    # The step's decisions, replayed when reverse mode runs the step again (`replay.py`).
    h_next, keep = decision(replay_decisions((h_next, keep), forced))
    return Step(
        sa, sb, s_end, y1, interp, stages, keep, finite1, h_next, solver_state1,
        controller_state1, gaps,
    )


def equilibrium_probe(ctx: LoopContext, sa, sb, y0, y1, y_error, targs):
    """The error estimate of a step that did not move the state: that of a perturbation.

    At an equilibrium (x0 = 0 for x'' = −x) every stage is zero, the error estimate is
    exactly zero and the controller grows the step tenfold per step, to steps far
    longer than the flow's time scale. The state is still exact there, but its
    derivatives are not: jacfwd of x'' = −x from 0 over 2π gave [[−16, −3.2],
    [3.2, −16]] instead of the identity. On such steps the controller is given the
    error of the same step from a state perturbed by atol/rtol: relative to atol, that
    is the perturbation's relative error over rtol, so nearby trajectories (and the
    Jacobian) are kept to the relative tolerance. (A direct evaluation, not a jvp:
    it works whatever loop kind the Runge–Kutta stages use.)
    """
    if not ctx.has_error:
        return y_error
    solver, term = ctx.solver, ctx.term
    still = jnp.all(y_error == 0) & jnp.all(y1 == y0)

    def probe():
        u = jnp.full_like(y0, ctx.tol_a / ctx.tol_r / jnp.sqrt(ctx.n))

        def error_of(y):
            state = solver.init(term, sa, sb, y, targs)
            return error_or_zero(solver.step(term, sa, sb, y, targs, state, True)[1], y)

        nearby_error = error_of(jax.lax.stop_gradient(y0) + u)
        return jnp.where(still, jax.lax.stop_gradient(jnp.abs(nearby_error)), y_error)

    return if_any_lane(still, probe, y_error)
