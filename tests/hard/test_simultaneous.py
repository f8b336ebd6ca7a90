"""Simultaneous impacts: a particle in the unit box hitting a corner.

Two walls are reached at the same instant (to round-off: the start is computed as
corner − v·T in floating point, so the two landing times differ by a few ulps). Both resets
must be applied, once each, and since the two walls' laws act on different coordinates the
outcome must not depend on the order of the surfaces in the scene.
"""

import math

import jax
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import grazejax as gj

from ..helpers import unit_box
from ._common import EPS, f64, f64_args, record, status

ORDERS = {"forward": (0, 1, 2, 3), "reversed": (3, 2, 1, 0)}
BOXES = {name: unit_box(order) for name, order in ORDERS.items()}

_RUNNERS = {}


def _run(order, x0, t1, args):
    if order not in _RUNNERS:
        scene = BOXES[order]
        _RUNNERS[order] = jax.jit(
            lambda x0, t1, args: gj.simulate(scene, x0, 0.0, t1, args, direction=1, max_impacts=4,
                                             rtol=1e-12, atol=1e-12)
        )
    return _RUNNERS[order](x0, t1, args)


@settings(max_examples=20, deadline=None, derandomize=True)
@given(
    rx=st.floats(0.1, 1.0),
    ry=st.floats(0.1, 1.0),
    corner=st.sampled_from([(1, 1), (1, 0), (0, 1), (0, 0)]),
    angle=st.floats(0.1, math.pi / 2 - 0.1),
    speed=st.floats(0.1, 10.0),
    frac=st.floats(0.1, 0.9),
)
def test_corner_hit_applies_both_resets_in_any_order(rx, ry, corner, angle, speed, frac):
    sx, sy = (1 if c == 1 else -1 for c in corner)  # direction towards the corner
    v = np.array([sx * speed * math.cos(angle), sy * speed * math.sin(angle)])
    T = frac / speed  # |v_i| T < 1: the start lies inside the box
    x0 = np.array(corner, float) - v * T
    # Next wall after the corner: 1 / (r_i |v_i|) later along each axis; stop halfway.
    t1 = T + 0.5 * min(1 / (rx * abs(v[0])), 1 / (ry * abs(v[1])))
    args = f64_args(rx=rx, ry=ry)
    out = {}
    for order in ORDERS:
        sol = _run(order, f64([*x0, *v]), f64(t1), args)
        assert status(sol) == gj.Status.SUCCESS
        assert int(sol.num_impacts) == 2
        times = np.asarray(sol.impact_times[:2])
        np.testing.assert_allclose(times, T, rtol=0, atol=64 * EPS * t1 / speed + 1e-13)
        # Which walls fired (as wall ids, whatever their position in the scene).
        fired = sorted(ORDERS[order][i] for i in np.asarray(sol.impact_surface[:2]))
        expected = sorted([0 if corner[0] == 1 else 2, 1 if corner[1] == 1 else 3])
        assert fired == expected
        assert np.diff(np.asarray(sol.impact_surface[:2]))[0] > 0  # applied in scene order
        out[order] = np.asarray(sol.x_final)
    exact = np.concatenate([np.array(corner, float) + np.array([-rx * v[0], -ry * v[1]]) * (t1 - T),
                            [-rx * v[0], -ry * v[1]]])
    for order in ORDERS:
        np.testing.assert_allclose(out[order], exact, rtol=1e-12, atol=1e-12)
    diff = np.max(np.abs(out["forward"] - out["reversed"]))
    assert diff <= 1e-14 * max(1.0, speed)
    record("corner: |x_final - closed form| (max)", np.max(np.abs(out["forward"] - exact)))
    record("corner: forward vs reversed surface order", diff)
