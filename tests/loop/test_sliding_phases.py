"""`ZenoStick` runs step in phases: `program.free_step` while no lane slides, the full
`program.step` while one does (`_loop/forward.py: staged_log_loop`, `_loop/pool.py: _in_phases`).

The phases are a cost saving only (a run that never slides paid 1.25× for the per-step
sliding tests at batch 1): the results must equal the flat loop's bit for bit, in single
runs (small and staged logs), under `vmap` and in `sweep`, for runs that slide, release
and slide again, and for runs that never slide. (Under `vmap` with XLA's default fusion
emitters: with the older ones, which the suite compiles with, the two programs' saved
states can differ by an ulp; see the test.)
"""

import diffrax
import jax
import jax.lax as lax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
import grazejax._loop.pool as pool_module
import grazejax._loop.runners as runners_module
from grazejax import _compiler
from grazejax import examples as ex

TABLE_ARGS = {"g": 9.81, "e": 0.3, "A": 0.1, "omega": 12.0}  # A ω² > g: releases
FIELDS = ("t_final", "x_final", "num_impacts", "impact_times", "impact_pre", "impact_post",
          "impact_surface", "impact_kind", "status", "zeno_time", "num_steps",
          "num_accepted_steps", "xs")


@pytest.fixture
def flat_loop(monkeypatch):
    """Run `simulate` with the flat loop (`program.step` at every iteration) inside the
    context."""

    class Flat:
        def __enter__(self):
            monkeypatch.setattr(
                runners_module, "staged_log_loop",
                lambda cond, program, init: lax.while_loop(cond, program.step, init),
            )

        def __exit__(self, *exc):
            monkeypatch.undo()

    return Flat()


def _assert_bitwise_equal(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        if x is None:
            assert y is None
            continue
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y), err_msg=name)


def _table(x0, max_impacts):
    return gj.simulate(ex.vibrating_table(), x0, 0.0, 2.0, TABLE_ARGS, zeno="stick",
                       max_impacts=max_impacts, rtol=1e-10, atol=1e-12, throw=False,
                       saveat=diffrax.SaveAt(ts=jnp.linspace(0, 2, 7)))


@pytest.mark.parametrize("max_impacts", [12, 300])  # 12 rows: no staging; 300: staged
def test_phases_equal_flat_loop_single_runs(flat_loop, max_impacts):
    x0 = jnp.array([0.3, 0.0])
    phased = jax.jit(lambda x: _table(x, max_impacts))(x0)
    with flat_loop:
        flat = jax.jit(lambda x: _table(x, max_impacts))(x0)
    kinds = np.asarray(phased.impact_kind)
    # The case must exercise the phases: sliding starts and ends more than once.
    if max_impacts == 300:
        assert np.sum(kinds == int(gj.ImpactKind.STICK)) >= 2
        assert np.sum(kinds == int(gj.ImpactKind.RELEASE)) >= 2
    _assert_bitwise_equal(phased, flat)


def test_phases_equal_flat_loop_never_sliding(flat_loop):
    """ex1dof impacts transversally: a `ZenoStick` run that never slides (all free steps)."""

    def run(x):
        return gj.simulate(ex.ex1dof(), x, 0.0, 60.0, ex.ex1dof_args(0.2), zeno="stick",
                           max_impacts=16, rtol=1e-10, atol=1e-10)

    x0 = jnp.array([0.0, 0.0384224329])
    phased = jax.jit(run)(x0)
    with flat_loop:
        flat = jax.jit(run)(x0)
    assert int(phased.num_impacts) == 9
    assert not np.any(np.asarray(phased.impact_kind) == int(gj.ImpactKind.STICK))
    _assert_bitwise_equal(phased, flat)
    stop = jax.jit(lambda x: gj.simulate(ex.ex1dof(), x, 0.0, 60.0, ex.ex1dof_args(0.2),
                                         max_impacts=16, rtol=1e-10, atol=1e-10))(x0)
    np.testing.assert_array_equal(np.asarray(phased.impact_times), np.asarray(stop.impact_times))


def test_phases_equal_flat_loop_under_vmap(flat_loop):
    """Lanes that slide (dropped from low) next to lanes that only bounce at first.

    Compiled with XLA's fusion emitters, the default for a batched program (the suite's
    XLA_FLAGS choose the older ones, tests/conftest.py): with the older emitters the two
    programs' saved states differ by an ulp (1.8e-15 in 2 of 42), their fusions rounding
    the dense interpolation differently."""
    x0s = jnp.stack([jnp.array([0.3, 0.0]), jnp.array([0.02, 0.0]), jnp.array([1.0, 0.5])])
    batched = {_compiler.FUSION_EMITTERS_OPTION: True}
    phased = jax.jit(jax.vmap(lambda x: _table(x, 300)), compiler_options=batched)(x0s)
    with flat_loop:
        flat = jax.jit(jax.vmap(lambda x: _table(x, 300)), compiler_options=batched)(x0s)
    assert np.any(np.asarray(phased.impact_kind) == int(gj.ImpactKind.STICK))
    _assert_bitwise_equal(phased, flat)


def test_sweep_with_phases_equals_flat_pool(monkeypatch):
    x0s = jnp.stack([jnp.array([0.3, 0.0]), jnp.array([0.02, 0.0]), jnp.array([1.0, 0.5]),
                     jnp.array([0.5, -0.2])])

    def run():
        return gj.sweep(ex.vibrating_table(), x0s, 0.0, 2.0, TABLE_ARGS, progress=False,
                        zeno="stick", max_impacts=300, rtol=1e-10, atol=1e-12, pool_size=2)

    phased = run()
    # Lanes slide and release at different times; one (from high up) never slides.
    released = np.any(phased.impact_kind == int(gj.ImpactKind.RELEASE), axis=1)
    assert 2 <= np.sum(released) < x0s.shape[0]
    monkeypatch.setattr(
        pool_module, "_in_phases",
        lambda cond, body, free_body, program, state, carry_of: lax.while_loop(cond, body, state),
    )
    _assert_bitwise_equal(phased, run())
