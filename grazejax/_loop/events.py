"""Event detection on one accepted step: crossings, in-step dips, the restart guard.

Everything here works on a single solver step [sa, sb] of the *local clock* s (time since
the last impact, see `_loop/state.py`), through the step's dense interpolant P(s). For each
surface the gap along the step is g(s) = d·Φ(t(s), P(s)), with d = +1 for the usual
"impact when Φ reaches 0 from above" and d = −1 for the mirrored test used in backward
time, where Γ̃ may be met from either side.

Why not `diffrax.Event`: it compares signs at step ends only, so an excursion into Φ < 0
that starts and ends inside one step is missed (diffrax #507); several conditions are
resolved in pytree order rather than time order (#639); and it has no notion of "do not
re-trigger at the start". We test each accepted step for

- a *crossing*: g(sa) > 0 >= g(sb);
- a *dip*: g > 0 at both ends but ġ(sa) < 0 < ġ(sb), so g has an interior minimum; we
  find it (root of ġ along the interpolant) and call it an impact when g_min <= 0;
- a *hump*: g <= 0 at both ends but ġ(sa) > 0 > ġ(sb): the flight rises out of Φ < 0 and
  comes back down through Φ = 0 within the interval, an impact when g_max > 0.

Both tests read only the ends of an interval, so they are complete only where g has at
most one interior extremum there. A step is long where the *state* is easy to integrate,
not where the gap is: a wall that oscillates (Φ = x − a sin ωt) or a curved surface crossed
by a long step (Φ = r + cos x) puts several extrema of g inside one step, and a dip to
Φ < 0 between end slopes that are not (−, +) went unseen. So every step is tested in two
halves, at the interpolant's value and slope at the midpoint (`split_step_ends`), and is
accepted only if those samples *resolve* the gap (`gap_resolution`): each half's cubic
Hermite model, checked at an irrational fraction of the half, keeps a half that no test
flags clear of Φ = 0 by several times its error, and holds no pair of extrema that
straddles Φ = 0. A step that fails is retaken shorter, as the step-size controller retakes
an inaccurate one. Resolved steps of smooth flows pass at once (the model's error shrinks
like h⁴): the test costs three more interpolant evaluations per step; the root searches
run only when some lane (under vmap) has a candidate.
"""

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._geometry import FLOOR_ULPS
from .._roots import bracketed_root, safe_divide

# Where a restart step that leaves Φ = 0 tangentially is judged (see `step_ends`).
LIFT_FRACTION = 2.0**-20
# Each half's cubic model is checked at these fractions of the half: irrational, so that
# a gap oscillating with a period that divides the step (a wall moving at ω with
# h ≈ 2πk/ω) cannot agree with the model at every check point.
CHECK_POINTS = (2.0**0.5 - 1.0, 0.5 * (5.0**0.5 - 1.0))
# The same check points as fractions of the whole step.
CHECK_FRACTIONS = (0.5 * CHECK_POINTS[0], 0.5 + 0.5 * CHECK_POINTS[1])
# Every sample with a value and a rate, in time order: they cut the step into the four
# parts that the search visits in turn (`split_parts`, `envelope.py`).
PART_FRACTIONS = (0.0, CHECK_FRACTIONS[0], 0.5, CHECK_FRACTIONS[1], 1.0)
# A half whose samples are all on one side of Φ = 0 and which no test flags must clear
# Φ = 0 by this many times its model's error.
CLEARANCE = 4.0
# Every half's model must predict its check point to this fraction of the half's spread of
# values (or to the floor): the shape of the gap, the number of its extrema, is resolved.
SHAPE = 0.125
# A gap that stays this many times its variation (`is_far`) or its step's model error
# (`is_clear`) clear of Φ = 0 on the free side needs no verdict: the verdict's clearance
# rule asks CLEARANCE = 4 of the halves' model errors, which these bound.
FAR = 8.0


class StepEnds(NamedTuple):
    """Guarded gap values and slopes of one surface at the two ends of a step."""

    g_start: jax.Array  # G(s_start): g(sa), or ġ(sa) on a restart step (see `guarded`)
    g_end: jax.Array  # G(sb), same sign as g(sb)
    slope_start: jax.Array  # ġ(sa) (not below 0 at a tangential lift-off)
    slope_end: jax.Array  # ġ(sb)
    s_start: jax.Array  # where g_start was taken: sa, or just after it (tangential lift-off)


def guarded(g, sa, restart):
    """The restart guard: on a step that starts on the surface use G(s) = g(s)/(s − sa).

    G has the same roots as g inside the step but not the known root at sa, and
    G(sa) = ġ(sa) (its limit). So a flight that leaves the surface upward and comes back
    down within one step is still caught (a plain sign test would see 0 then < 0 and miss
    it), while a flight leaving into Φ < 0 (ġ(sa) < 0, the paper's ex1dof) never
    re-triggers. See docs/design.md, *Diffrax traps*.
    """

    def G(s):
        ds = s - sa
        ok = ds > 0
        g_s = g(s)
        return jnp.where(restart, safe_divide(g_s, ds, ok), g_s)

    return G


def step_ends(rate, sa, sb, restart, g_a, g_b) -> StepEnds:
    """Gap values and slopes at the step's ends.

    `rate(θ)` is `(g, ġ)` at the fraction θ of the step (a Python float: 0, 1 or the
    lift-off point), along the step's interpolant (`_loop/detect.py`: evaluated at a
    constant fraction, the interpolant's weights are constants).

    `g_a`, `g_b` are the gap at the solver's own states y(sa), y(sb), not at the
    interpolant: the interpolant reproduces its end states only to round-off, and a
    crossing that ends a step exactly (an elastic ball's step ends where its flight does)
    could read g > 0 on the interpolant while the state the next step starts from has
    g < 0 — and no later step would ever see the sign change (a ball falling through an
    impenetrable floor). With the states' own values, consecutive steps share their end
    values, so every sign change of the sequence of states is seen by exactly one step.

    A restart step is judged by G(sa) = ġ(sa), except for a *tangential lift-off*: after a
    jump that leaves ġ = 0 to round-off (restitution 0 on a moving table), G(sa) reads 0 or
    ±1 ulp although the flight rises (ġ > 0 just after sa) — and a return through Φ = 0 within the same
    step was missed: the ball fell through the table with SUCCESS (found by the
    chatter–stick–release campaign at e = 0, Aω² = 1.25 g, ω = 8). Such a step is judged
    at s_lift = sa + 2⁻²⁰(sb − sa) (`LIFT_FRACTION`) instead, where G ≈ ġ + g̈·(s − sa)/2
    has left the round-off, and the crossing is searched in [s_lift, sb]: the flight does
    not re-trigger at sa, and a hop shorter than 2⁻²⁰ of the step is a touch (its depth is
    below the floor).
    """
    _, slope_a = rate(0.0)
    _, slope_b = rate(1.0)
    s_lift = sa + (sb - sa) * LIFT_FRACTION
    g_at_lift, slope_lift = rate(LIFT_FRACTION)
    lifted = s_lift - sa
    # (guarded(g, sa, restart)(s_lift), from g's value there)
    g_lift = jnp.where(restart, safe_divide(g_at_lift, lifted, lifted > 0), g_at_lift)
    rising = slope_lift > 0
    # ġ(sa) is round-off when G at least doubles over the first 2⁻²⁰ of the step; it may
    # read +1 ulp as well as −1 (the rate from the state's own stage reads +2e-17 where
    # the interpolant's read −1e-16 on the table above: a root of G in its round-off at
    # sa + 2e-16 was taken for a return, and the run ended in ZENO).
    round_off = slope_a <= 0.5 * slope_lift
    lifting = restart & round_off & rising & (g_lift > 0) & (s_lift > sa)
    g_start = jnp.where(restart, jnp.where(lifting, g_lift, slope_a), g_a)
    # A lift-off rises from sa: no interior minimum of g is looked for from there (a
    # round-off slope of −1 ulp would otherwise make a "dip" of depth 0 at sa, a false γ
    # contact at every release).
    slope_start = jnp.where(lifting, jnp.maximum(slope_a, 0.0), slope_a)
    return StepEnds(g_start, g_b, slope_start, slope_b, jnp.where(lifting, s_lift, sa))


def split_step_ends(ends: StepEnds, s_mid, g_mid, slope_mid, sa, restart):
    """The `StepEnds` of the step's two halves, given the gap `g_mid` and its rate
    `slope_mid` at the step's midpoint `s_mid` (the restart guard and the lift-off belong
    to the first half). The midpoint's value is guarded like the ends: on a restart step
    G(s) = g(s)/(s − sa), which has g's sign. Scalars throughout: under `vmap` every array
    op of a step is one more kernel in every lane's every step.
    """
    apart = s_mid > sa
    G_mid = jnp.where(restart & apart, g_mid / jnp.where(apart, s_mid - sa, 1.0), g_mid)
    first = StepEnds(ends.g_start, G_mid, ends.slope_start, slope_mid, ends.s_start)
    second = StepEnds(G_mid, ends.g_end, slope_mid, ends.slope_end, s_mid)
    return first, second


def split_parts(ends: StepEnds, inner, sa, restart):
    """The `StepEnds` of the step's parts between consecutive samples, given `inner`, the
    `(s, g, ġ)` of each interior sample in time order (`PART_FRACTIONS`). Values are
    guarded as in `split_step_ends`; the restart guard and the lift-off belong to the
    first part."""
    parts = []
    g_start, slope_start, s_start = ends.g_start, ends.slope_start, ends.s_start
    for s, g, slope in inner:
        apart = s > sa
        G = jnp.where(restart & apart, g / jnp.where(apart, s - sa, 1.0), g)
        parts.append(StepEnds(g_start, G, slope_start, slope, s_start))
        g_start, slope_start, s_start = G, slope, s
    parts.append(StepEnds(g_start, ends.g_end, slope_start, ends.slope_end, s_start))
    return tuple(parts)


def is_far(values, slopes):
    """Whether a gap sampled at `values` with slopes in θ (h·ġ) `slopes` stays clear of
    Φ = 0 over the step without a model (`FAR`): then it is resolved, whatever its shape.
    The values' spread plus the largest step·slope bounds the halves' model errors (at
    most ~2 spreads + ½ step·slope)."""
    lowest = functools.reduce(jnp.minimum, values)
    spread = functools.reduce(jnp.maximum, values) - lowest
    steepest = functools.reduce(jnp.maximum, map(jnp.abs, slopes))
    return lowest > FAR * (spread + steepest)


def is_clear(g, d, checks):
    """Whether a gap stays `FAR` times its step's model error clear of Φ = 0: then it is
    resolved, whatever its shape.

    `g` = (g(0), g(½), g(1)), `d` their slopes in θ (h·ġ), `checks` the value and slope in
    θ at `CHECK_FRACTIONS` (as `gap_resolution` reads them). The model is the cubic
    Hermite interpolant of the step's ends, whose values lie within
    b = max|d_end − Δ|/4 of the chord (Δ = g(1) − g(0)): above min(g(0), g(1)) − b. Its
    error is read as the verdict reads each half's: at the midpoint and the check points,
    value and slope/8 (a gap oscillating between them cannot match both at each point).
    `is_far` asks the same of the samples' spread and slopes, which a long step across a
    flight makes large: most steps between impacts pass here and not there.
    """
    g0, g_mid, g1 = g
    d0, d_mid, d1 = d
    bound = _chord_bound(g0, g1, d0, d1)
    error = jnp.zeros_like(g0)
    samples = ((0.5, (g_mid, d_mid)), *zip(CHECK_FRACTIONS, checks, strict=True))
    for u, (value, slope) in samples:
        model, model_slope = _hermite(g0, g1, d0, d1, u)
        misfit = jnp.maximum(jnp.abs(value - model), jnp.abs(slope - model_slope) / 8)
        error = jnp.maximum(error, misfit)
    return jnp.minimum(g0, g1) - bound > FAR * error


def gap_resolution(g, d, checks, flagged, floor, restart, known, g_start):
    """Whether the samples of a step resolve its gap: `(resolved, shrink)`.

    `g` = (g(0), g(½), g(1)) is the gap at θ = 0, ½, 1 and `d` its slopes in θ (h·ġ);
    `checks` the gap and its slope in θ at `CHECK_POINTS` of each half; `flagged` whether
    each half's end tests (`is_candidate`) flag it; `floor` the gap's round-off floor;
    `restart` whether the step starts on the surface (that root is known: the guard
    excludes it, and so does the clearance of the first half); `known` the gap's share of
    the solver's tolerance (Σ|∂Φ/∂x_k|·(atol + rtol·|x_k|)): the trajectory itself is not
    known better, so a misfit within it is no reason to retake a step (a state gliding
    along a surface stays within it of Φ = 0 for many steps). The model of each half is
    the cubic Hermite interpolant of its ends' values and slopes. Per half:

    - *its shape*: the model must predict the check point's value and slope to within
      `SHAPE` of the half's spread of values and of slopes (or the floor). Then it has the
      gap's extrema and, where it crosses Φ = 0 once, the gap does too: the end tests,
      which find one extremum or one root per half, are complete. Value and slope: a gap
      oscillating within the half cannot match both at a point (sin and cos do not
      vanish together), whatever its period.
    - *clear of the surface*: a half that is not flagged, with both ends on one side of
      Φ = 0, must stay `CLEARANCE` model errors (plus the floor) away from it at its ends,
      unless the model is exact to round-off. Its model has no interior minimum on the
      free side (nor maximum inside Φ < 0), or it would be flagged or hold a pair (below),
      so its ends are its closest points. The model's error is the larger of its value
      misfit, its slope misfit / 8 and 1/16 of the whole step's cubic misfit at ½ (the
      error shrinks like h⁴).
    - *no hidden pair of extrema*: the model has no local maximum and minimum inside the
      half, further apart than the floor, that straddle Φ = 0 within the model error. The
      end tests cannot see a dip between such extrema (their end slopes are (+, +) or
      (−, −)), and a crossing between them may have three roots.

    - *samples in order*: the gap's samples along the half (in time order: its ends and
      its check point) change sign no more often than its end tests allow: never on a half that
      no test flags and whose ends are on one side, once where the ends differ in sign,
      twice for a dip or a hump. A check point on the far side of Φ = 0 (beyond the
      floor) is a contact seen directly, whatever the model says: a hop that leaves a
      moving wall and comes back within half a step fits a cubic through its ends to
      within `SHAPE` while its check point lies inside the wall. On a restart step the
      first sample's side is that of `g_start` (the guarded G(s_start), `step_ends`),
      as g(sa) is the known root.

    `shrink` is the factor by which to retake the step: from the misfits' h⁴ law, read
    off in powers of two (no root in every step of every lane): 0.5 where at most 16
    times too large, 0.25 to 256, else 0.1.
    """
    g0, g_mid, g1 = g
    d0, d_mid, d1 = d
    # The gap's values carry their own rounding, which the floor (from ∇Φ·x) does not see
    # where Φ has a large constant part (σ − x near x = 0): a model of values that moved
    # by less than that rounding misfits by it, in value and (×6) in slope.
    eps = jnp.finfo(jnp.result_type(g0)).eps
    size = jnp.maximum(jnp.maximum(jnp.abs(g0), jnp.abs(g_mid)), jnp.abs(g1))
    known = jnp.maximum(known, FLOOR_ULPS * eps * size)
    mid_misfit = jnp.abs(g_mid - (0.5 * (g0 + g1) + (d0 - d1) / 8))
    resolved = jnp.array(True)
    worst = jnp.zeros_like(g0)  # the largest misfit / allowed ratio of a half
    halves = ((g0, g_mid, d0, d_mid), (g_mid, g1, d_mid, d1))
    for q, ((p0, p1, m0, m1), u, (value, slope), flag) in enumerate(
        zip(halves, CHECK_POINTS, checks, flagged, strict=True)
    ):
        m0, m1, slope = 0.5 * m0, 0.5 * m1, 0.5 * slope  # slopes in the half's fraction
        model, model_slope = _hermite(p0, p1, m0, m1, u)
        value_misfit = jnp.abs(value - model)
        slope_misfit = jnp.abs(slope - model_slope)
        spread = jnp.maximum(jnp.maximum(p0, p1), value) - jnp.minimum(jnp.minimum(p0, p1), value)
        slope_spread = jnp.maximum(jnp.maximum(jnp.abs(m0), jnp.abs(m1)), jnp.abs(p1 - p0))
        shape_allowed = jnp.maximum(SHAPE * spread, known)
        slope_allowed = jnp.maximum(SHAPE * slope_spread, 6 * known)
        shaped = (value_misfit <= shape_allowed) & (slope_misfit <= slope_allowed)
        error = jnp.maximum(jnp.maximum(value_misfit, slope_misfit / 8), mid_misfit / 16)
        one_side = ((p0 > 0) & (p1 > 0)) | ((p0 < 0) & (p1 < 0))
        distance = jnp.minimum(jnp.abs(p0), jnp.abs(p1))
        if q == 0:
            one_side = jnp.where(restart, p1 != 0, one_side)
            distance = jnp.where(restart, jnp.abs(p1), distance)
        needed = CLEARANCE * error + floor
        clear = ~one_side | flag | (distance > needed) | (error <= known)
        hidden = _hidden_pair(p0, p1, m0, m1, error + floor, floor)
        sides = [_side(v, floor) for v in (p0, value, p1)]
        if q == 0:
            sides[0] = jnp.where(restart, jnp.sign(g_start), sides[0])
        in_order = _sign_changes(sides) <= _allowed_changes(sides[0], sides[-1], flag)
        resolved = resolved & clear & shaped & ~hidden & in_order
        ratio = jnp.maximum(
            jnp.where(clear, 0.0, needed / jnp.maximum(distance, floor)),
            jnp.where(shaped, 0.0, jnp.maximum(value_misfit / shape_allowed,
                                               slope_misfit / slope_allowed)),
        )
        ratio = jnp.where(in_order, ratio, jnp.maximum(ratio, 16.0))
        worst = jnp.maximum(worst, ratio)
    return resolved, shrink_for(worst)


def shrink_for(worst):
    """The factor by which to retake a step whose worst misfit is `worst` times what is
    allowed, for misfits that shrink like h⁴: 0.5 to 16, 0.25 to 256, else 0.1."""
    return jnp.where(worst <= 16, 0.5, jnp.where(worst <= 256, 0.25, 0.1))


def _side(value, floor):
    """+1 or −1 for a gap value beyond the floor on either side of Φ = 0, 0 within it (a
    touch at round-off is on no side)."""
    return jnp.where(jnp.abs(value) > floor, jnp.sign(value), 0.0)


def _sign_changes(sides):
    """How often a sequence of `_side`s changes sign (zeros are skipped)."""
    changes = jnp.zeros((), jnp.int32)
    last = jnp.zeros_like(sides[0])
    for side in sides:
        changes = changes + ((side != 0) & (last != 0) & (side != last))
        last = jnp.where(side != 0, side, last)
    return changes


def _allowed_changes(first, last, flagged):
    """The sign changes a half's end tests account for, from the sides of its ends: one
    between ends on either side of Φ = 0 (a crossing, or a flight rising out of Φ < 0) or
    where an end is within the floor, two for a flagged dip or hump, none for an unflagged
    half with both ends on one side."""
    one_side = first * last > 0
    return jnp.where(one_side, jnp.where(flagged, 2, 0), 1)


def _hermite(p0, p1, m0, m1, u: float):
    """The cubic Hermite interpolant with values p0, p1 and slopes m0, m1 on [0, 1], and
    its slope, at the constant u."""
    u2, u3 = u * u, u * u * u
    value = (
        (2 * u3 - 3 * u2 + 1) * p0 + (u3 - 2 * u2 + u) * m0 + (3 * u2 - 2 * u3) * p1
        + (u3 - u2) * m1
    )
    slope = (6 * u2 - 6 * u) * (p0 - p1) + (3 * u2 - 4 * u + 1) * m0 + (3 * u2 - 2 * u) * m1
    return value, slope


def _chord_bound(p0, p1, m0, m1):
    """How far the cubic Hermite interpolant on [0, 1] with values p0, p1 and slopes m0, m1
    strays from its chord: max(|m0 − Δ|, |m1 − Δ|)/4, Δ = p1 − p0."""
    delta = p1 - p0
    return 0.25 * jnp.maximum(jnp.abs(m0 - delta), jnp.abs(m1 - delta))


def _hidden_pair(p0, p1, m0, m1, margin, floor):
    """Whether the cubic Hermite interpolant on [0, 1] with values p0, p1 and slopes m0, m1
    may hold a local maximum and minimum inside (0, 1) that straddle Φ = 0 within
    `margin`, further apart than `floor`. Without divisions or roots: both critical
    points are inside iff p'(u) = A u² + B u + C has a positive discriminant, its vertex
    −B/2A in (0, 1) and p'(0), p'(1) of A's sign; the cubic's values lie within
    b = max(|m0 − Δ|, |m1 − Δ|)/4 of the chord (Δ = p1 − p0), which bounds the extrema."""
    delta = p1 - p0
    A = 3 * (m0 + m1) - 6 * delta
    B = 6 * delta - 4 * m0 - 2 * m1
    C = m0
    pair = (
        (B * B > 4 * A * C) & (A * B < 0) & (jnp.abs(B) < 2 * jnp.abs(A))
        & (A * C > 0) & (A * (A + B + C) > 0)
    )
    bound = _chord_bound(p0, p1, m0, m1)
    low = jnp.minimum(p0, p1) - bound
    high = jnp.maximum(p0, p1) + bound
    return pair & (2 * bound > floor) & (low <= margin) & (high >= -margin)


def is_candidate(ends: StepEnds):
    """Cheap test: may this interval contain a contact for this surface? `(crossing, dip,
    hump)`. With at most one interior extremum of g (what `gap_resolution` asks of each
    half of a step) these are all the ways to reach Φ = 0 from above: a sign change from
    + to −; a minimum between end slopes (−, +) from above; or a maximum between end slopes
    (+, −) from below, which leaves Φ < 0 and comes back down through Φ = 0."""
    crossing = (ends.g_start > 0) & (ends.g_end <= 0)
    dip = (ends.g_start > 0) & (ends.g_end > 0) & (ends.slope_start < 0) & (ends.slope_end > 0)
    hump = (
        (ends.g_start <= 0) & (ends.g_end <= 0) & (ends.slope_start > 0) & (ends.slope_end < 0)
    )
    return crossing, dip, hump


class Contact(NamedTuple):
    found: jax.Array  # bool: a contact inside (sa, sb]
    time: jax.Array  # local time of the contact (crossing root, or minimum for a touch)
    touch: jax.Array  # bool: tangential within the floor (γ): the time is the minimum


def locate(g, sa, s_lo, s_hi, ends: StepEnds, restart, floor, finder) -> Contact:
    """Locate the first contact in the sub-interval [s_lo, s_hi] of the step from `sa`,
    given that `is_candidate` said maybe (the restart guard is taken from `sa`), with
    the root finder `finder` (`_roots`)."""
    crossing, dip, hump = is_candidate(ends)
    G = guarded(g, sa, restart)
    extremum = dip | hump

    # 1. The interior extremum of g, for dips and humps: the root of ∓ġ, which goes from
    # > 0 to <= 0 (−ġ for a minimum, ġ for a maximum).
    direction = jnp.where(hump, 1.0, -1.0)

    def signed_slope(s):
        return direction * jax.jvp(g, (s,), (jnp.ones_like(s),))[1]

    # Inactive lanes get an empty bracket, so they cost no iterations under vmap.
    _, t_ext = bracketed_root(
        signed_slope, jnp.where(extremum, s_lo, s_hi), s_hi, direction * ends.slope_start,
        direction * ends.slope_end, finder=finder,
    )
    t_ext = jnp.where(extremum, t_ext, s_hi)
    g_ext = jnp.where(extremum, g(t_ext), ends.g_end)
    # A dip is a contact iff it reaches within the floor of Φ = 0; within the floor either
    # way it is a touch (γ), so an exact tangency is reported the same whatever the last
    # bits. A hump is one iff it rises above the floor: it then comes back down through
    # Φ = 0 (a touch from below never enters the free side).
    dip_hits = dip & (g_ext <= floor)
    touch = dip_hits & (g_ext > -floor)
    hump_hits = hump & (g_ext > floor)

    # 2. The crossing root of G: on [s_start, s_hi] for crossings, [s_start, t_ext] for
    # deep dips, [t_ext, s_hi] for humps.
    lower = jnp.where(hump, t_ext, ends.s_start)
    upper = jnp.where(dip, t_ext, s_hi)
    G_upper = jnp.where(dip, jnp.minimum(G(upper), 0.0), ends.g_end)
    G_lower = jnp.where(hump, G(t_ext), jnp.where(ends.g_start > 0, ends.g_start, 1.0))
    deep = crossing | (dip_hits & ~touch) | hump_hits
    _, t_cross = bracketed_root(G, jnp.where(deep, lower, upper), upper, G_lower, G_upper,
                                finder=finder)

    found = crossing | dip_hits | hump_hits
    time = jnp.where(touch, t_ext, t_cross)
    return Contact(found, time, touch)
