"""Continuation of periodic orbits through grazing: ex1dof (paper §5) and the impact oscillator."""

import math

import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex
from grazejax._orbits.continuation import ContinuationStatus, continue_orbit
from grazejax._orbits.periodic import OrbitStatus, find_periodic_orbit

from .test_periodic import (  # shared scenes: shared compiled programs
    EPS,
    EX1DOF,
    OSC,
    TOL,
    period_one_closed_form,
)


def ex1dof_args(mu):
    return ex.ex1dof_args(mu)


def test_ex1dof_grazing_bifurcation_at_zero(tmp_path):
    """Ψ_μ (no impact, μ < 0) grazes Γ at μ = 0 and becomes the impacting cycle (μ > 0)."""
    orbit = find_periodic_orbit(EX1DOF, [1.7, 0.0], 6.28, ex1dof_args(-0.3), fix=1,
                                start_at_impact=False, **TOL)
    branch = continue_orbit(EX1DOF, orbit, ex1dof_args, -0.3, 0.3, progress=False, **TOL)
    assert ContinuationStatus(branch.status) == ContinuationStatus.REACHED_STOP
    assert branch.mu[0] == -0.3 and branch.mu[-1] == 0.3
    assert len(branch.grazing) == 1
    graze = branch.grazing[0]
    assert graze.kind == "persistence"
    assert (graze.impacts_before, graze.impacts_after) == (0, 1)
    # Located to the accuracy of the weakly attracting cycle (1 − ρ ≈ 6e-4 amplifies the
    # 1e-12 integration tolerance to ~1e-9 in amplitude).
    assert abs(graze.mu) < 1e-8
    np.testing.assert_allclose(graze.point, [0.0, 0.0], atol=1e-6)
    assert abs(graze.depth) < 1e-6

    before = branch.mu < graze.mu
    after = branch.mu > graze.mu + 1e-6
    assert np.all(branch.num_impacts[before] == 0) and np.all(branch.num_impacts[after] == 1)
    assert np.all(branch.stable)
    # μ < 0: the closed form, period 2π and multiplier exp(−2πε(1 + μ)²).
    mu = branch.mu[before]
    np.testing.assert_allclose(branch.period[before], 2 * math.pi, atol=1e-8)
    np.testing.assert_allclose(branch.multipliers[before][:, 1].real,
                               np.exp(-2 * math.pi * EPS * (1 + mu) ** 2), atol=1e-8)
    np.testing.assert_allclose(branch.x_max[before][:, 0], 2 + mu, atol=1e-6)
    # μ > 0: the impacting cycle is super-stable near grazing (ρ → 0 with μ).
    rho = np.abs(branch.multipliers[after][:, 1])
    assert rho[0] < 1e-3 and np.all(np.diff(rho) > 0)
    last = find_periodic_orbit(EX1DOF, branch.x0[-1], branch.period[-1], ex1dof_args(0.3),
                               t0=branch.t0[-1], start_at_impact=False, **TOL)
    assert int(last.status) == OrbitStatus.SUCCESS
    np.testing.assert_allclose(branch.period[-1], float(last.period), atol=1e-8)

    path = tmp_path / "ex1dof-bifurcation.png"
    gj.plot_bifurcation_diagram(branch, path, coordinate=0, title="ex1dof")
    assert path.exists() and path.stat().st_size > 10_000


def test_ex1dof_grazing_from_the_impacting_side():
    """The impacting cycle (μ = 0.2) continued down: its impact speed → 0 like √μ, so
    arclength in μ stalls; the impact-speed monitor locates grazing at μ = 0 (closed form:
    Ψ_μ touches Γ at μ = 0) and continuation goes on along Ψ_μ (period 2π, max x1 = 2 + μ)."""
    orbit = find_periodic_orbit(EX1DOF, [2.0, 0.0], 6.2, ex1dof_args(0.2), fix=1,
                                start_at_impact=False, **TOL)
    branch = continue_orbit(EX1DOF, orbit, ex1dof_args, 0.2, -0.2, progress=False, **TOL)
    assert ContinuationStatus(branch.status) == ContinuationStatus.REACHED_STOP, branch.message
    assert len(branch.grazing) == 1
    graze = branch.grazing[0]
    assert (graze.impacts_before, graze.impacts_after, graze.kind) == (1, 0, "persistence")
    assert abs(graze.mu) < 1e-6
    assert branch.mu[-1] == -0.2
    before, after = branch.mu > graze.mu, branch.mu < graze.mu
    assert np.all(branch.num_impacts[before] == 1) and np.all(branch.num_impacts[after] == 0)
    np.testing.assert_allclose(branch.period[after], 2 * math.pi, atol=1e-8)
    # x_max is the largest of 400 samples (and the impact states): 2e-6 short of the peak.
    np.testing.assert_allclose(branch.x_max[after][:, 0], 2 + branch.mu[after], atol=1e-5)
    assert branch.settings.rtol == TOL["rtol"] and branch.settings.atol == TOL["atol"]


def _grazing_mu_by_scipy(eps=1e-4):
    """μ_c, independently: where the impacting cycle's impact speed is 0, its post-impact
    state is J(0, 0) = (0, μ²) and the flight from there returns to x1 = 0 tangentially.
    SciPy's DOP853 (rtol 1e-13) flies from (0, μ²) to the next minimum of x1 (x2 crossing 0
    upwards); Brent's method finds the μ where that minimum is 0 (−0.1059845091 here)."""
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    def x1_at_return(mu):
        def f(t, x):
            return [x[1], -eps * (x[1] ** 2 + (x[0] - 1) ** 2 - (1 + mu) ** 2) * x[1] - x[0] + 1]

        def minimum(t, x):
            return x[1]

        minimum.direction, minimum.terminal = 1, True
        sol = solve_ivp(f, (0.0, 20.0), [0.0, mu * mu], method="DOP853", rtol=1e-13,
                        atol=1e-14, events=minimum, first_step=1e-3)
        return sol.y_events[0][0][0]

    return brentq(x1_at_return, -0.2, -0.05, xtol=1e-14)


@pytest.mark.slow
def test_ex1dof_impacting_family_ends_where_its_impact_speed_vanishes():
    """The impacting cycle of μ < 0 exists only below μ_c ≈ −0.10598 (computed independently
    with SciPy): its impact speed → 0."""
    args = ex1dof_args(-0.3)
    orbit = find_periodic_orbit(EX1DOF, [0.0, 0.084], 6.1, args, **TOL)
    assert orbit.start_at_impact and int(orbit.num_impacts) == 1
    branch = continue_orbit(EX1DOF, orbit, ex1dof_args, -0.3, 0.0, progress=False, **TOL)
    assert ContinuationStatus(branch.status) == ContinuationStatus.BRANCH_ENDS
    end = branch.grazing[-1]
    assert end.kind == "end" and end.impacts_before == 1
    np.testing.assert_allclose(end.mu, _grazing_mu_by_scipy(), atol=2e-5)
    assert abs(end.depth) < 1e-8  # −v²/(2a): the impact speed has gone to 0
    assert np.all(branch.num_impacts == 1) and np.all(branch.stable)
    # Brute force: between μ_c and 0 every start ends on the continuous cycle.
    sweep = gj.sweep(EX1DOF, np.stack([np.zeros(6), np.linspace(0.02, 0.3, 6)], axis=1), 0.0,
                     3000.0, ex1dof_args(-0.05), progress=False, max_impacts=2000)
    late = sweep.impact_times > 2000.0
    assert not np.any(late)


@pytest.mark.slow
def test_forced_oscillator_fold_and_grazing():
    """Period-1 impacting orbits of the forced oscillator (ω = 0.5) lose stability at a
    fold just before grazing; the unstable one ends at grazing (σ* = A/√D), where the
    non-impacting response takes over (a non-smooth fold)."""
    omega = 0.5

    def args_of(sigma):
        return ex.impact_oscillator_args(zeta=0.05, A=1.0, omega=omega, sigma=sigma, r=0.8)

    T = 2 * math.pi / omega
    orbit = find_periodic_orbit(OSC, [1.08, -0.2], T, args_of(1.2), fixed_period=True, **TOL)
    branch = continue_orbit(OSC, orbit, args_of, 1.2, 1.4, ds=0.05, progress=False, **TOL)
    assert ContinuationStatus(branch.status) == ContinuationStatus.REACHED_STOP
    sigma_star = 1 / math.sqrt((1 - omega**2) ** 2 + (2 * 0.05 * omega) ** 2)
    graze = branch.grazing[0]
    np.testing.assert_allclose(graze.mu, sigma_star, atol=1e-6)
    assert (graze.impacts_before, graze.impacts_after, graze.kind) == (1, 0, "fold")
    impacting = branch.num_impacts == 1
    largest = np.abs(branch.multipliers[:, 0])
    # Stable (complex pair of modulus r e^{−ζT}... = √det U) far from grazing, unstable
    # near it: the largest multiplier grows without bound as the impact speed → 0.
    np.testing.assert_allclose(largest[0], math.sqrt(0.64 * math.exp(-0.1 * T)), rtol=1e-8)
    assert branch.stable[0] and not np.all(branch.stable[impacting])
    assert np.max(largest[impacting]) > 50
    # Past grazing: the linear response, multipliers e^{(−ζ ± i√(1−ζ²))T}.
    free = ~impacting
    np.testing.assert_allclose(np.abs(branch.multipliers[free]), math.exp(-0.05 * T), rtol=1e-8)


def _osc_08(sigma):
    return ex.impact_oscillator_args(zeta=0.05, A=1.0, omega=0.8, sigma=sigma, r=0.8)


def test_forced_oscillator_grazing_then_the_one_impact_family():
    """x'' + 0.1x' + x = cos(0.8t), stop at σ (r = 0.8): the non-impacting response (σ = 3)
    grazes at σ* = 1/√((1 − ω²)² + (2ζω)²) and the one-impact family begins there. Its
    orbits are checked against the closed-form period-1 orbit (impact phase and speed)."""
    omega = 0.8
    T = 2 * math.pi / omega
    orbit = find_periodic_orbit(OSC, np.asarray(ex.linear_response(0.0, _osc_08(3.0))), T,
                                _osc_08(3.0), fixed_period=True, **TOL)
    branch = continue_orbit(OSC, orbit, _osc_08, 3.0, 2.6, progress=False, **TOL)
    sigma_star = 1 / math.sqrt((1 - omega**2) ** 2 + (2 * 0.05 * omega) ** 2)
    graze = branch.grazing[0]
    np.testing.assert_allclose(graze.mu, sigma_star, atol=1e-6)
    assert (graze.impacts_before, graze.impacts_after) == (0, 1), branch.message
    impacting = np.flatnonzero(branch.num_impacts == 1)
    assert len(impacting) >= 3 and np.all(branch.mu[impacting] < sigma_star)
    # The farthest one-impact point against the closed form.
    i = impacting[np.argmax(sigma_star - branch.mu[impacting])]
    args = _osc_08(float(branch.mu[i]))
    again = find_periodic_orbit(OSC, branch.x0[i], T, args, t0=branch.t0[i], fixed_period=True,
                                start_at_impact=False, **TOL)
    assert int(again.status) == OrbitStatus.SUCCESS and int(again.num_impacts) == 1
    theta, v, rho = period_one_closed_form(args, float(again.impact_times[0]))
    np.testing.assert_allclose(float(again.impact_times[0]) % T, theta % T, atol=1e-8)
    np.testing.assert_allclose(float(again.impact_pre[0][1]), v, atol=1e-8)
    np.testing.assert_allclose(np.sort(np.abs(branch.multipliers[i])), np.sort(np.abs(rho)), rtol=1e-6)


def _scipy_period_map(sigma, x, t0, T, omega=0.8, zeta=0.05, r=0.8):
    """The forced oscillator's time-T map, independently: SciPy's DOP853 with a terminal
    event at x = σ (approached from below) and v → −r v there."""
    from scipy.integrate import solve_ivp

    def f(t, y):
        return [y[1], -2 * zeta * y[1] - y[0] + math.cos(omega * t)]

    def hit(t, y):
        return y[0] - sigma

    hit.terminal, hit.direction = True, 1
    t, y = t0, np.asarray(x, float)
    for _ in range(100):
        sol = solve_ivp(f, (t, t0 + T), y, method="DOP853", rtol=1e-12, atol=1e-13, events=hit)
        if sol.status != 1:
            return sol.y[:, -1]
        t, y = sol.t_events[0][0], np.array([sigma, -r * sol.y_events[0][0][1]])
    raise AssertionError("too many impacts in one period")


def _scipy_period_doubling(t0, x_guess, T, bracket):
    """σ where a multiplier of the period-1 orbit is −1: Brent's method on det(DP + I), P
    the SciPy period map, its fixed point by scipy.optimize.root, DP by central differences."""
    from scipy.optimize import brentq, root

    state = {"x": np.asarray(x_guess, float)}

    def g(sigma):
        fixed = root(lambda x: _scipy_period_map(sigma, x, t0, T) - x, state["x"], tol=1e-13)
        # hybr may report "not making good progress" once at round-off: judge the residual.
        assert np.max(np.abs(fixed.fun)) < 1e-10, fixed.message
        state["x"] = fixed.x
        h = 1e-6
        DP = np.column_stack([
            (_scipy_period_map(sigma, fixed.x + h * e, t0, T)
             - _scipy_period_map(sigma, fixed.x - h * e, t0, T)) / (2 * h)
            for e in np.eye(2)
        ])
        return np.linalg.det(DP + np.eye(2))

    return brentq(g, *bracket, xtol=1e-10)


@pytest.mark.slow
def test_forced_oscillator_period_doubling_and_the_period_two_orbit():
    """From σ = 1.5 upward the one-impact orbit of x'' + 0.1x' + x = cos(0.8t) (r = 0.8)
    loses stability through a multiplier −1 near σ = 1.93; the period-2 orbit found from
    it at σ = 2.0 is the attractor. Both against a separate SciPy shooting code."""
    T = 2 * math.pi / 0.8
    sol = gj.simulate(OSC, np.zeros(2), 0.0, 100 * T, _osc_08(1.5), max_impacts=1000, **TOL)
    orbit = find_periodic_orbit(OSC, np.asarray(sol.x_final), T, _osc_08(1.5), fixed_period=True,
                                **TOL)
    assert int(orbit.status) == OrbitStatus.SUCCESS and int(orbit.num_impacts) == 1
    branch = continue_orbit(OSC, orbit, _osc_08, 1.5, 2.0, progress=False, **TOL)
    pd = [p for p in branch.special_points if p.kind == "period-doubling"]
    assert len(pd) == 1 and pd[0].label == "PD"
    point = pd[0]
    np.testing.assert_allclose(np.min(np.abs(np.asarray(point.multipliers) + 1)), 0, atol=1e-7)
    sigma_pd = _scipy_period_doubling(point.t0, point.x0, T, (point.mu - 0.02, point.mu + 0.02))
    np.testing.assert_allclose(point.mu, sigma_pd, atol=1e-5)
    assert branch.stable[branch.mu < point.mu - 1e-3].all()
    assert not branch.stable[branch.mu > point.mu + 1e-3].any()

    # Branch switching just past the period-doubling point, then the period-2 family.
    mu_two = point.mu + 0.005
    two = gj.period_doubled_orbit(OSC, point, _osc_08(mu_two), **TOL)
    assert int(two.status) == OrbitStatus.SUCCESS, two.message
    np.testing.assert_allclose(float(two.period), 2 * T)
    assert int(two.num_impacts) == 2 and bool(two.stable)
    family = continue_orbit(OSC, two, _osc_08, mu_two, 2.0, progress=False, **TOL)
    assert ContinuationStatus(family.status) == ContinuationStatus.REACHED_STOP, family.message
    assert family.mu[-1] == 2.0 and family.num_impacts[-1] == 2 and family.stable[-1]
    # SciPy: the attractor reached from rest, sampled at the orbit's phase, is that orbit.
    t0, x_two = float(family.t0[-1]), family.x0[-1]
    x = np.zeros(2)
    for _ in range(400):
        x = _scipy_period_map(2.0, x, t0, T)
    other = _scipy_period_map(2.0, x, t0, T)
    assert np.max(np.abs(x - other)) > 1e-2  # period 2, not 1
    distance = min(np.max(np.abs(x - x_two)), np.max(np.abs(other - x_two)))
    assert distance < 1e-6


def test_branch_export_and_labelled_diagram(tmp_path):
    """The repr, CSV/JSON export and the diagram's labels, on a hand-made three-point
    branch."""
    import csv
    import json

    rho = np.array([[-0.9, 0.1], [-1.0, 0.1], [-1.1, 0.1]], complex)
    pd_point = gj.SpecialPoint(kind="period-doubling", mu=0.5, x0=np.array([1.0, 0.0]), t0=0.0,
                               period=2.0, multipliers=rho[1], num_impacts=1,
                               eigenvector=np.array([1.0, 0.0]))
    branch = gj.Branch(
        mu=np.array([0.4, 0.5, 0.6]), period=np.full(3, 2.0), x0=np.ones((3, 2)), t0=np.zeros(3),
        multipliers=rho, num_impacts=np.ones(3, int), stable=np.array([True, False, False]),
        x_min=-np.ones((3, 2)), x_max=np.ones((3, 2)) * [[1.0], [1.1], [1.2]],
        poincare_determinant=np.ones(3), grazing=(), status=int(ContinuationStatus.REACHED_STOP),
        special_points=(pd_point,),
    )
    # The repr names the status (the field holds the enum, equal to its code).
    assert "status=<ContinuationStatus.REACHED_STOP: 0>" in repr(branch)
    assert branch.status == 0 and branch.status is ContinuationStatus.REACHED_STOP
    rows = list(csv.DictReader(branch.to_csv(tmp_path / "b.csv").splitlines()))
    assert (tmp_path / "b.csv").exists() and len(rows) == 3
    assert float(rows[1]["mu"]) == 0.5 and rows[1]["special"] == "PD" and rows[0]["special"] == ""
    assert float(rows[2]["abs_rho_0"]) == pytest.approx(1.1)
    data = json.loads(branch.to_json(tmp_path / "b.json"))
    assert data["special_points"][0]["label"] == "PD" and data["status"] == "REACHED_STOP"
    assert data["points"]["multipliers_re"][1][0] == -1.0
    fig = gj.plot_bifurcation_diagram(branch, tmp_path / "b.png")
    texts = [t.get_text() for t in fig.axes[0].texts]
    assert any(t.startswith("PD") for t in texts)
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "1 impact(s)/period, stable" in labels and "1 impact(s)/period, unstable" in labels
