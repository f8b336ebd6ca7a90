"""Derivatives for values computed without them.

Diagnostics of a solve (an orbit's monodromy, its multipliers, its impacts) are computed
once on constants, so that solving is not slowed by derivatives nobody asked for. Returned
inside a differentiable result, they must not then differentiate to a silent 0: each is
either given its true forward-mode derivative (`with_forward_tangents`) or marked as having
none (`without_derivative`: its tangent is NaN).
"""

import jax
import jax.numpy as jnp


def with_forward_tangents(jvp, values, primals):
    """`values` (computed without derivatives) with the tangents `jvp(primals, tangents)[1]`:
    `jvp` is the forward-mode derivative of the function that computed them (e.g. a compiled
    `jax.jvp`), run only when asked for.

    Under `jax.grad` a tangent that needs the transpose of a loop raises JAX's own error
    (never a 0).
    """

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


@jax.custom_jvp
def undefined_derivative(value, undefined):
    """`value`, whose derivative is NaN where `undefined` (a boolean array) holds, itself
    elsewhere: for a value that has no derivative where it is computed (an event time at a
    tangential contact). The rule is linear in the tangent (a factor NaN or 1), so reverse
    mode, which transposes it, gives NaN there too and the plain cotangent elsewhere (a
    `jnp.where` between two branches would send NaN · 0 = NaN into both)."""
    return value


@undefined_derivative.defjvp
def _undefined_derivative_jvp(primals, tangents):
    value, undefined = primals
    value_dot, _ = tangents
    factor = jnp.where(undefined, jnp.nan, 1.0).astype(jnp.result_type(value))
    return value, factor * value_dot
