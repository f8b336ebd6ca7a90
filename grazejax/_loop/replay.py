"""Step decisions that reverse mode replays when it runs steps again.

A step decides whether it is accepted and how long the next step is. Reverse mode runs
steps again from checkpoints (Equinox's checkpointed loops, `jax.checkpoint` in
`bounded.py`), and XLA compiles that re-run in another program, whose fusions round the
stages differently in the last bits. The step-size controller's error estimate, a
difference of nearly equal stage sums, turns that into other steps, and the gradient
becomes that of a trajectory stitched from mismatched pieces (x'' = −x backward over
[−40, 0], Tsit5, rtol = 1e-12: grad differed from jacfwd by up to 3.3e-8 with the default
checkpoints, 5.1e-6 with 30, 7.4e-9 with `DirectAdjoint`;
`tests/test_reverse.py::test_recomputed_steps_replay_the_first_pass`). So the first pass's
decisions are kept (a record of rows `(h_next, keep)`, one per step, or `jax.checkpoint`
residuals named `DECISION`) and a re-run replays them.
"""

import jax.numpy as jnp
from jax.ad_checkpoint import checkpoint_name

DECISION = "grazejax_step_decision"
NO_DECISIONS = (jnp.nan, False)  # (h_next, keep) of a step not yet taken


def decision(value):
    """`value`, marked as a step decision that `jax.checkpoint`'s policy saves."""
    return checkpoint_name(value, DECISION)


def replay_decisions(decided, forced):
    """`forced` where it was recorded (its step size is not NaN), else `decided`.

    (See the module docstring.)
    """
    if forced is None:
        return decided
    recorded = ~jnp.isnan(forced[0])
    return tuple(jnp.where(recorded, f, d) for f, d in zip(forced, decided, strict=True))


def unrecorded_decisions(template_time, shape):
    """A record of step decisions `(h_next, keep)` for `shape` steps, none recorded yet
    (step sizes in `template_time`'s dtype)."""
    h, keep = NO_DECISIONS
    return (jnp.full(shape, h, jnp.result_type(template_time)), jnp.full(shape, keep))


def row(record, i):
    """Row(s) `i` of a record (or of Equinox buffers: indexed leaf by leaf, as a tree map
    would enter the buffer objects)."""
    return tuple(leaf[i] for leaf in record)


def set_row(record, i, decisions):
    return tuple(leaf.at[i].set(d) for leaf, d in zip(record, decisions, strict=True))
