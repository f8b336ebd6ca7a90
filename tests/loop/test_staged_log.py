"""The impact log written outside the stepping loop (`_loop/forward.py: staged_log_loop`).

A single run whose log is larger than XLA:CPU's 512-byte threshold steps in an inner loop
with a staging log of one landing's rows, and moves them to the full log in an outer loop
(see `_loop.state.stage_log`). The results must be those of the plain loop, which a log of
at most 512 bytes still takes: the rows a small log holds, the counts, the statuses and the
derivatives. The golden runs (`tests/golden`) hold the same results bit for bit across the
change, for the runs with large logs among them (sticking, Zeno, boundary points).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
import grazejax._loop.forward as forward_module
from grazejax import examples as ex

from ..helpers import unit_box

SMALL, LARGE = 16, 100  # ex1dof rows of 2 states: 256 bytes (plain loop) and 1600 (staged)
BOX_ARGS = {"rx": 0.9, "ry": 0.9}


@pytest.fixture
def staged_calls(monkeypatch):
    """Count the runs that took the staged loop (one call of `stage_log` per trace)."""
    calls = []
    original = forward_module.stage_log

    def spy(c, rows):
        calls.append(rows)
        return original(c, rows)

    monkeypatch.setattr(forward_module, "stage_log", spy)
    return calls


def _ex1dof(x0, max_impacts, t1=60.0):
    return gj.simulate(ex.ex1dof(), x0, 0.0, t1, ex.ex1dof_args(0.2), max_impacts=max_impacts,
                       throw=False)


def test_staged_only_where_it_gains(staged_calls):
    x0 = jnp.array([0.5, 1.2])
    _ex1dof(x0, SMALL)
    assert staged_calls == []  # small log: plain loop
    _ex1dof(x0, LARGE)
    assert staged_calls == [1]  # one row per landing: one surface, one side
    jax.vmap(lambda x: _ex1dof(x, LARGE))(jnp.stack([x0, x0 + 0.01]))
    assert staged_calls == [1]  # batched: plain loop
    jax.jacfwd(lambda x: _ex1dof(x, LARGE).x_final)(x0)
    assert staged_calls == [1, 1]  # forward mode at batch 1: staged


def _rows(sol, k):
    return [np.asarray(getattr(sol, f))[:k] for f in
            ("impact_times", "impact_pre", "impact_post", "impact_surface", "impact_kind")]


def _assert_same_rows(small, large, k):
    for a, b in zip(_rows(small, k), _rows(large, k), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-14, atol=0)


def test_staged_log_equals_small_log(staged_calls):
    x0 = jnp.array([0.5, 1.2])
    small, large = _ex1dof(x0, SMALL), _ex1dof(x0, LARGE)
    assert staged_calls == [1]
    assert int(small.num_impacts) == int(large.num_impacts) == 9
    assert int(small.status) == int(large.status) == int(gj.Status.SUCCESS)
    _assert_same_rows(small, large, 9)
    np.testing.assert_allclose(small.x_final, large.x_final, rtol=1e-14)
    assert np.isnan(np.asarray(large.impact_times)[9:]).all()
    assert (np.asarray(large.impact_kind)[9:] == int(gj.ImpactKind.NONE)).all()


def test_staged_log_overflow(staged_calls):
    """More impacts than rows: the log keeps the first ones and the run stops at the last."""
    x0 = jnp.array([0.5, 1.2])
    small, large = _ex1dof(x0, SMALL, t1=400.0), _ex1dof(x0, 40, t1=400.0)
    assert staged_calls == [1]
    assert int(small.status) == int(large.status) == int(gj.Status.MAX_IMPACTS)
    assert int(small.num_impacts) == SMALL and int(large.num_impacts) == 40
    _assert_same_rows(small, large, SMALL)


def test_staged_log_two_rows_per_landing(staged_calls):
    """A corner: two walls in one landing, two rows staged together (4 rows of 4 states:
    128 bytes, plain; 40 rows: staged)."""
    scene = unit_box()
    x0 = jnp.array([0.3, 0.3, 0.7, 0.7])  # reaches the corner (1, 1) at t = 1

    def run(m):
        return gj.simulate(scene, x0, 0.0, 2.5, BOX_ARGS, max_impacts=m, rtol=1e-12, atol=1e-12,
                           throw=False)

    small, large = run(4), run(40)
    assert staged_calls == [4]  # four walls, one side each
    k = int(small.num_impacts)
    assert k == int(large.num_impacts) >= 2
    assert int(small.status) == int(large.status) == int(gj.Status.SUCCESS)
    assert np.asarray(large.impact_times)[0] == np.asarray(large.impact_times)[1]  # together
    _assert_same_rows(small, large, k)
    np.testing.assert_allclose(small.x_final, large.x_final, rtol=1e-14)


def test_staged_log_derivatives(staged_calls):
    x0 = jnp.array([0.5, 1.2])

    def times(x, m):
        return _ex1dof(x, m).impact_times[:9]

    j_small = jax.jacfwd(lambda x: times(x, SMALL))(x0)
    j_large = jax.jacfwd(lambda x: times(x, LARGE))(x0)
    assert staged_calls == [1]
    np.testing.assert_allclose(j_small, j_large, rtol=1e-12, atol=1e-14)
    assert np.all(np.isfinite(j_large))
