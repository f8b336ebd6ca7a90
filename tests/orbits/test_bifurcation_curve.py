"""Special points of `continue_orbit` solved by their defining systems, and curves of
bifurcation points in two parameters (`continue_bifurcation`), against the vibrating
table's closed forms (test_bifurcation.py): Γ_PD(e) = √(c² + (1 + r²)²), Γ_LP(e) = c,
c = πr, r = (1 − e)/(1 + e). Along the period-doubling curve the other multiplier is
−e² (det U = e²), so at e = 1 (Γ = 1) both are −1: a 1:2 resonance.
"""

import math

import numpy as np
import pytest

import grazejax as gj
from grazejax._orbits.bifurcation_curve import _codim2_points, _watched

from .test_bifurcation import E, args_of, fold_closed, guess, period_doubling_closed
from .test_orbit_derivatives import TABLE, table_orbit

# Newton's tolerance on the defining system is 1e-9 relative (default); its quadratic
# convergence leaves the solved μ near the flow's own accuracy (rtol 1e-11).
MU_TOL = 1e-9


def _branch_args(gamma):
    return args_of(gamma, E)


@pytest.mark.parametrize("kind, stop, closed", [
    ("fold", 1.0, fold_closed),
    pytest.param("period-doubling", 1.6, period_doubling_closed, marks=pytest.mark.slow),
])
def test_continue_orbit_solves_its_special_points(kind, stop, closed):
    """The fold was the vertex of a parabola through three branch points (2.3e-7 from
    Γ_LP with a 1.9e-3 step), period doubling a secant search: both are now solved by
    their defining systems."""
    branch = gj.continue_orbit(TABLE, table_orbit(1.3, E), _branch_args, 1.3, stop,
                               progress=False, max_points=30, rtol=1e-11)
    found = [p for p in branch.special_points if p.kind == kind]
    assert len(found) == 1
    point = found[0]
    assert point.solved and point.fixed_period and point.num_impacts == 1
    assert abs(point.mu - closed(E)[0]) < MU_TOL
    target = 1.0 if kind == "fold" else -1.0
    assert np.min(np.abs(point.multipliers - target)) < 1e-7
    assert branch.to_dict()["special_points"][0]["solved"] is True


def test_period_doubling_curve_matches_the_closed_form_and_meets_the_resonance():
    gamma = period_doubling_closed(E)[0]
    start = guess("period-doubling", gamma + 0.003)
    curve = gj.continue_bifurcation(TABLE, start, args_of, gamma + 0.003, E, 1.1,
                                    progress=False, rtol=1e-11, ds=0.05, ds_max=0.2)
    assert curve.message == "reached nu_stop" and curve.kind == "period-doubling"
    assert curve.nu[0] == E and curve.nu[-1] == 1.1 and len(curve) >= 5
    want = np.array([period_doubling_closed(e)[0] for e in curve.nu])
    assert np.max(np.abs(curve.mu - want)) < MU_TOL
    # The multipliers −1 and −e² on every point, one impact per period.
    np.testing.assert_allclose(np.sort(curve.multipliers.real, axis=1),
                               np.stack([-np.maximum(1, curve.nu**2),
                                         -np.minimum(1, curve.nu**2)], axis=1), atol=1e-7)
    assert (curve.num_impacts == 1).all()
    # The 1:2 resonance at (Γ, e) = (1, 1), between the two points around it.
    (codim2,) = curve.codim2
    assert codim2.kind == "1:2 resonance"
    assert curve.nu[codim2.after - 1] < 1.0 < curve.nu[codim2.after]
    around = slice(codim2.after - 1, codim2.after + 1)
    assert abs(codim2.nu - 1.0) < np.ptp(curve.nu[around])
    assert abs(codim2.mu - 1.0) < np.ptp(curve.mu[around])


@pytest.mark.slow
def test_fold_curve_from_a_branch_point_matches_the_closed_form():
    branch = gj.continue_orbit(TABLE, table_orbit(1.3, E), _branch_args, 1.3, 1.0,
                               progress=False, max_points=30, rtol=1e-11)
    (fold,) = [p for p in branch.special_points if p.kind == "fold"]
    curve = gj.continue_bifurcation(TABLE, fold, args_of, fold.mu, E, 0.3, progress=False,
                                    rtol=1e-11)
    assert curve.message == "reached nu_stop" and curve.nu[-1] == 0.3
    want = np.array([fold_closed(e)[0] for e in curve.nu])
    assert np.max(np.abs(curve.mu - want)) < MU_TOL
    # A multiplier 1 and e² (det U = e²): nothing met on the way.
    np.testing.assert_allclose(np.sort(curve.multipliers.real, axis=1),
                               np.stack([curve.nu**2, np.ones(len(curve))], axis=1), atol=1e-7)
    assert curve.codim2 == ()


def _points(multiplier_rows, impacts=None, nus=None):
    from grazejax._orbits.arclength import CurvePoint
    from grazejax._orbits.bifurcation_curve import _Diagnostics

    rows = [np.asarray(r, complex) for r in multiplier_rows]
    nus = np.arange(len(rows), dtype=float) if nus is None else nus
    impacts = [1] * len(rows) if impacts is None else impacts
    return [CurvePoint(np.array([0.0, 10.0 + nu, nu]), np.zeros(3), 1,
                       _Diagnostics(0.0, 1.0, r, k)) for r, nu, k in zip(rows, nus, impacts, strict=True)]


def test_codimension_two_test_functions():
    """Each watched test function changes sign exactly where its event happens, on
    multipliers made up for the purpose."""
    # A period-doubling curve whose other multiplier goes 0.5 → 1.5: fold-flip.
    points = _points([[-1.0, 0.5], [-1.0, 1.5]])
    (p,) = _codim2_points("period-doubling", True, points)
    assert p.kind == "fold-flip" and p.after == 1 and p.nu == pytest.approx(0.5)
    # A fold curve of an autonomous orbit (two multipliers 1), the third through −1.
    (p,) = _codim2_points("fold", False, _points([[1.0, 1.0, -0.8], [1.0, 1.0, -1.2]]))
    assert p.kind == "fold-flip"
    # A Neimark–Sacker pair e^{±iθ} with θ from 0.8π to 0.6π: through 2π/3 (1:3).
    pair = [[np.exp(1j * t), np.exp(-1j * t), 0.1] for t in (0.8 * math.pi, 0.6 * math.pi)]
    (p,) = _codim2_points("neimark-sacker", True, _points(pair))
    assert p.kind == "1:3 resonance"
    # θ from 0.3π to 0.6π: through π/2 (1:4); the third multiplier through 1: fold-NS.
    pair = [[np.exp(0.3j * math.pi), np.exp(-0.3j * math.pi), 0.9],
            [np.exp(0.6j * math.pi), np.exp(-0.6j * math.pi), 1.1]]
    kinds = {p.kind for p in _codim2_points("neimark-sacker", True, _points(pair))}
    assert kinds == {"1:4 resonance", "fold-neimark-sacker"}
    # The impact count changes: the curve meets grazing.
    (p,) = _codim2_points("fold", True, _points([[1.0, 0.3], [1.0, 0.3]], impacts=[1, 2]))
    assert p.kind == "grazing"
    # Nothing happens: nothing is reported.
    assert _codim2_points("period-doubling", True, _points([[-1.0, 0.2], [-1.0, 0.4]])) == ()
    assert set(_watched("period-doubling", True, [-1.0, 0.2])) == {
        "fold-flip", "1:2 resonance", "flip-neimark-sacker"}


def test_bad_arguments_are_refused():
    start = guess("period-doubling", 1.5)
    with pytest.raises(ValueError, match="kind"):
        gj.continue_bifurcation(TABLE, start, args_of, 1.5, E, 0.6, kind="cusp")
    with pytest.raises(ValueError, match="nothing to continue"):
        gj.continue_bifurcation(TABLE, start, args_of, 1.5, E, E)
    with pytest.raises(ValueError, match="ds_min"):
        gj.continue_bifurcation(TABLE, start, args_of, 1.5, E, 0.6, ds=1.0, ds_max=0.1)
    with pytest.raises(ValueError, match="fix"):
        gj.continue_bifurcation(TABLE, start, args_of, 1.5, E, 0.6, fixed_period=False, fix=9)
    with pytest.raises(TypeError, match="Scene"):
        gj.continue_bifurcation(None, start, args_of, 1.5, E, 0.6)
