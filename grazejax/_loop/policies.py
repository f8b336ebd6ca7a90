"""What the loop does at a Zeno accumulation or a sticking contact: the policy classes and
the sliding phase of `ZenoStick` (compiled in only when that policy is chosen)."""

import abc
from typing import TYPE_CHECKING, ClassVar

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp

from .._geometry import contact_frame
from .._roots import bracketed_root, safe_divide
from .._status import ImpactKind, Status
from .compact import if_any_lane
from .state import write_log

if TYPE_CHECKING:
    from .context import LoopContext
    from .state import LoopState


class AbstractZenoPolicy(eqx.Module):
    """What `grazejax.simulate` does at a Zeno accumulation (impacts accumulating at a
    finite time) or at a tangential restart pushed into a surface (e.g. restitution 0).

    Pass an instance as `simulate(..., zeno=...)` or `sweep(..., zeno=...)`; the strings
    `"stop"` and `"stick"` mean `grazejax.ZenoStop` and `grazejax.ZenoStick`.

    The loop's phases call a policy's methods where the two differ (they take the loop's
    own context and state: hooks of the loop, not a user extension point): `start` at t0,
    `after_jumps` at every landing, `solver_step`, `find_release` and `release_newton`
    in every step.
    """

    # Whether the sliding phase is compiled into the loop (static structure, not a number).
    slides: eqx.AbstractClassVar[bool]

    @abc.abstractmethod
    def start(self, ctx: "LoopContext", x0, args, stuck0, resting0, status0, log):
        """A start at rest on a surface, pushed in (`stuck0`; `resting0`: on an
        impenetrable one). Returns `(x0, stick0, log, num_impacts0, status0, zeno_time0)`."""

    @abc.abstractmethod
    def after_jumps(
        self, ctx: "LoopContext", c: "LoopState", lands, s_event, t_event, x_post, restart,
        stuck_each, pushed_in, applied, applied_any,
    ):
        """The Zeno test (and sliding) at the post-impact state `x_post`. Returns
        `(restart, zeno, intervals, zeno_time, stick, x_post, event_row)`, `event_row` a
        log row (a start or end of sliding) or None."""

    def solver_step(self, ctx: "LoopContext", c: "LoopState", step_with, slides: bool, sb):
        """The solver's step to local time `sb`, `step_with(term)`, in the field the lanes'
        phases call for."""
        return step_with(ctx.free_term)

    def find_release(self, ctx: "LoopContext", c: "LoopState", sa, sb, y1, y_of, detecting):
        """The end of sliding in the step: `(release, t_release)`, or None where nothing
        slides."""
        return None

    def release_newton(self, ctx: "LoopContext", c: "LoopState", s_star, y_star, f_star,
                       newton, step):
        """The landing's Newton step at a release (`_loop/land.py`), or `step` unchanged."""
        return step


class ZenoStop(AbstractZenoPolicy):
    """End the run with `Status.ZENO` (the default).

    The predicted accumulation time is in `Solution.zeno_time`.
    """

    slides: ClassVar[bool] = False

    def start(self, ctx, x0, args, stuck0, resting0, status0, log):
        # On an impenetrable surface, pushed in: ZENO at t0 (as after a tangential
        # restart); on another the flight simply starts, into Φ < 0 (the paper's setting:
        # Φ < 0 is not forbidden, only met from above).
        resting0 = resting0 & (status0 == int(Status.SUCCESS))
        status0 = jnp.where(resting0, int(Status.ZENO), status0)
        zeno_time0 = jnp.where(resting0, ctx.t0, ctx.nan)
        return x0, jnp.zeros((ctx.m,), bool), log, jnp.array(0), status0, zeno_time0

    def after_jumps(self, ctx, c, lands, s_event, t_event, x_post, restart, stuck_each,
                    pushed_in, applied, applied_any):
        stuck = jnp.any(stuck_each)
        zeno, intervals, zeno_time = zeno_test(ctx, c, s_event, t_event, stuck, applied_any)
        return restart, zeno | stuck, intervals, zeno_time, c.stick, x_post, None


class ZenoStick(AbstractZenoPolicy):
    """Slide on the surface under the contact force the free flow calls for, and release
    when the free flow pulls away (Φ̈ ≥ 0); both moments are logged (`ImpactKind.STICK`,
    `ImpactKind.RELEASE`). Forward time only. See *Sticking* in docs/semantics.md.

    **Example:**

    ```python
    import grazejax as gj
    from grazejax.examples import vibrating_table

    args = {"g": 9.81, "e": 0.5, "A": 0.05, "omega": 10.0}
    sol = gj.simulate(vibrating_table(), [0.3, 0.0], 0.0, 3.0, args, zeno=gj.ZenoStick())
    ```
    """

    slides: ClassVar[bool] = True

    def start(self, ctx, x0, args, stuck0, resting0, status0, log):
        return stick_at_start(ctx, x0, args, stuck0, status0, ctx.nan, log)

    def after_jumps(self, ctx, c, lands, s_event, t_event, x_post, restart, stuck_each,
                    pushed_in, applied, applied_any):
        restart, stuck_each, released = keep_sliding(
            ctx, c, lands, t_event, x_post, restart, stuck_each
        )
        stuck = jnp.any(stuck_each)
        zeno, intervals, zeno_time = zeno_test(ctx, c, s_event, t_event, stuck, applied_any)
        zeno, stick, x_post, event_row, intervals = start_or_end_sliding(
            ctx, c, lands, t_event, x_post, zeno, stuck, stuck_each, pushed_in, applied,
            applied_any, released, intervals,
        )
        return restart, zeno, intervals, zeno_time, stick, x_post, event_row

    def solver_step(self, ctx, c, step_with, slides, sb):
        if not slides:
            return step_with(ctx.free_term)

        def sliding_step():
            y1, *rest = step_with(ctx.term)
            return (hold_on_contact(ctx, c, sb, y1), *rest)

        # The sliding field only while some lane slides: decided once per step, not per
        # stage (the field's own `cond`, evaluated in each of the 6–13 stages, made
        # zeno="stick" cost half as much again in runs that never slide). The free
        # field is the sliding field's no-lane-slides branch: results are unchanged.
        return lax.cond(
            eqxi.unvmap_any(jnp.any(c.stick)), sliding_step, lambda: step_with(ctx.free_term),
        )

    def find_release(self, ctx, c, sa, sb, y1, y_of, detecting):
        # Φ̈ of the slid-on surface at both ends, only while some lane slides (every step
        # would pay for it in runs that never slide).
        def release_test():
            return locate_release(ctx, c, sa, sb, y1, y_of, detecting)

        def no_release():
            return jnp.array(False), jnp.array(jnp.inf, ctx.dtype)

        return lax.cond(eqxi.unvmap_any(detecting & jnp.any(c.stick)), release_test, no_release)

    def release_newton(self, ctx, c, s_star, y_star, f_star, newton, step):
        # The same Newton step on the free Φ̈ of the sliding surface, along the sliding
        # flow, so that jacfwd gets the release time's tangent (first order).
        t_hi, t_lo, args_ = c.t_hi, c.t_lo, c.args

        def release_step():
            r, r_dot = jax.jvp(
                lambda s_, y_: ctx.sliding_pull(c.stick, s_, y_, t_hi, t_lo, args_),
                (s_star, y_star), (jnp.ones_like(s_star), f_star),
            )
            return newton(c.releasing, r, r_dot, jnp.zeros_like(r), step)

        return if_any_lane(c.releasing, release_step, step)


_BY_NAME = {"stop": ZenoStop, "stick": ZenoStick}


def as_zeno_policy(zeno) -> AbstractZenoPolicy:
    """A policy from a policy or its name (`"stop"`, `"stick"`: kept for existing code)."""
    if isinstance(zeno, AbstractZenoPolicy):
        return zeno
    if isinstance(zeno, str) and zeno in _BY_NAME:
        return _BY_NAME[zeno]()
    raise ValueError(
        f"zeno must be 'stop' or 'stick' (or grazejax.ZenoStop(), grazejax.ZenoStick()), "
        f"got {zeno!r}"
    )


# --------------------------------------------------------------------------------------
# The sliding phase (ZenoStick)
# --------------------------------------------------------------------------------------


def sliding_phases(cond, step, free_step, slides):
    """A loop body that runs `free_step` while `cond` holds and nothing `slides`, then
    `step` while `cond` holds and something does: a `ZenoStick` loop pays for the sliding
    tests only while a lane slides (`simulate`'s and `sweep`'s loops)."""

    def phases(state):
        state = lax.while_loop(lambda z: cond(z) & ~slides(z), free_step, state)
        return lax.while_loop(lambda z: cond(z) & slides(z), step, state)

    return phases


def sliding_field(vector_field, pieces, t, y, args_, stick, free):
    """f + λd on the surfaces slid on (see *Sticking* in docs/semantics.md); the constrained field
    is evaluated only while some lane slides."""

    def constrained():
        out = free
        for i, piece in enumerate(pieces):
            _, _, gdd, _, grad_gd, d = contact_frame(piece.gap, piece.jump, vector_field, t, y, args_)
            gain = jnp.dot(grad_gd, d)  # d(Φ̈)/dλ
            force = -safe_divide(gdd, gain, stick[i] & (gain != 0)) * d
            out = out + jnp.where(stick[i], force, 0.0)
        return out

    return if_any_lane(jnp.any(stick), constrained, free)


def hold_on_contact(ctx: "LoopContext", c: "LoopState", sb, y1):
    """A sliding lane's step end moved back onto its contact manifold M = {Φ = 0, Φ̇ = 0}.

    The sliding field holds Φ̈ = 0 only up to the step's truncation error and rounding
    (f + λd cancels the normal acceleration in floating point, and how it rounds depends
    on how XLA fuses it), so an uncorrected sliding state drifts off M, like t² from a
    constant residual: a ball resting on its floor sinks into it. Projected at every step
    end (the projection `stick_at_start` uses), the drift stays at one step's error. On M
    the projection's derivative is the projector onto M's tangent space, which the
    sliding flow's tangents already lie in: derivatives are unchanged to first order."""
    return ctx.project_onto_contacts(c.stick, ctx.abs_time(sb, c.t_hi, c.t_lo), y1, c.args)


def stick_at_start(ctx: "LoopContext", x0, args, stuck0, status0, zeno_time0, log):
    """A start at rest on a surface, pushed in: sliding from t0 (or ZENO at t0 if on two
    surfaces)."""
    t0 = ctx.t0
    stuck_any = jnp.any(stuck0)
    starts = stuck_any & (jnp.sum(stuck0) == 1)
    stick0 = stuck0 & starts
    x_on = ctx.project_onto_contacts(stick0, t0, x0, args)
    log = write_log(log, 0, starts, t0, x0, x_on, jnp.argmax(stick0), int(ImpactKind.STICK))
    num_impacts0 = starts.astype(jnp.array(0).dtype)
    status0 = jnp.where(stuck_any & ~starts, int(Status.ZENO), status0)
    zeno_time0 = jnp.where(stuck_any, t0, zeno_time0)
    return x_on, stick0, log, num_impacts0, status0, zeno_time0


def locate_release(ctx: "LoopContext", c: "LoopState", sa, sb, y1, y_of, detecting):
    """The end of sliding in this step: the free flow's Φ̈ on the sliding surface reaches
    0 from below. Returns `(release, t_release)`: found in the step, and its local time.

    As for the gap's dips (diffrax #507), a sign test at the step's ends is not enough: a
    state sliding at rest has a zero error estimate, its steps grow tenfold each, and Φ̈
    can rise above 0 and fall back inside one step (found: a forced oscillator resting on
    its stop slid through a whole forcing period, `test_forced_oscillator_chatters_...`).
    So an interior maximum of Φ̈ (its rate going from > 0 to < 0) is located too, and is
    a release if Φ̈ reaches 0 there.
    """
    args_ = c.args

    def pull(s_, y_):
        return ctx.sliding_pull(c.stick, s_, y_, c.t_hi, c.t_lo, args_)

    def pull_along(s_):
        return pull(s_, y_of(s_))

    def rate(s_):
        return jax.jvp(pull_along, (s_,), (jnp.ones_like(s_),))[1]

    sliding = detecting & jnp.any(c.stick)
    pull_a, pull_b = pull(sa, c.y), pull(sb, y1)
    rate_a, rate_b = rate(sa), rate(sb)
    at_end = sliding & (pull_b >= 0)
    peak = sliding & (pull_a < 0) & (pull_b < 0) & (rate_a > 0) & (rate_b < 0)

    def bracket():
        # The maximum of Φ̈ (root of its rate, from > 0 to < 0); inactive lanes get an
        # empty bracket, so they cost no iterations under vmap.
        _, s_max = bracketed_root(rate, jnp.where(peak, sa, sb), sb, rate_a, rate_b,
                                  finder=ctx.event_root_finder)
        s_max = jnp.where(peak, s_max, sb)
        pull_max = jnp.where(peak, pull_along(s_max), pull_b)
        release = at_end | (peak & (pull_max >= 0))
        # bracketed_root wants f(lo) > 0 >= f(hi): search the sign change of −Φ̈;
        # `hi` is the first point at or past it, so the state leaves pulled away.
        lo = jnp.where(release & (pull_a < 0), sa, s_max)
        _, hi = bracketed_root(lambda s_: -pull_along(s_), lo, s_max, -pull_a, -pull_max,
                               finder=ctx.event_root_finder)
        return release, hi

    release, t_release = lax.cond(
        eqxi.unvmap_any(at_end | peak), bracket, lambda: (jnp.zeros_like(at_end), sb)
    )
    t_release = jax.lax.stop_gradient(jnp.where(release, t_release, jnp.inf))
    return release, t_release


def keep_sliding(ctx: "LoopContext", c: "LoopState", lands, t_event, x_post, restart, stuck_each):
    """Sliding at the post-impact state: a release is not a new sticking, and a lane that
    slid on one surface while it hit another keeps sliding if not thrown off."""
    args_ = c.args
    # A release lands on a tangential state with Φ̈ ≈ 0: not a new sticking.
    released = c.stick & c.releasing & lands
    stuck_each = stuck_each & ~released
    restart = restart | released
    # An impact on another surface while sliding: the state is still on the surface
    # it slid on, up to the sliding flow's drift (solver tolerance, not round-off,
    # so the on-surface floor cannot tell); it keeps sliding if not thrown off it.
    was_on = c.stick & lands & ~c.releasing

    def stays_on(stuck_each):
        for i, piece in enumerate(ctx.pieces):
            _, gd, gdd, _, grad_gd, _ = ctx.contact_geometry(piece, t_event, x_post, args_)
            drift = jnp.sum(jnp.abs(grad_gd) * ctx.state_tol(x_post))
            stays = was_on[i] & (gd <= drift) & (gdd < 0)
            stuck_each = stuck_each.at[i].set(stuck_each[i] | stays)
        return stuck_each

    stuck_each = if_any_lane(jnp.any(was_on), lambda: stays_on(stuck_each), stuck_each)
    restart = restart | was_on
    return restart, stuck_each, released


def zeno_test(ctx: "LoopContext", c: "LoopState", s_event, t_event, stuck, applied_any):
    """Zeno: geometric shrinking of the inter-impact times. Returns
    `(zeno, intervals, zeno_time)`."""
    interval = jax.lax.stop_gradient(s_event)
    intervals = jnp.concatenate([c.intervals[1:], interval[None]])
    d0, d1, d2 = intervals[0], intervals[1], intervals[2]
    r_prev = safe_divide(d1, d0, d0 > 0)
    r_last = safe_divide(d2, d1, d1 > 0)
    geometric = (r_last > 0) & (r_last < 1) & (jnp.abs(r_last - r_prev) <= 0.05 * r_last)
    remaining = safe_divide(d2 * r_last, 1 - r_last, r_last < 1)
    elapsed = jnp.abs(t_event - ctx.t0)
    zeno = geometric & (remaining <= ctx.zeno_rtol * elapsed)
    t_resolution = ctx.h_min_at(t_event, c.time_scale)
    zeno = zeno | (interval <= t_resolution) & (c.num_impacts > 0)
    zeno = zeno & applied_any  # (a release is not an impact)
    zeno_time = jnp.where(
        zeno, t_event + ctx.sigma * remaining, jnp.where(stuck, t_event, c.zeno_time)
    )
    return zeno, intervals, zeno_time


def start_or_end_sliding(
    ctx: "LoopContext", c: "LoopState", lands, t_event, x_post, zeno, stuck, stuck_each,
    pushed_in, applied, applied_any, released, intervals,
):
    """Slide on the surface just hit (or found stuck) if the free flow pushes into it; on
    two surfaces at once there is no sliding rule: stop (ZENO).

    Returns `(zeno, stick, x_post, event_row, intervals)`; `event_row` is the log row of a
    start (STICK) or end (RELEASE) of sliding.
    """
    args_ = c.args
    want = stuck_each | (zeno & jnp.array(applied) & pushed_in)
    starts = lands & applied_any & (jnp.sum(want) == 1)
    zeno = (zeno | stuck) & ~starts
    stick = jnp.where(starts, want, jnp.where(lands & (c.releasing | applied_any), False, c.stick))
    moves = (starts & want) | released

    x_moved = if_any_lane(
        jnp.any(moves), lambda: ctx.project_onto_contacts(moves, t_event, x_post, args_), x_post
    )
    event_row = (
        starts | jnp.any(released), x_post, x_moved,
        jnp.argmax(want | released),
        jnp.where(starts, int(ImpactKind.STICK), int(ImpactKind.RELEASE)),
    )
    # A new sequence of impacts after sliding: forget the old intervals.
    intervals = jnp.where(starts | c.releasing, jnp.nan, intervals)
    return zeno, stick, x_moved, event_row, intervals
