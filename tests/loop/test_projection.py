"""`Scene.project` in the loop: the step after a projected step starts from the projected
state with the field evaluated there, not with the FSAL stage of the unprojected end."""

from typing import ClassVar

import diffrax
import jax.numpy as jnp
import numpy as np

import grazejax as gj
from grazejax._loop.unrolled import UnrolledERK

from ..helpers import clockwise, projected_circle_scene


class FreshFirstStage(diffrax.AbstractAdaptiveSolver):
    """An FSAL method that never reuses its last stage: every step evaluates its first
    stage at the state it starts from (as after a jump)."""

    inner: UnrolledERK
    term_structure: ClassVar = diffrax.AbstractTerm

    @property
    def interpolation_cls(self):
        return self.inner.interpolation_cls

    @property
    def end_stage(self):
        return self.inner.end_stage

    def order(self, terms):
        return self.inner.order(terms)

    def error_order(self, terms):
        return self.inner.error_order(terms)

    def init(self, terms, t0, t1, y0, args):
        return self.inner.init(terms, t0, t1, y0, args)

    def func(self, terms, t0, y0, args):
        return self.inner.func(terms, t0, y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        return self.inner.step(terms, t0, t1, y0, args, solver_state, True)


def test_the_step_after_a_projection_evaluates_its_first_stage():
    """Tsit5 (FSAL) on the kicked circle, at a loose tolerance so that each step's end is
    moved by the projection well above round-off: the run equals, to round-off, the same
    method with its first stage evaluated afresh at every step. (The stored stage, taken at
    the unprojected end, moves the impact time by ~1e-9 here.)"""
    scene = projected_circle_scene()
    theta0, t1, alpha = 1.0, 4.0, 0.3
    x0 = jnp.array([np.cos(theta0), np.sin(theta0)])
    args = {"alpha": jnp.asarray(alpha)}
    loose = dict(rtol=1e-6, atol=1e-6)
    fsal = gj.simulate(scene, x0, 0.0, t1, args, **loose)
    fresh = gj.simulate(scene, x0, 0.0, t1, args,
                        solver=FreshFirstStage(UnrolledERK(diffrax.Tsit5())), **loose)
    for sol in (fsal, fresh):
        assert gj.Status(int(sol.status)) == gj.Status.SUCCESS and int(sol.num_impacts) == 1
        # on the circle to round-off, and on its closed form to the tolerance
        assert abs(float(jnp.linalg.norm(sol.x_final)) - 1.0) <= 4 * np.finfo(float).eps
        np.testing.assert_allclose(sol.x_final, clockwise(t1 + alpha) @ np.asarray(x0),
                                   atol=1e-5)
    assert int(fsal.num_steps) == int(fresh.num_steps)
    np.testing.assert_allclose(fsal.impact_times[0], fresh.impact_times[0], rtol=1e-14)
    np.testing.assert_allclose(fsal.x_final, fresh.x_final, rtol=0, atol=1e-14)
