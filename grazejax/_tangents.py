"""Derivatives for values computed without them.

Diagnostics of a solve (an orbit's monodromy, its multipliers, its impacts) are computed
once on constants, so that solving is not slowed by derivatives nobody asked for. Returned
inside a differentiable result, they must not then differentiate to a silent 0: each is
either given its true forward-mode derivative (`with_forward_tangents`) or marked as having
none (`without_derivative`: its tangent is NaN).
"""

import jax
import jax.numpy as jnp


def with_forward_tangents(fn, values, primals, jvp=None):
    """`values` (equal to `fn(*primals)`, computed without derivatives), whose tangents are
    those of `fn` at `primals`: the forward-mode derivative is computed only when asked for.

    `jvp(primals, tangents)`, if given, is `jax.jvp(lambda p: fn(*p), ...)` compiled once.
    `fn`'s own computation must be differentiable in forward mode; under `jax.grad` a
    tangent that needs the transpose of a loop raises JAX's own error (never a 0).
    """
    if jvp is None:
        jvp = lambda p, t: jax.jvp(lambda pr: fn(*pr), (p,), (t,))  # noqa: E731

    @jax.custom_jvp
    def attach(values, primals):
        return values

    @attach.defjvp
    def attach_jvp(p, t):
        values, primals = p
        _, primals_dot = t
        return values, jvp(primals, primals_dot)[1]

    return attach(values, primals)


@jax.custom_jvp
def without_derivative(value, deps):
    """`value`, whose derivative with respect to `deps` is NaN (a quantity that depends on
    them but has no meaningful derivative, e.g. a solve's residual)."""
    return value


@without_derivative.defjvp
def _without_derivative_jvp(primals, tangents):
    value, _ = primals
    return value, jnp.full(jnp.shape(value), jnp.nan, jnp.result_type(value))
