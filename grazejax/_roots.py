"""Bracketed scalar root finding on a step's dense interpolant.

diffrax locates events with an unbracketed Newton iteration started at the step's end
(`_integrate.py`); on a high-order interpolant that can leave the step or fail to converge
(one cause of `Dopri8` event errors: docs/design.md, *Diffrax traps*). Every root we
look for is already bracketed by a sign change inside one step, so we keep the bracket and
take fast steps inside it.

Two methods (`method=`, or `search_method` around tracing for side-by-side benchmarks):

- `"itp"`, the default (Oliveira & Takahashi, ACM TOMS 47(1), 2020): regula falsi,
  truncated towards the midpoint and projected into a shrinking ball around it; never
  more than one iteration more than bisection.
- `"newton"`: a safeguarded Newton iteration (Numerical Recipes' `rtsafe`, plus a
  bracket-closing phase). The slope comes with the value from one `jax.jvp` of the
  interpolated gap; the first point is regula falsi; a Newton point outside the bracket,
  or one that does not halve the step before the last, is replaced by the midpoint; once
  the Newton step is down to the gap's rounding, points at least one ulp inwards close
  the bracket onto adjacent floats.

Why ITP stays the default (grazejax issue 14, `benchmarks/bench_roots.py`): in single
runs Newton takes fewer iterations per call (mean / max, ITP → Newton: transversal
7.8 / 9 → 4.2 / 5, near grazing 12.3 / 19 → 5.2 / 6, Zeno 11.3 / 25 → 7.5 / 10), but a
sweep pays, per call, the slowest lane's count times every lane's cost of one iteration:
over a random-phase ex1dof sweep (Dopri8, 1e-8) the per-lane mean was 9.8 vs 9.2, with a
longer tail for Newton (max 38 against 21: near-grazing crossings converge linearly, like a
double root), and an iteration with a jvp costs more. Measured side by side, 256 lanes:
random phases 391 vs 641 µs per trajectory (ITP vs Newton), in phase within noise.
"""

import contextlib

import jax
import jax.lax as lax
import jax.numpy as jnp

_METHODS = ("newton", "itp")
_default_method = "itp"


@contextlib.contextmanager
def search_method(method: str):
    """Trace the loop's root searches with `method` (`"newton"` or `"itp"`) inside this
    block: for side-by-side benchmarks only (the choice is made at trace time)."""
    global _default_method
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    old, _default_method = _default_method, method
    try:
        yield
    finally:
        _default_method = old


def bracketed_root(
    fn, lo, hi, f_lo, f_hi, *, rel_width: float = 0.0, max_iter: int = 60, count: bool = False,
    method: str | None = None,
):
    """Locate the sign change of `fn` in `[lo, hi]`, given `f_lo > 0 >= f_hi`.

    Returns `(lo, hi)` with `fn(lo) > 0 >= fn(hi)` and `hi - lo` at most `rel_width` times
    the initial bracket, or a few ulps (the default; adjacent floats with `"newton"`).
    `hi` is the first point at or past the sign change. The result carries no
    derivative: callers apply one Newton step outside (the implicit function theorem) when they need tangents. `count=True` also
    returns the number of iterations (for tests and profiles). `method` is `"itp"` (the
    default, see the module docstring) or `"newton"`.

    Why to machine precision by default: the landing step's Newton correction leaves an
    error e²·|g''|/(2|g'|) for a proposal error e, which is not small near grazing or in a
    Zeno sequence (|g'| → 0) when the step is much longer than the flight (measured: a
    1e-10-of-a-step proposal gave 1e-8 relative flight-time errors late in a bouncing
    ball's Zeno sequence).
    """
    method = _default_method if method is None else method
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
    if method == "newton":
        out = _newton(fn, lo, hi, f_lo, f_hi, rel_width * (hi - lo), target, max_iter)
    elif method == "itp":
        out = _itp(fn, lo, hi, f_lo, f_hi, target, max_iter)
    else:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
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
        positive = f_guess > 0
        lo, f_lo = jnp.where(positive, guess, lo), jnp.where(positive, f_guess, f_lo)
        hi, f_hi = jnp.where(positive, hi, guess), jnp.where(positive, f_hi, f_guess)
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
    n_half = jnp.ceil(jnp.log2(jnp.maximum(width0 / target, 1.0)))
    n_max = jnp.minimum(n_half + 1, 1000.0)

    def not_done(carry):
        lo, hi, f_lo, f_hi, it = carry
        return (it < max_iter) & (hi - lo > target) & (f_hi != 0)

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
        radius = half_target * jnp.exp2(n_max - it) - 0.5 * width
        mid = jnp.where(jnp.abs(truncated - middle) <= radius, truncated, middle - towards * radius)
        mid = jnp.where((mid > lo) & (mid < hi), mid, middle)
        f_mid = fn(mid)
        positive = f_mid > 0
        lo, f_lo = jnp.where(positive, mid, lo), jnp.where(positive, f_mid, f_lo)
        hi, f_hi = jnp.where(positive, hi, mid), jnp.where(positive, f_hi, f_mid)
        return lo, hi, f_lo, f_hi, it + 1

    init = (lo, hi, f_lo, f_hi, jnp.zeros_like(lo))
    lo, hi, _, _, iterations = lax.while_loop(not_done, body, init)
    return lo, hi, iterations


def safe_divide(num, den, ok):
    """num / den where `ok`, else 0, with the double-`where` that keeps tangents finite."""
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def stop(x):
    return jax.lax.stop_gradient(x)
