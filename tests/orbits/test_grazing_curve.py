"""Two-parameter continuation of grazing orbits, against closed forms and SciPy."""

import math

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex
from grazejax._orbits.forced_period import require_period_fixed_in

from .test_periodic import OSC, TOL

ZETA = 0.05  # the oscillator's field is x'' + 2ζx' + x = cos(ωt): x'' + 0.1x' + x


def _osc(omega, sigma):
    return ex.impact_oscillator_args(zeta=ZETA, A=1.0, omega=omega, sigma=sigma, r=0.8)


def _period(omega, sigma):
    return 2 * jnp.pi / omega


def _amplitude(omega):
    """The non-impacting response's amplitude A(ω): the grazing curve σ_graz(ω)."""
    return 1 / np.sqrt((1 - omega**2) ** 2 + (2 * ZETA * omega) ** 2)


@pytest.fixture(scope="module")
def free_orbit():
    """The non-impacting orbit at (ω, σ) = (0.8, 3.0), where every test here starts (it
    was solved again in each)."""
    omega, sigma = 0.8, 3.0  # the free response clears the stop by 0.29 here
    args = _osc(omega, sigma)
    orbit = gj.find_periodic_orbit(OSC, np.asarray(ex.linear_response(0.0, args)),
                                   2 * math.pi / omega, args, fixed_period=True, **TOL)
    assert int(orbit.status) == gj.OrbitStatus.SUCCESS
    return orbit


@pytest.fixture(scope="module")
def forced_curve(free_orbit):
    return gj.continue_grazing(OSC, free_orbit, _osc, 0.8, 3.0, 0.6, period_of=_period,
                               progress=False, **TOL)


def test_forced_oscillator_grazing_curve_matches_closed_form(forced_curve):
    """σ_graz(ω) = A(ω), the contact at the response's maximum (x, v) = (A, 0), at the
    phase ωt0 ≡ φ = atan2(2ζω, 1 − ω²) (mod 2π)."""
    curve = forced_curve
    assert gj.ContinuationStatus(curve.status) == gj.ContinuationStatus.REACHED_STOP
    assert curve.mu[0] == 0.8 and curve.mu[-1] == 0.6 and len(curve) >= 5
    assert np.all(np.diff(curve.mu) < 0)
    # The error budget: the fixed point of the period map inherits the one-period
    # integration error (≤ ~1e3 local errors of rtol·|x|, a generous step count),
    # amplified by ‖(I − M)⁻¹‖ ≤ 1/(1 − e^{−ζT}) (M = monodromy, |ρ| = e^{−ζT}); Newton's
    # own error (newton_tol = 1e-10, quadratic) is far below. With rtol = 1e-12,
    # |x| ≤ 2.8 and T ≤ 2π/0.6 this is ≤ 1e3 · 1e-12 · 2.8 · 3.1 ≈ 9e-9: tolerance 1e-8.
    T = 2 * np.pi / curve.mu
    bound = 1e3 * TOL["rtol"] * np.max(curve.nu) / (1 - np.exp(-ZETA * T))
    assert np.all(bound <= 1e-8)
    exact = _amplitude(curve.mu)
    np.testing.assert_allclose(curve.nu, exact, rtol=0, atol=1e-8)
    np.testing.assert_allclose(curve.x0[:, 0], exact, rtol=0, atol=1e-8)
    np.testing.assert_allclose(curve.x0[:, 1], 0.0, atol=1e-8)
    phase = np.arctan2(2 * ZETA * curve.mu, 1 - curve.mu**2)
    wrapped = np.angle(np.exp(1j * (curve.mu * curve.t0 - phase)))
    np.testing.assert_allclose(wrapped, 0.0, atol=1e-7)
    np.testing.assert_allclose(curve.period, T, rtol=1e-14)
    # A genuine graze: the gap has a minimum there (Φ̈ = A − cos(ωt0)... > 0) and the orbit
    # stays on the free side elsewhere; no impact.
    assert np.all(curve.curvature > 0) and np.all(curve.min_gap > -1e-8)
    assert np.all(curve.num_impacts == 0)


def test_forced_grazing_orbits_are_periodic_and_tangent_by_scipy(forced_curve):
    """Independently of grazejax's integrator: from each third point's contact, SciPy's
    DOP853 returns to the same state after one period, and x never exceeds σ."""
    from scipy.integrate import solve_ivp

    curve = forced_curve
    for i in range(0, len(curve), 3):
        omega, sigma, t0 = float(curve.mu[i]), float(curve.nu[i]), float(curve.t0[i])
        T = 2 * math.pi / omega

        def field(t, y, omega=omega):
            return [y[1], -2 * ZETA * y[1] - y[0] + math.cos(omega * t)]

        sol = solve_ivp(field, (t0, t0 + T), curve.x0[i], method="DOP853", rtol=1e-13,
                        atol=1e-14, dense_output=True)
        np.testing.assert_allclose(sol.y[:, -1], curve.x0[i], atol=1e-8)
        x = sol.sol(np.linspace(t0, t0 + T, 2001))[0]
        assert np.max(x) <= sigma + 1e-8 and abs(x[0] - sigma) <= 1e-8


def _ex1dof_wall():
    """ex1dof with its wall at x1 = w (args["w"]): Ψ_μ reaches x1 = −μ, so the orbit
    grazes the wall on the line w = −μ, period 2π (an autonomous closed form)."""
    base = ex.ex1dof()
    wall = gj.Surface(phi=lambda t, x, args: x[0] - args["w"], jump=base.surfaces[0].jump,
                      where=lambda t, x, args: x[1] <= 0)
    return gj.Scene(base.vector_field, [wall])


def _ex1dof_wall_args(mu, w):
    return dict(ex.ex1dof_args(mu), w=jnp.asarray(w, float))


@pytest.mark.slow
def test_autonomous_grazing_curve_matches_closed_form():
    scene = _ex1dof_wall()
    orbit = gj.find_periodic_orbit(scene, [1.7, 0.0], 6.28, _ex1dof_wall_args(-0.3, 0.0), fix=1,
                                   start_at_impact=False, **TOL)
    assert int(orbit.status) == gj.OrbitStatus.SUCCESS and int(orbit.num_impacts) == 0
    curve = gj.continue_grazing(scene, orbit, _ex1dof_wall_args, -0.3, 0.0, -0.1,
                                progress=False, **TOL)
    assert gj.ContinuationStatus(curve.status) == gj.ContinuationStatus.REACHED_STOP
    assert curve.mu[-1] == -0.1 and len(curve) >= 3
    # The cycle attracts weakly (1 − ρ = 1 − e^{−2πε(1+μ)²} ≥ 3e-4): the same budget as
    # above, 1e3 · rtol · |x| / (1 − ρ) ≤ 1e3 · 1e-12 · 2 / 3e-4 ≈ 7e-6.
    rho = np.exp(-2 * np.pi * 1e-4 * (1 + curve.mu) ** 2)
    bound = 1e3 * TOL["rtol"] * 2 / (1 - rho)
    np.testing.assert_array_less(np.abs(curve.nu + curve.mu), bound)
    np.testing.assert_array_less(np.abs(curve.period - 2 * np.pi), 10 * bound)
    np.testing.assert_allclose(curve.x0[:, 0], curve.nu, atol=1e-12)  # on the wall
    np.testing.assert_array_less(np.abs(curve.x0[:, 1]), bound)       # tangentially
    assert np.all(curve.curvature > 0)


def _grazing_amplitude(omega, zeta):
    """σ_graz = D^(−1/2), D = (1 − ω²)² + (2ζω)², and its derivatives in ω and ζ."""
    D = (1 - omega**2) ** 2 + (2 * zeta * omega) ** 2
    dD_domega = -4 * omega * (1 - omega**2) + 8 * zeta**2 * omega
    dD_dzeta = 8 * zeta * omega**2
    return D**-0.5, -0.5 * D**-1.5 * dD_domega, -0.5 * D**-1.5 * dD_dzeta


def test_grazing_closed_form_derivatives_two_ways():
    h = 1e-6
    for k, shift in ((1, (h, 0.0)), (2, (0.0, h))):
        plus = _grazing_amplitude(0.8 + shift[0], ZETA + shift[1])[0]
        minus = _grazing_amplitude(0.8 - shift[0], ZETA - shift[1])[0]
        np.testing.assert_allclose(_grazing_amplitude(0.8, ZETA)[k], (plus - minus) / (2 * h),
                                   rtol=1e-8)


@pytest.mark.parametrize("parameter", ["omega", "zeta"])
def test_located_grazing_amplitude_and_its_derivatives(parameter, free_orbit):
    """`locate_grazing` solves σ_graz at ν = ω or ζ (μ = σ) and `jax.jacfwd` differentiates
    it by the implicit function theorem: both against the closed form. The point (the aux
    output) and its derivative come from one `jacfwd`: one compiled program, where a
    plain solve first compiled another. The start is `free_orbit`: at (ω, ζ, σ) =
    (0.8, ζ, 3.0) both parameters' starts are that orbit."""
    omega, zeta = 0.8, ZETA

    def args_of(sigma, nu):
        if parameter == "omega":
            return ex.impact_oscillator_args(zeta=zeta, A=1.0, omega=nu, sigma=sigma, r=0.8)
        return ex.impact_oscillator_args(zeta=nu, A=1.0, omega=omega, sigma=sigma, r=0.8)

    def period_of(sigma, nu):
        return 2 * jnp.pi / (nu if parameter == "omega" else omega)

    nu = omega if parameter == "omega" else zeta
    orbit = free_orbit

    def located(n):
        point = gj.locate_grazing(OSC, orbit, args_of, n, mu=3.0, nu_guess=nu,
                                  period_of=period_of, **TOL)
        return point.mu, point

    sigma, d_omega, d_zeta = _grazing_amplitude(omega, zeta)
    derivative, point = jax.jacfwd(located, has_aux=True)(nu)
    assert point.message == "SUCCESS" and point.kind == "grazing"
    # Newton's tolerance 1e-10 relative, converged quadratically: the fixed point's own
    # accuracy (rtol 1e-12, see the curve tests) is what is left.
    assert abs(float(point.mu) - sigma) < 1e-9
    assert abs(float(point.test_value)) < 1e-9 and int(point.num_impacts) == 0
    np.testing.assert_allclose(np.asarray(point.x0), [sigma, 0.0], atol=1e-9)
    np.testing.assert_allclose(float(derivative), d_omega if parameter == "omega" else d_zeta,
                               rtol=1e-8)
    with pytest.raises(ValueError, match="nu_guess"):
        jax.jacfwd(lambda n: gj.locate_grazing(OSC, orbit, args_of, n, mu=3.0).mu)(nu)


def test_grazing_is_a_kind_of_bifurcation_point_and_curve(forced_curve, free_orbit):
    """`locate_bifurcation` and `continue_bifurcation` take grazing points too: with μ = σ
    and ν = ω, the located point is σ_graz(ω), and the curve followed in ω is
    `continue_grazing`'s (the fixture, in (ω, σ)) with the parameters' roles swapped."""
    omega, sigma = 0.8, 3.0
    args = _osc(omega, sigma)
    orbit = free_orbit
    contacts = gj.orbit_contacts(OSC, orbit, args, max_depth=math.inf, **TOL)
    m = int(np.argmin(np.abs(np.asarray(contacts.depth))))
    point = gj.GrazingPoint(mu=sigma, orbit=orbit, surface=int(contacts.surfaces[m]),
                            time=float(contacts.times[m]), point=np.asarray(contacts.points[m]),
                            depth=float(contacts.depth[m]), impacts_before=0, impacts_after=1,
                            kind="persistence")

    def args_of(s, w):
        return _osc(w, s)

    def period_of(s, w):
        return 2 * jnp.pi / w

    located = gj.locate_bifurcation(OSC, point, args_of, omega, period_of=period_of, **TOL)
    assert located.kind == "grazing" and located.message == "SUCCESS"
    # Without period_of the period would stay the guess's while ν = ω moves: the solve
    # would answer another problem (dσ/dω = 3.34 where the closed form gives 11.3), so it
    # is refused with the fix; so is an adjoint Newton's method cannot run.
    with pytest.raises(ValueError, match=r"period_of=lambda mu, nu"):
        gj.locate_bifurcation(OSC, point, args_of, omega, **TOL)
    with pytest.raises(ValueError, match=r"locate_grazing.*DirectAdjoint"):
        gj.locate_bifurcation(OSC, point, args_of, omega, period_of=period_of,
                              adjoint=diffrax.RecursiveCheckpointAdjoint(), **TOL)
    assert abs(float(located.mu) - _amplitude(omega)) < 1e-9
    direct = gj.locate_grazing(OSC, point, args_of, omega, period_of=period_of,
                               newton_tol=1e-9, **TOL)
    assert float(located.mu) == float(direct.mu)

    curve = gj.continue_bifurcation(OSC, orbit, args_of, sigma, omega, 0.6, kind="grazing",
                                    period_of=period_of, progress=False, newton_tol=1e-10,
                                    max_newton_steps=10, **TOL)
    assert isinstance(curve, gj.GrazingCurve) and curve.status == forced_curve.status
    np.testing.assert_array_equal(curve.nu, forced_curve.mu)
    np.testing.assert_array_equal(curve.mu, forced_curve.nu)
    np.testing.assert_array_equal(curve.x0, forced_curve.x0)


def test_a_period_held_fixed_is_checked_against_the_moving_parameter(free_orbit):
    """The forced period held fixed is refused where the parameter moves it (ω), with the fix,
    and accepted where it does not (σ moves the stop, A the forcing's amplitude)."""
    with pytest.raises(ValueError, match=r"continue_orbit.*period_of=lambda mu"):
        gj.continue_orbit(OSC, free_orbit, lambda w: _osc(w, 3.0), 0.8, 0.7, progress=False)
    for args_at in (lambda s: _osc(0.8, s),
                    lambda a: ex.impact_oscillator_args(zeta=ZETA, A=a, omega=0.8, sigma=3.0,
                                                        r=0.8)):
        require_period_fixed_in(OSC, args_at, 1.5, free_orbit.t0, free_orbit.x0,
                                free_orbit.period, caller="test", parameter="p", fix="")
