"""Bracketed scalar root finding on a step's dense interpolant.

diffrax locates events with an unbracketed Newton iteration started at the step's end
(`_integrate.py`); on a high-order interpolant that can leave the step or fail to converge
(one cause of `Dopri8` event errors: docs/design.md, *Diffrax traps*). Every root we
look for is already bracketed by a sign change inside one step, so we keep the bracket and
take fast steps inside it.

Three root finders, strategy objects that `simulate(..., event_root_finder=...)` passes down
to every search of the loop (the in-step contact and extremum searches, the end of
sliding):

- `Chandrupatla()`, the default (T. R. Chandrupatla, 1997): inverse quadratic
  interpolation where it is well behaved, else bisection, with steps that close the
  bracket from both sides; guarded to at most bisection's count plus a few iterations.
- `ITP()` (Oliveira & Takahashi, ACM TOMS 47(1), 2020): regula falsi, truncated towards
  the midpoint and projected into a shrinking ball around it; never more than one
  iteration more than bisection.
- `BracketedNewton()`: a safeguarded Newton iteration (Numerical Recipes' `rtsafe`, plus a
  bracket-closing phase). The slope comes with the value from one `jax.jvp` of the
  interpolated gap; the first point is regula falsi; a Newton point outside the bracket,
  or one that does not halve the step before the last, is replaced by the midpoint; once
  the Newton step is down to the gap's rounding, points at least one ulp inwards close
  the bracket onto adjacent floats.

Why Chandrupatla (`benchmarks/bench_roots.py` measures the three): a sweep pays, per
search, the slowest lane's iteration count times every lane's cost of one iteration, so
both the count and the cost of an iteration matter. ITP shrinks the bracket from one side
and only closes it by its bisection guarantee, so it takes many iterations; Newton takes
fewer but pays a jvp per iteration and has a long tail over a random-phase sweep
(near-grazing crossings converge linearly, like a double root). Chandrupatla takes about
Newton's counts at the cost of an ITP iteration.
"""

import abc

import equinox as eqx
import jax
import jax.lax as lax
import jax.numpy as jnp


class AbstractBracketedRootFinder(eqx.Module):
    """A bracketed scalar root finder: what the loop's searches call (`bracketed_root`).

    Unlike Optimistix's root finders these never leave their bracket: every root the loop
    looks for is bracketed by a sign change inside one step.
    """

    @abc.abstractmethod
    def close(self, fn, lo, hi, f_lo, f_hi, width, target, max_iter):
        """Shrink `[lo, hi]` (with `fn(lo) = f_lo > 0 >= f_hi = fn(hi)`) around the sign
        change: `(lo, hi, iterations)`, stopping at `width` (0: to the end) or at
        `target` (a few ulps of the bracket's ends), or after `max_iter` iterations."""


class Chandrupatla(AbstractBracketedRootFinder):
    """Chandrupatla's method (the default): inverse quadratic interpolation where it is
    well behaved, else bisection; at most bisection's count plus a few iterations."""

    def close(self, fn, lo, hi, f_lo, f_hi, width, target, max_iter):
        return _chandrupatla(fn, lo, hi, f_lo, f_hi, target, max_iter)


class ITP(AbstractBracketedRootFinder):
    """The ITP method (interpolate, truncate, project): never more than one iteration more
    than bisection."""

    def close(self, fn, lo, hi, f_lo, f_hi, width, target, max_iter):
        return _itp(fn, lo, hi, f_lo, f_hi, target, max_iter)


class BracketedNewton(AbstractBracketedRootFinder):
    """Safeguarded Newton inside the bracket, which it closes onto adjacent floats."""

    def close(self, fn, lo, hi, f_lo, f_hi, width, target, max_iter):
        return _newton(fn, lo, hi, f_lo, f_hi, width, target, max_iter)


def bracketed_root(
    fn, lo, hi, f_lo, f_hi, *, rel_width: float = 0.0, max_iter: int = 60, count: bool = False,
    finder: AbstractBracketedRootFinder | None = None,
):
    """Locate the sign change of `fn` in `[lo, hi]`, given `f_lo > 0 >= f_hi`.

    Returns `(lo, hi)` with `fn(lo) > 0 >= fn(hi)` and `hi - lo` at most `rel_width` times
    the initial bracket, or a few ulps (the default; adjacent floats with `"newton"`).
    `hi` is the first point at or past the sign change. The result carries no
    derivative: callers apply one Newton step outside (the implicit function theorem) when
    they need tangents. `count=True` also returns the number of iterations (for tests and
    profiles). `finder` is the root finder (default `Chandrupatla()`, see the module
    docstring).

    Why to machine precision by default: the landing step's Newton correction leaves an
    error e²·|g''|/(2|g'|) for a proposal error e, which is not small near grazing or in a
    Zeno sequence (|g'| → 0) when the step is much longer than the flight: late in a
    bouncing ball's Zeno sequence a proposal good to a small fraction of the step still
    left flight-time errors far above the tolerance (`benchmarks/README.md`).
    """
    finder = Chandrupatla() if finder is None else finder
    lo, hi, f_lo, f_hi = (lax.stop_gradient(v) for v in (lo, hi, f_lo, f_hi))
    # The values `fn` closes over (the step's interpolant, args) are held constant too: a
    # while loop whose body reads differentiated values cannot be transposed, so reverse
    # mode would fail here although no derivative is wanted from the search.
    fn_closed, consts = jax.closure_convert(fn, lo)
    consts = [lax.stop_gradient(c) for c in consts]

    def fn(s):  # noqa: F811
        return fn_closed(s, *consts)

    eps = jnp.finfo(jnp.result_type(lo)).eps
    target = jnp.maximum(rel_width * (hi - lo), 4 * eps * jnp.maximum(jnp.abs(lo), jnp.abs(hi)))
    out = finder.close(fn, lo, hi, f_lo, f_hi, rel_width * (hi - lo), target, max_iter)
    lo, hi, iterations = out
    return (lo, hi, iterations) if count else (lo, hi)


def _newton(fn, lo, hi, f_lo, f_hi, width, converged, max_iter):
    """Safeguarded Newton: `(lo, hi, iterations)`.

    Stops when `hi - lo <= width` or when `lo` and `hi` are adjacent floats: `hi` is then
    *the* first float past the computed sign change, whatever the path to it. (A stop at
    a few ulps, as ITP's, leaves `hi` anywhere in them, and the landing step's rounding
    depends on its last bits: an elastic ball's speed drifted by 0.015 or −0.7 ulps per
    bounce for proposals one ulp apart, tests/hard/test_contacts.py.) A Newton step below
    `converged` (a few ulps: the rounding of fn) has converged: from there the bracket is
    closed by points at least one ulp inwards.
    """

    def value_and_slope(s):
        return jax.jvp(fn, (s,), (jnp.ones_like(s),))

    def not_done(carry):
        lo, hi, f_lo, f_hi = carry[:4]
        it = carry[-1]
        apart = (hi - lo > width) & (jnp.nextafter(lo, hi) < hi)
        return (it < max_iter) & apart & (f_hi != 0)

    def body(carry):
        lo, hi, f_lo, f_hi, x, f_x, slope_x, step_last, step_before, it = carry
        middle = 0.5 * (lo + hi)
        # First point: regula falsi from the two end values (no slope known yet).
        denom = f_lo - f_hi
        falsi = (f_lo * hi - f_hi * lo) / jnp.where(denom > 0, denom, 1.0)
        newton = x - f_x / jnp.where(slope_x != 0, slope_x, 1.0)
        step = jnp.abs(newton - x)
        has_newton = (it > 0) & (slope_x != 0) & jnp.isfinite(newton)
        # rtsafe's test: a Newton step must be at most half the step before the last one
        # (not the last: after a bisection, the Newton step from the midpoint back to a
        # root near the old end is as long as that bisection step).
        use_newton = has_newton & (newton > lo) & (newton < hi) & (step <= 0.5 * step_before)
        # Close the bracket: once converged, step to the Newton point if it lies inwards,
        # else one ulp inwards (x is always one end of the bracket: every point evaluated
        # replaces one, so "inwards" is towards the other end).
        closing = has_newton & (step < converged)
        inwards = jnp.nextafter(x, jnp.where(f_x > 0, hi, lo))
        close = jnp.where((newton - inwards) * (inwards - x) >= 0, newton, inwards)
        guess = jnp.where(
            it == 0, falsi, jnp.where(closing, close, jnp.where(use_newton, newton, middle))
        )
        guess = jnp.where(jnp.isfinite(guess) & (guess > lo) & (guess < hi), guess, middle)
        f_guess, slope_guess = value_and_slope(guess)
        lo, hi, f_lo, f_hi = _with_point(lo, hi, f_lo, f_hi, guess, f_guess)
        # (A closing step does not count as a step: if rounding in fn kept it from
        # crossing, the next one is again a Newton or closing step, not a bisection.)
        step_before = jnp.where(closing, step_before, step_last)
        step_last = jnp.where(closing, step_last, jnp.abs(guess - x))
        return lo, hi, f_lo, f_hi, guess, f_guess, slope_guess, step_last, step_before, it + 1

    zero = jnp.zeros_like(lo)
    # (x = lo to start: the first point is regula falsi, so x's values are not used; the
    # first "previous steps" are twice the bracket, so any Newton step inside it is taken.)
    init = (lo, hi, f_lo, f_hi, lo, f_lo, zero, 2 * (hi - lo), 2 * (hi - lo), zero)
    lo, hi, *_, iterations = lax.while_loop(not_done, body, init)
    return lo, hi, iterations


def _itp(fn, lo, hi, f_lo, f_hi, target, max_iter):
    """ITP: `(lo, hi, iterations)`."""
    half_target = 0.5 * target
    # ITP's constants: κ1 = 0.1 / (initial width), κ2 = 2, n0 = 1 (one iteration of slack
    # over bisection's count n_half).
    width0 = hi - lo
    kappa1 = 0.1 / jnp.where(width0 > 0, width0, 1.0)
    n_max = _ball_budget(lo, hi, target, 1)

    def not_done(carry):
        lo, hi, _, f_hi, it = carry
        return _still_open(lo, hi, f_hi, it, target, max_iter)

    def body(carry):
        lo, hi, f_lo, f_hi, it = carry
        width = hi - lo
        middle = 0.5 * (lo + hi)
        # Regula falsi between the bracket ends (f_lo > 0 >= f_hi: the denominator is > 0).
        denom = f_lo - f_hi
        falsi = (f_lo * hi - f_hi * lo) / jnp.where(denom > 0, denom, 1.0)
        falsi = jnp.where(jnp.isfinite(falsi), falsi, middle)
        # Truncate: move δ = κ1·width² towards the middle (or to it).
        towards = jnp.where(middle >= falsi, 1.0, -1.0)
        delta = kappa1 * width * width
        truncated = jnp.where(delta <= jnp.abs(middle - falsi), falsi + towards * delta, middle)
        # Project into the ball around the middle that keeps the bisection guarantee.
        radius = _ball_radius(half_target, n_max, it, width)
        mid = jnp.where(jnp.abs(truncated - middle) <= radius, truncated, middle - towards * radius)
        mid = jnp.where((mid > lo) & (mid < hi), mid, middle)
        lo, hi, f_lo, f_hi = _with_point(lo, hi, f_lo, f_hi, mid, fn(mid))
        return lo, hi, f_lo, f_hi, it + 1

    init = (lo, hi, f_lo, f_hi, jnp.zeros_like(lo))
    lo, hi, _, _, iterations = lax.while_loop(not_done, body, init)
    return lo, hi, iterations


# Chandrupatla's worst case over bisection's (its projection into ITP's ball): at most
# bisection's count plus this many iterations, and one more where rounding in the ball's
# radius leaves the bracket an ulp too wide (≤ 51 + 6 + 1 < max_iter = 60 in double).
_CHANDRUPATLA_SLACK = 6


def _chandrupatla(fn, lo, hi, f_lo, f_hi, target, max_iter):
    """Chandrupatla's method: `(lo, hi, iterations)`.

    T. R. Chandrupatla, Adv. Eng. Software 28(3), 1997 (the method of SciPy's
    `scipy.optimize.elementwise.find_root`): inverse quadratic interpolation through the
    newest point, the other end of the bracket and the point the newest one replaced,
    taken where it is well behaved (Chandrupatla's test on ξ and Φ), else bisection; every
    point at least half the target width inside the bracket, so that once one end has
    converged the next point lands just past the root and closes the bracket from the
    other side (regula falsi, and ITP built on it, keep the far end fixed and shrink the
    bracket by bisection: 54 iterations for exp(−5s) − 0.01 on [0, 2]).

    Two guards: a bracket that has not halved over three iterations is bisected (slow
    one-sided progress near a double root, i.e. near grazing), and every point is
    projected into ITP's ball around the midpoint with `_CHANDRUPATLA_SLACK` iterations of
    slack, so that no search takes more than bisection's count plus that, whatever the
    function.
    """
    half_target = 0.5 * target
    n_max = _ball_budget(lo, hi, target, _CHANDRUPATLA_SLACK)

    def not_done(carry):
        lo, hi, _, f_hi = carry[:4]
        return _still_open(lo, hi, f_hi, carry[-1], target, max_iter)

    def body(carry):
        lo, hi, f_lo, f_hi, a, f_a, c, f_c, widths, it = carry
        # widths: the bracket's width after each of the last three iterations, oldest first
        # a: the newest point (one end of the bracket); b: the other end; c: the point
        # a replaced (on a's side, or b's old value), for the interpolation.
        a_is_lo = a == lo
        b, f_b = jnp.where(a_is_lo, hi, lo), jnp.where(a_is_lo, f_hi, f_lo)
        width = hi - lo
        xi = (a - b) / jnp.where(c != b, c - b, 1.0)
        phi = (f_a - f_b) / jnp.where(f_c != f_b, f_c - f_b, 1.0)
        interpolate = (it > 0) & (phi * phi < xi) & ((1 - phi) * (1 - phi) < 1 - xi)
        t_iqi = (f_a / (f_b - f_a)) * (f_c / (f_b - f_c)) + ((c - a) / (b - a)) * (
            f_a / (f_c - f_a)
        ) * (f_b / (f_c - f_b))
        # First point: regula falsi from the two end values.
        t_falsi = f_a / (f_a - f_b)
        t = jnp.where(it == 0, t_falsi, jnp.where(interpolate, t_iqi, 0.5))
        stalled = width > 0.5 * widths[0]
        t = jnp.where(jnp.isfinite(t) & ~stalled, t, 0.5)
        t_lim = half_target / width
        t = jnp.clip(t, t_lim, 1 - t_lim)
        x = a + t * (b - a)
        # ITP's projection: the bracket after this iteration is at most
        # target · 2^(n_max − it − 1) wide, whatever the function.
        middle = 0.5 * (lo + hi)
        radius = _ball_radius(half_target, n_max, it, width)
        x = jnp.clip(x, middle - radius, middle + radius)
        x = jnp.where((x > lo) & (x < hi), x, middle)
        f_x = fn(x)
        # The point replaced by x (kept for the interpolation): a if x is on a's side,
        # else b (and a becomes the far end).
        same_side = (f_x > 0) == (f_a > 0)
        c, f_c = jnp.where(same_side, a, b), jnp.where(same_side, f_a, f_b)
        lo, hi, f_lo, f_hi = _with_point(lo, hi, f_lo, f_hi, x, f_x)
        widths = (widths[1], widths[2], width)
        return lo, hi, f_lo, f_hi, x, f_x, c, f_c, widths, it + 1

    # (The first point is regula falsi from a = lo, b = hi; c is not read before it is
    # set. The widths start at infinity: no bisection is forced in the first three.)
    inf = jnp.full_like(lo, jnp.inf)
    widths = (inf, inf, inf)
    init = (lo, hi, f_lo, f_hi, lo, f_lo, hi, f_hi, widths, jnp.zeros_like(lo))
    lo, hi, *_, iterations = lax.while_loop(not_done, body, init)
    return lo, hi, iterations


def _still_open(lo, hi, f_hi, it, target, max_iter):
    """Whether a search goes on: iterations left, the bracket wider than the target and
    its upper end not an exact root."""
    return (it < max_iter) & (hi - lo > target) & (f_hi != 0)


def _with_point(lo, hi, f_lo, f_hi, x, f_x):
    """`(lo, hi, f_lo, f_hi)` with x in place of the end on its side of the sign change."""
    positive = f_x > 0
    return (
        jnp.where(positive, x, lo), jnp.where(positive, hi, x),
        jnp.where(positive, f_x, f_lo), jnp.where(positive, f_hi, f_x),
    )


def _ball_budget(lo, hi, target, slack):
    """ITP's n_max: bisection's iteration count from [lo, hi] to `target`, plus `slack`."""
    n_half = jnp.ceil(jnp.log2(jnp.maximum((hi - lo) / target, 1.0)))
    return jnp.minimum(n_half + slack, 1000.0)


def _ball_radius(half_target, n_max, it, width):
    """ITP's ball around the midpoint at iteration `it`: a point inside it leaves the
    bracket at most target · 2^(n_max − it − 1) wide."""
    return half_target * jnp.exp2(n_max - it) - 0.5 * width


def safe_divide(num, den, ok):
    """num / den where `ok`, else 0, with the double-`where` that keeps tangents finite."""
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def stop(x):
    return jax.lax.stop_gradient(x)
