"""Long horizons: 10^4 elastic impacts, drift measured against closed forms.

- Bouncing ball, e = 1: free fall is integrated exactly up to round-off, so impact speeds
  may drift only by round-off per impact; impact-time errors then grow like n².
- Rotation x'' = −x with an elastic wall x1 = 0: each half turn carries the solver's error
  (~ its tolerance); drift of the energy and of the impact times must stay below
  C × rtol × n, C = O(1).
"""

import math

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


def test_elastic_ball_ten_thousand_impacts():
    """t1 = 1e4 (the 10^4th impact is at t ≈ 9030). Free fall is exact up to round-off, so
    the energy drift is far below C·rtol·n: measured ~100 ulps per impact (Tsit5's tableau
    is not exact in binary), bounded here by 1e-3·rtol·n."""
    g, h0, rtol = 9.81, 1.0, 1e-8
    sol = _elastic_ball(1e4)
    assert status(sol) == gj.Status.MAX_IMPACTS
    assert int(sol.num_impacts) == N
    exact, _ = ex.bouncing_ball_impact_times(h0, 0.0, g, 1.0, N)
    n = np.arange(1, N + 1)
    w = math.sqrt(2 * g * h0)
    pre = np.asarray(sol.impact_pre)
    drift = np.abs((0.5 * pre[:, 1] ** 2 + g * pre[:, 0]) / (0.5 * w * w) - 1)
    assert np.all(drift <= 1e-3 * rtol * n)
    # A speed error growing like n shifts every later flight: time errors grow like n².
    err_t = np.abs(np.asarray(sol.impact_times) - exact)
    assert np.all(err_t <= 1e-3 * rtol * n**2 * (w / g))
    assert float(np.min(pre[:, 0])) > -1e-15  # no tunnelling
    record("ball e=1, 1e4 impacts (t1=1e4): energy drift per impact / eps", np.max(drift / n) / EPS)
    record("ball e=1, 1e4 impacts (t1=1e4): |t_n - exact| at n=1e4", err_t[-1])


def test_elastic_ball_accuracy_does_not_depend_on_a_far_horizon():
    """t1 = 1e6 instead of 1e4: the steps may grow with the horizon (the flow is exact, its
    error estimate 0), the accuracy must not: ~100 ulps of energy per impact either way."""
    sol = _elastic_ball(1e6)
    assert status(sol) == gj.Status.MAX_IMPACTS
    pre = np.asarray(sol.impact_pre)
    assert float(np.min(pre[:, 0])) > -1e-15
    n = np.arange(1, N + 1)
    drift = np.abs((0.5 * pre[:, 1] ** 2 + 9.81 * pre[:, 0]) / 9.81 - 1)
    assert np.all(drift <= 1024 * EPS * n)
    record("ball e=1, 1e4 impacts (t1=1e6): energy drift per impact / eps", np.max(drift / n) / EPS)


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
