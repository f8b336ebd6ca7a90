"""A refilling pool of lanes: `sweep`'s answer to the slowest-lane problem.

A vmapped while loop runs until its slowest lane finishes (docs/design.md, *Batches*): a batch that mixes
2-impact and 200-impact lanes costs as if every lane had 200. The pool instead runs
`Program.step` (one solver step, see `_loop.program`) on `width` lane *slots*, and
whenever enough slots have finished it writes their results into the output rows of their
lanes and loads the next queued lanes into those slots. All of it is one XLA program: a
`lax.while_loop` of refills around a `lax.while_loop` of steps, with dynamic gathers and
scatters; every predicate is an unbatched scalar, so nothing is selected per lane per step.

Every lane computes exactly what `simulate` computes for it alone: the same `init`, then the
same `step` until it stops running (a finished lane is frozen by `step` itself, exactly as in
`simulate`'s loop), then the same `finish`. Which other lanes share the pool changes nothing
but the cost.

**The tail.** Once the queue is empty the pool can only drain: with k of `width` slots still
running, a step costs as much as with all of them. When at most `width // TAIL` slots are left
running, they are compacted into a pool of `width // TAIL` slots that runs to the end.
"""

from typing import Any

import equinox as eqx
import jax
import jax.lax as lax
import jax.numpy as jnp

from .._solution import Solution
from .policies import sliding_phases

# Refill once at least `width // REFILL` slots have finished (or none is running): a refill
# costs about one vmapped `init` and one whole-pool select, a few steps' worth; refilling
# less often leaves finished slots idle for longer. Tuned in benchmarks/bench_sweep.py.
REFILL = 8
# The drain pool is `width // TAIL` slots wide, for pools of at least MIN_TAIL_WIDTH slots.
TAIL = 8
MIN_TAIL_WIDTH = 256


def _where_rows(mask, new, old):
    """Row-wise select between two batched pytrees (rows = the leading axis)."""

    def pick(a, b):
        return jnp.where(mask.reshape(mask.shape + (1,) * (a.ndim - 1)), a, b)

    return jax.tree.map(pick, new, old)


def _freeze(carry, mask):
    # An empty slot must not run: mark it finished. `step` then leaves it unchanged.
    return eqx.tree_at(lambda c: c.done, carry, carry.done | mask)


def run_pool(
    program, x0s, args, in_axes: tuple[Any, Any], valid, width: int, on_finished=None
) -> Solution:
    """Run every valid lane of `(x0s, args)` through `program` on a refilling pool.

    **Arguments:**

    - `program`: a `_loop.program.Program` (init, step, running, finish of one lane).
    - `x0s`, `args`: the lanes' inputs; batched leaves carry the lanes along axis 0 as
      given by `in_axes = (x0 axis, args axes)` (`0` or `None`, as for `jax.vmap`).
    - `valid`: bool[lanes]; the valid lanes come first (the rest is padding, never run).
    - `width`: number of slots (static).
    - `on_finished`: optional host function, called (`jax.debug.callback`) with the number
      of lanes finished at each refill: progress reports.

    **Returns:** the lanes' `Solution`s stacked along axis 0 (padding rows are zeros).
    """
    num_lanes = valid.shape[0]
    count = jnp.sum(valid.astype(jnp.int32))
    width = max(1, min(width, num_lanes))
    refill_at = max(1, width // REFILL)
    # A narrow tail pool only pays for its compilation (a second copy of the step) when it
    # is much narrower than the pool; small sweeps care more about compile time.
    tail = width // TAIL if width >= MIN_TAIL_WIDTH else width

    init = jax.vmap(program.init, in_axes=in_axes)
    step, free_step = jax.vmap(program.step), jax.vmap(program.free_step)
    running = jax.vmap(program.running)
    finish = jax.vmap(program.finish)

    def load(lanes, ok):
        lanes = jnp.clip(lanes, 0, jnp.maximum(count - 1, 0))
        x = x0s if in_axes[0] is None else x0s[lanes]
        a = jax.tree.map(
            lambda leaf, axis: leaf if axis is None else leaf[lanes],
            args, in_axes[1], is_leaf=lambda v: v is None,
        )
        return _freeze(init(x, a), ~ok)

    # The pool starts empty (zeros, frozen): the first refill loads it, so that `init` is
    # compiled once. Output rows: index `num_lanes` is out of bounds and dropped (a slot
    # with nothing to write).
    shapes = jax.eval_shape(load, jnp.zeros(width, jnp.int32), jnp.zeros(width, bool))
    carry = _freeze(jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes),
                    jnp.ones(width, bool))
    out = jax.tree.map(
        lambda s: jnp.zeros((num_lanes,) + s.shape[1:], s.dtype), jax.eval_shape(finish, shapes)
    )
    slot_lane = jnp.full(width, -1)  # -1: an empty slot
    queue_at = jnp.array(0)  # the next lane to load

    def write(out, carry, slot_lane, rows):
        if on_finished is not None:
            jax.debug.callback(on_finished, jnp.sum(rows.astype(jnp.int32)))
        index = jnp.where(rows, slot_lane, num_lanes)
        return jax.tree.map(lambda o, v: o.at[index].set(v, mode="drop"), out, finish(carry))

    def num_running(carry):
        # (a running slot is occupied: empty and finished slots are frozen)
        return jnp.sum(running(carry).astype(jnp.int32))

    def draining(num_live, queue_empty):
        # Hand over to the narrow tail pool: the queue is empty and few slots still run.
        if tail == width:
            return jnp.array(False)
        return queue_empty & (num_live <= tail)

    # ---- phase 1: the pool, refilled from the queue ----

    def steps_cond(state):
        # One reduction per step: neither which slots are occupied nor the queue changes
        # while the pool steps.
        carry, occupied, queue_empty = state
        num_live = num_running(carry)
        stop = (num_live == 0) | (occupied - num_live >= refill_at)
        return ~(stop | draining(num_live, queue_empty))

    def steps_body(state):
        carry, occupied, queue_empty = state
        return step(carry), occupied, queue_empty

    def free_steps_body(state):
        carry, occupied, queue_empty = state
        return free_step(carry), occupied, queue_empty

    def refill_cond(state):
        carry, slot_lane, queue_at, _ = state
        more = jnp.any(slot_lane >= 0) | (queue_at < count)
        return more & ~draining(num_running(carry), queue_at >= count)

    def refill_body(state):
        carry, slot_lane, queue_at, out = state
        occupied = jnp.sum((slot_lane >= 0).astype(jnp.int32))
        carry, _, _ = _in_phases(
            steps_cond, steps_body, free_steps_body, program,
            (carry, occupied, queue_at >= count), carry_of=lambda state: state[0],
        )
        finished = (slot_lane >= 0) & ~running(carry)
        out = write(out, carry, slot_lane, finished)
        free = finished | (slot_lane < 0)
        lane = queue_at + jnp.cumsum(free.astype(jnp.int32)) - 1
        loaded = free & (lane < count)
        carry = _where_rows(loaded, load(lane, loaded), carry)
        slot_lane = jnp.where(loaded, lane, jnp.where(free, -1, slot_lane))
        queue_at = queue_at + jnp.sum(loaded.astype(jnp.int32))
        return carry, slot_lane, queue_at, out

    carry, slot_lane, queue_at, out = lax.while_loop(
        refill_cond, refill_body, (carry, slot_lane, queue_at, out)
    )
    if tail == width:
        return out

    # ---- phase 2: the tail, compacted into `tail` slots ----
    # Finished lanes are written first; the (at most `tail`) running ones move, in slot
    # order, to the narrow pool and run to the end there.
    live = running(carry) & (slot_lane >= 0)
    out = write(out, carry, slot_lane, (slot_lane >= 0) & ~live)
    order = jnp.argsort(~live, stable=True)[:tail]
    moved = live[order]
    carry = _freeze(jax.tree.map(lambda leaf: leaf[order], carry), ~moved)
    slot_lane = jnp.where(moved, slot_lane[order], -1)
    # (The tail keeps the one step: phases here would add two more copies of the step to
    # compile, for the last few lanes.)
    carry = lax.while_loop(lambda c: jnp.any(running(c)), step, carry)
    return write(out, carry, slot_lane, slot_lane >= 0)


def _in_phases(cond, body, free_body, program, state, *, carry_of):
    """`while cond: body`, with `free_body` while no slot slides (as `simulate` does, see
    `_loop/forward.py: staged_log_loop`): a `ZenoStick` sweep that never slides pays nothing for
    the sliding tests. `carry_of(state)` is the pool's carry."""
    if program.free_step is program.step:
        return lax.while_loop(cond, body, state)
    phases = sliding_phases(cond, body, free_body, lambda s: jnp.any(carry_of(s).stick))
    return lax.while_loop(cond, phases, state)
