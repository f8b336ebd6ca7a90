"""An unstable periodic orbit: numerical divergence grows by the Floquet multiplier.

A quadratic restitution law (like the paper's orbex2 wall Γ1, y2 → −R1 y2²): on the wall
x = 0 the velocity v− < 0 becomes v+ = k v−². Between impacts the flight returns to the
wall with the opposite velocity, both for free fall (x'' = −g) and for the rotation
x'' = −x. So the impact map is v ↦ k v², with the fixed point v* = 1/k (a periodic orbit)
and the multiplier ρ = d(k v²)/dv = 2k v* = 2: the distance from the orbit doubles every
period. The monodromy matrix has eigenvalues {1 (along the flow), ρ}.

The orbit is started exactly (to round-off); round-off and solver error seed the
divergence, and its measured growth rate must be ρ.
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj

from ..helpers import rotation_field
from ._common import f64, f64_args, record, runner, status


def _quadratic_wall():
    return gj.Surface(
        phi=lambda t, x, a: x[0],
        jump=lambda t, x, a: x.at[1].set(a["k"] * x[1] ** 2),
        name="x = 0, v -> k v^2",
    )


QUAD_BALL = gj.Scene(
    lambda t, x, a: jnp.stack([x[1], -a["g"] * jnp.ones_like(x[0])]), [_quadratic_wall()]
)
QUAD_ROTATION = gj.Scene(rotation_field, [_quadratic_wall()])

RHO = 2.0
CASES = {
    # name: (tolerance, args, apex start, period)
    "free fall": ("default", dict(g=9.81, k=0.8), lambda v: [v * v / (2 * 9.81), 0.0], lambda v: 2 * v / 9.81),
    "rotation": ("tight", dict(k=0.8), lambda v: [v, 0.0], lambda v: math.pi),
}
SCENE_OF = {"free fall": QUAD_BALL, "rotation": QUAD_ROTATION}


@pytest.mark.parametrize("case", list(CASES))
def test_divergence_from_the_unstable_orbit_grows_by_the_multiplier(case):
    tol, args, apex, period = CASES[case]
    v_star = 1 / args["k"]
    n_max = 45
    sol = runner(SCENE_OF[case], tol, max_impacts=n_max)(
        f64(apex(v_star)), f64(0.0), f64(n_max * period(v_star)), f64_args(**args)
    )
    k = int(sol.num_impacts)
    d = np.asarray(sol.impact_post[:k, 1]) - v_star  # distance from the orbit, per period
    # The first periods sit on the orbit to round-off / solver error; then it doubles.
    window = (np.abs(d[:-1]) > 1e-9) & (np.abs(d[:-1]) < 1e-4) & (np.abs(d[1:]) < 2e-4)
    assert np.count_nonzero(window) >= 8
    ratios = d[1:][window] / d[:-1][window]
    # Nonlinear correction k·d ≤ 1e-4; fresh error per period ≤ ~1e-12 / 1e-9.
    assert np.all(np.abs(ratios - RHO) <= 2e-3)
    # The seed: where the divergence started (extrapolated back to n = 0).
    first = np.argmax(window)
    seed = abs(d[first]) / RHO**first
    record(f"Floquet {case}: max |measured ratio - rho| per period", np.max(np.abs(ratios - RHO)))
    record(f"Floquet {case}: divergence seed |d_0| (extrapolated)", seed)
    # Eventually the orbit is left for good (escape upward, or collapse to the wall).
    assert np.max(np.abs(d)) > 1e-3 or status(sol) != gj.Status.SUCCESS


def test_monodromy_eigenvalues_are_one_and_the_multiplier():
    """jacfwd of x(T) for one period T = π of the rotation case, from the apex."""
    v_star = 1 / 0.8
    jac = runner(QUAD_ROTATION, "tight", max_impacts=3, jac=True)
    M = np.asarray(jac(f64([v_star, 0.0]), f64(0.0), f64(math.pi), f64_args(k=0.8)))
    eig = np.sort(np.linalg.eigvals(M).real)
    np.testing.assert_allclose(eig, [1.0, RHO], atol=1e-8)
    record("Floquet rotation: monodromy eigenvalue error (jacfwd)", np.max(np.abs(eig - [1.0, RHO])))
