"""Very small and very large units, and float32.

Units: lengths × L and times × T (g → g L/T², v → v L/T). A bouncing ball must give the
same impact count and the same relative accuracy at every scale, and near-grazing
detection must hold at the same *relative* depths: the contact floor must scale with
the units. It does at every scale below, also when velocities and lengths have different
scales (L/T ≠ L), because the floor is taken per coordinate (64 ulps of
Σ_k |∂Φ/∂x_k|·max|x_k|): a large velocity no longer sets the floor of a position gap.

float32 (`allow_float32=True` with a float32 x0): runs, keeps float32 throughout, and is
accurate to ~1e-5 relative.
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex

from ..helpers import dip_start
from ._common import ROTATION_WALL, f64, f64_args, record, runner, status

SCALES = [(1e-6, 1.0), (1e6, 1.0), (1.0, 1e6), (1e6, 1e6), (1e-6, 1e6), (1.0, 1e-6), (1e-6, 1e-6), (1e6, 1e-6)]
_ids = [f"L={L:g},T={T:g}" for L, T in SCALES]


@pytest.mark.parametrize("L,T", SCALES, ids=_ids)
def test_bouncing_ball_is_scale_invariant(L, T):
    g, e, h0 = 9.81, 0.8, 1.0
    run = runner("ball", "tight", max_impacts=1000)
    unit = run(f64([h0, 0.0]), f64(0.0), f64(10.0), f64_args(g=g, e=e))
    sol = run(f64([h0 * L, 0.0]), f64(0.0), f64(10.0 * T), f64_args(g=g * L / T**2, e=e))
    assert status(sol) == status(unit) == gj.Status.ZENO
    k = int(sol.num_impacts)
    assert k == int(unit.num_impacts)
    exact, t_inf = ex.bouncing_ball_impact_times(h0, 0.0, g, e, k)
    def errors(s, T):
        return (np.max(np.abs(np.asarray(s.impact_times[:k]) / T - exact)),
                abs(float(s.zeno_time) / T - t_inf))

    err_t, err_z = errors(sol, T)
    unit_t, unit_z = errors(unit, 1.0)
    # Same relative accuracy as in unit scale (round-off: ~2e-12 at t ~ 4).
    assert err_t <= 1e-12 * t_inf and err_z <= 1e-11 * t_inf
    assert err_t <= 2 * unit_t + 1e-13 and err_z <= 2 * unit_z + 1e-13
    w = math.sqrt(2 * g * h0)
    np.testing.assert_allclose(-np.asarray(sol.impact_pre[:k, 1]) / (L / T), w * e ** np.arange(k), rtol=0, atol=2e-12 * w)
    assert float(np.min(np.asarray(sol.impact_pre[:k, 0]))) / L >= -1e-14
    record("scales: ball impact-time error / T (all scales)", err_t)
    record("scales: ball zeno_time error / T (all scales)", err_z)


@pytest.mark.parametrize(
    "L,T",
    SCALES,
    ids=_ids,
)
def test_near_grazing_at_relative_depths_is_scale_invariant(L, T):
    """Dips of 1e-6, 1e-9, 1e-11 (relative) are impacts at the exact time, misses by the
    same amounts are not, at every scale (the unit-scale floor is ~1e-14)."""
    a, v0 = 2.0, -1.0
    run = runner("free_fall", "default")
    worst = 0.0
    for delta in (1e-6, 1e-9, 1e-11, -1e-11, -1e-9, -1e-6):
        x0, t_hit, v_hit = dip_start(delta, a, v0)
        sol = run(f64([x0[0] * L, x0[1] * L / T]), f64(0.0), f64(3.0 * T), f64_args(a=a * L / T**2))
        k = int(sol.num_impacts)
        if delta < 0:
            assert k == 0, f"false contact on a miss by {-delta:g} L"
            continue
        assert k == 1 and gj.ImpactKind(int(sol.impact_kind[0])) == gj.ImpactKind.ALPHA
        dt = abs(float(sol.impact_times[0]) / T - t_hit)
        assert dt <= 1e-14 / abs(v_hit) * 64
        worst = max(worst, dt * abs(v_hit))
    record("scales: near-grazing |dt/T|·|v_hit| (scale-consistent cases)", worst)


# ------------------------------------------------------------------ float32 ------------


def test_float32_bouncing_ball():
    """float32 in, float32 out; impact times ~1e-6 and zeno_time ~1e-4 relative (the Zeno
    tail is cut at float32 resolution), never below the floor by more than ~1e-7."""
    run = runner("ball", "default", max_impacts=200, allow_float32=True)
    args = {"g": jnp.float32(9.81), "e": jnp.float32(0.8)}
    sol = run(jnp.array([1.0, 0.0], jnp.float32), jnp.float32(0.0), jnp.float32(10.0), args)
    assert sol.x_final.dtype == jnp.float32 and sol.impact_times.dtype == jnp.float32
    assert status(sol) == gj.Status.ZENO
    k = int(sol.num_impacts)
    assert k >= 20
    exact, t_inf = ex.bouncing_ball_impact_times(1.0, 0.0, 9.81, 0.8, k)
    times = np.asarray(sol.impact_times[:k], np.float64)
    rel_t = np.max(np.abs(times - exact) / exact)
    rel_z = abs(float(sol.zeno_time) - t_inf) / t_inf
    assert rel_t <= 1e-5 and rel_z <= 1e-4
    assert float(np.min(np.asarray(sol.impact_pre[:k, 0]))) >= -1e-7
    record("float32: ball impact times, max relative error", rel_t)
    record("float32: ball zeno_time relative error", rel_z)




def test_float32_rotation_with_wall():
    """x = (sin t, cos t) reflected at x1 = −1/2: impacts at 7π/6 + 4πm/3·... (closed form
    chain: each flight between impacts is the arc from x2 = +√3/2 to x2 = −√3/2)."""
    run = runner(ROTATION_WALL, "default", max_impacts=20, allow_float32=True)
    sol = run(jnp.array([0.0, 1.0], jnp.float32), jnp.float32(0.0), jnp.float32(30.0),
              {"c": jnp.float32(0.5)})
    assert sol.x_final.dtype == jnp.float32
    k = int(sol.num_impacts)
    # First impact at 7π/6; then each flight is the arc between x2 = +√3/2 and −√3/2
    # through x1 = 1: length 2π − 2·(π/3)... = 4π/3.
    exact = 7 * math.pi / 6 + 4 * math.pi / 3 * np.arange(k)
    exact = exact[exact < 30.0]
    assert k == len(exact) == 7
    rel_t = np.max(np.abs(np.asarray(sol.impact_times[:k], np.float64) - exact) / exact)
    assert rel_t <= 1e-5
    np.testing.assert_allclose(np.asarray(sol.impact_pre[:k, 1]), -math.sqrt(0.75), atol=1e-5)
    record("float32: rotation impact times, max relative error", rel_t)
