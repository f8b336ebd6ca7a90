"""A stiff flow with the implicit diffrax.Kvaerno5.

State (x, u): the set point u descends at speed c (u' = −c) and x relaxes to it fast,
x' = −λ (x − u), λ up to 1e6. Wall Φ = x (free side x > 0); the impact raises the set
point, u → u + H. Closed form of a flight from (x0, u0):

    x(s) = u0 + c/λ − c s + (x0 − u0 − c/λ) e^{−λ s},

so after the transient (e^{−λ s} underflows to 0 in double long before the wall) the first
impact is at t_1 = u0/c + 1/λ, in the state (0, −c/λ), and every later flight lasts exactly
H/c. An explicit method would need ~λ·H/(3.3 c) steps per flight (stability); Kvaerno5
takes a few dozen.
"""

import diffrax
import jax.numpy as jnp
import mpmath
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import grazejax as gj

from ._common import f64, f64_args, record, runner, status

RELAXATION = gj.Scene(
    lambda t, x, a: jnp.stack([-a["lam"] * (x[0] - x[1]), -a["c"] * jnp.ones_like(x[1])]),
    [
        gj.Surface(
            phi=lambda t, x, a: x[0],
            jump=lambda t, x, a: x.at[1].add(a["H"]),
            inverse_jump=lambda t, x, a: x.at[1].add(-a["H"]),
            impenetrable=True,
            name="x = 0",
        )
    ],
)
KVAERNO5 = diffrax.Kvaerno5()
N_IMPACTS = 20


def _reference_times(x0, u0, lam, c, H, n):
    """Impact times from the closed-form flights, roots in 50-digit arithmetic."""
    with mpmath.workdps(50):
        lam, c, H = mpmath.mpf(lam), mpmath.mpf(c), mpmath.mpf(H)
        x, u, t, times = mpmath.mpf(x0), mpmath.mpf(u0), mpmath.mpf(0), []
        for _ in range(n):
            def flight(s, x=x, u=u):
                return u + c / lam - c * s + (x - u - c / lam) * mpmath.exp(-lam * s)

            s_hi = abs(u) / c + 1 / lam + 1
            if x == 0:  # leaving the wall: concave flight, remove the root at s = 0
                s = mpmath.findroot(lambda s: flight(s) / s, (s_hi * mpmath.mpf(10) ** -30, s_hi),
                                    solver="illinois", verify=False)
            else:  # monotone or concave from x0 > 0: one root
                s = mpmath.findroot(flight, (mpmath.mpf(0), s_hi), solver="illinois", verify=False)
            t += s
            times.append(float(t))
            x, u = mpmath.mpf(0), u - c * s + H
        return np.array(times)


@settings(max_examples=6, deadline=None, derandomize=True)
@given(
    log_lam=st.floats(3, 6),
    c=st.floats(0.5, 2.0),
    H=st.floats(1.1, 2.0),
    x0=st.floats(0.1, 2.0),
    u0=st.floats(-1.0, 2.0),
)
def test_stiff_relaxation_towards_a_wall_kvaerno5(log_lam, c, H, x0, u0):
    """Random stiffness 1e3..1e6; with u0 < 0 the first impact happens inside the stiff
    transient (after ~ln(x0/|u0|)/λ), the hardest place to locate it."""
    lam = 10.0**log_lam
    run = runner(RELAXATION, "default", max_impacts=N_IMPACTS, solver=KVAERNO5)
    sol = run(f64([x0, u0]), f64(0.0), f64(1e3), f64_args(lam=lam, c=c, H=H))
    assert status(sol) == gj.Status.MAX_IMPACTS
    exact = _reference_times(x0, u0, lam, c, H, N_IMPACTS)
    rtol = 1e-8
    err_t = np.abs(np.asarray(sol.impact_times) - exact)
    assert np.all(err_t <= 10 * rtol * exact)
    pre = np.asarray(sol.impact_pre)
    np.testing.assert_allclose(pre[:, 0], 0.0, atol=1e-12)
    # After the first flight every impact happens at the set point's lag: u = −c/λ.
    np.testing.assert_allclose(pre[1:, 1], -c / lam, rtol=0, atol=10 * rtol * (abs(u0) + H))
    steps_per_flight = int(sol.num_steps) / N_IMPACTS
    assert steps_per_flight < 200
    record("stiff Kvaerno5: max |t_n - exact| / (rtol t_n)", np.max(err_t / (rtol * exact)))
    if u0 < 0:
        record("stiff Kvaerno5: first impact inside the transient, |t_1 - exact| / rtol",
               err_t[0] / rtol)
    record("stiff Kvaerno5: steps per flight", steps_per_flight)
    record("stiff Kvaerno5: explicit-stability steps per flight (min over cases)",
           lam * H / (3.3 * c), "min")
