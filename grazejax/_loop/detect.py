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
            gaps.ends, gaps.bounds, gaps.candidate,
        )
        found, times, touch, boundary = per_lane(
            functools.partial(_search, ctx), candidate, inputs,
            lambda _: _nothing_found(ctx),
        )
        found = found & candidate & ~c.stick[:, None]
    else:
        found, times, touch, boundary = _nothing_found(ctx)
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
    return Detection(detecting, event, first, pending, touch, boundary, releasing)


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
    ends: tuple  # per piece, per side: the halves' `StepEnds`
    bounds: tuple  # (sa, midpoint, sb)
    candidate: tuple  # per piece, per side, per half: it may hold a contact


def _search(ctx: LoopContext, inputs: SearchInputs):
    """Locate the first contact of every piece and side in the step: `(found, times,
    touch, boundary)`, each [m, signs]."""
    args_, t_hi, t_lo = inputs.args, inputs.t_hi, inputs.t_lo
    y_of = inputs.interp.evaluate
    mask_shape = ctx.mask_shape
    found = jnp.zeros(mask_shape, bool)
    times = jnp.full(mask_shape, jnp.inf, ctx.dtype)
    touch = jnp.zeros(mask_shape, bool)
    boundary = jnp.zeros(mask_shape, bool)
    for i, piece in enumerate(ctx.pieces):
        for k, (sign, halves) in enumerate(zip(piece.signs, inputs.ends[i], strict=True)):
            g = ctx.gap_along(piece, sign, y_of, t_hi, t_lo, args_)

            def inside(s, piece=piece):
                return piece.inside(ctx.abs_time(s, t_hi, t_lo), y_of(s), args_, ctx.state_tol)

            sa, _, sb = inputs.bounds
            floor = step_floor(ctx, piece, t_hi, t_lo, args_, inputs.flight_scale, sa, sb,
                               inputs.y1, halves[0].slope_start, halves[1].slope_end)
            contact, on_boundary = _first_contact(
                g, inside, halves, inputs.bounds, inputs.restart[i], floor,
                inputs.candidate[i][k], ctx.event_root_finder,
            )
            found = found.at[i, k].set(contact.found)
            times = times.at[i, k].set(jnp.where(contact.found, contact.time, jnp.inf))
            touch = touch.at[i, k].set(contact.touch)
            boundary = boundary.at[i, k].set(on_boundary)
    return found, times, touch, boundary


def _first_contact(g, inside, halves, bounds, restart, floor, flags, finder):
    """The first contact inside the piece, over the step's halves in time order:
    `(Contact, on ∂Γ)`. A half that `is_candidate` did not flag is not searched; a dip
    that stays above the floor, or a contact outside the piece, moves on to the second.
    (One copy of `locate` in a loop of at most two rounds, not two copies: its root
    searches are the largest part of the program.)"""
    first_flag, second_flag = flags
    sa, s_mid, sb = bounds

    def pick(j, first, second):
        return jax.tree.map(lambda a, b: jnp.where(j == 0, a, b), first, second)

    def searching(carry):
        j, contact, _ = carry
        return (j < 2) & ~contact.found

    def search(carry):
        j, _, _ = carry
        e = pick(j, *halves)
        s_lo, s_hi = jnp.where(j == 0, sa, s_mid), jnp.where(j == 0, s_mid, sb)
        contact = locate(g, sa, s_lo, s_hi, e, restart, floor, finder)
        in_piece, on_boundary = inside(contact.time)
        contact = contact._replace(found=contact.found & in_piece)
        after = jnp.where((j == 0) & second_flag, 1, 2)
        return after, contact, on_boundary

    no = jnp.array(False)
    start = jnp.where(first_flag, 0, jnp.where(second_flag, 1, 2))
    _, contact, on_boundary = lax.while_loop(
        searching, search, (start, Contact(no, sb, no), no)
    )
    return contact, on_boundary


def nothing_detected(ctx: LoopContext) -> Detection:
    """The `Detection` of a step that does not search (a landing step)."""
    found, _, touch, boundary = _nothing_found(ctx)
    no = jnp.array(False)
    return Detection(no, no, jnp.array(jnp.inf, ctx.dtype), found, touch, boundary, no)


def _nothing_found(ctx: LoopContext):
    mask_shape = ctx.mask_shape
    return (
        jnp.zeros(mask_shape, bool), jnp.full(mask_shape, jnp.inf, ctx.dtype),
        jnp.zeros(mask_shape, bool), jnp.zeros(mask_shape, bool),
    )
