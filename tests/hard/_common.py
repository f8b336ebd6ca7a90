"""Shared scenes, cached jitted runners and the measurement log of the hard-case suite.

Compilation dominates the cost of these tests (2-5 s per distinct scene and option set),
so every scene here is built once, at import, and every runner is `jax.jit`-compiled once
and cached: hypothesis examples pass their numbers through `x0`, `t0`, `t1` and `args`,
never through closures.

`record(name, value)` keeps the worst value of a measured quantity; tests/hard/conftest.py
prints them all at the end of the session (`pytest tests/hard -s`). The table in
docs/hard_cases.md was filled from that printout.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
from grazejax import examples as ex

from ..helpers import free_fall_scene, rotation_field

EPS = float(np.finfo(np.float64).eps)
FLOOR_ULPS = 64  # the documented contact floor, in ulps of the gap's scale (README)

TIGHT = dict(rtol=1e-12, atol=1e-12)
DEFAULT = dict()  # simulate's defaults: rtol=1e-8, atol=1e-10
LOOSE = dict(rtol=1e-3, atol=1e-6)
TOLERANCES = {"tight": TIGHT, "default": DEFAULT, "loose": LOOSE}

MEASURED: dict[str, float] = {}


def record(name: str, value, worst: str = "max") -> None:
    """Keep the worst value seen for `name`: the largest, or the smallest (`worst="min"`)."""
    pick = max if worst == "max" else min
    MEASURED[name] = pick(MEASURED.get(name, float(value)), float(value))


def status(sol) -> gj.Status:
    return gj.Status(int(sol.status))


# ------------------------------------------------------------------ scenes -------------

FREE_FALL = free_fall_scene(restitution=0.8)  # x' = v, v' = a; floor Φ = x, v → −0.8 v
BALL = ex.bouncing_ball()
TABLE = ex.vibrating_table()
OSCILLATOR = ex.impact_oscillator()
EX1DOF = ex.ex1dof()


# x1' = x2, x2' = −x1 (circles about 0) with a wall x1 = −c (free side x1 > −c), elastic.
ROTATION_WALL = gj.Scene(
    rotation_field,
    [
        gj.Surface(
            phi=lambda t, x, a: x[0] + a["c"],
            jump=lambda t, x, a: x.at[1].set(-x[1]),
            inverse_jump=lambda t, x, a: x.at[1].set(-x[1]),
            impenetrable=True,
            name="x1 = -c",
        )
    ],
)


# ------------------------------------------------------------------ runners ------------


@functools.cache
def runner(scene, tol: str = "default", max_impacts: int = 1, direction: int = 1,
           max_steps: int = 100_000, solver=None, allow_float32: bool = False, jac: bool = False,
           zeno: str = "stop"):
    """jit(simulate) for a scene (a name from `SCENES`, or a test module's own `Scene`)
    with traced (x0, t0, t1, args), compiled once per scene and options."""
    scene = SCENES[scene] if isinstance(scene, str) else scene
    options = dict(TOLERANCES[tol], max_impacts=max_impacts, direction=direction,
                   max_steps=max_steps, allow_float32=allow_float32, zeno=zeno)
    if solver is not None:
        options["solver"] = solver

    def run(x0, t0, t1, args):
        return gj.simulate(scene, x0, t0, t1, args, **options)

    if jac:
        return jax.jit(jax.jacfwd(lambda x0, t0, t1, args: run(x0, t0, t1, args).x_final))
    return jax.jit(run)


def _free_fall_field(t, x, args):
    return jnp.stack([x[1], args["a"] * jnp.ones_like(x[0])])


# free fall above a wall at height c (Φ = x − c), restitution 0.8: exact tangencies off 0.
WALL_FREE_FALL = gj.Scene(
    _free_fall_field,
    [gj.Surface(phi=lambda t, x, a: x[0] - a["c"], jump=lambda t, x, a: x.at[1].set(-0.8 * x[1]))],
)

SCENES = {
    "wall_free_fall": WALL_FREE_FALL,
    "free_fall": FREE_FALL,
    "ball": BALL,
    "table": TABLE,
    "oscillator": OSCILLATOR,
    "ex1dof": EX1DOF,
    "rotation_wall": ROTATION_WALL,
}


def f64(value):
    """A strongly typed float64 array (python floats are weakly typed: another compile)."""
    return jnp.asarray(np.asarray(value, np.float64))


def f64_args(**kw):
    return {k: f64(v) for k, v in kw.items()}
