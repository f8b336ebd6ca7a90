"""Periodic orbits: closed forms, the (A6) matrix, Floquet multipliers, grazing branches.

Every test shares one scene object per system and one set of tolerances, so that each
compiled period map is built once for the whole module.
"""

import math

import diffrax
import jax
import jax.extend
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

import grazejax as gj
from grazejax import examples as ex
from grazejax._orbits.contacts import grazing_branches, orbit_contacts
from grazejax._orbits.floquet import floquet_multipliers, product_eigenvalues, saltation
from grazejax._orbits.periodic import OrbitStatus, eigvals_sorted, find_periodic_orbit

from ..helpers import central_differences

EX1DOF = ex.ex1dof()
EPS = 1e-4
TOL = dict(rtol=1e-12, atol=1e-13)  # one set for all ex1dof solves: one compiled program
OSC = ex.impact_oscillator()


def osc_args(sigma, omega=0.5, zeta=0.05, A=1.0, r=0.8):
    return ex.impact_oscillator_args(zeta=zeta, A=A, omega=omega, sigma=sigma, r=r)


def psi_mu(mu):
    """The continuous cycle of ex1dof at its rightmost point, and its multiplier."""
    return np.array([2.0 + mu, 0.0]), math.exp(-2 * math.pi * EPS * (1 + mu) ** 2)


# --------------------------------------------------------------------------------------
# ex1dof: the continuous family Ψ_μ (closed form)
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("mu", [-0.2, -0.05, 0.0])
def test_ex1dof_continuous_cycle_matches_closed_form(mu):
    x_exact, rho = psi_mu(mu)
    # 1% off in amplitude and 1.5% in period. At μ = 0 the cycle grazes Γ, and a guess
    # outside it lies in the basin (for Newton) of the large unstable impacting cycle
    # through (2.4957, 0) (multiplier 1.998): start on the circle there.
    offset = -0.02 if mu < 0 else 0.0
    guess = x_exact + np.array([offset, 0.0])
    orbit = find_periodic_orbit(EX1DOF, guess, 6.19, ex.ex1dof_args(mu), fix=1,
                                start_at_impact=False, **TOL)
    assert OrbitStatus(int(orbit.status)) == OrbitStatus.SUCCESS, orbit.message
    assert int(orbit.num_impacts) == 0
    np.testing.assert_allclose(float(orbit.period), 2 * math.pi, rtol=0, atol=1e-9)
    # The cycle is weakly attracting (1 − ρ ≈ 6e-4): the integration error of one period
    # is amplified by 1/(1 − ρ) in the radial direction.
    np.testing.assert_allclose(orbit.x0, x_exact, atol=1e-12 / (1 - rho) * 100)
    rhos = np.asarray(orbit.multipliers)
    np.testing.assert_allclose(rhos.real, [1.0, rho], rtol=0, atol=1e-9)
    np.testing.assert_allclose(rhos.imag, 0.0, atol=1e-12)
    assert bool(orbit.stable)
    # (A6) with ζ2 fixed: det[f(x0), (U − I) e1] = (1 + μ)(ρ − 1) at the rightmost point.
    np.testing.assert_allclose(float(orbit.poincare_determinant), (1 + mu) * (rho - 1), rtol=1e-6)


def test_ex1dof_impacting_cycle_started_at_impact_and_away_agree():
    args = ex.ex1dof_args(0.2)
    at_impact = find_periodic_orbit(EX1DOF, [0.0, 0.04], 6.2, args, **TOL)
    away = find_periodic_orbit(EX1DOF, [2.0, 0.0], 6.2, args, **TOL)
    for orbit in (at_impact, away):
        assert int(orbit.status) == OrbitStatus.SUCCESS, orbit.message
        assert int(orbit.num_impacts) == 1
    assert at_impact.start_at_impact and not away.start_at_impact
    # The paper's phase: ζ1 = 0 kept exactly, and x0 is the post-impact state.
    assert int(at_impact.fix) == 0 and float(at_impact.x0[0]) == 0.0
    np.testing.assert_allclose(at_impact.impact_post[0], at_impact.x0, atol=1e-10)
    np.testing.assert_allclose(float(at_impact.impact_times[0]), float(at_impact.period), atol=1e-10)
    np.testing.assert_allclose(float(at_impact.period), float(away.period), rtol=0, atol=1e-10)
    np.testing.assert_allclose(at_impact.multipliers, away.multipliers, atol=1e-8)
    np.testing.assert_allclose(float(at_impact.multipliers[0].real), 1.0, atol=1e-8)
    # (A6) matrix: columns ∂S/∂T = f(x(T+)) and (U − I) e2, as in the paper.
    f0 = np.asarray(EX1DOF.vector_field(0.0, at_impact.x0, args))
    U = np.asarray(at_impact.monodromy)
    expected = np.column_stack([f0, (U - np.eye(2))[:, 1]])
    np.testing.assert_allclose(at_impact.poincare_matrix, expected, rtol=1e-8, atol=1e-10)

    # The determinant identity det U = Π det S_i · exp(∫ tr A), and the stable multipliers.
    floquet = floquet_multipliers(EX1DOF, at_impact, args, **TOL)
    assert float(floquet.determinant_error) < 1e-9
    np.testing.assert_allclose(floquet.multipliers, at_impact.multipliers, atol=1e-9)
    # ex1dof's jump x2 → x2 − (1 + R x2 + μ x2³) x2 + μ²: det S = −(2R + 4μ v²) w,
    # with v, w the normal speeds before and after the impact.
    v, w = float(at_impact.impact_pre[0, 1]), float(at_impact.impact_post[0, 1])
    np.testing.assert_allclose(float(floquet.saltation_determinants[0]), -(1.8 + 0.8 * v * v) * w,
                               rtol=1e-10)


def test_monodromy_matches_finite_differences_and_saltation():
    args = ex.ex1dof_args(0.2)
    orbit = find_periodic_orbit(EX1DOF, [2.0, 0.0], 6.2, args, **TOL)
    T = float(orbit.period)
    run = jax.jit(lambda x: gj.simulate(EX1DOF, x, 0.0, T, args, **TOL).x_final)
    x0 = np.asarray(orbit.x0)
    h = 1e-6
    fd = central_differences(run, x0, h)
    np.testing.assert_allclose(orbit.monodromy, fd, rtol=1e-5, atol=1e-6)
    # The closed-form saltation matrix maps f⁻ to f⁺ at the impact.
    S = np.asarray(saltation(EX1DOF, 0, orbit.impact_times[0], orbit.impact_pre[0], args))
    f_minus = EX1DOF.vector_field(0.0, orbit.impact_pre[0], args)
    f_plus = EX1DOF.vector_field(0.0, orbit.impact_post[0], args)
    np.testing.assert_allclose(S @ np.asarray(f_minus), f_plus, rtol=1e-10, atol=1e-12)


def test_period_derivative_by_implicit_function_theorem():
    def period_of(mu):
        orbit = find_periodic_orbit(EX1DOF, jnp.array([0.0, 0.04]), 6.2, ex.ex1dof_args(mu),
                                    start_at_impact=True, num_impacts=1, **TOL)
        return orbit.period

    derivative = float(jax.jacfwd(period_of)(0.2))
    h = 1e-5
    fd = float(central_differences(period_of, 0.2, h))
    np.testing.assert_allclose(derivative, fd, rtol=1e-6)


def test_orbits_of_other_sizes_share_one_compiled_newton():
    """Newton's absolute tolerance follows each orbit's size (newton_tol · max |x|): it is
    an input of the compiled solver, not part of it (a new program per orbit took ~30 s)."""
    from grazejax._orbits.periodic import _newton

    programs, newton_atols = [], []
    for mu in (-0.2, -0.05):
        x_exact, _ = psi_mu(mu)
        orbit = find_periodic_orbit(EX1DOF, x_exact - np.array([0.02, 0.0]), 6.19,
                                    ex.ex1dof_args(mu), fix=1, start_at_impact=False, **TOL)
        assert OrbitStatus(int(orbit.status)) == OrbitStatus.SUCCESS, orbit.message
        programs.append(_newton.single.jitted._cached._cache_size())
        newton_atols.append(orbit.settings.newton_atol)
    assert newton_atols[0] != newton_atols[1]
    assert programs[1] == programs[0]


def _count_loops(jaxpr) -> int:
    """`while` loops in a jaxpr, nested ones included."""
    count = 0
    for eqn in jaxpr.eqns:
        count += eqn.primitive.name == "while"
        for sub in jax.extend.core.jaxprs_in_params(eqn.params):
            count += _count_loops(sub)
    return count


@pytest.mark.slow  # (five compilations of the loop; Newton's use of it is in the default tests)
def test_newton_residual_linearizes_in_one_pass():
    """Newton linearizes its residual with `jax.linearize`, which runs a while loop twice
    (primal, then the whole loop again for the tangents). `jacobian_in_one_pass` gives the
    same value and derivatives (in y, in args, forward and reverse) from one pass."""
    from grazejax._orbits.period_map import jacobian_in_one_pass

    def residual(y, a):
        x_end = gj.simulate(EX1DOF, y, 0.0, 3.0, a, max_impacts=4, adjoint=diffrax.DirectAdjoint(),
                            **TOL).x_final
        return x_end - y

    one_pass = jacobian_in_one_pass(residual)
    y, a = jnp.array([0.1, 0.5]), ex.ex1dof_args(0.2)
    np.testing.assert_array_equal(one_pass(y, a), residual(y, a))
    forward = jax.jacfwd(one_pass)(y, a)
    np.testing.assert_allclose(forward, jax.jacfwd(residual)(y, a), rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(jax.jacrev(one_pass)(y, a), forward, rtol=1e-13, atol=1e-14)
    mu_derivative = [jax.jacfwd(lambda mu, f=f: f(y, ex.ex1dof_args(mu)))(0.2)
                     for f in (one_pass, residual)]
    np.testing.assert_allclose(*mu_derivative, rtol=1e-13, atol=1e-14)

    def linearized(f):
        return jax.make_jaxpr(lambda y: jax.linearize(lambda z: f(z, a), y)[1](y))(y).jaxpr

    assert _count_loops(linearized(one_pass)) < _count_loops(linearized(residual))


# --------------------------------------------------------------------------------------
# Forced impact oscillator: period-1 orbit against a closed form
# --------------------------------------------------------------------------------------


def period_one_closed_form(args, theta_guess):
    """Period-1 orbit with one impact of x'' + 2ζx' + x = A cos ωt at the stop x = σ.

    Between impacts x = x_p + e^{A(t−s)}(x(s) − x_p(s)) (x_p the periodic response). An
    impact at phase θ with speed v > 0 (x → σ from below, v → −r v) closes after one
    forcing period T iff (I − E) u(θ) + v (e2 + r E e2) = 0, E = e^{AT},
    u = (σ, 0) − x_p(θ): a scalar equation in θ (the 2×2 determinant), then v.
    Monodromy (after the impact): U = S E, S = [[−r, 0], [(a⁺ + r a⁻)/v, −r]].
    """
    z, A_, w, s, r = (float(args[k]) for k in ("zeta", "A", "omega", "sigma", "r"))
    T = 2 * math.pi / w
    M = np.array([[0.0, 1.0], [-1.0, -2 * z]])
    E = scipy.linalg.expm(M * T)
    e2 = np.array([0.0, 1.0])
    col = e2 + r * E @ e2

    def u(theta):
        return np.array([s, 0.0]) - ex.linear_response(theta, args)

    def g(theta):
        return np.linalg.det(np.column_stack([(np.eye(2) - E) @ u(theta), col]))

    theta = scipy.optimize.brentq(g, theta_guess - 0.3, theta_guess + 0.3, xtol=1e-15)
    v = -np.linalg.lstsq(col[:, None], (np.eye(2) - E) @ u(theta), rcond=None)[0][0]
    forcing = A_ * math.cos(w * theta) - s
    a_minus, a_plus = forcing - 2 * z * v, forcing + 2 * z * r * v
    S = np.array([[-r, 0.0], [(a_plus + r * a_minus) / v, -r]])
    return theta, v, np.linalg.eigvals(S @ E)


def test_forced_oscillator_period_one_orbit_matches_closed_form():
    args = osc_args(1.2)
    T = 2 * math.pi / 0.5
    orbit = find_periodic_orbit(OSC, [1.08, -0.2], T, args, fixed_period=True, **TOL)
    assert int(orbit.status) == OrbitStatus.SUCCESS, orbit.message
    assert int(orbit.num_impacts) == 1 and float(orbit.period) == T
    theta, v, rho = period_one_closed_form(args, float(orbit.impact_times[0]))
    np.testing.assert_allclose(float(orbit.impact_times[0]) % T, theta % T, atol=1e-9)
    np.testing.assert_allclose(orbit.impact_pre[0], [1.2, v], atol=1e-9)
    ours = np.sort_complex(np.asarray(orbit.multipliers))
    np.testing.assert_allclose(ours, np.sort_complex(rho), atol=1e-8)
    # |ρ|² = det U = r² e^{−2ζT} (a complex pair): stable.
    np.testing.assert_allclose(np.abs(ours) ** 2, 0.64 * math.exp(-0.1 * T), rtol=1e-8)
    assert bool(orbit.stable)


# --------------------------------------------------------------------------------------
# Bad input: a status and a message, never a hang or NaN
# --------------------------------------------------------------------------------------


def test_far_guess_ends_with_a_status_not_nan():
    orbit = find_periodic_orbit(EX1DOF, [50.0, 50.0], 1.0, ex.ex1dof_args(-0.2), fix=1,
                                start_at_impact=False, **TOL)
    status = OrbitStatus(int(orbit.status))
    assert status != OrbitStatus.SUCCESS
    assert "guess" in orbit.message or "Newton" in orbit.message
    assert np.all(np.isfinite(orbit.x0)) and np.isfinite(float(orbit.period))


def test_failed_solve_makes_no_stability_claim():
    """The forced oscillator x'' + 0.1x' + x = cos(0.8t), stop at σ = 1.8 (r = 0.8), from a
    poor guess: Newton fails, and neither `stable` nor `summary()` claims (A5)."""
    args = ex.impact_oscillator_args(zeta=0.05, A=1.0, omega=0.8, sigma=1.8, r=0.8)
    orbit = find_periodic_orbit(OSC, [0.0, 0.0], 2 * math.pi / 0.8, args, fixed_period=True, **TOL)
    assert OrbitStatus(int(orbit.status)) != OrbitStatus.SUCCESS
    # At the last iterate the multipliers are inside the unit circle: no verdict anyway.
    assert not bool(orbit.stable)
    text = orbit.summary()
    assert "NOT CONVERGED" in text and "no (A5) verdict" in text and "(A5) holds" not in text
    assert orbit.settings.rtol == TOL["rtol"] and orbit.settings.atol == TOL["atol"]


def test_tolerances_scale_with_the_orbit():
    """A forced linear oscillator of amplitude 1e-9 (the stop far away): its multipliers are
    the eigenvalues of e^{MT} whatever the amplitude, and x0 the closed-form response. With
    the default atol (scaled to the orbit) both are right; an explicit atol far above the
    orbit's size × rtol (1e-13 against 1e-21) is reported, not passed off as converged. The
    explicit atol is the module's (`TOL`), whose forced-oscillator program the other tests
    compile already (it was 1e-12, one more program; with 1e-13 the solve is LOOSE_ATOL all
    the same, its multipliers 1.1e-4 off)."""
    omega = 0.8
    T = 2 * math.pi / omega
    args = ex.impact_oscillator_args(zeta=0.05, A=1e-9, omega=omega, sigma=1.0, r=0.8)
    rho = np.sort_complex(np.linalg.eigvals(scipy.linalg.expm(np.array([[0.0, 1.0], [-1.0, -0.1]]) * T)))
    x_exact = np.asarray(ex.linear_response(0.0, args))
    orbit = find_periodic_orbit(OSC, [1e-9, 0.0], T, args, fixed_period=True, rtol=1e-12)
    assert int(orbit.status) == OrbitStatus.SUCCESS, orbit.message
    np.testing.assert_allclose(np.sort_complex(np.asarray(orbit.multipliers)), rho, atol=1e-10)
    np.testing.assert_allclose(orbit.x0, x_exact, rtol=1e-9, atol=1e-9 * 1e-9)
    assert orbit.settings.atol <= 1e-20 and orbit.settings.newton_atol <= 1e-16
    loose = find_periodic_orbit(OSC, [1e-9, 0.0], T, args, fixed_period=True, **TOL)
    assert OrbitStatus(int(loose.status)) == OrbitStatus.LOOSE_ATOL
    assert not bool(loose.stable) and "no (A5) verdict" in loose.summary()
    # What it would have claimed: multipliers off by ~1e-4, orders above rtol.
    assert np.max(np.abs(np.sort_complex(np.asarray(loose.multipliers)) - rho)) > 1e-5


def test_fixed_coordinate_tangent_to_the_flow_is_reported():
    # At (2, 0) the flow is vertical: x1 = 2 is not a section.
    orbit = find_periodic_orbit(EX1DOF, [2.0, 0.0], 6.28, ex.ex1dof_args(-0.2), fix=0,
                                start_at_impact=False, **TOL)
    assert OrbitStatus(int(orbit.status)) == OrbitStatus.FIX_TANGENT
    assert "tangent" in orbit.message


def test_equilibrium_guess_is_reported():
    orbit = find_periodic_orbit(EX1DOF, [1.0, 0.0], 6.28, ex.ex1dof_args(-0.2),
                                start_at_impact=False, **TOL)
    assert OrbitStatus(int(orbit.status)) == OrbitStatus.EQUILIBRIUM


def test_invalid_arguments_raise_readable_errors():
    with pytest.raises(ValueError, match="period"):
        find_periodic_orbit(EX1DOF, [2.0, 0.0], -1.0, ex.ex1dof_args(0.0))
    with pytest.raises(ValueError, match="fix"):
        find_periodic_orbit(EX1DOF, [2.0, 0.0], 6.0, ex.ex1dof_args(0.0), fix=5)
    with pytest.raises(ValueError, match="start_at_impact"):
        jax.jit(lambda a: find_periodic_orbit(EX1DOF, [2.0, 0.0], 6.0, a).period)(ex.ex1dof_args(0.0))


@pytest.mark.slow  # (compiles the whole solve, batched, as one program)
def test_solves_under_jit_and_vmap_match_one_by_one():
    """The docstring's promise: inside `jit`/`vmap` (with start_at_impact and num_impacts
    passed) nothing raises, and each lane is the orbit a single solve finds. (The default
    Newton's tolerances are arrays, traced inside jit: `float()` of them for the settings
    raised ConcretizationTypeError.) Agreement to Newton's tolerance (1e-8): two solutions
    of the same equations, each within it."""
    def solve(mu):
        return find_periodic_orbit(EX1DOF, jnp.array([0.0, 0.04]), 6.2, ex.ex1dof_args(mu),
                                   start_at_impact=True, num_impacts=1, **TOL)

    mus = jnp.array([0.15, 0.2, 0.25])
    batched = jax.jit(jax.vmap(lambda mu: (lambda o: (o.period, o.x0, o.status))(solve(mu))))(mus)
    for k, mu in enumerate(mus):
        one = solve(float(mu))
        assert int(batched[2][k]) == int(one.status) == OrbitStatus.SUCCESS
        np.testing.assert_allclose(batched[0][k], one.period, rtol=1e-8)
        np.testing.assert_allclose(batched[1][k], one.x0, rtol=1e-8, atol=1e-8 * 0.04)


# --------------------------------------------------------------------------------------
# Stable multipliers
# --------------------------------------------------------------------------------------


def test_product_eigenvalues_keep_tiny_multipliers():
    """Eigenvalues 1e10 and 1e-10 of a product of 20 factors: the formed product loses the
    small one entirely (its eigenvalues are accurate to eps·1e10 ≈ 1e-6 only)."""
    rng = np.random.default_rng(0)
    p = 20
    qs = [np.linalg.qr(rng.normal(size=(2, 2)))[0] for _ in range(p)]
    factors = []
    for k in range(p):
        d = np.diag([10 ** 0.5, 10 ** -0.5])  # per factor; product scales 1e±10
        factors.append(qs[(k + 1) % p] @ d @ qs[k].T)
    exact = np.array([1e10, 1e-10])
    naive = np.sort(np.abs(np.linalg.eigvals(np.linalg.multi_dot(factors[::-1]))))[::-1]
    stable = np.abs(product_eigenvalues(factors))
    np.testing.assert_allclose(stable, exact, rtol=1e-10)
    assert abs(naive[1] - 1e-10) > 1e-3 * 1e-10  # the formed product cannot resolve it


def test_multipliers_are_compiled_in_on_the_cpu_without_a_host_callback():
    """`eigvals_sorted` (the multipliers of every orbit, bifurcation and continuation
    program) is LAPACK's eigensolver compiled into the program on the CPU: JAX writes no
    program with a host callback to its persistent compilation cache, so with NumPy's
    through a callback each of those programs compiled again in every process. The values
    are NumPy's, sorted by modulus; the JVP is dλ = w dA v (central differences); a
    matrix that is not finite gives NaN."""
    m = np.array([[0.3, -1.2, 0.5], [0.8, 0.1, -0.4], [0.2, 0.9, -0.7]])
    d = np.array([[0.1, 0.0, -0.3], [0.2, 0.5, 0.1], [-0.4, 0.3, 0.2]])
    jvp = jax.jit(lambda a, da: jax.jvp(eigvals_sorted, (a,), (da,)))
    assert "callback" not in jvp.lower(m, d).as_text()
    values, slopes = jvp(m, d)
    host = np.linalg.eigvals(m)
    np.testing.assert_allclose(values, host[np.argsort(-np.abs(host), kind="stable")],
                               rtol=1e-14)
    h = 1e-6
    central = (np.asarray(eigvals_sorted(m + h * d)) - np.asarray(eigvals_sorted(m - h * d)))
    np.testing.assert_allclose(slopes, central / (2 * h), rtol=1e-7, atol=1e-9)
    assert np.all(np.isnan(np.asarray(eigvals_sorted(np.full((2, 2), np.nan)))))


def test_newton_roots_are_differentiated_without_a_host_callback():
    """`newton_root`, the Newton solve of every orbit, bifurcation and continuation
    program, differentiates its root by the implicit function theorem with a linear solve
    compiled into the program (optimistix's implicit adjoint checks lineax's solve by a
    host callback, which kept each derivative of an orbit out of the persistent cache).
    Closed form: r(y; a, c) = (y₀² − a, y₁ − c·y₀) has the root (√a, c√a); `c` is closed
    over, as the orbit residuals close over the phase condition."""
    from grazejax._orbits.period_map import newton_for, newton_root

    def root(a, c):
        def residual(y, args):
            return jnp.stack([y[0] ** 2 - args["a"], y[1] - c * y[0]])

        guess = jnp.array([1.0, 1.0])
        y, converged, _ = newton_root(residual, newton_for(1e-13, 1.0), guess, {"a": a}, 60)
        return y, converged

    jacobian = jax.jit(jax.jacfwd(lambda a, c: root(a, c)[0], argnums=(0, 1)))
    assert "callback" not in jacobian.lower(2.0, 3.0).as_text()
    a, c = 2.0, 3.0
    y, converged = root(a, c)
    assert bool(converged)
    np.testing.assert_allclose(y, [math.sqrt(a), c * math.sqrt(a)], rtol=1e-14)
    by_a, by_c = jacobian(a, c)
    np.testing.assert_allclose(by_a, [0.5 / math.sqrt(a), 0.5 * c / math.sqrt(a)], rtol=1e-13)
    np.testing.assert_allclose(by_c, [0.0, math.sqrt(a)], rtol=1e-13, atol=1e-15)
    gradient = jax.grad(lambda a: root(a, c)[0].sum())(a)
    np.testing.assert_allclose(gradient, (1 + c) * 0.5 / math.sqrt(a), rtol=1e-13)
    lanes = jax.vmap(jax.jacfwd(lambda a: root(a, c)[0]))(jnp.array([0.5, 2.0, 4.5]))
    np.testing.assert_allclose(lanes[:, 0], 0.5 / np.sqrt([0.5, 2.0, 4.5]), rtol=1e-13)


# --------------------------------------------------------------------------------------
# The grazing cycle of ex1dof: its two branches (A4), (A5)
# --------------------------------------------------------------------------------------


def test_ex1dof_grazing_cycle_branches():
    args = ex.ex1dof_args(0.0)
    orbit = find_periodic_orbit(EX1DOF, [2.0, 0.0], 6.28, args, fix=1, start_at_impact=False, **TOL)
    contacts = orbit_contacts(EX1DOF, orbit, args, **TOL)
    graze = contacts.grazing(1e-6)
    assert graze.sum() == 1
    np.testing.assert_allclose(contacts.times[graze], [math.pi], atol=1e-6)
    np.testing.assert_allclose(contacts.points[graze][0], [0.0, 0.0], atol=1e-6)

    branches = grazing_branches(EX1DOF, orbit, args, **TOL)
    assert branches.impacts.tolist() == [[False], [True]]
    assert np.all(branches.realized) and np.all(branches.finite) and np.all(branches.a5)
    miss, hit = np.asarray(branches.multipliers)
    # Not impacting: the smooth flow's multiplier exp(−2πε) (the paper prints 0.939).
    np.testing.assert_allclose(miss.real, [1.0, math.exp(-2 * math.pi * EPS)], atol=1e-9)
    # Impacting: det S = 2R²v² → 0 on neighbours with impact speed v → 0 (paper: 0.912).
    np.testing.assert_allclose(hit.real, [1.0, 0.0], atol=1e-6)
