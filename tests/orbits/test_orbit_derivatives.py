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


def x0_closed(omega, gamma=1.3, e=0.5, t0=T0):
    """The orbit's state at the phase t0 when the table's frequency is ω (Γ fixed, so
    A = Γg/ω² and the impact phase φ stay; T = 2π/ω): a flight x = A sin φ + (gT/2)s − gs²/2,
    s = t0 − φ/ω the time since the impact."""
    phi = math.acos(math.pi * (1 - e) / (1 + e) / gamma)
    period = 2 * math.pi / omega
    s = t0 - phi / omega
    amplitude = gamma * G_ACC / omega**2
    return np.array([amplitude * math.sin(phi) + G_ACC * period * s / 2 - G_ACC * s * s / 2,
                     G_ACC * period / 2 - G_ACC * s])


def test_closed_form_start_state_is_the_apex_start():
    np.testing.assert_allclose(x0_closed(OMEGA), X0, rtol=1e-14, atol=1e-14)


@pytest.fixture(scope="module")
def table_jacobian():
    """One `jax.jacfwd` of the table's orbit in p = (Γ, e, t0, ω), the period a function
    of ω (T = 2π/ω, `fixed_period`), for the three tests below: one traced and compiled
    program instead of one per test (78-138 s of CPU each, cold), and the orbit itself (the aux
    output) from the same program. Rows: tr U, Re ρ₀, |ρ₀|, the impact time, x0 (two),
    the residual. Columns: ∂/∂Γ, ∂/∂e, ∂/∂t0, ∂/∂ω."""

    def diagnostics(p):
        gamma, e, t0, omega = p[0], p[1], p[2], p[3]
        args = dict(g=G_ACC, e=e, A=gamma * G_ACC / omega**2, omega=omega)
        o = gj.find_periodic_orbit(TABLE, X0, 2 * jnp.pi / omega, args, t0=t0,
                                   fixed_period=True, start_at_impact=False, num_impacts=1,
                                   rtol=1e-11)
        rows = jnp.stack([jnp.trace(o.monodromy), jnp.real(o.multipliers[0]),
                          jnp.abs(o.multipliers[0]), o.impact_times[0]])
        return jnp.concatenate([rows, o.x0, o.residual[None]]), (o.status, o.monodromy)

    jac, (status, monodromy) = jax.jacfwd(diagnostics, has_aux=True)(
        jnp.array([1.3, 0.5, T0, OMEGA]))
    return np.asarray(jac), int(status), np.asarray(monodromy)


def test_monodromy_and_multiplier_derivatives_match_the_closed_form(table_jacobian):
    """jacfwd of tr U and Re ρ in (Γ, e): the closed form's, not a silent 0 (they were 0)."""
    jac, status, monodromy = table_jacobian
    assert status == gj.OrbitStatus.SUCCESS
    np.testing.assert_allclose(float(np.trace(monodromy)), closed_trace(1.3, 0.5), atol=1e-9)
    np.testing.assert_allclose(float(np.linalg.det(monodromy)), 0.25, atol=1e-9)
    d_gamma, d_e = closed_trace_derivatives(1.3, 0.5)
    # The orbit (and so its Jacobian) is accurate to ~rtol = 1e-11 relative; its
    # derivative in the parameters to a few times that.
    np.testing.assert_allclose(jac[0, :2], [d_gamma, d_e], rtol=1e-8)
    # A complex pair: Re ρ = tr U / 2, |ρ| = √det U = e.
    np.testing.assert_allclose(jac[1, :2], [d_gamma / 2, d_e / 2], rtol=1e-8)
    np.testing.assert_allclose(jac[2, :2], [0.0, 1.0], atol=1e-8)
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


def test_orbit_derivatives_in_the_start_time_and_the_residual(table_jacobian):
    """x0 depends on t0 (a forced orbit's phase): its derivative is the flow's, f(t0, x0),
    not 0; the solve's residual has no meaningful derivative: NaN, not 0. (The columns
    ∂/∂t0 and ∂residual/∂Γ of the module's one Jacobian, with the other parameters' tangents
    alongside: the same derivative code as jacfwd in t0, or in Γ, alone.)"""
    jac, _, _ = table_jacobian
    np.testing.assert_allclose(jac[4:6, 2], [0.0, -G_ACC], atol=1e-9)
    assert np.isnan(jac[6, 0])


def test_fixed_period_carries_its_derivative(table_jacobian):
    """A forced orbit's period given as a function of the parameter (T = 2π/ω): its
    derivative flows through T too (it was dropped: only args carried one). The table's
    orbit at the phase t0 as a function of ω (column ∂/∂ω of the module's Jacobian; ω is
    in args and in T), against central differences of its closed form `x0_closed`. With
    T's tangent dropped the derivative is (−0.117, −2.057), not (−0.451, −0.938). (This
    was the impact oscillator's non-impacting orbit, one more program: 78 s of CPU.)"""
    jac, _, _ = table_jacobian
    h = 1e-6
    exact = (x0_closed(OMEGA + h) - x0_closed(OMEGA - h)) / (2 * h)
    np.testing.assert_allclose(jac[4:6, 3], exact, rtol=1e-6, atol=1e-8)


@pytest.mark.parametrize("scene_name", ["table", pytest.param("ball", marks=pytest.mark.slow)])
def test_second_derivatives_through_impacts(scene_name):
    """∂²/∂p∂x of the final state across impacts (moving and fixed walls): the event
    time's one Newton step carries first derivatives only; the curvature terms make
    second derivatives right. Against central differences of the first derivative.

    Both blocks (∂²/∂p∂x and ∂²/∂x²) come from one Hessian in z = (x, p), and the first
    derivative is one jitted program called at the seven points: outside `jit`, each
    call retraced and recompiled the impact loop (nine programs, now two). `simulate`
    runs the same traced loop inside `jit` as under a bare `jacfwd`."""
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

    def end(z):
        sol = gj.simulate(scene, z[:2], t0, t1, args_of(z[2]), rtol=1e-12, atol=1e-12)
        return jnp.concatenate([sol.x_final, sol.impact_times[:1]]), sol.num_impacts

    jac_z = jax.jacfwd(end, has_aux=True)  # (∂end/∂z, impacts)
    jac = jax.jit(lambda z: jac_z(z)[0])
    hessian, impacts = jax.jit(jax.jacfwd(jac_z, has_aux=True))(jnp.append(x0, p0))
    assert int(impacts) >= 1
    hessian = np.asarray(hessian)
    mixed, pure = hessian[:, :2, 2], hessian[:, :2, :2]
    h = 1e-5
    z0 = jnp.append(x0, p0)
    fd = np.stack([(np.asarray(jac(z0 + h * e)) - np.asarray(jac(z0 - h * e))) / (2 * h)
                   for e in jnp.eye(3)], axis=-1)
    fd_mixed, fd_pure = fd[:, :2, 2], fd[:, :2, :2]
    # Central differences of a first derivative accurate to ~1e-11: truncation h² ~ 1e-10
    # times the third derivative, rounding ~1e-11/h = 1e-6.
    np.testing.assert_allclose(mixed, fd_mixed, atol=1e-5 * max(1.0, np.max(np.abs(fd_mixed))))
    np.testing.assert_allclose(pure, fd_pure, atol=1e-5 * max(1.0, np.max(np.abs(fd_pure))))
