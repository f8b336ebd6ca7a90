"""`LoopContext`: what every lane of one configuration shares.

Built once per `build_program` call (at trace time) and read by every phase; nothing in it
changes while the loop runs. Its per-surface helpers are static Python loops over the pieces.
"""

from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from .._adjoint import LoopKinds
from .._custom_types import RealScalar, VectorField
from .._geometry import Piece, contact_frame, gap_rates, is_tangential, project_to_contact
from .._roots import AbstractBracketedRootFinder
from .._status import ImpactKind
from .policies import AbstractZenoPolicy, sliding_field


class LoopContext(eqx.Module):
    """The static data of one configuration of the loop, shared by all its phases."""

    vector_field: VectorField  # f, in the scene's own time
    project: VectorField | None  # the scene's map back onto its invariant manifold, or None
    pieces: tuple[Piece, ...]  # the surfaces as the loop sees them (images when backward)
    impact_kinds: tuple[ImpactKind, ImpactKind, ImpactKind]  # α, β, γ (or α′, β′, γ′)
    sigma: int  # +1 forward, -1 backward
    t0: RealScalar
    t1: RealScalar
    ts: Float[Array, " saves"] | None  # saveat times, or None: no dense output compiled
    dtype: Any
    n: int  # state dimension
    m: int  # number of surface pieces
    max_signs: int  # the most sides of one piece that can be hit (1 or 2)
    eps: float
    tol_r: Any  # the controller's tolerances: the state is known to them only
    tol_a: Any
    solver: diffrax.AbstractSolver
    controller: Any  # the loop's step-size controller (see `stepping.loop_controller`)
    has_error: bool  # the solver has an embedded error estimate
    term: diffrax.ODETerm  # the field in the loop's clock (see `loop_field`)
    error_order: Any
    kinds: LoopKinds
    policy: AbstractZenoPolicy
    event_root_finder: AbstractBracketedRootFinder  # every bracketed search of the loop (`_roots`)
    # The loop runs on a batch of lanes (`jax.vmap`, `sweep`'s pool): the impact log's
    # row writes then run only on iterations where some lane writes (`write_log_rows`).
    batched: bool
    # Probe the field for a jump at every restart state (`field.py`; simulate's
    # `check_field_jumps`).
    check_field_jumps: bool
    dt0: Any
    max_impacts: int
    max_steps: int
    zeno_rtol: float
    zero: RealScalar
    nan: RealScalar

    @property
    def sticky(self) -> bool:
        """Whether sliding is compiled in: the policy slides (ZenoStick) and there is a
        surface (`build_context` runs a scene without surfaces with ZenoStop)."""
        return self.policy.slides

    @property
    def free_term(self) -> diffrax.ODETerm:
        """The loop's field without the sliding force (`term` itself unless sticky)."""
        if not self.sticky:
            return self.term
        return diffrax.ODETerm(loop_field(self.vector_field, self.pieces, self.sigma, False))

    @property
    def log_rows_per_landing(self) -> int:
        """Impact-log rows one landing can write: one per (surface, side), and the start or
        end of sliding."""
        return sum(len(p.signs) for p in self.pieces) + int(self.sticky)

    @property
    def mask_shape(self) -> tuple[int, int]:
        return (self.m, self.max_signs)

    def state_tol(self, x):
        # The state is only known to the solver's tolerance: piece boundaries (`where`) are
        # resolved to within ten times that, so a crossing exactly on ∂Γ is not lost.
        return 10 * (self.tol_a + self.tol_r * jnp.abs(x))

    def abs_time(self, s, t_hi, t_lo):
        """The loop runs in local time s >= 0; absolute time is t = t_hi + t_lo + σ s."""
        return loop_time(self.sigma, s, t_hi, t_lo)

    def s_end_of(self, t_hi, t_lo):
        return self.sigma * ((self.t1 - t_hi) - t_lo)

    def h_min_at(self, t_abs, time_scale):
        """Below h_min a step no longer moves t: the controller has given up."""
        return 16 * self.eps * jnp.maximum(jnp.abs(t_abs), time_scale)

    # ---- per-surface helpers ----

    def contact_geometry(self, piece, t, y, args_):
        return contact_frame(piece.gap, piece.jump, self.vector_field, t, y, args_)

    def project_onto_contacts(self, on, t, y, args_):
        """`y` projected onto the contact manifold {Φ = 0, Φ̇ = 0} of the surface `on`
        marks (`y` itself where it marks none)."""
        out = y
        for i, piece in enumerate(self.pieces):
            on_m = project_to_contact(piece.gap, piece.jump, self.vector_field, t, y, args_)
            out = jnp.where(on[i], on_m, out)
        return out

    def gap_along(self, piece, sign, s_to_y, t_hi, t_lo, args_):
        def g(s):
            return sign * piece.gap(self.abs_time(s, t_hi, t_lo), s_to_y(s), args_)

        return g

    def slopes_at(self, piece, sign, s, y, t_hi, t_lo, args_):
        """g, ġ, g̈ along the true vector field at (s, y), in the loop's clock."""
        return gap_rates(
            piece.gap, self.vector_field, self.abs_time(s, t_hi, t_lo), y, args_, sign,
            self.sigma,
        )

    def sliding_pull(self, stick, s, y, t_hi, t_lo, args_):
        """Φ̈ of the free flow on the surface being slid on: the state leaves when ≥ 0."""
        rate = jnp.zeros((), self.dtype)
        for i, piece in enumerate(self.pieces):
            _, _, gdd = self.slopes_at(piece, 1, s, y, t_hi, t_lo, args_)
            rate = rate + jnp.where(stick[i], gdd, 0.0)
        return rate

    def on_surface(self, piece, t, y, args_, x_scale=None, step_ulps=0.0):
        floor = piece.floor(t, y, args_, x_scale)
        if piece.signs:  # the step-length term, with the slope along the true field
            sigma, f = self.sigma, self.vector_field
            slope = jax.jvp(
                lambda tt, yy: piece.gap(tt, yy, args_), (t, y),
                (sigma * jnp.ones_like(t), sigma * f(t, y, args_)),
            )[1]
            floor = floor + step_ulps * jax.lax.stop_gradient(jnp.abs(slope))
        g = piece.gap(t, y, args_)
        return (jnp.abs(g) <= floor) & jnp.isfinite(g), floor

    def contact_tests(self, t_hi, t_lo, y, args_, x_scale, step_ulps=0.0):
        """Per surface, at a restart: on it (guard the flight's first step), stuck on it,
        and pushed into it by the free flow.

        Stuck is a tangential restart with the flow pushing in: the state would slide into
        Φ < 0 from rest (e.g. restitution 0). That is sticking, the end of a Zeno
        sequence; never tunnel.
        """
        t = t_hi + t_lo
        restart, stuck, pushed = [], [], []
        for piece in self.pieces:
            on, floor = self.on_surface(piece, t, y, args_, x_scale, step_ulps)
            restart.append(on)
            stuck_i = pushed_i = jnp.array(False)
            for sign in piece.signs:
                _, gd, gdd = self.slopes_at(piece, sign, jnp.zeros_like(t), y, t_hi, t_lo, args_)
                tangential = is_tangential(gd, gdd, floor)
                stuck_i = stuck_i | (on & tangential & (gdd < 0))
                pushed_i = pushed_i | (on & (gdd < 0))
            stuck.append(stuck_i)
            pushed.append(pushed_i)
        as_mask = lambda v: jnp.array(v, dtype=bool).reshape((self.m,))  # noqa: E731
        return as_mask(restart), as_mask(stuck), as_mask(pushed)

    def impenetrable_contact(self, t, s, t_hi, t_lo, x, args_, x_scale, step_ulps=None,
                             x_before=None):
        """State x at time t (local time s of the flight from t_hi + t_lo), over the
        impenetrable pieces: `(inside, resting)`.

        `inside`: x strictly inside one (beyond its contact floor), or on it and moving in
        across it (ġ < 0, not tangential): the next flight would start inside. At a start
        that is a bad start (the ball on the floor moving down fell through it with
        SUCCESS); after a landing's jumps, a bad jump (a wall's jump that put the state
        under an impenetrable floor ran on with SUCCESS). `resting`: on one at rest,
        pushed in (tangential, g̈ < 0): sticking, as after a tangential restart
        (`contact_tests`). `step_ulps`: the landing step's term of the floor.

        `x_before`: after a landing, the event state before the jumps. It lies on its
        surface only to the event's accuracy (a moving wall's event state sat 2e-11
        inside), and a jump that does not move the gap (a restitution law on the
        velocities) leaves the state there: inside is then *deeper* than the event
        state, not merely below the floor."""
        inside_any = resting_any = jnp.array(False)
        for piece in self.pieces:
            if piece.check_jump_side:
                g, gd, gdd = self.slopes_at(piece, 1, s, x, t_hi, t_lo, args_)
                floor = piece.floor(t, x, args_, x_scale)
                if step_ulps is not None:
                    floor = floor + step_ulps * jnp.abs(jax.lax.stop_gradient(gd))
                in_piece, _ = piece.inside(t, x, args_, self.state_tol)
                on = jnp.abs(g) <= floor
                tangential = is_tangential(gd, gdd, floor)
                entering = on & (gd < 0) & ~tangential
                depth = g
                if x_before is not None:
                    depth = g - jnp.minimum(piece.gap(t, x_before, args_), 0.0)
                inside_any = inside_any | (((depth < -floor) | entering) & in_piece)
                resting_any = resting_any | (on & tangential & (gdd < 0) & in_piece)
        return inside_any, resting_any


def loop_time(sigma, s, t_hi, t_lo):
    return t_hi + (t_lo + sigma * s)


def loop_field(vector_field, pieces, sigma, sticky) -> Callable:
    """The field the solver integrates: σ·f in the local clock s, with the sliding force
    added while a lane slides (`targs = (args, t_hi, t_lo, stick)`).

    A plain function (not a method of `LoopContext`): the solver's term holds it, and a
    bound method would make the whole context part of the term's pytree.
    """

    def local_field(s, y, targs):
        args_, t_hi, t_lo, stick = targs
        t = loop_time(sigma, s, t_hi, t_lo)
        free = vector_field(t, y, args_)
        if sticky:
            free = sliding_field(vector_field, pieces, t, y, args_, stick, free)
        return sigma * free

    return local_field
