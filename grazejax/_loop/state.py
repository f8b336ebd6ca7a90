"""`LoopState`: everything one lane carries from one solver step to the next."""

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PyTree

from .._custom_types import Args, BoolScalar, IntScalar, RealScalar, State
from .compact import if_any_lane


class LoopState(eqx.Module):
    """One lane's loop state (shapes for one lane; `vmap` and `sweep` add a leading axis).

    The loop runs in local time s >= 0 since the last restart; absolute time is
    t = t_hi + t_lo + σ s, with the restart time in double-double (see `dd_add`).
    """

    args: Args  # this lane's parameters (in the state so that a pool of lanes can refill)
    time_scale: RealScalar  # |t| below which a step no longer moves time (see h_min_at)
    s: RealScalar  # local clock at the start of the next step
    t_hi: RealScalar  # absolute time of the last restart, double-double
    t_lo: RealScalar
    y: State
    h: RealScalar  # next step size
    solver_state: PyTree[Any]
    controller_state: PyTree[Any]
    made_jump: BoolScalar
    restart: Bool[Array, " m"]  # the flight starts on surface i (guard its first step)
    flight_scale: State  # max |x_k| over the current flight, per coordinate: its round-off scale
    landing: BoolScalar  # the next step lands exactly on a located contact
    target: RealScalar  # local time of that contact
    pending: Bool[Array, "m signs"]  # which surfaces (and sides) the contact involves
    touch: Bool[Array, "m signs"]  # tangential contacts (γ)
    boundary: Bool[Array, "m signs"]  # contacts on ∂Γ (β)
    h_after: RealScalar  # step size to resume with after the impact
    num_impacts: IntScalar
    # While the loop writes a staging log (`stage_log`): the impacts already in the full
    # log, so that the staging log's row 0 is impact `log_base`. None: the log is the full one.
    log_base: IntScalar | None
    log_t: Float[Array, " impacts"] | None
    log_pre: Float[Array, "impacts n"] | None
    log_post: Float[Array, "impacts n"] | None
    log_surface: Int[Array, " impacts"] | None
    log_kind: Int[Array, " impacts"] | None
    stick: Bool[Array, " m"]  # sliding on surface i, held by its contact force (ZenoStick)
    releasing: BoolScalar  # the located event is the end of that sliding (release)
    intervals: Float[Array, " 3"]  # the last three inter-impact times, for Zeno detection
    zeno_time: RealScalar
    num_steps: IntScalar
    num_accepted: IntScalar
    status: IntScalar
    done: BoolScalar
    t_final: RealScalar
    x_final: State
    save_index: IntScalar | None
    save_xs: Float[Array, "saves n"] | None


# The impact log, and all of the state's buffers: written row by row, never read inside the
# loop (see `write_log`).
LOG = ("log_t", "log_pre", "log_post", "log_surface", "log_kind")
BUFFERS = LOG + ("save_index", "save_xs")


def impact_log(c: LoopState) -> tuple:
    """The state's impact log, as the tuple `write_log` takes (fields `LOG`)."""
    return tuple(getattr(c, k) for k in LOG)


def with_impact_log(c: LoopState, log) -> LoopState:
    """`c` with its impact log replaced by `log` (the tuple `impact_log` returns)."""
    return _set_fields(c, LOG, log)


def _set_fields(c: LoopState, names, values) -> LoopState:
    """`c` with the fields `names` replaced by `values` (None allowed: a field left out)."""
    return eqx.tree_at(
        lambda z: tuple(getattr(z, k) for k in names), c, tuple(values),
        is_leaf=lambda z: z is None,
    )


def without_buffers(c: LoopState) -> LoopState:
    return _set_fields(c, BUFFERS, (None,) * len(BUFFERS))


def with_buffers(small: LoopState, full: LoopState) -> LoopState:
    return _set_fields(small, BUFFERS, (getattr(full, k) for k in BUFFERS))


# The fields that carry a derivative of (x0, args) through the loop: the fixed point that
# JAX's while-loop jvp rule finds (measured on ex1dof; `save_xs` with saveat). The rest
# (step sizes, the controller, counters, flags) carries none: the step size is stopped
# on purpose (see `init`).
TANGENT_FIELDS = (
    "s", "t_hi", "t_lo", "y", "solver_state", "flight_scale", "h_after", "log_t", "log_pre",
    "log_post", "intervals", "zeno_time", "t_final", "x_final", "save_xs",
)
# Loop-invariant inputs and values fixed at t0: never batched or differentiated more than
# `init` made them.
_UNSEEDED = ("args", "time_scale")


def seed_fixed_point(c: LoopState, x0, args) -> LoopState:
    """`c` unchanged in value, but batched and differentiated as the loop will make it.

    JAX's while loop finds which carries are batched (vmap) and which have tangents (jvp)
    by a fixed point: it transforms the whole loop body, sees which outputs picked up a
    batch axis or a tangent that the inputs lacked, and transforms it again — three times
    here (tangents on 3 → 13 → 14 carries, batch axes on 9 → 35 → 36), and both rules
    nest under jacfwd. Each pass re-traces a body of ~1000 equations: most of the
    lowering time of `jacfwd(simulate)` and `vmap(simulate)`. Starting from the fixed
    point makes the first pass the last. `where(False, anchor, value)` is `value`
    exactly, XLA folds it, and it is batched (has a tangent) wherever the anchor is,
    which depends on every input.
    """
    anchor = jnp.ravel(x0)[0]
    for leaf in jax.tree.leaves(args):
        if eqx.is_array(leaf) and leaf.size and jnp.issubdtype(leaf.dtype, jnp.inexact):
            anchor = jnp.where(False, jnp.ravel(leaf)[0].astype(anchor.dtype), anchor)
    frozen = jax.lax.stop_gradient(anchor)

    def seed(value, differentiable):
        if not eqx.is_array_like(value):
            return value
        value = jnp.asarray(value)  # (a Python scalar becomes the loop carry's array anyway)
        inexact = jnp.issubdtype(value.dtype, jnp.inexact)
        source = anchor if differentiable and inexact else frozen
        return jnp.where(False, source.astype(value.dtype), value)

    names = [k for k in c.__dataclass_fields__ if k not in _UNSEEDED]
    values = [
        jax.tree.map(lambda v, d=name in TANGENT_FIELDS: seed(v, d), getattr(c, name))
        for name in names
    ]
    return _set_fields(c, names, values)


def _without_log(c: LoopState) -> LoopState:
    return _set_fields(c, LOG, (None,) * len(LOG))


def packing(template: LoopState):
    """`(pack, unpack)`: the state as one flat array per dtype, plus the impact log.

    For the checkpointed loop of reverse mode only. The log is passed to
    `eqxi.while_loop(buffers=...)` as Diffrax passes its save buffers (written one row at a
    time, never read in the loop): it is then stored once instead of in every checkpoint
    (with the default ~450 checkpoints, 1000 log rows were 31 MiB of checkpoints), and the
    backward pass reads each row's cotangent once instead of carrying the whole log's
    cotangent through every step. (`save_xs` is not a buffer: the reverse-mode save
    selects whole arrays.) The rest is packed: the checkpointed loop's backward pass handles
    every carry leaf separately at every step (load from a checkpoint, save to one, select,
    add cotangents); with ~40 small leaves that bookkeeping cost more than the step's own
    VJP. Concatenating and slicing is exact: values and derivatives are those of the
    unpacked loop.
    """
    leaves, treedef = jax.tree.flatten(_without_log(template))
    dtypes = list(dict.fromkeys(jnp.result_type(leaf) for leaf in leaves))
    layout, offsets = [], dict.fromkeys(dtypes, 0)
    for leaf in leaves:
        dtype, size = jnp.result_type(leaf), int(np.prod(jnp.shape(leaf)))
        layout.append((dtypes.index(dtype), offsets[dtype], size, jnp.shape(leaf)))
        offsets[dtype] += size

    def pack(c: LoopState):
        flat = jax.tree.leaves(_without_log(c))
        groups = tuple(
            jnp.concatenate(
                [jnp.ravel(x).astype(d) for x, (g, *_) in zip(flat, layout, strict=True) if g == i]
            )
            for i, d in enumerate(dtypes)
        )
        return groups, impact_log(c)

    def unpack(packed) -> LoopState:
        groups, log = packed
        flat = [groups[g][o : o + size].reshape(shape) for g, o, size, shape in layout]
        return _set_fields(jax.tree.unflatten(treedef, flat), LOG, log)

    return pack, unpack


def write_log(log, row, apply, t, pre, post, surface, kind):
    """Write one impact-log row where `apply`. Rows past the end (simultaneous impacts
    overflowing `max_impacts`) are not written: the log holds the first impacts, the same
    in every loop kind."""
    log_t, log_pre, log_post, log_surface, log_kind = log
    size = log_t.shape[0]
    if not isinstance(log_t, jax.Array):
        # The write-once buffers of a checkpointed loop (`packing`): a predicated write.
        # (Not `mode="drop"`: their transpose reads the cotangent back with the same mode,
        # and an out-of-bounds read fills NaN.) Buffers must be written at most once per
        # index, so a row past the end must not be clamped onto the last one.
        pred = apply & (row < size)
        row = jnp.minimum(row, size - 1)
        return tuple(
            buffer.at[row].set(value, pred=pred)
            for buffer, value in zip(log, (t, pre, post, surface, kind), strict=True)
        )
    # A row that is not applied is written out of bounds and dropped: the buffers are only
    # written, never read, in the loop, so XLA updates them in place (a read-modify-write
    # `where(apply, new, log[row])` made it copy every buffer at every iteration under vmap:
    # per-lane cost grew with max_impacts).
    row = jnp.where(apply, row, size)
    return (
        log_t.at[row].set(t, mode="drop"),
        log_pre.at[row].set(pre, mode="drop"),
        log_post.at[row].set(post, mode="drop"),
        log_surface.at[row].set(surface, mode="drop"),
        log_kind.at[row].set(kind, mode="drop"),
    )


def write_log_rows(log, row, t, rows, skip_unwritten=False):
    """Write one landing's rows (`rows = (apply, pre, post, surface, kind)`, one entry per
    slot, all at time `t`): the applied slots, in order, from `row` on.

    One scatter per buffer for all slots (not one write per slot): each write is a kernel
    run at every iteration, applied or not.

    The writes run only on iterations where some lane writes a row (most iterations land
    no lane): always for several slots (a sliding policy's second slot, a scatter per
    buffer, otherwise costs a run that never slides), for one slot with `skip_unwritten`
    (a batched loop, where each write is a scatter over the batch). For one trajectory the
    single write is a small in-place update, and through a conditional XLA would no longer
    drop a log nobody reads (a `jacfwd` of a final state would pay for it). Batched, the
    conditional costs `vmap(jacfwd)` of final states a little and gains more where the
    log is returned (`benchmarks/README.md`).
    """
    apply = rows[0]
    if not isinstance(log[0], jax.Array):
        # The write-once buffers of a checkpointed loop: row by row (see `write_log`).
        return _write_slots_one_by_one(log, row, t, rows)
    if apply.shape[0] > 1:
        return if_any_lane(jnp.any(apply), lambda: _scatter_slots(log, row, t, rows), log)
    if skip_unwritten:
        return if_any_lane(jnp.any(apply), lambda: _write_slots_one_by_one(log, row, t, rows),
                           log)
    return _write_slots_one_by_one(log, row, t, rows)


def _write_slots_one_by_one(log, row, t, rows):
    apply, pre, post, surface, kind = rows
    at = jnp.array(0)
    for slot in range(apply.shape[0]):
        log = write_log(log, row + at, apply[slot], t, pre[slot], post[slot], surface[slot],
                        kind[slot])
        at = at + apply[slot]
    return log


def _scatter_slots(log, row, t, rows):
    """The applied slots to consecutive rows from `row`; the others out of bounds, dropped."""
    apply, pre, post, surface, kind = rows
    index = jnp.where(apply, row + jnp.cumsum(apply) - apply, log[0].shape[0])
    times = jnp.broadcast_to(t, apply.shape)
    return tuple(
        buffer.at[index].set(value.astype(buffer.dtype), mode="drop")
        for buffer, value in zip(log, (times, pre, post, surface, kind), strict=True)
    )


def log_row_offset(c: LoopState):
    """The row of the state's log that impact number 0 would go to: 0 for the full log,
    `-log_base` for a staging log."""
    return 0 if c.log_base is None else -c.log_base


def stage_log(c: LoopState, rows: int):
    """`(staged, full_log)`: the state with a staging log of `rows` rows in place of its
    impact log, and the full log it will be flushed into (`flush_log`).

    Why: XLA:CPU runs a loop body's kernels one after another only if none of them touches
    a buffer over 512 bytes (`ThunkExecutor::Options::execute_sequential_buffer_threshold`,
    fixed in `CpuExecutable::Create`, no flag); otherwise every iteration pays for its
    dataflow executor (most of an iteration's time at batch 1). The log's rows are written
    in the body, so a log of more than 32 two-dimensional rows (the default holds 100)
    would make every single-trajectory run much slower. A staging log of one
    landing's rows keeps the body under the threshold; the loop stops when a lane has staged
    a row, and the rows go to the full log outside it (`forward.py: staged_log_loop`).

    The staging rows are filled from small fields of the state that have the batch axes
    and tangents the rows will have (`where(False, field, fill)` is `fill`, folded by XLA),
    so that JAX's while-loop fixed point holds at once (see `seed_fixed_point`). Not from
    the full log itself: then XLA can drop the log and its writes from a run whose log is
    unused (it cannot see through a nested loop that reads it).
    """
    full = impact_log(c)

    def fill(like, buffer):
        shape = (rows,) + buffer.shape[1:]
        value = jnp.nan if jnp.issubdtype(buffer.dtype, jnp.inexact) else -1
        return jnp.where(False, like.astype(buffer.dtype), jnp.full(shape, value, buffer.dtype))

    likes = (c.t_final, c.x_final, c.x_final, c.num_impacts, c.num_impacts)
    staged = tuple(fill(like, b) for like, b in zip(likes, full, strict=True))
    return _set_fields(c, LOG + ("log_base",), staged + (c.num_impacts,)), full


def has_staged_rows(c: LoopState):
    return c.num_impacts > c.log_base


def flush_log(c: LoopState, full_log) -> LoopState:
    """Write the staged rows into `full_log` (rows `log_base` on); the state with it."""
    base = c.log_base
    staged = impact_log(c)
    for j in range(staged[0].shape[0]):
        row = tuple(r[j] for r in staged)
        full_log = write_log(full_log, base + j, j < c.num_impacts - base, *row)
    return with_full_log(c, full_log)


def with_full_log(c: LoopState, full_log) -> LoopState:
    """The state with `full_log` as its impact log (no staging)."""
    return _set_fields(c, LOG + ("log_base",), tuple(full_log) + (None,))


def two_sum(a, b):
    s = a + b
    bb = s - a
    err = (a - (s - bb)) + (b - bb)
    return s, err


def dd_add(hi, lo, x):
    """(hi, lo) + x in double-double arithmetic."""
    s, e = two_sum(hi, x)
    e = e + lo
    return two_sum(s, e)
