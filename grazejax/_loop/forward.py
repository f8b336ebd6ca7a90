"""The forward-mode impact loop: `while cond: step` in phases, where they gain.

`staged_log_loop` writes a single run's impact log outside the loop that steps, and runs a
sliding policy's steps only while something slides; `mark_forward_only` names the fix when
someone asks it for reverse mode. Reverse mode's loops are in `reverse.py`.
"""

import math

import equinox as eqx
import equinox.internal as eqxi
import jax.lax as lax
import jax.numpy as jnp

from .._adjoint import REVERSE_HINT
from .._compiler import SEQUENTIAL_BUFFER_BYTES
from .compact import under_vmap
from .policies import sliding_phases
from .program import Program
from .state import flush_log, has_staged_rows, impact_log, stage_log


def staged_log_loop(cond, program: "Program", init):
    """`while cond: step`, in phases: the impact log written outside the loop that steps,
    and the steps of a sliding policy only while something slides.

    The inner loop steps with a staging log of one landing's rows and stops when a lane has
    staged one; the outer loop moves those rows to the full log and resumes. At batch 1
    the inner body then touches no buffer over XLA:CPU's 512-byte threshold for running
    its kernels in sequence (see `stage_log`); the outer body runs once per impact.

    Only where it gains: a single run or its `jacfwd` with a large log (an unused log costs
    nothing either way: XLA drops it). Not under `vmap`: every iteration there already
    touches large buffers, and the outer loop would stop whenever any lane impacts. A small
    log (≤ 512 bytes) needs none of it.

    With `ZenoStick`, the steps while no lane slides are `program.free_step` (no sliding
    field, no search for the end of sliding: a run that never slides would pay for the
    two per-step tests), and `program.step` runs from the
    landing that starts sliding until no lane slides; under `vmap` too (the phase changes
    only when a lane starts or ends sliding). Same values either way: `step`'s tests pick
    exactly `free_step`'s computation while nothing slides.
    """
    rows = program.log_rows_per_landing
    staging = stages_log(program, init)
    phased = program.free_step is not program.step
    if not staging and not phased:
        return lax.while_loop(cond, program.step, init)

    def more(z):
        return cond(z) & ~eqxi.unvmap_any(has_staged_rows(z)) if staging else cond(z)

    def steps_until_a_row(c):
        staged, full_log = stage_log(c, rows) if staging else (c, None)
        if phased:
            staged = sliding_phases(
                more, program.step, program.free_step,
                lambda z: eqxi.unvmap_any(jnp.any(z.stick)),
            )(staged)
        else:
            staged = lax.while_loop(more, program.step, staged)
        return flush_log(staged, full_log) if staging else staged

    return lax.while_loop(cond, steps_until_a_row, init)


def stages_log(program: "Program", init) -> bool:
    """Whether a single run's loop writes its impact log outside the loop that steps (see
    `staged_log_loop`)."""
    rows = program.log_rows_per_landing
    log_bytes = max(
        math.prod(jnp.shape(b)) * jnp.result_type(b).itemsize for b in impact_log(init)
    )
    return rows > 0 and log_bytes > SEQUENTIAL_BUFFER_BYTES and not under_vmap(init)


def mark_forward_only(tree):
    is_float = lambda leaf: eqx.is_inexact_array(leaf)  # noqa: E731
    floats, others = eqx.partition(tree, is_float)
    floats = eqxi.nondifferentiable_backward(floats, msg=REVERSE_HINT)
    return eqx.combine(floats, others)
