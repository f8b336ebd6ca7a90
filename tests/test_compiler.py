"""XLA compiler options (`grazejax/_compiler.py`) and the persistent compilation cache
(`grazejax/_compilation_cache.py`).

The vector width changes how XLA vectorises the lanes of a vmapped run, not its
arithmetic: the same batch compiled with 512-bit and with XLA's default vectors gives the
same bits, on ex1dof at random phases (every phase of the loop: searches, landings,
rejections) and on a 12-dimensional chain whose error norm and surface reduce over the
state. When the options apply is checked against the host, the user's XLA_FLAGS and what
this XLA knows; the kernels compiled with the one-run options nest in other programs.
"""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.experimental.compilation_cache import compilation_cache

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


@pytest.fixture
def jax_cache_config():
    """Restores the test run's own cache folder (`conftest.py`) after a test that moves it."""
    saved = (jax.config.jax_compilation_cache_dir,
             jax.config.jax_persistent_cache_min_compile_time_secs)
    yield
    jax.config.update("jax_compilation_cache_dir", saved[0])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", saved[1])
    compilation_cache.reset_cache()  # JAX reopens the restored folder at its next compile


def test_enable_compilation_cache_sets_the_folder(jax_cache_config, tmp_path, monkeypatch):
    monkeypatch.delenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", raising=False)
    monkeypatch.setenv("GRAZEJAX_COMPILATION_CACHE", "off")  # an explicit folder wins
    assert gj.enable_compilation_cache(tmp_path / "xla") == tmp_path / "xla"
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
    assert jax.config.jax_persistent_cache_min_compile_time_secs == 0.5
    # Without a folder: "off" changes nothing; a folder JAX has is kept.
    assert gj.enable_compilation_cache() is None
    assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
    monkeypatch.setenv("GRAZEJAX_COMPILATION_CACHE", str(tmp_path / "other"))
    assert gj.enable_compilation_cache() == tmp_path / "xla"
    # ... else the variable's folder, else the user's cache folder.
    jax.config.update("jax_compilation_cache_dir", None)
    assert gj.enable_compilation_cache() == tmp_path / "other"
    jax.config.update("jax_compilation_cache_dir", None)
    monkeypatch.delenv("GRAZEJAX_COMPILATION_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "home"))
    assert gj.enable_compilation_cache() == tmp_path / "home" / "grazejax" / "jax"
    # A minimum compile time the user set for JAX is kept.
    monkeypatch.setenv("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "2.0")
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 2.0)
    gj.enable_compilation_cache(tmp_path)
    assert jax.config.jax_persistent_cache_min_compile_time_secs == 2.0


CACHED_RUN = textwrap.dedent(
    """
    import sys, time
    import jax, jax.numpy as jnp
    import grazejax as gj
    from grazejax import examples as ex

    events = []
    jax.monitoring.register_event_listener(lambda event, **_: events.append(event))
    gj.enable_compilation_cache(sys.argv[1])
    start = time.perf_counter()
    sol = gj.simulate(ex.bouncing_ball(), jnp.array([1.0, 0.0]), 0.0, 2.0,
                      {"g": 9.81, "e": 0.8})
    jax.block_until_ready(sol.x_final)
    print(events.count("/jax/compilation_cache/cache_hits"),
          events.count("/jax/compilation_cache/cache_misses"), time.perf_counter() - start)
    """
)


def test_a_second_process_loads_its_program_from_the_cache(tmp_path):
    # Every program is stored (no minimum compile time), so that the check does not hang on
    # how fast this machine compiles.
    env = {**os.environ, "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0"}
    runs = []
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", CACHED_RUN, str(tmp_path)], env=env,
                             capture_output=True, text=True, check=True, timeout=300)
        hits, misses, seconds = out.stdout.split()
        runs.append((int(hits), int(misses), float(seconds)))
    print("first simulate (hits, misses, s): compiled", runs[0], "from the cache", runs[1])
    assert runs[0][0] == 0 and runs[0][1] > 0
    assert runs[1][:2] == (runs[0][1], 0)
