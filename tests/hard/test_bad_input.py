"""Bad input inside jit/vmap: per-lane statuses, never a poisoned batch.

tests/test_validation.py covers the checks that raise before compilation; this adds what
happens to traced values: NaN parameters and NaN-producing jumps in one lane of a batch,
and backward runs through a jump that has no inverse.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex

from ._common import f64, f64_args, runner, status


def _ball_field(t, x, a):
    return jnp.stack([x[1], -a["g"] * jnp.ones_like(x[0])])


# A ball whose floor law breaks (NaN) above the impact speed vmax.
FRAGILE_BALL = gj.Scene(
    _ball_field,
    [
        gj.Surface(
            phi=lambda t, x, a: x[0],
            jump=lambda t, x, a: x.at[1].set(jnp.where(jnp.abs(x[1]) > a["vmax"], jnp.nan, -a["e"] * x[1])),
        )
    ],
)
# A floor that stops the ball dead (v → e·v with e = 0): J is not invertible.
STICKY_FLOOR = gj.Scene(
    _ball_field,
    [gj.Surface(phi=lambda t, x, a: x[0], jump=lambda t, x, a: x.at[1].set(a["e"] * x[1]))],
)


def _ball_state(h0, v0, g, e, t):
    """Closed-form state of a bouncing ball at time t (no Zeno before t), and the count."""
    times, _ = ex.bouncing_ball_impact_times(h0, v0, g, e, 50)
    k = int(np.searchsorted(times, t))
    if k == 0:
        return np.array([h0 + v0 * t - g * t * t / 2, v0 - g * t]), 0
    w = math.sqrt(v0 * v0 + 2 * g * h0)
    v_up = e**k * w  # take-off speed after the k-th impact
    s = t - times[k - 1]
    return np.array([v_up * s - g * s * s / 2, v_up - g * s]), k


def test_nan_args_and_nan_jumps_stay_in_their_lane():
    """Lanes: normal, e = NaN (bad parameter), a drop fast enough to make the jump NaN,
    normal. The bad lanes end NONFINITE with finite last states; the others reach t1 with
    the closed-form state."""
    g, vmax, t1 = 9.81, 5.0, 1.0
    x0s = f64([[1.0, 0.0], [1.0, 0.0], [2.0, 0.0], [0.5, 1.0]])
    es = f64([0.8, np.nan, 0.8, 0.5])
    single = runner(FRAGILE_BALL, "tight", max_impacts=20)
    batched = jax.jit(jax.vmap(single, in_axes=(0, None, None, {"g": None, "e": 0, "vmax": None})))
    args = {"g": f64(g), "e": es, "vmax": f64(vmax)}
    batch = batched(x0s, f64(0.0), f64(t1), args)
    statuses = [gj.Status(int(s)) for s in batch.status]
    assert statuses[1] == gj.Status.NONFINITE and int(batch.num_impacts[1]) == 0
    assert statuses[2] == gj.Status.NONFINITE and int(batch.num_impacts[2]) == 1
    # The NaN jump lane stops at its first impact, at the exact time, with the pre state.
    t_hit = math.sqrt(2 * 2.0 / g)
    assert abs(float(batch.t_final[2]) - t_hit) < 1e-12
    np.testing.assert_allclose(batch.x_final[2], [0.0, -g * t_hit], atol=1e-10)
    assert np.all(np.isfinite(np.asarray(batch.x_final)))
    for i in (0, 3):
        h0, v0 = np.asarray(x0s[i])
        exact, k = _ball_state(h0, v0, g, float(es[i]), t1)
        assert statuses[i] == gj.Status.SUCCESS
        assert int(batch.num_impacts[i]) == k >= 1
        np.testing.assert_allclose(batch.x_final[i], exact, rtol=0, atol=1e-11)
        times, _ = ex.bouncing_ball_impact_times(h0, v0, g, float(es[i]), k)
        np.testing.assert_allclose(batch.impact_times[i, :k], times, atol=1e-11)


def _nan_t1_run():
    return runner("ball", "tight", max_impacts=1000)(
        f64([1.0, 0.0]), f64(0.0), f64(np.nan), f64_args(g=9.81, e=0.8)
    )


def test_nan_end_time_inside_jit_is_not_a_success():
    """t1 = NaN, traced (outside jit it raises): the run must not report success."""
    sol = _nan_t1_run()
    assert status(sol) != gj.Status.SUCCESS
    assert np.all(np.isfinite(np.asarray(sol.x_final)))


def test_nan_end_time_inside_jit_is_nonfinite_at_once():
    sol = _nan_t1_run()
    assert status(sol) == gj.Status.NONFINITE
    assert int(sol.num_steps) <= 1


def test_backward_batch_with_a_non_invertible_lane_keeps_the_other_lanes():
    """Lane 0: v → −0.5 v (invertible); lane 1: v → 0 (not). Backward from (0.5, 3) at
    t = 1 to t = 0."""
    g = 9.81
    single = runner(STICKY_FLOOR, "tight", max_impacts=10, direction=-1)
    batched = jax.jit(jax.vmap(single, in_axes=(0, None, None, {"g": None, "e": 0})))
    x0s = f64([[0.5, 3.0], [0.5, 3.0]])
    batch = batched(x0s, f64(1.0), f64(0.0), {"g": f64(g), "e": f64([-0.5, 0.0])})
    # Lane 0, closed form: backward flight to x = 0, met at s = (w − 3)/g with the
    # post-impact velocity w = √(9 + g); the inverse jump v → v / (−0.5); then the
    # backward flight over the remaining r = 1 − s.
    w = math.sqrt(9.0 + g)
    s = (w - 3.0) / g
    v_before = w / -0.5
    r = 1.0 - s  # time left backward
    x_end = 0.0 - v_before * r - g * r * r / 2
    assert int(batch.num_impacts[0]) == 1
    np.testing.assert_allclose(batch.x_final[0], [x_end, v_before + g * r], rtol=1e-9)
    assert gj.Status(int(batch.status[1])) != gj.Status.SUCCESS or int(batch.num_impacts[1]) == 0


def test_zeno_option_is_checked():
    scene, args = ex.bouncing_ball(), {"g": 9.81, "e": 0.5}
    with pytest.raises(ValueError, match="zeno must be 'stop' or 'stick'"):
        gj.simulate(scene, [1.0, 0.0], 0.0, 1.0, args, zeno="slide")
    with pytest.raises(ValueError, match="forward time only"):
        gj.simulate(scene, [1.0, 0.0], 1.0, 0.0, args, zeno="stick")


def test_sliding_on_two_surfaces_at_once_ends_zeno():
    """A ball at rest in a corner (floor and a slanted wall, both pushing back): there is
    no rule for sliding on two surfaces, so zeno="stick" ends ZENO at t0 instead of
    tunnelling through either."""
    def field(t, x, a):
        return jnp.stack([x[2], x[3], jnp.zeros_like(x[2]) + a["gx"], jnp.zeros_like(x[3]) - a["g"]])

    def bounce(normal):
        def jump(t, x, a):
            n = jnp.asarray(normal, x.dtype) / math.hypot(*normal)
            v = x[2:]
            return jnp.concatenate([x[:2], v - 1.5 * jnp.dot(v, n) * n])
        return jump

    corner = gj.Scene(field, [
        gj.Surface(phi=lambda t, x, a: x[1], jump=bounce((0.0, 1.0)), name="floor"),
        gj.Surface(phi=lambda t, x, a: x[0], jump=bounce((1.0, 0.0)), name="wall"),
    ])
    sol = gj.simulate(corner, [0.0, 0.0, 0.0, 0.0], 0.0, 1.0, {"g": 9.81, "gx": -1.0}, zeno="stick")
    assert status(sol) == gj.Status.ZENO and float(sol.t_final) == 0.0
