"""The loop that stores each step's linearisation (`grazejax/_loop/stored.py`).

Against `lax.while_loop` differentiated in forward mode: the same primal bits, and
`jax.grad` equal to `jax.jacfwd` for loops with integer leaves, parameters closed over,
buffers written once, blocks ended early, a step bound that cuts the loop, under `vmap`
and `jit`, for several block sizes; and steps stored apart (`apart=`, the impact loop's
landings) against the same loop with a `cond` between the two kinds of step."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax import lax

from grazejax._loop.stored import stored_while_loop

ROWS = 12  # buffer rows: one per "landing" of the model loop


def model(p, *, stored, max_steps=400, block=8, dt=0.01, t1=2.5, apart=None):
    """A pendulum stepped by explicit Euler, with a "landing" every 25 steps whose state is
    written to a row of a buffer (as the impact log's rows are). With `apart = (kicks,
    rows)`, a step from a state whose count n has `n % 25` in `kicks` is another kind of
    step (a velocity kick that depends on the parameters), stored apart in `rows` rows."""
    w, damping = p[0], p[1]

    def cond(c):
        return c["t"] < t1

    def step(c):
        x, v = c["y"]
        y = jnp.stack([x + dt * v, v - dt * (w**2 * jnp.sin(x) + damping * v)])
        n = c["n"] + 1
        return {"t": c["t"] + dt, "y": y, "n": n, "landed": n % 25 == 0}

    def write(c, buffer):
        row = jnp.minimum(c["n"] // 25 - 1, ROWS - 1)
        value = c["y"][0] * jnp.cos(c["y"][1])
        return buffer.at[row].set(jnp.where(c["landed"], value, buffer[row]))

    def kicked(c):
        out = step(c)
        x, v = out["y"]
        return {**out, "y": jnp.stack([x, -0.8 * v + damping * jnp.cos(w * x)])}

    def is_kicked(c):
        return jnp.isin(c["n"] % 25, jnp.asarray(apart[0])) if apart else jnp.asarray(False)

    init = {"t": jnp.asarray(0.0), "y": p[2:], "n": jnp.asarray(0), "landed": jnp.asarray(False)}
    buffer = jnp.zeros(ROWS)
    if stored:
        final, buffer = stored_while_loop(
            cond, step, init, max_steps, buffers=buffer, write=write,
            ends_block=lambda c: c["landed"], block=block,
            apart=(is_kicked, kicked, apart[1]) if apart else None,
        )
    else:
        def body(carry):
            k, c, buffer = carry
            c = lax.cond(is_kicked(c), kicked, step, c)
            return k + 1, c, write(c, buffer)

        _, final, buffer = lax.while_loop(
            lambda carry: (carry[0] < max_steps) & cond(carry[1]), body,
            (jnp.asarray(0), init, buffer),
        )
    return final, buffer


def loss(p, **kw):
    final, buffer = model(p, **kw)
    weights = jnp.arange(1.0, ROWS + 1.0)
    return jnp.sum(final["y"] ** 2) + final["t"] + jnp.sum(weights * buffer)


P = jnp.array([1.3, 0.2, 0.5, -0.3])


def close(a, b):
    # Both modes sum the same terms in different orders: a few ulps per step.
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12 * float(jnp.max(jnp.abs(b))))


def test_primal_bits_equal_the_plain_loop():
    for kw in ({}, {"max_steps": 60}):
        (a, buf_a), (b, buf_b) = model(P, stored=True, **kw), model(P, stored=False, **kw)
        for key in a:
            np.testing.assert_array_equal(a[key], b[key])
        np.testing.assert_array_equal(buf_a, buf_b)
    assert int(model(P, stored=True, max_steps=60)[0]["n"]) == 60  # the bound cuts the loop


@pytest.mark.parametrize("block", [1, 3, 8])
@pytest.mark.parametrize("max_steps", [400, 60, 251])
def test_grad_equals_jacfwd(block, max_steps):
    reverse = jax.grad(lambda p: loss(p, stored=True, block=block, max_steps=max_steps))(P)
    forward = jax.jacfwd(lambda p: loss(p, stored=False, max_steps=max_steps))(P)
    assert np.all(np.abs(forward) > 0)
    close(reverse, forward)


def test_grad_equals_central_differences():
    reverse = jax.grad(lambda p: loss(p, stored=True))(P)
    h = 1e-6
    for i in range(P.shape[0]):
        e = jnp.zeros_like(P).at[i].set(h)
        diff = (loss(P + e, stored=True) - loss(P - e, stored=True)) / (2 * h)
        np.testing.assert_allclose(reverse[i], diff, rtol=1e-6)


def test_forward_pass_stores_what_the_primal_computes():
    """`jax.vjp`'s primal output equals the plain run's, and the pullback is linear."""
    out, pullback = jax.vjp(lambda p: loss(p, stored=True), P)
    assert out == loss(P, stored=False)
    (g1,), (g2,) = pullback(1.0), pullback(2.5)
    close(g2, 2.5 * g1)


def test_under_vmap_and_jit():
    ps = jnp.stack([P, P * 1.1, P * jnp.array([0.9, 1.5, -1.0, 2.0])])
    # A batched stopping time (t1): the loop's predicate is then batched too.
    t1s = jnp.array([2.5, 1.0, 1.7])
    grad = jax.jit(jax.vmap(jax.grad(lambda p, t1: loss(p, stored=True, t1=t1))))
    forward = jax.vmap(jax.jacfwd(lambda p, t1: loss(p, stored=False, t1=t1)))
    close(grad(ps, t1s), forward(ps, t1s))


def test_closed_over_values_not_differentiated():
    """A traced value the loop closes over but the loss is not differentiated with
    respect to (here t1 under jit) stays a constant of the loop."""
    grad = jax.jit(jax.grad(lambda p, t1: loss(p, stored=True, t1=t1)))
    close(grad(P, 1.3), jax.jacfwd(lambda p: loss(p, stored=False, t1=1.3))(P))


@pytest.mark.parametrize("block", [1, 3, 8])
@pytest.mark.parametrize("max_steps", [400, 60, 251])
@pytest.mark.parametrize("kicks", [(24,), (0, 7), (23, 24)])
def test_steps_stored_apart(block, max_steps, kicks):
    """Primal bits, and grad = jacfwd, with steps of another kind stored apart: after a
    landing, at a block's start, in the middle of a block, two in a row."""
    apart = (kicks, 40)
    for key, value in model(P, stored=True, apart=apart, max_steps=max_steps)[0].items():
        np.testing.assert_array_equal(
            value, model(P, stored=False, apart=apart, max_steps=max_steps)[0][key])
    reverse = jax.grad(
        lambda p: loss(p, stored=True, block=block, max_steps=max_steps, apart=apart))(P)
    forward = jax.jacfwd(lambda p: loss(p, stored=False, max_steps=max_steps, apart=apart))(P)
    close(reverse, forward)
    plain = jax.jacfwd(lambda p: loss(p, stored=False, max_steps=max_steps))(P)
    assert np.max(np.abs(forward - plain)) > 1e-3  # the kicks matter


def test_more_steps_apart_than_rows_is_a_nan_gradient():
    """A bound on the steps stored apart that the run exceeds gives NaN, not a gradient
    through overwritten rows."""
    few = jax.grad(lambda p: loss(p, stored=True, apart=((24,), 3)))(P)
    assert np.all(np.isnan(few))
    enough = jax.grad(lambda p: loss(p, stored=True, apart=((24,), 10)))(P)
    close(enough, jax.jacfwd(lambda p: loss(p, stored=False, apart=((24,), 10)))(P))
