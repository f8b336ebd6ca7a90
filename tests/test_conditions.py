"""check_conditions: the paper's (C1), (C2), (C4)-(C7) on its own scenes and on a bad one."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex
from grazejax._conditions import check_conditions


def bad_scene():
    """One violation of each kind, at known places (f is a rotation: x1' = x2, x2' = −x1).

    - "cubic": Φ = x1³: ∇Φ = 0 on all of Γ (C1), and so ⟨∇Φ, f⟩ = 0 there (C4).
    - "kink": Γ = {x2 = 1, x1 ≤ 0}, J with |x1 + 1/2| (not C¹ at x1 = −1/2: C2) that moves
      the boundary point (0, 1) to (0, 1.1) (C6, and so C7).
    - "flat": Γ = {x1 = −3/2}, J = (x1, x1/2) (det DJ = 0: C2; Φ̃ undefined: C5 untested),
      and ⟨∇Φ, f⟩ = x2 changes sign at (−3/2, 0), an interior point (C4).
    """

    def vector_field(t, x, args):
        return jnp.stack([x[1], -x[0]])

    cubic = gj.Surface(
        phi=lambda t, x, a: x[0] ** 3, jump=lambda t, x, a: x.at[1].set(-x[1]), name="cubic"
    )
    kink = gj.Surface(
        phi=lambda t, x, a: x[1] - 1.0,
        jump=lambda t, x, a: jnp.stack([x[0], 2.0 - x[1] + 0.2 * jnp.abs(x[0] + 0.5)]),
        where=lambda t, x, a: x[0] <= 0,
        name="kink",
    )
    flat = gj.Surface(
        phi=lambda t, x, a: x[0] + 1.5,
        jump=lambda t, x, a: jnp.stack([x[0], 0.5 * x[0]]),
        name="flat",
    )
    return gj.Scene(vector_field, [cubic, kink, flat])


@pytest.fixture(scope="module")
def bad_report():
    return check_conditions(bad_scene(), None, samples=600)


def test_bad_scene_violations_are_found_where_they_are(bad_report):
    r = bad_report
    assert not r.ok
    # cubic
    assert r.holds("C1", 0) is False
    assert r.holds("C4", 0) is False
    # kink: not C¹ near x1 = −1/2, and J moves the boundary point (0, 1)
    c2 = next(x for x in r.results if x.condition == "C2" and x.surface == 1)
    assert c2.holds is False and "not C¹" in c2.detail
    assert np.any(np.abs(c2.points[:, 1] + 0.5) < 0.02)
    c6 = next(x for x in r.results if x.condition == "C6" and x.surface == 1)
    assert c6.holds is False
    np.testing.assert_allclose(c6.points[0, 1:], [0.0, 1.0], atol=1e-9)
    assert r.holds("C7", 1) is False
    assert r.holds("C4", 1) is True  # ⟨∇Φ, f⟩ = −x1 vanishes only on ∂Γ
    # flat: singular J, interior tangency at (−3/2, 0)
    c2 = next(x for x in r.results if x.condition == "C2" and x.surface == 2)
    assert c2.holds is False and "det DJ = 0" in c2.detail
    c4 = next(x for x in r.results if x.condition == "C4" and x.surface == 2)
    assert c4.holds is False
    np.testing.assert_allclose(c4.points[0, 1:], [-1.5, 0.0], atol=1e-9)
    assert r.holds("C5", 2) is None
    assert r.holds("C6", 2) is True  # vacuous: no boundary


def test_report_is_readable(bad_report):
    text = str(bad_report)
    first = text.splitlines()[1]
    assert "VIOLATED" in first  # violations are listed first
    assert "(C1) cubic: VIOLATED" in text
    assert "at t = 0, x = [-1.5" in text
    assert len(bad_report.violations) == sum("VIOLATED" in line for line in text.splitlines())


@pytest.mark.parametrize("name", ["orbex2", "smalldisc"])
def test_two_wall_scenes_satisfy_the_conditions(name):
    make, make_args = ex.PAPER_SCENES[name]
    report = check_conditions(make(), make_args(), samples=400)
    assert report.ok, str(report)
    # each wall has one boundary point, (c, 0) and (0, 0), fixed by J
    for i in (0, 1):
        c6 = next(x for x in report.results if x.condition == "C6" and x.surface == i)
        assert "1 boundary point" in c6.detail


def test_ex1dof_conditions_depend_on_mu():
    scene = ex.ex1dof()
    r = check_conditions(scene, ex.ex1dof_args(0.0), samples=400)
    # Everything but (C3) holds at μ = 0. (C3): J(0, x2) = (0, −R x2² − μ x2⁴ + μ²) ≤ 0
    # maps Γ = {x1 = 0, x2 ≤ 0} into Γ, so Γ ∩ Γ̃ = Γ̃ contains interior points of Γ.
    assert [v.condition for v in r.violations] == ["C3"]
    # μ ≠ 0: J(0, 0) = (0, μ²) ≠ (0, 0), so (C6) fails at ∂Γ = {(0, 0)} (the paper says
    # (C1)-(C7) "can be verified"); and Γ̃ then contains the tangency point (0, 0).
    r = check_conditions(scene, ex.ex1dof_args(0.2), samples=400)
    assert r.holds("C6") is False and r.holds("C7") is False and r.holds("C5") is False
    # μ = −0.2: det DJ = −x2 (2R + 4μ x2²) vanishes at x2 = −√(R/(−2μ)) = −1.5 on Γ
    r = check_conditions(scene, ex.ex1dof_args(-0.2), samples=400)
    c2 = next(x for x in r.results if x.condition == "C2")
    assert c2.holds is False
    np.testing.assert_allclose(c2.points[0, 1:], [0.0, -1.5], atol=1e-9)


def test_exnonaxial_violates_c2_and_c4():
    """The paper's non-axial example: J maps onto the diagonal (det DJ ≡ 0), and its
    Γ = {x1 + x2 = √2} is a whole line, so the grazing point is interior (C4)."""
    r = check_conditions(ex.exnonaxial(), ex.exnonaxial_args(), samples=400)
    assert r.holds("C2") is False
    assert r.holds("C5") is None
    c4 = next(x for x in r.results if x.condition == "C4")
    assert c4.holds is False
    np.testing.assert_allclose(c4.points[0, 1:], [1 / math.sqrt(2)] * 2, atol=1e-9)


def test_bad_arguments():
    with pytest.raises(TypeError):
        check_conditions("not a scene")
    with pytest.raises(ValueError, match="box"):
        check_conditions(ex.orbex2(), ex.orbex2_args(), box=[[0, 1]])
    with pytest.raises(ValueError, match="no surfaces"):
        check_conditions(gj.Scene(lambda t, x, a: -x), None, box=[[-1, 1]])


def _ball(restricted):
    floor = gj.Surface(phi=lambda t, x, a: x[0], jump=lambda t, x, a: x.at[1].set(-0.8 * x[1]),
                       where=(lambda t, x, a: x[1] <= 0) if restricted else None)
    return gj.Scene(lambda t, x, a: jnp.stack([x[1], -9.81 * jnp.ones_like(x[0])]), [floor])


def test_c3_unrestricted_floor_is_its_own_image():
    """Γ = {h = 0}: J(0, v) = (0, −0.8 v) is on Γ again, so Γ̃ = Γ and every interior
    point is in Γ ∩ Γ̃ (C3 fails); restricted to v ≤ 0, Γ̃ = {h = 0, v ≥ 0} meets Γ only
    at (0, 0) = ∂Γ (C3 holds)."""
    r = check_conditions(_ball(False), None, samples=200)
    assert r.holds("C3") is False
    assert check_conditions(_ball(True), None, samples=200).holds("C3") is True


def test_a1_a_continuum_of_grazing_points_is_not_isolated():
    """f = (0, 1) is tangent to Γ = {x1 = 0} everywhere: every point is a grazing point
    ((C4) and (A1) fail); exnonaxial's single interior tangency is isolated ((A1) holds)."""
    wall = gj.Surface(phi=lambda t, x, a: x[0], jump=lambda t, x, a: x)
    shear = gj.Scene(lambda t, x, a: jnp.stack([jnp.zeros_like(x[0]), jnp.ones_like(x[1])]), [wall])
    r = check_conditions(shear, None, samples=200, box=[[-1, 1], [-1, 1]])
    assert r.holds("A1") is False and r.holds("C4") is False
    assert check_conditions(ex.exnonaxial(), ex.exnonaxial_args(), samples=400).holds("A1") is True


def test_c9_blow_up_before_the_surface_is_a_violation():
    """x1' = x1² blows up at t = 1/x1(0) ≤ 2 from x1(0) ∈ [0.5, 2], while Γ = {x2 = −5} is
    only reached at t = x2(0) + 5 ≥ 4: the flight is not continuable to Γ (C9 fails)."""
    wall = gj.Surface(phi=lambda t, x, a: x[1] + 5.0, jump=lambda t, x, a: x.at[0].set(-x[0]))
    scene = gj.Scene(lambda t, x, a: jnp.stack([x[0] ** 2, -jnp.ones_like(x[1])]), [wall])
    r = check_conditions(scene, None, samples=100, box=[[0.5, 2.0], [-1.0, 1.0]], flights=16)
    assert r.holds("C9") is False


def test_c10_meeting_the_image_first_is_a_violation():
    """Γ = {x1 = 1} with J = shift by −2: Γ̃ = {x1 = −1}. The flow x' = (−1, 0) from
    −1 < x1 < 1 (the free side Φ = 1 − x1 > 0) meets Γ̃ and never Γ (C10 fails)."""
    wall = gj.Surface(phi=lambda t, x, a: 1.0 - x[0], jump=lambda t, x, a: x.at[0].add(-2.0))
    scene = gj.Scene(lambda t, x, a: jnp.stack([-jnp.ones_like(x[0]), jnp.zeros_like(x[1])]), [wall])
    r = check_conditions(scene, None, samples=100, box=[[-0.9, 0.9], [-1.0, 1.0]], flights=16,
                         horizon=4.0)
    assert r.holds("C10") is False and r.holds("C9") is True


@pytest.mark.slow
def test_orbex2_passes_c8_to_c10():
    """The paper verifies (C1)–(C10) for orbex2: the flights agree on both walls (from the
    strip 0 ≤ y1 ≤ c between them, no flight meets an image wall before its wall)."""
    r = check_conditions(ex.orbex2(), ex.orbex2_args(), samples=200, flights=32)
    assert all(r.holds(c) is True for c in ("C8", "C9", "C10")), str(r)
