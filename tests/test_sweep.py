"""grazejax.sweep: batch equals loop, chunking, per-lane status, devices, bad input, and the
refilling pool (`balance="refill"`) against single runs and against plain vmap."""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import grazejax as gj
from grazejax import examples as ex

SCENE = ex.ex1dof()
OPTS = dict(rtol=1e-9, atol=1e-11, max_impacts=20, progress=False)


def test_sweep_equals_single_runs_and_keeps_input_order():
    args = ex.ex1dof_args(0.2)
    x0s = np.stack([np.zeros(7), np.linspace(0.05, 0.9, 7)], axis=1)
    for balance in ("none", "refill"):
        out = gj.sweep(SCENE, x0s, 0.0, 30.0, args, chunk_size=3, balance=balance, **OPTS)
        assert out.x_final.shape == (7, 2) and isinstance(out.x_final, np.ndarray)
        for i in range(7):
            single = gj.simulate(SCENE, x0s[i], 0.0, 30.0, args, rtol=1e-9, atol=1e-11, max_impacts=20)
            assert int(out.num_impacts[i]) == int(single.num_impacts)
            assert int(out.status[i]) == int(single.status)
            np.testing.assert_allclose(out.x_final[i], single.x_final, rtol=1e-11, atol=1e-13)


def test_sweep_over_parameters():
    mus = np.array([-0.2, 0.0, 0.2])
    args = dict(ex.ex1dof_args(), mu=jnp.asarray(mus))
    out = gj.sweep(SCENE, np.array([1.0, 1.0]), 0.0, 20.0, args, **OPTS)
    for i, mu in enumerate(mus):
        single = gj.simulate(SCENE, [1.0, 1.0], 0.0, 20.0, ex.ex1dof_args(mu), rtol=1e-9, atol=1e-11, max_impacts=20)
        np.testing.assert_allclose(out.x_final[i], single.x_final, rtol=1e-11, atol=1e-13)


def test_a_bad_lane_does_not_spoil_the_others():
    args = ex.ex1dof_args(0.2)
    x0s = np.array([[0.0, 0.5], [np.nan, 0.5], [0.0, 0.7]])
    with pytest.warns(gj.FailedLanesWarning, match=r"1 of 3 lanes failed \(NONFINITE 1\)"):
        out = gj.sweep(SCENE, x0s, 0.0, 20.0, args, **OPTS)
    assert list(out.status) == [gj.Status.SUCCESS, gj.Status.NONFINITE, gj.Status.SUCCESS]
    assert np.all(np.isfinite(out.x_final[[0, 2]]))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(x0s=np.zeros((0, 2))), "empty batch"),
        (dict(x0s=np.zeros((3, 2)), args=dict(ex.ex1dof_args(), mu=jnp.zeros(4)),
              args_batched=dict(mu=True, eps=False, R=False)), "mismatched batch sizes"),
        (dict(x0s=np.zeros((3, 2)), chunk_size=0), "chunk_size"),
        (dict(x0s=np.zeros((3, 2, 1))), "x0s must have shape"),
        (dict(x0s=np.zeros((3, 2)), balance="presort"), "balance must be one of"),
        (dict(x0s=np.zeros((3, 2)), pool_size=0), "pool_size must be a positive integer"),
        (dict(x0s=np.zeros((3, 2)), pool_size=2.5), "pool_size must be a positive integer"),
        (dict(x0s=np.zeros((3, 2)), balance="none", pool_size=4), "pool_size applies to"),
    ],
)
def test_bad_input(kwargs, match):
    kwargs.setdefault("args", ex.ex1dof_args(0.2))
    with pytest.raises(ValueError, match=match):
        gj.sweep(SCENE, t0=0.0, t1=1.0, progress=False, **kwargs)


def test_bad_simulate_option():
    with pytest.raises(TypeError, match="unknown simulate options"):
        gj.sweep(SCENE, np.zeros((3, 2)), 0.0, 1.0, ex.ex1dof_args(0.2), rtl=1e-3, progress=False)


# ----------------------------------------------------------------------------------------
# The refilling pool: a bouncing ball with restitution 0.2 … 0.97, so lanes range from a few
# impacts (Zeno soon) to the log's end; plus a NaN lane and lanes cut off by max_steps.
# Every call has the same shapes, so each configuration compiles once for all examples.
# ----------------------------------------------------------------------------------------

BALL = ex.bouncing_ball()
LANES = 12
BALL_OPTS = dict(rtol=1e-8, atol=1e-10, max_impacts=30, max_steps=60, saveat=np.linspace(0.0, 3.0, 7))


def _ball_lanes(heights, restitutions, nan_lane):
    x0s = np.stack([np.asarray(heights), np.zeros(LANES)], axis=1)
    x0s[nan_lane, 0] = np.nan
    return x0s, dict(g=9.81, e=jnp.asarray(restitutions))


@jax.jit
def _ball_single(x0, e):
    return gj.simulate(BALL, x0, 0.0, 3.0, dict(g=9.81, e=e), direction=1, **BALL_OPTS)


def _assert_same_lanes(out, ref, exact):
    for field in ("status", "num_impacts", "num_steps", "num_accepted_steps", "impact_surface",
                  "impact_kind"):
        np.testing.assert_array_equal(getattr(out, field), getattr(ref, field), err_msg=field)
    for field in ("t_final", "x_final", "impact_times", "impact_pre", "impact_post", "zeno_time",
                  "ts", "xs"):
        if exact or getattr(ref, field) is None:
            np.testing.assert_array_equal(getattr(out, field), getattr(ref, field), err_msg=field)
        else:
            # 30 bounces amplify a last-bit difference to ~1e-12 relative.
            np.testing.assert_allclose(getattr(out, field), getattr(ref, field), rtol=1e-10,
                                       atol=1e-12, err_msg=field)


@settings(max_examples=6, deadline=None)
@given(
    heights=st.lists(st.floats(0.05, 2.0), min_size=LANES, max_size=LANES),
    restitutions=st.lists(st.floats(0.2, 0.97), min_size=LANES, max_size=LANES),
    nan_lane=st.integers(0, LANES - 1),
)
def test_refill_equals_loop_and_vmap(heights, restitutions, nan_lane):
    x0s, args = _ball_lanes(heights, restitutions, nan_lane)
    kw = dict(progress=False, **BALL_OPTS)
    # A pool of 4 slots fed from a queue of 12: about ten refills per chunk. (The NaN lane
    # fails: every sweep warns.)
    with pytest.warns(gj.FailedLanesWarning, match="NONFINITE 1"):
        pool = gj.sweep(BALL, x0s, 0.0, 3.0, args, balance="refill", pool_size=4, **kw)
    assert pool.status[nan_lane] == gj.Status.NONFINITE
    # The bit-for-bit claims: other pool widths and chunkings give the same bits...
    with pytest.warns(gj.FailedLanesWarning, match="NONFINITE 1"):
        wide = gj.sweep(BALL, x0s, 0.0, 3.0, args, balance="refill", chunk_size=7, pool_size=7,
                        **kw)
    _assert_same_lanes(wide, pool, exact=True)
    # ... and so does plain vmap (the same loop; only XLA's fusion of it differs, which can
    # move a result by an ulp: see the module docstring of grazejax._sweep).
    with pytest.warns(gj.FailedLanesWarning, match="NONFINITE 1"):
        plain = gj.sweep(BALL, x0s, 0.0, 3.0, args, balance="none", **kw)
    _assert_same_lanes(plain, pool, exact=True)
    # One by one (unbatched XLA code rounds differently in the last bits).
    singles = [_ball_single(x0s[i], args["e"][i]) for i in range(LANES)]
    loop = jax.tree.map(lambda *leaves: np.stack(leaves), *singles)
    _assert_same_lanes(pool, loop, exact=False)


def test_a_lane_does_not_depend_on_the_lanes_beside_it():
    """The same start gives the same bits whatever starts share its vmapped batch. ex1dof's
    field depends on t and on both coordinates, so a field value recomputed elsewhere may
    round differently from the one the last stage stored (FSAL): the recomputation after a
    jump must happen for the lanes that jumped only, not for every lane whenever one of them
    jumped (as a `cond` on any lane did: a lane's bits then moved with its neighbours'
    impacts; see `grazejax._loop.unrolled`). Batches of one size are one program; batches of
    other sizes are other programs, which XLA may fuse (and contract into FMAs) differently,
    so they agree to rounding only (`grazejax._sweep`'s docstring)."""
    x0s = np.stack([np.zeros(10), np.linspace(0.05, 0.9, 10)], axis=1)
    run = jax.jit(jax.vmap(lambda x: gj.simulate(
        ex.ex1dof(), x, 0.0, 30.0, ex.ex1dof_args(0.2), rtol=1e-9, atol=1e-11,
        max_impacts=20)))
    everyone = run(jnp.asarray(x0s))
    assert np.all(np.asarray(everyone.status) == gj.Status.SUCCESS)
    assert np.all(np.asarray(everyone.num_impacts) >= 4)
    others = np.stack([np.zeros(10), np.linspace(0.93, 0.06, 10)], axis=1)  # other impacts
    for lanes in ([0, 1], [0, 1, 2, 3, 4, 5], [2, 5, 8]):
        mixed = others.copy()
        mixed[lanes] = x0s[lanes]
        beside = run(jnp.asarray(mixed))
        mine = jax.tree.map(lambda leaf, lanes=lanes: np.asarray(leaf)[lanes], beside)
        picked = jax.tree.map(lambda leaf, lanes=lanes: np.asarray(leaf)[lanes], everyone)
        _assert_same_lanes(mine, picked, exact=True)
        few = run(jnp.asarray(x0s[lanes]))  # another batch size: another program
        _assert_same_lanes(few, picked, exact=False)


def test_refill_mixes_lane_costs_and_statuses():
    # Deterministic companion of the property test: make sure the mix it relies on happens
    # (Zeno lanes, max-steps lanes, a full impact log, a NaN lane, lanes with 0 steps).
    x0s, args = _ball_lanes(np.linspace(0.1, 2.0, LANES), np.linspace(0.2, 0.97, LANES), 5)
    with pytest.warns(gj.FailedLanesWarning) as warned:
        out = gj.sweep(BALL, x0s, 0.0, 3.0, args, balance="refill", pool_size=4, progress=False,
                       **BALL_OPTS)
    statuses = set(out.status.tolist())
    failed = {gj.Status(s).name: int(np.sum(out.status == s)) for s in sorted(statuses)
              if s not in (gj.Status.SUCCESS, gj.Status.MAX_IMPACTS, gj.Status.ZENO)}
    assert len(warned) == 1 and str(warned[0].message).startswith(
        f"grazejax.sweep: {sum(failed.values())} of {LANES} lanes failed ("
        + ", ".join(f"{name} {n}" for name, n in failed.items()) + ")")
    assert {gj.Status.ZENO, gj.Status.MAX_STEPS, gj.Status.NONFINITE} <= statuses, statuses
    assert out.num_steps.max() == 60 and out.num_steps.min() == 0
    assert out.num_impacts.max() >= 5 * max(1, out.num_impacts[out.num_impacts > 0].min())
    assert out.ts.shape == (LANES, 7) and out.xs.shape == (LANES, 7, 2)


def test_sharded_over_four_cpu_devices_equals_single_device():
    script = textwrap.dedent(
        """
        import numpy as np, jax
        import grazejax as gj
        from grazejax import examples as ex
        assert len(jax.devices()) == 4, jax.devices()
        x0s = np.stack([np.zeros(10), np.linspace(0.05, 0.9, 10)], axis=1)
        kw = dict(rtol=1e-9, atol=1e-11, max_impacts=20, progress=False)
        many = gj.sweep(ex.ex1dof(), x0s, 0.0, 30.0, ex.ex1dof_args(0.2), chunk_size=6, **kw)
        one = gj.sweep(ex.ex1dof(), x0s, 0.0, 30.0, ex.ex1dof_args(0.2), devices=jax.devices()[:1], **kw)
        np.testing.assert_array_equal(many.num_impacts, one.num_impacts)
        np.testing.assert_array_equal(many.status, one.status)
        np.testing.assert_allclose(many.x_final, one.x_final, rtol=1e-12, atol=1e-14)
        # The pool: each device runs its own pool on its share of the chunk; same bits.
        x0s[3, 0] = np.nan
        kw = dict(kw, max_steps=540, saveat=np.linspace(0.0, 30.0, 5))
        for pool in (None, 2):
            many = gj.sweep(ex.ex1dof(), x0s, 0.0, 30.0, ex.ex1dof_args(0.2), chunk_size=6,
                            balance="refill", pool_size=pool, **kw)
            one = gj.sweep(ex.ex1dof(), x0s, 0.0, 30.0, ex.ex1dof_args(0.2), devices=jax.devices()[:1],
                           balance="refill", pool_size=pool, **kw)
            for field in ("status", "num_steps", "x_final", "impact_times", "impact_post", "xs"):
                np.testing.assert_array_equal(getattr(many, field), getattr(one, field), err_msg=field)
        statuses = set(many.status.tolist())
        assert {gj.Status.NONFINITE, gj.Status.MAX_STEPS, gj.Status.SUCCESS} <= statuses, statuses
        print("OK", many.x_final.shape)
        """
    )
    env = dict(os.environ, XLA_FLAGS=f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "OK (10, 2)" in out.stdout


def test_sweep_passes_every_simulate_option_to_the_pool():
    """zeno="stick" (and any option of simulate) reaches the pool: balls dropped on a
    vibrating table chatter, stick and release in the sweep exactly as in single runs."""
    table, args = ex.vibrating_table(), dict(g=9.81, e=0.3, A=0.1, omega=12.0)
    opts = dict(rtol=1e-10, atol=1e-12, max_impacts=300, zeno="stick")
    x0s = np.stack([np.linspace(0.2, 0.4, 5), np.zeros(5)], axis=1)
    out = gj.sweep(table, x0s, 0.0, 2.0, args, progress=False, pool_size=2, **opts)
    assert np.all(np.sum(out.impact_kind == int(gj.ImpactKind.RELEASE), axis=1) >= 2)
    for i in range(5):
        single = gj.simulate(table, x0s[i], 0.0, 2.0, args, **opts)
        assert int(out.num_impacts[i]) == int(single.num_impacts)
        np.testing.assert_array_equal(out.impact_kind[i], single.impact_kind)
        np.testing.assert_allclose(out.x_final[i], single.x_final, rtol=1e-10, atol=1e-12)


def test_two_processes_with_jax_distributed_equal_one_process(tmp_path):
    """Multi-host use: two processes (one CPU device each, gloo collectives) joined by
    jax.distributed.initialize run the same sweep call; each gets the whole result, equal to
    the single-process run bit for bit."""
    import socket

    with socket.socket() as s:
        s.bind(("localhost", 0))
        port = s.getsockname()[1]
    script = textwrap.dedent(
        f"""
        import sys
        import jax
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
        jax.distributed.initialize(coordinator_address="localhost:{port}", num_processes=2,
                                   process_id=int(sys.argv[1]))
        import numpy as np
        import grazejax as gj
        from grazejax import examples as ex
        assert jax.process_count() == 2 and len(jax.devices()) == 2
        x0s = np.stack([np.zeros(10), np.linspace(0.05, 0.9, 10)], axis=1)
        x0s[3, 0] = np.nan  # a bad lane (and NaN != NaN: inputs must not be compared)
        out = {{}}
        for balance in ("refill", "none"):
            sol = gj.sweep(ex.ex1dof(), x0s, 0.0, 30.0, ex.ex1dof_args(0.2), rtol=1e-9,
                           atol=1e-11, max_impacts=20, progress=False, balance=balance)
            out.update({{balance + "_" + k: getattr(sol, k) for k in
                        ("x_final", "num_impacts", "status", "impact_times")}})
        np.savez(sys.argv[2], **out)
        """
    )
    # (one CPU device per process: a device count in XLA_FLAGS is dropped, the rest kept)
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if "device_count" not in f]
    env = dict(os.environ, XLA_FLAGS=" ".join(flags))
    procs = [
        subprocess.Popen([sys.executable, "-c", script, str(i), str(tmp_path / f"p{i}.npz")], env=env,
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for i in range(2)
    ]
    logs = [p.communicate(timeout=600)[0] for p in procs]
    assert all(p.returncode == 0 for p in procs), logs
    x0s = np.stack([np.zeros(10), np.linspace(0.05, 0.9, 10)], axis=1)
    x0s[3, 0] = np.nan
    for i in range(2):
        got = np.load(tmp_path / f"p{i}.npz")
        for balance in ("refill", "none"):
            with pytest.warns(gj.FailedLanesWarning, match="NONFINITE 1"):
                ref = gj.sweep(SCENE, x0s, 0.0, 30.0, ex.ex1dof_args(0.2), balance=balance,
                               **OPTS)
            for k in ("x_final", "num_impacts", "status", "impact_times"):
                np.testing.assert_array_equal(got[f"{balance}_{k}"], getattr(ref, k), err_msg=k)
