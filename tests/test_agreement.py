"""`classify_point` and the simulator must both agree with the contact's true kind.

Seeded random starts on each example scene are simulated; at every logged impact the
pre-impact state's kind (α, β, γ) is decided here, independently of grazejax's contact
geometry (which `classify_point` and the simulator share, so comparing them with each
other would let a wrong shared verdict pass): from the scene's own functions, the gap's
rate Φ̇ = ∂Φ/∂t + ∇Φ·f and curvature Φ̈ along the flow give the depth Φ̇²/(2|Φ̈|) of the
parabola's dip through the point, and `where` probed across the point gives the boundary.
A contact is decided only outside a band around the criteria (a dip deeper than 1e-9, far
above the solver's 1e-10 errors, is transversal; the boundary is probed at 1e-10·(1 + |x|)),
and both the logged kind and `classify_point`'s must be the decided one. Exact
tangencies (free-fall parabolas whose minimum touches the floor exactly) are γ by
construction: both must say γ. A point moved off the surface by 1e3 contact floors along
∇Φ must be on neither Γ nor Γ̃ for the ball. Counted disagreements must be 0.
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


# A dip deeper than this (in Φ's units: the examples' gaps are O(1)) is a transversal
# contact: 1e5 contact floors, 10x the solver tolerance of the runs below.
TRANSVERSAL_DEPTH = 1e-9
# A logged contact point lies on its surface to the run's accuracy.
ON_SURFACE = 1e-8


def _true_kind(scene, i, t, x, args):
    """The contact's kind from the scene's own functions (not grazejax's geometry), or None
    if it is within the band where transversal and tangential are not told apart."""
    surface, x = scene.surfaces[i], jnp.asarray(x)
    t = jnp.asarray(t, x.dtype)

    def rate(t_, x_):  # Φ̇ = ∂Φ/∂t + ∇Φ·f
        return jax.jvp(lambda s, y: surface.phi(s, y, args), (t_, x_),
                       (jnp.ones_like(t_), scene.vector_field(t_, x_, args)))[1]

    gap = float(surface.phi(t, x, args))
    assert abs(gap) < ON_SURFACE, (gap, x)
    v = float(rate(t, x))
    a = float(jax.jvp(rate, (t, x), (jnp.ones_like(t), scene.vector_field(t, x, args)))[1])
    if surface.where is not None:
        step = 1e-10 * (1 + float(jnp.max(jnp.abs(x))))
        inside = bool(surface.where(t, x, args))
        moved = [bool(surface.where(t, x.at[k].add(sign * step), args))
                 for k in range(x.shape[0]) for sign in (1.0, -1.0)]
        if any(m != inside for m in moved):
            return gj.ImpactKind.BETA if v * v > 2 * abs(a) * TRANSVERSAL_DEPTH else None
    if v * v > 2 * abs(a) * TRANSVERSAL_DEPTH or (a == 0 and v != 0):
        return gj.ImpactKind.ALPHA
    return None  # near-tangential: not decided here (the exact tangencies test γ)


def _disagreements(scene, args, x0s, t1):
    bad, checked, undecided = [], 0, 0
    run = jax.jit(jax.vmap(lambda x0: gj.simulate(scene, x0, 0.0, t1, args, rtol=1e-10,
                                                  atol=1e-12, max_impacts=20, direction=1)))
    sol = run(jnp.asarray(x0s))
    for lane in range(len(x0s)):
        for k in range(int(sol.num_impacts[lane])):
            logged = int(sol.impact_kind[lane, k])
            if logged not in (gj.ImpactKind.ALPHA, gj.ImpactKind.BETA, gj.ImpactKind.GAMMA):
                continue  # STICK/RELEASE rows are not contacts of the free flow
            i, t = int(sol.impact_surface[lane, k]), float(sol.impact_times[lane, k])
            truth = _true_kind(scene, i, t, sol.impact_pre[lane, k], args)
            if truth is None:
                undecided += 1
                continue
            point = gj.classify_point(scene, i, t, sol.impact_pre[lane, k], args)
            checked += 1
            if int(point.kind) != truth or logged != truth:
                bad.append((lane, k, truth.name, gj.ImpactKind(logged).name,
                            gj.ImpactKind(int(point.kind)).name))
    return bad, checked, undecided


def test_classify_point_agrees_with_the_simulator_on_random_runs():
    rng = np.random.default_rng(12)
    total = 0
    for name, scene, args, (lo, hi), t1 in CASES:
        x0s = rng.uniform(lo, hi, size=(6, 2))
        bad, checked, undecided = _disagreements(scene, args, x0s, t1)
        assert bad == [], (name, bad)
        assert undecided == 0, name  # random starts meet their surfaces transversally
        total += checked
    assert total >= 40  # the campaign looked at enough impacts to mean something


def test_exact_tangencies_are_gamma_for_both():
    """x = h + v0 t + t²/2 with v0² = 2h: the minimum touches Φ = x = 0 exactly."""
    scene = free_fall_scene(0.8)
    x0s = np.array([[0.5, -1.0], [0.125, -0.5], [2.0, -2.0], [0.03125, -0.25]])
    args = {"a": 1.0}
    run = jax.jit(jax.vmap(lambda x0: gj.simulate(scene, x0, 0.0, 3.0, args, rtol=1e-10,
                                                  atol=1e-12, max_impacts=20, direction=1)))
    sol = run(jnp.asarray(x0s))
    for lane, (_, v0) in enumerate(x0s):
        # The truth by construction: a tangency at t = −v0, at x = (0, 0).
        assert int(sol.num_impacts[lane]) >= 1
        assert int(sol.impact_kind[lane, 0]) == gj.ImpactKind.GAMMA, lane
        np.testing.assert_allclose(float(sol.impact_times[lane, 0]), -v0, atol=1e-6)
        pre = sol.impact_pre[lane, 0]
        assert _true_kind(scene, 0, float(sol.impact_times[lane, 0]), pre, args) is None
        point = gj.classify_point(scene, 0, float(sol.impact_times[lane, 0]), pre, args)
        assert int(point.kind) == gj.ImpactKind.GAMMA, lane
    sol = gj.simulate(scene, jnp.asarray(x0s[0]), 0.0, 3.0, args)
    assert int(sol.impact_kind[0]) == gj.ImpactKind.GAMMA


def test_points_off_the_surface_are_on_neither():
    scene, args = ex.bouncing_ball(), {"g": 9.81, "e": 0.8}
    eps = float(np.finfo(float).eps)
    for h in (1e3 * 64 * eps, -1e3 * 64 * eps):
        point = gj.classify_point(scene, 0, 0.0, [h, -1.0], args)
        assert int(point.kind) == gj.ImpactKind.NONE and not bool(point.on_surface)
