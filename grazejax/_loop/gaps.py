"""Every surface's gap along a step just taken, sampled where the contact tests read it.

The tests themselves (`_events.py`) work on values and slopes of the gap at the ends of the
step's `SUB_STEPS` sub-intervals; this module evaluates them on the step's dense output,
once per step, for the step-size verdict (`step.py`: an unresolved gap retakes the step)
and for the in-step search (`detect.py`).
"""

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from .._custom_types import BoolScalar, RealScalar
from .._events import SUB_STEPS, gap_resolution, is_candidate, split_step_ends, step_ends
from .._geometry import FLOOR_ULPS
from .._roots import safe_divide
from .context import LoopContext
from .state import LoopState

_INTERIOR = tuple(j / SUB_STEPS for j in range(1, SUB_STEPS))


class GapSamples(NamedTuple):
    """The gap of every piece and side along one step."""

    # per piece, per side: the `StepEnds` of the sub-intervals (each field an array [K])
    ends: tuple
    bounds: Float[Array, " K1"]  # the sub-intervals' ends in local time (sa, …, sb)
    floors: Float[Array, "m signs"]  # each gap's round-off floor over the step
    resolved: BoolScalar  # the samples resolve every gap (`gap_resolution`)
    shrink: RealScalar  # where not: the factor by which to retake the step
    candidate: Bool[Array, "m signs"]  # a sub-interval may hold a contact (`is_candidate`)


def sample_gaps(ctx: LoopContext, c: LoopState, sa, sb, y1, interp, stages) -> GapSamples:
    """Sample each piece's gap on the step [sa, sb] from `c.y` to `y1`."""
    args_ = c.args
    along = at_fraction(interp)
    at_ends = rates_at_ends(ctx, c.y, sa, sb, y1, stages)
    h = sb - sa
    bounds = jnp.stack([sa] + [fraction_time(theta, sa, sb) for theta in _INTERIOR] + [sb])
    x_scale = jnp.maximum(c.flight_scale, jnp.abs(y1))
    floor_base = []
    for piece in ctx.pieces:
        floor_base.append(piece.floor(ctx.abs_time(sb, c.t_hi, c.t_lo), y1, args_, x_scale))
    ends, floors = [], []
    resolved = jnp.array(True)
    shrink = jnp.ones((), ctx.dtype)
    for i, piece in enumerate(ctx.pieces):
        row, floor_row = [], []
        for sign in piece.signs:

            def gap(s, y, piece=piece, sign=sign):
                return sign * piece.gap(ctx.abs_time(s, c.t_hi, c.t_lo), y, args_)

            def rate(theta, gap=gap):
                s, y, dy_ds = at_ends[theta] if theta in at_ends else along(theta, sa, sb)
                return jax.jvp(gap, (s, y), (jnp.ones_like(s), dy_ds))

            g_a, g_b = gap(sa, c.y), gap(sb, y1)
            whole = step_ends(rate, sa, sb, c.restart[i], g_a, g_b)
            inner = [rate(theta) for theta in _INTERIOR]
            g = jnp.stack([g_a] + [v for v, _ in inner] + [g_b])
            slope = jnp.stack([whole.slope_start] + [r for _, r in inner] + [whole.slope_end])
            # Round-off of a step also grows with its length: add h·max|ġ| (a long step
            # of an exactly integrated flow carries ~100s of ulps).
            step_term = FLOOR_ULPS * ctx.eps * h * jnp.maximum(
                jnp.abs(whole.slope_start), jnp.abs(whole.slope_end)
            )
            floor = floor_base[i] + jax.lax.stop_gradient(step_term)
            ok, factor = gap_resolution(g, h * slope, floor)
            # (a sliding state is on its surface: no contact with it is searched for; a
            # gap that is not finite along the step, as an image surface's far from it
            # through a Newton inverse, has no contact to resolve)
            defined = jnp.all(jnp.isfinite(g)) & jnp.all(jnp.isfinite(slope))
            ok = ok | c.stick[i] | ~defined
            resolved = resolved & ok
            shrink = jnp.minimum(shrink, jnp.where(ok, 1.0, factor))
            row.append(split_step_ends(whole, bounds, g, slope, c.restart[i]))
            floor_row.append(floor)
        ends.append(tuple(row))
        floors.append(floor_row)
    candidate = _candidates(ctx, c, ends)
    floors_ = _as_mask(ctx, floors, jnp.inf)
    return GapSamples(
        tuple(ends), bounds, floors_, jax.lax.stop_gradient(resolved),
        jax.lax.stop_gradient(shrink), candidate,
    )


def _candidates(ctx: LoopContext, c: LoopState, ends):
    rows = []
    for i, row in enumerate(ends):
        flags = []
        for e in row:
            crossing, dip = is_candidate(e)
            flags.append(jnp.any(crossing | dip) & ~c.stick[i])
        rows.append(flags)
    return _as_mask(ctx, rows, False)


def _as_mask(ctx: LoopContext, rows, fill):
    """Per piece, per side values as an [m, max_signs] array (`fill` where a piece has
    fewer sides)."""
    if ctx.m == 0:
        return jnp.full(ctx.mask_shape, fill)
    return jnp.stack([
        jnp.stack(list(row) + [jnp.full_like(row[0], fill)] * (ctx.max_signs - len(row)))
        for row in rows
    ])


def rates_at_ends(ctx: LoopContext, y0, sa, sb, y1, stages):
    """`{θ: (s, y, dy/ds)}` at the step's ends, from the solver's own states and stages.

    An explicit Runge–Kutta step's first stage is h·f(sa, y(sa)), and an FSAL tableau's last
    is h·f(sb, y(sb)): the rates at the ends need no interpolant. Evaluated on the
    interpolant, each was a contraction of all the stages (a dot that XLA's CPU backend
    does not fuse) in every step of every lane. For other solvers the interpolant's ends
    are used.
    """
    end_stage = getattr(ctx.solver, "end_stage", None)
    k = stages
    if end_stage is None or not isinstance(k, jax.Array) or k.ndim != 2:
        return {}
    h = sb - sa
    # (an empty step has no slope, as on the interpolant)
    rate_of = lambda stage: safe_divide(stage, h, h != 0)  # noqa: E731
    return {0.0: (sa, y0, rate_of(k[0])), 1.0: (sb, y1, rate_of(k[end_stage]))}


def at_fraction(interp):
    """`(s, P(s), P'(s))` at a constant fraction θ of the step [sa, sb], for every step.

    Diffrax's dense outputs are polynomials in θ = (s − sa)/(sb − sa) with per-step
    coefficients (the stages). The same output on [0, 1] with constant ends, evaluated at
    a constant θ, has its polynomial weights folded into constants by XLA: what is left is
    one contraction of the stages with constant weights (a jvp through `evaluate` at the
    traced times would recompute the weights for every lane and take a batched dot per
    evaluation). Mathematically the same values (P'(s) = dP/dθ / (sb − sa)); the rounding
    differs by ulps. Interpolations from outside Diffrax and grazejax (`Vern9`'s) are
    evaluated at the traced times (their `evaluate` might not rescale by their ends).
    """
    if not type(interp).__module__.startswith(("diffrax.", "grazejax.")):

        def traced(theta, sa, sb):
            s = fraction_time(theta, sa, sb)
            y, dy = jax.jvp(interp.evaluate, (s,), (jnp.ones_like(s),))
            return s, y, dy

        return traced
    dtype = jnp.result_type(interp.t0)
    # (arrays, not Python floats: some dense outputs do ω-arithmetic with their ends)
    unit = eqx.tree_at(
        lambda i: (i.t0, i.t1), interp, (jnp.zeros((), dtype), jnp.ones((), dtype))
    )

    def folded(theta, sa, sb):
        s = fraction_time(theta, sa, sb)
        one = jnp.ones((), jnp.result_type(s))
        y, dy_dtheta = jax.jvp(unit.evaluate, (theta * one,), (one,))
        h = sb - sa
        # (an empty step has no slope, as linear_rescale's guard gives on the traced path)
        dy_ds = jax.tree.map(lambda d: safe_divide(d, h, h != 0), dy_dtheta)
        return s, y, dy_ds

    return folded


def fraction_time(theta, sa, sb):
    # The ends exactly (sa + (sb − sa) need not round to sb).
    if theta == 0:
        return sa
    if theta == 1:
        return sb
    return sa + (sb - sa) * theta
