"""Phases compacted to the lanes that need them (`grazejax/_loop/compact.py`).

A lane's result must not depend on which other lanes share the batch: the compacted
batching rule is checked against the plain per-lane `cond` (a loop over lanes) for batches
below, at and above the sub-batch width, with every mask pattern, under jit, closing over
traced values, and differentiated in both nestings of jacfwd and vmap. Then the loop
itself: random-phase ex1dof lanes (where some lane searches or lands on almost every
iteration) give the same bits whichever lanes share their batch, and agree with single
runs to 1e-13 (vmap and a single run differ by XLA's vectorisation alone, as before).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex
from grazejax._loop.compact import compacted_width, per_lane


def _phase(ops):
    # A phase with a data-dependent inner loop, as the root searches have.
    x, k = ops
    n, y = jax.lax.while_loop(lambda c: c[1] < 10.0, lambda c: (c[0] + 1, c[1] * k), (0, x))
    return y + jnp.sin(x), n


def _nothing(ops):
    return -ops[0], jnp.array(-1)


def _plain(x, k, need):
    return jax.lax.cond(need, _phase, _nothing, (x, k))


@pytest.mark.parametrize("lanes", [1, 8, 9, 130])
@pytest.mark.parametrize(
    "pattern", ["none", "all", "random", "first", "last", "block", "tail", "alternate"]
)
def test_batch_equals_loop(lanes, pattern):
    # (neighbouring lanes are sliced, others gathered: "block" and "tail" mix both, with a
    # last round padded past the batch)
    rng = np.random.default_rng(lanes)
    x = jnp.asarray(rng.uniform(0.5, 2.0, lanes))
    index = np.arange(lanes)
    need = {
        "none": np.zeros(lanes, bool), "all": np.ones(lanes, bool),
        "random": rng.uniform(size=lanes) < 0.2,
        "first": index == 0, "last": index == lanes - 1,
        "block": (index >= lanes // 5) & (index < lanes - lanes // 3),
        "tail": index >= lanes - (lanes * 2) // 5, "alternate": index % 2 == 0,
    }[pattern]
    batched = jax.jit(jax.vmap(lambda x, n: per_lane(_phase, n, (x, 1.7), _nothing)))(
        x, jnp.asarray(need)
    )
    for i in range(lanes):
        want = _plain(x[i], 1.7, need[i])
        assert float(batched[0][i]) == float(want[0])
        assert int(batched[1][i]) == int(want[1])
    assert compacted_width(lanes) <= lanes


def test_closing_over_traced_values_in_a_loop():
    # The rule runs while JAX batches the enclosing while loop: a phase closing over a
    # jit-traced value must not leak it (it is hoisted into the operands).
    def run(x, k):
        def body(c):
            i, y = c
            out = per_lane(lambda ops: (ops * k, ops), y > 0.5, y, lambda ops: (ops, ops))
            return i + 1, out[0]

        return jax.lax.while_loop(lambda c: c[0] < 3, body, (0, x))[1]

    x = jnp.array([0.1, 0.7, 1.0])
    got = jax.jit(lambda x, k: jax.vmap(lambda xi: run(xi, k))(x))(x, 2.0)
    np.testing.assert_array_equal(got, [0.1, 5.6, 8.0])


def test_differentiable_phase_in_both_nestings():
    def run(x):
        def body(c):
            i, y = c
            out = per_lane(
                lambda ops: ops * jnp.cos(ops), y > 0.5, y, lambda ops: ops, differentiable=True
            )
            return i + 1, out

        return jax.lax.while_loop(lambda c: c[0] < 3, body, (0, x))[1]

    def plain(x):
        y = x
        for _ in range(3):
            y = jnp.where(y > 0.5, y * jnp.cos(y), y)
        return y

    x = jnp.array([0.1, 0.7, 1.0, 2.5])
    want = jax.vmap(jax.grad(plain))(x)
    np.testing.assert_allclose(jnp.diag(jax.jacfwd(jax.vmap(run))(x)), want, rtol=1e-14)
    np.testing.assert_allclose(jax.vmap(jax.jacfwd(run))(x), want, rtol=1e-14)
    np.testing.assert_allclose(jax.vmap(run)(x), jax.vmap(plain)(x), rtol=1e-15)


def test_random_phase_lanes_do_not_depend_on_their_companions():
    # ex1dof near its μ = 0.2 cycle, from states at random phases: lanes search and land
    # on different iterations, so the compacted phases run on changing sub-batches. A
    # lane's result is the same whichever lanes share its batch (vmap against single
    # runs differs by XLA's vectorisation alone: within 1e-13 here, as before compaction).
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    rng = np.random.default_rng(0)
    phases = jnp.asarray(np.sort(rng.uniform(0.0, 2 * np.pi, 24)))
    cycle = gj.simulate(scene, jnp.array([0.0, 0.0384224329]), 0.0, 2 * np.pi, args,
                        saveat=phases, rtol=1e-12, atol=1e-12, max_impacts=10)

    def one(x0):
        return gj.simulate(scene, x0, 0.0, jnp.inf, args, rtol=1e-10, atol=1e-10,
                           max_impacts=4, direction=1)

    batch = jax.jit(jax.vmap(one))
    everyone = batch(cycle.xs)
    assert np.all(np.asarray(everyone.status) == int(gj.Status.MAX_IMPACTS))
    order = rng.permutation(24)
    shuffled = batch(cycle.xs[order])
    np.testing.assert_array_equal(shuffled.impact_times, everyone.impact_times[order])
    np.testing.assert_array_equal(shuffled.x_final, everyone.x_final[order])
    np.testing.assert_array_equal(shuffled.num_steps, everyone.num_steps[order])
    few = batch(cycle.xs[::5])
    np.testing.assert_array_equal(few.impact_times, everyone.impact_times[::5])
    alone = jax.jit(one)
    for i in range(0, 24, 7):
        single = alone(cycle.xs[i])
        np.testing.assert_allclose(everyone.impact_times[i], single.impact_times, rtol=0,
                                   atol=1e-13)
        assert int(everyone.num_steps[i]) == int(single.num_steps)
