"""How the impact loop runs: one class per kind of loop that an `adjoint` asks for.

Each kind builds and runs its own loop over the program's phases (as a Diffrax adjoint runs
its own loop): `ForwardLoop` (the default: a `lax.while_loop`, forward-mode derivatives),
`CheckpointedLoop` (`diffrax.RecursiveCheckpointAdjoint`: reverse mode) and `BoundedLoop`
(`diffrax.DirectAdjoint`: both modes). `loop_for` maps `_adjoint.loop_kinds`' reading of
the user's adjoint to one of them.
"""

import abc

import equinox as eqx

from .._adjoint import LoopKinds
from .bounded import bounded_while_loop
from .forward import mark_forward_only, staged_log_loop, stages_log
from .program import Program
from .reverse import (
    checkpoint_count,
    checkpointed_deciding,
    every_step_staged,
    every_step_stored,
    two_level_checkpointed,
)
from .state import packing


class AbstractLoop(eqx.Module):
    """A way to run `while cond: program.step` from a loop state."""

    @abc.abstractmethod
    def run(self, cond, program: Program, init, max_steps: int):
        """The final loop state, after at most `max_steps + 1` iterations from `init`."""


class ForwardLoop(AbstractLoop):
    """A `lax.while_loop` with the staged impact log (`forward.py`): the primal's cost,
    `jax.jvp`/`jax.jacfwd` only (reverse mode raises an error that names the adjoints)."""

    def run(self, cond, program, init, max_steps):
        return mark_forward_only(staged_log_loop(cond, program, init))


class CheckpointedLoop(AbstractLoop):
    """Reverse mode (`reverse.py`): with `checkpoints=None` two levels of checkpoints
    (~√max_steps); with a checkpoint per step, every step's linearisation stored (or its
    log rows staged) and no step run twice; otherwise Equinox's recursive schedule with
    `checkpoints` checkpoints."""

    checkpoints: int | None

    def run(self, cond, program, init, max_steps):
        bound = max_steps + 1
        checkpoints = checkpoint_count(self.checkpoints, max_steps)
        if checkpoints is None:
            return two_level_checkpointed(cond, program, init, bound)
        if checkpoints == bound:
            final = every_step_stored(cond, program, init, bound)  # (None: does not pay)
            if final is not None:
                return final
            if stages_log(program, init):
                return every_step_staged(cond, program, init, bound)
        pack, unpack = packing(init)
        final, _ = checkpointed_deciding(
            lambda packed: cond(unpack(packed)), program, pack, unpack, init, bound,
            checkpoints, buffers=True,
        )
        return unpack(final)


class BoundedLoop(AbstractLoop):
    """Nested scans whose recomputation replays the step decisions (`bounded.py`): both
    modes, at the memory of every step. The log stays in the carry: as Equinox buffers it
    cost about twice as much (`benchmarks/README.md`)."""

    def run(self, cond, program, init, max_steps):
        return bounded_while_loop(cond, program.step, init, max_steps + 1)


def loop_for(kinds: LoopKinds) -> AbstractLoop:
    """The loop of an adjoint's `LoopKinds` (`_adjoint.loop_kinds`)."""
    if kinds.outer == "lax":
        return ForwardLoop()
    if kinds.outer == "checkpointed":
        return CheckpointedLoop(kinds.checkpoints)
    return BoundedLoop()
