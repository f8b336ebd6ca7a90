"""A while loop that reverse mode differentiates by storing each step's linearisation.

Equinox's checkpointed loop stores carries: its backward pass runs every step again (with
the impact loop's event detection, root searches and step-size controller) before it
transposes it. This loop stores, for every step, the residuals of `jax.vjp(step)` (what
the transposed step reads: stage values, the selects' predicates, ...), and its backward
pass only applies the stored pullbacks, last step first. Memory: one row of residuals per
step up to `max_steps` (~130 numbers for the forced impact oscillator), allocated before
the loop.

Why blocks: XLA:CPU runs a sequence of kernels one after another only if none of them
touches a buffer over 512 bytes, and otherwise through its dataflow executor, whose
bookkeeping costs more than a small step's kernels (see `reverse.py: _nested`). A step's
residuals (~1 KB) and their store are over that size, so an inner loop runs up to `block`
steps and stages their residuals in pieces of at most 512 bytes (`_Layout`), and an outer
loop moves a block's pieces to the store; the backward pass reads a block's pieces and
applies its pullbacks in an inner loop of the same kind. Forced impact oscillator, 10
impacts, every step stored, one core, min of 11: 3.0x the primal, against 3.55x with
Equinox's checkpointed loop storing every step. Storing pays only while a step's
residuals are small (many pieces, and their store, cost more than running a step again):
`reverse.py: storing_limit` picks this loop or Equinox's.

Steps of another kind (`apart=`: the impact loop's landings) are linearised on their own
and stored in rows of their own: one `cond` inside the step would store the union of
both branches' residuals in every row (the forced oscillator's rows: 864 bytes with the
landing branch, 566 without; every step stored 3.07/3.40/3.84x -> 2.26/2.43/2.70x the
primal at 10/100/1000 impacts).
"""

import functools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from .._compiler import SEQUENTIAL_BUFFER_BYTES


def stored_while_loop(
    cond_fun: Callable[[Any], Any],
    step: Callable[[Any], Any],
    small,
    max_steps: int,
    *,
    buffers=(),
    write: Callable[[Any, Any], Any] | None = None,
    ends_block: Callable[[Any], Any] | None = None,
    block: int = 8,
    replay=None,
    apart=None,
    max_residual_bytes: int | None = None,
):
    """`while cond_fun(small): small = step(small)`, at most `max_steps` steps; with
    `buffers = write(small, buffers)` after every step for which `ends_block(small)` and
    after the last step (in the forward pass of reverse mode, also every `block` steps:
    after a step that `ends_block` does not mark, `write` must write nothing new).
    Returns `(small, buffers)`. Differentiable in reverse mode only (a `custom_vjp`).

    With `replay` (a pytree of arrays with a leading axis of `max_steps` rows: one step's
    decisions per row, rows not recorded marked by the step), `step` is
    `(small, forced) -> (small, decided)`: it replays `forced`, its row of `replay`, where
    recorded, and returns the decisions it took; the loop returns
    `(small, buffers, decisions)`, `decisions` with the structure of `replay`. A caller
    that runs the loop again (reverse mode's recomputation) passes the first run's
    decisions, so that both runs take the same steps (`replay.py`).

    With `apart = (is_apart, apart_step, rows)`, a step from a state where `is_apart(small)`
    is `apart_step(small)` (the same signature as `step`) and its residuals are stored
    apart from the other steps', at most `rows` of them: the impact loop's landings, whose
    branch would otherwise add its residuals to every step's row (forced impact
    oscillator: 864 bytes a step, 566 without the landing's). A step ends its block after
    it; the other steps are `step(small)` for states that are not apart.

    With `max_residual_bytes`, returns None (and builds no loop) where a step's residuals
    (the other steps', not those stored apart) take more bytes than that: storing them
    does not pay (`reverse.storing_limit`). The step's linearisation that measures them is
    the one the forward pass replays (`_Linearised`): it is traced once.

    The impact loop's contract: `cond_fun` and `ends_block` are unbatched
    (`eqxi.unvmap_any`), as `step` freezes finished lanes itself and every lane's residuals
    are stored at one index; `write` writes each row of `buffers` at most once and the loop
    never reads them (Equinox's `buffers`), so a row's cotangent goes only to the step that
    wrote it; the initial `buffers` do not depend on differentiated inputs.
    """
    if write is None:
        write = lambda small, buffers: buffers  # noqa: E731
    if ends_block is None:
        ends_block = lambda small: jnp.asarray(False)  # noqa: E731
    deciding = replay is not None
    if not deciding:
        replay, plain_step = (), step
        step = lambda small, forced: (plain_step(small), ())  # noqa: E731
    replay = jax.tree.map(jnp.asarray, replay)
    forced = jax.tree.map(lambda r: r[0], replay)
    cond_closed, cond_consts = jax.closure_convert(cond_fun, small)
    ends_closed, ends_consts = jax.closure_convert(ends_block, small)
    step_closed, step_consts = jax.closure_convert(step, small, forced)
    write_closed, write_consts = jax.closure_convert(write, small, buffers)
    fns = _Fns(cond_closed, ends_closed, step_closed, write_closed, max_steps, block, deciding)
    apart_tests, apart_consts = (), ()
    if apart is not None:
        is_apart, apart_step, fns.apart_rows = apart
        if not deciding:
            plain_apart = apart_step
            apart_step = lambda small, forced: (plain_apart(small), ())  # noqa: E731
        fns.is_apart, apart_tests = jax.closure_convert(is_apart, small)
        fns.apart_step, apart_consts = jax.closure_convert(apart_step, small, forced)
    fns.linearised_step = _Linearised(fns, fns.step, small, forced, tuple(step_consts))
    if (max_residual_bytes is not None
            and _nbytes(fns.linearised_step.residual_shapes) > max_residual_bytes):
        return None
    small, buffers, decisions = _stored(
        fns, small, buffers, jax.lax.stop_gradient(replay),
        (tuple(cond_consts), tuple(ends_consts), tuple(apart_tests)), tuple(step_consts),
        tuple(write_consts), tuple(apart_consts))
    return (small, buffers, decisions) if deciding else (small, buffers)


class _Fns:
    """The loop's closed functions and sizes, and the residuals' layouts found while
    tracing the forward pass (read by the backward pass)."""

    def __init__(self, cond, ends, step, write, max_steps, block, deciding):
        self.cond, self.ends, self.step, self.write = cond, ends, step, write
        self.max_steps, self.block, self.deciding = max_steps, block, deciding
        self.step_layout = self.write_layout = self.apart_layout = None
        self.is_apart = self.apart_step = None  # (see `stored_while_loop`'s `apart`)
        # (each kind of step's `_Linearised`: the step's by `stored_while_loop`, the
        # apart step's by `_fwd`)
        self.linearised_step = self.linearised_apart = None
        self.apart_rows = 0

    def block_goes_on(self, j, small, tests):
        """Whether step `j` of a block may run: a block's first step always, later ones
        unless the step before ended the block (`ends_block`, then `write`)."""
        return (j == 0) | ~_bool(self.ends(small, *tests[1]))

    def apart(self, small, tests):
        """Whether the step from `small` is stored apart (never without `apart`)."""
        return _bool(self.is_apart(small, *tests[2]) if self.is_apart else False)

    def any_step(self, small, forced, step_consts, apart_consts, tests):
        """The step from `small`, whichever kind it is (the loop without derivatives)."""
        if self.is_apart is None:
            return self.step(small, forced, *step_consts)
        return lax.cond(self.apart(small, tests),
                        lambda: self.apart_step(small, forced, *apart_consts),
                        lambda: self.step(small, forced, *step_consts))


class _Layout:
    """Pytree leaves packed in pieces, per dtype, small enough that a block of `block`
    rows of a piece stays within `SEQUENTIAL_BUFFER_BYTES` (XLA:CPU's sequential-executor threshold):
    the inner loops stage their rows in such pieces. Whole leaves go to a piece where they
    fit (one concatenation per piece: cutting a flat row at fixed widths cost ~60 slices
    per step), larger leaves are cut."""

    def __init__(self, leaves, treedef, block: int | None):
        self.treedef = treedef
        self.shapes = [jnp.shape(x) for x in leaves]
        self.dtypes = list(dict.fromkeys(jnp.result_type(x) for x in leaves))
        self.pieces = []  # per piece: (group, [(leaf, start, stop)], width)
        for g, d in enumerate(self.dtypes):
            width = (max(1, SEQUENTIAL_BUFFER_BYTES // (block * np.dtype(d).itemsize)) if block
                     else sum(int(np.prod(jnp.shape(x))) for x in leaves
                              if jnp.result_type(x) == d))
            current, used = [], 0
            for i, x in enumerate(leaves):
                if jnp.result_type(x) != d:
                    continue
                size = int(np.prod(jnp.shape(x)))
                for a in range(0, max(size, 1), width) if size > width else [0]:
                    n = min(width, size - a)
                    if used + n > width:
                        self.pieces.append((g, current, used))
                        current, used = [], 0
                    current.append((i, a, a + n))
                    used += n
            if current:
                self.pieces.append((g, current, used))

    def pack(self, leaves):
        """One row: a tuple of pieces."""
        flat = [jnp.ravel(x) for x in leaves]
        return tuple(
            jnp.concatenate([flat[i][a:b].astype(self.dtypes[g]) for i, a, b in segments])
            for g, segments, _ in self.pieces
        )

    def unpack(self, pieces):
        """The pytree from one row's pieces."""
        parts = [[] for _ in self.shapes]
        for piece, (_, segments, _) in zip(pieces, self.pieces, strict=True):
            offset = 0
            for i, a, b in segments:
                parts[i].append((a, piece[offset : offset + b - a]))
                offset += b - a
        leaves = [
            jnp.concatenate([p for _, p in sorted(ps, key=lambda t: t[0])]).reshape(shape)
            if len(ps) > 1 else ps[0][1].reshape(shape)
            for ps, shape in zip(parts, self.shapes, strict=True)
        ]
        return jax.tree.unflatten(self.treedef, leaves)

    def stores(self, rows: int):
        return tuple(jnp.zeros((rows, n), self.dtypes[g]) for g, _, n in self.pieces)


def _inexact(x) -> bool:
    return jnp.issubdtype(jnp.result_type(x), jnp.inexact)


def _float_part(tree):
    """The floating-point leaves of `tree` (others None): what cotangents carry."""
    return [x if _inexact(x) else None for x in jax.tree.leaves(tree)]


def _with_float0(cts, like):
    """Cotangents for `like`'s structure: `cts` (list of leaves) for its floating-point
    leaves, JAX's float0 zeros for the others."""
    leaves, tree = jax.tree.flatten(like)
    return jax.tree.unflatten(tree, [
        ct if _inexact(x) else np.zeros(jnp.shape(x), jax.dtypes.float0)
        for ct, x in zip(cts, leaves, strict=True)
    ])


def _zeros_float_part(tree):
    return [jnp.zeros_like(x) if _inexact(x) else None for x in jax.tree.leaves(tree)]


def _add(a, b):
    return [None if x is None else x + y for x, y in zip(a, b, strict=True)]


@functools.partial(jax.custom_vjp, nondiff_argnums=(0,))
def _stored(fns, small, buffers, replay, tests, step_consts, write_consts, apart_consts):
    """The loop without derivatives: steps until `ends_block`, then `write`; with
    decisions, also at most as many steps at a time as the inner loop's carry can stage
    decisions of within XLA:CPU's sequential threshold (64 for float64 step sizes),
    written to the record between blocks: the outer iteration that writes them touches
    the whole record and runs on the dataflow executor, so it should run rarely."""
    block = _decision_block(replay) if fns.deciding else None
    replay = _spare_rows(replay, block)

    def inner_more(state):
        j, k, small, _ = state
        free = fns.block_goes_on(j, small, tests)
        more = free & (k < fns.max_steps) & fns.cond(small, *tests[0])
        return more & (j < block) if block else more

    def inner_step(state):
        j, k, small, (forced, staged) = state
        small, decided = fns.any_step(small, _row(forced, j), step_consts, apart_consts, tests)
        return j + 1, k + 1, small, (forced, _set_row(staged, j, decided))

    def more(state):
        k, small, *_ = state
        return (k < fns.max_steps) & fns.cond(small, *tests[0])

    def outer_step(state):
        k, small, buffers, record = state
        # (without decisions these are empty tuples: one inner loop until `ends_block`)
        rows = (_rows(replay, k, block), _rows(record, k, block))
        _, k_next, small, (_, staged) = lax.while_loop(
            inner_more, inner_step, (jnp.asarray(0), k, small, rows))
        record = _set_rows(record, k, staged)
        return k_next, small, fns.write(small, buffers, *write_consts), record

    init = (jnp.asarray(0), small, buffers, replay)
    _, small, buffers, record = lax.while_loop(more, outer_step, init)
    return small, buffers, _drop_spare(record, fns.max_steps)


def _decision_block(replay) -> int:
    itemsize = max(jnp.result_type(x).itemsize for x in jax.tree.leaves(replay))
    return SEQUENTIAL_BUFFER_BYTES // itemsize


def _row(tree, j):
    return jax.tree.map(lambda x: lax.dynamic_index_in_dim(x, j, 0, keepdims=False), tree)


def _set_row(tree, j, row):
    return jax.tree.map(lambda x, r: lax.dynamic_update_index_in_dim(x, r, j, 0), tree, row)


def _rows(tree, k, block):
    return jax.tree.map(lambda x: lax.dynamic_slice_in_dim(x, k, block, 0), tree)


def _set_rows(tree, k, rows):
    return jax.tree.map(lambda x, r: lax.dynamic_update_slice_in_dim(x, r, k, 0), tree, rows)


def _spare_rows(replay, block):
    """`replay` with `block` more rows (copies of its last, never stepped on): a block's
    rows are read and written whole from its first step's index, and a slice that ran
    past the end would be moved back (JAX clamps the start)."""
    return jax.tree.map(lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], block or 0, 0)]),
                        replay)


def _drop_spare(record, rows):
    return jax.tree.map(lambda x: x[:rows], record)


def _nbytes(tree) -> int:
    return sum(int(np.prod(jnp.shape(x))) * jnp.result_type(x).itemsize
               for x in jax.tree.leaves(tree))


def _bool(x):
    # A closure-converted function may return a Python bool (`~False` is -1).
    return jnp.asarray(x, dtype=bool)


def _step_linearised(fns, small, forced, step_consts, step=None):
    """`(step's outputs, (its pullback's leaves, treedef))`, the replayed decisions held
    fixed (they carry no derivative); `step` defaults to `fns.step`."""
    step = fns.step if step is None else step
    out, pullback, decided = jax.vjp(
        lambda s, *consts: step(s, forced, *consts), small, *step_consts, has_aux=True)
    return (out, decided), jax.tree.flatten(pullback)


def _write_linearised(fns, small, buffers, write_consts):
    out, pullback = jax.vjp(fns.write, small, buffers, *write_consts)
    return out, jax.tree.flatten(pullback)


class _Linearised:
    """A step's linearisation traced once: `(outputs, decided), residual leaves` from
    `(small, forced, consts)`, replayed from its jaxpr wherever the forward pass runs the
    step (`jax.core.eval_jaxpr` binds the recorded operations again: no Python function,
    no `jax.vjp` machinery). Linearising the impact loop's step is most of a reverse-mode
    program's tracing (~2.4 s each for the bouncing ball's step). `.residual_shapes` gives
    the residuals' layout and size; `.treedef` rebuilds the pullback from them."""

    def __init__(self, fns, step, small, forced, consts):
        def linearised(small, forced, consts):
            (out, decided), (leaves, treedef) = _step_linearised(fns, small, forced, consts,
                                                                 step)
            self.treedef = treedef
            return (out, decided), leaves

        self.closed, shapes = jax.make_jaxpr(linearised, return_shape=True)(
            small, forced, consts)
        self.out_tree = jax.tree.structure(shapes)
        self.residual_shapes = shapes[1]

    def __call__(self, small, forced, consts):
        flat = jax.tree.leaves((small, forced, consts))
        out = jax.core.eval_jaxpr(self.closed.jaxpr, self.closed.consts, *flat)
        return jax.tree.unflatten(self.out_tree, out)


def _find_layouts(fns, small, buffers, replay, step_consts, write_consts, apart_consts):
    """The residuals' layouts: of the step's linearisation (traced by `stored_while_loop`),
    of the step stored apart (traced here, once: `_Linearised`) and of one write
    (`eval_shape` runs nothing)."""
    forced = _row(replay, 0)
    leaves = fns.linearised_step.residual_shapes
    # Pieces only where the step's own buffers are small: otherwise its loop runs on
    # the dataflow executor anyway, and one row per dtype costs the fewest kernels.
    small_buffers = all(_nbytes(x) <= SEQUENTIAL_BUFFER_BYTES
                        for x in jax.tree.leaves((small, step_consts)))
    fns.step_layout = _Layout(leaves, fns.linearised_step.treedef,
                              fns.block if small_buffers else None)

    def trace_write(small, buffers):
        _, (leaves, treedef) = _write_linearised(fns, small, buffers, write_consts)
        fns.write_layout = _Layout(leaves, treedef, 1)
        return 0

    jax.eval_shape(trace_write, small, buffers)
    if fns.apart_step is not None:
        fns.linearised_apart = _Linearised(fns, fns.apart_step, small, forced, apart_consts)
        fns.apart_layout = _Layout(fns.linearised_apart.residual_shapes,
                                   fns.linearised_apart.treedef, None)


def _fwd(fns, small, buffers, replay, tests, step_consts, write_consts, apart_consts):
    _find_layouts(fns, small, buffers, replay, step_consts, write_consts, apart_consts)
    step_layout, write_layout, block = fns.step_layout, fns.write_layout, fns.block
    padded = _spare_rows(replay, block)

    def inner_more(state):
        j, k, small, *_ = state
        return ((j < block) & (k < fns.max_steps) & fns.block_goes_on(j, small, tests)
                & fns.cond(small, *tests[0]) & ~fns.apart(small, tests))

    def inner_step(state):
        j, k, small, staging, (forced, staged) = state
        (small, decided), leaves = fns.linearised_step(small, _row(forced, j), step_consts)
        staging = tuple(lax.dynamic_update_index_in_dim(s, r, j, 0)
                        for s, r in zip(staging, step_layout.pack(leaves), strict=True))
        return j + 1, k + 1, small, staging, (forced, _set_row(staged, j, decided))

    def more(state):
        _, k, small, *_ = state
        return (k < fns.max_steps) & fns.cond(small, *tests[0])

    def outer_step(state):
        b, k, small, buffers, step_stores, write_stores, starts, record, apart = state
        rows = (_rows(padded, k, block), _rows(record, k, block))
        j, k_next, small, staging, (_, staged) = lax.while_loop(
            inner_more, inner_step,
            (jnp.asarray(0), k, small, step_layout.stores(block), rows))
        record = _set_rows(record, k, staged)
        if fns.apart_step is not None:
            # (not before the write that a block's last step asked for)
            due = fns.block_goes_on(j, small, tests)
            small, k_next, record, apart = _apart_step(
                fns, b, k_next, small, due, record, apart, padded, tests, apart_consts)
        buffers, (leaves, _) = _write_linearised(fns, small, buffers, write_consts)
        step_stores = tuple(lax.dynamic_update_slice_in_dim(s, r, k, 0)
                            for s, r in zip(step_stores, staging, strict=True))
        write_stores = tuple(lax.dynamic_update_index_in_dim(s, r, b, 0)
                             for s, r in zip(write_stores, write_layout.pack(leaves), strict=True))
        starts = lax.dynamic_update_index_in_dim(starts, k, b, 0)
        return b + 1, k_next, small, buffers, step_stores, write_stores, starts, record, apart

    # Every block has at least one step: at most `max_steps` blocks. `block` spare rows in
    # the step stores: a block's rows are written whole from its first step's index.
    n_blocks = fns.max_steps
    index = jnp.asarray(0).dtype
    # (the steps stored apart: their rows, how many, and each block's: −1 for none)
    apart = ((fns.apart_layout.stores(fns.apart_rows + 1), jnp.asarray(0),
              jnp.full((n_blocks,), -1, index)) if fns.apart_step is not None else ())
    init = (jnp.asarray(0), jnp.asarray(0), small, buffers,
            step_layout.stores(fns.max_steps + block),
            write_layout.stores(n_blocks),
            jnp.zeros((n_blocks + 1,), index), padded, apart)
    b, k, small_end, buffers_end, step_stores, write_stores, starts, record, apart = \
        lax.while_loop(more, outer_step, init)
    starts = lax.dynamic_update_index_in_dim(starts, k, b, 0)
    residuals = (b, starts, step_stores, write_stores, apart, small, buffers, replay, tests,
                 step_consts, write_consts, apart_consts)
    return (small_end, buffers_end, _drop_spare(record, fns.max_steps)), residuals


def _apart_step(fns, b, k, small, due, record, apart, padded, tests, apart_consts):
    """After block `b`'s other steps: the step stored apart, if `small` calls for one and
    it is `due`.

    Its row is written outside the `cond` (a store passed through a branch may be
    copied): where no step runs, a spare last row is written with zeros. More steps apart
    than `fns.apart_rows` would overwrite the last row: it is then NaN, and so is the
    gradient."""
    stores, count, of_block = apart
    runs = due & fns.apart(small, tests) & (k < fns.max_steps) & fns.cond(small, *tests[0])

    def run(small):
        (small, decided), leaves = fns.linearised_apart(small, _row(padded, k), apart_consts)
        return small, decided, fns.apart_layout.pack(leaves)

    def skip(small):
        return small, _row(record, k), tuple(jnp.zeros_like(s[0]) for s in stores)

    small, decided, rows = lax.cond(runs, run, skip, small)
    last = fns.apart_rows - 1
    overflow = runs & (count > last)
    rows = tuple(jnp.where(overflow, jnp.nan, r) if _inexact(r) else r for r in rows)
    at = jnp.where(runs, jnp.minimum(count, last), last + 1)
    stores = tuple(lax.dynamic_update_index_in_dim(s, r, at, 0)
                   for s, r in zip(stores, rows, strict=True))
    of_block = lax.dynamic_update_index_in_dim(of_block, jnp.where(runs, count, -1), b, 0)
    record = _set_row(record, k, decided)
    return small, k + runs, record, (stores, count + runs, of_block)


def _bwd(fns, residuals, ct):
    b_end, starts, step_stores, write_stores, apart, small, buffers, replay, tests, \
        step_consts, write_consts, apart_consts = residuals
    step_layout, write_layout, block = fns.step_layout, fns.write_layout, fns.block
    ct_small, ct_buffers, _ = ct  # (the decisions carry no derivative)
    # The buffers are written once per row and never read by the loop: the cotangent of a
    # row goes to the step that wrote it, and the buffers' cotangent is the same for every
    # step. Kept out of the carry (and the zeroing of written rows in the write's pullback
    # dropped), it is not copied at every step: carried, XLA copied the log's cotangents
    # twice per step (forced impact oscillator, 1000-row log).
    ct_buffers = _with_float0(_float_part(ct_buffers), buffers)

    def pull_back(layout, stores, i, ct_small, acc):
        """Row `i` of `stores`' pullback applied: `(ct of the state before, acc + ct of
        the step's constants)`."""
        pullback = layout.unpack(tuple(
            lax.dynamic_index_in_dim(s, i, 0, keepdims=False) for s in stores))
        d_small, *d_consts = pullback(_with_float0(ct_small, small))
        return _float_part(d_small), _add(acc, _float_part(d_consts))

    def inner_back(state):
        j, ct_small, acc, staging = state
        j = j - 1
        return j, *pull_back(step_layout, staging, j, ct_small, acc), staging

    def apart_back(b, ct_small, acc_apart):
        """The pullback of block `b`'s step stored apart, if it had one: `(ct, acc, 1)`."""
        if fns.apart_step is None:
            return ct_small, acc_apart, 0
        stores, _, of_block = apart
        row = of_block[b]

        def back(ct_small, acc_apart):
            return pull_back(fns.apart_layout, stores, row, ct_small, acc_apart)

        ct_small, acc_apart = lax.cond(row >= 0, back, lambda *a: a, ct_small, acc_apart)
        return ct_small, acc_apart, (row >= 0).astype(starts.dtype)

    def outer_back(state):
        b, ct_small, acc_step, acc_write, acc_apart = state
        b = b - 1
        start, stop = starts[b], starts[b + 1]
        pullback = write_layout.unpack(tuple(
            lax.dynamic_index_in_dim(s, b, 0, keepdims=False) for s in write_stores))
        d_small, _, *d_consts = pullback(ct_buffers)
        ct_small = _add(ct_small, _float_part(d_small))
        # (a block's step stored apart came after its other steps)
        ct_small, acc_apart, ran = apart_back(b, ct_small, acc_apart)
        rows = tuple(lax.dynamic_slice_in_dim(s, start, block, 0) for s in step_stores)
        _, ct_small, acc_step, _ = lax.while_loop(
            lambda s: s[0] > 0, inner_back,
            (stop - start - ran, ct_small, acc_step, rows))
        return b, ct_small, acc_step, _add(acc_write, _float_part(d_consts)), acc_apart

    init = (b_end, _float_part(ct_small), _zeros_float_part(step_consts),
            _zeros_float_part(write_consts), _zeros_float_part(apart_consts))
    _, ct_small, acc_step, acc_write, acc_apart = lax.while_loop(
        lambda s: s[0] > 0, outer_back, init)
    zeros = lambda tree: _with_float0(_zeros_float_part(tree), tree)  # noqa: E731
    # The initial buffers are constants of the loop's caller (NaN-filled log rows).
    return (_with_float0(ct_small, small), zeros(buffers), zeros(replay), zeros(tests),
            _with_float0(acc_step, step_consts), _with_float0(acc_write, write_consts),
            _with_float0(acc_apart, apart_consts))


_stored.defvjp(_fwd, _bwd)
