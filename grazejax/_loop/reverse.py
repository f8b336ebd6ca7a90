"""The impact loop in reverse mode: the loops that `jax.grad` differentiates.

Which loop runs is `CheckpointedLoop`'s choice (`runners.py`, by `adjoint`):
`two_level_checkpointed` (the default `RecursiveCheckpointAdjoint()`), `every_step_stored`
or `every_step_staged` (a checkpoint per step), `checkpointed_deciding` (Equinox's
checkpointed loop with a given number of checkpoints). Every loop that runs steps again in
its backward pass replays the first pass's step decisions (`replay.py`).
"""

import math

import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp

from .compact import under_vmap
from .forward import stages_log
from .program import Program
from .replay import row, set_row, unrecorded_decisions
from .state import flush_log, has_staged_rows, impact_log, packing, stage_log, with_full_log
from .stored import stored_while_loop


def two_level_checkpointed(cond, program: "Program", init, bound: int):
    """`while cond: step` for at most `bound` iterations, reverse-differentiable with
    two levels: an Equinox checkpointed loop stores the state every `chunk ≈ √bound`
    steps, and each chunk is a loop that stores its steps' linearisations
    (`_loop/stored.py`) while the backward pass crosses it, or, where a step's residuals
    are large (`storing_limit`), an Equinox loop with a checkpoint per step. The price is
    one more forward pass over each chunk; memory: ~√bound carries and `chunk` rows of
    residuals (or carries), whatever the run's length.

    History, forced impact oscillator, one core, min of 7, each against the previous code
    in the same minutes: Equinox's own schedule (√(2·bound) ≈ 447 checkpoints, recursive
    recomputation) 10.2/11.0x the primal at 100/1000 impacts -> two levels of Equinox
    loops with a checkpoint per iteration 8.0/8.3x; the log staged (below) 5.9/6.7/6.8x
    at 10/100/1000 impacts; each step as a nested computation (`_nested`)
    4.7/4.8/5.0x; the chunks as loops that store linearisations (no step of a chunk run
    a third time in the backward pass) 4.53/4.69/4.96x -> 3.97/4.16/4.42x (same process,
    min of 9), gradients bit-equal; a landing's residuals stored apart
    (`_landings_apart`) 4.30/4.70/4.76x -> 3.35/3.34/3.42x (another machine, separate
    processes, min of 7/7/3). The chunk length mattered little (64 or 2048 steps: within 1%).

    The backward pass runs each chunk again from its checkpoint: the first pass records
    every step's decisions (a row per step, a write-once buffer) and the re-run replays
    them (`_loop/replay.py`), so that XLA's different
    rounding of the re-run cannot make it take other steps (gradients were off by up to
    3.3e-8 relative at rtol = 1e-12). Cost, alternately with the code before (two rounds):
    4.2-4.5/4.5/4.5-4.6x the primal at 10/100/1000 impacts against 3.8-4.3/4.3/4.5x.

    Where a single run stages its log (`stages_log`), an outer iteration also ends at a
    landing that wrote rows, and moves them to the full log (the outer loop's write-once
    buffers; ~one more carry per log row). The inner loop then carries one landing's rows
    instead of the whole log, so its passes run on XLA's sequential executor as the
    primal does.
    """
    chunk = math.isqrt(bound - 1) + 1
    outer_bound = -(-bound // chunk)
    pack, unpack = packing(init)
    staging = stages_log(program, init)
    if staging:
        rows = program.log_rows_per_landing
        # An outer iteration runs a whole chunk, or stops at a landing with rows (at most
        # one per row of the log, and the one that fills it ends the run), or at the end.
        outer_bound += impact_log(init)[0].shape[0] + 2
        inner_pack, inner_unpack = packing(stage_log(init, rows)[0])
    else:
        inner_pack, inner_unpack = pack, unpack

    def inner_cond(packed):
        z = inner_unpack(packed)
        return cond(z) & ~eqxi.unvmap_any(has_staged_rows(z)) if staging else cond(z)

    limit = storing_limit(init)
    # The step decisions, recorded by the first pass and replayed where the backward pass
    # runs a chunk again (`_loop/replay.py`): row n for a lane's step n
    # (a chunk writes `chunk` rows from its first step; rows past its last step are
    # written again by the next chunk), an Equinox buffer (its backward pass reads it
    # filled). (A row per outer iteration would grow with the log: staged landings end
    # outer iterations.)
    record = unrecorded_decisions(init.s, (bound + chunk,))

    def outer_step(carry):
        packed, record = carry
        c = unpack(packed)
        chunk_steps = c.num_steps + jnp.arange(chunk)
        forced = jax.lax.stop_gradient(row(record, chunk_steps))
        staged, full_log = stage_log(c, rows) if staging else (c, None)
        stored = limit >= 0 and stored_while_loop(
            inner_cond, _packed_deciding(program, inner_pack, inner_unpack, False),
            inner_pack(staged), chunk, replay=forced,
            apart=_landings_apart(
                program, inner_unpack, chunk,
                _packed_deciding(program, inner_pack, inner_unpack, True)),
            max_residual_bytes=limit,
        )
        if stored:
            staged, _, decided = stored
        else:
            staged, decided = checkpointed_deciding(
                inner_cond, program, inner_pack, inner_unpack, staged, chunk, chunk,
                buffers=not staging, forced=forced)
        staged = inner_unpack(staged)
        record = set_row(record, chunk_steps, decided)
        return pack(flush_log(staged, full_log) if staging else staged), record

    final, _ = eqxi.while_loop(
        lambda carry: cond(unpack(carry[0])), outer_step, (pack(init), record),
        max_steps=outer_bound, kind="checkpointed", checkpoints=outer_bound,
        buffers=lambda carry: (carry[0][1], carry[1]),
    )
    return unpack(final)


def _packed_deciding(program: "Program", pack, unpack, landing: bool | None = None):
    """`program.deciding_step` on packed states (`landing`: see `Program.lands`)."""

    def step(packed, forced):
        c, decided = program.deciding_step(unpack(packed), forced, landing=landing)
        return pack(c), decided

    return step


def _landings_apart(program: "Program", unpack, bound: int, landing_step):
    """`stored_while_loop`'s `apart` for the impact loop: a landing step's residuals (the
    jump, its saltation, the log rows, ...) in rows of their own, and the other steps'
    rows without them. A landing never follows a landing (a step that lands does not
    search: `program._next_state`), so a loop of `bound` steps has at most ⌈bound/2⌉.
    Forced impact oscillator: 864 bytes a step with the landing branch, 566 without."""
    return (lambda packed: program.lands(unpack(packed)), landing_step, (bound + 1) // 2 + 1)


def checkpointed_deciding(cond, program: "Program", pack, unpack, c, bound: int,
                           checkpoints: int, *, buffers: bool, forced=None):
    """`while cond(packed): step` from `c`, at most `bound` steps, in Equinox's
    checkpointed loop (each step nested, `_nested`), replaying recorded step decisions
    (`_loop/replay.py`): those of `forced` (one row per step, from an earlier pass), else
    the loop's own record (a write-once buffer: Equinox's backward pass, which runs steps
    again from its checkpoints, reads it filled). Returns the packed state and the
    decisions taken."""
    step = _nested(program.deciding_step, pack, unpack, deciding=True)

    def body(carry):
        packed, j, decided = carry
        packed, taken = step(packed, row(decided if forced is None else forced, j))
        return packed, j + 1, set_row(decided, j, taken)

    packed, _, decided = eqxi.while_loop(
        lambda carry: cond(carry[0]), body,
        (pack(c), jnp.asarray(0), unrecorded_decisions(c.s, (bound,))),
        max_steps=bound, kind="checkpointed", checkpoints=checkpoints,
        buffers=lambda carry: (carry[0][1], carry[2]) if buffers else carry[2],
    )
    return packed, decided


def every_step_stored(cond, program: "Program", init, bound: int):
    """`while cond: step` for at most `bound` steps, every step's linearisation stored
    (`_loop/stored.py`): the backward pass applies the stored pullbacks and runs no step
    again. Where a single run stages its log (`stages_log`), the loop carries one
    landing's rows and writes them to the full log (write-once buffers) after the step
    that staged them. Forced impact oscillator, 1000-row log, one core, min of 9, against
    Equinox's checkpointed loop with a checkpoint per step in the same process:
    3.56/3.76/3.92x -> 2.94/3.24/3.76x the primal at 10/100/1000 impacts; with a landing's
    residuals stored apart (`_landings_apart`) 3.07/3.40/3.84x -> 2.26/2.43/2.70x (another
    machine, separate processes, min of 7/7/3).

    None where a step's residuals are over `storing_limit`: storing them does not pay."""
    limit = storing_limit(init)
    if limit < 0:
        return None
    if not stages_log(program, init):
        pack, unpack = packing(init)

        def plain(landing):
            return lambda packed: pack(program.step(unpack(packed), landing=landing))

        stored = stored_while_loop(
            lambda packed: cond(unpack(packed)), plain(False), pack(init), bound,
            apart=_landings_apart(program, unpack, bound, plain(True)),
            max_residual_bytes=limit,
        )
        return stored and unpack(stored[0])
    staged, full_log = stage_log(init, program.log_rows_per_landing)
    pack, unpack = packing(staged)

    def step(landing):
        return lambda packed: pack(_staging_own_rows(program, landing)(unpack(packed)))

    stored = stored_while_loop(
        lambda packed: cond(unpack(packed)), step(False), pack(staged), bound,
        apart=_landings_apart(program, unpack, bound, step(True)),
        buffers=full_log,
        write=lambda packed, log: impact_log(flush_log(unpack(packed), log)),
        ends_block=lambda packed: eqxi.unvmap_any(has_staged_rows(unpack(packed))),
        max_residual_bytes=limit,
    )
    return stored and with_full_log(unpack(stored[0]), stored[1])


def every_step_staged(cond, program: "Program", init, bound: int):
    """`while cond: step`, every step a checkpoint, with the impact log staged: the loop
    carries one landing's rows, and each iteration moves the rows its step wrote to the
    full log (the loop's write-once buffers) after the step. The step itself, and its VJP,
    then run in a nested computation with small buffers only (`_nested`), while the full
    log is written outside it: a gradient with a large log costs less than with the log in
    the step's buffers, with the same results (`tests/test_reverse.py`)."""
    staged, full_log = stage_log(init, program.log_rows_per_landing)
    pack, unpack = packing(staged)

    nested = _nested(_staging_own_rows(program), pack, unpack)

    def body(carry):
        small, log = carry
        small = nested(small)
        return small, impact_log(flush_log(unpack(small), log))

    small, log = eqxi.while_loop(
        lambda carry: cond(unpack(carry[0])), body, (pack(staged), full_log),
        max_steps=bound, kind="checkpointed", checkpoints=bound,
        buffers=lambda carry: carry[1],
    )
    return with_full_log(unpack(small), log)


def _staging_own_rows(program: "Program", landing: bool | None = None):
    """The step of the every-step loops that stage the log: row 0 of the staging log is
    the next impact, so each step stages its own rows (flushed after it)."""

    def step(c):
        return program.step(eqx.tree_at(lambda z: z.log_base, c, c.num_impacts),
                            landing=landing)

    return step


def _nested(step, pack, unpack, *, deciding: bool = False):
    """The checkpointed loops' body `pack(step(unpack(packed)))`, run as a nested
    computation: the branch of a `cond` whose predicate is true whenever the body runs
    (num_steps ≥ 0; XLA cannot fold it), unbatched so that `vmap` keeps it a `cond`.
    With `deciding`, `step` is `program.deciding_step` and the body
    `(packed, forced decisions) -> (packed, decisions taken)`.

    Why: XLA:CPU runs a sequence of kernels one after another only if none touches a
    buffer over 512 bytes (see `stage_log`), and decides it per sequence: a loop body and
    each branch of a conditional are sequences of their own. An Equinox checkpointed loop's
    body reads and writes its store of checkpoints, so the whole step (and its VJP in the
    backward loop) ran on the dataflow executor, whose bookkeeping was ~65% of a gradient's
    time (perf, forced impact oscillator, 100 impacts). In a branch, the step and its VJP
    (JAX linearizes and transposes a `cond` branch-wise) run sequentially; only the
    checkpoint reads, writes and cotangent sums stay outside.
    """
    if not deciding:  # `step` without decisions: none forced, none returned
        with_decisions = _nested(lambda c, forced: (step(c), forced), pack, unpack,
                                 deciding=True)
        return lambda packed: with_decisions(packed, ())[0]

    # (packed, forced decisions) -> (packed, decisions taken)
    def run(operands):
        c, decided = step(unpack(operands[0]), operands[1])
        return pack(c), decided

    def body(packed, forced):
        always = eqxi.unvmap_all(unpack(packed).num_steps >= 0)
        return lax.cond(always, run, lambda q: q, (packed, forced))

    return body


def storing_limit(init) -> int:
    """The most residual bytes per step for which reverse mode stores each step's
    linearisation (`_loop/stored.py`) rather than a carry per step that the backward
    pass runs again (Equinox's checkpointed loop); −1: never (`stored_while_loop`'s
    `max_residual_bytes`, measured on the step's own linearisation).

    Stores pay where a step's residuals are small (up to `_STORED_RESIDUAL_BYTES`): the
    backward pass then applies them instead of running the step again. Where they are
    large (a Fourier forcing's sines and cosines of every stage), staging and storing
    them costs more than the re-run; under `vmap` the stores would hold every lane's
    residuals, so batched runs keep carries. The measurements behind the threshold are in
    `benchmarks/README.md`, *Each step's linearisation stored*.
    """
    return -1 if under_vmap(init) else _STORED_RESIDUAL_BYTES


# The most residual bytes per step that reverse mode stores (see `storing_limit`).
_STORED_RESIDUAL_BYTES = 1024


def checkpoint_count(checkpoints: int | None, max_steps: int) -> int | None:
    """The checkpoints to ask Equinox for: `checkpoints >= max_steps` means every step.

    The loop runs up to `max_steps + 1` iterations (the last one marks MAX_STEPS), and
    Equinox's checkpointed loop takes its fast path (no recomputation, no checkpoint
    schedule in the backward pass) only when the checkpoints equal its step bound: a user's
    `RecursiveCheckpointAdjoint(checkpoints=max_steps)` would miss it by one and cost
    much more.
    """
    if checkpoints is not None and checkpoints >= max_steps:
        return max_steps + 1
    return checkpoints
