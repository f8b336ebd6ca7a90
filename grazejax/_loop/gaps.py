"""Every surface's gap along a step just taken, sampled where the contact tests read it.

The tests themselves (`events.py`) work on values and slopes of the gap at the step's ends
and its midpoint; this module evaluates them on the step's dense output,
once per step, for the step-size verdict (`step.py`: an unresolved gap retakes the step)
and for the in-step search (`detect.py`).
"""

import functools
import operator
from typing import Any, NamedTuple

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp

from .._custom_types import BoolScalar, RealScalar
from .._geometry import FLOOR_ULPS
from .._roots import safe_divide
from .context import LoopContext
from .envelope import clear_of_surface, curvature_bound, part_arrays, part_resolution
from .events import (
    CHECK_FRACTIONS,
    LIFT_FRACTION,
    PART_FRACTIONS,
    gap_resolution,
    is_candidate,
    is_clear,
    is_far,
    shrink_for,
    split_parts,
    split_step_ends,
    step_ends,
)
from .state import LoopState

# Every fraction of a step at which the tests read the gap.
_FRACTIONS = (0.0, LIFT_FRACTION, CHECK_FRACTIONS[0], 0.5, CHECK_FRACTIONS[1], 1.0)


class GapSamples(NamedTuple):
    """The gap of every piece and side along one step (scalars per lane: under `vmap`
    every array op of a step is one more kernel in every lane's every step)."""

    # per piece, per side: the two halves' `StepEnds` (searched in time order)
    ends: tuple
    bounds: tuple  # the searched halves' ends in local time: (sa, midpoint, sb)
    resolved: BoolScalar  # the samples resolve every gap (`gap_resolution`)
    shrink: RealScalar  # where not: the factor by which to retake the step
    candidate: tuple  # per piece, per side, per half: it may hold a contact (`is_candidate`)
    any_candidate: BoolScalar
    curvature: tuple  # per piece, per side: the curvature bound (θ units, `envelope.py`)


def sample_gaps(ctx: LoopContext, c: LoopState, sa, sb, y1, interp, stages, *,
                batched: bool = False, checking=True) -> GapSamples:
    """Sample each piece's gap on the step [sa, sb] from `c.y` to `y1`.

    The verdict `resolved` (`gap_resolution`) is computed under a `cond`, only where a
    gap is not far from Φ = 0 (`is_far`, `is_clear`) in some lane `checking` it: its
    arithmetic is light, but XLA's CPU fusion copies it into every consumer of the step's
    decision (each field of the next state), and under `vmap` each copy runs over the
    whole batch; a conditional's results are computed once, and in a single run most
    steps skip it.
    `batched` (the loop runs under `vmap`): the dense output is evaluated at every
    fraction in one contraction (in a single run that is a kernel of its own per step).
    """
    at = rates_at_ends(ctx, c.y, sa, sb, y1, stages)
    inner = tuple(theta for theta in _FRACTIONS if theta not in at)
    if batched:
        at.update(zip(inner, at_fractions(interp, inner, sa, sb), strict=True))
    else:
        at.update((theta, at_fraction(interp)(theta, sa, sb)) for theta in inner)
    step = _StepView(c, sa, sb, fraction_time(0.5, sa, sb), y1, at, interp)
    ends, candidates, curvatures = [], [], []
    resolved, any_candidate = jnp.array(True), jnp.array(False)
    shrink = jnp.ones((), ctx.dtype)
    for i, piece in enumerate(ctx.pieces):
        row, candidate_row, curvature_row = [], [], []
        for sign in piece.signs:
            parts, flagged, far, verdict, curvature = _sample_one(ctx, step, i, piece, sign)
            # (a gap far from Φ = 0 on this step needs no verdict: most steps of a run)
            trivially = lambda: (jnp.array(True), jnp.array(1.0, ctx.dtype))  # noqa: E731
            some_lane = eqxi.unvmap_any(checking & ~far) if batched else checking & ~far
            ok, factor = lax.cond(some_lane, verdict, trivially)
            ok = ok | far
            # (a sliding state is on its surface: no contact with it is searched for)
            ok = ok | c.stick[i]
            resolved = resolved & ok
            shrink = jnp.minimum(shrink, jnp.where(ok, 1.0, factor))
            flagged = tuple(flag & ~c.stick[i] for flag in flagged)
            any_candidate = functools.reduce(operator.or_, flagged, any_candidate)
            row.append(parts)
            candidate_row.append(flagged)
            curvature_row.append(jax.lax.stop_gradient(curvature))
        ends.append(tuple(row))
        candidates.append(tuple(candidate_row))
        curvatures.append(tuple(curvature_row))
    bounds = (sa, step.s_mid, sb)
    return GapSamples(
        tuple(ends), bounds, jax.lax.stop_gradient(resolved),
        jax.lax.stop_gradient(shrink), tuple(candidates), any_candidate, tuple(curvatures),
    )


class _StepView(NamedTuple):
    """What sampling one surface's gap on a step reads."""

    c: LoopState
    sa: RealScalar
    sb: RealScalar
    s_mid: RealScalar
    y1: Any
    at: dict  # `{θ: (s, y, dy/ds)}` at every fraction the tests read (`_FRACTIONS`)
    interp: Any  # the step's dense output (the gap's second derivatives, `curvatures_at`)


def _sample_one(ctx: LoopContext, step: _StepView, i: int, piece, sign):
    """One piece's side: `(halves, flags, far, verdict, K)`, the two halves' `StepEnds`
    (searched), whether an end test flags each half, whether the gap is far from
    Φ = 0 on the step (`is_far`, `is_clear` and the curvature bound's proof,
    `envelope.clear_of_surface`: no verdict needed), and the resolution verdict as a
    function (`gap_resolution`'s and `envelope.part_resolution`'s `(resolved, shrink)`),
    so the caller may compute it under a `cond`, and the curvature bound K
    (`envelope.curvature_bound`)."""
    c, sa, sb, h = step.c, step.sa, step.sb, step.sb - step.sa

    def gap(s, y):
        return sign * piece.gap(ctx.abs_time(s, c.t_hi, c.t_lo), y, c.args)

    def rate(theta):
        s, y, dy_ds = step.at[theta]
        return jax.jvp(gap, (s, y), (jnp.ones_like(s), dy_ds))

    g_a, g_b = gap(sa, c.y), gap(sb, step.y1)
    whole = step_ends(rate, sa, sb, c.restart[i], g_a, g_b)
    g_mid, slope_mid = rate(0.5)
    halves = split_step_ends(whole, step.s_mid, g_mid, slope_mid, sa, c.restart[i])
    half_flags = []
    for e in halves:
        crossing, dip, hump = is_candidate(e)
        half_flags.append(crossing | dip | hump)
    slopes = (whole.slope_start, slope_mid, whole.slope_end)
    # A gap that is not finite along the step (an image surface's far from it, through a
    # Newton inverse) has no contact to resolve.
    defined = functools.reduce(operator.and_, map(jnp.isfinite, (g_a, g_mid, g_b, *slopes)))

    # (outside `verdict`: a conditional that read the dense output would copy every
    # lane's stages into its branch at every step)
    check_rates = tuple(map(rate, CHECK_FRACTIONS))
    checks = tuple((value, h * slope) for value, slope in check_rates)
    step_slopes = tuple(h * r for r in slopes)
    # The four parts between the samples, with their end tests' flags: the curvature
    # bound judges each part (`envelope.part_resolution`); a flagged part is left to the search.
    inner = (
        (fraction_time(CHECK_FRACTIONS[0], sa, sb), *check_rates[0]),
        (step.s_mid, g_mid, slope_mid),
        (fraction_time(CHECK_FRACTIONS[1], sa, sb), *check_rates[1]),
    )
    parts = split_parts(whole, inner, sa, c.restart[i])
    flags = tuple(functools.reduce(operator.or_, is_candidate(e)) for e in parts)
    # The search visits the halves, not the four parts: searched by parts, an elastic
    # ball's energy drifted by ~1.3 ulps per bounce (SciML's long horizon, 1,565 bounces;
    # by halves it stays within round-off); the parts serve the bound above.
    search_parts = halves
    # Every sample in time order, values and slopes in θ, and the curvature bound.
    values = (g_a, checks[0][0], g_mid, checks[1][0], g_b)
    theta_slopes = (step_slopes[0], checks[0][1], step_slopes[1], checks[1][1], step_slopes[2])
    second = curvatures_at(gap, step.interp, PART_FRACTIONS, sa, sb)
    curvature = curvature_bound(values, theta_slopes, PART_FRACTIONS, second)
    far = is_far((g_a, g_mid, g_b, *(v for v, _ in checks)),
                 (*step_slopes, *(d for _, d in checks)))
    far = far | is_clear((g_a, g_mid, g_b), step_slopes, checks)
    far = far & clear_of_surface(values, theta_slopes, PART_FRACTIONS, curvature) & defined

    def verdict():
        floor = step_floor(ctx, piece, c.t_hi, c.t_lo, c.args, c.flight_scale, sa, sb,
                           step.y1, slopes[0], slopes[-1])
        # (the gap's share of the solver's tolerance: `Piece.floor` with the tolerance per
        # coordinate in place of the coordinates' magnitudes)
        tol = ctx.tol_a + ctx.tol_r * jnp.maximum(c.flight_scale, jnp.abs(step.y1))
        known = piece.floor(ctx.abs_time(sb, c.t_hi, c.t_lo), step.y1, c.args,
                            tol / (FLOOR_ULPS * ctx.eps))
        known = jnp.maximum(known, floor)
        ok, factor = gap_resolution((g_a, g_mid, g_b), step_slopes, checks,
                                    tuple(half_flags), floor, c.restart[i], known,
                                    whole.g_start)
        # A tangential lift-off (`step_ends`: ġ(sa) = 0 to round-off, the flight rising)
        # has g ≈ g̈·s²/2 from the surface: a bound with a safety factor on g'' can never
        # prove such a gap positive, at any step length, so its step is left to the
        # halves' tests, which judge it from the lift-off point.
        lifting = whole.s_start > sa
        flagged = jnp.stack([flag | lifting for flag in flags])
        starts_on_surface = jnp.stack([c.restart[i] & (j == 0) for j in range(len(flags))])
        resolved, ratio = part_resolution(
            *part_arrays(values, theta_slopes, PART_FRACTIONS), curvature, floor, known, flagged,
            starts_on_surface)
        ok = ok & jnp.all(resolved)
        worst = jnp.maximum(jnp.zeros_like(g_a), jnp.max(ratio))
        factor = jnp.minimum(factor, shrink_for(worst))
        # (the branches of the caller's `cond` must agree in type: float32 runs too)
        return ok | ~defined, jnp.asarray(factor, ctx.dtype)

    return search_parts, tuple(half_flags), far, verdict, curvature


def curvatures_at(gap, interp, thetas, sa, sb):
    """d²g/dθ² at the fractions `thetas` of the step [sa, sb], along its dense output (θ
    units, as `envelope.curvature_bound` reads them).

    Values and slopes alone cap what they can show of the curvature: over a part of width w
    their differences never exceed ~2·max|ġ|/w, which for a gap oscillating at ω is
    2/(ωw) of its true curvature ω²·amplitude: a part that holds more than a third of an
    oscillation hides most of it. The second derivative read at the samples scales like the
    curvature itself. Computed without derivatives (it decides, it is not an output)."""
    sa, sb, interp = jax.lax.stop_gradient((sa, sb, interp))
    h = sb - sa
    if _rescales(interp):
        unit, one = _on_unit_interval(interp)
        state_at = unit.evaluate
    else:
        one = jnp.ones((), jnp.result_type(sa))
        state_at = lambda theta: interp.evaluate(sa + h * theta)  # noqa: E731

    def along(theta):
        return gap(sa + h * theta, state_at(theta))

    def second(theta):
        slope = lambda th: jax.jvp(along, (th,), (one,))[1]  # noqa: E731
        return jax.jvp(slope, (theta,), (one,))[1]

    # One copy of the nested JVP for all the fractions, in single runs too: a copy per
    # fraction is a large share of a run's program, and every transform of the run
    # (jacfwd, an orbit's Newton, its derivatives) traces and compiles each copy again;
    # the values are the same bits.
    return jax.vmap(second)(jnp.asarray(thetas, one.dtype))


def step_floor(ctx: LoopContext, piece, t_hi, t_lo, args_, flight_scale, sa, sb, y1,
               slope_start, slope_end):
    """A gap's round-off floor over the step [sa, sb] (`Piece.floor` at its end state, with
    the flight's magnitudes), plus h·max|ġ|: round-off of a step also grows with its
    length (a long step of an exactly integrated flow carries ~100s of ulps)."""
    x_scale = jnp.maximum(flight_scale, jnp.abs(y1))
    step_term = FLOOR_ULPS * ctx.eps * (sb - sa) * jnp.maximum(
        jnp.abs(slope_start), jnp.abs(slope_end)
    )
    floor = piece.floor(ctx.abs_time(sb, t_hi, t_lo), y1, args_, x_scale)
    return floor + jax.lax.stop_gradient(step_term)


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


def at_fractions(interp, thetas, sa, sb):
    """`[(s, P(s), P'(s))]` at the constant fractions `thetas` of the step [sa, sb].

    Diffrax's dense outputs are polynomials in θ = (s − sa)/(sb − sa) with per-step
    coefficients (the stages). The same output on [0, 1] with constant ends, evaluated at
    constant θ, has its polynomial weights folded into constants by XLA: what is left is
    one contraction of the stages with a constant matrix, for every fraction at once (each
    evaluation on its own was a contraction kernel of its own at every step; a jvp through
    `evaluate` at the traced times also recomputed the weights for every lane).
    Mathematically the same values (P'(s) = dP/dθ / (sb − sa)); the rounding differs by
    ulps. Interpolations from outside Diffrax and grazejax are evaluated at the traced
    times (their `evaluate` might not rescale by their ends).
    """
    if not thetas:
        return []
    times = [fraction_time(theta, sa, sb) for theta in thetas]
    if not _rescales(interp):
        out = []
        for s in times:
            y, dy = jax.jvp(interp.evaluate, (s,), (jnp.ones_like(s),))
            out.append((s, y, dy))
        return out
    unit, one = _on_unit_interval(interp)
    ys, dys = jax.vmap(lambda theta: jax.jvp(unit.evaluate, (theta,), (one,)))(
        jnp.asarray(thetas, one.dtype)
    )
    h = sb - sa
    out = []
    for j, s in enumerate(times):
        # (an empty step has no slope, as linear_rescale's guard gives on the traced path)
        dy_ds = jax.tree.map(lambda d, j=j: safe_divide(d[j], h, h != 0), dys)
        out.append((s, jax.tree.map(lambda y, j=j: y[j], ys), dy_ds))
    return out


def at_fraction(interp):
    """`(s, P(s), P'(s))` at one constant fraction θ of the step [sa, sb]: the output on
    [0, 1] at θ, as in `at_fractions`, without the batch of fractions (one fraction in a
    batch of one made its weights a row, which XLA hoisted out of the step loop and then
    copied into the column its contraction reads, one kernel per weight vector at every
    step; unbatched they are read where they are). Same weights, same contraction: the
    same bits."""

    def at(theta, sa, sb):
        if not _rescales(interp):
            return at_fractions(interp, (theta,), sa, sb)[0]
        unit, one = _on_unit_interval(interp)
        y, dy = jax.jvp(unit.evaluate, (jnp.asarray(theta, one.dtype),), (one,))
        h = sb - sa
        return fraction_time(theta, sa, sb), y, jax.tree.map(
            lambda d: safe_divide(d, h, h != 0), dy)

    return at


def _rescales(interp) -> bool:
    """Whether the dense output is one of Diffrax's or grazejax's, whose `evaluate` rescales
    time by its ends (so that it may be evaluated on [0, 1])."""
    return type(interp).__module__.startswith(("diffrax.", "grazejax."))


def _on_unit_interval(interp):
    """The same dense output with ends 0 and 1, and the scalar 1 of its dtype."""
    dtype = jnp.result_type(interp.t0)
    # (arrays, not Python floats: some dense outputs do ω-arithmetic with their ends)
    unit = eqx.tree_at(
        lambda i: (i.t0, i.t1), interp, (jnp.zeros((), dtype), jnp.ones((), dtype))
    )
    return unit, jnp.ones((), dtype)


def fraction_time(theta, sa, sb):
    # The ends exactly (sa + (sb − sa) need not round to sb).
    if theta == 0:
        return sa
    if theta == 1:
        return sb
    return sa + (sb - sa) * theta
