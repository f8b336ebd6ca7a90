"""`simulate`: the jit-compiled impact loop.

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
from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp
import numpy as np

from ._adjoint import REVERSE_HINT, loop_kinds
from ._events import is_candidate, locate, step_ends
from ._geometry import (
    FLOOR_ULPS,
    backward_piece,
    contact_frame,
    forward_piece,
    gap_rates,
    is_tangential,
    project_to_contact,
)
from ._roots import bracketed_root, safe_divide
from ._scene import Scene
from ._solution import ACCEPTED, SimulationError, Solution, failure_message
from ._status import ImpactKind, Status
from ._stepping import error_or_zero, loop_controller
from ._validate import validate_inputs

# --------------------------------------------------------------------------------------
# Loop state
# --------------------------------------------------------------------------------------


class _Carry(eqx.Module):
    args: Any  # this lane's parameters (in the carry so that a pool of lanes can refill)
    time_scale: Any  # |t| below which a step no longer moves time (see h_min_at)
    s: Any  # local clock at the start of the next step
    t_hi: Any  # absolute time of the last restart, double-double
    t_lo: Any
    y: Any
    h: Any  # next step size
    solver_state: Any
    controller_state: Any
    made_jump: Any
    restart: Any  # bool[m]: the flight starts on surface i (guard its first step)
    flight_scale: Any  # max |x_k| over the current flight, per coordinate: its round-off scale
    landing: Any  # bool: the next step lands exactly on a located contact
    target: Any  # local time of that contact
    pending: Any  # bool[m, signs]: which surfaces (and sides) the contact involves
    touch: Any  # bool[m, signs]: tangential contacts (γ)
    boundary: Any  # bool[m, signs]: contacts on ∂Γ (β)
    h_after: Any  # step size to resume with after the impact
    num_impacts: Any
    log_t: Any
    log_pre: Any
    log_post: Any
    log_surface: Any
    log_kind: Any
    stick: Any  # bool[m]: sliding on surface i, held by its contact force (zeno="stick")
    releasing: Any  # bool: the located event is the end of that sliding (release)
    intervals: Any  # the last three inter-impact times, for Zeno detection
    zeno_time: Any
    num_steps: Any
    num_accepted: Any
    status: Any
    done: Any
    t_final: Any
    x_final: Any
    save_index: Any
    save_xs: Any


def _two_sum(a, b):
    s = a + b
    bb = s - a
    err = (a - (s - bb)) + (b - bb)
    return s, err


def _dd_add(hi, lo, x):
    """(hi, lo) + x in double-double arithmetic."""
    s, e = _two_sum(hi, x)
    e = e + lo
    return _two_sum(s, e)


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
    zeno: str = "stop",
    direction: int | None = None,
    allow_float32: bool = False,
    throw: bool = False,
    adjoint=None,
) -> Solution:
    r"""Simulate x' = f(t, x) with jumps x → J_i(x) on the surface pieces Γ_i, from t0 to t1.

    One call is one XLA program: it works under `jax.jit`, `jax.vmap` (batched `x0` and
    `args` leaves) and `jax.jacfwd` (with respect to `x0` and `args`).

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
      `Dopri8`, and the implicit `Kvaerno5` for stiff flows.
    - `rtol`, `atol`: tolerances of the default `diffrax.PIDController`.
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
      surface. `"stop"` (default): the run ends with `Status.ZENO`. `"stick"`: the state
      slides on the surface (Φ = 0, Φ̇ = 0) under the contact force that the free flow
      calls for (see *Sticking* below) and is released when the free flow would pull it
      away (Φ̈ ≥ 0); both moments are logged (`ImpactKind.STICK`, `ImpactKind.RELEASE`).
      Forward time only.
    - `direction`: `+1` or `-1`; needed only when `t0`, `t1` are traced (inside `jit`).
    - `allow_float32`: grazejax runs in float64; a float32 `x0` is an error unless this
      is set (contact floors then scale with float32's epsilon).
    - `adjoint`: how the loop is differentiated, as a Diffrax adjoint.
      `None`/`diffrax.ForwardMode()` (default): `jax.jvp`/`jax.jacfwd`;
      `diffrax.RecursiveCheckpointAdjoint(checkpoints=...)`: `jax.grad`/`jax.vjp`
      (recomputes steps between checkpoints); `diffrax.DirectAdjoint()`: both modes, at the
      memory cost of every step. Event-time tangents are the same in every mode (the
      implicit function theorem at the landing step).
    - `throw`: raise if the run does not end with `SUCCESS`, `MAX_IMPACTS` or `ZENO`.
      Outside `jit`: a [`grazejax.SimulationError`][] that names the status and the fix,
      with the Solution as `error.solution`. Inside `jit`/`vmap`: a runtime error
      (`eqx.branched_error_if`) that names the status, without the Solution.
      ([`grazejax.sweep`][] checks on the host and names the failing lanes.)

    **Returns:** a [`grazejax.Solution`][].

    **Sticking** (`zeno="stick"`): on the contact manifold M = {Φ = 0, Φ̇ = 0} the flow is
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
    checked, program = prepare(
        scene, x0, t0, t1, args, saveat=saveat, direction=direction,
        allow_float32=allow_float32, solver=solver, rtol=rtol, atol=atol,
        stepsize_controller=stepsize_controller, dt0=dt0, max_impacts=max_impacts,
        max_steps=max_steps, zeno_rtol=zeno_rtol, zeno=zeno, adjoint=adjoint,
    )

    def cond(c):
        # Unbatched on purpose: under vmap, a batched predicate makes JAX select every
        # carry leaf per lane at every iteration, copying the whole impact log and save
        # buffers (measured: 56 µs per lane-step with max_impacts = 400). Finished lanes
        # are frozen by `step` itself, so the loop can run until the last lane is done.
        return eqxi.unvmap_any(program.running(c))

    final = run_loop(cond, program, program.init(checked.x0, args), adjoint, max_steps)
    sol = program.finish(final)
    _raise_if_bad_start(sol)
    if throw:
        sol = _throw_if_failed(sol)
    return sol


def run_loop(cond, program: "Program", init, adjoint, max_steps: int):
    """`while cond: step`, as the loop kind that `adjoint` asks for (see `_adjoint`)."""
    kinds = loop_kinds(adjoint)
    if kinds.outer == "lax":
        final = lax.while_loop(cond, program.step, init)
        # Name the fix if someone asks for reverse mode (the bare error names lax.while_loop).
        return _mark_forward_only(final)
    return eqxi.while_loop(
        cond, program.step, init, max_steps=max_steps + 1, kind=kinds.outer,
        checkpoints=kinds.checkpoints,
    )


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


class Program(eqx.Module):
    """The impact loop of one configuration, as functions of one lane's loop state.

    `simulate` is `finish(while_loop(any running, step, init(x0, args)))`. `sweep` runs the
    same functions on a pool of lanes that it refills as lanes finish, so every lane
    computes exactly what `simulate` computes for it alone.
    """

    init: Callable = eqx.field(static=True)  # (x0, args) -> carry
    step: Callable = eqx.field(static=True)  # carry -> carry: one solver step (frozen when done)
    running: Callable = eqx.field(static=True)  # carry -> bool: not finished, not out of steps
    finish: Callable = eqx.field(static=True)  # carry -> Solution


def build_program(
    scene: Scene, checked, *, solver, rtol, atol, stepsize_controller, dt0, max_impacts,
    max_steps, zeno_rtol, zeno="stop", adjoint=None,
) -> Program:
    """The loop functions for `scene`, with inputs checked by `validate_inputs`.

    `checked.x0` is only a template (shape and dtype); t0, t1 and saveat are shared by
    every lane that runs the program.
    """
    if zeno not in ("stop", "stick"):
        raise ValueError(f"zeno must be 'stop' or 'stick', got {zeno!r}")
    if zeno == "stick" and checked.sigma < 0:
        raise ValueError(
            "zeno='stick' is forward time only: a backward run cannot tell where a sliding "
            "phase began (the release map is not invertible)"
        )
    t0, t1, sigma, ts = checked.t0, checked.t1, checked.sigma, checked.ts
    dtype = checked.x0.dtype
    n = checked.x0.shape[0]

    if solver is None:
        solver = diffrax.Tsit5()
    # Diffrax's solvers with an embedded error estimate are its adaptive solvers (Euler and
    # the stochastic ones are not).
    has_error = isinstance(solver, diffrax.AbstractAdaptiveSolver)
    controller = loop_controller(
        stepsize_controller, solver, rtol=rtol, atol=atol, dt0=dt0, has_error_estimate=has_error
    )
    solver = _with_implicit_tolerances(solver, controller)
    # Runge-Kutta stages default to a checkpointed loop (custom_vjp), which forward-mode
    # autodiff cannot enter; a plain lax loop supports jvp, jacfwd and vmap. The adjoint
    # decides (see `_adjoint`); a kind the user set on the solver is kept.
    kinds = loop_kinds(adjoint)
    if getattr(solver, "scan_kind", "lax") is None and kinds.stages is not None:
        solver = eqx.tree_at(
            lambda s: s.scan_kind, solver, kinds.stages, is_leaf=lambda x: x is None
        )

    f = scene.vector_field
    if sigma > 0:
        pieces = tuple(forward_piece(s) for s in scene.surfaces)
        impact_kinds = (ImpactKind.ALPHA, ImpactKind.BETA, ImpactKind.GAMMA)
    else:
        pieces = tuple(backward_piece(s, f) for s in scene.surfaces)
        impact_kinds = (ImpactKind.ALPHA_PRIME, ImpactKind.BETA_PRIME, ImpactKind.GAMMA_PRIME)
    m = len(pieces)
    max_signs = max((len(p.signs) for p in pieces), default=1)
    eps = jnp.finfo(dtype).eps
    # The state is only known to the solver's tolerance: piece boundaries (`where`) are
    # resolved to within ten times that, so a crossing exactly on ∂Γ is not lost.
    tol_r = getattr(controller, "rtol", rtol)
    tol_a = getattr(controller, "atol", atol)

    def state_tol(x):
        return 10 * (tol_a + tol_r * jnp.abs(x))

    # The loop runs in local time s >= 0; absolute time is t = t_hi + t_lo + σ s.
    def abs_time(s, t_hi, t_lo):
        return t_hi + (t_lo + sigma * s)

    # Sliding is compiled in only when asked for (zeno="stick"), and the constrained
    # field is evaluated only while some lane slides.
    sticky = zeno == "stick" and m > 0

    def contact_geometry(piece, t, y, args_):
        return contact_frame(piece.gap, piece.jump, f, t, y, args_)

    def sliding_field(t, y, args_, stick, free):
        def constrained():
            out = free
            for i, piece in enumerate(pieces):
                _, _, gdd, _, grad_gd, d = contact_geometry(piece, t, y, args_)
                gain = jnp.dot(grad_gd, d)  # d(Φ̈)/dλ
                force = -safe_divide(gdd, gain, stick[i] & (gain != 0)) * d
                out = out + jnp.where(stick[i], force, 0.0)
            return out

        return lax.cond(eqxi.unvmap_any(jnp.any(stick)), constrained, lambda: free)

    def project_onto_contact(piece, t, y, args_):
        return project_to_contact(piece.gap, piece.jump, f, t, y, args_)

    def local_field(s, y, targs):
        args_, t_hi, t_lo, stick = targs
        t = abs_time(s, t_hi, t_lo)
        free = f(t, y, args_)
        if sticky:
            free = sliding_field(t, y, args_, stick, free)
        return sigma * free

    term = diffrax.ODETerm(local_field)

    def s_end_of(t_hi, t_lo):
        return sigma * ((t1 - t_hi) - t_lo)

    error_order = solver.error_order(term)
    zero = jnp.zeros((), dtype)

    # Below h_min a step no longer moves t: the controller has given up.
    def h_min_at(t_abs, time_scale):
        return 16 * eps * jnp.maximum(jnp.abs(t_abs), time_scale)

    # ---- per-surface helpers (static Python loops over the pieces) ----

    def gap_along(piece, sign, s_to_y, t_hi, t_lo, args_):
        def g(s):
            return sign * piece.gap(abs_time(s, t_hi, t_lo), s_to_y(s), args_)

        return g

    def slopes_at(piece, sign, s, y, t_hi, t_lo, args_):
        """g, ġ, g̈ along the true vector field at (s, y), in the loop's clock."""
        return gap_rates(piece.gap, f, abs_time(s, t_hi, t_lo), y, args_, sign, sigma)

    def sliding_pull(stick, s, y, t_hi, t_lo, args_):
        """Φ̈ of the free flow on the surface being slid on: the state leaves when ≥ 0."""
        rate = jnp.zeros((), dtype)
        for i, piece in enumerate(pieces):
            _, _, gdd = slopes_at(piece, 1, s, y, t_hi, t_lo, args_)
            rate = rate + jnp.where(stick[i], gdd, 0.0)
        return rate

    def on_surface(piece, t, y, args_, x_scale=None, step_ulps=0.0):
        floor = piece.floor(t, y, args_, x_scale)
        if piece.signs:  # the step-length term, with the slope along the true field
            slope = jax.jvp(
                lambda tt, yy: piece.gap(tt, yy, args_), (t, y),
                (sigma * jnp.ones_like(t), sigma * f(t, y, args_)),
            )[1]
            floor = floor + step_ulps * jax.lax.stop_gradient(jnp.abs(slope))
        g = piece.gap(t, y, args_)
        return (jnp.abs(g) <= floor) & jnp.isfinite(g), floor

    nan = jnp.array(jnp.nan, dtype)
    mask_shape = (m, max_signs)

    def contact_tests(t_hi, t_lo, y, args_, x_scale, step_ulps=0.0):
        """Per surface, at a restart: on it (guard the flight's first step), stuck on it,
        and pushed into it by the free flow.

        Stuck is a tangential restart with the flow pushing in: the state would slide into
        Φ < 0 from rest (e.g. restitution 0). That is sticking, the end of a Zeno
        sequence; never tunnel.
        """
        t = t_hi + t_lo
        restart, stuck, pushed = [], [], []
        for piece in pieces:
            on, floor = on_surface(piece, t, y, args_, x_scale, step_ulps)
            restart.append(on)
            stuck_i = pushed_i = jnp.array(False)
            for sign in piece.signs:
                _, gd, gdd = slopes_at(piece, sign, jnp.zeros_like(t), y, t_hi, t_lo, args_)
                tangential = is_tangential(gd, gdd, floor)
                stuck_i = stuck_i | (on & tangential & (gdd < 0))
                pushed_i = pushed_i | (on & (gdd < 0))
            stuck.append(stuck_i)
            pushed.append(pushed_i)
        as_mask = lambda v: jnp.array(v, dtype=bool).reshape((m,))  # noqa: E731
        return as_mask(restart), as_mask(stuck), as_mask(pushed)

    def _starts_inside(t, x, args_, x_scale):
        """x0 strictly inside an impenetrable piece (beyond its contact floor)."""
        inside_any = jnp.array(False)
        for piece in pieces:
            if piece.check_jump_side:
                floor = piece.floor(t, x, args_, x_scale)
                in_piece, _ = piece.inside(t, x, args_, state_tol)
                inside_any = inside_any | ((piece.gap(t, x, args_) < -floor) & in_piece)
        return inside_any

    def init(x0, args) -> _Carry:
        targs0 = (args, t0, jnp.zeros_like(t0), jnp.zeros((m,), bool))
        s_end0 = s_end_of(t0, jnp.zeros_like(t0))
        tnext, controller_state0 = controller.init(
            term, zero, s_end0, x0, dt0, targs0, solver.func, error_order
        )
        # Step sizes carry no derivative: the flow's derivative does not depend on how it
        # was stepped, and the controller's choice depends on the state through an error
        # norm that is not differentiable where the error is zero (from x0 = 0 the step
        # size's tangent leaked into jacfwd of x'' = −x over 2π: [[−16, −3.2], [3.2, −16]]
        # instead of the identity). The end of the run (t1) and the event times keep theirs.
        h0 = jax.lax.stop_gradient(jnp.minimum(tnext, s_end0))
        solver_state0 = solver.init(term, zero, h0, x0, targs0)
        time_scale = jnp.maximum(jnp.abs(t0), 1e3 * jnp.abs(h0))
        time_scale = jnp.maximum(time_scale, jnp.where(jnp.isfinite(t1), jnp.abs(t1), 0.0))
        # At t0 there is no flight history to scale round-off by: use ‖x0‖∞ for every
        # coordinate, so that a start from a logged post-impact state (x1 = 2e-32 on a wall
        # at x1 = 0, moving in) counts as on the surface and does not re-trigger.
        x0_scale = jnp.full_like(x0, jnp.max(jnp.abs(x0)))
        restart0, stuck0, _ = contact_tests(t0, jnp.zeros_like(t0), x0, args, x0_scale)
        # A start at rest on a surface, pushed in: with zeno="stick", sliding from t0 (or
        # ZENO at t0 if on two surfaces). With "stop" the flight simply starts, into Φ < 0
        # (the paper's setting: Φ < 0 is not forbidden, only met from above).
        status0 = jnp.where(
            _starts_inside(t0, x0, args, x0_scale), int(Status.BAD_START), int(Status.SUCCESS)
        )
        zeno_time0 = nan
        stick0 = jnp.zeros((m,), bool)
        log = (
            jnp.full((max_impacts,), jnp.nan, dtype),
            jnp.full((max_impacts, n), jnp.nan, dtype),
            jnp.full((max_impacts, n), jnp.nan, dtype),
            jnp.full((max_impacts,), -1),
            jnp.full((max_impacts,), int(ImpactKind.NONE)),
        )
        num_impacts0 = jnp.array(0)
        if sticky:
            stuck_any = jnp.any(stuck0)
            starts = stuck_any & (jnp.sum(stuck0) == 1)
            stick0 = stuck0 & starts
            x_on = x0
            for i, piece in enumerate(pieces):
                x_on = jnp.where(stick0[i], project_onto_contact(piece, t0, x0, args), x_on)
            log = _write_log(log, 0, starts, t0, x0, x_on, jnp.argmax(stick0), int(ImpactKind.STICK))
            x0 = x_on
            num_impacts0 = starts.astype(num_impacts0.dtype)
            status0 = jnp.where(stuck_any & ~starts, int(Status.ZENO), status0)
            zeno_time0 = jnp.where(stuck_any, t0, zeno_time0)
        if ts is not None:
            save_xs0 = jnp.full((ts.shape[0], n), jnp.nan, dtype)
            save_index0 = jnp.array(0)
        else:
            save_xs0 = save_index0 = None
        finite0 = (
            jnp.all(jnp.isfinite(x0)) & _tree_all_finite(args) & jnp.isfinite(t0) & ~jnp.isnan(t1)
        )
        return _Carry(
            args=args, time_scale=time_scale, s=zero, t_hi=t0, t_lo=jnp.zeros_like(t0), y=x0,
            h=h0, solver_state=solver_state0, controller_state=controller_state0,
            # (sliding from t0 changes the field the solver's first stage was built with)
            made_jump=jnp.any(stick0), restart=restart0, flight_scale=jnp.abs(x0),
            landing=jnp.array(False), target=zero,
            pending=jnp.zeros(mask_shape, bool), touch=jnp.zeros(mask_shape, bool),
            boundary=jnp.zeros(mask_shape, bool), h_after=h0,
            num_impacts=num_impacts0,
            log_t=log[0], log_pre=log[1], log_post=log[2], log_surface=log[3], log_kind=log[4],
            stick=stick0, releasing=jnp.array(False),
            intervals=jnp.full((3,), jnp.nan, dtype), zeno_time=zeno_time0,
            num_steps=jnp.array(0), num_accepted=jnp.array(0),
            status=jnp.where(finite0, status0, int(Status.NONFINITE)),
            done=~finite0 | (status0 != int(Status.SUCCESS)), t_final=t0, x_final=x0,
            save_index=save_index0, save_xs=save_xs0,
        )

    # ---- saving at requested times (compiled only when asked) ----

    def save(c: _Carry, interp, sa, s_stop):
        if ts is None:
            return c.save_index, c.save_xs
        num = ts.shape[0]

        def local(j):
            return sigma * ((ts[jnp.minimum(j, num - 1)] - c.t_hi) - c.t_lo)

        if kinds.outer != "lax":
            # Reverse mode cannot transpose the data-dependent save loop below: evaluate
            # the interpolant at every requested time and keep those of this step (costs
            # len(saveat) evaluations per step, only with a reverse-capable adjoint).
            j = jnp.arange(num)
            s_j = local(j)
            mine = (j >= c.save_index) & (s_j <= s_stop)
            values = jax.vmap(lambda s_: interp.evaluate(jnp.clip(s_, sa, s_stop)))(s_j)
            save_xs = jnp.where(mine[:, None], values, c.save_xs)
            return c.save_index + jnp.sum(mine), save_xs

        def cond(carry):
            j, _ = carry
            return (j < num) & (local(j) <= s_stop)

        def body(carry):
            j, xs = carry
            s_j = jnp.clip(local(j), sa, s_stop)
            return j + 1, xs.at[j].set(interp.evaluate(s_j))

        return lax.while_loop(cond, body, (c.save_index, c.save_xs))

    # ---- step-size control at equilibria ----

    def equilibrium_probe(sa, sb, y0, y1, y_error, targs):
        """The error estimate of a step that did not move the state: that of a perturbation.

        At an equilibrium (x0 = 0 for x'' = −x) every stage is zero, the error estimate is
        exactly zero and the controller grows the step tenfold per step, to steps far
        longer than the flow's time scale. The state is still exact there, but its
        derivatives are not: jacfwd of x'' = −x from 0 over 2π gave [[−16, −3.2],
        [3.2, −16]] instead of the identity. On such steps the controller is given the
        error of the same step from a state perturbed by atol/rtol: relative to atol, that
        is the perturbation's relative error over rtol, so nearby trajectories (and the
        Jacobian) are kept to the relative tolerance. (A direct evaluation, not a jvp:
        it works whatever loop kind the Runge–Kutta stages use.)
        """
        if not has_error:
            return y_error
        still = jnp.all(y_error == 0) & jnp.all(y1 == y0)

        def probe():
            u = jnp.full_like(y0, tol_a / tol_r / jnp.sqrt(n))

            def error_of(y):
                state = solver.init(term, sa, sb, y, targs)
                return error_or_zero(solver.step(term, sa, sb, y, targs, state, True)[1], y)

            nearby_error = error_of(jax.lax.stop_gradient(y0) + u)
            return jnp.where(still, jax.lax.stop_gradient(jnp.abs(nearby_error)), y_error)

        return lax.cond(eqxi.unvmap_any(still), probe, lambda: y_error)

    # ---- one iteration: one solver step ----

    def body(c_in: _Carry) -> _Carry:
        # A lane out of steps is frozen like a finished one (see `cond`), but keeps
        # done = False so that it reports MAX_STEPS.
        out_of_steps = ~c_in.done & (c_in.num_steps >= max_steps)
        c = eqx.tree_at(lambda z: z.done, c_in, c_in.done | out_of_steps)
        args_ = c.args
        targs = (args_, c.t_hi, c.t_lo, c.stick)
        s_end = s_end_of(c.t_hi, c.t_lo)
        sa = c.s
        sb = jnp.where(c.landing, c.target, jnp.minimum(sa + c.h, s_end))
        y1, y_error, dense_info, solver_state1, _ = solver.step(
            term, sa, sb, c.y, targs, c.solver_state, c.made_jump
        )
        # A NaN error estimate must reject the step, not poison the controller (diffrax #143).
        y_error = error_or_zero(y_error, y1)
        y_error = jnp.where(jnp.isnan(y_error), jnp.inf, y_error)
        y_error = equilibrium_probe(sa, sb, c.y, y1, y_error, targs)
        keep, _, tnext, _, controller_state1, _ = controller.adapt_step_size(
            sa, sb, c.y, y1, targs, y_error, error_order, c.controller_state
        )
        finite1 = jnp.all(jnp.isfinite(y1))
        keep = keep & finite1
        h_next = jax.lax.stop_gradient(tnext - jnp.where(keep, sb, sa))
        interp = solver.interpolation_cls(t0=sa, t1=sb, **dense_info)
        num_steps = c.num_steps + 1

        # ---------- detection on a normally accepted step ----------
        detecting = keep & ~c.landing & ~c.done

        def y_of(s):
            return interp.evaluate(s)

        ends = []
        for i, piece in enumerate(pieces):
            row = []
            for sign in piece.signs:
                g = gap_along(piece, sign, y_of, c.t_hi, c.t_lo, args_)
                g_a = sign * piece.gap(abs_time(sa, c.t_hi, c.t_lo), c.y, args_)
                g_b = sign * piece.gap(abs_time(sb, c.t_hi, c.t_lo), y1, args_)
                row.append((g, step_ends(g, sa, sb, c.restart[i], g_a, g_b)))
            ends.append(row)
        candidate = jnp.array(False)
        for i, row in enumerate(ends):
            for _, e in row:
                crossing, dip = is_candidate(e)
                # A sliding state is on its surface: no contact with it is searched for.
                candidate = candidate | ((crossing | dip) & ~c.stick[i])
        candidate = detecting & candidate

        def search():
            found = jnp.zeros(mask_shape, bool)
            times = jnp.full(mask_shape, jnp.inf, dtype)
            touch = jnp.zeros(mask_shape, bool)
            boundary = jnp.zeros(mask_shape, bool)
            for i, piece in enumerate(pieces):
                for k, (g, e) in enumerate(ends[i]):
                    x_scale = jnp.maximum(c.flight_scale, jnp.abs(y1))
                    # Round-off of a step also grows with its length: add h·max|ġ| (a
                    # long step of an exactly integrated flow carries ~100s of ulps).
                    e = ends[i][k][1]
                    step_term = FLOOR_ULPS * eps * (sb - sa) * jnp.maximum(
                        jnp.abs(e.slope_start), jnp.abs(e.slope_end)
                    )
                    floor = piece.floor(abs_time(sb, c.t_hi, c.t_lo), y1, args_, x_scale)
                    floor = floor + jax.lax.stop_gradient(step_term)
                    contact = locate(g, sa, sb, e, c.restart[i], floor)
                    t_abs = abs_time(contact.time, c.t_hi, c.t_lo)
                    inside, on_boundary = piece.inside(t_abs, y_of(contact.time), args_, state_tol)
                    ok = contact.found & inside
                    found = found.at[i, k].set(ok)
                    times = times.at[i, k].set(jnp.where(ok, contact.time, jnp.inf))
                    touch = touch.at[i, k].set(contact.touch)
                    boundary = boundary.at[i, k].set(on_boundary)
            return found, times, touch, boundary

        def no_search():
            return (
                jnp.zeros(mask_shape, bool), jnp.full(mask_shape, jnp.inf, dtype),
                jnp.zeros(mask_shape, bool), jnp.zeros(mask_shape, bool),
            )

        if m > 0:
            found, times, touch, boundary = lax.cond(
                eqxi.unvmap_any(candidate), search, no_search
            )
        else:
            found, times, touch, boundary = no_search()
        found = found & candidate & ~c.stick[:, None]
        times = jnp.where(found, times, jnp.inf)
        event = jnp.any(found)
        # (A scene without surfaces is a plain ODE solve: no contact, ever.)
        first = jax.lax.stop_gradient(jnp.min(times)) if m > 0 else jnp.array(jnp.inf, dtype)
        releasing = jnp.array(False)
        if sticky:
            # Release: the free flow's Φ̈ on the sliding surface reaches 0 from below.
            def pull(s_, y_):
                return sliding_pull(c.stick, s_, y_, c.t_hi, c.t_lo, args_)

            pull_a, pull_b = pull(sa, c.y), pull(sb, y1)
            release = detecting & jnp.any(c.stick) & (pull_b >= 0)

            def locate_release():
                # bracketed_root wants f(lo) > 0 >= f(hi): search the sign change of −Φ̈;
                # `hi` is the first point at or past it, so the state leaves pulled away.
                lo = jnp.where(release & (pull_a < 0), sa, sb)
                _, hi = bracketed_root(
                    lambda s_: -pull(s_, y_of(s_)), lo, sb, -pull_a, -pull_b
                )
                return hi

            t_release = lax.cond(
                eqxi.unvmap_any(release), locate_release, lambda: sb
            )
            t_release = jax.lax.stop_gradient(jnp.where(release, t_release, jnp.inf))
            releasing = release & (t_release <= first)
            first = jnp.minimum(first, t_release)
            event = event | release
        simultaneous = 1e3 * eps * (jnp.abs(first) + (sb - sa))
        pending = found & (times <= first + simultaneous) & ~releasing

        # ---------- the landing step: apply the impact(s) ----------
        # The branch returns only small values: the log and save buffers are written below,
        # outside the cond, one row at a time (threading them through the cond made every
        # iteration copy them: cost grew with max_impacts and len(saveat)).
        def land():
            return _land(c, y1, sa, sb, interp)

        def no_land():
            slots = sum(len(p.signs) for p in pieces) + int(sticky)
            rows = (
                jnp.zeros((slots,), bool), jnp.zeros((slots, n), dtype), jnp.zeros((slots, n), dtype),
                jnp.zeros((slots,), jnp.asarray(0).dtype), jnp.zeros((slots,), jnp.asarray(0).dtype),
            )
            return _without_buffers(c), rows, jnp.zeros((), dtype), jnp.array(-jnp.inf, dtype)

        if m > 0:
            landed_small, rows, t_event, s_save = lax.cond(
                eqxi.unvmap_any(c.landing & ~c.done), land, no_land
            )
        else:
            landed_small, rows, t_event, s_save = no_land()
        log = (c.log_t, c.log_pre, c.log_post, c.log_surface, c.log_kind)
        count = jnp.array(0)
        for slot in range(rows[0].shape[0]):
            apply, pre, post, surface, kind = (r[slot] for r in rows)
            row = jnp.minimum(c.num_impacts + count, max_impacts - 1)
            log = _write_log(log, row, apply, t_event, pre, post, surface, kind)
            count = count + apply
        landed = eqx.tree_at(
            lambda z: (z.log_t, z.log_pre, z.log_post, z.log_surface, z.log_kind),
            _with_buffers(landed_small, c),
            log,
        )

        # ---------- assemble the next carry ----------
        accept_free = detecting & ~event  # accepted, no contact: move on
        go_land = detecting & event  # contact located: retake the step up to it
        reject = ~keep & ~c.landing & ~c.done

        save_index, save_xs = c.save_index, c.save_xs
        if ts is not None:
            # One save pass for the step just taken, in the flight's clock before any jump:
            # up to sb on a free step, up to the event on a landing, nothing otherwise.
            s_stop = jnp.where(accept_free, sb, jnp.where(c.landing & ~c.done, s_save, -jnp.inf))
            save_index, save_xs = save(c, interp, sa, s_stop)

        reached_end = accept_free & (sb >= s_end - h_min_at(abs_time(sb, c.t_hi, c.t_lo), c.time_scale))
        underflow = reject & (h_next < h_min_at(abs_time(sa, c.t_hi, c.t_lo), c.time_scale))
        fail_status = jnp.where(finite1, int(Status.STEP_SIZE_UNDERFLOW), int(Status.NONFINITE))

        def pick(a_free, a_land, a_goland, a_other):
            return jnp.where(
                accept_free, a_free, jnp.where(c.landing, a_land, jnp.where(go_land, a_goland, a_other))
            )

        new = _Carry(
            args=c.args, time_scale=c.time_scale,
            s=pick(sb, landed.s, sa, sa),
            t_hi=jnp.where(c.landing, landed.t_hi, c.t_hi),
            t_lo=jnp.where(c.landing, landed.t_lo, c.t_lo),
            y=pick(y1, landed.y, c.y, c.y),
            h=jax.lax.stop_gradient(pick(h_next, landed.h, c.h, h_next)),
            solver_state=jax.tree.map(
                lambda a, b: jnp.where(accept_free | c.landing, a, b), solver_state1, c.solver_state
            ),
            controller_state=jax.tree.map(
                lambda a, b: jnp.where(c.landing, b, a), controller_state1, c.controller_state
            ),
            made_jump=pick(False, landed.made_jump, c.made_jump, c.made_jump),
            restart=jnp.where(accept_free, False, jnp.where(c.landing, landed.restart, c.restart)),
            flight_scale=jnp.where(
                accept_free, jnp.maximum(c.flight_scale, jnp.abs(y1)), landed.flight_scale
            ),
            landing=go_land,
            stick=landed.stick,
            releasing=jnp.where(go_land, releasing, landed.releasing),
            target=jnp.where(go_land, first, c.target),
            pending=jnp.where(go_land, pending, c.pending),
            touch=jnp.where(go_land, touch & pending, c.touch),
            boundary=jnp.where(go_land, boundary & pending, c.boundary),
            # After the impact, restart no larger than twice the flight just ended: the
            # dynamics changed, and an exactly integrated flow would otherwise grow the
            # step 10x per flight (to 1e9 with t1 = inf) until the event search loses
            # its precision.
            h_after=jnp.where(
                go_land, jnp.minimum(jnp.maximum(sb - sa, h_next), 2 * first + h_min_at(first, c.time_scale)), c.h_after
            ),
            num_impacts=landed.num_impacts,
            log_t=landed.log_t, log_pre=landed.log_pre, log_post=landed.log_post,
            log_surface=landed.log_surface, log_kind=landed.log_kind,
            intervals=landed.intervals, zeno_time=landed.zeno_time,
            num_steps=jnp.where(c.done, c.num_steps, num_steps),
            num_accepted=c.num_accepted + (accept_free | (c.landing & ~c.done)),
            status=jnp.where(
                reached_end | c.done | c.landing, landed.status,
                jnp.where(underflow, fail_status, c.status),
            ),
            done=c.done | reached_end | landed.done | underflow,
            t_final=jnp.where(
                reached_end, t1, jnp.where(underflow, abs_time(sa, c.t_hi, c.t_lo), landed.t_final)
            ),
            x_final=jnp.where(reached_end, y1, jnp.where(underflow, c.y, landed.x_final)),
            save_index=save_index, save_xs=save_xs,
        )
        return eqx.tree_at(lambda z: z.done, new, new.done & ~out_of_steps)

    # ---- landing: the step [sa, target] has just been taken exactly ----

    def _land(c: _Carry, y_star, sa, s_star, interp) -> _Carry:
        args_ = c.args
        t_hi, t_lo = c.t_hi, c.t_lo
        lands = c.landing & ~c.done
        # Round-off in the event state is relative to the magnitudes met in this flight, not
        # to the (possibly tiny) state at the contact: a touch at x ≈ 0, v ≈ 0 still carries
        # the absolute error of the flight that led there.
        flight_scale = jnp.maximum(c.flight_scale, jnp.abs(y_star))
        # ... and to the length of the landing step, as in the detection floor.
        step_ulps = FLOOR_ULPS * eps * jax.lax.stop_gradient(s_star - sa)
        # One Newton step on the time, with the true vector field: corrects the
        # interpolant's root to the method's accuracy and carries d(time)/d(params) by
        # the implicit function theorem. Driven by the first pending surface.
        f_star = local_field(s_star, y_star, (args_, t_hi, t_lo, c.stick))
        # Accept corrections up to 1% of the landing step, but never less than ~1e-6 of the
        # flight: a step can end ulps before the contact, and the next one then lands after
        # a few ulps of width.
        width = jax.lax.stop_gradient(jnp.maximum(s_star - sa, 1e-6 * s_star))

        def newton(use, value, slope, delta):
            small = jnp.abs(jax.lax.stop_gradient(value)) <= 1e-2 * jnp.abs(jax.lax.stop_gradient(slope)) * width
            ok = use & small & (slope != 0)
            return jnp.where(ok, -safe_divide(value, slope, ok), delta)

        delta = jnp.zeros_like(s_star)
        chosen = jnp.array(False)
        for i, piece in enumerate(pieces):
            for k, sign in enumerate(piece.signs):
                g, gd, _ = slopes_at(piece, sign, s_star, y_star, t_hi, t_lo, args_)
                use = c.pending[i, k] & ~c.touch[i, k] & ~chosen
                delta = newton(use, g, gd, delta)
                chosen = chosen | use
        if sticky:
            # A release: the same Newton step on the free Φ̈ of the sliding surface, along
            # the sliding flow, so that jacfwd gets the release time's tangent.
            r, r_dot = jax.jvp(
                lambda s_, y_: sliding_pull(c.stick, s_, y_, t_hi, t_lo, args_),
                (s_star, y_star), (jnp.ones_like(s_star), f_star),
            )
            delta = newton(c.releasing, r, r_dot, delta)
        s_event = s_star + delta
        y_event = y_star + f_star * delta
        t_event_hi, t_event_lo = _dd_add(t_hi, t_lo, sigma * s_event)
        t_event = t_event_hi + t_event_lo

        # Pieces met together within round-off: a piece the in-step search did not report
        # (its own crossing lies within the contact floor of this event, e.g. surfaces a
        # few ulps apart) is hit now too if the state is on it and approaching it. Without
        # this, the flight after the jump would start "on" it, moving in, and never impact.
        near = []
        for i, piece in enumerate(pieces):
            on, _ = on_surface(piece, t_event, y_event, args_, flight_scale, step_ulps)
            in_piece, on_boundary = piece.inside(t_event, y_event, args_, state_tol)
            near.append((on & in_piece & ~c.stick[i], on_boundary))

        # Apply the jumps in surface order.
        x = y_event
        count = jnp.array(0)
        applied_any = jnp.array(False)
        bad_side = jnp.array(False)
        rows = []  # one per (surface, side): (apply, pre, post, surface, kind)
        applied = []  # per surface
        for i, piece in enumerate(pieces):
            applied.append(jnp.array(False))
            for k, sign in enumerate(piece.signs):
                _, gd, _ = slopes_at(piece, sign, s_event, x, t_hi, t_lo, args_)
                approaching = (gd < 0) | c.touch[i, k]
                # `lands` folded in here so that the log is written row-wise only: a
                # whole-array select of the log every iteration dominated batched runs.
                # (a piece already pending on one side is not hit again on its other side)
                hit = c.pending[i, k] | (near[i][0] & (gd < 0) & ~jnp.any(c.pending[i]))
                apply = lands & hit & (~applied_any | approaching)
                x_new = piece.jump(t_event, x, args_)
                on_boundary = jnp.where(c.pending[i, k], c.boundary[i, k], near[i][1])
                kind = jnp.where(
                    c.touch[i, k], int(impact_kinds[2]), jnp.where(on_boundary, int(impact_kinds[1]), int(impact_kinds[0]))
                )
                rows.append((apply, x, x_new, jnp.asarray(i), kind))
                x_scale = jnp.maximum(flight_scale, jnp.abs(x_new))
                if piece.check_jump_side:
                    g_new, gd_new, gdd_new = slopes_at(piece, sign, s_event, x_new, t_hi, t_lo, args_)
                    floor = piece.floor(t_event, x_new, args_, x_scale) + step_ulps * jnp.abs(
                        jax.lax.stop_gradient(gd)
                    )
                    moving_in = (gd_new < 0) & ~is_tangential(gd_new, gdd_new, floor)
                    bad_side = bad_side | (apply & ((g_new < -floor) | ((g_new <= floor) & moving_in)))
                x = jnp.where(apply, x_new, x)
                count = count + apply
                applied_any = applied_any | apply
                applied[i] = applied[i] | apply
        x_post = x
        num_impacts = c.num_impacts + count

        # Restart guard and sticking test at the post-impact state.
        x_scale = jnp.maximum(flight_scale, jnp.abs(x_post))
        restart, stuck_each, pushed_in = contact_tests(t_event_hi, t_event_lo, x_post, args_, x_scale, step_ulps)
        released = jnp.zeros((m,), bool)
        if sticky:
            # A release lands on a tangential state with Φ̈ ≈ 0: not a new sticking.
            released = c.stick & c.releasing & lands
            stuck_each = stuck_each & ~released
            restart = restart | released
            # An impact on another surface while sliding: the state is still on the surface
            # it slid on, up to the sliding flow's drift (solver tolerance, not round-off,
            # so the on-surface floor cannot tell); it keeps sliding if not thrown off it.
            was_on = c.stick & lands & ~c.releasing
            for i, piece in enumerate(pieces):
                _, gd, gdd, _, grad_gd, _ = contact_geometry(piece, t_event, x_post, args_)
                drift = jnp.sum(jnp.abs(grad_gd) * state_tol(x_post))
                stays = was_on[i] & (gd <= drift) & (gdd < 0)
                stuck_each = stuck_each.at[i].set(stuck_each[i] | stays)
            restart = restart | was_on
        stuck = jnp.any(stuck_each)

        # Zeno: geometric shrinking of the inter-impact times.
        interval = jax.lax.stop_gradient(s_event)
        intervals = jnp.concatenate([c.intervals[1:], interval[None]])
        d0, d1, d2 = intervals[0], intervals[1], intervals[2]
        r_prev = safe_divide(d1, d0, d0 > 0)
        r_last = safe_divide(d2, d1, d1 > 0)
        geometric = (r_last > 0) & (r_last < 1) & (jnp.abs(r_last - r_prev) <= 0.05 * r_last)
        remaining = safe_divide(d2 * r_last, 1 - r_last, r_last < 1)
        elapsed = jnp.abs(t_event - t0)
        zeno = geometric & (remaining <= zeno_rtol * elapsed)
        t_resolution = h_min_at(t_event, c.time_scale)
        zeno = zeno | (interval <= t_resolution) & (c.num_impacts > 0)
        zeno = zeno & applied_any  # (a release is not an impact)
        zeno_time = jnp.where(zeno, t_event + sigma * remaining, jnp.where(stuck, t_event, c.zeno_time))
        if sticky:
            # Slide on the surface just hit (or found stuck) if the free flow pushes into
            # it; on two surfaces at once there is no sliding rule: stop (ZENO).
            want = stuck_each | (zeno & jnp.array(applied) & pushed_in)
            starts = lands & applied_any & (jnp.sum(want) == 1)
            zeno = (zeno | stuck) & ~starts
            stick = jnp.where(starts, want, jnp.where(lands & (c.releasing | applied_any), False, c.stick))
            x_moved = x_post
            for i, piece in enumerate(pieces):
                on_m = project_onto_contact(piece, t_event, x_post, args_)
                x_moved = jnp.where((starts & want[i]) | released[i], on_m, x_moved)
            event_row = (
                starts | jnp.any(released), x_post, x_moved,
                jnp.argmax(want | released), jnp.where(starts, int(ImpactKind.STICK), int(ImpactKind.RELEASE)),
            )
            rows.append(event_row)
            num_impacts = num_impacts + event_row[0]
            x_post = x_moved
            # A new sequence of impacts after sliding: forget the old intervals.
            intervals = jnp.where(starts | c.releasing, jnp.nan, intervals)
        else:
            zeno = zeno | stuck
            stick = c.stick

        finite = jnp.all(jnp.isfinite(x_post))
        status = jnp.where(
            ~finite, int(Status.NONFINITE),
            jnp.where(bad_side, int(Status.BAD_JUMP),
            jnp.where(zeno, int(Status.ZENO),
            jnp.where(num_impacts >= max_impacts, int(Status.MAX_IMPACTS), int(Status.SUCCESS)))),
        )
        stop = status != int(Status.SUCCESS)
        # Left-continuity with respect to the *logged* impact time: save up to s_event plus
        # the rounding of t_event, so `saveat=[t_impact]` returns the pre-impact state.
        s_save = jnp.where(lands, s_event + 4 * eps * jnp.abs(t_event), -jnp.inf)
        keep_old = lambda new, old: jnp.where(lands, new, old)  # noqa: E731
        small = eqx.tree_at(
            lambda z: (
                z.s, z.t_hi, z.t_lo, z.y, z.h, z.made_jump, z.restart, z.flight_scale, z.num_impacts,
                z.intervals, z.zeno_time, z.status, z.done, z.t_final, z.x_final, z.stick,
                z.releasing,
            ),
            c,
            (
                keep_old(jnp.zeros_like(s_event), c.s),
                keep_old(t_event_hi, c.t_hi),
                keep_old(t_event_lo, c.t_lo),
                keep_old(jnp.where(finite, x_post, y_event), c.y),
                keep_old(c.h_after, c.h),
                keep_old(True, c.made_jump),
                keep_old(restart, c.restart),
                keep_old(jnp.abs(jnp.where(finite, x_post, y_event)), c.flight_scale),
                keep_old(num_impacts, c.num_impacts),
                keep_old(intervals, c.intervals),
                keep_old(zeno_time, c.zeno_time),
                keep_old(status, c.status),
                keep_old(stop, c.done),
                keep_old(t_event, c.t_final),
                keep_old(jnp.where(finite, x_post, y_event), c.x_final),
                keep_old(stick, c.stick),
                keep_old(False, c.releasing),
            ),
        )
        rows = jax.tree.map(lambda *r: jnp.stack(r), *rows)
        return _without_buffers(small), rows, t_event, s_save

    def running(c: _Carry):
        return ~c.done & (c.num_steps < max_steps)

    def finish(final: _Carry) -> Solution:
        out_of_steps = ~final.done
        t_now = abs_time(final.s, final.t_hi, final.t_lo)
        return Solution(
            t_final=jnp.where(out_of_steps, t_now, final.t_final),
            x_final=jnp.where(out_of_steps, final.y, final.x_final),
            num_impacts=final.num_impacts,
            impact_times=final.log_t,
            impact_pre=final.log_pre,
            impact_post=final.log_post,
            impact_surface=final.log_surface,
            impact_kind=final.log_kind,
            status=jnp.where(out_of_steps, int(Status.MAX_STEPS), final.status),
            zeno_time=final.zeno_time,
            num_steps=final.num_steps,
            num_accepted_steps=final.num_accepted,
            ts=ts,
            xs=final.save_xs,
        )

    return Program(init=init, step=body, running=running, finish=finish)


_BUFFERS = ("log_t", "log_pre", "log_post", "log_surface", "log_kind", "save_index", "save_xs")


def _without_buffers(c: _Carry) -> _Carry:
    return eqx.tree_at(
        lambda z: tuple(getattr(z, k) for k in _BUFFERS), c, (None,) * len(_BUFFERS),
        is_leaf=lambda z: z is None,
    )


def _with_buffers(small: _Carry, full: _Carry) -> _Carry:
    return eqx.tree_at(
        lambda z: tuple(getattr(z, k) for k in _BUFFERS), small,
        tuple(getattr(full, k) for k in _BUFFERS), is_leaf=lambda z: z is None,
    )


def _write_log(log, row, apply, t, pre, post, surface, kind):
    # A row that is not applied is written out of bounds and dropped: the buffers are only
    # written, never read, in the loop, so XLA updates them in place (a read-modify-write
    # `where(apply, new, log[row])` made it copy every buffer at every iteration under vmap:
    # per-lane cost grew with max_impacts).
    log_t, log_pre, log_post, log_surface, log_kind = log
    row = jnp.where(apply, row, log_t.shape[0])
    return (
        log_t.at[row].set(t, mode="drop"),
        log_pre.at[row].set(pre, mode="drop"),
        log_post.at[row].set(post, mode="drop"),
        log_surface.at[row].set(surface, mode="drop"),
        log_kind.at[row].set(kind, mode="drop"),
    )


def _tree_all_finite(tree):
    leaves = [
        jnp.all(jnp.isfinite(leaf))
        for leaf in jax.tree.leaves(tree)
        if eqx.is_array_like(leaf) and jnp.issubdtype(jnp.result_type(leaf), jnp.inexact)
    ]
    return jnp.all(jnp.array(leaves)) if leaves else jnp.array(True)


def _raise_if_bad_start(sol: Solution):
    """Outside jit and vmap a start inside an impenetrable surface is an input error."""
    status = sol.status
    if isinstance(status, jax.core.Tracer) or jnp.ndim(status) != 0:
        return
    if int(status) == Status.BAD_START:
        raise ValueError(
            f"x0 = {sol.x_final} lies inside an impenetrable surface (Φ < 0 beyond round-off, "
            "inside its `where`): start on the free side Φ >= 0, or mark the surface "
            "impenetrable=False if trajectories may live in Φ < 0"
        )


def _with_implicit_tolerances(solver, controller):
    """Give an implicit solver's root finder the controller's tolerances, as diffeqsolve does."""
    if not isinstance(solver, diffrax.AbstractImplicitSolver):
        return solver
    from diffrax._root_finder import use_stepsize_tol

    attrs = [
        a for a in ("rtol", "atol", "norm") if getattr(solver.root_finder, a) is use_stepsize_tol
    ]
    if not attrs:
        return solver
    return eqx.tree_at(
        lambda s: tuple(getattr(s.root_finder, a) for a in attrs),
        solver,
        tuple(getattr(controller, a) for a in attrs),
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
