"""Bracketed scalar root finding on a step's dense interpolant.

diffrax locates events with an unbracketed Newton iteration started at the step's end
(`_integrate.py`); on a high-order interpolant that can leave the step or fail to converge
(one cause of the `Dopri8` event errors noted in docs/design.md, *Diffrax traps*). Every root we look for is
already bracketed by a sign change inside one step, so a bracketed method is both safe and
fast: the Illinois variant of regula falsi converges superlinearly and never leaves the
bracket.
"""

import jax
import jax.lax as lax
import jax.numpy as jnp


def bracketed_root(fn, lo, hi, f_lo, f_hi, *, rel_width: float = 0.0, max_iter: int = 60):
    """Locate the sign change of `fn` in `[lo, hi]`, given `f_lo > 0 >= f_hi`.

    Returns `(lo, hi)` with `fn(lo) > 0 >= fn(hi)` and `hi - lo` at most `rel_width` times
    the initial bracket, or a few ulps (the default). `hi` is the first point at or past
    the sign change. The result carries no derivative: callers apply one Newton step
    outside (the implicit function theorem) when they need tangents.

    Why to machine precision by default: the landing step's Newton correction leaves an
    error e²·|g''|/(2|g'|) for a proposal error e, which is not small near grazing or in a
    Zeno sequence (|g'| → 0) when the step is much longer than the flight (measured: a
    1e-10-of-a-step proposal gave 1e-8 relative flight-time errors late in a bouncing
    ball's Zeno sequence).
    """
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

    def not_done(carry):
        lo, hi, f_lo, f_hi, _, it = carry
        return (it < max_iter) & (hi - lo > target) & (f_hi != 0)

    def body(carry):
        lo, hi, f_lo, f_hi, side, it = carry
        # Secant point between the bracket ends; f_lo > 0 >= f_hi keeps the denominator
        # non-zero. Fall back to bisection if round-off pushes it out of the open bracket.
        denom = f_lo - f_hi
        mid = hi - f_hi * (hi - lo) / jnp.where(denom > 0, denom, 1.0)
        bisect = 0.5 * (lo + hi)
        inside = (mid > lo) & (mid < hi)
        # Every sixth iteration bisect, which bounds the worst case on flat functions.
        mid = jnp.where(inside & (it % 6 != 5), mid, bisect)
        f_mid = fn(mid)
        positive = f_mid > 0
        # Illinois: when the same end is replaced twice running, halve the other end's
        # value so that the secant point moves across the root.
        f_hi = jnp.where(positive & (side == 1), 0.5 * f_hi, f_hi)
        f_lo = jnp.where(~positive & (side == -1), 0.5 * f_lo, f_lo)
        lo, f_lo = jnp.where(positive, mid, lo), jnp.where(positive, f_mid, f_lo)
        hi, f_hi = jnp.where(positive, hi, mid), jnp.where(positive, f_hi, f_mid)
        side = jnp.where(positive, 1, -1)
        return lo, hi, f_lo, f_hi, side, it + 1

    init = (lo, hi, f_lo, f_hi, jnp.array(0), jnp.array(0))
    lo, hi, *_ = lax.while_loop(not_done, body, init)
    return lo, hi


def safe_divide(num, den, ok):
    """num / den where `ok`, else 0, with the double-`where` that keeps tangents finite."""
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def stop(x):
    return jax.lax.stop_gradient(x)
