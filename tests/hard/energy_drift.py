"""Energy drift of an elastic ball per bounce, by solver (docs/hard_cases.md).

    python -m tests.hard.energy_drift

Every flight of the elastic ball is integrated the same way, so the rounding of each
Runge–Kutta step is the same in every flight and adds up coherently. A tableau's weights
are not exact in binary: summed as Σ_j b_j k_j, free fall's speed gained a fixed number of
ulps per bounce and the impact times drifted like k². The unrolled steps sum relative to the
first stage (`grazejax/_loop/unrolled.py`), exact for a constant field: the gain per bounce is a
small fraction of an ulp and the drift grows like k.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
from grazejax import examples as ex


def drift(solver, bounces=400, h=1.0, g=9.81, tol=1e-10):
    sol = gj.simulate(ex.bouncing_ball(), jnp.array([h, 0.0]), 0.0, jnp.inf, {"g": g, "e": 1.0},
                      solver=solver, rtol=tol, atol=tol, max_impacts=bounces)
    speed = np.abs(np.asarray(sol.impact_pre[:, 1]))
    k = np.arange(bounces)
    error = np.asarray(sol.impact_times) - np.sqrt(2 * h / g) * (2 * k + 1)
    gain_ulps = (speed[-1] / np.sqrt(2 * g * h) - 1) / (bounces - 1) / np.finfo(float).eps
    slope = np.polyfit(np.log(k[50:] + 1.0), np.log(np.abs(error[50:]) + 1e-300), 1)[0]
    return gain_ulps, error[-1], slope


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    for solver in (diffrax.Tsit5(), diffrax.Dopri5(), diffrax.Dopri8()):
        gain, last, slope = drift(solver)
        print(f"{type(solver).__name__}: speed gain {gain:.3g} ulps/bounce, "
              f"impact-time error at bounce 400 {last:.2e}, log-log slope {slope:.2f}")
