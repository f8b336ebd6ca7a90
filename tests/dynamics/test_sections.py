"""`gj.poincare` and `gj.orbit_diagram` against closed forms and an independent impact map.

Compile budget (default job): five programs, each computed once in a module fixture and read
by several tests: a stroboscopic run and a user section (forced / damped oscillator), a
batch of two bouncing balls, the vibrating table's orbit diagram (one vmapped program over
μ) and its one-by-one runs (one single-run program, called twice).

Tolerances: a run at rtol (atol = rtol/100, states of order 1) carries the global error
of a few hundred steps' local errors, ~ rtol each, not amplified by these damped or
contracting flows, so every comparison with a closed form uses ERROR = 1e3·rtol (the
measured errors are quoted next to each check: from 14 times smaller, the oscillator's
global error, to round-off, the ball's exact parabolas).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import brentq

import grazejax as gj
from grazejax import examples as ex
from grazejax._dynamics.orbit_diagram import detect_period

RTOL = 1e-10
ATOL = 1e-12
ERROR = 1e3 * RTOL  # see the module docstring

OSCILLATOR = ex.impact_oscillator()
BALL = ex.bouncing_ball()
TABLE = ex.vibrating_table()

ZETA, OMEGA = 0.05, 1.5
OMEGA_D = math.sqrt(1 - ZETA**2)


def damped_free_motion(t, x0):
    """x'' + 2ζx' + x = 0 from x0 = (a, b) at time 0 (closed form)."""
    a, b = x0
    c = (b + ZETA * a) / OMEGA_D
    decay = np.exp(-ZETA * t)
    x = decay * (a * np.cos(OMEGA_D * t) + c * np.sin(OMEGA_D * t))
    v = -ZETA * x + decay * OMEGA_D * (-a * np.sin(OMEGA_D * t) + c * np.cos(OMEGA_D * t))
    return np.stack([x, v], axis=-1)


def first_coordinate(t, x, args):
    """The user section h = x₁ (module level: one scene, one program)."""
    return x[0]


# --------------------------------------------------------------------------------------
# Stroboscopic points and a user section: a forced and a damped oscillator (no impacts)
# --------------------------------------------------------------------------------------

STROBE_X0, STROBE_T0, STROBE_TRANSIENT = np.array([0.7, -0.2]), 0.3, 5.0
STROBE_ARGS = ex.impact_oscillator_args(zeta=ZETA, A=1.0, omega=OMEGA, sigma=100.0)


@pytest.fixture(scope="module")
def strobe():
    return gj.poincare(OSCILLATOR, STROBE_X0, STROBE_T0, STROBE_ARGS, period=2 * np.pi / OMEGA,
                       num_points=6, transient=STROBE_TRANSIENT, rtol=RTOL, atol=ATOL)


def test_stroboscopic_points_are_the_closed_form_solution_at_t0_plus_kT(strobe):
    # x(t) = steady response x_p(t) + damped free motion of x0 − x_p(t0), from t0.
    period = 2 * np.pi / OMEGA
    times = STROBE_T0 + STROBE_TRANSIENT + period * np.arange(1, 7)
    exact = ex.linear_response(times, STROBE_ARGS) + damped_free_motion(
        times - STROBE_T0, STROBE_X0 - ex.linear_response(STROBE_T0, STROBE_ARGS))
    np.testing.assert_allclose(strobe.times, times, rtol=0, atol=1e-13)
    np.testing.assert_allclose(strobe.points, exact, rtol=0, atol=ERROR)  # measured 7.1e-11
    assert np.all(np.asarray(strobe.status) == gj.Status.SUCCESS)
    assert int(strobe.run_status) == gj.Status.SUCCESS


@pytest.fixture(scope="module")
def crossings():
    # Damped free oscillator from (1, 0): crossings of x₁ = 0 upwards, after t = 3.
    args = ex.impact_oscillator_args(zeta=ZETA, A=0.0, omega=OMEGA, sigma=100.0)
    return gj.poincare(OSCILLATOR, np.array([1.0, 0.0]), 0.0, args, section=first_coordinate,
                       direction=1, num_points=5, transient=3.0, rtol=RTOL, atol=ATOL,
                       max_impacts=8)


def test_section_crossings_are_the_closed_form_zeros_upwards(crossings):
    # x = e^{−ζt} cos(ω_d t − ψ)/cos ψ, tan ψ = ζ/ω_d: zeros at ω_d t = ψ + π/2 + kπ, with
    # x' = e^{−ζt} > 0 for odd k (upward crossings) and < 0 for even k (not section points).
    # The crossings are events with an identity jump: had a restart at one of them changed
    # the trajectory, the later crossings would be off.
    psi = math.atan(ZETA / OMEGA_D)
    times = (psi + np.pi / 2 + (2 * np.arange(5) + 1) * np.pi) / OMEGA_D
    assert times[0] > 3.0 > times[0] - 2 * np.pi / OMEGA_D  # the first one after the transient
    # Time errors grow with the phase error of the run: measured 1.5e-12 .. 9.6e-12.
    np.testing.assert_allclose(crossings.times, times, rtol=0, atol=ERROR)
    np.testing.assert_allclose(crossings.points[:, 0], 0.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(crossings.points[:, 1], np.exp(-ZETA * times), rtol=0,
                               atol=ERROR)  # measured 3.0e-11
    assert np.all(np.asarray(crossings.status) == gj.Status.SUCCESS)
    # The run goes on to its budget of 8 events: 8 upward crossings (t = 4.77, 11.06, ...),
    # the downward ones passing through unlogged.
    assert int(crossings.run_status) == gj.Status.MAX_IMPACTS
    assert int(crossings.num_events) == 8


# --------------------------------------------------------------------------------------
# Impact map of the bouncing ball; missing points are NaN with their reason
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def balls():
    # One program, two lanes (batched args): e = 0.9 runs out of its 20-impact budget before
    # 30 points; e = 0.3 reaches its Zeno accumulation first.
    return gj.poincare(BALL, np.array([[1.0, 0.0], [1.0, 0.0]]), 0.0,
                       {"g": 9.81, "e": np.array([0.9, 0.3])}, surface=0, num_points=30,
                       transient=0.5, max_impacts=20, rtol=RTOL, atol=ATOL)


@pytest.mark.parametrize("lane, e", [(0, 0.9), (1, 0.3)])
def test_impact_map_points_of_the_bouncing_ball_are_the_closed_forms(balls, lane, e):
    found = np.asarray(balls.status[lane]) == gj.Status.SUCCESS
    count = int(found.sum())
    assert found[:count].all() and not found[count:].any()  # found points come first
    exact_times, _ = ex.bouncing_ball_impact_times(1.0, 0.0, 9.81, e, count + 1)
    # The first impact (t = 0.4515) lies inside the transient (0.5): skipped.
    # Measured: times 4.6e-14, speeds 1.6e-14 (exact parabolas: only the event's rounding).
    np.testing.assert_allclose(balls.times[lane, :count], exact_times[1:], rtol=0, atol=ERROR)
    # Post-impact: on the floor, moving up at e^k √(2gh).
    speeds = e ** np.arange(2, count + 2) * math.sqrt(2 * 9.81)
    np.testing.assert_allclose(balls.points[lane, :count, 0], 0.0, rtol=0, atol=ERROR)
    np.testing.assert_allclose(balls.points[lane, :count, 1], speeds, rtol=0, atol=ERROR)


def test_points_a_run_did_not_reach_are_nan_with_the_reason_never_zeros(balls):
    status = np.asarray(balls.status)
    points, times = np.asarray(balls.points), np.asarray(balls.times)
    missing = status != gj.Status.SUCCESS
    assert np.all(np.isnan(points[missing])) and np.all(np.isnan(times[missing]))
    assert np.all(np.isfinite(points[~missing]))
    # e = 0.9: the 20-impact budget holds 19 points after the transient, then MAX_IMPACTS.
    assert int((~missing[0]).sum()) == 19
    assert set(status[0, 19:].tolist()) == {gj.Status.MAX_IMPACTS}
    # e = 0.3: the run ends ZENO before its budget, and its missing points say so.
    assert int(balls.run_status[1]) == gj.Status.ZENO
    assert 0 < int((~missing[1]).sum()) < 19
    assert set(status[1][missing[1]].tolist()) == {gj.Status.ZENO}


# --------------------------------------------------------------------------------------
# Orbit diagram of the ball on a vibrating table, across its period doubling
# --------------------------------------------------------------------------------------
# Γ = Aω²/g, ω = 2π, e = 0.5: the period-1 orbit (one impact per forcing period) has the
# closed form x⁺ = A sin φ, v⁺ = g/2 with cos φ = πr/Γ, r = (1 − e)/(1 + e)
# (docs/bifurcations.md); it loses stability at Γ_PD = √((πr)² + (1 + r²)²) = 1.5268.

G, TABLE_OMEGA, E = 9.81, 2 * math.pi, 0.5
R = (1 - E) / (1 + E)
MUS = np.array([1.3, 1.6])  # below and above Γ_PD


def table_args(gamma):
    return dict(g=G, e=E, A=gamma * G / TABLE_OMEGA**2, omega=TABLE_OMEGA)


def period_one_point(gamma):
    """(post-impact state, impact phase θ in [0, 1)) of the period-1 orbit."""
    phi = math.acos(math.pi * R / gamma)
    return np.array([table_args(gamma)["A"] * math.sin(phi), G / 2]), phi / TABLE_OMEGA


def table_start(gamma):
    """The period-1 orbit's state at t = 0, kicked by 0.05 in velocity (so that the
    unstable orbit above Γ_PD is left, not followed to round-off)."""
    (x, v), theta = period_one_point(gamma)
    s = 1.0 - theta  # time since the impact
    return np.array([x + v * s - G / 2 * s * s, v - G * s + 0.05])


TABLE_OPTIONS = dict(surface=0, num_points=8, transient=60.0, rtol=RTOL, atol=ATOL,
                     max_impacts=96)


@pytest.fixture(scope="module")
def diagram():
    starts = np.stack([table_start(mu) for mu in MUS])
    return gj.orbit_diagram(TABLE, starts, table_args, MUS, **TABLE_OPTIONS)


def table_impact_map(theta, state, args):
    """The next impact of the table from a post-impact (θ, x, v), independently of
    grazejax: the flight is a parabola, the first root of its gap to the table is bracketed
    on a grid of 1e-3 and polished by Brent's method, then the restitution law applied."""
    x, v = state
    a, w, g, e = args["A"], args["omega"], args["g"], args["e"]

    def gap(s):
        return x + v * s - g * s * s / 2 - a * math.sin(w * (theta + s))

    grid = np.arange(1e-3, 5.0, 1e-3)
    values = np.array([gap(s) for s in grid])
    k = int(np.argmax(values < 0))
    s = brentq(gap, grid[k - 1], grid[k], xtol=1e-15, rtol=1e-15)
    t = theta + s
    table_velocity = a * w * math.cos(w * t)
    v_pre = v - g * s
    return t, np.array([a * math.sin(w * t), table_velocity - e * (v_pre - table_velocity)])


def test_orbit_diagram_finds_period_one_below_and_period_two_above_the_doubling(diagram):
    assert np.asarray(diagram.period).tolist() == [1, 2]
    assert np.asarray(diagram.status).tolist() == [gj.Status.SUCCESS] * 2
    # Below Γ_PD: every point is the closed-form period-1 point (measured 2.0e-13, and
    # 2.1e-14 in the impact phase).
    point, theta = period_one_point(MUS[0])
    np.testing.assert_allclose(diagram.points[0], np.broadcast_to(point, (8, 2)), rtol=0,
                               atol=ERROR)
    phases = np.mod(np.asarray(diagram.times[0]), 1.0)
    np.testing.assert_allclose(phases, theta, rtol=0, atol=ERROR)
    # Above: two alternating points, both away from the (unstable) period-1 point.
    points = np.asarray(diagram.points[1])
    assert np.max(np.abs(points[0] - points[1])) > 0.1
    assert np.min(np.abs(points[:2] - period_one_point(MUS[1])[0]).max(axis=1)) > 0.05


@pytest.mark.parametrize("lane", [0, 1])
def test_orbit_diagram_points_follow_an_independent_impact_map(diagram, lane):
    # Each point, mapped by the independent impact map above, lands on the next one: the
    # period-2 points are a true 2-cycle of the table's impact map, not an artefact
    # (measured: times 7.1e-15, states 1.1e-13).
    args = table_args(MUS[lane])
    times, points = np.asarray(diagram.times[lane]), np.asarray(diagram.points[lane])
    for k in range(3):
        t_next, x_next = table_impact_map(times[k], points[k], args)
        assert abs(t_next - times[k + 1]) < ERROR
        np.testing.assert_allclose(x_next, points[k + 1], rtol=0, atol=ERROR)


def test_the_recurrence_tolerance_follows_the_solver_tolerance(diagram):
    # 1e3·(rtol·max|x| + atol) per coordinate, from the points of each μ.
    scale = np.max(np.abs(np.asarray(diagram.points)), axis=1)
    np.testing.assert_allclose(diagram.tolerance, 1e3 * (RTOL * scale + ATOL), rtol=1e-15)


def test_the_batched_diagram_is_the_one_by_one_runs(diagram):
    # The diagram runs all μ as lanes of one vmapped program; poincare of one start is a
    # program of one trajectory (other XLA fusions: the same to rounding, which the
    # contracting attractors keep within the recurrence tolerance; measured: identical).
    for lane, mu in enumerate(MUS):
        single = gj.poincare(TABLE, table_start(mu), 0.0, table_args(mu), **TABLE_OPTIONS)
        np.testing.assert_allclose(single.points, diagram.points[lane], rtol=0,
                                   atol=float(np.max(diagram.tolerance[lane])))
        np.testing.assert_array_equal(single.status, diagram.section.status[lane])


def test_plot_orbit_diagram_draws_points_and_a_lyapunov_panel(diagram):
    import matplotlib

    matplotlib.use("Agg")
    fig = gj.plot_orbit_diagram(diagram, coordinate=1, lyapunov=np.array([-0.3, -0.1]))
    top, bottom = fig.axes
    drawn = np.concatenate([line.get_ydata() for line in top.get_lines()])
    np.testing.assert_allclose(np.sort(drawn), np.sort(np.asarray(diagram.points)[..., 1].ravel()))
    assert {t.get_text() for t in top.get_legend().get_texts()} == {"period 1", "period 2"}
    np.testing.assert_allclose(bottom.get_lines()[0].get_ydata(), [-0.3, -0.1])
    matplotlib.pyplot.close(fig)


# --------------------------------------------------------------------------------------
# No programs: the period detection and the argument checks
# --------------------------------------------------------------------------------------


def test_detect_period_finds_the_smallest_recurrence_within_the_tolerance():
    cycle = np.array([[0.0, 1.0], [1.0, 2.0], [0.5, 3.0], [2.0, 0.0]])
    points = np.tile(cycle, (4, 1))
    tolerance = np.array([1e-6, 1e-6])
    assert detect_period(points, tolerance) == 4
    assert detect_period(points[:, :1] * 0 + 1.0, tolerance[:1]) == 1
    noisy = points + 0.5e-6 * np.cos(np.arange(16))[:, None]
    assert detect_period(noisy, tolerance) == 4  # differences up to 1e-6: still recur
    assert detect_period(points + 1e-5 * np.arange(16)[:, None], tolerance) == 0  # drifts
    assert detect_period(points[:7], tolerance) == 0  # 4 > 7 // 2: not seen twice
    with_nan = points.copy()
    with_nan[-1] = np.nan
    assert detect_period(with_nan, tolerance) == 0


def test_poincare_asks_for_exactly_one_kind_of_section():
    x0, args = jnp.array([1.0, 0.0]), {"g": 9.81, "e": 0.9}
    with pytest.raises(ValueError, match="exactly one"):
        gj.poincare(BALL, x0, 0.0, args, period=1.0, surface=0, num_points=2)
    with pytest.raises(ValueError, match="exactly one"):
        gj.poincare(BALL, x0, 0.0, args, num_points=2)
    with pytest.raises(ValueError, match="surface must be an index"):
        gj.poincare(BALL, x0, 0.0, args, surface=1, num_points=2)
    with pytest.raises(ValueError, match="direction"):
        gj.poincare(BALL, x0, 0.0, args, section=first_coordinate, direction=2, num_points=2)
    with pytest.raises(TypeError, match="saveat"):
        gj.poincare(BALL, x0, 0.0, args, surface=0, num_points=2, saveat=[1.0])


# --------------------------------------------------------------------------------------
# Slow: a finer diagram across the doubling, and continue_state
# --------------------------------------------------------------------------------------

SWEEP_MUS = np.linspace(1.3, 1.7, 17)


@pytest.mark.slow
def test_the_period_changes_from_one_to_two_at_the_closed_form_doubling():
    diagram = gj.orbit_diagram(TABLE, np.stack([table_start(mu) for mu in SWEEP_MUS]),
                               table_args, SWEEP_MUS, surface=0, num_points=16,
                               transient=60.0, rtol=RTOL, atol=ATOL, max_impacts=200)
    gamma_pd = math.sqrt((math.pi * R) ** 2 + (1 + R**2) ** 2)  # 1.5268
    period = np.asarray(diagram.period)
    assert np.all(np.asarray(diagram.status) == gj.Status.SUCCESS)
    # Away from Γ_PD (where convergence is slow and 0, "not found", is the honest answer):
    assert np.all(period[SWEEP_MUS < gamma_pd - 0.05] == 1)
    assert np.all(period[(SWEEP_MUS > gamma_pd + 0.04) & (SWEEP_MUS < 1.63)] == 2)
    assert set(period[np.abs(SWEEP_MUS - gamma_pd) < 0.05].tolist()) <= {0, 1, 2}
    for lane in np.flatnonzero(period == 1):
        np.testing.assert_allclose(diagram.points[lane, -1], period_one_point(SWEEP_MUS[lane])[0],
                                   rtol=0, atol=ERROR)


@pytest.mark.slow
def test_continue_state_starts_each_mu_from_the_previous_last_point():
    # Stroboscopic at integer times, where the table is at height 0 for every Γ (a state
    # of one μ is then never inside the table of the next).
    options = dict(period=1.0, num_points=16, transient=40.0, rtol=RTOL, atol=ATOL,
                   max_impacts=200)
    diagram = gj.orbit_diagram(TABLE, table_start(1.3), table_args, SWEEP_MUS,
                               continue_state=True, **options)
    assert np.all(np.asarray(diagram.status) == gj.Status.SUCCESS)
    # Each μ ran from the previous one's last point: its times continue the clock ...
    np.testing.assert_allclose(diagram.times[:, -1], 56.0 * np.arange(1, 18), rtol=0,
                               atol=1e-9)
    # ... and a single run from that point gives the same points.
    k = 5
    single = gj.poincare(TABLE, np.asarray(diagram.points[k - 1, -1]),
                         float(diagram.times[k - 1, -1]), table_args(SWEEP_MUS[k]), **options)
    np.testing.assert_allclose(single.points, diagram.points[k], rtol=0, atol=ERROR)
    # Period 1 below the doubling, with the closed-form orbit's state at integer times.
    period = np.asarray(diagram.period)
    assert np.all(period[SWEEP_MUS < 1.47] == 1)
    assert np.all(period[(SWEEP_MUS > 1.57) & (SWEEP_MUS < 1.63)] == 2)
    for lane in np.flatnonzero(SWEEP_MUS < 1.47):
        on_orbit = table_start(SWEEP_MUS[lane]) - np.array([0.0, 0.05])  # without the kick
        np.testing.assert_allclose(diagram.points[lane], np.broadcast_to(on_orbit, (16, 2)),
                                   rtol=0, atol=ERROR)


@pytest.mark.slow
def test_section_in_both_directions_alternates_down_and_up_crossings():
    # direction=0: both probe surfaces (Φ = h and Φ = −h); the zeros of the damped
    # oscillator alternate downward (x' = −e^{−ζt}) and upward (x' = +e^{−ζt}).
    args = ex.impact_oscillator_args(zeta=ZETA, A=0.0, omega=OMEGA, sigma=100.0)
    both = gj.poincare(OSCILLATOR, np.array([1.0, 0.0]), 0.0, args, section=first_coordinate,
                       direction=0, num_points=6, rtol=RTOL, atol=ATOL, max_impacts=6)
    psi = math.atan(ZETA / OMEGA_D)
    times = (psi + np.pi / 2 + np.arange(6) * np.pi) / OMEGA_D
    np.testing.assert_allclose(both.times, times, rtol=0, atol=ERROR)
    signs = np.where(np.arange(6) % 2 == 0, -1.0, 1.0)
    np.testing.assert_allclose(both.points[:, 1], signs * np.exp(-ZETA * times), rtol=0,
                               atol=ERROR)


@pytest.mark.slow
def test_jacfwd_of_impact_map_points_includes_the_saltation_matrices():
    # Ball from (h, v0): post-impact speeds e^k √(v0² + 2gh), so ∂v_k/∂h = e^k g/√(2gh) and
    # ∂v_k/∂v0 = 0 at v0 = 0; the heights stay 0 (∂x_k = 0).
    args = {"g": 9.81, "e": 0.9}

    def points(x0):
        return gj.poincare(BALL, x0, 0.0, args, surface=0, num_points=3, max_impacts=4,
                           rtol=RTOL, atol=ATOL).points

    jacobian = np.asarray(jax.jacfwd(points)(jnp.array([1.0, 0.0])))
    slopes = 0.9 ** np.arange(1, 4) * 9.81 / math.sqrt(2 * 9.81)
    np.testing.assert_allclose(jacobian[:, 1, 0], slopes, rtol=ERROR)
    np.testing.assert_allclose(jacobian[:, 1, 1], 0.0, atol=ERROR)
    np.testing.assert_allclose(jacobian[:, 0, :], 0.0, atol=ERROR)
