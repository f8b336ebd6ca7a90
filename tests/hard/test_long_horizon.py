"""Long horizons: 10^4 elastic impacts, drift measured against closed forms.

- Bouncing ball, e = 1: free fall is integrated exactly up to round-off, and the Runge–Kutta
  sums are taken relative to the first stage (exact for a constant field), so impact speeds
  carry a round-off that does not grow with n and impact-time errors grow like n (like n²
  when every flight gained the same ulps of speed).
- Rotation x'' = −x with an elastic wall x1 = 0: each half turn carries the solver's error
  (~ its tolerance); drift of the energy and of the impact times must stay below
  C × rtol × n, C = O(1).
"""

import math

import diffrax
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex

from ._common import EPS, f64, f64_args, record, runner, status

N = 10_000


def _elastic_ball(t1):
    return runner("ball", "default", max_impacts=N)(
        f64([1.0, 0.0]), f64(0.0), f64(t1), f64_args(g=9.81, e=1.0)
    )


# Round-off of an elastic ball's energy at any impact, in ulps: a bound independent of the
# number of impacts (measured maxima 130 at t1 = 1e4 and 132 at t1 = 1e6 over 10^4 impacts).
# A flight-to-flight gain of even one ulp would pass it within 2048 impacts.
ENERGY_ULPS = 2048


def _drift_and_time_errors(sol, h0, g):
    exact, _ = ex.bouncing_ball_impact_times(h0, 0.0, g, 1.0, int(sol.num_impacts))
    n = len(exact)
    pre = np.asarray(sol.impact_pre)[:n]
    w = math.sqrt(2 * g * h0)
    drift = np.abs((0.5 * pre[:, 1] ** 2 + g * pre[:, 0]) / (0.5 * w * w) - 1)
    return drift, np.abs(np.asarray(sol.impact_times)[:n] - exact), exact


def test_elastic_ball_ten_thousand_impacts():
    """t1 = 1e4 (the 10^4th impact is at t ≈ 9030). Free fall is exact up to round-off: the
    energy stays within a round-off bound that does not grow with n, so a time error is
    the speed's relative round-off times the time itself — linear in n."""
    sol = _elastic_ball(1e4)
    assert status(sol) == gj.Status.MAX_IMPACTS
    assert int(sol.num_impacts) == N
    drift, err_t, exact = _drift_and_time_errors(sol, 1.0, 9.81)
    assert np.all(drift <= ENERGY_ULPS * EPS)
    assert np.all(err_t <= ENERGY_ULPS * EPS * exact)
    assert float(np.min(np.asarray(sol.impact_pre)[:, 0])) > -1e-15  # no tunnelling
    record("ball e=1, 1e4 impacts (t1=1e4): max energy error / eps", np.max(drift) / EPS)
    record("ball e=1, 1e4 impacts (t1=1e4): |t_n - exact| at n=1e4", err_t[-1])


def test_elastic_ball_accuracy_does_not_depend_on_a_far_horizon():
    """t1 = 1e6 instead of 1e4: the steps may grow with the horizon (the flow is exact, its
    error estimate 0), the accuracy must not."""
    sol = _elastic_ball(1e6)
    assert status(sol) == gj.Status.MAX_IMPACTS
    assert float(np.min(np.asarray(sol.impact_pre)[:, 0])) > -1e-15
    drift, err_t, exact = _drift_and_time_errors(sol, 1.0, 9.81)
    assert np.all(drift <= ENERGY_ULPS * EPS)
    assert np.all(err_t <= ENERGY_ULPS * EPS * exact)
    record("ball e=1, 1e4 impacts (t1=1e6): max energy error / eps", np.max(drift) / EPS)


@pytest.mark.parametrize("solver", ["default", "Dopri8"])
def test_elastic_ball_over_sciml_long_horizon(solver):
    """SciML's long-horizon event test: h = 50, g = 9.8, t in [0, 1e4], rtol = atol = 1e-10:
    all 1565 impacts, each time within 1e-8 of the closed form, and the error linear in
    the impact count (bounded by the energy's round-off times the time itself)."""
    kw = {} if solver == "default" else {"solver": getattr(diffrax, solver)()}
    sol = gj.simulate(ex.bouncing_ball(), f64([50.0, 0.0]), 0.0, 1e4, f64_args(g=9.8, e=1.0),
                      rtol=1e-10, atol=1e-10, max_impacts=1600, **kw)
    assert status(sol) == gj.Status.SUCCESS
    exact, _ = ex.bouncing_ball_impact_times(50.0, 0.0, 9.8, 1.0, 1600)
    assert int(sol.num_impacts) == int(np.sum(exact <= 1e4)) == 1565
    drift, err_t, exact = _drift_and_time_errors(sol, 50.0, 9.8)
    assert np.max(err_t) <= 1e-8
    assert np.all(drift <= ENERGY_ULPS * EPS)
    assert np.all(err_t <= ENERGY_ULPS * EPS * exact)
    record(f"ball h=50, 1565 impacts, {solver}: |t_n - exact| at n=1565", err_t[-1])


def test_elastic_ball_with_t1_infinite_runs_max_impacts():
    """`t1 = inf` is the documented way to run "N impacts"."""
    sol = _elastic_ball(math.inf)
    assert status(sol) == gj.Status.MAX_IMPACTS
    pre = np.asarray(sol.impact_pre)
    assert float(np.min(pre[:, 0])) > -1e-15
    exact, _ = ex.bouncing_ball_impact_times(1.0, 0.0, 9.81, 1.0, N)
    np.testing.assert_allclose(sol.impact_times, exact, rtol=1e-9)


def _rotation_drift(tol, n_impacts):
    sol = runner("rotation_wall", tol, max_impacts=n_impacts, max_steps=200 * n_impacts)(
        f64([0.0, 1.0]), f64(0.0), f64(math.inf), f64_args(c=0.0)
    )
    assert status(sol) == gj.Status.MAX_IMPACTS
    n = np.arange(1, n_impacts + 1)
    post = np.asarray(sol.impact_post)
    energy_err = np.abs(post[:, 0] ** 2 + post[:, 1] ** 2 - 1)
    time_err = np.abs(np.asarray(sol.impact_times) - math.pi * n)
    return energy_err, time_err, n


@pytest.mark.parametrize(
    "tol,rtol,n_impacts",
    [
        ("default", 1e-8, N),
        pytest.param("tight", 1e-12, N, marks=pytest.mark.slow),
    ],
)
def test_rotation_with_elastic_wall_drift_is_linear_in_tolerance(tol, rtol, n_impacts):
    """x = (|sin t|, ...): impacts at t_n = nπ exactly, energy x1² + x2² = 1."""
    energy_err, time_err, n = _rotation_drift(tol, n_impacts)
    c_energy = np.max(energy_err / (rtol * n))
    c_time = np.max(time_err / (rtol * n))
    assert c_energy <= 2.0 and c_time <= 2.0
    record(f"rotation 1e4 impacts {tol}: max |E_n - 1| / (rtol n)", c_energy)
    record(f"rotation 1e4 impacts {tol}: max |t_n - n pi| / (rtol n)", c_time)
