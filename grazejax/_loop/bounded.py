"""`DirectAdjoint`'s loop: nested scans that both autodiff modes pass, whose recomputed steps
replay the first pass's step-size decisions.

A while loop of unknown length becomes reverse-differentiable as nested scans: `base`
iterations of `base` iterations of ... of one step, each guarded by a `lax.cond` on the
loop's predicate, every level above the innermost wrapped in `jax.checkpoint`, so that
memory grows with `base × levels` carries instead of one per step (Equinox's bounded loop,
which Diffrax's `DirectAdjoint` uses, is built so).

**Why not Equinox's.** `jax.checkpoint` recomputes a block of steps in the backward pass,
and XLA compiles that recomputation as part of another program: its fusions differ, so the
recomputed stages round differently in the last bits. The step-size controller amplifies
that: its error estimate is a difference of nearly equal stage sums (at rtol = 1e-12 an
ulp of a stage moves it by ~1e-4 relative), so the recomputed block took slightly
different steps, ended at a slightly different time, and the gradient was that of a
trajectory stitched from mismatched blocks. With all fusion disabled
(`XLA_FLAGS=--xla_disable_hlo_passes=fusion,cpu-instruction-fusion`) the gradient agreed
with forward mode to 7e-15; with Equinox's loop it differed by up to 7.4e-9 relative
(x'' = −x backward over [−40, 0], Tsit5, rtol = atol = 1e-12;
`tests/test_reverse.py::test_recomputed_steps_replay_the_first_pass`). Here the step's
decisions (step accepted, next step size) are named (`replay.decision`), and the checkpoint
policy saves exactly those (a few bytes per step): the recomputation takes the first
pass's steps, and the gradient agrees with forward mode to round-off. (The checkpointed
loops of `RecursiveCheckpointAdjoint`, which are not `jax.checkpoint`, replay a record
of the decisions instead: `reverse.py: checkpointed_deciding`.) It is also a little
faster than Equinox's loop (`benchmarks/README.md`).
"""

import equinox.internal as eqxi
import jax
import jax.numpy as jnp
from jax import lax

from .replay import DECISION

_REPLAY_DECISIONS = jax.checkpoint_policies.save_only_these_names(DECISION)


def bounded_while_loop(cond, step, init, max_steps: int, base: int = 16):
    """`while cond(c): c = step(c)`, at most `max_steps` iterations, differentiable in both
    modes. `step` must leave finished lanes unchanged (the impact loop's step freezes
    them): under `vmap` every lane steps while any lane runs."""
    size = base
    while size < max_steps:
        size *= base
    carry = (jnp.asarray(0), jax.tree.map(jnp.asarray, init))
    return _nested(cond, step, carry, size, base, max_steps)[1]


def _nested(cond, step, carry, size, base, max_steps):
    if size == 1:
        count, c = carry
        return count + 1, step(c)

    def one(carry, _):
        count, c = carry
        go = eqxi.unvmap_any(cond(c)) & (count < max_steps)
        inner = lambda z: _nested(cond, step, z, size // base, base, max_steps)  # noqa: E731
        return lax.cond(go, inner, lambda z: z, carry), None

    if size > base:
        one = jax.checkpoint(one, prevent_cse=False, policy=_REPLAY_DECISIONS)
    return lax.scan(one, carry, None, length=base)[0]
