"""The bracketed root search: its invariants, its worst case, and that it converges fast on
smooth roots (Chandrupatla, the default; ITP and the safeguarded Newton search beside it)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from grazejax._roots import _CHANDRUPATLA_SLACK, ITP, BracketedNewton, Chandrupatla, bracketed_root

FINDERS = {"chandrupatla": Chandrupatla(), "itp": ITP(), "newton": BracketedNewton()}

EPS = float(np.finfo(np.float64).eps)

CASES = {
    # name: (fn, lo, hi, root)
    "linear": (lambda s: 0.37 - s, 0.0, 1.0, 0.37),
    "quadratic": (lambda s: 0.3 - s + 0.1 * s**2, 0.0, 1.0, (1 - np.sqrt(1 - 0.12)) / 0.2),
    "exponential": (lambda s: jnp.exp(-3 * s) - 0.5, 0.0, 1.0, np.log(2) / 3),
    "offset clock": (lambda s: 1e-3 - (s - 100) ** 2, 100.0, 101.0, 100 + np.sqrt(1e-3)),
    # a crossing next to a flat minimum: the near-grazing case
    "near grazing": (lambda s: (s - 1) ** 2 - 1e-12, 0.0, 1.0, 1 - 1e-6),
    "steep": (lambda s: jnp.tanh(1e4 * (0.7 - s)), 0.0, 1.0, 0.7),
}


def _search(fn, lo, hi):
    lo, hi = jnp.float64(lo), jnp.float64(hi)
    return jax.jit(lambda: bracketed_root(fn, lo, hi, fn(lo), fn(hi), count=True))()


@pytest.mark.parametrize("name", sorted(CASES))
def test_bracket_invariants_and_iterations(name):
    fn, lo0, hi0, root = CASES[name]
    lo, hi, iterations = _search(fn, lo0, hi0)
    assert lo0 <= lo < hi <= hi0 or float(fn(hi)) == 0
    assert float(fn(lo)) > 0 >= float(fn(hi))
    # To a few ulps of the clock, as documented (4 eps·max|s|)...
    assert float(hi - lo) <= 4 * EPS * max(abs(lo0), abs(hi0)) or float(fn(hi)) == 0
    # ...around the true root (the root's own conditioning: the near-grazing root moves by
    # δg/|g'| = eps/2e-6 for a rounding δg of g).
    assert abs(float(hi) - root) <= 1e-9 if name == "near grazing" else 8 * EPS * (1 + abs(root))
    # Never more than _CHANDRUPATLA_SLACK iterations over bisection's count, and far fewer
    # on smooth roots (bisection needs ~50 from a unit bracket to 4 eps).
    assert int(iterations) <= _bisection_count(lo0, hi0) + _CHANDRUPATLA_SLACK + 1
    if name in ("linear", "quadratic", "exponential", "offset clock", "steep"):
        assert int(iterations) <= 18


def _bisection_count(lo0, hi0):
    return np.ceil(np.log2((hi0 - lo0) / (4 * EPS * max(abs(lo0), abs(hi0)))))


@pytest.mark.parametrize("method", ["chandrupatla", "itp"])
def test_worst_case_on_roots_flat_or_steep(method):
    """Seeded roots of sign(r − s)·|r − s|^p, p ∈ [0.1, 6]: flat (p > 1: a crossing at a
    tangency, as at grazing) or infinitely steep (p < 1) at the root, where interpolation
    gains nothing. The bracket still closes around the root within bisection's count plus
    the method's slack (ITP: 1), plus one for rounding in the projection's radius (seen:
    ITP took 52 at r = 0.3156, p = 2.598 from a unit bracket)."""
    rng = np.random.default_rng(1)
    slack = {"chandrupatla": _CHANDRUPATLA_SLACK, "itp": 1}[method]
    for _ in range(30):
        r, p = rng.uniform(0.01, 0.99), rng.uniform(0.1, 6.0)

        def fn(s, r=r, p=p):
            return jnp.sign(r - s) * jnp.abs(r - s) ** p

        lo, hi, iterations = jax.jit(lambda fn=fn: bracketed_root(
            fn, jnp.float64(0.0), jnp.float64(1.0), fn(0.0), fn(1.0), count=True,
            finder=FINDERS[method]))()
        assert float(fn(lo)) > 0 >= float(fn(hi))
        assert abs(float(hi) - r) <= 8 * EPS, (r, p)
        assert int(iterations) <= _bisection_count(0.0, 1.0) + slack + 1, (r, p)


def test_empty_bracket_costs_nothing():
    lo, hi, iterations = _search(lambda s: 1.0 - s, 0.5, 0.5)
    assert int(iterations) == 0 and float(lo) == float(hi) == 0.5


def test_random_smooth_roots():
    """Seeded cubics with one root in [0, 1]: invariants hold and the mean count is small."""
    rng = np.random.default_rng(0)
    counts = []
    for _ in range(40):
        r = rng.uniform(0.05, 0.95)
        a, b = rng.uniform(0.1, 3.0, 2)

        def fn(s, r=r, a=a, b=b):
            return (r - s) * (a + b * (s - r) ** 2)

        lo, hi, iterations = _search(fn, 0.0, 1.0)
        assert float(fn(lo)) > 0 >= float(fn(hi))
        assert abs(float(hi) - r) <= 8 * EPS
        counts.append(int(iterations))
    # (measured: mean 7.6, at most 11)
    assert np.mean(counts) <= 9, counts


@pytest.mark.parametrize("name", sorted(CASES))
def test_newton_and_itp_agree(name):
    """The safeguarded Newton search against ITP (the default): the same root,
    the bracket closed onto adjacent floats, and few iterations on simple roots."""
    fn, lo0, hi0, root = CASES[name]
    lo0, hi0 = jnp.float64(lo0), jnp.float64(hi0)

    def search(method):
        return jax.jit(lambda: bracketed_root(
            fn, lo0, hi0, fn(lo0), fn(hi0), count=True, finder=FINDERS[method]))()

    lo, hi, iterations = search("newton")
    _, hi_itp, iterations_itp = search("itp")
    assert float(fn(lo)) > 0 >= float(fn(hi))
    assert float(np.nextafter(float(lo), np.inf)) >= float(hi) or float(fn(hi)) == 0
    assert abs(float(hi) - float(hi_itp)) <= 8 * EPS * max(1.0, abs(root))
    assert int(iterations) <= int(iterations_itp)
    if name in ("linear", "quadratic", "exponential", "offset clock"):
        assert int(iterations) <= 12


def test_simulate_takes_every_event_root_finder_and_refuses_others():
    """`simulate(..., event_root_finder=...)` passes the finder to every search of the
    loop: each closes its brackets to a few ulps, so the runs agree to rounding (a ball
    with e = 0.8, whose impacts each end a flight found by the in-step search)."""
    import grazejax as gj
    from grazejax.examples import bouncing_ball

    scene, args = bouncing_ball(), {"g": 9.81, "e": 0.8}
    runs = {
        name: gj.simulate(scene, [1.0, 0.0], 0.0, 3.0, args, rtol=1e-10, atol=1e-10,
                          event_root_finder=finder)
        for name, finder in FINDERS.items()
    }
    base = runs["chandrupatla"]
    assert int(base.num_impacts) >= 6
    for sol in runs.values():
        assert int(sol.num_impacts) == int(base.num_impacts)
        np.testing.assert_allclose(sol.impact_times, base.impact_times, rtol=0, atol=1e-13)
    with pytest.raises(TypeError, match="event_root_finder must be a grazejax bracketed"):
        gj.simulate(scene, [1.0, 0.0], 0.0, 3.0, args, event_root_finder="itp")
