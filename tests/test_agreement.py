"""`classify_point` and the simulator share one contact geometry: they must agree.

Seeded random starts on each example scene are simulated; at every logged impact the
pre-impact state is classified by `classify_point` on the logged surface, and its kind
(α, β, γ) must be the one the simulator logged. Exact tangencies (free-fall parabolas
whose minimum touches the floor exactly) are included: both must say γ. A point moved off
the surface by 1e3 contact floors along ∇Φ must be on neither Γ nor Γ̃ for the ball.
Counted disagreements must be 0.
"""

import jax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
from grazejax import examples as ex

from .helpers import free_fall_scene

CASES = [
    # name, scene, args, box of starts (lo, hi), t1
    ("ball", ex.bouncing_ball(), {"g": 9.81, "e": 0.8}, ([0.2, -1.0], [2.0, 1.0]), 3.0),
    ("oscillator", ex.impact_oscillator(), ex.impact_oscillator_args(), ([-0.5, -1.0], [0.1, 1.0]), 25.0),
    ("ex1dof", ex.ex1dof(), ex.ex1dof_args(0.2), ([0.3, 0.8], [0.8, 1.4]), 20.0),
    ("orbex2", ex.orbex2(), ex.orbex2_args(), ([0.5, 0.8], [0.9, 1.3]), 10.0),
]


def _disagreements(scene, args, x0s, t1):
    bad, checked = [], 0
    run = jax.jit(jax.vmap(lambda x0: gj.simulate(scene, x0, 0.0, t1, args, rtol=1e-10,
                                                  atol=1e-12, max_impacts=20, direction=1)))
    sol = run(jnp.asarray(x0s))
    for lane in range(len(x0s)):
        for k in range(int(sol.num_impacts[lane])):
            logged = int(sol.impact_kind[lane, k])
            if logged not in (gj.ImpactKind.ALPHA, gj.ImpactKind.BETA, gj.ImpactKind.GAMMA):
                continue  # STICK/RELEASE rows are not contacts of the free flow
            i, t = int(sol.impact_surface[lane, k]), float(sol.impact_times[lane, k])
            point = gj.classify_point(scene, i, t, sol.impact_pre[lane, k], args)
            checked += 1
            if int(point.kind) != logged:
                bad.append((lane, k, gj.ImpactKind(logged).name, gj.ImpactKind(int(point.kind)).name))
    return bad, checked


def test_classify_point_agrees_with_the_simulator_on_random_runs():
    rng = np.random.default_rng(12)
    total = 0
    for name, scene, args, (lo, hi), t1 in CASES:
        x0s = rng.uniform(lo, hi, size=(6, 2))
        bad, checked = _disagreements(scene, args, x0s, t1)
        assert bad == [], (name, bad)
        total += checked
    assert total >= 40  # the campaign looked at enough impacts to mean something


def test_exact_tangencies_are_gamma_for_both():
    """x = h + v0 t + t²/2 with v0² = 2h: the minimum touches Φ = x = 0 exactly."""
    scene = free_fall_scene(0.8)
    x0s = np.array([[0.5, -1.0], [0.125, -0.5], [2.0, -2.0], [0.03125, -0.25]])
    bad, checked = _disagreements(scene, {"a": 1.0}, x0s, 3.0)
    assert checked == 4 and bad == []
    sol = gj.simulate(scene, jnp.asarray(x0s[0]), 0.0, 3.0, {"a": 1.0})
    assert int(sol.impact_kind[0]) == gj.ImpactKind.GAMMA


def test_points_off_the_surface_are_on_neither():
    scene, args = ex.bouncing_ball(), {"g": 9.81, "e": 0.8}
    eps = float(np.finfo(float).eps)
    for h in (1e3 * 64 * eps, -1e3 * 64 * eps):
        point = gj.classify_point(scene, 0, 0.0, [h, -1.0], args)
        assert int(point.kind) == gj.ImpactKind.NONE and not bool(point.on_surface)
