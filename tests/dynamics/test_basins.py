"""`gj.basins` against independent references: SciPy runs of a smooth bistable oscillator,
and an impact map of the ball on a vibrating table built from closed-form flights.

Compile budget (default job): three section programs, each run once in a module fixture
and read by several tests: the damped Duffing oscillator's stroboscopic section over 24
starts (the recurrence and the features runs share it), the same in chunks of 5 (a second
shape), and the vibrating table's impact map over an 8×8 grid. The classification itself
runs on the host (NumPy) and is also checked on synthetic sequences, which compile nothing.
bSTAB's published pendulum case (10,000 starts, one more program, ~10 s). Slow job: the
table on a 20×20 grid in padded chunks, and notebooks/04-basins.ipynb's
classification of ex1dof reproduced with a feature (a sweep and a user section).

Tolerances: a start is on an attractor when its section points recur within the
recurrence tolerance TOL = 1e3·(rtol·max|x| + atol) (`RECURRENCE_FACTOR`); what is left
of its transient is below that, so an attractor's points are compared with their closed
form or reference at TOL (the measured distances are quoted next to each check).
"""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import grazejax as gj
from grazejax import examples as ex
from grazejax._dynamics.basins import _classify_chunk
from grazejax._dynamics.orbit_diagram import RECURRENCE_FACTOR

RTOL, ATOL = 1e-8, 1e-10  # simulate's defaults, used by every run here


def recurrence_tolerance(scale):
    """TOL of the module docstring for states of size `scale`."""
    return RECURRENCE_FACTOR * (RTOL * scale + ATOL)


# --------------------------------------------------------------------------------------
# A smooth bistable system: damped Duffing x'' + δx' − x + x³ = 0, foci at x = ±1
# --------------------------------------------------------------------------------------

DELTA = 0.5


def duffing_field(t, x, args):
    return jnp.stack([x[1], -args["delta"] * x[1] + x[0] - x[0] ** 3])


DUFFING = gj.Scene(duffing_field)
DUFFING_ARGS = {"delta": DELTA}
# A line of starts across several of the interleaved spiral arms of the two basins.
DUFFING_STARTS = np.stack([np.linspace(-2.3, 2.3, 24), np.full(24, 0.4)], axis=1)
DUFFING_RUN = dict(period=1.0, num_points=8, transient=60.0)


def duffing_mean_position(points):
    """A feature: the mean of x over the section points (module level: one program)."""
    return jnp.mean(points[:, 0])


def duffing_reference_sign(x0, rtol):
    """The sign of x at t = 200 from SciPy's DOP853: the equilibrium the start reaches."""
    sol = solve_ivp(lambda t, x: [x[1], -DELTA * x[1] + x[0] - x[0] ** 3], (0.0, 200.0), x0,
                    method="DOP853", rtol=rtol, atol=rtol * 1e-2)
    return np.sign(sol.y[0, -1])


@pytest.fixture(scope="module")
def duffing():
    return gj.basins(DUFFING, DUFFING_STARTS, 0.0, DUFFING_ARGS, **DUFFING_RUN)


def test_duffing_labels_are_the_equilibria_scipy_reaches(duffing):
    reference = np.array([duffing_reference_sign(x0, 1e-11) for x0 in DUFFING_STARTS])
    # The reference itself does not depend on its tolerance (no start is that close to
    # the basin boundary, the stable manifold of the saddle at 0).
    loose = np.array([duffing_reference_sign(x0, 1e-8) for x0 in DUFFING_STARTS])
    np.testing.assert_array_equal(reference, loose)
    assert set(reference.tolist()) == {-1.0, 1.0}
    assert np.all(duffing.status == gj.BasinStatus.ATTRACTOR)
    assert duffing.num_attractors == 2
    sign_of_label = np.array([np.sign(a.points[0, 0]) for a in duffing.attractors])
    np.testing.assert_array_equal(sign_of_label[duffing.labels], reference)
    # Both basins hold several arms on this line: the labels change sign 3 times.
    assert np.count_nonzero(np.diff(reference)) == 3


def test_duffing_attractors_are_the_stable_foci(duffing):
    for attractor in duffing.attractors:
        assert attractor.period == 1
        focus = np.array([np.sign(attractor.points[0, 0]), 0.0])
        # The residual of the transient (e^{−δt/2} decay): measured 1.8e-7 ≤ TOL = 1e-5.
        np.testing.assert_allclose(attractor.points[0], focus, rtol=0,
                                   atol=recurrence_tolerance(1.0))
    # Attractors are numbered by their first start: start 0 (x = −2.3) reaches +1.
    assert [a.first_start for a in duffing.attractors] == [0, 4]


@pytest.fixture(scope="module")
def duffing_chunked():
    return gj.basins(DUFFING, DUFFING_STARTS, 0.0, DUFFING_ARGS, chunk_size=5, **DUFFING_RUN)


def test_chunked_is_unchunked(duffing, duffing_chunked):
    # 24 starts in chunks of 5 (the last one padded): the attractor table carries over
    # from chunk to chunk, so labels and attractors are those of one chunk of 24.
    np.testing.assert_array_equal(duffing_chunked.labels, duffing.labels)
    np.testing.assert_array_equal(duffing_chunked.status, duffing.status)
    np.testing.assert_array_equal(duffing_chunked.fractions, duffing.fractions)
    for a, b in zip(duffing_chunked.attractors, duffing.attractors, strict=True):
        np.testing.assert_allclose(a.points, b.points, rtol=0, atol=1e-14)
        assert (a.period, a.first_start) == (b.period, b.first_start)


def test_features_group_the_starts_as_the_recurrences_do(duffing):
    # The mean position over the section points is ≈ ±1; groups of radius 0.5.
    by_features = gj.basins(DUFFING, DUFFING_STARTS, 0.0, DUFFING_ARGS,
                            features=duffing_mean_position, grid=0.5, **DUFFING_RUN)
    np.testing.assert_array_equal(by_features.labels, duffing.labels)
    features = np.array([a.feature[0] for a in by_features.attractors])
    np.testing.assert_allclose(features, [1.0, -1.0], rtol=0, atol=recurrence_tolerance(1.0))
    assert [a.period for a in by_features.attractors] == [1, 1]


# --------------------------------------------------------------------------------------
# An impact system: a ball on a vibrating table, Γ = Aω²/g = 1.05, e = 0.8
# --------------------------------------------------------------------------------------
# Two attractors coexist with chatter: the period-1 orbit (one impact per table period,
# v⁺ = gT/2, x⁺ = A sin φ, cos φ = πr/Γ, r = (1 − e)/(1 + e), stable up to
# Γ_PD = √((πr)² + (1 + r²)²) = 1.0708) and a period-3 orbit of three different impacts;
# starts that chatter down onto the table end ZENO.

TABLE = ex.vibrating_table()
OMEGA, G, E, GAMMA = 2 * math.pi, 9.81, 0.8, 1.05
TABLE_ARGS = dict(g=G, e=E, A=GAMMA * G / OMEGA**2, omega=OMEGA)
TABLE_SHAPE = (8, 8)
TABLE_EXTENT = (0.05, 1.5, -3.0, 3.0)
_H, _V = np.meshgrid(np.linspace(0.05, 1.5, 8), np.linspace(-3.0, 3.0, 8))
TABLE_STARTS = np.stack([_H.ravel(), _V.ravel()], axis=1)
TABLE_TRANSIENT, TABLE_POINTS = 60.0, 16


def table_impact_map(x0, args, t_skip, count, dt=1e-3, slowest=1e-3):
    """An independent impact map: the post-impact states (x⁺, v⁺) of the first `count`
    impacts at θ ≥ t_skip, or None when the ball chatters (relative speed after an impact
    below `slowest`, or a flight shorter than dt).

    A flight is a parabola; its impact is the first sign change of the gap
    x(s) − A sin(ωs) on a grid of step dt, refined by Brent's method to round-off.
    """
    g, e, amplitude, omega = args["g"], args["e"], args["A"], args["omega"]
    t, x, v = 0.0, float(x0[0]), float(x0[1])
    steps = dt * np.arange(1, 6001)
    out = []
    while len(out) < count:
        def gap(s, t=t, x=x, v=v):
            return x + v * (s - t) - 0.5 * g * (s - t) ** 2 - amplitude * math.sin(omega * s)

        values = x + v * steps - 0.5 * g * steps**2 - amplitude * np.sin(omega * (t + steps))
        first = int(np.argmax(values < 0))
        if first == 0:
            return None  # no impact within the grid, or a flight shorter than dt
        theta = brentq(gap, t + steps[first - 1], t + steps[first], xtol=1e-15, rtol=1e-15)
        table_speed = amplitude * omega * math.cos(omega * theta)
        v = table_speed - e * (v - g * (theta - t) - table_speed)
        t, x = theta, amplitude * math.sin(omega * theta)
        if v - table_speed < slowest:
            return None
        if t >= t_skip:
            out.append((x, v))
    return np.array(out)


def shift_distance(cycle, points):
    """The distance (max norm) between two cycles of one length, over cyclic shifts."""
    return min(np.max(np.abs(np.roll(cycle, -s, axis=0) - points)) for s in range(len(cycle)))


def reference_labels(reference, attractors):
    """The label each reference sequence deserves: −1 for chatter (None) or no recurrence
    within TOL (a transient not yet decayed), else the attractor whose cycle its last
    points are, up to a cyclic shift (−2 if none: a cycle the tested run did not find)."""
    labels = []
    for points in reference:
        if points is None:
            labels.append(-1)
            continue
        tol = recurrence_tolerance(np.max(np.abs(points)))
        recurs = any(np.all(np.abs(points[p:] - points[:-p]) <= tol)
                     for p in range(1, len(points) // 2 + 1))
        matches = [k for k, a in enumerate(attractors)
                   if shift_distance(a.points, points[-a.period:]) <= tol]
        labels.append(-1 if not recurs else (matches[0] if matches else -2))
    return np.array(labels)


@pytest.fixture(scope="module")
def table():
    return gj.basins(TABLE, TABLE_STARTS, 0.0, TABLE_ARGS, surface=0, num_points=TABLE_POINTS,
                     transient=TABLE_TRANSIENT, max_impacts=200)


@pytest.fixture(scope="module")
def table_reference():
    return [table_impact_map(x0, TABLE_ARGS, TABLE_TRANSIENT, TABLE_POINTS)
            for x0 in TABLE_STARTS]


def test_table_attractors_are_the_closed_form_period_1_and_the_reference_period_3(
        table, table_reference):
    assert sorted(a.period for a in table.attractors) == [1, 3]
    (one,) = [a for a in table.attractors if a.period == 1]
    r = (1 - E) / (1 + E)
    phase = math.acos(math.pi * r / GAMMA)
    exact = np.array([TABLE_ARGS["A"] * math.sin(phase), G * (2 * math.pi / OMEGA) / 2])
    tol = recurrence_tolerance(exact[1])
    np.testing.assert_allclose(one.points[0], exact, rtol=0, atol=tol)  # measured 6e-8
    (three,) = [a for a in table.attractors if a.period == 3]
    # The period-3 cycle of the reference, from its first start: measured 1.5e-13.
    reference = table_reference[three.first_start][-3:]
    assert shift_distance(three.points, reference) <= recurrence_tolerance(7.0)


def test_table_labels_agree_with_the_reference_impact_map(table, table_reference):
    np.testing.assert_array_equal(table.labels,
                                  reference_labels(table_reference, table.attractors))
    # Chatter: the run ends ZENO before its points, the start is in no basin.
    chatter = np.array([reference is None for reference in table_reference])
    assert 0 < chatter.sum() < len(TABLE_STARTS)
    np.testing.assert_array_equal(table.status[chatter], gj.BasinStatus.FAILED)
    np.testing.assert_array_equal(table.run_status[chatter], gj.Status.ZENO)
    # Measured: 24 starts on the period-1 orbit, 15 on the period-3 one, 25 chatter; the
    # largest distance between a start's reference cycle and its attractor 1.7e-6.
    assert table.num_undecided == chatter.sum()


def table_args_of(gamma):
    return dict(TABLE_ARGS, A=gamma * G / OMEGA**2)


def test_basin_continuation_keeps_each_attractor_through_the_period_doubling(table):
    """Γ = 1.0, 1.05, 1.09, 1.12 on the table's grid (its program: args are inputs): the
    period-1 orbit (v⁺ = gT/2, closed form) doubles past Γ_PD = 1.0708 and keeps its id,
    the period-3 orbit keeps the other; each value's fractions are `basins`' own (the
    fixture at Γ = 1.05). With `match_distance` below the doubling's jump (measured
    Hausdorff distance 0.53) the period-2 orbit is a new attractor instead."""
    gammas = [1.0, 1.05, 1.09, 1.12]
    curve = gj.continue_basins(TABLE, TABLE_STARTS, 0.0, table_args_of, gammas, surface=0,
                               num_points=TABLE_POINTS, transient=TABLE_TRANSIENT,
                               max_impacts=200)
    assert curve.fractions.shape == (4, 2)
    periods = [{key: a.period for key, a in found.items()} for found in curve.attractors]
    (doubling,) = [key for key, period in periods[0].items() if period == 1]
    assert [p[doubling] for p in periods] == [1, 1, 2, 2]
    assert [p[1 - doubling] for p in periods] == [3, 3, 3, 3]
    for found in curve.attractors[:2]:
        np.testing.assert_allclose(found[doubling].points[0, 1], G / 2, rtol=0, atol=1e-6)
    # Γ = 1.05: the same labels and fractions as the fixture, up to the ids' order.
    ids = {k: key for key, a in curve.attractors[1].items()
           for k, b in enumerate(table.attractors) if a.period == b.period}
    mapped = np.array([ids[k] if k >= 0 else -1 for k in table.labels])
    np.testing.assert_array_equal(curve.labels[1], mapped)
    np.testing.assert_allclose(curve.fractions[1, [ids[0], ids[1]]], table.fractions, rtol=0,
                               atol=0)
    np.testing.assert_allclose(curve.fractions.sum(axis=1) + curve.num_undecided / 64, 1.0)
    strict = gj.continue_basins(TABLE, TABLE_STARTS, 0.0, table_args_of, gammas[1:3],
                                surface=0, num_points=TABLE_POINTS,
                                transient=TABLE_TRANSIENT, max_impacts=200,
                                match_distance=0.3)
    assert strict.fractions.shape == (2, 3)
    assert np.count_nonzero(strict.fractions[0]) == 2 and strict.fractions[0, 2] == 0


def test_fractions_and_standard_errors_by_formula(table):
    total = len(TABLE_STARTS)
    counts = np.array([np.count_nonzero(table.labels == k) for k in range(table.num_attractors)])
    assert np.all(counts > 0)
    np.testing.assert_array_equal(table.fractions, counts / total)
    s = counts / total
    np.testing.assert_allclose(table.standard_errors, np.sqrt(s * (1 - s) / total), rtol=1e-15)
    # Starts labelled −1 count in the total only.
    assert counts.sum() + table.num_undecided == total
    np.testing.assert_allclose(table.fractions.sum(), 1 - table.num_undecided / total,
                               rtol=1e-15)
    in_no_basin = table.labels == -1
    np.testing.assert_array_equal(in_no_basin, table.status != gj.BasinStatus.ATTRACTOR)
    assert np.all(table.run_status[table.status == gj.BasinStatus.FAILED] != gj.Status.SUCCESS)


def test_plot_basins_draws_the_labels_with_no_basin_grey(table):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = gj.plot_basins(table, TABLE_SHAPE, TABLE_EXTENT)
    (image,) = fig.axes[0].images
    np.testing.assert_array_equal(np.asarray(image.get_array()),
                                  table.labels.reshape(TABLE_SHAPE) + 1)
    assert image.cmap(0)[:3] == pytest.approx((0.6, 0.6, 0.6))  # label −1
    assert len(fig.axes[0].get_legend().get_texts()) == table.num_attractors + 1
    plt.close(fig)


# --------------------------------------------------------------------------------------
# The classification on synthetic sequences (no compilation)
# --------------------------------------------------------------------------------------


def _section(points, status):
    """A batched `gj.Section` of given points and per-point statuses."""
    points = np.asarray(points, np.float64)
    status = np.asarray(status, np.int64)
    return gj.Section(points=points, times=np.zeros(status.shape), status=status,
                      run_status=status[:, -1], num_events=np.zeros(len(points), np.int64))


def _classify(points, status, bound=None):
    table = []
    config = dict(features=None, grid=None, bound=bound, factor=RECURRENCE_FACTOR, rtol=RTOL,
                  atol=ATOL)
    labels, basin_status, run_status, period, _ = _classify_chunk(
        _section(points, status), 0, table, config)
    return labels, basin_status, run_status, period, table


def test_classification_of_synthetic_sequences():
    n_points = 12
    rng = np.random.default_rng(0)
    a, b = np.array([1.0, 0.0]), np.array([-1.0, 0.5])
    two_cycle = np.array([a, b] * (n_points // 2)) + 1e-9 * rng.standard_normal((n_points, 2))
    fixed = np.tile([0.3, 0.3], (n_points, 1))
    angles = 2.399963 * np.arange(n_points)  # golden-angle rotation: quasi-periodic
    ok = np.zeros(n_points, np.int64)
    missing = np.where(np.arange(n_points) < 5, gj.Status.SUCCESS, gj.Status.MAX_IMPACTS)
    cut = np.where(np.arange(n_points)[:, None] < 5, fixed, np.nan)
    tol = recurrence_tolerance(0.3)  # 3.1e-6 for the fixed point
    drift = fixed + 0.5 * tol * np.arange(n_points)[:, None]  # recurs, never settles
    converging = fixed + 0.5 * tol * 0.8 ** np.arange(n_points)[:, None]
    sequences = [
        (two_cycle, ok),                          # 0: period 2
        (np.roll(two_cycle, 1, axis=0), ok),      # 1: the same cycle, other phase
        (fixed, ok),                              # 2: a fixed point
        (fixed + 0.6 * tol, ok),                  # 3: the same within tolerance
        (fixed + 1e-4, ok),                       # 4: another fixed point
        (np.stack([np.cos(angles), np.sin(angles)], 1), ok),  # 5: no recurrence
        (cut, missing),                           # 6: run stopped at MAX_IMPACTS
        (np.tile([1e3, 0.0], (n_points, 1)), ok),  # 7: beyond bound = 100
        (drift, ok),                              # 8: a drift of 0.5 TOL per map
        (converging, ok),                         # 9: steps shrinking by 0.8 per map
    ]
    labels, status, run_status, period, table = _classify(
        [p for p, _ in sequences], [s for _, s in sequences], bound=100.0)
    np.testing.assert_array_equal(labels, [0, 0, 1, 1, 2, -1, -1, -1, -1, 1])
    B = gj.BasinStatus
    np.testing.assert_array_equal(
        status, [B.ATTRACTOR] * 5 + [B.UNDECIDED, B.FAILED, B.DIVERGED, B.UNDECIDED, B.ATTRACTOR])
    assert run_status[6] == gj.Status.MAX_IMPACTS
    assert np.all(np.delete(run_status, 6) == gj.Status.SUCCESS)
    np.testing.assert_array_equal(period[[0, 1, 2, 3, 4, 8, 9]], [2, 2, 1, 1, 1, 1, 1])
    # The cycle starts from its lexicographically smallest point: b = (−1, 0.5) first.
    np.testing.assert_allclose(table[0].points, [b, a], rtol=0, atol=1e-8)
    assert [t.first_start for t in table] == [0, 2, 4]


# --------------------------------------------------------------------------------------
# Slow: a larger table grid, in padded chunks, against the reference map
# --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_table_basins_on_a_20x20_grid_in_chunks_agree_with_the_reference_map():
    # 400 starts in chunks of 64 (the last one padded with copies of its first start):
    # every label agrees with the independent impact map, so the basin stabilities are
    # the reference's own counts over N.
    h, v = np.meshgrid(np.linspace(0.05, 1.5, 20), np.linspace(-3.0, 3.0, 20))
    starts = np.stack([h.ravel(), v.ravel()], axis=1)
    result = gj.basins(TABLE, starts, 0.0, TABLE_ARGS, surface=0, num_points=TABLE_POINTS,
                       transient=TABLE_TRANSIENT, max_impacts=200, chunk_size=64)
    reference = [table_impact_map(x0, TABLE_ARGS, TABLE_TRANSIENT, TABLE_POINTS)
                 for x0 in starts]
    assert sorted(a.period for a in result.attractors) == [1, 3]
    expected = reference_labels(reference, result.attractors)
    np.testing.assert_array_equal(result.labels, expected)
    chatter = np.array([cycle is None for cycle in reference])
    np.testing.assert_array_equal(result.run_status[chatter], gj.Status.ZENO)
    # Measured: a start still on its slow transient at t = 60 (UNDECIDED, like its
    # reference sequence), the others in the counts below.
    undecided = ~chatter & (expected == -1)
    np.testing.assert_array_equal(result.status[undecided], gj.BasinStatus.UNDECIDED)
    counts = np.bincount(expected[expected >= 0], minlength=2)
    np.testing.assert_array_equal(result.fractions, counts / len(starts))


def ex1dof_wall_reached(points):
    """+1 if the last section point (the top of the turn, x2 = 0 falling, x1 > 1) lies
    beyond x1 = 2, i.e. the orbit's radius about (1, 0) exceeds 1 so that it reaches the
    wall x1 = 0; −1 otherwise."""
    return jnp.sign(points[-1, 0] - 2.0)


def ex1dof_velocity(t, x, args):
    """The user section x2 = 0 (module level: one program)."""
    return x[1]


# --------------------------------------------------------------------------------------
# A published case: bSTAB's damped driven pendulum (Stender & Hoffmann 2021, case 1)
# --------------------------------------------------------------------------------------

# θ'' + αθ' + K sin θ = T with α = 0.1, T = 0.5, K = 1: a stable equilibrium (FP) at
# θ = asin(T/K) and a rotating limit cycle (LC). bSTAB's basin stability from 10,000
# uniform starts on [−π + asin(T/K), π + asin(T/K)] × [−10, 10] (its published case 1,
# also pyBasin's reference): FP 0.152, LC 0.848, standard error 0.0036.
PENDULUM_ARGS = {"alpha": 0.1, "T": 0.5, "K": 1.0}
BSTAB_FP, BSTAB_SE = 0.152, 0.0035902089075707


def pendulum_field(t, x, a):
    return jnp.stack([x[1], -a["alpha"] * x[1] + a["T"] - a["K"] * jnp.sin(x[0])])


def pendulum_mean_speed(points):
    """bSTAB classifies by the speed's spread over the settled run; its mean separates the
    same two attractors (0 at the equilibrium, about T/α on the rotation)."""
    return jnp.mean(points[:, 1])


def test_pendulum_basin_stability_matches_bstab_and_scipy():
    n = 10_000
    rng = np.random.default_rng(0)
    low = -np.pi + np.arcsin(0.5)
    starts = np.stack([rng.uniform(low, low + 2 * np.pi, n), rng.uniform(-10, 10, n)], axis=1)
    b = gj.basins(gj.Scene(pendulum_field), starts, 0.0, PENDULUM_ARGS, period=1.0,
                  num_points=16, transient=300.0, features=pendulum_mean_speed, grid=0.5)
    labels = np.asarray(b.labels)
    assert np.all(labels >= 0)
    fp = int(np.argmin([abs(float(a.feature[0])) for a in b.attractors]))
    assert len(b.attractors) == 2
    # The equilibrium is the closed form (asin(T/K) mod 2π, 0), to the recurrence tolerance.
    point = np.asarray(b.attractors[fp].points)[-1]
    phase = (point[0] - np.arcsin(0.5) + np.pi) % (2 * np.pi) - np.pi
    assert abs(phase) < 1e-5 and abs(point[1]) < 1e-5
    # Two Monte Carlo estimates of the same fraction: within 3 joint standard errors
    # (measured: 0.1537 ± 0.0036 here against 0.152 ± 0.0036).
    fraction, error = float(b.fractions[fp]), float(b.standard_errors[fp])
    print(f"FP basin stability {fraction:.4f} ± {error:.4f}")
    assert abs(fraction - BSTAB_FP) < 3 * math.hypot(error, BSTAB_SE), (fraction, error)
    # Start by start against SciPy's DOP853: the attractor each of 40 starts reaches.
    for i in rng.choice(n, 40, replace=False):
        ref = solve_ivp(lambda t, x: [x[1], -0.1 * x[1] + 0.5 - np.sin(x[0])], (0.0, 316.0),
                        starts[i], method="DOP853", rtol=1e-10, atol=1e-12,
                        t_eval=np.linspace(300.0, 316.0, 17))
        assert (labels[i] == fp) == (abs(np.mean(ref.y[1])) < 1.0), i


@pytest.mark.slow
def test_ex1dof_basins_reproduce_the_notebook_by_features_and_by_recurrences():
    # notebooks/04-basins.ipynb at 16×16: ex1dof, μ = −0.2, horizon T = 200; a start is on
    # the impacting cycle if it hit the wall during the last three turns (its own
    # classification, from gj.sweep's impact log, repeated here). Through the new API:
    # sections at the top of each turn (x2 = 0 falling) over the last three turns, one
    # feature: whether the orbit still reaches the wall. Measured: 23.4% of the starts
    # impacting, the same starts in both.
    g1, g2 = np.linspace(-0.1, 2.1, 16), np.linspace(-1.1, 1.1, 16)
    x1, x2 = np.meshgrid(g1, g2)
    starts = np.stack([x1.ravel(), x2.ravel()], axis=1)
    scene, args, horizon = ex.ex1dof(), ex.ex1dof_args(-0.2), 200.0
    notebook = gj.sweep(scene, starts, 0.0, horizon, args, rtol=1e-7, atol=1e-9,
                        max_impacts=64, progress=False)
    k = notebook.num_impacts
    last = np.where(k > 0, notebook.impact_times[np.arange(len(k)), np.maximum(k - 1, 0)],
                    -np.inf)
    impacting = last > horizon - 3 * 2 * np.pi
    assert 0 < impacting.mean() < 1
    run = dict(section=ex1dof_velocity, direction=-1, num_points=8,
               transient=horizon - 3 * 2 * np.pi, rtol=1e-7, atol=1e-9, max_impacts=128)
    result = gj.basins(scene, starts, 0.0, args, features=ex1dof_wall_reached, grid=0.5,
                       **run)
    assert result.num_undecided == 0
    (wall,) = [k for k, a in enumerate(result.attractors) if a.feature[0] == 1.0]
    np.testing.assert_array_equal(result.labels == wall, impacting)
    np.testing.assert_allclose(result.fractions[wall], impacting.mean(), rtol=1e-15)
    # The recurrences alone (the same program): the impacting cycle is the one attractor,
    # with the same basin. The non-impacting starts recur too (their radius drifts by
    # less than the tolerance per turn at ε = 1e-4) but do not settle: UNDECIDED, not a
    # continuum of circles taken for attractors.
    recurrences = gj.basins(scene, starts, 0.0, args, **run)
    assert recurrences.num_attractors == 1
    np.testing.assert_array_equal(recurrences.labels == 0, impacting)
    np.testing.assert_array_equal(recurrences.status[~impacting], gj.BasinStatus.UNDECIDED)
    assert np.count_nonzero(recurrences.period[~impacting] > 0) > 0  # measured 32 of 196


def mean_point(points):
    """A feature: the mean section point (module level: one program)."""
    return jnp.mean(points, axis=0)


def test_feature_grouping_of_synthetic_sequences():
    # Leader clustering with radius 0.1: no recurrence needed (the rotation is one group),
    # a failed run is −1 whatever its feature, groups numbered by their first start.
    n_points = 12
    angles = 2.399963 * np.arange(n_points)
    rotation = np.stack([np.cos(angles), np.sin(angles)], 1)  # mean ≈ (0.03, 0.01)
    fixed = np.tile([2.0, 0.0], (n_points, 1))
    ok = np.zeros(n_points, np.int64)
    zeno = np.where(np.arange(n_points) < 4, gj.Status.SUCCESS, gj.Status.ZENO)
    sequences = [(rotation, ok), (fixed, ok), (fixed + 0.05, ok), (rotation + 0.3, ok),
                 (np.where(np.arange(n_points)[:, None] < 4, fixed, np.nan), zeno)]
    table = []
    config = dict(features=mean_point, grid=0.1, bound=None, factor=RECURRENCE_FACTOR,
                  rtol=RTOL, atol=ATOL)
    labels, status, run_status, _, radius = _classify_chunk(
        _section([p for p, _ in sequences], [s for _, s in sequences]), 0, table, config)
    np.testing.assert_array_equal(labels, [0, 1, 1, 2, -1])
    B = gj.BasinStatus
    np.testing.assert_array_equal(status, [B.ATTRACTOR] * 4 + [B.FAILED])
    assert run_status[4] == gj.Status.ZENO
    np.testing.assert_allclose(table[1].feature, [2.0, 0.0], rtol=0, atol=1e-15)
    assert [t.period for t in table] == [0, 1, 0]  # the rotation has no period
    np.testing.assert_array_equal(radius, 0.1)


def test_bad_arguments_raise_before_any_run():
    run = dict(period=1.0, num_points=8, transient=1.0)
    with pytest.raises(ValueError, match="shape"):
        gj.basins(DUFFING, np.array([0.5, 0.0]), 0.0, DUFFING_ARGS, **run)
    with pytest.raises(TypeError, match="grid"):
        gj.basins(DUFFING, DUFFING_STARTS, 0.0, DUFFING_ARGS, grid=0.5, **run)
    with pytest.raises(ValueError, match="exactly one"):
        gj.basins(DUFFING, DUFFING_STARTS, 0.0, DUFFING_ARGS, num_points=8, transient=1.0)
    with pytest.raises(ValueError, match="chunk_size"):
        gj.basins(DUFFING, DUFFING_STARTS, 0.0, DUFFING_ARGS, chunk_size=0, **run)
    with pytest.raises(ValueError, match="at least one"):
        gj.continue_basins(DUFFING, DUFFING_STARTS, 0.0, lambda d: {"delta": d}, [], **run)
    with pytest.raises(ValueError, match="match_distance"):
        gj.continue_basins(DUFFING, DUFFING_STARTS, 0.0, lambda d: {"delta": d}, [0.5],
                           match_distance=-1.0, **run)
