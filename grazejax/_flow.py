"""The free flow x' = f(t, x) between two times, without impacts: defined once for every
analysis (W-maps, meeting times, variational equations, the period map's closing hop).

- `free_flow`: the adaptive flight of `simulate` (same solver, tolerances, step control,
  and the scene's `project` after every step), between two possibly traced times, in
  either direction.
- `short_free_flow`: a fixed-step RK4 hop over a short time δ, smooth in δ, for Newton
  solves that need the flow over a small, changing gap (the period map).
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
from jax import lax

from ._scene import Scene
from ._simulate import simulate

# Options of `simulate` that the analysis helpers set themselves.
OWN_OPTIONS = ("max_impacts", "direction", "saveat", "throw")


def flight_kwargs(kw):
    """The user's `simulate` options that apply to a flight without impacts."""
    return {k: v for k, v in kw.items() if k not in OWN_OPTIONS}


class _Rescaled(eqx.Module):
    """x' = f(t, x) on [t_a, t_b] as dx/ds = (t_b − t_a) f(t_a + (t_b − t_a) s, x), s ∈ [0, 1].

    Why: a flow between two *traced* times (τ from an event, back to θ) has a direction
    unknown at trace time; in s it always runs forward, for either sign of t_b − t_a, and
    for t_b = t_a it is the identity. The times enter as args, so `jacfwd` differentiates
    through them.
    """

    vector_field: Any = eqx.field(static=True)

    def __call__(self, s, y, params):
        t_a, t_b, args = params
        span = t_b - t_a
        return span * self.vector_field(t_a + span * s, y, args)


class _RescaledProjection(eqx.Module):
    """A scene's `project(t, x, args)` in the clock of `_Rescaled`: at s ∈ [0, 1], the
    time t_a + (t_b − t_a) s."""

    project: Any = eqx.field(static=True)

    def __call__(self, s, y, params):
        t_a, t_b, args = params
        return self.project(t_a + (t_b - t_a) * s, y, args)


def free_flow(flow: Scene, x, t_a, t_b, args, kw):
    """`(x(t_b), status)` for x' = f from (t_a, x), without impacts (either direction).

    `flow` is a scene whose surfaces are ignored: its field, and its `project`, applied
    after every step as `simulate` applies it, so that an analysis's flights (a W-map's,
    a variational flight's) are the flights of the runs they linearise."""
    project = None if flow.project is None else _RescaledProjection(flow.project)
    scene = Scene(_Rescaled(flow.vector_field), [], project=project)
    sol = simulate(scene, x, 0.0, 1.0, (t_a, t_b, args), **flight_kwargs(kw))
    return sol.x_final, sol.status


def short_free_flow(vector_field, t, x, delta, args, substeps: int = 8):
    """x(t + δ) of x' = f(t, x) from (t, x), ignoring surfaces, by classical RK4.

    For a small δ that a Newton solve moves (δ = 0 at the solution, either sign before):
    fixed steps keep it smooth in δ and cheap; the error, O(δ⁵/substeps⁴), vanishes with δ.
    """
    h = delta / substeps

    def step(i, y):
        s = t + i * h
        k1 = vector_field(s, y, args)
        k2 = vector_field(s + h / 2, y + h / 2 * k1, args)
        k3 = vector_field(s + h / 2, y + h / 2 * k2, args)
        k4 = vector_field(s + h, y + h * k3, args)
        return y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    return lax.fori_loop(0, substeps, step, x)
