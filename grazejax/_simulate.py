"""`simulate`: the jit-compiled impact loop.

The loop itself lives in `_loop/` (named phases over a typed state: `state`, `context`,
`step`, `detect`, `land`, `policies`, `program`); this module is its entry point.

Design (and why it is not a loop of `diffeqsolve` calls with a `diffrax.Event`):

- **One flat loop, one solver step per iteration.** Flights are integrated by Diffrax's
  own solvers (`solver.step`), step-size controllers (`adapt_step_size`) and dense
  interpolants, but the loop around them is ours. An impact does not end a `diffeqsolve`
  and start another: it resets the state in place. Under `jax.vmap` this matters: nested
  loops (impacts outside, steps inside) make every lane wait for the slowest lane's flight
  at *every* impact; a flat loop only waits once, for the slowest lane overall.
- **Events located exactly, never missed.** `_events.py` tests every accepted step for
  crossings *and* in-step dips (diffrax #507), resolves several surfaces in time order
  (not pytree order, #639), and guards restarts on a surface.
- **The event state comes from a real step, not the interpolant.** When a contact is found
  at s* (on the interpolant), the step is retaken from its start to s* ("landing step"),
  then one Newton step s* ← s* − g/ġ corrects the time. The event state therefore has the
  accuracy of the method, whatever its interpolant's order, and the Newton step carries
  the implicit-function-theorem tangent of the event time, so `jax.jacfwd` through the
  loop gives exactly the saltation-matrix sensitivities (docs/design.md, *Derivatives*).
- **A local clock.** Steps run in s = time since the last impact; the impact times are
  accumulated in double-double (t_hi, t_lo). Long runs keep full resolution in every
  flight, and event times do not drift with |t| (docs/design.md, *The loop*: a local clock).
- **Backward time** (`t1 < t0`) is forward time for the reversed field −f(−·), with the
  image surfaces Γ̃_i (gap Φ_i ∘ J_i⁻¹, met from either side) and the inverse jumps.
"""

import functools
import math

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp
import numpy as np

from ._adjoint import REVERSE_HINT, loop_kinds
from ._compiler import SEQUENTIAL_BUFFER_BYTES, single_run_jit
from ._loop.bounded import bounded_while_loop
from ._loop.policies import AbstractZenoPolicy, sliding_phases
from ._loop.program import Program, build_program
from ._loop.replay import row, set_row, unrecorded_decisions
from ._loop.state import (
    flush_log,
    has_staged_rows,
    impact_log,
    packing,
    stage_log,
    with_full_log,
)
from ._loop.stored import residual_bytes, stored_while_loop
from ._scene import Scene
from ._solution import ACCEPTED, FIELD_FIX, SimulationError, Solution, failure_message
from ._status import Status
from ._validate import is_concrete, validate_inputs

# --------------------------------------------------------------------------------------
# simulate
# --------------------------------------------------------------------------------------


def simulate(
    scene: Scene,
    x0,
    t0,
    t1,
    args=None,
    *,
    solver: diffrax.AbstractSolver | None = None,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    stepsize_controller: diffrax.AbstractAdaptiveStepSizeController | None = None,
    dt0=None,
    max_impacts: int = 100,
    max_steps: int = 100_000,
    saveat=None,
    zeno_rtol: float = 1e-6,
    zeno: str | AbstractZenoPolicy = "stop",
    direction: int | None = None,
    allow_float32: bool = False,
    throw: bool = False,
    adjoint=None,
    check_field_jumps: bool = True,
) -> Solution:
    r"""Simulate x' = f(t, x) with jumps x → J_i(x) on the surface pieces Γ_i, from t0 to t1.

    One call is one XLA program: it works under `jax.jit`, `jax.vmap` (batched `x0` and
    `args` leaves) and `jax.jacfwd` (with respect to `x0` and `args`). Called outside any
    transformation, it checks its inputs and runs a program compiled once per scene object
    and options (with `grazejax.compiler_options(batched=False)`) and kept: new `x0`, `t0`,
    `t1` and numbers in `args` (arrays, Python floats) do not compile it again.

    **Arguments:**

    - `scene`: a [`grazejax.Scene`][].
    - `x0`: initial state, shape `(n,)`. Must not lie strictly inside a surface
      (it may lie *on* one: a flight never impacts at its start time).
    - `t0`, `t1`: start and end times. `t1 < t0` integrates backward in time through the
      image surfaces Γ̃_i = J_i(Γ_i) with the inverse jumps (paper, Theorem 2.2).
      `t1 = ±inf` runs until `max_impacts` (e.g. `max_impacts=1` is the impact map).
    - `args`: a pytree of parameters passed to every scene function. Vary numbers here:
      changing them never recompiles.
    - `solver`: a Diffrax solver (default `diffrax.Tsit5()`). Tested: `Tsit5`, `Dopri5`,
      `Dopri8`, `grazejax.Vern9`, and the implicit `Kvaerno5` for stiff flows.
    - `rtol`, `atol`: tolerances of the default step-size controller (Diffrax's
      `PIDController` with its default coefficients).
    - `stepsize_controller`: an adaptive Diffrax controller (overrides `rtol`/`atol`).
    - `dt0`: first step size (default: chosen by the controller).
    - `max_impacts`: size of the impact log; the run stops (status `MAX_IMPACTS`) right
      after this many impacts.
    - `max_steps`: bound on solver steps (status `MAX_STEPS`).
    - `saveat`: times at which to save the state: a `diffrax.SaveAt(ts=..., t0=..., t1=...)`
      (read as Diffrax reads it: t0, then ts, then t1) or a plain 1-D array of times,
      monotone in the direction of integration. Values are left-continuous (pre-impact at
      an impact time); times after the run stopped (e.g. at `MAX_IMPACTS`) are NaN.
      `SaveAt(steps=True)`, `dense=True` and `fn=...` are not supported (a `ValueError`
      says so). Without `saveat` no dense output is compiled.
    - `zeno_rtol`: Zeno accumulation is declared when the last three inter-impact times
      shrink geometrically (ratios equal to 5%) and the predicted time left to
      accumulation is below `zeno_rtol × (t − t0)`; the estimate is in `zeno_time`.
    - `zeno`: what happens at a Zeno accumulation or a tangential restart pushed into a
      surface: a policy, [`grazejax.ZenoStop`][] or [`grazejax.ZenoStick`][], or its name
      `"stop"` / `"stick"`. `ZenoStop()` (default): the run ends with `Status.ZENO`.
      `ZenoStick()`: the state slides on the surface (Φ = 0, Φ̇ = 0) under the contact force that the free flow
      calls for (see *Sticking* below) and is released when the free flow would pull it
      away (Φ̈ ≥ 0); both moments are logged (`ImpactKind.STICK`, `ImpactKind.RELEASE`).
      Forward time only.
    - `direction`: `+1` or `-1`; needed only when `t0`, `t1` are traced (inside `jit`).
    - `allow_float32`: grazejax runs in float64; a float32 `x0` is an error unless this
      is set (contact floors then scale with float32's epsilon).
    - `adjoint`: how the loop is differentiated, as a Diffrax adjoint.
      `None`/`diffrax.ForwardMode()` (default): `jax.jvp`/`jax.jacfwd`;
      `diffrax.RecursiveCheckpointAdjoint(checkpoints=...)`: `jax.grad`/`jax.vjp`
      (`checkpoints=None`, the default: the state every ~√max_steps steps and at each
      impact, and, while the backward pass crosses one such chunk, each of its steps'
      linearisation: ~√max_steps + max_impacts carries and ~√max_steps rows of
      residuals; an integer c: Equinox's recursive schedule with c checkpoints;
      `checkpoints >= max_steps` stores every step's linearisation and runs no step
      twice, the fastest reverse pass when `max_steps` bounds the run closely);
      `diffrax.DirectAdjoint()`: both modes, at the
      memory cost of every step. Event-time tangents are the same in every mode (the
      implicit function theorem at the landing step).
    - `check_field_jumps`: at every event (impact, crossing, release), probe the vector
      field at the state the next flight starts from, and stop with
      `Status.FIELD_DISCONTINUITY` if it jumps there (a field written with `sign(·)` on the
      event surface, whose side after the event is decided by round-off; outside
      `jit`/`vmap` a `ValueError` that names the fix: modes, [`grazejax.PiecewiseScene`][]).
      Seven evaluations of f per event, none differentiated; `False` compiles it out.
    - `throw`: raise if the run does not end with `SUCCESS`, `MAX_IMPACTS` or `ZENO`.
      Outside `jit`: a [`grazejax.SimulationError`][] that names the status and the fix,
      with the Solution as `error.solution`. Inside `jit`/`vmap`: a runtime error
      (`eqx.branched_error_if`) that names the status, without the Solution.
      ([`grazejax.sweep`][] checks on the host and names the failing lanes.)

    **Returns:** a [`grazejax.Solution`][].

    **Sticking** (`zeno=ZenoStick()`, or `"stick"`): on the contact manifold M = {Φ = 0, Φ̇ = 0} the flow is
    F = f + λd, with Φ̇, Φ̈ the derivatives along the free flow f, λ = −Φ̈/(∇ₓΦ̇·d) and d
    the direction in which the surface's jump law applies its impulses: (DJ − I)∇ₓΦ̇,
    minus its component along ∇ₓΦ (the least-norm ∇ₓΦ̇ direction if the jump law has
    no impulse there). ∇ₓΦ·d = 0 keeps Φ̇ unchanged and λ makes d(Φ̇)/dt = 0, so M is
    invariant. For a mechanical system x = (q, v), Φ = Φ(t, q), with a restitution law,
    d = (0, n): the normal contact force on the velocities, which holds while the free
    flow pushes into the surface (Φ̈ < 0). Sliding starts at the impact where Zeno is detected (the skipped
    tail is at most `zeno_rtol·t` long; the state is projected onto M, removing the
    residual normal velocity), or at once after a tangential post-impact state pushed in
    (e.g. restitution 0). It ends at the first root of Φ̈ (bracketed on the step's dense
    output, a solver step lands on it); the state is projected onto M again and flies
    freely from there. Another surface met while sliding is an ordinary impact (sliding
    stops, and restarts if the state is again tangential and pushed in). Sliding on two
    surfaces at once is not modelled: the run ends with `Status.ZENO`.

    **Event semantics** (docs/semantics.md): an impact on Γ_i happens when Φ_i reaches 0 while
    decreasing, or touches 0 tangentially, at a point of the closed piece (`where` true to
    within round-off). Upward crossings pass through; Φ < 0 is allowed. A flight starting on
    a surface (after a jump or at x0) does not impact at its start time. Excursions into
    Φ < 0 shorter than a solver step are found by an in-step minimum search: an excursion of
    depth δ > floor is an impact, a miss by more than the floor is not, and contacts within
    the floor (64 ulps of Σ_k |∂Φ/∂x_k|·max|x_k| over the flight + |∂Φ/∂t|·|t| + h·|ġ| for a
    step of length h; ~1e-14 for unit-size states) are reported as grazing (γ).
    Contacts on several pieces within ~1e3 ulps of each other
    are simultaneous: all are applied, in the order of `scene.surfaces`, each only if its
    surface is still approached after the previous jumps.

    **Example:**

    ```python
    import grazejax as gj
    from grazejax.examples import bouncing_ball

    scene, args = bouncing_ball(), {"g": 9.81, "e": 0.8}
    sol = gj.simulate(scene, [1.0, 0.0], 0.0, 2.0, args)
    print(sol.summary())
    ```
    """
    options = dict(
        solver=solver, rtol=rtol, atol=atol, stepsize_controller=stepsize_controller,
        dt0=dt0, max_impacts=max_impacts, max_steps=max_steps, zeno_rtol=zeno_rtol,
        zeno=zeno, adjoint=adjoint, check_field_jumps=check_field_jumps,
        allow_float32=allow_float32,
    )
    if is_concrete(scene, x0, t0, t1, args, saveat, options):
        # Outside any transformation: check the inputs here, where their values are known,
        # then run one cached XLA program, compiled once per scene and options.
        checked = validate_inputs(
            scene, x0, t0, t1, args, max_impacts=max_impacts, max_steps=max_steps,
            direction=direction, allow_float32=allow_float32, saveat=saveat,
        )
        sol = _compiled_run(
            scene, checked.x0, checked.t0, checked.t1, _traced_numbers(args),
            saveat=checked.ts, direction=checked.sigma, **options,
        )
    else:
        sol = _run(scene, x0, t0, t1, args, saveat=saveat, direction=direction, **options)
    _raise_if_bad_input(sol)
    if throw:
        sol = _throw_if_failed(sol)
    return sol


def _run(scene, x0, t0, t1, args, *, saveat, direction, adjoint, max_steps, **options):
    """The run itself: one XLA program (prepare, loop, finish), no Python-side checks."""
    checked, program = prepare(
        scene, x0, t0, t1, args, saveat=saveat, direction=direction, adjoint=adjoint,
        max_steps=max_steps, **options,
    )

    def cond(c):
        # Unbatched on purpose: under vmap, a batched predicate makes JAX select every
        # carry leaf per lane at every iteration, copying the whole impact log and save
        # buffers (measured: 56 µs per lane-step with max_impacts = 400). Finished lanes
        # are frozen by `step` itself, so the loop can run until the last lane is done.
        return eqxi.unvmap_any(program.running(c))

    final = run_loop(cond, program, program.init(checked.x0, args), adjoint, max_steps)
    return program.finish(final)


# A call outside jit used to run the loop's `while` as its own program, traced and compiled
# again at every call (~1.5 s each for ex1dof, 20 impacts), with everything around it
# dispatched op by op. As one jitted program, a repeated call with the same scene and
# options runs at once (x0, t0, t1, array args and Python floats in args are inputs; the
# input checks already trace scene functions with abstract `args`, so no scene can read a
# float of `args` in Python, and passing the floats as inputs changes no scene's behaviour).
_compiled_run = single_run_jit(_run)


def _traced_numbers(args):
    """`args` with its Python floats as arrays (inputs of the compiled run, so that a new
    value does not compile it again); `args` itself if it has none. Ints, bools and other
    leaves stay static. (Not `_linearize._args_arrays`, which makes ints floats and floats
    strong float64 for differentiating with respect to them: here an int may be an index,
    and a float32 run keeps its weak floats.)"""
    leaves, tree = jax.tree.flatten(args)
    if not any(isinstance(leaf, float | np.floating) for leaf in leaves):
        return args
    return jax.tree.unflatten(tree, [jnp.asarray(leaf) if isinstance(leaf, float | np.floating)
                                     else leaf for leaf in leaves])


def run_loop(cond, program: "Program", init, adjoint, max_steps: int):
    """`while cond: step`, as the loop kind that `adjoint` asks for (see `_adjoint`)."""
    kinds = loop_kinds(adjoint)
    if kinds.outer == "lax":
        final = _staged_log_loop(cond, program, init)
        # Name the fix if someone asks for reverse mode (the bare error names lax.while_loop).
        return _mark_forward_only(final)
    if kinds.outer == "checkpointed":
        checkpoints = _checkpoint_count(kinds.checkpoints, max_steps)
        if checkpoints is None:
            return _two_level_checkpointed(cond, program, init, max_steps + 1)
        if checkpoints == max_steps + 1 and _stores_pay(program, init):
            return _every_step_stored(cond, program, init, max_steps + 1)
        if checkpoints == max_steps + 1 and _stages_log(program, init):
            return _every_step_staged(cond, program, init, max_steps + 1)
        pack, unpack = packing(init)
        final, _ = _checkpointed_deciding(
            lambda packed: cond(unpack(packed)), program, pack, unpack, init, max_steps + 1,
            checkpoints, buffers=True)
        return unpack(final)
    # DirectAdjoint: nested scans whose recomputation replays the step decisions
    # (`_loop/bounded.py`). The log stays in the carry: as Equinox buffers it took 8–10×
    # the primal at 10 impacts against 4.6× (separate runs on a loaded machine).
    return bounded_while_loop(cond, program.step, init, max_steps + 1)


def _two_level_checkpointed(cond, program: "Program", init, bound: int):
    """`while cond: step` for at most `bound` iterations, reverse-differentiable with
    two levels: an Equinox checkpointed loop stores the state every `chunk ≈ √bound`
    steps, and each chunk is a loop that stores its steps' linearisations
    (`_loop/stored.py`) while the backward pass crosses it, or, where a step's residuals
    are large (`_stores_pay`), an Equinox loop with a checkpoint per step. The price is
    one more forward pass over each chunk; memory: ~√bound carries and `chunk` rows of
    residuals (or carries), whatever the run's length.

    History, forced impact oscillator, one core, min of 7, each against the previous code
    in the same minutes: Equinox's own schedule (√(2·bound) ≈ 447 checkpoints, recursive
    recomputation) 10.2/11.0x the primal at 100/1000 impacts -> two levels of Equinox
    loops with a checkpoint per iteration 8.0/8.3x; the log staged (below) 5.9/6.7/6.8x
    at 10/100/1000 impacts; each step as a nested computation (`_nested`)
    4.7/4.8/5.0x; the chunks as loops that store linearisations (no step of a chunk run
    a third time in the backward pass) 4.53/4.69/4.96x -> 3.97/4.16/4.42x (same process,
    min of 9), gradients bit-equal. The chunk length mattered little (64 or 2048 steps: within 1%).

    The backward pass runs each chunk again from its checkpoint: the first pass records
    every step's decisions (a row per step, a write-once buffer) and the re-run replays
    them (`_loop/replay.py`), so that XLA's different
    rounding of the re-run cannot make it take other steps (gradients were off by up to
    3.3e-8 relative at rtol = 1e-12). Cost, alternately with the code before (two rounds):
    4.2-4.5/4.5/4.5-4.6x the primal at 10/100/1000 impacts against 3.8-4.3/4.3/4.5x.

    Where a single run stages its log (`_stages_log`), an outer iteration also ends at a
    landing that wrote rows, and moves them to the full log (the outer loop's write-once
    buffers; ~one more carry per log row). The inner loop then carries one landing's rows
    instead of the whole log, so its passes run on XLA's sequential executor as the
    primal does.
    """
    chunk = math.isqrt(bound - 1) + 1
    outer_bound = -(-bound // chunk)
    pack, unpack = packing(init)
    staging = _stages_log(program, init)
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

    store_linearisations = _stores_pay(program, init)
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
        if store_linearisations:
            staged, _, decided = stored_while_loop(
                inner_cond, _packed_deciding(program, inner_pack, inner_unpack),
                inner_pack(staged), chunk, replay=forced,
            )
        else:
            staged, decided = _checkpointed_deciding(
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


def _packed_deciding(program: "Program", pack, unpack):
    """`program.deciding_step` on packed states."""

    def step(packed, forced):
        c, decided = program.deciding_step(unpack(packed), forced)
        return pack(c), decided

    return step


def _checkpointed_deciding(cond, program: "Program", pack, unpack, c, bound: int,
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


def _every_step_stored(cond, program: "Program", init, bound: int):
    """`while cond: step` for at most `bound` steps, every step's linearisation stored
    (`_loop/stored.py`): the backward pass applies the stored pullbacks and runs no step
    again. Where a single run stages its log (`_stages_log`), the loop carries one
    landing's rows and writes them to the full log (write-once buffers) after the step
    that staged them. Forced impact oscillator, 1000-row log, one core, min of 9, against
    Equinox's checkpointed loop with a checkpoint per step in the same process:
    3.56/3.76/3.92x -> 2.94/3.24/3.76x the primal at 10/100/1000 impacts."""
    if not _stages_log(program, init):
        pack, unpack = packing(init)
        small, _ = stored_while_loop(
            lambda packed: cond(unpack(packed)),
            lambda packed: pack(program.step(unpack(packed))), pack(init), bound,
        )
        return unpack(small)
    staged, full_log = stage_log(init, program.log_rows_per_landing)
    pack, unpack = packing(staged)

    def step(packed):
        return pack(_staging_own_rows(program)(unpack(packed)))

    small, log = stored_while_loop(
        lambda packed: cond(unpack(packed)), step, pack(staged), bound,
        buffers=full_log,
        write=lambda packed, log: impact_log(flush_log(unpack(packed), log)),
        ends_block=lambda packed: eqxi.unvmap_any(has_staged_rows(unpack(packed))),
    )
    return with_full_log(unpack(small), log)


def _every_step_staged(cond, program: "Program", init, bound: int):
    """`while cond: step`, every step a checkpoint, with the impact log staged: the loop
    carries one landing's rows, and each iteration moves the rows its step wrote to the
    full log (the loop's write-once buffers) after the step. The step itself, and its VJP,
    then run in a nested computation with small buffers only (`_nested`), while the full
    log is written outside it. Forced impact oscillator, 1000-row log, one core, min of 7,
    the previous commit alternately: 4.9/5.2× → 3.7/3.6× the primal at 10 impacts,
    5.7/5.6× → 4.0/3.9× at 100; the same results and gradients (`tests/test_reverse.py`)."""
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


def _staging_own_rows(program: "Program"):
    """The step of the every-step loops that stage the log: row 0 of the staging log is
    the next impact, so each step stages its own rows (flushed after it)."""

    def step(c):
        return program.step(eqx.tree_at(lambda z: z.log_base, c, c.num_impacts))

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


def _stages_log(program: "Program", init) -> bool:
    """Whether a single run's loop writes its impact log outside the loop that steps (see
    `_staged_log_loop`)."""
    rows = program.log_rows_per_landing
    log_bytes = max(
        math.prod(jnp.shape(b)) * jnp.result_type(b).itemsize for b in impact_log(init)
    )
    return rows > 0 and log_bytes > SEQUENTIAL_BUFFER_BYTES and not _under_vmap(init)


def _stores_pay(program: "Program", init) -> bool:
    """Whether reverse mode stores each step's linearisation (`_loop/stored.py`) rather
    than a carry per step that the backward pass runs again (Equinox's checkpointed loop).

    Measured (one core, min of 7-11, both in the same process), every step stored / the
    default two levels: forced impact oscillator, 864 bytes of residuals per step, 3.0x /
    4.1-4.4x the primal against 3.55x / 4.5-5.0x; a Fourier forcing of 10/40/100
    coefficients, 3/6/24 KB per step (the pieces the blocks stage them in, and their
    store, cost more than a step's re-run): 4.7/6.0/6.4x / 5.5/7.6/10.9x against
    4.0/4.9/4.3x / 5.3/6.3/5.8x. Under `vmap` the stores hold every lane's residuals:
    forced oscillator, 10 impacts, `vmap(grad)`, 16 lanes 3.40x / 4.14x against 3.55x /
    4.49x, 128 lanes 6.39x / 6.14x against 4.53x / 5.07x; batched runs keep carries.
    """
    if _under_vmap(init):
        return False
    if _stages_log(program, init):
        init = stage_log(init, program.log_rows_per_landing)[0]
    pack, unpack = packing(init)
    step = lambda packed: pack(program.step(unpack(packed)))  # noqa: E731
    return residual_bytes(step, pack(init)) <= _STORED_RESIDUAL_BYTES


def _checkpoint_count(checkpoints: int | None, max_steps: int) -> int | None:
    """The checkpoints to ask Equinox for: `checkpoints >= max_steps` means every step.

    The loop runs up to `max_steps + 1` iterations (the last one marks MAX_STEPS), and
    Equinox's checkpointed loop takes its fast path (no recomputation, no checkpoint
    schedule in the backward pass) only when the checkpoints equal its step bound: a user's
    `RecursiveCheckpointAdjoint(checkpoints=max_steps)` missed it by one and cost 8.9× the
    primal instead of 5.2× (forced impact oscillator, 10 impacts, max_steps = 1000).
    """
    if checkpoints is not None and checkpoints >= max_steps:
        return max_steps + 1
    return checkpoints


def _under_vmap(tree) -> bool:
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


# The most residual bytes per step that reverse mode stores (see `_stores_pay`).
_STORED_RESIDUAL_BYTES = 1024


def _staged_log_loop(cond, program: "Program", init):
    """`while cond: step`, in phases: the impact log written outside the loop that steps,
    and the steps of a sliding policy only while something slides.

    The inner loop steps with a staging log of one landing's rows and stops when a lane has
    staged one; the outer loop moves those rows to the full log and resumes. At batch 1
    the inner body then touches no buffer over XLA:CPU's 512-byte threshold for running
    its kernels in sequence (see `stage_log`); the outer body runs once per impact.

    Only where it gains (measured on ex1dof, t ∈ [0, 60], 9 impacts): a single run or its
    `jacfwd` with a 100-row log took 0.59-0.65× the time of the plain loop, an unused log
    0.96-1.03× (XLA drops it either way). Not under `vmap`: every iteration there already
    touches large buffers, and the outer loop would stop whenever any lane impacts (a
    64-lane vmap took 1.26×). A small log (≤ 512 bytes) needs none of it.

    With `ZenoStick`, the steps while no lane slides are `program.free_step` (no sliding
    field, no search for the end of sliding: a run that never slides paid 1.25× for the
    two per-step tests at batch 1, grazejax issue 14), and `program.step` runs from the
    landing that starts sliding until no lane slides; under `vmap` too (the phase changes
    only when a lane starts or ends sliding). Same values either way: `step`'s tests pick
    exactly `free_step`'s computation while nothing slides.
    """
    rows = program.log_rows_per_landing
    staging = _stages_log(program, init)
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


def _mark_forward_only(tree):
    is_float = lambda leaf: eqx.is_inexact_array(leaf)  # noqa: E731
    floats, others = eqx.partition(tree, is_float)
    floats = eqxi.nondifferentiable_backward(floats, msg=REVERSE_HINT)
    return eqx.combine(floats, others)


def prepare(scene, x0, t0, t1, args, *, saveat, direction, allow_float32, max_impacts,
            max_steps, **loop_options):
    """Check the inputs of one run and build its loop: `(checked inputs, Program)`.

    Shared by `simulate` and `sweep`'s pool, which passes one lane's inputs as the template.
    `loop_options` are `build_program`'s other keyword options.
    """
    checked = validate_inputs(
        scene, x0, t0, t1, args, max_impacts=max_impacts, max_steps=max_steps,
        direction=direction, allow_float32=allow_float32, saveat=saveat,
    )
    program = build_program(
        scene, checked, max_impacts=max_impacts, max_steps=max_steps, **loop_options
    )
    return checked, program


def _raise_if_bad_input(sol: Solution):
    """Outside jit and vmap a start inside an impenetrable surface, and a field that jumps
    at an event surface, are input errors: raise a `ValueError` that names the fix."""
    status = sol.status
    if isinstance(status, jax.core.Tracer) or jnp.ndim(status) != 0:
        return
    if int(status) == Status.FIELD_DISCONTINUITY:
        k = int(sol.num_impacts) - 1
        at = (f"at the event at t = {float(sol.t_final):.15g} (surface "
              f"{int(sol.impact_surface[k])}, post-event state {sol.x_final})" if k >= 0 else
              f"at x0 = {sol.x_final}, which lies on a surface")
        raise ValueError(
            f"the vector field jumps {at}: it "
            "switches on the event surface itself (sign(·) or jnp.where on the state), so "
            "the side whose field the next flight uses is decided by round-off, and the run "
            f"would lose accuracy silently. Fix: {FIELD_FIX}."
        )
    if int(status) == Status.BAD_START:
        raise ValueError(
            f"x0 = {sol.x_final} lies inside an impenetrable surface (Φ < 0 beyond round-off, "
            "inside its `where`): start on the free side Φ >= 0, or mark the surface "
            "impenetrable=False if trajectories may live in Φ < 0"
        )


def _throw_if_failed(sol: Solution) -> Solution:
    """`throw=True`: fail loudly if the run did not end with one of `ACCEPTED`.

    Outside `jit` the status is a value: raise a `SimulationError` that names it and
    carries the Solution. Inside `jit`/`vmap` there is no value to test in Python, so the
    check is compiled in (`eqx.branched_error_if`): the runtime error names the status
    (under `vmap`: the highest failing status code of the batch), without the Solution.
    """
    status = sol.status
    if not isinstance(status, jax.core.Tracer):
        if not np.all(np.isin(np.asarray(status), [int(s) for s in ACCEPTED])):
            raise SimulationError(sol)
        return sol
    ok = functools.reduce(jnp.logical_or, [status == int(s) for s in ACCEPTED])
    messages = [failure_message(Status(code)) for code in range(len(Status))]
    x_final = eqx.branched_error_if(sol.x_final, ~ok, status, messages)
    return eqx.tree_at(lambda s: s.x_final, sol, x_final)
