"""The search for a contact inside an accepted step (see `_events.py` for the tests)."""

import functools
from typing import Any, NamedTuple

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp
from jaxtyping import Array, Bool

from .._custom_types import BoolScalar, RealScalar
from .._events import is_candidate, locate, step_ends
from .._geometry import FLOOR_ULPS
from .._roots import safe_divide
from .compact import per_lane
from .context import LoopContext
from .policies import locate_release
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
    ends = _step_ends(ctx, c, step)
    candidate = jnp.array(False)
    for i, row in enumerate(ends):
        for e in row:
            crossing, dip = is_candidate(e)
            # A sliding state is on its surface: no contact with it is searched for.
            candidate = candidate | ((crossing | dip) & ~c.stick[i])
    candidate = detecting & candidate

    if ctx.m > 0:
        # Only the lanes with a candidate pay for the searches under vmap (`compact.py`).
        inputs = SearchInputs(
            step.sa, step.sb, step.y1, step.interp, c.args, c.t_hi, c.t_lo, c.restart,
            c.flight_scale, tuple(tuple(row) for row in ends),
        )
        found, times, touch, boundary = per_lane(
            functools.partial(_search, ctx), candidate, inputs,
            lambda _: _nothing_found(ctx),
        )
    else:
        found, times, touch, boundary = _nothing_found(ctx)
    found = found & candidate & ~c.stick[:, None]
    times = jnp.where(found, times, jnp.inf)
    event = jnp.any(found)
    # (A scene without surfaces is a plain ODE solve: no contact, ever.)
    first = jax.lax.stop_gradient(jnp.min(times)) if ctx.m > 0 else jnp.array(jnp.inf, ctx.dtype)
    releasing = jnp.array(False)
    if ctx.sticky and slides:
        # Φ̈ of the slid-on surface at both ends, only while some lane slides (every step
        # paid for it in runs that never slide: grazejax issue 14).
        def release_test():
            return locate_release(ctx, c, sa, sb, y1, step.interp.evaluate, detecting)

        def no_release():
            return jnp.array(False), jnp.array(jnp.inf, ctx.dtype)

        release, t_release = lax.cond(
            eqxi.unvmap_any(detecting & jnp.any(c.stick)), release_test, no_release
        )
        releasing = release & (t_release <= first)
        first = jnp.minimum(first, t_release)
        event = event | release
    simultaneous = 1e3 * ctx.eps * (jnp.abs(first) + (sb - sa))
    pending = found & (times <= first + simultaneous) & ~releasing
    return Detection(detecting, event, first, pending, touch, boundary, releasing)


def _step_ends(ctx: LoopContext, c: LoopState, step: Step):
    """Per piece and side: the `StepEnds` of the gap along the step's interpolant."""
    sa, sb, y1, args_ = step.sa, step.sb, step.y1, c.args
    along = _at_fraction(step.interp)
    at_ends = _rates_at_ends(ctx, c, step)
    ends = []
    for i, piece in enumerate(ctx.pieces):
        row = []
        for sign in piece.signs:

            def gap(s, y, piece=piece, sign=sign):
                return sign * piece.gap(ctx.abs_time(s, c.t_hi, c.t_lo), y, args_)

            def rate(theta, gap=gap):
                # (Inside the step only the lift-off point of `step_ends` is read. Under a
                # `cond` on any lane restarting it cost more than it saved.)
                s, y, dy_ds = at_ends[theta] if theta in at_ends else along(theta, sa, sb)
                return jax.jvp(gap, (s, y), (jnp.ones_like(s), dy_ds))

            row.append(step_ends(rate, sa, sb, c.restart[i], gap(sa, c.y), gap(sb, y1)))
        ends.append(row)
    return ends


def _rates_at_ends(ctx: LoopContext, c: LoopState, step: Step):
    """`{θ: (s, y, dy/ds)}` at the step's ends, from the solver's own states and stages.

    An explicit Runge–Kutta step's first stage is h·f(sa, y(sa)), and an FSAL tableau's last
    is h·f(sb, y(sb)): the rates at the ends need no interpolant. Evaluated on the
    interpolant, each was a contraction of all the stages (a dot that XLA's CPU backend
    does not fuse) in every step of every lane (grazejax issue 14). For other solvers
    the interpolant's ends are used, as before.
    """
    end_stage = getattr(ctx.solver, "end_stage", None)
    k = step.stages
    if end_stage is None or not isinstance(k, jax.Array) or k.ndim != 2:
        return {}
    h = step.sb - step.sa
    # (an empty step has no slope, as on the interpolant)
    rate_of = lambda stage: safe_divide(stage, h, h != 0)  # noqa: E731
    return {0.0: (step.sa, c.y, rate_of(k[0])), 1.0: (step.sb, step.y1, rate_of(k[end_stage]))}


def _at_fraction(interp):
    """`(s, P(s), P'(s))` at a constant fraction θ of the step [sa, sb], for every step.

    Diffrax's dense outputs are polynomials in θ = (s − sa)/(sb − sa) with per-step
    coefficients (the stages). The same output on [0, 1] with constant ends, evaluated at
    a constant θ, has its polynomial weights folded into constants by XLA: what is left is
    one contraction of the stages with constant weights. The jvp through `evaluate` at
    the traced times sa and sb recomputed the weights for every lane and took a batched
    dot per evaluation, three evaluations per surface and step: an ex1dof sweep (Dopri8
    1e-12, 2048 lanes) went from 214 to 148 µs per trajectory in phase and from 283 to
    171 at random phases (grazejax issue 14). Mathematically the same values
    (P'(s) = dP/dθ / (sb − sa)); the rounding differs by ulps. Interpolations from
    outside Diffrax and grazejax (`Vern9`'s) are evaluated as before (their `evaluate`
    might not rescale by their ends).
    """
    if not type(interp).__module__.startswith(("diffrax.", "grazejax.")):

        def traced(theta, sa, sb):
            s = _fraction_time(theta, sa, sb)
            y, dy = jax.jvp(interp.evaluate, (s,), (jnp.ones_like(s),))
            return s, y, dy

        return traced
    dtype = jnp.result_type(interp.t0)
    # (arrays, not Python floats: some dense outputs do ω-arithmetic with their ends)
    unit = eqx.tree_at(
        lambda i: (i.t0, i.t1), interp, (jnp.zeros((), dtype), jnp.ones((), dtype))
    )

    def folded(theta, sa, sb):
        s = _fraction_time(theta, sa, sb)
        one = jnp.ones((), jnp.result_type(s))
        y, dy_dtheta = jax.jvp(unit.evaluate, (theta * one,), (one,))
        h = sb - sa
        # (an empty step has no slope, as linear_rescale's guard gives on the traced path)
        dy_ds = jax.tree.map(lambda d: safe_divide(d, h, h != 0), dy_dtheta)
        return s, y, dy_ds

    return folded


def _fraction_time(theta, sa, sb):
    # The ends exactly (sa + (sb − sa) need not round to sb).
    if theta == 0:
        return sa
    if theta == 1:
        return sb
    return sa + (sb - sa) * theta


class SearchInputs(NamedTuple):
    """What the search of one lane reads: the step, its clock and the gaps at its ends."""

    sa: RealScalar
    sb: RealScalar
    y1: Array
    interp: Any  # the step's dense output
    args: Any
    t_hi: RealScalar
    t_lo: RealScalar
    restart: Bool[Array, " m"]
    flight_scale: Array
    ends: tuple  # per piece, per side: `StepEnds`


def _search(ctx: LoopContext, inputs: SearchInputs):
    """Locate the contact of every piece and side in the step: `(found, times, touch,
    boundary)`, each [m, signs]."""
    sa, sb, y1, args_ = inputs.sa, inputs.sb, inputs.y1, inputs.args
    t_hi, t_lo = inputs.t_hi, inputs.t_lo
    y_of = inputs.interp.evaluate
    mask_shape = ctx.mask_shape
    found = jnp.zeros(mask_shape, bool)
    times = jnp.full(mask_shape, jnp.inf, ctx.dtype)
    touch = jnp.zeros(mask_shape, bool)
    boundary = jnp.zeros(mask_shape, bool)
    for i, piece in enumerate(ctx.pieces):
        for k, (sign, e) in enumerate(zip(piece.signs, inputs.ends[i], strict=True)):
            g = ctx.gap_along(piece, sign, y_of, t_hi, t_lo, args_)
            x_scale = jnp.maximum(inputs.flight_scale, jnp.abs(y1))
            # Round-off of a step also grows with its length: add h·max|ġ| (a
            # long step of an exactly integrated flow carries ~100s of ulps).
            step_term = FLOOR_ULPS * ctx.eps * (sb - sa) * jnp.maximum(
                jnp.abs(e.slope_start), jnp.abs(e.slope_end)
            )
            floor = piece.floor(ctx.abs_time(sb, t_hi, t_lo), y1, args_, x_scale)
            floor = floor + jax.lax.stop_gradient(step_term)
            contact = locate(g, sa, sb, e, inputs.restart[i], floor)
            t_abs = ctx.abs_time(contact.time, t_hi, t_lo)
            inside, on_boundary = piece.inside(t_abs, y_of(contact.time), args_, ctx.state_tol)
            ok = contact.found & inside
            found = found.at[i, k].set(ok)
            times = times.at[i, k].set(jnp.where(ok, contact.time, jnp.inf))
            touch = touch.at[i, k].set(contact.touch)
            boundary = boundary.at[i, k].set(on_boundary)
    return found, times, touch, boundary


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
