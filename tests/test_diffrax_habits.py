"""What users of Diffrax expect to work: `diffrax.SaveAt`, `Solution.ys`, `throw=True` (outside and inside
jit, single runs and batches), `Solution.summary()` on a batch, a progress bar that counts
lanes, and `grazejax bench` naming the extra it needs."""

import io
import re

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj
from grazejax import _sweep
from grazejax import examples as ex

BALL = ex.bouncing_ball()
ARGS = {"g": 9.81, "e": 0.8}
ELASTIC = {"g": 9.81, "e": 1.0}  # never Zeno: runs out of steps when max_steps is small
TOL = dict(rtol=1e-10, atol=1e-12)
RUNTIME_ERRORS = (eqx.EquinoxRuntimeError, jax.errors.JaxRuntimeError)

# ---------------------------------------------------------------- diffrax.SaveAt ------


def test_saveat_ts_equals_plain_times():
    ts = jnp.linspace(0.0, 1.0, 6)
    plain = gj.simulate(BALL, [1.0, 0.0], 0.0, 1.0, ARGS, saveat=ts, **TOL)
    wrapped = gj.simulate(BALL, [1.0, 0.0], 0.0, 1.0, ARGS, saveat=diffrax.SaveAt(ts=ts), **TOL)
    np.testing.assert_array_equal(wrapped.ts, plain.ts)
    np.testing.assert_array_equal(wrapped.xs, plain.xs)


def test_ys_is_diffraxs_name_for_the_saved_states():
    ts = jnp.linspace(0.0, 1.0, 6)
    sol = gj.simulate(BALL, [1.0, 0.0], 0.0, 1.0, ARGS, saveat=diffrax.SaveAt(ts=ts), **TOL)
    assert sol.ys is sol.xs and sol.ys.shape == (6, 2)
    batch = jax.vmap(lambda h: gj.simulate(BALL, jnp.stack([h, 0.0]), 0.0, 1.0, ARGS,
                                           saveat=ts, **TOL))(jnp.array([1.0, 2.0]))
    assert batch.ys.shape == (2, 6, 2)
    assert gj.simulate(BALL, [1.0, 0.0], 0.0, 1.0, ARGS).ys is None


def test_saveat_t0_ts_t1_in_diffrax_order():
    ts = jnp.array([0.25, 0.5])
    saveat = diffrax.SaveAt(t0=True, ts=ts, t1=True)
    sol = gj.simulate(BALL, [1.0, 0.0], 0.0, 1.0, ARGS, saveat=saveat, **TOL)
    np.testing.assert_array_equal(sol.ts, [0.0, 0.25, 0.5, 1.0])
    np.testing.assert_array_equal(sol.xs[0], [1.0, 0.0])
    # t1 is reached (SUCCESS): the state saved there is the final state, to round-off of
    # the dense output at the step end.
    assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
    np.testing.assert_allclose(sol.xs[-1], sol.x_final, rtol=0, atol=1e-12)


def test_saveat_under_jit_and_in_sweep():
    ts = jnp.linspace(0.0, 1.0, 5)
    for saveat in (ts, diffrax.SaveAt(ts=ts)):
        run = jax.jit(lambda x0, saveat=saveat: gj.simulate(BALL, x0, 0.0, 1.0, ARGS, saveat=saveat))
        out = gj.sweep(BALL, np.array([[1.0, 0.0], [0.5, 0.0]]), 0.0, 1.0, ARGS, saveat=saveat,
                       progress=False)
        if saveat is ts:
            jitted, swept = run(jnp.array([1.0, 0.0])).xs, out.xs
        else:  # SaveAt(ts=...) and the plain times compile the same program
            np.testing.assert_array_equal(run(jnp.array([1.0, 0.0])).xs, jitted)
            np.testing.assert_array_equal(out.xs, swept)
            np.testing.assert_array_equal(out.ts[0], ts)


@pytest.mark.parametrize(
    "saveat,match",
    [
        (diffrax.SaveAt(steps=True), "steps=True"),
        (diffrax.SaveAt(dense=True), "dense=True"),
        (diffrax.SaveAt(t1=True, solver_state=True), "solver_state=True"),
        (diffrax.SaveAt(ts=[0.5], fn=lambda t, y, args: y[0]), "fn="),
        (diffrax.SaveAt(subs=[diffrax.SubSaveAt(t0=True), diffrax.SubSaveAt(t1=True)]), "subs"),
    ],
)
def test_unsupported_saveat_names_what_works(saveat, match):
    with pytest.raises(ValueError, match=match) as info:
        gj.simulate(BALL, [1.0, 0.0], 0.0, 1.0, ARGS, saveat=saveat)
    assert "SaveAt(ts=...)" in str(info.value)


def test_saveat_t1_at_infinity_points_to_x_final():
    with pytest.raises(ValueError, match="x_final"):
        gj.simulate(BALL, [1.0, 0.0], 0.0, jnp.inf, ARGS, saveat=diffrax.SaveAt(t1=True))


# ---------------------------------------------------------------- throw=True ----------


def test_throw_names_status_fix_and_carries_the_solution():
    with pytest.raises(gj.SimulationError) as info:
        gj.simulate(BALL, [1.0, 0.0], 0.0, 100.0, ELASTIC, max_steps=20, throw=True)
    error = info.value
    assert error.status == gj.Status.MAX_STEPS and error.lanes is None
    assert "MAX_STEPS" in str(error) and "raise max_steps" in str(error)
    assert int(error.solution.num_steps) == 20
    assert gj.Status(int(error.solution.status)) == gj.Status.MAX_STEPS


def test_throw_accepts_max_impacts_and_zeno():
    sol = gj.simulate(BALL, [1.0, 0.0], 0.0, 5.0, ARGS, max_impacts=3, throw=True)
    assert gj.Status(int(sol.status)) == gj.Status.MAX_IMPACTS
    sol = gj.simulate(BALL, [1.0, 0.0], 0.0, 5.0, ARGS, max_impacts=200, throw=True)
    assert gj.Status(int(sol.status)) == gj.Status.ZENO


def test_throw_under_jit_and_vmap_names_the_status():
    def run(x0):
        return gj.simulate(BALL, x0, 0.0, 100.0, ELASTIC, max_steps=20, throw=True).x_final

    # The runtime raises the compiled check's message (the exception type is JAX's).
    with pytest.raises(RUNTIME_ERRORS, match="MAX_STEPS.*raise max_steps"):
        jax.block_until_ready(jax.jit(run)(jnp.array([1.0, 0.0])))
    with pytest.raises(RUNTIME_ERRORS, match="MAX_STEPS"):
        jax.block_until_ready(jax.vmap(run)(jnp.array([[1.0, 0.0], [0.5, 0.0]])))
    # A run that succeeds passes through the compiled check unchanged.
    fine = jax.jit(lambda x0: gj.simulate(BALL, x0, 0.0, 0.2, ARGS, throw=True).x_final)
    assert np.all(np.isfinite(fine(jnp.array([1.0, 0.0]))))


def _nan_above(height):
    """A falling ball whose field is NaN above `height`: lanes started there fail at once
    (NONFINITE: every step from x0 is NaN, the step size too)."""
    floor = BALL.surfaces[0]
    field = lambda t, x, a: jnp.stack([x[1], -a["g"] + jnp.where(x[0] > height, jnp.nan, 0.0)])
    return gj.Scene(field, [floor])


@pytest.mark.parametrize("balance", ["refill", "none"])
def test_sweep_warns_or_throws_naming_the_failing_lanes(balance):
    scene = _nan_above(3.0)
    x0s = np.array([[0.1, 0.0], [5.0, 0.0], [0.2, 0.0], [4.0, 0.0]])
    kw = dict(max_impacts=5, max_steps=50, progress=False, balance=balance)
    # Without throw: one warning (progress=False too) that counts the failing lanes.
    with pytest.warns(gj.FailedLanesWarning) as warned:
        quiet = gj.sweep(scene, x0s, 0.0, 1.0, ARGS, **kw)
    np.testing.assert_array_equal(quiet.status == gj.Status.NONFINITE, [False, True, False, True])
    assert len(warned) == 1 and warned[0].filename == __file__
    assert str(warned[0].message).startswith("grazejax.sweep: 2 of 4 lanes failed (NONFINITE 2)")
    # With throw: the error instead (a warning first would be an error here too).
    with pytest.raises(gj.SimulationError) as info:
        gj.sweep(scene, x0s, 0.0, 1.0, ARGS, throw=True, **kw)
    np.testing.assert_array_equal(info.value.lanes, [1, 3])
    assert info.value.status == gj.Status.NONFINITE
    assert "2 of 4 lanes failed (NONFINITE 2); the first is lane 1" in str(info.value)
    np.testing.assert_array_equal(info.value.solution.status, quiet.status)


# ---------------------------------------------------------------- summary -------------


def test_summary_of_a_batch_counts_statuses_and_lists_lanes():
    x0s = np.array([[1.0, 0.0], [0.5, 0.0], [0.2, 0.0]])
    out = gj.sweep(BALL, x0s, 0.0, 5.0, ARGS, max_impacts=3, progress=False)
    names = [gj.Status(int(s)).name for s in out.status]
    text = out.summary(max_lanes=2)
    assert text.startswith("3 lanes: ")
    for name in set(names):
        assert f"{name} {names.count(name)}" in text
    assert f"lane 0: {names[0]}" in text and f"lane 1: {names[1]}" in text
    assert "lane 2:" not in text and "1 more lane" in text
    # A vmapped Solution (JAX arrays with a batch axis) reads the same way.
    batched = jax.vmap(lambda x0: gj.simulate(BALL, x0, 0.0, 5.0, ARGS, max_impacts=3))(
        jnp.asarray(x0s)
    )
    assert batched.summary(max_lanes=2).splitlines()[0] == text.splitlines()[0]


# ---------------------------------------------------------------- progress bar --------


@pytest.mark.parametrize("balance", ["refill", "none"])
def test_progress_counts_lanes(monkeypatch, balance):
    import tqdm.auto

    bars = []

    class Bar(tqdm.auto.tqdm):  # the real bar, drawn into a string, every update shown
        def __init__(self, *args, **kwargs):
            super().__init__(*args, file=io.StringIO(), mininterval=0, **kwargs)
            self.updates = []
            bars.append(self)

        def update(self, n=1):
            self.updates.append(n)
            return super().update(n)

        def close(self):
            self.drawn = self.fp.getvalue()
            super().close()

    monkeypatch.setattr(tqdm.auto, "tqdm", Bar)
    x0s = np.stack([np.full(12, 0.0), np.linspace(0.05, 0.9, 12)], axis=1)
    gj.sweep(ex.ex1dof(), x0s, 0.0, 20.0, ex.ex1dof_args(0.2), max_impacts=4, chunk_size=12,
             balance=balance, pool_size=4 if balance == "refill" else None, progress=True)
    (bar,) = bars
    assert bar.unit == "lane" and bar.total == 12 and bar.n == 12
    if balance == "refill":
        # One chunk, but the bar moves as the pool's slots finish, never past the total.
        assert len(bar.updates) > 1 and sum(bar.updates) <= 12
    # Until the first lanes are done the program compiles: the bar says so, with no rate or
    # ETA (they would be the compile's); then tqdm's usual rate and ETA.
    frames = [f.strip() for f in bar.drawn.split("\r") if f.strip()]
    compiling = [f for f in frames if "(compiling)" in f]
    running = frames[len(compiling):]
    assert compiling and frames[:len(compiling)] == compiling, frames
    assert all("lane/s" not in f and "s/lane" not in f and "<" not in f for f in compiling)
    assert compiling[0].startswith("grazejax.sweep (compiling):   0%")
    assert running and all(f.startswith("grazejax.sweep: ") and "<" in f for f in running)
    assert re.search(r"\d(lane/s|s/lane)\]$", running[-1]), running[-1]
    assert running[-1].startswith("grazejax.sweep: 100%")
    assert _sweep._BAR[0] is None  # no bar left behind for a later sweep's reports
