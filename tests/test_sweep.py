"""grazejax.sweep: batch equals loop, chunking, per-lane status, devices, bad input."""

import os
import subprocess
import sys
import textwrap

import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import examples as ex

SCENE = ex.ex1dof()
OPTS = dict(rtol=1e-9, atol=1e-11, max_impacts=20, progress=False)


def test_sweep_equals_single_runs_and_keeps_input_order():
    args = ex.ex1dof_args(0.2)
    x0s = np.stack([np.zeros(7), np.linspace(0.05, 0.9, 7)], axis=1)
    for balance in ("none", "presort"):
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
    ],
)
def test_bad_input(kwargs, match):
    kwargs.setdefault("args", ex.ex1dof_args(0.2))
    with pytest.raises(ValueError, match=match):
        gj.sweep(SCENE, t0=0.0, t1=1.0, progress=False, **kwargs)


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
        print("OK", many.x_final.shape)
        """
    )
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4")
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "OK (10, 2)" in out.stdout
