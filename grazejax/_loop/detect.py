"""The search for a contact inside an accepted step (see `events.py` for the tests, and
`gaps.py` for the samples of the gap they read)."""

import functools
from typing import Any, NamedTuple

import jax
import jax.lax as lax
import jax.numpy as jnp
from jaxtyping import Array, Bool

from .._custom_types import BoolScalar, RealScalar
from .compact import per_lane
from .context import LoopContext
from .envelope import lower_bound
from .events import Contact, locate
from .gaps import step_floor
from .state import LoopState
from .step import Step


class Detection(NamedTuple):
    """What the in-step search found in a step; only meaningful where `detecting`."""

    detecting: BoolScalar  # a normally accepted step (not a landing, lane not finished)
    event: BoolScalar  # a contact (or a release) was found: the step is retaken up to it
    first: RealScalar  # local time of the earliest one
    pending: Bool[Array, "m signs"]  # the surfaces (and sides) met at `first`
    touch: Bool[Array, "m signs"]  # tangential contacts
    boundary: Bool[Array, "m signs"]  # contacts on ∂Γ
    releasing: BoolScalar  # the event is the end of sliding
    # the curvature bound proves no earlier contact before each pending one
    # (`_verified`); where not, the step is retaken shorter instead of landing
    verified: BoolScalar


def detect(ctx: LoopContext, c: LoopState, step: Step, slides: bool = True) -> Detection:
    """The contacts (and, with `slides`, the end of sliding) inside an accepted step."""
    sa, sb, y1 = step.sa, step.sb, step.y1
    detecting = step.keep & ~c.landing & ~c.done
    if ctx.m > 0:
        gaps = step.gaps
        candidate = detecting & gaps.any_candidate
        # Only the lanes with a candidate pay for the searches under vmap (`compact.py`).
        inputs = SearchInputs(
            step.interp, step.y1, c.args, c.t_hi, c.t_lo, c.restart, c.flight_scale,
            gaps.ends, gaps.bounds, gaps.candidate, gaps.curvature,
        )
        found, times, touch, boundary, verified = per_lane(
            functools.partial(_search, ctx), candidate, inputs,
            lambda _: _nothing_found(ctx),
        )
        found = found & candidate & ~c.stick[:, None]
    else:
        found, times, touch, boundary, verified = _nothing_found(ctx)
    times = jnp.where(found, times, jnp.inf)
    event = jnp.any(found)
    # (A scene without surfaces is a plain ODE solve: no contact, ever.)
    first = jax.lax.stop_gradient(jnp.min(times)) if ctx.m > 0 else jnp.array(jnp.inf, ctx.dtype)
    releasing = jnp.array(False)
    found_release = None
    if slides:  # (the end of sliding, where the policy slides: `find_release`)
        found_release = ctx.policy.find_release(ctx, c, sa, sb, y1, step.interp.evaluate,
                                                detecting)
    if found_release is not None:
        release, t_release = found_release
        releasing = release & (t_release <= first)
        first = jnp.minimum(first, t_release)
        event = event | release
    simultaneous = 1e3 * ctx.eps * (jnp.abs(first) + (sb - sa))
    pending = found & (times <= first + simultaneous) & ~releasing
    verified = jnp.all(verified | ~pending)
    return Detection(detecting, event, first, pending, touch, boundary, releasing, verified)


class SearchInputs(NamedTuple):
    """What the search of one lane reads: the step's dense output, its clock and the
    sampled gaps (`gaps.GapSamples`)."""

    interp: Any  # the step's dense output
    y1: Array  # the step's end state
    args: Any
    t_hi: RealScalar
    t_lo: RealScalar
    restart: Bool[Array, " m"]
    flight_scale: Array
    ends: tuple  # per piece, per side: the parts' `StepEnds`
    bounds: tuple  # the parts' ends, from sa to sb
    candidate: tuple  # per piece, per side, per part: it may hold a contact
    curvature: tuple  # per piece, per side: the gap's curvature bound (θ units)


def _search(ctx: LoopContext, inputs: SearchInputs):
    """Locate the first contact of every piece and side in the step: `(found, times,
    touch, boundary)`, each [m, signs]."""
    args_, t_hi, t_lo = inputs.args, inputs.t_hi, inputs.t_lo
    y_of = inputs.interp.evaluate
    mask_shape = ctx.mask_shape
    found = jnp.zeros(mask_shape, bool)
    verified = jnp.ones(mask_shape, bool)
    times = jnp.full(mask_shape, jnp.inf, ctx.dtype)
    touch = jnp.zeros(mask_shape, bool)
    boundary = jnp.zeros(mask_shape, bool)
    for i, piece in enumerate(ctx.pieces):
        for k, (sign, parts) in enumerate(zip(piece.signs, inputs.ends[i], strict=True)):
            g = ctx.gap_along(piece, sign, y_of, t_hi, t_lo, args_)

            def inside(s, piece=piece):
                return piece.inside(ctx.abs_time(s, t_hi, t_lo), y_of(s), args_, ctx.state_tol)

            sa, sb = inputs.bounds[0], inputs.bounds[-1]
            floor = step_floor(ctx, piece, t_hi, t_lo, args_, inputs.flight_scale, sa, sb,
                               inputs.y1, parts[0].slope_start, parts[-1].slope_end)
            curvature = inputs.curvature[i][k] / (sb - sa) ** 2  # (θ units to s units)
            contact, on_boundary, sure = _first_contact(
                g, inside, parts, inputs.bounds, inputs.restart[i], floor,
                inputs.candidate[i][k], ctx.event_root_finder, curvature,
            )
            verified = verified.at[i, k].set(sure)
            found = found.at[i, k].set(contact.found)
            times = times.at[i, k].set(jnp.where(contact.found, contact.time, jnp.inf))
            touch = touch.at[i, k].set(contact.touch)
            boundary = boundary.at[i, k].set(on_boundary)
    return found, times, touch, boundary, verified


def _first_contact(g, inside, parts, bounds, restart, floor, flags, finder, curvature):
    """The first contact inside the piece, over the step's parts in time order:
    `(Contact, on ∂Γ)`. A part that `is_candidate` did not flag is not searched; a dip
    that stays above the floor, or a contact outside the piece, moves on to the next
    flagged part. (One copy of `locate` in a loop over the parts, not one per part: its
    root searches are the largest part of the program.) The third result says whether
    the curvature bound proves the contact the part's first (`_verified`).

    A restart state is on its surface to within the floor, not exactly: g(sa) may be up
    to a floor above 0. The guard G(s) = g(s)/(s − sa) removes a root at sa only, so a
    flight that leaves into Φ < 0 from g(sa) > 0 still has g's root ulps after sa. In the
    first part the guard hides it (G(sa) = ġ(sa) ≤ 0: no crossing is tested for); a later
    part starts from a value with g's sign, and there the same root read as a new
    crossing wherever the step was short (a run's last step, clipped at t1, re-fired every
    surface met a few ulps apart: SciML's `event_repeat`). So on a restart step that left
    downward, a later part that starts on the free side within the round-off band of the
    start (g ≤ max(g(sa), 0) + floor), still moving in, holds only the start's own root
    (a flight that rose out of the band, or turned back up, is still searched)."""
    sa, sb = bounds[0], bounds[-1]
    count = len(parts)
    flags = jnp.stack(flags)
    lows, highs = jnp.stack(bounds[:-1]), jnp.stack(bounds[1:])
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *parts)

    def next_flagged(j):
        """The first flagged part at or after j (`count` where none)."""
        later = flags & (jnp.arange(count) >= j)
        return jnp.where(jnp.any(later), jnp.argmax(later), count)

    def searching(carry):
        j, contact, _, _ = carry
        return (j < count) & ~contact.found

    band = jnp.maximum(g(sa), 0.0) + floor
    left_downward = restart & (parts[0].g_start <= 0)

    def search(carry):
        j, _, _, _ = carry
        e = jax.tree.map(lambda x: x[j], stacked)
        contact = locate(g, sa, lows[j], highs[j], e, restart, floor, finder)
        in_piece, on_boundary = inside(contact.time)
        g_lo = g(lows[j])
        start_root = left_downward & (j > 0) & (g_lo > 0) & (g_lo <= band) & (e.slope_start <= 0)
        contact = contact._replace(found=contact.found & in_piece & ~start_root)
        sure = _verified(g, e.s_start, contact, restart & (j == 0), floor, curvature)
        return next_flagged(j + 1), contact, on_boundary, sure

    no = jnp.array(False)
    _, contact, on_boundary, sure = lax.while_loop(
        searching, search, (next_flagged(0), Contact(no, sb, no), no, jnp.array(True))
    )
    return contact, on_boundary, sure | ~contact.found


def _verified(g, s_start, contact, starts_on_surface, floor, curvature):
    """Whether the curvature bound proves that g stays above −floor on the part from
    `s_start` to the contact located in it (`envelope.lower_bound` with the gap's value
    and rate at both ends): a part flagged by its end tests may hold several roots, and
    the root search returns one of them, not necessarily the first. Touches (the minimum
    of a dip within the floor) are taken as found. Parts that start inside Φ < 0 (humps)
    have no earlier contact to miss before they rise."""
    g0, d0 = jax.jvp(g, (s_start,), (jnp.ones_like(s_start),))
    gt, dt = jax.jvp(g, (contact.time,), (jnp.ones_like(contact.time),))
    width = jnp.maximum(contact.time - s_start, 0.0)
    whole, after_start = lower_bound(g0, gt, d0, dt, width, curvature)
    low = jnp.where(starts_on_surface, after_start, whole)
    from_free_side = jnp.where(starts_on_surface, d0 > 0, g0 > 0)
    slack_small = 0.125 * curvature * width * width <= floor
    return ~contact.found | contact.touch | ~from_free_side | slack_small | (low >= -floor)


def nothing_detected(ctx: LoopContext) -> Detection:
    """The `Detection` of a step that does not search (a landing step)."""
    found, _, touch, boundary, _ = _nothing_found(ctx)
    no = jnp.array(False)
    return Detection(no, no, jnp.array(jnp.inf, ctx.dtype), found, touch, boundary, no,
                     jnp.array(True))


def _nothing_found(ctx: LoopContext):
    mask_shape = ctx.mask_shape
    return (
        jnp.zeros(mask_shape, bool), jnp.full(mask_shape, jnp.inf, ctx.dtype),
        jnp.zeros(mask_shape, bool), jnp.zeros(mask_shape, bool), jnp.ones(mask_shape, bool),
    )
