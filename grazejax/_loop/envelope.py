"""Bounds on a surface's gap between the samples of a step, from a bound on its curvature.

The contact tests (`events.py`) read the gap g and its rate at five points of each step,
θ = 0, c₁, ½, c₂, 1 (`events.PART_FRACTIONS`), which cut it into four *parts*. Samples alone
can never prove that g stays clear of Φ = 0 between them: a ball over a corrugated floor
follows an exact parabola, its steps grow long, and a dip of the gap between two samples
is invisible to any test that reads values at fixed fractions. What makes the test
complete is a bound on the curvature: if |g''| ≤ K on a part of width w with end values
p₀, p₁ and slopes d₀, d₁ (in θ), then g lies above

- the two tangent parabolas p₀ + d₀x − Kx²/2 and p₁ − d₁(w − x) − K(w − x)²/2, and
- the chord parabola p₀ + (p₁ − p₀)x/w − Kx(w − x)/2,

so the larger of these bounds the gap's minimum over the part from below (`lower_bound`).
A part that no end test flags is accepted only where that bound proves it clear of Φ = 0
(beyond the round-off floor), or where K·w²/8, all the curvature could hide, is below the
trajectory's own tolerance (`part_resolution`); otherwise the step is retaken shorter,
and the bound tightens like h².

K itself comes from the samples (`curvature_bound`): the gap's second derivative at each
of the five samples (`gaps.curvatures_at`), and three lower bounds of max|g''| from every
pair of consecutive samples (the change of slope over the part, and the values' distance
from each end's tangent); K is the largest plus their spread, at most `SAFETY` times the
largest (exact for a constant g''). The second derivatives carry the bound where a part is
long against the gap's oscillation: the differences of values and slopes over a part of
width w never exceed ~2·max|ġ|/w, 2/(ωw) of the curvature of a gap oscillating at ω,
while g'' read at a sample scales like the curvature itself. The one assumption left is
that g'' on a step is within `SAFETY` of what its own samples show (as a solver's error
estimate is assumed to be within its safety factor of the error): a gap whose curvature
is small at all five samples and whose differences are small too (many oscillations per
step, each sample near an inflection point) remains unseen, as it would by any method
that samples the step.
"""

import jax.numpy as jnp
import numpy as np

from .._roots import safe_divide

# K is this many times the largest curvature that the samples show.
SAFETY = 2.0


def curvature_bound(values, slopes, fractions, second=None):
    """A bound of max|g''| (in θ) from the lower bounds that consecutive samples give,
    |d₁ − d₀|/w and 2|p₁ − p₀ − d₀w|/w², 2|p₀ − p₁ + d₁w|/w² for each part of width w, and
    |g''| at the samples (`second`, an array over them, where given): the largest, plus
    the spread between the largest and the smallest, at most (`SAFETY` − 1) times the
    largest. Where g'' is constant (a parabola: free fall onto a plane) every estimate is
    the same and the bound is exact, so it retakes no step that the gap itself does not
    call for; where the gap oscillates faster than the samples the estimates scatter and
    the bound is `SAFETY` times the largest."""
    p0, p1, d0, d1, w = part_arrays(values, slopes, fractions)
    estimates = [jnp.abs(d1 - d0) / w,
                 2 * jnp.abs(p1 - p0 - d0 * w) / (w * w),
                 2 * jnp.abs(p0 - p1 + d1 * w) / (w * w)]
    # (a second derivative that is not finite says nothing: the differences decide)
    if second is not None:
        estimates.append(jnp.where(jnp.isfinite(second), jnp.abs(second), 0.0))
    # (arrays over the parts and samples: one copy of the arithmetic, the same bits as a
    # copy per part, as max and min are exact)
    estimates = jnp.concatenate(estimates)
    largest, smallest = jnp.max(estimates, axis=0), jnp.min(estimates, axis=0)
    return largest + jnp.minimum(largest - smallest, (SAFETY - 1) * largest)


def lower_bound(p0, p1, d0, d1, w, K):
    """A lower bound of g over a part [0, w] with |g''| ≤ K: `(over [0, w], over (0, w])`.

    The second leaves out the value at x = 0, for a part that starts on the surface (the
    restart guard's known root): with d₀ > 0 the tangent parabola there is positive just
    after 0, and the bound is that of the rest of the part.

    The larger of the two tangent parabolas is the pointwise bound; they differ by a linear
    function of x, so they cross once, at x_c, and each is concave: its minimum over each
    side of x_c is at that side's ends, {0, x_c, w}."""

    def left(x):
        return p0 + d0 * x - 0.5 * K * x * x

    def right(x):
        return p1 - d1 * (w - x) - 0.5 * K * (w - x) * (w - x)

    offset = p1 - p0 - d1 * w - 0.5 * K * w * w  # right − left at x = 0
    rate = d1 + K * w - d0  # d(right − left)/dx
    x_c = safe_divide(-offset, rate, rate != 0)
    crosses = (rate != 0) & (x_c > 0) & (x_c < w)
    at_cross = jnp.where(crosses, left(jnp.where(crosses, x_c, 0.0)), jnp.inf)
    after_start = jnp.minimum(jnp.maximum(left(w), p1), at_cross)
    tangents = jnp.minimum(jnp.maximum(p0, right(0.0)), after_start)
    # The chord parabola: convex, its minimum at its vertex (clipped to the part).
    Kw = K * w
    vertex = jnp.clip(0.5 * w - safe_divide(p1 - p0, Kw, Kw > 0), 0.0, w)
    vertex = jnp.where(Kw > 0, vertex, jnp.where(p1 < p0, w, 0.0))
    chord = p0 + (p1 - p0) * vertex / w - 0.5 * K * vertex * (w - vertex)
    return jnp.maximum(tangents, chord), after_start


def part_resolution(p0, p1, d0, d1, w, K, floor, known, flagged, restart):
    """Whether a part's samples and the curvature bound K prove it free of an unflagged
    contact: `(resolved, ratio)`, `ratio` the factor by which its curvature slack exceeds
    what would prove it (squared: the slack shrinks like h², the caller's shrink table
    reads an h⁴ law).

    A part that an end test flags is searched (`locate`); a part whose ends are on either
    side of Φ = 0 is left to the halves' sign-order test (`events.gap_resolution`). A part
    with both ends on the free side must stay above the floor (a dip that reaches within
    the floor is a touch); one with both ends inside (Φ < 0) must stay below it (a hump
    that rises above it comes back down through Φ = 0). On a restart part (`restart`, it
    starts on the surface) the side is the one the flight leaves into (d₀'s sign), and the
    start's own root is left out."""
    low, low_after_start = lower_bound(p0, p1, d0, d1, w, K)
    high = -lower_bound(-p0, -p1, -d0, -d1, w, K)[0]
    free = jnp.where(restart, (d0 > 0) & (p1 > 0), (p0 > 0) & (p1 > 0))
    inside = jnp.where(restart, (d0 < 0) & (p1 < 0), (p0 < 0) & (p1 < 0))
    lowest = jnp.where(restart, low_after_start, low)
    proved = jnp.where(free, lowest > floor, high <= floor)
    slack = 0.125 * K * w * w
    small = slack <= known
    resolved = ~(free | inside) | flagged | small | proved
    distance = jnp.where(free, jnp.minimum(p0, p1), -jnp.maximum(p0, p1))
    distance = jnp.where(restart, jnp.abs(p1), distance)
    ratio = (slack + floor) / jnp.maximum(distance, floor)
    return resolved, jnp.where(resolved, 0.0, ratio * ratio)


def clear_of_surface(values, slopes, fractions, K):
    """Whether the bound proves every part of a step on the free side clear of Φ = 0
    (strictly above it): then the step needs no verdict (`gaps.sample_gaps`' screen)."""
    low, _ = lower_bound(*part_arrays(values, slopes, fractions), K)
    return jnp.all(low > 0)


def part_arrays(values, slopes, fractions):
    """`(p₀, p₁, d₀, d₁, w)` of every part between consecutive samples, as arrays over the
    parts: the bounds are elementwise, so one copy of their arithmetic serves all parts
    (a copy per part would be traced and compiled again by every transform of a run;
    elementwise, the values are the same bits)."""
    p, d = jnp.stack(values), jnp.stack(slopes)
    w = jnp.asarray(np.diff(np.asarray(fractions, float)), p.dtype)
    return p[:-1], p[1:], d[:-1], d[1:], w
