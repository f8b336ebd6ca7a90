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
  find it (root of ġ along the interpolant) and call it an impact when g_min <= 0.

Both tests read only the ends of an interval, so they are complete only where g has at
most one interior extremum there. A step is long where the *state* is easy to integrate,
not where the gap is: a wall that oscillates (Φ = x − a sin ωt) or a curved surface crossed
by a long step (Φ = r + cos x) puts several extrema of g inside one step, and a dip to
Φ < 0 between end slopes that are not (−, +) went unseen. So every step is tested in
`SUB_STEPS` equal sub-intervals, at the interpolant's values and slopes at their ends
(`split_step_ends`), and is accepted only if those samples *resolve* the gap
(`gap_resolution`): a cubic Hermite model of each half predicts the quarter points to
within a fraction of the gap's variation or its round-off floor, and no sub-interval's
model holds a pair of extrema that straddles Φ = 0. A step that fails is retaken shorter,
as the step-size controller retakes an inaccurate one. Resolved steps of smooth flows
pass at once (the model's error shrinks like h⁴): the test costs three more interpolant
evaluations per surface per step; the root searches run only when some lane (under vmap)
has a candidate.
"""

from typing import NamedTuple

import jax
import jax.numpy as jnp

from ._roots import bracketed_root, safe_divide

# Where a restart step that leaves Φ = 0 tangentially is judged (see `step_ends`).
LIFT_FRACTION = 2.0**-20
# Every step's gap is sampled at the ends of this many equal sub-intervals (θ = j/4).
# `gap_resolution` checks each half's cubic model at its midpoint, so it must be 4.
SUB_STEPS = 4
# A half's cubic model must predict its midpoint to this fraction of the gap's variation
# over the step (or to the round-off floor) for the step to count as resolved.
RESOLUTION = 0.125
# A surface farther than this many times the gap's variation (plus the model's error)
# from every sample cannot be reached within the step: its resolution is not asked for.
FAR = 4.0


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
        return jnp.where(restart, safe_divide(g(s), ds, ok), g(s))

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


def split_step_ends(ends: StepEnds, bounds, g, slope, restart) -> StepEnds:
    """The `StepEnds` of the step's `SUB_STEPS` sub-intervals, each field an array [K].

    `ends` are the whole step's (from `step_ends`: the restart guard and the lift-off
    belong to the first sub-interval); `bounds` [K + 1] the sub-intervals' ends in local
    time, `g` and `slope` [K + 1] the gap and its rate there (the entries at the step's
    ends are not read). Interior values are guarded like the ends: on a restart step
    G(s) = g(s)/(s − sa), which has g's sign.
    """
    sa = bounds[0]
    inner_s, inner_g = bounds[1:-1], g[1:-1]
    apart = inner_s > sa
    inner_G = jnp.where(restart & apart, inner_g / jnp.where(apart, inner_s - sa, 1.0), inner_g)
    inner_slope = slope[1:-1]
    before = lambda first, inner: jnp.concatenate([jnp.reshape(first, (1,)), inner])  # noqa: E731
    after = lambda inner, last: jnp.concatenate([inner, jnp.reshape(last, (1,))])  # noqa: E731
    return StepEnds(
        g_start=before(ends.g_start, inner_G),
        g_end=after(inner_G, ends.g_end),
        slope_start=before(ends.slope_start, inner_slope),
        slope_end=after(inner_slope, ends.slope_end),
        s_start=before(ends.s_start, inner_s),
    )


def gap_resolution(g, d, floor):
    """Whether the samples of a step resolve its gap: `(resolved, shrink)`.

    `g` [5] is the gap at θ = 0, ¼, ½, ¾, 1 and `d` [5] its slope in θ (h·ġ); `floor`
    the gap's round-off floor. Two tests (module docstring):

    - *the model is good*: each half's cubic Hermite interpolant (from its ends' values
      and slopes) predicts the gap at the half's midpoint to within `RESOLUTION` of the
      gap's variation over the step, or to the floor. A gap that oscillates within the
      step fails it (the prediction is off by the oscillation), unless every sample is
      `FAR` from Φ = 0 compared with the variation and the misfit.
    - *no hidden pair of extrema*: no quarter's cubic model has a local maximum and a
      local minimum inside it, deeper apart than the floor, that straddle Φ = 0 (within
      the misfit). The end-slope tests cannot see a dip between such extrema (their end
      slopes are (+, +) or (−, −)), and a crossing between them may have three roots.

    `shrink` is the factor by which to retake the step: from the model's misfit
    (which shrinks like h⁴) where the first test fails, else a quarter.
    """
    misfit = jnp.maximum(
        jnp.abs(g[1] - (0.5 * (g[0] + g[2]) + (d[0] - d[2]) / 16)),
        jnp.abs(g[3] - (0.5 * (g[2] + g[4]) + (d[2] - d[4]) / 16)),
    )
    variation = jnp.max(g) - jnp.min(g)
    far = jnp.min(jnp.abs(g)) > FAR * (variation + misfit)
    allowed = jnp.maximum(RESOLUTION * variation, floor)
    modelled = far | (misfit <= allowed)
    margin = misfit + floor
    hidden = jnp.array(False)
    for q in range(SUB_STEPS):
        low, high = _interior_extrema(g[q], g[q + 1], d[q] / SUB_STEPS, d[q + 1] / SUB_STEPS)
        hidden = hidden | ((high - low > floor) & (low <= margin) & (high >= -margin))
    resolved = modelled & (far | ~hidden)
    ratio = allowed / jnp.where(misfit > 0, misfit, 1.0)
    shrink = jnp.where(modelled, 0.25, jnp.clip(0.9 * jnp.sqrt(jnp.sqrt(ratio)), 0.1, 0.5))
    return resolved, shrink


def _interior_extrema(p0, p1, m0, m1):
    """The local minimum and maximum of the cubic Hermite interpolant on [0, 1] with values
    p0, p1 and slopes m0, m1, where it has both inside (0, 1); else (+inf, −inf)."""
    # p'(u) = A u² + B u + C
    A = 6 * (p0 - p1) + 3 * (m0 + m1)
    B = -6 * (p0 - p1) - 4 * m0 - 2 * m1
    C = m0
    disc = B * B - 4 * A * C
    ok = (A != 0) & (disc > 0)
    root = jnp.sqrt(jnp.where(ok, disc, 0.0))
    two_a = jnp.where(ok, 2 * A, 1.0)
    u1, u2 = (-B - root) / two_a, (-B + root) / two_a
    inside = ok & (u1 > 0) & (u1 < 1) & (u2 > 0) & (u2 < 1)

    def p(u):
        u2_, u3_ = u * u, u * u * u
        return (
            (2 * u3_ - 3 * u2_ + 1) * p0 + (u3_ - 2 * u2_ + u) * m0
            + (-2 * u3_ + 3 * u2_) * p1 + (u3_ - u2_) * m1
        )

    v1, v2 = p(u1), p(u2)
    low = jnp.where(inside, jnp.minimum(v1, v2), jnp.inf)
    high = jnp.where(inside, jnp.maximum(v1, v2), -jnp.inf)
    return low, high


def is_candidate(ends: StepEnds):
    """Cheap test: may this step contain a contact for this surface?"""
    crossing = (ends.g_start > 0) & (ends.g_end <= 0)
    dip = (ends.g_start > 0) & (ends.g_end > 0) & (ends.slope_start < 0) & (ends.slope_end > 0)
    return crossing, dip


class Contact(NamedTuple):
    found: jax.Array  # bool: a contact inside (sa, sb]
    time: jax.Array  # local time of the contact (crossing root, or minimum for a touch)
    touch: jax.Array  # bool: tangential within the floor (γ): the time is the minimum


def locate(g, sa, s_lo, s_hi, ends: StepEnds, restart, floor) -> Contact:
    """Locate the first contact in the sub-interval [s_lo, s_hi] of the step from `sa`,
    given that `is_candidate` said maybe (the restart guard is taken from `sa`)."""
    crossing, dip = is_candidate(ends)
    G = guarded(g, sa, restart)

    # 1. The interior minimum of g, for dips: root of ġ, which goes from < 0 to > 0.
    def neg_slope(s):
        return -jax.jvp(g, (s,), (jnp.ones_like(s),))[1]

    # Inactive lanes get an empty bracket, so they cost no iterations under vmap.
    _, t_min = bracketed_root(
        neg_slope, jnp.where(dip, s_lo, s_hi), s_hi, -ends.slope_start, -ends.slope_end
    )
    t_min = jnp.where(dip, t_min, s_hi)
    g_min = jnp.where(dip, g(t_min), ends.g_end)
    # Contact iff the dip reaches within the floor of Φ = 0; within the floor either way
    # it is a touch (γ), so an exact tangency is reported the same whatever the last bits.
    dip_hits = dip & (g_min <= floor)
    touch = dip_hits & (g_min > -floor)

    # 2. The crossing root of G, on [s_start, s_hi] for crossings or [s_start, t_min] for
    # deep dips.
    upper = jnp.where(dip, t_min, s_hi)
    G_upper = jnp.where(dip, jnp.minimum(G(upper), 0.0), ends.g_end)
    G_lower = jnp.where(ends.g_start > 0, ends.g_start, 1.0)
    deep = crossing | (dip_hits & ~touch)
    _, t_cross = bracketed_root(G, jnp.where(deep, ends.s_start, upper), upper, G_lower, G_upper)

    found = crossing | dip_hits
    time = jnp.where(touch, t_min, t_cross)
    return Contact(found, time, touch)
