"""Lyapunov spectra through impacts (`gj.lyapunov_spectrum`), against independent values.

The impact oscillator x'' + 2ζx' + x = A cos ωt with a stop at σ (restitution r) is linear
between impacts, so everything about its period-1 orbit has a closed form: the flight
Jacobian is expm(M τ), M = [[0, 1], [−1, −2ζ]], the saltation matrix of the stop is
S = [[−r, 0], [(a⁺ + r a⁻)/v, −r]] (det S = r²), and the orbit itself solves two equations
in the impact phase and speed (SciPy). None of it runs grazejax's loop.

Compile budget: the oscillator tests share one scene object, one set of options and one
window count, so they compile two programs (one run, and one batch of lanes whose results
several tests read); Lorenz and the one-vector run add one each.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

import grazejax as gj
from grazejax import examples as ex
from grazejax._dynamics.lyapunov import LyapunovStatus, start_frame

OSC = ex.impact_oscillator()
# A stable period-1 orbit with one impact per period and real multipliers (≈ −0.27, −0.55:
# exponents ≈ −0.25 and −0.11, well apart).
PARAMETERS = dict(zeta=0.05, A=1.0, omega=1.2, sigma=0.2, r=0.5)
ARGS = ex.impact_oscillator_args(**PARAMETERS)
PERIOD = 2 * math.pi / PARAMETERS["omega"]
NUM_WINDOWS = 20
T1 = NUM_WINDOWS * PERIOD
RTOL = 1e-10
OPTIONS = dict(rtol=RTOL, atol=1e-12, max_impacts=8)
# Near-grazing floor on the relative approach speed (lyapunov_spectrum's default).
GRAZING_SPEED = 10 * math.sqrt(RTOL)


# --------------------------------------------------------------------------------------
# Closed forms of the linear impact oscillator
# --------------------------------------------------------------------------------------


def flight(tau, zeta=PARAMETERS["zeta"]):
    """The flight Jacobian expm(M τ) (the same for every flight: the field is linear)."""
    return scipy.linalg.expm(np.array([[0.0, 1.0], [-1.0, -2 * zeta]]) * tau)


def flow(y, t_a, t_b, args=ARGS):
    """The free flow from (t_a, y) to t_b: the steady response plus the decaying rest."""
    steady = ex.linear_response
    return steady(t_b, args) + flight(t_b - t_a, float(args["zeta"])) @ (y - steady(t_a, args))


def periodic_orbit():
    """(θ, v): impact phase in [0, T) and pre-impact speed of the period-1 orbit, from
    P(σ, −r v) over one period = (σ, v)."""
    sigma, r = PARAMETERS["sigma"], PARAMETERS["r"]

    def residual(u):
        theta, v = u
        return flow(np.array([sigma, -r * v]), theta, theta + PERIOD) - np.array([sigma, v])

    theta, v = scipy.optimize.fsolve(residual, [0.17, 1.78], xtol=1e-12)
    assert np.max(np.abs(residual([theta, v]))) < 1e-12
    return theta % PERIOD, v


def jump_factors(theta, v):
    """The closed-form saltation matrix of the orbit's impact, and the jump's own DJ."""
    zeta, A, omega, sigma, r = (PARAMETERS[k] for k in ("zeta", "A", "omega", "sigma", "r"))
    force = -sigma + A * math.cos(omega * theta)
    a_minus, a_plus = -2 * zeta * v + force, 2 * zeta * r * v + force
    saltation = np.array([[-r, 0.0], [(a_plus + r * a_minus) / v, -r]])
    return saltation, np.diag([1.0, -r])


def monodromy(theta, jump):
    """One period's tangent map from phase 0 (≡ T): flight to θ, `jump`, flight to T."""
    return flight(PERIOD - theta) @ jump @ flight(theta)


def qr_iteration(U, frame, num):
    """Benettin's estimate, in NumPy: (1/(num·T)) Σ log R_ii of `num` QR steps of U."""
    q, sums = frame, np.zeros(frame.shape[1])
    for _ in range(num):
        q, r = np.linalg.qr(U @ q)
        sums += np.log(np.abs(np.diag(r)))
        q = q * np.sign(np.diag(r))
    return sums / (num * PERIOD)


THETA, SPEED = periodic_orbit()
SALTATION, DJ = jump_factors(THETA, SPEED)
# The orbit's state at phase 0 (≡ T): the post-impact state flown from θ to T.
ORBIT_X0 = flow(np.array([PARAMETERS["sigma"], -PARAMETERS["r"] * SPEED]), THETA, PERIOD)
AMPLITUDE = float(np.hypot(*ex.linear_response(0.0, ARGS) * [1.0, 1 / PARAMETERS["omega"]]))


# --------------------------------------------------------------------------------------
# One batch of lanes (one program) read by several tests, and the same lanes one by one
# --------------------------------------------------------------------------------------

# Lanes: the orbit; two starts off it (they fall onto the orbit, impacting every period);
# the non-impacting steady response with the stop moved to 1e-9 below its peak (a
# near-grazing first impact); a start just below the stop pushed into it by the
# forcing (chattering: more impacts in the first window than max_impacts).
LANES = {
    "orbit": (ORBIT_X0, ARGS),
    "off orbit": (np.array([0.0, 0.0]), ARGS),
    "far off orbit": (np.array([-1.0, 1.5]), ARGS),
    "grazing": (ex.linear_response(0.0, ARGS),
                ex.impact_oscillator_args(**{**PARAMETERS, "sigma": AMPLITUDE * (1 - 1e-9)})),
    "chattering": (np.array([0.199, 0.05]), ARGS),
}


def spectrum(x0, args):
    return gj.lyapunov_spectrum(OSC, x0, 0.0, T1, args, renormalize=PERIOD, **OPTIONS)


@pytest.fixture(scope="module")
def batch():
    x0s = jnp.asarray(np.stack([x0 for x0, _ in LANES.values()]))
    args = jax.tree.map(lambda *leaves: jnp.stack(leaves), *[a for _, a in LANES.values()])
    result = jax.vmap(spectrum)(x0s, args)
    return {name: jax.tree.map(lambda leaf, i=i: leaf[i], result)
            for i, name in enumerate(LANES)}


@pytest.fixture(scope="module")
def single_runs():
    return {name: spectrum(*LANES[name]) for name in ("orbit", "off orbit", "far off orbit")}


def test_periodic_orbit_spectrum_is_log_floquet_over_period(single_runs):
    result = single_runs["orbit"]
    assert LyapunovStatus(int(result.status)) == LyapunovStatus.SUCCESS, result.message
    assert int(result.num_impacts) == NUM_WINDOWS  # one impact per period
    np.testing.assert_allclose(float(result.averaging_time), NUM_WINDOWS * PERIOD, rtol=1e-14)
    U = monodromy(THETA, SALTATION)
    floquet = np.sort(np.log(np.abs(np.linalg.eigvals(U))) / PERIOD)[::-1]
    # Windows of one period from phase 0 multiply the frame by U each: the finite-time
    # estimate is Benettin's QR iteration on the closed-form U from the same start frame.
    # Its error is that of the simulated tangent map, about the solver's rtol per window
    # relative to the stretches (1e3 · rtol / T allows for its growth over a period).
    finite_time = np.sort(qr_iteration(U, start_frame(2, 2), NUM_WINDOWS))[::-1]
    np.testing.assert_allclose(result.exponents, finite_time, rtol=0, atol=1e3 * RTOL / PERIOD)
    # The finite-time estimate tends to ln|ρ|/T like C/T_avg: log R_ii of the QR iteration
    # settle at N ln|ρ_i| + c_i, c_i set by the start frame's projections on the Floquet
    # vectors; the orbit's transient has decayed (the state starts on it). Here
    # |c_i| < 0.5, so C/T_avg is below 0.005, far below the 0.14 between the exponents.
    np.testing.assert_allclose(result.exponents, floquet, rtol=0,
                               atol=0.5 / float(result.averaging_time))
    assert abs(floquet[0] - floquet[1]) > 0.1


def plain_run(name):
    """The lane's trajectory by one plain `simulate` over the whole span (its impact log:
    an independent account of the impacts the windows met)."""
    x0, args = LANES[name]
    sol = gj.simulate(OSC, x0, 0.0, T1, args, rtol=RTOL, atol=1e-12, max_impacts=64)
    assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
    k = int(sol.num_impacts)
    return sol, np.asarray(sol.impact_times[:k]), np.asarray(sol.impact_pre[:k])


def test_sum_identity_with_saltation_determinants(batch):
    """Σλ·T = ∫ div f dt + Σ ln|det S_j| on the starts off the orbit (k = n)."""
    zeta = PARAMETERS["zeta"]
    for name in ("off orbit", "far off orbit"):
        result = batch[name]
        assert LyapunovStatus(int(result.status)) == LyapunovStatus.SUCCESS, result.message
        # The impacts, logged by an independent plain run, and their saltation matrices in
        # closed form (grazejax.saltation_matrix: derivatives of f, Φ, J at the point).
        _, times, pres = plain_run(name)
        assert int(result.num_impacts) == len(times) >= NUM_WINDOWS
        args = LANES[name][1]
        dets = [np.linalg.det(gj.saltation_matrix(OSC, 0, t, x, args).matrix)
                for t, x in zip(times, pres, strict=True)]
        np.testing.assert_allclose(dets, PARAMETERS["r"] ** 2, rtol=1e-12)
        T = float(result.averaging_time)
        np.testing.assert_allclose(T, T1, rtol=1e-14)
        expected = -2 * zeta * T + np.sum(np.log(np.abs(dets)))  # div f = −2ζ exactly
        # The tangent map's determinant is that of the discrete flow, exact to the solver's
        # local error per step: allow 1e3·rtol per unit time.
        np.testing.assert_allclose(float(np.sum(result.exponents)) * T, expected, rtol=0,
                                   atol=1e3 * RTOL * T)


def test_spectrum_without_saltation_is_clearly_different(single_runs, batch):
    """The same tangent map built from the flights and DJ alone (no saltation) gives a
    spectrum far outside the tolerances above: tests 1 and 2 need the saltation matrices."""
    without = np.sort(np.log(np.abs(np.linalg.eigvals(monodromy(THETA, DJ)))) / PERIOD)[::-1]
    with_saltation = np.asarray(single_runs["orbit"].exponents)
    assert np.max(np.abs(without - with_saltation)) > 0.05  # vs tolerances ≤ 0.005
    # The sum identity without saltation: ln|det DJ| = ln r per impact instead of 2 ln r.
    result = batch["off orbit"]
    T = float(result.averaging_time)
    sum_without = -2 * PARAMETERS["zeta"] * T + int(result.num_impacts) * math.log(PARAMETERS["r"])
    assert abs(float(np.sum(result.exponents)) * T - sum_without) > 10.0


def test_vmap_over_starts_and_args_equals_a_loop(single_runs, batch):
    for name, single in single_runs.items():
        for field in ("exponents", "history", "averaging_time"):
            np.testing.assert_allclose(getattr(batch[name], field), getattr(single, field),
                                       rtol=1e-9, atol=1e-12, err_msg=f"{name}: {field}")
        for field in ("num_impacts", "status", "simulation_status", "grazing_windows"):
            np.testing.assert_array_equal(getattr(batch[name], field), getattr(single, field))
    assert not np.any(np.isnan(np.asarray(batch["off orbit"].history)))


def test_grazing_window_is_flagged(batch):
    """The steady response peaks 1e-9 above the stop: its first impact comes at a relative
    speed ~4e-5 (then the square-root kick throws the state onto an impacting orbit). The
    flagged windows are exactly those holding an impact slower than the floor, read from
    the independent run's log (relative speed |v|/|f| for the wall x = σ)."""
    result = batch["grazing"]
    assert LyapunovStatus(int(result.status)) == LyapunovStatus.GRAZING, result.message
    sol, times, pres = plain_run("grazing")
    args = LANES["grazing"][1]
    fields = np.stack([np.asarray(OSC.vector_field(t, x, args)) for t, x in zip(times, pres,
                                                                              strict=True)])
    speeds = np.abs(fields[:, 0]) / np.linalg.norm(fields, axis=1)
    slow = speeds < GRAZING_SPEED
    assert slow[0] and not np.all(slow)  # a near-grazing impact, and ordinary ones
    expected = np.zeros(NUM_WINDOWS, bool)
    expected[(times[slow] // PERIOD).astype(int)] = True
    np.testing.assert_array_equal(result.grazing_windows, expected)
    assert not np.any(np.asarray(batch["orbit"].grazing_windows))


def test_failed_window_propagates_into_status(batch):
    result = batch["chattering"]
    assert LyapunovStatus(int(result.status)) == LyapunovStatus.MAX_IMPACTS, result.message
    assert gj.Status(int(result.simulation_status)) == gj.Status.MAX_IMPACTS
    # The first window failed: nothing was averaged, and nothing pretends otherwise.
    assert float(result.averaging_time) == 0.0
    assert np.all(np.isnan(np.asarray(result.exponents)))
    assert np.all(np.isnan(np.asarray(result.history)))


def test_bad_times_are_refused():
    with pytest.raises(ValueError, match="forward in time"):
        gj.lyapunov_spectrum(OSC, ORBIT_X0, 1.0, 0.0, ARGS)
    with pytest.raises(ValueError, match="forward in time"):
        gj.lyapunov_spectrum(OSC, ORBIT_X0, 0.0, 1.0, ARGS, transient=2.0)
    with pytest.raises(ValueError, match="longer than"):
        gj.lyapunov_spectrum(OSC, ORBIT_X0, 0.0, 1.0, ARGS, renormalize=2.0)
    with pytest.raises(ValueError, match="k must be"):
        gj.lyapunov_spectrum(OSC, ORBIT_X0, 0.0, 1.0, ARGS, k=3)


# --------------------------------------------------------------------------------------
# A smooth system: Lorenz (10, 28, 8/3)
# --------------------------------------------------------------------------------------

SIGMA, RHO, BETA = 10.0, 28.0, 8.0 / 3.0
LORENZ = gj.Scene(lambda t, x, a: jnp.stack([
    SIGMA * (x[1] - x[0]), x[0] * (RHO - x[2]) - x[1], x[0] * x[1] - BETA * x[2]]))


def test_lorenz_sum_is_the_constant_divergence_and_k1_follows_the_first_vector():
    common = dict(transient=1.0, renormalize=0.25, rtol=1e-10, atol=1e-12)
    result = gj.lyapunov_spectrum(LORENZ, [1.0, 1.0, 20.0], 0.0, 11.0, **common)
    assert LyapunovStatus(int(result.status)) == LyapunovStatus.SUCCESS, result.message
    assert int(result.num_impacts) == 0 and float(result.averaging_time) == 10.0
    # div f = −(σ + 1 + β) everywhere; the discrete flow's determinant matches it to the
    # solver's local error, 1e3·rtol per unit time as above.
    np.testing.assert_allclose(float(np.sum(result.exponents)), -(SIGMA + 1 + BETA), rtol=0,
                               atol=1e3 * 1e-10)
    # One vector renormalised by its norm is Gram–Schmidt's first column: the same running
    # estimate as the full frame's first column (the start frames share it), up to the
    # rounding of QR against a norm, which the stretching does not amplify.
    maximal = gj.maximal_lyapunov_exponent(LORENZ, [1.0, 1.0, 20.0], 0.0, 11.0, **common)
    assert LyapunovStatus(int(maximal.status)) == LyapunovStatus.SUCCESS, maximal.message
    np.testing.assert_allclose(maximal.history[:, 0], result.history[:, 0], rtol=0, atol=1e-10)
    # Windows 8 times longer (the same 40 windows: the same program): the frame's stretches
    # part by e^((λ1 − λ3)·2) ≈ e^31 > 1/(1e8·eps), the smallest exponent is round-off, and
    # the status says so; the identity, exact above, is visibly broken.
    too_long = gj.lyapunov_spectrum(LORENZ, [1.0, 1.0, 20.0], 0.0, 81.0,
                                    **{**common, "renormalize": 2.0})
    assert LyapunovStatus(int(too_long.status)) == LyapunovStatus.WINDOW_TOO_LONG
    assert abs(float(np.sum(too_long.exponents)) + SIGMA + 1 + BETA) > 1e3 * (1e3 * 1e-10)


@pytest.mark.slow
def test_lorenz_spectrum_matches_published_values():
    """λ ≈ (0.9056, 0, −14.5723) (Sprott, *Chaos and Time-Series Analysis*, 2003).

    Finite-time exponents over T fluctuate like √(D/T); for Lorenz's λ1, D ≈ 0.3 (in
    time units), so at T = 1000 one standard deviation is ≈ 0.02: 0.05 is 2.5 of them.
    λ2 = 0 is approached like 1/T (the flow direction, no diffusion): 0.02 is generous.
    """
    common = dict(transient=10.0, renormalize=0.5, max_steps=10_000)
    result = gj.lyapunov_spectrum(LORENZ, [1.0, 1.0, 20.0], 0.0, 1010.0, **common)
    assert LyapunovStatus(int(result.status)) == LyapunovStatus.SUCCESS, result.message
    error = np.abs(np.asarray(result.exponents) - [0.9056, 0.0, -14.5723])
    assert np.all(error <= [0.05, 0.02, 0.05]), result.exponents
    np.testing.assert_allclose(float(np.sum(result.exponents)), -(SIGMA + 1 + BETA), atol=1e-4)
    maximal = gj.maximal_lyapunov_exponent(LORENZ, [1.0, 1.0, 20.0], 0.0, 1010.0, **common)
    np.testing.assert_allclose(maximal.exponents, [0.9056], rtol=0, atol=0.05)


@pytest.mark.slow
def test_orbit_spectrum_agrees_with_find_periodic_orbit_and_floquet_multipliers(single_runs):
    """Three routes to the orbit's exponents: the closed form above, grazejax's periodic
    orbit solver with its Floquet multipliers (per-impact factors), and the windows."""
    orbit = gj.find_periodic_orbit(OSC, ORBIT_X0, PERIOD, ARGS, fixed_period=True,
                                   start_at_impact=False, rtol=RTOL)
    assert int(orbit.status) == gj.OrbitStatus.SUCCESS, orbit.message
    np.testing.assert_allclose(orbit.x0, ORBIT_X0, rtol=0, atol=1e-8)
    floquet = gj.floquet_multipliers(OSC, orbit, ARGS, rtol=RTOL)
    from_floquet = np.sort(np.log(np.abs(np.asarray(floquet.multipliers))) / PERIOD)[::-1]
    closed_form = np.sort(np.log(np.abs(np.linalg.eigvals(monodromy(THETA, SALTATION))))
                          / PERIOD)[::-1]
    np.testing.assert_allclose(from_floquet, closed_form, rtol=0, atol=1e-7)
    # The windows' finite-time estimate is within C/T_avg of the limit (see the first test).
    result = single_runs["orbit"]
    np.testing.assert_allclose(result.exponents, from_floquet, rtol=0,
                               atol=0.5 / float(result.averaging_time))


@pytest.mark.slow
def test_maximal_exponent_through_impacts_is_power_iteration_on_monodromy():
    result = gj.maximal_lyapunov_exponent(OSC, ORBIT_X0, 0.0, T1, ARGS, renormalize=PERIOD,
                                          **OPTIONS)
    assert LyapunovStatus(int(result.status)) == LyapunovStatus.SUCCESS, result.message
    expected = qr_iteration(monodromy(THETA, SALTATION), start_frame(2, 1), NUM_WINDOWS)
    np.testing.assert_allclose(result.exponents, expected, rtol=0, atol=1e3 * RTOL / PERIOD)
    without = qr_iteration(monodromy(THETA, DJ), start_frame(2, 1), NUM_WINDOWS)
    assert abs(float(result.exponents[0]) - float(without[0])) > 0.01
