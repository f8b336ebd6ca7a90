"""jax.jacfwd of x_final with respect to x0 at and near grazing.

Near grazing the true Jacobian blows up like 1/|v_hit| (the saltation matrix
S = DJ + (f⁺ − DJ f⁻)∇Φᵀ/(∇Φ·f⁻) has ∇Φ·f⁻ = v_hit → 0), so large-but-finite entries are
the right answer on the hit side; on the miss side it is the plain flow Jacobian. At exact
grazing (a contact the simulator classifies as tangential) the map is not differentiable:
jacfwd returns NaN there, never a finite number that is neither side's value.
"""

import math

import numpy as np
import pytest

from ..helpers import central_differences, dip_start
from ._common import f64, f64_args, record, runner

A, V0, E = 2.0, -1.0, 0.8
T1 = 3.0  # the dip's minimum is at τ = 0.5


def _flow(s):
    return np.array([[1.0, s], [0.0, 1.0]])


def _closed_form_jacobian(delta):
    """d x(T1) / d x0 for the parabola dipping δ below the floor (restitution 0.8)."""
    if delta <= 0:
        return _flow(T1)
    _, t_hit, v_hit = dip_start(delta, A, V0)
    S = np.array([[-E, 0.0], [(1 + E) * A / v_hit, -E]])
    return _flow(T1 - t_hit) @ S @ _flow(t_hit)


@pytest.mark.parametrize("delta", [1e-2, 1e-5, 1e-8, 1e-11, 0.0, -1e-11, -1e-8, -1e-2])
def test_jacfwd_near_grazing_is_finite_and_matches_the_saltation_matrix(delta):
    jac = runner("free_fall", "default", max_impacts=2, jac=True)
    x0, _, v_hit = dip_start(delta, A, V0)
    J = np.asarray(jac(f64(x0), f64(0.0), f64(T1), f64_args(a=A)))
    if delta == 0.0:
        # Exact grazing: not differentiable (the miss-side limit is the flow Jacobian, the
        # hit side diverges).
        assert np.all(np.isnan(J))
        return
    assert np.all(np.isfinite(J))
    exact = _closed_form_jacobian(delta)
    # Conditioning: a position error ε ~ 1e-15 changes v_hit² = 2aδ by 2aε, i.e. the
    # 1/v_hit entries by ε/(2δ) relative.
    rel = np.max(np.abs(J - exact)) / np.max(np.abs(exact))
    assert rel <= 1e-8 + 4e-15 / abs(delta)
    record(f"jacfwd near grazing delta={delta:g}: relative error vs closed form", rel)
    if delta > 0:
        record("jacfwd near grazing: largest finite entry (delta=1e-11)", np.max(np.abs(J)))


@pytest.mark.parametrize("radius_offset", [0.0, 1e-6, -1e-6], ids=["grazing", "hit", "miss"])
def test_jacfwd_ex1dof_grazing_cycle_is_finite(radius_offset):
    """ex1dof at μ = 0: the cycle of radius 1 about (1, 0) grazes Γ at the origin; J is
    the identity there with DJ singular (∂J2/∂x2 = −2R x2 = 0). Two turns."""
    jac = runner("ex1dof", "tight", max_impacts=3, jac=True)
    run = runner("ex1dof", "tight", max_impacts=3)  # shared with test_grazing
    args = f64_args(mu=0.0, eps=1e-4, R=0.9)
    x0 = np.array([2.0 + radius_offset, 0.0])
    t1 = 4 * math.pi
    J = np.asarray(jac(f64(x0), f64(0.0), f64(t1), args))
    assert np.all(np.isfinite(J))
    record(f"jacfwd ex1dof {radius_offset:+g}: max |J|", np.max(np.abs(J)))
    if radius_offset < 0:
        # Miss side: smooth; central differences with a step far below the margin.
        h = 1e-8
        fd = central_differences(lambda x: run(f64(x), f64(0.0), f64(t1), args).x_final, x0, h)
        np.testing.assert_allclose(J, fd, atol=1e-5)
        record("jacfwd ex1dof miss side vs central FD", np.max(np.abs(J - fd)))


def _ceiling_scene():
    import jax.numpy as jnp

    import grazejax as gj

    field = lambda t, x, c: jnp.stack([x[1], -jnp.ones_like(x[0])])  # noqa: E731
    ceiling = gj.Surface(phi=lambda t, x, c: c - x[0], jump=lambda t, x, c: x.at[1].set(-0.5 * x[1]))
    return gj.Scene(field, [ceiling])


def _ceiling_closed_form(v0, c, t1=3.0):
    """x(t1) from (0, v0) under x'' = −1 with one impact on the ceiling x = c (v⁺ = −v⁻/2)."""
    import mpmath

    s = mpmath.sqrt(v0**2 - 2 * c)  # the impact speed
    t_hit = v0 - s
    return c - s / 2 * (t1 - t_hit) - (t1 - t_hit) ** 2 / 2


@pytest.mark.parametrize("depth", [1e-2, 1e-6, 0.0])
def test_derivatives_at_a_touch_are_nan_in_both_modes(depth):
    """A particle launched at v0 = 1 towards a ceiling at c = 1/2 − depth: d x(3)/d v0
    grows like 1/√depth on the impacting side (against the closed form, differentiated by
    mpmath); at depth 0 the trajectory only touches the ceiling and there is no
    derivative: NaN from `jax.jacfwd` and from `jax.grad` (DirectAdjoint), never a finite
    number."""
    import diffrax
    import jax
    import jax.numpy as jnp
    import mpmath

    import grazejax as gj

    scene, c = _ceiling_scene(), 0.5 - depth

    def end(v0, adjoint=None):
        sol = gj.simulate(scene, jnp.stack([jnp.zeros_like(v0), v0]), 0.0, 3.0, c, rtol=1e-12,
                          atol=1e-12, adjoint=adjoint)
        return sol.x_final[0]

    forward = float(jax.jacfwd(end)(1.0))
    reverse = float(jax.grad(lambda v: end(v, diffrax.DirectAdjoint()))(1.0))
    if depth == 0.0:
        assert math.isnan(forward) and math.isnan(reverse)
        return
    with mpmath.workdps(40):
        exact = float(mpmath.diff(lambda v: _ceiling_closed_form(v, mpmath.mpf(c)), 1))
    # Conditioning: ε ~ 1e-15 in the impact position moves s² = 2·depth by ~ε.
    assert abs(forward - exact) <= (1e-9 + 4e-15 / depth) * abs(exact)
    assert reverse == pytest.approx(forward, rel=1e-12)
