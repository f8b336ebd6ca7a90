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
- **Events located exactly, never missed.** `_loop/events.py` tests every accepted step for
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
import inspect

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import numpy as np

from ._adjoint import loop_kinds
from ._compiler import compiler_options
from ._loop.compact import under_vmap
from ._loop.policies import AbstractZenoPolicy
from ._loop.program import build_program
from ._loop.runners import loop_for
from ._roots import AbstractBracketedRootFinder
from ._scene import Scene
from ._solution import ACCEPTED, FIELD_FIX, SimulationError, Solution, failure_message
from ._status import Status
from ._validate import has_values, validate_inputs

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
    event_root_finder: AbstractBracketedRootFinder | None = None,
) -> Solution:
    r"""Simulate x' = f(t, x) with jumps x → J_i(x) on the surface pieces Γ_i, from t0 to t1.

    One call is one XLA program: it works under `jax.jit`, `jax.vmap` (batched `x0` and
    `args` leaves) and `jax.jacfwd` (with respect to `x0` and `args`). Called outside `jit`
    and `vmap` (also under an eager `jax.jvp`, `jax.jacfwd` or `jax.grad`), it checks its
    inputs and runs a program compiled once per scene object and options (with
    `grazejax.compiler_options(batched=False)`) and kept: new `x0`, `t0`, `t1`, numbers in
    `args`, `rtol`, `atol`, `zeno_rtol` and `dt0` do not compile it again, and a second eager
    `jax.jacfwd` or `jax.grad` of a call reuses the first one's program. What counts as an
    impact, a grazing contact, Zeno and sticking is written down exactly in docs/semantics.md.

    **Arguments:**

    - `scene`: a `grazejax.Scene`.
    - `x0`: initial state, shape `(n,)`: on a surface is allowed, strictly inside is not.
    - `t0`, `t1`: start and end times. `t1 < t0` runs backward through the image surfaces
      J_i(Γ_i); `t1 = ±inf` runs until `max_impacts` (`max_impacts=1`: the impact map).
    - `args`: a pytree of parameters passed to every scene function; changing its numbers
      never recompiles.
    - `solver`: a Diffrax solver (default `diffrax.Tsit5()`; tested: `Tsit5`, `Dopri5`,
      `Dopri8`, `grazejax.Vern9`, and the implicit `Kvaerno5` for stiff flows).
    - `rtol`, `atol`: tolerances of the default `diffrax.PIDController`.
    - `stepsize_controller`: an adaptive Diffrax controller (overrides `rtol`/`atol`).
    - `dt0`: first step size (default: chosen by the controller).
    - `max_impacts`: rows of the impact log; the run stops (`MAX_IMPACTS`) after as many.
    - `max_steps`: bound on solver steps (status `MAX_STEPS`).
    - `saveat`: a `diffrax.SaveAt(ts=..., t0=..., t1=...)` or a 1-D array of times, monotone
      in the direction of integration (pre-impact values at an impact time).
    - `zeno_rtol`: Zeno is declared when the inter-impact times shrink geometrically and
      the predicted time left is below `zeno_rtol × (t − t0)`.
    - `zeno`: at a Zeno accumulation or a tangential restart pushed into a surface:
      `"stop"` or `grazejax.ZenoStop()` (default: status `ZENO`); `"stick"` or
      `grazejax.ZenoStick()` (slide on the surface until the flow pulls away).
    - `direction`: `+1` or `-1`; needed only when `t0`, `t1` are traced (inside `jit`).
    - `allow_float32`: accept a float32 `x0` (contact floors then scale with float32's
      epsilon); otherwise grazejax runs in float64.
    - `throw`: raise unless the run ends with `SUCCESS`, `MAX_IMPACTS` or `ZENO`: outside
      `jit` a `grazejax.SimulationError` (the Solution as `error.solution`), inside a
      runtime error naming the status.
    - `adjoint`: a Diffrax adjoint: `None`/`diffrax.ForwardMode()` (default) for `jax.jacfwd`,
      `diffrax.RecursiveCheckpointAdjoint()` for `jax.grad`, `diffrax.DirectAdjoint()` for
      both (memory and cost: docs/linearization.md).
    - `check_field_jumps`: probe f where each flight restarts and stop with
      `FIELD_DISCONTINUITY` if it jumps there; `False` compiles the probe out.
    - `event_root_finder`: the bracketed root finder of the searches inside a step:
      `grazejax.Chandrupatla` (default), `grazejax.ITP` or `grazejax.BracketedNewton`.

    **Returns:** a `grazejax.Solution` (under `jax.vmap`, each field gains a batch axis):

    - `t_final`, `x_final`: where the run stopped: `t1` and x(t1) on `SUCCESS`, the last
      impact's time and post-impact state on `MAX_IMPACTS` and `ZENO`, the last state
      reached on a failure.
    - `status`: a `grazejax.Status` code (`sol.summary()` prints the run).
    - `num_impacts`: rows used in the impact log, whose `max_impacts` rows are padded with
      NaN: `impact_times` (θ), `impact_pre` (x(θ)), `impact_post` (x(θ+) = J(x(θ))),
      `impact_surface` (index in `scene.surfaces`), `impact_kind` (a `grazejax.ImpactKind`).
    - `zeno_time`: the estimated accumulation time when `status == ZENO`, else NaN.
    - `num_steps`, `num_accepted_steps`: solver steps, all and accepted.
    - `ts`, `xs`: saved times and states (`None` without `saveat`).

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
        allow_float32=allow_float32, event_root_finder=event_root_finder,
    )
    if has_values(scene, x0, t0, t1, args, saveat, options):
        # Outside jit and vmap (eager, or under an eager jvp/jacfwd/grad, whose primals are
        # values): check the inputs here, where their values are known, then run one cached
        # XLA program, compiled once per scene and options. JAX caches the program's
        # transforms too, so a second eager `jax.jacfwd` of the same call is not compiled
        # again.
        checked = validate_inputs(
            scene, x0, t0, t1, args, max_impacts=max_impacts, max_steps=max_steps,
            direction=direction, allow_float32=allow_float32, saveat=saveat,
            check_scene=False,  # `prepare` checks it when the run compiles
        )
        sol = _run_compiled(scene, checked, _traced_numbers(args), _traced_options(options))
    else:
        sol = _run(scene, x0, t0, t1, args, saveat=saveat, direction=direction, **options)
    _raise_if_bad_input(sol)
    if throw:
        sol = _throw_if_failed(sol)
    return sol


# simulate's keyword options and their defaults, read from its signature once: the entry
# points built on it (sweep, the sections, the dynamics functions) check and fill theirs here.
SIMULATE_OPTIONS = {
    name: p.default
    for name, p in inspect.signature(simulate).parameters.items()
    if p.kind is inspect.Parameter.KEYWORD_ONLY
}


def _run(scene, x0, t0, t1, args, *, saveat, direction, adjoint, max_steps, **options):
    """The run itself: one XLA program (prepare, loop, finish), no Python-side checks."""
    checked, program = prepare(
        scene, x0, t0, t1, args, saveat=saveat, direction=direction, adjoint=adjoint,
        max_steps=max_steps, batched=under_vmap((x0, t0, t1, args)), **options,
    )

    def cond(c):
        # Unbatched on purpose: under vmap, a batched predicate makes JAX select every
        # carry leaf per lane at every iteration, copying the whole impact log and save
        # buffers (the cost grows with max_impacts). Finished lanes
        # are frozen by `step` itself, so the loop can run until the last lane is done.
        return eqxi.unvmap_any(program.running(c))

    loop = loop_for(loop_kinds(adjoint))
    final = loop.run(cond, program, program.init(checked.x0, args), max_steps)
    return program.finish(final)


# Outside jit, the loop's `while` would run as its own program, traced and compiled again
# at every call, with everything around it dispatched op by op. As one jitted program, a
# repeated call with the same scene and options runs at once (x0, t0, t1, array args and
# Python floats in args are inputs; the input checks already trace scene functions with
# abstract `args`, so no scene can read a float of `args` in Python, and passing the floats
# as inputs changes no scene's behaviour). One `jax.jit` per static configuration, looked up
# by a key built from the known structure of the call: its dispatch is JAX's own, where a
# generic filtered jit partitions and hashes every input at every call.
_COMPILED: dict = {}


def _run_compiled(scene, checked, args, options) -> Solution:
    """`_run` as a compiled program, cached per scene, options and the static leaves of
    `args` (the arrays of `args` and `options`, x0, t0, t1 and the save times are inputs)."""
    leaves, tree = jax.tree.flatten((args, options))
    is_input = tuple(eqx.is_array(leaf) for leaf in leaves)
    inputs = [leaf for leaf, dynamic in zip(leaves, is_input, strict=True) if dynamic]
    static = tuple(None if dynamic else leaf for leaf, dynamic in zip(leaves, is_input, strict=True))
    top_level = _runs_at_top_level((checked.x0, checked.t0, checked.t1, inputs))
    key = (scene, checked.sigma, checked.ts is None, tree, static, top_level)
    try:
        run = _COMPILED.get(key)
    except TypeError as error:
        raise TypeError(
            "simulate: every leaf of `args` and of the options must be an array, a number or "
            f"another hashable value (it is part of the compiled program's key): {error}"
        ) from error
    if run is None:
        sigma = checked.sigma

        def program(x0, t0, t1, ts, inputs):
            given = iter(inputs)
            args_, options_ = jax.tree.unflatten(
                tree, [next(given) if leaf is None else leaf for leaf in static])
            return _run(scene, x0, t0, t1, args_, saveat=ts, direction=sigma, **options_)

        # Compiler options are for top-level programs only: under `jax.grad` the program is
        # staged into the linearized one, which JAX compiles with its own options.
        run = jax.jit(program, compiler_options=compiler_options(batched=False)
                      if top_level else None)
        _COMPILED[key] = run
    return run(checked.x0, checked.t0, checked.t1, checked.ts, inputs)


def _runs_at_top_level(tree) -> bool:
    """Whether a `jax.jit` called on `tree` compiles as its own program: eagerly, or under an
    eager `jax.jvp`/`jax.jacfwd`, not under the linearization of `jax.grad`/`jax.vjp`."""
    try:
        from jax._src.interpreters.ad import JVPTracer
    except ImportError:  # pragma: no cover
        return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(tree))
    return all(isinstance(leaf, JVPTracer) or not isinstance(leaf, jax.core.Tracer)
               for leaf in jax.tree.leaves(tree))


def _traced_numbers(args):
    """`args` with its Python floats as arrays (inputs of the compiled run, so that a new
    value does not compile it again); `args` itself if it has none. Ints, bools and other
    leaves stay static. (Not `_linearize.common._args_arrays`, which makes ints floats and
    floats strong float64 for differentiating with respect to them: here an int may be an
    index, and a float32 run keeps its weak floats.)"""
    leaves, tree = jax.tree.flatten(args)
    if not any(isinstance(leaf, float | np.floating) for leaf in leaves):
        return args
    return jax.tree.unflatten(tree, [jnp.asarray(leaf) if isinstance(leaf, float | np.floating)
                                     else leaf for leaf in leaves])


# The numeric options that are inputs of the compiled run (a new value is not a new
# program). `dt0` is one only for adaptive controllers: a constant step reads it in Python.
_NUMERIC_OPTIONS = ("rtol", "atol", "zeno_rtol", "dt0")


def numeric_options(options) -> dict:
    """The numeric options of `options` (`simulate`'s defaults where absent) as arrays:
    `{name: array}` for rtol, atol, zeno_rtol, and dt0 when given to an adaptive controller.
    A value that is already an array stays as it is."""
    constant_step = isinstance(options.get("stepsize_controller"), diffrax.ConstantStepSize)
    numbers = {}
    for name in _NUMERIC_OPTIONS:
        value = options.get(name, SIMULATE_OPTIONS[name])
        if value is None or (name == "dt0" and constant_step):
            continue
        if isinstance(value, bool) or not eqx.is_array_like(value):
            continue  # (an invalid value: left to the checks that name it)
        numbers[name] = value if eqx.is_array(value) else jnp.asarray(float(value))
    return numbers


def _traced_options(options):
    """`options` with its numeric options as arrays (inputs of the compiled run)."""
    return {**options, **numeric_options(options)}


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
        scene, checked, max_impacts=max_impacts, max_steps=max_steps, args=args, **loop_options
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
            "inside its `where`) or on it moving in (the first flight would start inside): "
            "start on the free side Φ >= 0 (on the surface: moving out, e.g. the "
            "post-impact state J(x0) of a pre-impact x0), or mark the surface "
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
