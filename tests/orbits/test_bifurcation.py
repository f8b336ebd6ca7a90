"""Bifurcation points solved by their defining systems (`locate_bifurcation`), and their
derivatives in a second parameter, against the vibrating table's closed forms.

Period-1 orbits of the ball on a vibrating table (see test_orbit_derivatives.py) have
tr U = −2e + (1 + e)²(1 − √(Γ² − c²)), det U = e², c = π r, r = (1 − e)/(1 + e):
- fold (a multiplier 1, tr U = 1 + e²): √(Γ² − c²) = 0, Γ_LP = c, dΓ_LP/de = π r';
- period doubling (tr U = −(1 + e²)): √(Γ² − c²) = 1 + r², Γ_PD = √(c² + (1 + r²)²),
  dΓ_PD/de = (c c' + 2(1 + r²) r r')/Γ_PD, r' = −2/(1 + e)².
"""

import math
from types import SimpleNamespace

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax._orbits.bifurcation import bialternate_square

from .test_orbit_derivatives import OMEGA, PERIOD, TABLE, apex_start, table_args

E = 0.5


def _r(e):
    return (1 - e) / (1 + e), -2 / (1 + e) ** 2


def fold_closed(e):
    r, dr = _r(e)
    return math.pi * r, math.pi * dr


def period_doubling_closed(e):
    r, dr = _r(e)
    c, dc = math.pi * r, math.pi * dr
    gamma = math.sqrt(c * c + (1 + r * r) ** 2)
    return gamma, (c * dc + 2 * (1 + r * r) * r * dr) / gamma


def test_closed_forms_two_ways():
    """The hand derivatives against central differences, and the closed-form points
    against the trace formula they solve."""
    h = 1e-6
    for closed in (fold_closed, period_doubling_closed):
        np.testing.assert_allclose(closed(E)[1], (closed(E + h)[0] - closed(E - h)[0]) / (2 * h),
                                   rtol=1e-8)
    c = fold_closed(E)[0]
    gamma = period_doubling_closed(E)[0]
    trace = -2 * E + (1 + E) ** 2 * (1 - math.sqrt(gamma**2 - c**2))
    np.testing.assert_allclose(trace, -(1 + E**2), rtol=1e-14)


def guess(kind, gamma, e=E):
    t0, x0 = apex_start(gamma, e)
    return SimpleNamespace(kind=kind, mu=gamma, x0=x0, t0=t0, period=PERIOD)


def args_of(gamma, e):
    return table_args(gamma, e)


@pytest.mark.parametrize("kind, closed, offset", [
    ("period-doubling", period_doubling_closed, -0.01),
    pytest.param("fold", fold_closed, 0.01, marks=pytest.mark.slow),
])
def test_forced_point_and_its_derivative_match_the_closed_form(kind, closed, offset):
    """The point (the aux output) and its derivative from one `jax.jacfwd`: one compiled
    program, where a plain solve first compiled another for the same point."""
    gamma, d_gamma = closed(E)
    start = guess(kind, gamma + offset)

    def located(e):
        point = gj.locate_bifurcation(TABLE, start, args_of, e, rtol=1e-11)
        return point.mu, point

    derivative, point = jax.jacfwd(located, has_aux=True)(E)
    assert point.message == "SUCCESS"
    assert point.kind == kind
    np.testing.assert_allclose(float(point.mu), gamma, atol=1e-9)
    target = -1.0 if kind == "period-doubling" else 1.0
    assert np.min(np.abs(np.asarray(point.multipliers) - target)) < 1e-8
    assert abs(float(point.test_value)) < 1e-9
    np.testing.assert_allclose(float(derivative), d_gamma, rtol=1e-7)


def _autonomous_table():
    """The vibrating table driven by an attracting oscillator (c, s) = (cos ωt, sin ωt) on
    its limit cycle (radius 1, radial multiplier e^{−2T}), table A s: the forced orbit
    becomes an autonomous one of the same period, with the same bifurcations."""

    def field(t, x, args):
        pull = 1.0 - x[2] ** 2 - x[3] ** 2
        return jnp.stack([x[1], -args["g"] * jnp.ones_like(x[0]),
                          -args["omega"] * x[3] + x[2] * pull, args["omega"] * x[2] + x[3] * pull])

    def jump(t, x, args):
        w_dot = args["A"] * args["omega"] * x[2]
        return x.at[1].set(w_dot - args["e"] * (x[1] - w_dot))

    wall = gj.Surface(phi=lambda t, x, args: x[0] - args["A"] * x[3], jump=jump,
                      impenetrable=True)
    return gj.Scene(field, [wall])


@pytest.mark.slow
def test_autonomous_period_doubling_matches_the_forced_one():
    """The free-period system (unknowns T, x, μ; phase condition on the oscillator) finds
    the same Γ_PD and period."""
    gamma, _ = period_doubling_closed(E)
    t0, x0 = apex_start(gamma - 0.01, E)
    phase = OMEGA * t0
    start = SimpleNamespace(kind="period-doubling", mu=gamma - 0.01,
                            x0=[x0[0], x0[1], math.cos(phase), math.sin(phase)], t0=0.0,
                            period=PERIOD * 1.001)
    point = gj.locate_bifurcation(_autonomous_table(), start, args_of, E, fixed_period=False,
                                  rtol=1e-11)
    assert point.message == "SUCCESS"
    np.testing.assert_allclose(float(point.mu), gamma, atol=1e-9)
    np.testing.assert_allclose(float(point.period), PERIOD, rtol=1e-10)
    # Multipliers: the trivial 1, the table's −1 and −e² (their product is det = e²), the
    # oscillator's radial e^{−2T}.
    want = np.sort(np.array([1.0, -1.0, -(E**2), math.exp(-2 * PERIOD)]))
    np.testing.assert_allclose(np.sort(np.real(np.asarray(point.multipliers))), want, atol=1e-7)


@pytest.mark.slow
def test_reverse_mode_equals_forward_mode():
    """jax.grad of Γ_PD(e) through DirectAdjoint, under jit, equals the closed form (and so
    jacfwd's, tested above)."""
    gamma, d_gamma = period_doubling_closed(E)
    start = guess("period-doubling", gamma - 0.01)

    def mu(e):
        return gj.locate_bifurcation(TABLE, start, args_of, e, rtol=1e-11,
                                     adjoint=diffrax.DirectAdjoint()).mu

    np.testing.assert_allclose(float(jax.jit(jax.grad(mu))(E)), d_gamma, rtol=1e-7)


def test_bialternate_square_has_the_pairwise_products():
    rng = np.random.default_rng(0)
    for n in (2, 3, 4):
        U = rng.normal(size=(n, n))
        rho = np.linalg.eigvals(U)
        want = np.sort_complex(np.array([rho[i] * rho[j] for i in range(n) for j in range(i + 1, n)]))
        got = np.sort_complex(np.linalg.eigvals(np.asarray(bialternate_square(jnp.asarray(U)))))
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_bad_arguments_are_refused():
    start = guess("period-doubling", 1.5)
    with pytest.raises(ValueError, match="kind"):
        gj.locate_bifurcation(TABLE, start, args_of, E, kind="cusp")
    with pytest.raises(ValueError, match="RecursiveCheckpointAdjoint"):
        gj.locate_bifurcation(TABLE, start, args_of, E,
                              adjoint=diffrax.RecursiveCheckpointAdjoint())
    with pytest.raises(ValueError, match="fix"):
        gj.locate_bifurcation(TABLE, start, args_of, E, fixed_period=False, fix=7)
