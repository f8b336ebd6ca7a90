"""XLA compiler options (`grazejax/_compiler.py`).

The vector width changes how XLA vectorises the lanes of a vmapped run, not its
arithmetic: the same batch compiled with 512-bit and with XLA's default vectors gives the
same bits, on ex1dof at random phases (every phase of the loop: searches, landings,
rejections) and on a 12-dimensional chain whose error norm and surface reduce over the
state. When the options apply is checked against the host, the user's XLA_FLAGS and what
this XLA knows; the kernels compiled with the one-run options nest in other programs.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import _compiler
from grazejax import examples as ex

WIDE = {_compiler.VECTOR_WIDTH_OPTION: 512}


def _chain(masses=6) -> gj.Scene:
    """Masses on springs in a line, forced at the first, the last one against a stop."""

    def field(t, x, args):
        q, v = x[:masses], x[masses:]
        left = jnp.concatenate([jnp.zeros(1), q[:-1]])
        right = jnp.concatenate([q[1:], q[-1:]])
        force = (left - 2 * q + right) - 0.05 * v
        force = force.at[0].add(jnp.cos(args["w"] * t))
        return jnp.concatenate([v, force])

    stop = gj.Surface(
        phi=lambda t, x, args: 0.3 - x[masses - 1] + 1e-3 * jnp.sum(x[:masses] ** 2),
        jump=lambda t, x, args: x.at[2 * masses - 1].set(-0.8 * x[2 * masses - 1]),
        name="stop",
    )
    return gj.Scene(field, [stop])


def _both_widths(run, inputs):
    return [jax.jit(run, compiler_options=options)(*inputs) for options in ({}, WIDE)]


def _assert_same_bits(default, wide):
    for name in ("status", "num_impacts", "impact_times", "x_final", "t_final", "num_steps"):
        np.testing.assert_array_equal(getattr(default, name), getattr(wide, name), err_msg=name)


def test_wide_vectors_give_the_same_bits_on_random_phases():
    rng = np.random.default_rng(0)
    starts = jnp.asarray(np.stack([rng.uniform(-0.5, 0.0, 37), rng.uniform(-0.3, 0.3, 37)], 1))
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)

    ts = jnp.linspace(0.0, 30.0, 61)

    def run(x0s):
        return jax.vmap(
            lambda x0: gj.simulate(scene, x0, 0.0, 30.0, args, max_impacts=30, saveat=ts)
        )(x0s)

    default, wide = _both_widths(run, (starts,))
    assert int(jnp.sum(default.num_impacts)) > 37  # impacts happened
    _assert_same_bits(default, wide)
    # (Saved states too: XLA's region-analysis copy insertion, 3% faster on this sweep,
    # returned wrong saved states for a single elastic-ball run of tests/golden.)
    np.testing.assert_array_equal(default.xs, wide.xs)


def test_one_run_options_agree_to_rounding():
    # XLA's older emitters may round transcendental functions differently: the last bits,
    # never the events. (Each emitter asked for explicitly: the suite's XLA_FLAGS choose the
    # older ones, tests/conftest.py.) ex1dof is forced by a cosine; saved states, impacts and jacfwd.
    scene, args = ex.ex1dof(), ex.ex1dof_args(0.2)
    ts = jnp.linspace(0.0, 40.0, 81)

    def run(x0):
        sol = gj.simulate(scene, x0, 0.0, 40.0, args, max_impacts=40, saveat=ts)
        return sol, jax.jacfwd(lambda x: gj.simulate(scene, x, 0.0, 40.0, args,
                                                     max_impacts=40).x_final)(x0)

    x0 = jnp.array([0.5, 1.2])
    (default, jac), (quick, jac_quick) = (
        jax.jit(run, compiler_options=options)(x0)
        for options in ({_compiler.FUSION_EMITTERS_OPTION: True},
                        {_compiler.FUSION_EMITTERS_OPTION: False})
    )
    assert int(default.num_impacts) > 5
    np.testing.assert_array_equal(default.num_impacts, quick.num_impacts)
    np.testing.assert_array_equal(default.impact_surface, quick.impact_surface)
    for got, want in ((quick.impact_times, default.impact_times), (quick.xs, default.xs),
                      (jac_quick, jac)):
        finite = np.isfinite(np.asarray(want))
        np.testing.assert_allclose(np.asarray(got)[finite], np.asarray(want)[finite],
                                   rtol=1e-11, atol=1e-12)


def test_wide_vectors_give_the_same_bits_on_a_chain():
    masses = 6
    rng = np.random.default_rng(1)
    starts = jnp.asarray(rng.uniform(-0.2, 0.2, (19, 2 * masses)))
    scene = _chain(masses)

    def run(x0s, w):
        return jax.vmap(
            lambda x0: gj.simulate(scene, x0, 0.0, 25.0, {"w": w}, rtol=1e-9, atol=1e-9,
                                   max_impacts=40)
        )(x0s)

    default, wide = _both_widths(run, (starts, jnp.asarray(1.3)))
    assert int(jnp.sum(default.num_impacts)) > 19
    assert np.all(np.asarray(default.status) == int(gj.Status.SUCCESS))
    _assert_same_bits(default, wide)


def test_options_only_for_a_cpu_with_avx512(monkeypatch):
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.setattr(_compiler, "_known", lambda option, value: True)
    monkeypatch.setattr(_compiler, "_host_has_avx512", lambda: True)
    assert gj.compiler_options("cpu") == WIDE
    assert gj.compiler_options("gpu") == {}
    assert gj.compiler_options("gpu", batched=False) == {}
    monkeypatch.setattr(_compiler, "_host_has_avx512", lambda: False)
    assert gj.compiler_options("cpu") == {}


def test_a_users_xla_flag_wins(monkeypatch):
    monkeypatch.setattr(_compiler, "_host_has_avx512", lambda: True)
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_prefer_vector_width=256")
    assert gj.compiler_options("cpu") == {}


@pytest.mark.skipif(jax.default_backend() != "cpu", reason="reads the host CPU")
def test_the_host_check_reads_cpuinfo():
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            text = cpuinfo.read()
    except OSError:
        pytest.skip("no /proc/cpuinfo here")
    expected = any("avx512f" in line.split() for line in text.splitlines()
                   if line.startswith("flags"))
    assert _compiler._host_has_avx512() is expected


def test_single_run_kernels_nest_in_other_programs():
    # JAX refuses compiler options on a nested jit: inside a trace the kernel is jitted
    # plainly, whether the trace shows in its inputs (tracers) or not (constants only).
    kernel = _compiler.single_run_jit(lambda x, k: jnp.sin(x) * k)
    x = jnp.linspace(0.0, 1.0, 5)
    top = kernel(x, 2.0)
    np.testing.assert_allclose(jax.jit(lambda y: kernel(y, 2.0))(x), top, rtol=1e-15)
    np.testing.assert_allclose(jax.jit(lambda: kernel(jnp.linspace(0.0, 1.0, 5), 2.0))(), top,
                               rtol=1e-15)
    np.testing.assert_allclose(jax.vmap(lambda y: kernel(y, 2.0))(x), top, rtol=1e-15)
    np.testing.assert_allclose(jax.grad(lambda y: kernel(y, 2.0).sum())(x), 2 * jnp.cos(x),
                               rtol=1e-15)


def test_an_option_this_xla_does_not_know_is_not_passed(monkeypatch):
    assert not _compiler._known("xla_cpu_no_such_option", 1)
    monkeypatch.delenv("XLA_FLAGS", raising=False)
    monkeypatch.setattr(_compiler, "_known", lambda option, value: True)
    assert gj.compiler_options("cpu", batched=False) == {_compiler.FUSION_EMITTERS_OPTION: False}
    monkeypatch.setattr(_compiler, "_known", lambda option, value: False)
    assert gj.compiler_options("cpu", batched=False) == {}
    monkeypatch.setattr(_compiler, "_host_has_avx512", lambda: True)
    assert gj.compiler_options("cpu") == {}


def test_a_users_xla_flag_wins_for_single_runs(monkeypatch):
    monkeypatch.setattr(_compiler, "_known", lambda option, value: True)
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=true")
    assert gj.compiler_options("cpu", batched=False) == {}


@pytest.mark.parametrize("balance", ["refill", "none"])
def test_sweep_compiles_with_the_batched_options(monkeypatch, balance):
    from grazejax import _sweep

    asked = []

    def spy(platform=None, *, batched=True):
        asked.append((platform, batched))
        return {}

    monkeypatch.setattr(_sweep, "compiler_options", spy)
    monkeypatch.setattr(_sweep, "_CHUNK_CACHE", {})  # (a cached program would not ask)
    x0s = jnp.stack([jnp.zeros(3), jnp.array([0.02, 0.03, 0.04])], axis=1)
    sol = gj.sweep(ex.ex1dof(), x0s, 0.0, 5.0, ex.ex1dof_args(0.2), balance=balance,
                   progress=False)
    assert sol.x_final.shape == (3, 2)
    assert asked == [(jax.devices()[0].platform, True)]
