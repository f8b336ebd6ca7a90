"""The landing step: the step [sa, target] has just been taken exactly; correct the event
time by one Newton step, apply the jumps, test the post-impact state and write the log."""

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp

from .._geometry import FLOOR_ULPS, is_tangential
from .._roots import safe_divide
from .._status import Status
from .._tangents import undefined_derivative
from .compact import per_lane
from .context import LoopContext
from .field import field_jumps
from .state import (
    LoopState,
    dd_add,
    impact_log,
    log_row_offset,
    with_buffers,
    with_impact_log,
    without_buffers,
    write_log_rows,
)
from .step import Step


def land_if_due(ctx: LoopContext, c: LoopState, step: Step, landing: bool | None = None):
    """The state after a landing step (buffers included), the event time and the local time
    up to which the step's dense output is saved; `c` unchanged if no lane lands.
    `landing`: whether some lane lands (`program.lands`), where the caller knows it."""
    # The branch returns only small values: the log and save buffers are written below,
    # outside the cond, one row at a time (threading them through the cond made every
    # iteration copy them: cost grew with max_impacts and len(saveat)).
    def land(operands):
        small, y_star, sa, s_star = operands
        return _land(ctx, small, y_star, sa, s_star)

    def no_land(operands):
        return _no_landing(ctx, operands[0])

    lands = c.landing & ~c.done
    operands = (without_buffers(c), step.y1, step.sa, step.sb)
    if ctx.m == 0 or landing is False:
        landed_small, rows, t_event, s_save = no_land(operands)
    elif landing:
        landed_small, rows, t_event, s_save = land(operands)
    elif ctx.kinds.outer == "lax":
        # Only the landing lanes pay for the landing under vmap (`compact.py`; a
        # differentiated call runs it uncompacted). Reverse-mode loops keep the plain
        # cond: a custom batching rule has no transpose.
        landed_small, rows, t_event, s_save = per_lane(
            land, lands, operands, no_land, differentiable=True
        )
    else:
        landed_small, rows, t_event, s_save = lax.cond(
            eqxi.unvmap_any(lands), land, no_land, operands
        )
    log = impact_log(c)
    row = c.num_impacts + log_row_offset(c)
    log = write_log_rows(log, row, t_event, rows, skip_unwritten=ctx.batched)
    landed = with_impact_log(with_buffers(landed_small, c), log)
    return landed, t_event, s_save


def _no_landing(ctx: LoopContext, small: LoopState):
    n, dtype = ctx.n, ctx.dtype
    slots = ctx.log_rows_per_landing
    rows = (
        jnp.zeros((slots,), bool), jnp.zeros((slots, n), dtype), jnp.zeros((slots, n), dtype),
        jnp.zeros((slots,), jnp.asarray(0).dtype), jnp.zeros((slots,), jnp.asarray(0).dtype),
    )
    return small, rows, jnp.zeros((), dtype), jnp.array(-jnp.inf, dtype)


def _land(ctx: LoopContext, c: LoopState, y_star, sa, s_star):
    args_ = c.args
    t_hi, t_lo = c.t_hi, c.t_lo
    lands = c.landing & ~c.done
    # Round-off in the event state is relative to the magnitudes met in this flight, not
    # to the (possibly tiny) state at the contact: a touch at x ≈ 0, v ≈ 0 still carries
    # the absolute error of the flight that led there.
    flight_scale = jnp.maximum(c.flight_scale, jnp.abs(y_star))
    # ... and to the length of the landing step, as in the detection floor.
    step_ulps = FLOOR_ULPS * ctx.eps * jax.lax.stop_gradient(s_star - sa)
    s_event, y_event = _newton_event_time(ctx, c, y_star, sa, s_star)
    t_event_hi, t_event_lo = dd_add(t_hi, t_lo, ctx.sigma * s_event)
    t_event = t_event_hi + t_event_lo

    near = _met_together(ctx, c, t_event, y_event, flight_scale, step_ulps)
    x_post, count, applied_any, bad_side, rows, applied = _apply_jumps(
        ctx, c, lands, s_event, t_event, y_event, near, flight_scale, step_ulps
    )
    num_impacts = c.num_impacts + count

    # Restart guard and sticking test at the post-impact state.
    x_scale = jnp.maximum(flight_scale, jnp.abs(x_post))
    restart, stuck_each, pushed_in = ctx.contact_tests(
        t_event_hi, t_event_lo, x_post, args_, x_scale, step_ulps
    )
    # A jump that contradicts *another* impenetrable surface than its own (its own is
    # tested as it is applied): the state after all of the landing's jumps, in the same
    # clock and scale as the tests above, so that the two share Φ, Φ̇, Φ̈.
    enters, _ = ctx.impenetrable_contact(t_event, jnp.zeros_like(t_event), t_event_hi,
                                         t_event_lo, x_post, args_, x_scale, step_ulps,
                                         x_before=y_event)
    bad_side = bad_side | (applied_any & enters)
    restart, zeno, intervals, zeno_time, stick, x_post, event_row = ctx.policy.after_jumps(
        ctx, c, lands, s_event, t_event, x_post, restart, stuck_each, pushed_in, applied,
        applied_any,
    )
    if event_row is not None:  # (a start or end of sliding)
        rows.append(event_row)
        num_impacts = num_impacts + event_row[0]

    # The field the next flight starts in must not jump at its first state (the sign(·)
    # trap, `field.py`): compiled only if asked for (the default).
    field_jump = jnp.array(False)
    if ctx.check_field_jumps:
        field_jump = field_jumps(ctx.vector_field, t_event, x_post, args_, x_scale)
    small = _after_landing(
        ctx, c, lands, s_event, t_event, t_event_hi, t_event_lo, y_event, x_post, bad_side,
        field_jump, zeno, num_impacts, restart, intervals, zeno_time, stick,
    )
    # Left-continuity with respect to the *logged* impact time: save up to s_event plus
    # the rounding of t_event, so `saveat=[t_impact]` returns the pre-impact state.
    s_save = jnp.where(lands, s_event + 4 * ctx.eps * jnp.abs(t_event), -jnp.inf)
    rows = jax.tree.map(lambda *r: jnp.stack(r), *rows)
    return without_buffers(small), rows, t_event, s_save


def _newton_event_time(ctx: LoopContext, c: LoopState, y_star, sa, s_star):
    """One Newton step on the time, with the true vector field: corrects the
    interpolant's root to the method's accuracy and carries d(time)/d(params) by
    the implicit function theorem. Driven by the first pending surface.

    One Newton step from a root without derivatives gives the event time's first
    derivatives; its second ones lack the gap's curvature along the flow, −g̈ δ̇²/ġ, and
    the event state's lack ẍ δ̇² (δ̇ the correction's tangent, the time's). Both are added
    through q = (δ − δ)², the second δ held constant: its value and first derivative are
    exactly 0, its second 2δ̇². Derivatives of derivatives (a monodromy's, in the
    parameters) are then right to second order, while values and first derivatives stay
    bit for bit those of one Newton step.
    """
    args_, t_hi, t_lo = c.args, c.t_hi, c.t_lo
    field_args = (args_, t_hi, t_lo, c.stick)
    f_star = ctx.term.vector_field(s_star, y_star, field_args)
    # Accept corrections up to 1% of the landing step, but never less than ~1e-6 of the
    # flight: a step can end ulps before the contact, and the next one then lands after
    # a few ulps of width.
    width = jax.lax.stop_gradient(jnp.maximum(s_star - sa, 1e-6 * s_star))

    def newton(use, value, slope, curvature, step):
        delta, bend = step
        small = jnp.abs(jax.lax.stop_gradient(value)) <= 1e-2 * jnp.abs(jax.lax.stop_gradient(slope)) * width
        ok = use & small & (slope != 0)
        return (jnp.where(ok, -safe_divide(value, slope, ok), delta),
                jnp.where(ok, -0.5 * safe_divide(curvature, slope, ok), bend))

    step = (jnp.zeros_like(s_star), jnp.zeros_like(s_star))
    chosen = jnp.array(False)
    for i, piece in enumerate(ctx.pieces):
        for k, sign in enumerate(piece.signs):
            g, gd, gdd = ctx.slopes_at(piece, sign, s_star, y_star, t_hi, t_lo, args_)
            use = c.pending[i, k] & ~c.touch[i, k] & ~chosen
            step = newton(use, g, gd, gdd, step)
            chosen = chosen | use
    step = ctx.policy.release_newton(ctx, c, s_star, y_star, f_star, newton, step)
    delta, bend = step
    # (no multiplication in δ − δ: its value is exactly 0 whatever the compiler fuses)
    q = (delta - jax.lax.stop_gradient(delta)) ** 2
    _, f_dot = jax.jvp(lambda s_, y_: ctx.term.vector_field(s_, y_, field_args),
                       (s_star, y_star), (jnp.ones_like(s_star), f_star))
    s_event = s_star + delta + bend * q
    y_event = y_star + f_star * (delta + bend * q) + 0.5 * f_dot * q
    # At a tangential contact the event time is not differentiable (it moves like the
    # square root of a parameter on one side, not at all on the other): its derivatives,
    # and the state's, are NaN there, never the 0 of a Newton step that was not taken.
    touching = jnp.any(c.pending & c.touch)
    return jax.tree.map(lambda v: undefined_derivative(v, touching), (s_event, y_event))


def _met_together(ctx: LoopContext, c: LoopState, t_event, y_event, flight_scale, step_ulps):
    """Pieces met together within round-off: a piece the in-step search did not report
    (its own crossing lies within the contact floor of this event, e.g. surfaces a few
    ulps apart) is hit now too if the state is on it and approaching it. Without this,
    the flight after the jump would start "on" it, moving in, and never impact.

    Returns, per piece, (on it and inside its closed piece, on its boundary, inside its
    closed piece)."""
    near = []
    for i, piece in enumerate(ctx.pieces):
        on, _ = ctx.on_surface(piece, t_event, y_event, c.args, flight_scale, step_ulps)
        in_piece, on_boundary = piece.inside(t_event, y_event, c.args, ctx.state_tol)
        near.append((on & in_piece & ~c.stick[i], on_boundary, in_piece))
    return near


def _apply_jumps(ctx: LoopContext, c: LoopState, lands, s_event, t_event, y_event, near,
                 flight_scale, step_ulps):
    """Apply the jumps in surface order, each only if its surface is still approached
    after the previous ones. Returns `(x_post, count, applied_any, bad_side, rows,
    applied)`: `rows` one log row per (surface, side), `applied` per surface."""
    args_, t_hi, t_lo = c.args, c.t_hi, c.t_lo
    impact_kinds = ctx.impact_kinds
    x = y_event
    count = jnp.array(0)
    applied_any = jnp.array(False)
    bad_side = jnp.array(False)
    rows = []  # one per (surface, side): (apply, pre, post, surface, kind)
    applied = []  # per surface
    for i, piece in enumerate(ctx.pieces):
        applied.append(jnp.array(False))
        for k, sign in enumerate(piece.signs):
            _, gd, _ = ctx.slopes_at(piece, sign, s_event, x, t_hi, t_lo, args_)
            approaching = (gd < 0) | c.touch[i, k]
            # `lands` folded in here so that the log is written row-wise only: a
            # whole-array select of the log every iteration dominated batched runs.
            # (a piece already pending on one side is not hit again on its other side)
            # The search judged the piece (`where`) on the step's interpolant; the event
            # state is the landing step's, which can lie outside a piece the interpolant
            # was inside of (by 1e-6 on a long Dopri8 step): it is judged again here, and
            # a contact outside the piece is no impact (the flight goes on through it).
            pending = c.pending[i, k] & near[i][2]
            hit = pending | (near[i][0] & (gd < 0) & ~jnp.any(c.pending[i]))
            apply = lands & hit & (~applied_any | approaching)
            x_new = piece.jump(t_event, x, args_)
            on_boundary = jnp.where(pending, c.boundary[i, k], near[i][1])
            kind = jnp.where(
                c.touch[i, k], int(impact_kinds[2]), jnp.where(on_boundary, int(impact_kinds[1]), int(impact_kinds[0]))
            )
            rows.append((apply, x, x_new, jnp.asarray(i), kind))
            x_scale = jnp.maximum(flight_scale, jnp.abs(x_new))
            if piece.check_jump_side:
                g_new, gd_new, gdd_new = ctx.slopes_at(piece, sign, s_event, x_new, t_hi, t_lo, args_)
                floor = piece.floor(t_event, x_new, args_, x_scale) + step_ulps * jnp.abs(
                    jax.lax.stop_gradient(gd)
                )
                moving_in = (gd_new < 0) & ~is_tangential(gd_new, gdd_new, floor)
                # Deeper than the event state itself (on the surface only to the event's
                # accuracy; see `LoopContext.impenetrable_contact`).
                g_event = sign * piece.gap(t_event, y_event, args_)
                deeper = g_new - jnp.minimum(g_event, 0.0) < -floor
                bad_side = bad_side | (apply & (deeper | ((g_new <= floor) & moving_in)))
            x = jnp.where(apply, x_new, x)
            count = count + apply
            applied_any = applied_any | apply
            applied[i] = applied[i] | apply
    return x, count, applied_any, bad_side, rows, applied


def _after_landing(ctx: LoopContext, c: LoopState, lands, s_event, t_event, t_event_hi,
                   t_event_lo, y_event, x_post, bad_side, field_jump, zeno, num_impacts,
                   restart, intervals, zeno_time, stick) -> LoopState:
    """The state to restart from: the event as the new origin of the local clock, the
    post-impact state, and the run's status (lanes that do not land keep theirs)."""
    finite = jnp.all(jnp.isfinite(x_post))
    status = jnp.where(
        ~finite, int(Status.NONFINITE),
        jnp.where(bad_side, int(Status.BAD_JUMP),
        jnp.where(field_jump, int(Status.FIELD_DISCONTINUITY),
        jnp.where(zeno, int(Status.ZENO),
        jnp.where(num_impacts >= ctx.max_impacts, int(Status.MAX_IMPACTS), int(Status.SUCCESS))))),
    )
    stop = status != int(Status.SUCCESS)
    keep_old = lambda new, old: jnp.where(lands, new, old)  # noqa: E731
    return eqx.tree_at(
        lambda z: (
            z.s, z.t_hi, z.t_lo, z.y, z.h, z.made_jump, z.restart, z.flight_scale, z.num_impacts,
            z.intervals, z.zeno_time, z.status, z.done, z.t_final, z.x_final, z.stick,
            z.releasing,
        ),
        c,
        (
            keep_old(jnp.zeros_like(s_event), c.s),
            keep_old(t_event_hi, c.t_hi),
            keep_old(t_event_lo, c.t_lo),
            keep_old(jnp.where(finite, x_post, y_event), c.y),
            keep_old(c.h_after, c.h),
            keep_old(True, c.made_jump),
            keep_old(restart, c.restart),
            keep_old(jnp.abs(jnp.where(finite, x_post, y_event)), c.flight_scale),
            keep_old(num_impacts, c.num_impacts),
            keep_old(intervals, c.intervals),
            keep_old(zeno_time, c.zeno_time),
            keep_old(status, c.status),
            keep_old(stop, c.done),
            keep_old(t_event, c.t_final),
            keep_old(jnp.where(finite, x_post, y_event), c.x_final),
            keep_old(stick, c.stick),
            keep_old(False, c.releasing),
        ),
    )

