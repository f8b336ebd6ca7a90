"""Derivatives of an orbit's diagnostics (monodromy, multipliers, impacts) and the second
derivatives of `simulate` they rest on, against closed forms and central differences.

The ball on a vibrating table (Φ = x − A sin ωt, v⁺ = ẇ − e(v − ẇ)) has a closed-form
period-1 orbit: flight time T = 2π/ω, take-off speed gT/2 relative to the ground, impact
phase φ with cos φ = c/Γ, c = π(1 − e)/(1 + e), Γ = Aω²/g (the stable one has sin φ > 0).
Its monodromy is U = F(T) S with the flight F(τ) = [[1, τ], [0, 1]] and the saltation
S = [[−e, 0], [−(1 + e)(g + ẅ)/(v⁻ − ẇ), −e]], v⁻ − ẇ = −gT/(1 + e), ẅ = −Γ g sin φ:
    tr U = −2e + (1 + e)²(1 − √(Γ² − c²)),  det U = e².
"""

import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex

TABLE = ex.vibrating_table()
G_ACC, OMEGA = 9.81, 2 * math.pi
PERIOD = 2 * math.pi / OMEGA


def table_args(gamma, e):
    return dict(g=G_ACC, e=e, A=gamma * G_ACC / OMEGA**2, omega=OMEGA)


def closed_trace(gamma, e):
    c = math.pi * (1 - e) / (1 + e)
    return -2 * e + (1 + e) ** 2 * (1 - math.sqrt(gamma**2 - c**2))


def closed_trace_derivatives(gamma, e):
    """∂ tr U/∂Γ and ∂ tr U/∂e, differentiated by hand."""
    c = math.pi * (1 - e) / (1 + e)
    s = math.sqrt(gamma**2 - c**2)
    dc_de = -2 * math.pi / (1 + e) ** 2
    d_gamma = -((1 + e) ** 2) * gamma / s
    d_e = -2 + 2 * (1 + e) * (1 - s) + (1 + e) ** 2 * c * dc_de / s
    return d_gamma, d_e


def apex_start(gamma, e):
    """(t0, x0): the orbit at the apex of its flight (v = 0, half a period after impact)."""
    phi = math.acos(math.pi * (1 - e) / (1 + e) / gamma)
    a = table_args(gamma, e)
    t_impact = phi / OMEGA
    height = a["A"] * math.sin(phi) + G_ACC * PERIOD**2 / 8
    return t_impact + PERIOD / 2, [height, 0.0]


T0, X0 = apex_start(1.3, 0.5)


def table_orbit(gamma, e, t0=T0, **kw):
    return gj.find_periodic_orbit(TABLE, X0, PERIOD, table_args(gamma, e), t0=t0,
                                  fixed_period=True, start_at_impact=False, num_impacts=1,
                                  rtol=1e-11, **kw)


def test_closed_form_derivatives_agree_with_central_differences():
    """The hand derivatives of the closed-form trace, checked a second way."""
    h = 1e-6
    d_gamma, d_e = closed_trace_derivatives(1.3, 0.5)
    fd_gamma = (closed_trace(1.3 + h, 0.5) - closed_trace(1.3 - h, 0.5)) / (2 * h)
    fd_e = (closed_trace(1.3, 0.5 + h) - closed_trace(1.3, 0.5 - h)) / (2 * h)
    np.testing.assert_allclose([d_gamma, d_e], [fd_gamma, fd_e], rtol=1e-8)


def test_monodromy_and_multiplier_derivatives_match_the_closed_form():
    """jacfwd of tr U and Re ρ in (Γ, e): the closed form's, not a silent 0 (they were 0)."""
    orbit = table_orbit(1.3, 0.5)
    assert int(orbit.status) == gj.OrbitStatus.SUCCESS, orbit.message
    np.testing.assert_allclose(float(jnp.trace(orbit.monodromy)), closed_trace(1.3, 0.5),
                               atol=1e-9)
    np.testing.assert_allclose(float(jnp.linalg.det(orbit.monodromy)), 0.25, atol=1e-9)

    def diagnostics(p):
        o = table_orbit(p[0], p[1])
        return jnp.stack([jnp.trace(o.monodromy), jnp.real(o.multipliers[0]),
                          jnp.abs(o.multipliers[0]), o.impact_times[0]])

    jac = np.asarray(jax.jacfwd(diagnostics)(jnp.array([1.3, 0.5])))
    d_gamma, d_e = closed_trace_derivatives(1.3, 0.5)
    # The orbit (and so its Jacobian) is accurate to ~rtol = 1e-11 relative; its
    # derivative in the parameters to a few times that.
    np.testing.assert_allclose(jac[0], [d_gamma, d_e], rtol=1e-8)
    # A complex pair: Re ρ = tr U / 2, |ρ| = √det U = e.
    np.testing.assert_allclose(jac[1], [d_gamma / 2, d_e / 2], rtol=1e-8)
    np.testing.assert_allclose(jac[2], [0.0, 1.0], atol=1e-8)
    # The impact time t* = φ/ω (mod T): ∂t*/∂Γ = c/(Γ² sin φ ω) (the closed-form phase).
    c = math.pi * 0.5 / 1.5
    phi = math.acos(c / 1.3)
    np.testing.assert_allclose(jac[3, 0], c / (1.3**2 * math.sin(phi) * OMEGA), rtol=1e-8)


@pytest.mark.slow
def test_multiplier_gradient_in_reverse_mode_equals_the_closed_form():
    """`jax.grad` through the orbit's adjoint (DirectAdjoint) gives the same derivative of
    the monodromy's trace as jacfwd and the closed form."""

    def trace(gamma):
        orbit = table_orbit(gamma, 0.5, adjoint=diffrax.DirectAdjoint())
        return jnp.trace(orbit.monodromy)

    np.testing.assert_allclose(jax.grad(trace)(1.3), closed_trace_derivatives(1.3, 0.5)[0],
                               rtol=1e-8)


def test_orbit_derivatives_in_the_start_time_and_the_residual():
    """x0 depends on t0 (a forced orbit's phase): its derivative is the flow's, f(t0, x0),
    not 0; the solve's residual has no meaningful derivative: NaN, not 0."""
    jac_t0 = jax.jacfwd(lambda t: table_orbit(1.3, 0.5, t0=t).x0)(T0)
    np.testing.assert_allclose(jac_t0, [0.0, -G_ACC], atol=1e-9)
    d_residual = jax.jacfwd(lambda g: table_orbit(g, 0.5).residual)(1.3)
    assert np.isnan(d_residual)


def test_fixed_period_carries_its_derivative():
    """A forced orbit's period given as a function of the parameter (T = 2π/ω): its
    derivative flows through T too (it was dropped: only args carried one)."""
    osc = ex.impact_oscillator()

    def args_of(omega):
        return ex.impact_oscillator_args(zeta=0.05, A=1.0, omega=omega, sigma=3.0, r=0.8)

    def x0_of(omega):
        # A non-impacting orbit: the linear response, in closed form.
        return gj.find_periodic_orbit(osc, ex.linear_response(0.0, args_of(0.8)),
                                      2 * math.pi / omega, args_of(omega), fixed_period=True,
                                      start_at_impact=False, num_impacts=0, rtol=1e-11).x0

    got = jax.jacfwd(x0_of)(0.8)
    h = 1e-6
    exact = (np.asarray(ex.linear_response(0.0, args_of(0.8 + h)))
             - np.asarray(ex.linear_response(0.0, args_of(0.8 - h)))) / (2 * h)
    np.testing.assert_allclose(got, exact, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("scene_name", ["table", pytest.param("ball", marks=pytest.mark.slow)])
def test_second_derivatives_through_impacts(scene_name):
    """∂²/∂p∂x of the final state across impacts (moving and fixed walls): the event
    time's one Newton step carries first derivatives only; the curvature terms make
    second derivatives right. Against central differences of the first derivative."""
    if scene_name == "table":
        scene, t0, t1 = TABLE, T0, T0 + 1.0
        x0 = jnp.asarray(X0)

        def args_of(p):
            return table_args(p, 0.5)
        p0 = 1.3
    else:
        scene, t0, t1 = ex.bouncing_ball(), 0.0, 2.5
        x0 = jnp.array([1.0, 0.3])

        def args_of(p):
            return dict(g=9.81, e=p)
        p0 = 0.8

    def end(x, p):
        sol = gj.simulate(scene, x, t0, t1, args_of(p), rtol=1e-12, atol=1e-12)
        return jnp.concatenate([sol.x_final, sol.impact_times[:1]])

    def jac_x(x, p):
        return jax.jacfwd(end)(x, p)

    sol = gj.simulate(scene, x0, t0, t1, args_of(p0), rtol=1e-12, atol=1e-12)
    assert int(sol.num_impacts) >= 1
    mixed = np.asarray(jax.jacfwd(jac_x, argnums=1)(x0, p0))
    pure = np.asarray(jax.jacfwd(jac_x)(x0, p0))
    h = 1e-5
    fd_mixed = (np.asarray(jac_x(x0, p0 + h)) - np.asarray(jac_x(x0, p0 - h))) / (2 * h)
    fd_pure = np.stack([(np.asarray(jac_x(x0 + h * e, p0)) - np.asarray(jac_x(x0 - h * e, p0)))
                        / (2 * h) for e in jnp.eye(2)], axis=-1)
    # Central differences of a first derivative accurate to ~1e-11: truncation h² ~ 1e-10
    # times the third derivative, rounding ~1e-11/h = 1e-6.
    np.testing.assert_allclose(mixed, fd_mixed, atol=1e-5 * max(1.0, np.max(np.abs(fd_mixed))))
    np.testing.assert_allclose(pure, fd_pure, atol=1e-5 * max(1.0, np.max(np.abs(fd_pure))))
