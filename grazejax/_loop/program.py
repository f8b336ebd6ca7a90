"""The loop of one configuration as four functions of one lane's state: `Program`."""

import functools
from collections.abc import Callable

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.lax as lax
import jax.numpy as jnp

from .._adjoint import loop_kinds
from .._geometry import backward_piece, forward_piece
from .._roots import AbstractBracketedRootFinder, Chandrupatla
from .._scene import Scene
from .._solution import Solution
from .._status import ImpactKind, Status
from .compact import under_vmap
from .context import LoopContext, loop_field
from .detect import Detection, detect, nothing_detected
from .field import continuous_in_state, field_jumps
from .land import land_if_due
from .policies import ZenoStop, as_zeno_policy
from .state import LoopState, seed_fixed_point
from .step import Step, take_step
from .stepping import loop_controller
from .unrolled import UnrolledERK, unrollable


class Program(eqx.Module):
    """The impact loop of one configuration, as functions of one lane's loop state.

    `simulate` is `finish(while_loop(any running, step, init(x0, args)))`. `sweep` runs the
    same functions on a pool of lanes that it refills as lanes finish, so every lane
    computes exactly what `simulate` computes for it alone.
    """

    init: Callable = eqx.field(static=True)  # (x0, args) -> state
    step: Callable = eqx.field(static=True)  # state -> state: one solver step (frozen when done)
    # (state, forced decisions) -> (state, decisions): `step`, replaying recorded decisions
    # where reverse mode recomputes steps (`replay.py`).
    deciding_step: Callable = eqx.field(static=True)
    # `step` for a state where no lane slides: no sliding field, no search for the end of
    # sliding (`step` itself without `ZenoStick`). A landing may still start sliding.
    free_step: Callable = eqx.field(static=True)
    # state -> bool: the next step lands (for some lane: unbatched); `step` and
    # `deciding_step` take `landing=True` / `False` for a step known to land or not (its
    # linearisation then holds only that branch's residuals: `reverse.py`).
    lands: Callable = eqx.field(static=True)
    running: Callable = eqx.field(static=True)  # state -> bool: not finished, not out of steps
    finish: Callable = eqx.field(static=True)  # state -> Solution
    log_rows_per_landing: int = eqx.field(static=True)  # impact-log rows one landing writes


def build_program(
    scene: Scene, checked, *, solver, rtol, atol, stepsize_controller, dt0, max_impacts,
    max_steps, zeno_rtol, zeno="stop", adjoint=None, check_field_jumps=True, args=None,
    batched=False, event_root_finder=None,
) -> Program:
    """The loop functions for `scene`, with inputs checked by `validate_inputs`.

    `checked.x0` and `args` are only templates (shapes, dtypes, structure); t0, t1 and
    saveat are shared by every lane that runs the program.
    """
    ctx = build_context(
        scene, checked, solver=solver, rtol=rtol, atol=atol,
        stepsize_controller=stepsize_controller, dt0=dt0, max_impacts=max_impacts,
        max_steps=max_steps, zeno_rtol=zeno_rtol, zeno=zeno, adjoint=adjoint,
        check_field_jumps=check_field_jumps, args=args, batched=batched,
        event_root_finder=event_root_finder,
    )
    # (functools.partial, not bound methods: `Program`'s static fields hash by identity.)
    step_ = functools.partial(step, ctx)
    return Program(
        init=functools.partial(init, ctx), step=step_,
        deciding_step=functools.partial(deciding_step, ctx),
        free_step=functools.partial(step, ctx, slides=False) if ctx.sticky else step_,
        lands=functools.partial(lands, ctx),
        running=functools.partial(running, ctx), finish=functools.partial(finish, ctx),
        log_rows_per_landing=ctx.log_rows_per_landing,
    )


def build_context(
    scene: Scene, checked, *, solver, rtol, atol, stepsize_controller, dt0, max_impacts,
    max_steps, zeno_rtol, zeno, adjoint, check_field_jumps=True, args=None, batched=False,
    event_root_finder=None,
) -> LoopContext:
    policy = as_zeno_policy(zeno)
    if event_root_finder is not None and not isinstance(
        event_root_finder, AbstractBracketedRootFinder
    ):
        raise TypeError(
            "event_root_finder must be a grazejax bracketed root finder (grazejax.Chandrupatla(), "
            f"grazejax.ITP() or grazejax.BracketedNewton()), got {type(event_root_finder).__name__}: "
            "every root the loop looks for is bracketed inside one step, and the search must "
            "not leave it"
        )
    if policy.slides and checked.sigma < 0:
        raise ValueError(
            "zeno='stick' is forward time only: a backward run cannot tell where a sliding "
            "phase began (the release map is not invertible)"
        )
    sigma = checked.sigma
    dtype = checked.x0.dtype

    if solver is None:
        solver = diffrax.Tsit5()
    # Diffrax's solvers with an embedded error estimate are its adaptive solvers (Euler and
    # the stochastic ones are not).
    has_error = isinstance(solver, diffrax.AbstractAdaptiveSolver)
    controller = loop_controller(
        stepsize_controller, solver, rtol=rtol, atol=atol, dt0=dt0, has_error_estimate=has_error
    )
    solver = _with_implicit_tolerances(solver, controller)
    # Diffrax's explicit tableaus run as straight-line stages: no inner loop, and both
    # autodiff modes (see `unrolled`). Other Runge-Kutta stages default to a checkpointed
    # loop (custom_vjp), which forward-mode autodiff cannot enter; a plain lax loop supports
    # jvp, jacfwd and vmap. The adjoint decides (see `_adjoint`); a kind the user set on
    # the solver is kept.
    kinds = loop_kinds(adjoint)
    if unrollable(solver):
        solver = UnrolledERK(solver)
    elif getattr(solver, "scan_kind", "lax") is None and kinds.stages is not None:
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
    if m == 0:  # (nothing to slide on: the sliding phase is not compiled)
        policy = ZenoStop()
    term = diffrax.ODETerm(loop_field(f, pieces, sigma, policy.slides))
    return LoopContext(
        vector_field=f, project=scene.project, pieces=pieces, impact_kinds=impact_kinds, sigma=sigma,
        t0=checked.t0, t1=checked.t1, ts=checked.ts, dtype=dtype, n=checked.x0.shape[0],
        m=m, max_signs=max((len(p.signs) for p in pieces), default=1),
        eps=jnp.finfo(dtype).eps,
        tol_r=getattr(controller, "rtol", rtol), tol_a=getattr(controller, "atol", atol),
        solver=solver, controller=controller, has_error=has_error, term=term,
        error_order=solver.error_order(term), kinds=kinds, policy=policy,
        event_root_finder=Chandrupatla() if event_root_finder is None else event_root_finder,
        batched=bool(batched),
        # A field that cannot jump needs no probe (neither compiled nor run): 8% of an
        # ex1dof run's compile time and 20 of its 212 fusions.
        check_field_jumps=bool(check_field_jumps) and m > 0
        and not continuous_in_state(f, checked.t0, checked.x0, args),
        dt0=dt0, max_impacts=max_impacts, max_steps=max_steps, zeno_rtol=zeno_rtol,
        zero=jnp.zeros((), dtype), nan=jnp.array(jnp.nan, dtype),
    )


# --------------------------------------------------------------------------------------
# init
# --------------------------------------------------------------------------------------


def init(ctx: LoopContext, x0, args) -> LoopState:
    t0, t1, m, n, dtype, zero = ctx.t0, ctx.t1, ctx.m, ctx.n, ctx.dtype, ctx.zero
    solver, controller, term = ctx.solver, ctx.controller, ctx.term
    targs0 = (args, t0, jnp.zeros_like(t0), jnp.zeros((m,), bool))
    s_end0 = ctx.s_end_of(t0, jnp.zeros_like(t0))
    tnext, controller_state0 = controller.init(
        term, zero, s_end0, x0, ctx.dt0, targs0, solver.func, ctx.error_order
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
    restart0, stuck0, _ = ctx.contact_tests(t0, jnp.zeros_like(t0), x0, args, x0_scale)
    # A start at rest on a surface, pushed in: with ZenoStick, sliding from t0 (or
    # ZENO at t0 if on two surfaces). With ZenoStop: ZENO at t0 on an impenetrable surface
    # (as after a tangential restart); on another the flight simply starts, into Φ < 0
    # (the paper's setting: Φ < 0 is not forbidden, only met from above).
    inside0, resting0 = ctx.impenetrable_contact(t0, jnp.zeros_like(t0), t0, jnp.zeros_like(t0),
                                                 x0, args, x0_scale)
    status0 = jnp.where(inside0, int(Status.BAD_START), int(Status.SUCCESS))
    if ctx.check_field_jumps:
        # A start on a surface is a restart like any other: the first flight's first stage
        # must not depend on which side of a jump of f round-off put x0 (`field.py`).
        jumps0 = jnp.any(restart0) & field_jumps(ctx.vector_field, t0, x0, args, x0_scale)
        status0 = jnp.where(
            (status0 == int(Status.SUCCESS)) & jumps0, int(Status.FIELD_DISCONTINUITY), status0
        )
    log = (
        jnp.full((ctx.max_impacts,), jnp.nan, dtype),
        jnp.full((ctx.max_impacts, n), jnp.nan, dtype),
        jnp.full((ctx.max_impacts, n), jnp.nan, dtype),
        jnp.full((ctx.max_impacts,), -1),
        jnp.full((ctx.max_impacts,), int(ImpactKind.NONE)),
    )
    # Traced times are not checked before the run (`validate_inputs` needs values): a t1
    # behind t0 in the compiled direction would run the other way, with the other
    # direction's surfaces. Such a run does not start.
    wrong_way = ctx.sigma * (t1 - t0) < 0
    x0, stick0, log, num_impacts0, status0, zeno_time0 = ctx.policy.start(
        ctx, x0, args, stuck0 & ~wrong_way, resting0, status0, log
    )
    status0 = jnp.where(wrong_way, int(Status.BAD_TIMES), status0)
    if ctx.ts is not None:
        save_xs0 = jnp.full((ctx.ts.shape[0], n), jnp.nan, dtype)
        save_index0 = jnp.array(0)
    else:
        save_xs0 = save_index0 = None
    finite0 = (
        jnp.all(jnp.isfinite(x0)) & _tree_all_finite(args) & jnp.isfinite(t0) & ~jnp.isnan(t1)
    )
    mask_shape = ctx.mask_shape
    state = LoopState(
        args=args, time_scale=time_scale, s=zero, t_hi=t0, t_lo=jnp.zeros_like(t0), y=x0,
        h=h0, solver_state=solver_state0, controller_state=controller_state0,
        # (sliding from t0 changes the field the solver's first stage was built with)
        made_jump=jnp.any(stick0), restart=restart0, flight_scale=jnp.abs(x0),
        landing=jnp.array(False), target=zero,
        pending=jnp.zeros(mask_shape, bool), touch=jnp.zeros(mask_shape, bool),
        boundary=jnp.zeros(mask_shape, bool), h_after=h0,
        num_impacts=num_impacts0, log_base=None,
        log_t=log[0], log_pre=log[1], log_post=log[2], log_surface=log[3], log_kind=log[4],
        stick=stick0, releasing=jnp.array(False),
        intervals=jnp.full((3,), jnp.nan, dtype), zeno_time=zeno_time0,
        num_steps=jnp.array(0), num_accepted=jnp.array(0),
        status=jnp.where(finite0, status0, int(Status.NONFINITE)),
        done=~finite0 | (status0 != int(Status.SUCCESS)), t_final=t0, x_final=x0,
        save_index=save_index0, save_xs=save_xs0,
    )
    return seed_fixed_point(state, x0, args)


# --------------------------------------------------------------------------------------
# step: one solver step, then detection, landing and saving as that step calls for
# --------------------------------------------------------------------------------------


def step(ctx: LoopContext, c_in: LoopState, slides: bool = True,
         landing: bool | None = None) -> LoopState:
    return deciding_step(ctx, c_in, None, slides, landing)[0]


def deciding_step(ctx: LoopContext, c_in: LoopState, forced, slides: bool = True,
                  landing: bool | None = None):
    """`(step(c_in), decisions)`: the step with the decisions `forced` (`(h_next, keep)`,
    NaN step size: none) replayed, and the decisions it took (see `replay.py`).

    `landing`: None (the step finds out), or whether `lands(c_in)` is known to hold, for
    reverse mode's stored loop (`reverse.py`), which linearises the two kinds of step
    apart."""
    # A lane out of steps is frozen like a finished one (see `simulate`'s `cond`), but
    # keeps done = False so that it reports MAX_STEPS.
    out_of_steps = _out_of_steps(ctx, c_in)
    c = eqx.tree_at(lambda z: z.done, c_in, c_in.done | out_of_steps)
    # A landing step searches nothing (`detect`'s `detecting` is false for it): known
    # statically, the search is left out of the program (unbatched: under vmap the other
    # lanes may not land).
    searches = not (landing and not under_vmap(c_in))
    taken = take_step(ctx, c, slides, forced, search=searches)
    if not searches:
        found = nothing_detected(ctx)
    else:
        found = detect(ctx, c, taken, slides)
    landed, _, s_save = land_if_due(ctx, c, taken, landing)
    new = _next_state(ctx, c, taken, found, landed, s_save)
    return eqx.tree_at(lambda z: z.done, new, new.done & ~out_of_steps), (taken.h_next, taken.keep)


def lands(ctx: LoopContext, c: LoopState):
    """Whether the step from `c` lands some lane (unbatched): the landing branch of
    `land_if_due` runs."""
    return eqxi.unvmap_any(c.landing & ~(c.done | _out_of_steps(ctx, c)))


def _out_of_steps(ctx: LoopContext, c: LoopState):
    return ~c.done & (c.num_steps >= ctx.max_steps)


def _next_state(ctx: LoopContext, c: LoopState, taken: Step, found: Detection,
                landed: LoopState, s_save) -> LoopState:
    """Assemble the next state from the step's outcome: a free step accepted, a contact
    located (retake the step up to it), a landing (the impact applied), or a rejection."""
    sa, sb, y1, h_next = taken.sa, taken.sb, taken.y1, taken.h_next
    accept_free = found.detecting & ~found.event  # accepted, no contact: move on
    located = found.detecting & found.event
    go_land = located & found.verified  # contact located: retake the step up to it
    # A contact the curvature bound does not prove first in its part: retake the step
    # from sa, half as far as the contact, so that its parts shrink around the
    # uncertain stretch (`detect._verified`); what follows is found on the way.
    unsure = located & ~found.verified
    h_next = jnp.where(unsure, jax.lax.stop_gradient(0.5 * (found.first - sa)), h_next)
    reject = (~taken.keep | unsure) & ~c.landing & ~c.done

    save_index, save_xs = c.save_index, c.save_xs
    if ctx.ts is not None:
        # One save pass for the step just taken, in the flight's clock before any jump:
        # up to sb on a free step, up to the event on a landing, nothing otherwise.
        s_stop = jnp.where(accept_free, sb, jnp.where(c.landing & ~c.done, s_save, -jnp.inf))
        save_index, save_xs = _save(ctx, c, taken.interp, sa, s_stop)

    h_min_at, abs_time = ctx.h_min_at, ctx.abs_time
    reached_end = accept_free & (sb >= taken.s_end - h_min_at(abs_time(sb, c.t_hi, c.t_lo), c.time_scale))
    # (NaN-safe: a field that is NaN at x0 gives the controller a NaN first step, and
    # every later one; that ends here as NONFINITE, not in MAX_STEPS.)
    underflow = reject & ~(h_next >= h_min_at(abs_time(sa, c.t_hi, c.t_lo), c.time_scale))
    fail_status = jnp.where(taken.finite, int(Status.STEP_SIZE_UNDERFLOW), int(Status.NONFINITE))

    def pick(a_free, a_land, a_goland, a_other):
        return jnp.where(
            accept_free, a_free, jnp.where(c.landing, a_land, jnp.where(go_land, a_goland, a_other))
        )

    first, pending = found.first, found.pending
    return LoopState(
        args=c.args, time_scale=c.time_scale,
        s=pick(sb, landed.s, sa, sa),
        t_hi=jnp.where(c.landing, landed.t_hi, c.t_hi),
        t_lo=jnp.where(c.landing, landed.t_lo, c.t_lo),
        y=pick(y1, landed.y, c.y, c.y),
        h=jax.lax.stop_gradient(pick(h_next, landed.h, c.h, h_next)),
        solver_state=jax.tree.map(
            lambda a, b: jnp.where(accept_free | c.landing, a, b), taken.solver_state, c.solver_state
        ),
        controller_state=jax.tree.map(
            lambda a, b: jnp.where(c.landing, b, a), taken.controller_state, c.controller_state
        ),
        # After a step that the scene's `project` ended, the next one evaluates its first
        # stage afresh, as after a jump: an FSAL solver's stored last stage is f at the
        # unprojected end, and so is its tangent, which lacks the projection's Jacobian
        # (derivatives through `project` would carry, from every step's first stage, the
        # part of the tangent that the projection removes from the state).
        made_jump=pick(ctx.project is not None, landed.made_jump, c.made_jump, c.made_jump),
        restart=jnp.where(accept_free, False, jnp.where(c.landing, landed.restart, c.restart)),
        flight_scale=jnp.where(
            accept_free, jnp.maximum(c.flight_scale, jnp.abs(y1)), landed.flight_scale
        ),
        landing=go_land,
        stick=landed.stick,
        releasing=jnp.where(go_land, found.releasing, landed.releasing),
        target=jnp.where(go_land, first, c.target),
        pending=jnp.where(go_land, pending, c.pending),
        touch=jnp.where(go_land, found.touch & pending, c.touch),
        boundary=jnp.where(go_land, found.boundary & pending, c.boundary),
        # After the impact, restart no larger than twice the flight just ended: the
        # dynamics changed, and an exactly integrated flow would otherwise grow the
        # step 10x per flight (to 1e9 with t1 = inf) until the event search loses
        # its precision.
        h_after=jnp.where(
            go_land, jnp.minimum(jnp.maximum(sb - sa, h_next), 2 * first + h_min_at(first, c.time_scale)), c.h_after
        ),
        num_impacts=landed.num_impacts, log_base=c.log_base,
        log_t=landed.log_t, log_pre=landed.log_pre, log_post=landed.log_post,
        log_surface=landed.log_surface, log_kind=landed.log_kind,
        intervals=landed.intervals, zeno_time=landed.zeno_time,
        num_steps=jnp.where(c.done, c.num_steps, c.num_steps + 1),
        num_accepted=c.num_accepted + (accept_free | (c.landing & ~c.done)),
        status=jnp.where(
            reached_end | c.done | c.landing, landed.status,
            jnp.where(underflow, fail_status, c.status),
        ),
        done=c.done | reached_end | landed.done | underflow,
        t_final=jnp.where(
            reached_end, ctx.t1, jnp.where(underflow, abs_time(sa, c.t_hi, c.t_lo), landed.t_final)
        ),
        x_final=jnp.where(reached_end, y1, jnp.where(underflow, c.y, landed.x_final)),
        save_index=save_index, save_xs=save_xs,
    )


def _zero_interpolant_unless(use, interp):
    """`interp` where `use`, else the same interpolant with zero coefficients on [0, 1]
    (finite everywhere, and so are its partials)."""
    zeroed = jax.tree.map(
        lambda a: jnp.where(use, a, jnp.zeros_like(a))
        if eqx.is_inexact_array(a) else a, interp,
    )
    return eqx.tree_at(lambda i: i.t1, zeroed, jnp.where(use, interp.t1, 1.0))


def _save(ctx: LoopContext, c: LoopState, interp, sa, s_stop):
    """Save the dense output at the requested times in (sa, s_stop] (compiled only with
    `saveat`)."""
    ts, sigma = ctx.ts, ctx.sigma
    num = ts.shape[0]

    def local(j):
        return sigma * ((ts[jnp.minimum(j, num - 1)] - c.t_hi) - c.t_lo)

    if ctx.kinds.outer != "lax":
        # Reverse mode cannot transpose the data-dependent save loop below: evaluate
        # the interpolant at every requested time and keep those of this step (costs
        # len(saveat) evaluations per step, only with a reverse-capable adjoint).
        j = jnp.arange(num)
        s_j = local(j)
        mine = (j >= c.save_index) & (s_j <= s_stop)
        # Every evaluation must be finite with finite partials, kept or not: reverse mode
        # multiplies the zero cotangent of a discarded value by them (0 × inf is NaN).
        # On a step without saves (s_stop = -inf on rejections, whose stages may be
        # huge), evaluate a zero polynomial on [0, 1] instead; on a step with saves, at
        # times clipped into the step. (jax.grad with saveat was NaN before.)
        saves = jnp.any(mine)
        safe = _zero_interpolant_unless(saves, interp)
        s_top = jnp.maximum(s_stop, sa)
        values = jax.vmap(lambda s_: safe.evaluate(jnp.clip(s_, sa, s_top)))(s_j)
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


# --------------------------------------------------------------------------------------
# running, finish
# --------------------------------------------------------------------------------------


def running(ctx: LoopContext, c: LoopState):
    return ~c.done & (c.num_steps < ctx.max_steps)


def finish(ctx: LoopContext, final: LoopState) -> Solution:
    out_of_steps = ~final.done
    t_now = ctx.abs_time(final.s, final.t_hi, final.t_lo)
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
        ts=ctx.ts,
        xs=final.save_xs,
    )


def _tree_all_finite(tree):
    leaves = [
        jnp.all(jnp.isfinite(leaf))
        for leaf in jax.tree.leaves(tree)
        if eqx.is_array_like(leaf) and jnp.issubdtype(jnp.result_type(leaf), jnp.inexact)
    ]
    return jnp.all(jnp.array(leaves)) if leaves else jnp.array(True)


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
