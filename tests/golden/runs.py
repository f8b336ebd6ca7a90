"""A fixed set of runs whose results are recorded, as a safety net for moving the loop.

Each run exercises one part of the impact loop: transversal impacts (ball, forced
oscillator), near-grazing impacts (ex1dof), boundary points (orbex2), sticking and release
(vibrating table with `zeno="stick"`), Zeno, backward time through Newton inverses, saveat,
batches, constant steps and forward-mode Jacobians. `python -m tests.golden.runs` rewrites
`golden.npz` (do it only before a refactor, never to make a changed result pass).
"""

import pathlib

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
from grazejax import examples as ex

PATH = pathlib.Path(__file__).with_name("golden.npz")
FIELDS = ("t_final", "x_final", "num_impacts", "impact_times", "impact_pre", "impact_post",
          "impact_surface", "impact_kind", "status", "zeno_time", "num_steps")


def _flat(name, sol, out):
    for field in FIELDS:
        out[f"{name}.{field}"] = np.asarray(getattr(sol, field))
    if sol.xs is not None:
        out[f"{name}.xs"] = np.asarray(sol.xs)


def _ball_args(e):
    return {"g": 9.81, "e": e}


def runs() -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    ball = ex.bouncing_ball()
    _flat("ball_zeno", gj.simulate(ball, jnp.array([1.0, 0.0]), 0.0, 5.0, _ball_args(0.8),
                                   max_impacts=200), out)
    _flat("ball_elastic", gj.simulate(ball, jnp.array([50.0, 0.0]), 0.0, 40.0, _ball_args(1.0),
                                      rtol=1e-10, atol=1e-10, max_impacts=20,
                                      saveat=jnp.linspace(0.0, 40.0, 9)), out)
    _flat("ball_backward", gj.simulate(ball, jnp.array([0.3, 1.0]), 3.0, 0.0, _ball_args(0.8),
                                       max_impacts=20), out)
    _flat("ball_fixed_steps", gj.simulate(ball, jnp.array([1.0, 0.0]), 0.0, 2.0, _ball_args(0.8),
                                          stepsize_controller=diffrax.ConstantStepSize(),
                                          dt0=0.01), out)
    osc, osc_args = ex.impact_oscillator(), ex.impact_oscillator_args()
    _flat("oscillator", gj.simulate(osc, jnp.array([0.0, 0.0]), 0.0, 30.0, osc_args,
                                    solver=diffrax.Dopri8(), rtol=1e-10, atol=1e-10,
                                    max_impacts=100), out)
    _flat("ex1dof", gj.simulate(ex.ex1dof(), jnp.array([0.5, 1.2]), 0.0, 20.0,
                                ex.ex1dof_args(0.2), max_impacts=50), out)
    _flat("orbex2", gj.simulate(ex.orbex2(), jnp.array([0.8, 1.2]), 0.0, 10.0,
                                ex.orbex2_args(), max_impacts=50), out)
    table = ex.vibrating_table()
    table_args = {"g": 9.81, "e": 0.5, "A": 0.05, "omega": 10.0}
    _flat("table_stick", gj.simulate(table, jnp.array([0.3, 0.0]), 0.0, 3.0, table_args,
                                     zeno="stick", max_impacts=200), out)
    lanes = jnp.stack([jnp.linspace(0.2, 2.0, 5), jnp.zeros(5)], axis=1)
    batch = jax.vmap(lambda x0: gj.simulate(ball, x0, 0.0, 3.0, _ball_args(0.7), direction=1,
                                            max_impacts=40))(lanes)
    _flat("ball_batch", batch, out)
    jac = jax.jacfwd(lambda x0: gj.simulate(osc, x0, 0.0, 12.0, osc_args,
                                            max_impacts=40).x_final)(jnp.array([0.1, 0.0]))
    out["oscillator_jacfwd"] = np.asarray(jac)
    return out


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    np.savez_compressed(PATH, **runs())
    print(f"wrote {PATH}")
