"""Phases that only some lanes need, paid for by those lanes alone under `vmap`.

A lane runs an expensive phase (the in-step root searches, a landing) only on some of its
loop iterations. Written per lane as `lax.cond(need, phase, nothing)`, it becomes under
`jax.vmap` a `select` over *both* branches for every lane, or, guarded by `unvmap_any`,
the phase for every lane whenever any lane needs it. With random phases some lane needs it
on almost every iteration, so every lane paid for every other lane's events, several
times the cost of lanes in phase.

`per_lane(phase, need, operands, nothing)` is that `cond` for one lane, and a
`jax.custom_batching.custom_vmap` rule for a batch: the lanes that need the phase are
gathered (in lane order) into sub-batches of `compacted_width(batch)` lanes, the phase runs
vmapped on each sub-batch in turn, and its results are scattered back; the other lanes get
`nothing(operands)`. A lane's result is what `phase` computes for it alone: which other
lanes need the phase changes only the cost. (Lanes in phase need it together; walking the
queue in sub-batches then costs what one call over the batch costs: measured, the same to
within noise, while a second, whole-batch copy of the phase doubled the compile time.)

Derivatives: JAX differentiates a custom batching rule by differentiating the rule, which
fails for this one (gathers inside a loop, under vmap of jvp: jax#9066's tree mismatch and
shape errors), and it has no transpose, so reverse mode cannot pass one either. A phase
whose results carry no derivatives (the searches: booleans, and times the loop stops the
gradient of) passes `differentiable=False`: its operands go through `stop_gradient`, and
no transformation ever sees the rule. A phase with derivatives (the landing) passes
`differentiable=True`: a `custom_jvp` runs it uncompacted when it is differentiated, and
the reverse-mode loops do not call `per_lane` for it at all (`land.py`).
"""

from collections.abc import Callable
from typing import Any

import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap

# The sub-batch is 1/SHARE of the batch, and at least MIN_WIDTH lanes: with random phases
# a few percent of the lanes of an ex1dof sweep need a search on a given iteration (one or
# two searches and one landing per impact, ~30 steps per impact). A sixteenth measured
# best against an eighth, a thirty-second and a sixty-fourth (`benchmarks/README.md`).
SHARE = 16
MIN_WIDTH = 8


def compacted_width(batch: int) -> int:
    """Lanes per sub-batch for a batch of `batch` lanes (the whole batch if small)."""
    return min(batch, max(MIN_WIDTH, -(-batch // SHARE)))


def if_any_lane(need, compute: Callable, unchanged):
    """`compute()` if some lane `need`s it (under `vmap`: any lane of the batch), else
    `unchanged`, which must be what `compute()` gives where no lane needs it.

    The cheap form of `per_lane` for work that is rare and light: no compaction, the whole
    batch runs `compute` on the iterations where any lane needs it. Used for the sliding
    policy's work at a landing (a release's Newton step, the tests of a lane that slid,
    the projection onto the sliding manifold, ~2% of a run that never slides), the log's
    row writes (`write_log_rows`), the sliding field and the equilibrium probe.
    """
    return lax.cond(eqxi.unvmap_any(need), compute, lambda: unchanged)


def per_lane(
    phase: Callable, need, operands: Any, nothing: Callable, *, differentiable: bool = False
) -> Any:
    """`phase(operands)` where `need`, else `nothing(operands)`; under `vmap` the lanes
    that do not need the phase do not pay for it (see the module docstring).

    `phase` and `nothing` are functions of one lane's operands with the same output
    structure. With `differentiable=False` the results carry no derivative; with True,
    a differentiated call runs the phase uncompacted (every lane pays, as a plain
    `lax.cond` under `vmap` would).
    """
    # The batching and derivative rules below are Python closures that JAX calls while it
    # transforms the enclosing loop, so they must not capture tracers: values the phase
    # closes over (a traced t0, a user's field closing over jitted arrays) are hoisted
    # into the operands.
    phase, phase_consts = _hoisted(phase, operands, slot=1)
    nothing, nothing_consts = _hoisted(nothing, operands, slot=2)
    operands = (operands, phase_consts, nothing_consts)
    if not differentiable:
        # (the hoisted values too: a traced t0 may carry a tangent)
        return _compacted_call(phase, nothing, need, jax.lax.stop_gradient(operands))

    @jax.custom_jvp
    def call(need, operands):
        return _compacted_call(phase, nothing, need, operands)

    @call.defjvp
    def call_jvp(primals, tangents):
        # JAX differentiates a custom batching rule by differentiating the rule, which
        # fails for this one (jax#9066: its gathers inside a loop under vmap of jvp); a
        # derivative is only needed in jacfwd runs, where the plain select costs what
        # it always did.
        need, operands = primals

        def plain(ops):
            def both(ops):
                return jax.tree.map(
                    lambda a, b: jnp.where(need, a, b), phase(ops), nothing(ops)
                )

            return lax.cond(eqxi.unvmap_any(need), both, nothing, ops)

        return jax.jvp(plain, (operands,), (tangents[1],))

    return call(need, operands)


def _compacted_call(phase, nothing, need, operands):
    @custom_vmap
    def one_lane(need, operands):
        return lax.cond(need, phase, nothing, operands)

    @one_lane.def_vmap
    def many_lanes(batch, in_batched, need, operands):
        need_batched, operands_batched = in_batched
        axes = _axes(operands_batched)
        if not need_batched:
            need = jnp.broadcast_to(need, (batch,))
        out = _compacted(phase, nothing, batch, need, operands, axes)
        return out, jax.tree.map(lambda _: True, out)

    return one_lane(need, operands)


def _compacted(phase, nothing, batch, need, operands, axes):
    width = compacted_width(batch)

    def lane_phase(ops, size):
        return jax.vmap(phase, in_axes=(axes,), axis_size=size)(ops)

    count = jnp.sum(need.astype(jnp.int32))
    rounds = -(-batch // width)
    # (vmap gives every leaf the batch axis, also those `nothing` does not compute)
    out = jax.vmap(nothing, in_axes=(axes,), axis_size=batch)(operands)

    if width == batch:
        # A small batch: one call over every lane, no gathers.
        def run_phase():
            return jax.tree.map(
                lambda r, o: jnp.where(need.reshape((batch,) + (1,) * (r.ndim - 1)), r, o),
                lane_phase(operands, batch), out,
            )
    else:
        def run_phase():
            # The lanes that need the phase, in lane order, padded with `batch` (out of
            # range: their gathers are clamped and their scatters dropped). Built here,
            # under the `cond` below: built at every iteration, its cumsum and scatter
            # cost an in-phase sweep, where most iterations need no phase.
            queue = jnp.nonzero(need, size=rounds * width, fill_value=batch)[0]

            def more(carry):
                start, _ = carry
                return start < count

            def one_round(carry):
                start, out = carry
                lanes = lax.dynamic_slice(queue, (start,), (width,))
                result = lane_phase(_pick(operands, axes, lanes, batch), width)
                out = jax.tree.map(lambda o, r: o.at[lanes].set(r, mode="drop"), out, result)
                return start + width, out

            return lax.while_loop(more, one_round, (jnp.array(0), out))[1]

    # Only when some lane needs the phase: the loop's carry (every lane's output) is copied
    # in whenever the loop is entered, even for zero rounds (in-phase sweeps, most
    # iterations).
    return lax.cond(count > 0, run_phase, lambda: out)


def _pick(operands, axes, lanes, batch):
    """The operands of `lanes` (sorted; out-of-range padding at the end).

    Lanes that follow each other (all of them in phase, and runs of neighbours otherwise)
    are one slice of every operand; others are gathered. The gathers are separate kernels,
    one per operand, slower than slices (the same bits). The scatter of the
    results stays: as a `cond` between it and an in-place slice update, XLA copied every
    lane's results at every round, which cost more than it saved.
    """
    first, last = lanes[0], lanes[-1]
    width = lanes.shape[0]
    neighbours = (last - first == width - 1) & (last < batch)
    is_none = lambda a: a is None  # noqa: E731

    def sliced():
        return jax.tree.map(
            lambda x, a: x if a is None else lax.dynamic_slice_in_dim(x, first, width, 0),
            operands, axes, is_leaf=is_none,
        )

    def gathered():
        return jax.tree.map(
            lambda x, a: x if a is None else x[jnp.minimum(lanes, batch - 1)],
            operands, axes, is_leaf=is_none,
        )

    return lax.cond(neighbours, sliced, gathered)


def _hoisted(fn, example, slot):
    """`fn` as a function of `(operands, phase consts, nothing consts)` (reading its own
    consts at `slot`) that closes over no array: what it read from its closure is
    returned as a list to pass in."""
    closed, out_shape = jax.make_jaxpr(fn, return_shape=True)(example)
    out_tree = jax.tree.structure(out_shape)

    def converted(operands):
        flat = jax.tree.leaves(operands[0])
        out = jax.core.eval_jaxpr(closed.jaxpr, operands[slot], *flat)
        return jax.tree.unflatten(out_tree, out)

    return converted, list(closed.consts)


def _axes(batched):
    return jax.tree.map(lambda b: 0 if b else None, batched)


def under_vmap(tree) -> bool:
    """Whether `tree` holds values batched by an enclosing `jax.vmap` (seen through `jvp`).

    Reads JAX's tracer classes from `jax._src` (no public API says whether a value is
    batched); if they move, this answers False and the run takes the staged loop, which is
    correct under vmap, only slower."""
    try:
        from jax._src.interpreters.ad import JVPTracer
        from jax._src.interpreters.batching import BatchTracer
    except ImportError:  # pragma: no cover
        return False
    for leaf in jax.tree.leaves(tree):
        while isinstance(leaf, jax.core.Tracer):
            if isinstance(leaf, BatchTracer):
                if getattr(leaf, "batch_dim", None) is not None:
                    return True
                leaf = leaf.val
            elif isinstance(leaf, JVPTracer):
                leaf = leaf.primal
            else:
                break
    return False
