"""The field-jump probe (`_loop/field.py`, `Status.FIELD_DISCONTINUITY`): a field written
with `sign(·)` on an event surface is refused at its first event; nothing else is.

Three layers: the probe on fields with known regularity (a jump, kinks, smooth fields with
large curvature), the two `sign(·)` scenes of issue 13 against their mode formulations, and
a no-false-alarm campaign over every example scene of the package (slow).
"""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import grazejax as gj
from grazejax import examples as ex
from grazejax._loop.field import continuous_in_state, field_jumps, field_probe

from ..helpers import quick_jit

TOL = 1e-10


# --------------------------------------------------------------------------------------
# The probe on fields of known regularity
# --------------------------------------------------------------------------------------


def _verdict(field, x, scale=1.0):
    x = jnp.asarray(x, float)
    return bool(field_jumps(lambda t, y, a: field(y), 0.0, x, None, jnp.full_like(x, scale)))


@pytest.mark.parametrize("side", [1e-31, -1e-31, 0.0, 3e-17, -3e-17])
@pytest.mark.parametrize("size", [1.0, 1e-3, 1e-9])
def test_a_jump_is_found_whichever_side_the_state_is_on(side, size):
    # x'' = −x − μ sign(x') at a turn: x' is round-off, f jumps by 2μ in x''.
    field = lambda y: jnp.stack([y[1], -y[0] - size * jnp.sign(y[1])])  # noqa: E731
    assert _verdict(field, [0.8, side])


@pytest.mark.parametrize(
    "force",
    [
        lambda x: jnp.maximum(-x, 0.0),  # kink: f continuous, ∂f jumps (p = 1)
        lambda x: jnp.maximum(-x, 0.0) ** 1.5,  # Hertz contact (p = 1.5)
        lambda x: jnp.abs(x),  # kink on both sides
        lambda x: jnp.sin(x),
        lambda x: jnp.exp(50.0 * x),  # smooth, curvature 2500 per unit length²
        lambda x: 1e6 * x**2,
    ],
)
@pytest.mark.parametrize("x", [1e-31, -1e-31, 0.0, 0.3])
def test_continuous_fields_are_not_refused(force, x):
    field = lambda y: jnp.stack([y[1], -9.81 + 1e3 * force(y[0])])  # noqa: E731
    assert not _verdict(field, [x, -2.0])


def test_no_verdict_at_rest_or_where_the_field_is_undefined():
    assert not _verdict(lambda y: jnp.zeros(2) * y, [0.0, 0.0])
    assert not _verdict(lambda y: jnp.stack([y[1], jnp.sqrt(y[0]) - jnp.sign(y[0])]), [0.0, -1.0])


def test_the_probe_margins():
    # The decision is far from its thresholds on both sides: a jump exceeds τ by
    # 8/(1e3·√ε) ≈ 5e5 (the jump itself inflates τ through the slope G, field.py) with
    # growth ≈ 0; a smooth field's second difference grows ≈ 4× (growth 3).
    jump = lambda t, y, a: jnp.stack([y[1], -y[0] - 1e-3 * jnp.sign(y[1])])  # noqa: E731
    sizes, tau, growths = field_probe(jump, 0.0, jnp.array([0.8, 1e-31]), None, jnp.ones(2))
    assert sizes[0] > 1e5 * tau and growths[0] < 1e-3  # the side beyond x' = 0
    assert sizes[1] < tau  # the side x⁺ is on: smooth
    # A smooth field's D ≈ δ²·D²f[v, v] = ε·L²·f'' stays below τ ≈ 1e3·ε·(F + L·G) unless
    # its curvature is ~1e3 times its slope: sin(1e4 x) is, and there D grows 4× (growth 3).
    smooth = lambda t, y, a: jnp.stack([y[1], jnp.exp(50.0 * y[0])])  # noqa: E731
    sizes, tau, growths = field_probe(smooth, 0.0, jnp.array([0.3, -2.0]), None, jnp.ones(2))
    assert jnp.all(sizes < 0.1 * tau)
    wavy = lambda t, y, a: jnp.stack([y[1], jnp.sin(1e4 * y[0])])  # noqa: E731
    sizes, tau, growths = field_probe(wavy, 0.0, jnp.array([0.3, -2.0]), None, jnp.ones(2))
    assert jnp.all(sizes > tau) and jnp.all(jnp.abs(growths - 3.0) < 0.1)


# --------------------------------------------------------------------------------------
# The sign(·) scenes of issue 13 are refused; their mode formulations are not
# --------------------------------------------------------------------------------------

ROCK = {"p": 2.0, "alpha": 0.2, "e": 0.9}


# (Each scene is built once: the runs of one scene share what the package caches per scene.)
@functools.cache
def sign_rocking_block():
    """θ'' = p²(θ − α sign θ), two pieces Φ = ±θ with a restitution jump (issue 13)."""
    field = lambda t, x, a: jnp.stack([x[1], a["p"] ** 2 * (x[0] - a["alpha"] * jnp.sign(x[0]))])  # noqa: E731
    restitution = lambda t, x, a: x.at[1].set(a["e"] * x[1])  # noqa: E731
    return gj.Scene(field, [gj.Surface(lambda t, x, a: x[0], restitution),
                            gj.Surface(lambda t, x, a: -x[0], restitution)])


@functools.cache
def sign_friction_oscillator():
    """x'' + x = −μ sign(x'), identity-jump events on x' = 0 from each side (issue 13)."""
    field = lambda t, x, a: jnp.stack([x[1], -x[0] - a["mu"] * jnp.sign(x[1])])  # noqa: E731
    same = lambda t, x, a: x  # noqa: E731
    return gj.Scene(field, [gj.Surface(lambda t, x, a: x[1], same),
                            gj.Surface(lambda t, x, a: -x[1], same)])


def test_sign_rocking_block_is_refused_at_its_first_impact():
    first = ex.rocking_block_impact_times(0.1, ROCK["p"], ROCK["alpha"], ROCK["e"], 1)[0]
    run = quick_jit(lambda x0: gj.simulate(sign_rocking_block(), x0, 0.0, 10.0, ROCK, rtol=TOL,
                                           atol=TOL, direction=1))
    sol = run(jnp.array([0.1, 0.0]))
    assert gj.Status(int(sol.status)) == gj.Status.FIELD_DISCONTINUITY
    assert int(sol.num_impacts) == 1
    assert abs(float(sol.t_final) - first) < 50 * TOL
    # Outside jit: a ValueError that names the fix.
    with pytest.raises(ValueError, match="PiecewiseScene"):
        gj.simulate(sign_rocking_block(), jnp.array([0.1, 0.0]), 0.0, 10.0, ROCK, rtol=TOL,
                    atol=TOL)
    # The mode formulation runs through its impacts, on the closed form.
    pw = ex.rocking_block()
    sol = gj.simulate(pw.scene, pw.state([0.1, 0.0], "right"), 0.0, 10.0, ROCK, rtol=TOL,
                      atol=TOL, max_impacts=8)
    assert gj.Status(int(sol.status)) == gj.Status.MAX_IMPACTS
    times = ex.rocking_block_impact_times(0.1, ROCK["p"], ROCK["alpha"], ROCK["e"], 8)
    np.testing.assert_allclose(np.asarray(sol.impact_times), times, rtol=0, atol=50 * TOL * 11)


def test_sign_friction_oscillator_is_refused_per_lane_at_its_first_turn():
    # Lanes 0, 1 (μ = 0) have a smooth field with the same events: they run to t1. From
    # (1, 0) the start is on x' = 0: refused at t0, before any flight used sign(0) = 0;
    # from (1, 0.3) at the first turn, at t = atan(0.3/1.1) (a circle about (−μ, 0)).
    run = quick_jit(jax.vmap(lambda x0, mu: gj.simulate(sign_friction_oscillator(), x0, 0.0,
                                                        20.0, {"mu": mu}, rtol=TOL, atol=TOL,
                                                        direction=1)))
    x0s = jnp.array([[1.0, 0.0], [1.0, 0.3], [1.0, 0.0], [1.0, 0.3]])
    sol = run(x0s, jnp.array([0.0, 0.0, 0.1, 0.1]))
    status = [gj.Status(int(s)) for s in sol.status]
    assert status == [gj.Status.SUCCESS] * 2 + [gj.Status.FIELD_DISCONTINUITY] * 2
    assert np.asarray(sol.num_impacts).tolist() == [6, 7, 0, 1]
    assert float(sol.t_final[2]) == 0.0
    first_turn = math.atan2(0.3, 1.0 + 0.1)
    assert abs(float(sol.t_final[3]) - first_turn) < 50 * TOL * (1 + first_turn)
    with pytest.raises(ValueError, match="x0 = .* lies on a surface.*PiecewiseScene"):
        gj.simulate(sign_friction_oscillator(), jnp.array([1.0, 0.0]), 0.0, 20.0, {"mu": 0.1})
    message = str(gj.SimulationError(sol))
    assert "FIELD_DISCONTINUITY" in message and "PiecewiseScene" in message
    # The check compiled out: the run goes on (inaccurately, issue 13), never refused.
    quiet = gj.simulate(sign_friction_oscillator(), jnp.array([1.0, 0.0]), 0.0, 20.0,
                        {"mu": 0.1}, rtol=TOL, atol=TOL, check_field_jumps=False)
    assert gj.Status(int(quiet.status)) != gj.Status.FIELD_DISCONTINUITY
    assert int(quiet.num_impacts) > 1



# --------------------------------------------------------------------------------------
# Fields that cannot jump are read from their jaxpr: no probe in their program
# --------------------------------------------------------------------------------------

_KINKED = [
    lambda t, x, a: jnp.stack([x[1], -jax.nn.relu(x[0]) + jnp.linalg.norm(x)]),
    lambda t, x, a: jnp.clip(x, -1.0, 1.0) + jnp.abs(x) ** 1.5 + jnp.maximum(x, 0.0),
    lambda t, x, a: x.at[1].set(x[0] * a) + jax.jit(lambda y: y[::-1])(x),
    lambda t, x, a: x.at[0].add(x[1] ** 2) + jax.lax.dynamic_update_slice(x, x[:1], (1,)),
    lambda t, x, a: jax.checkpoint(jnp.sin)(x),
    lambda t, x, a: jax.lax.cond(a > 0, lambda: x, lambda: -x),  # a choice on args only
    lambda t, x, a: jnp.where(t > 1.0, x, -x),  # a choice on t only (fixed in the probe)
    lambda t, x, a: jnp.stack([x[1], jnp.cos(a * t) - jnp.sin(x[0]) * jnp.exp(-x[1] ** 2)]),
]
_CAN_JUMP = [
    lambda t, x, a: jnp.stack([x[1], -jnp.sign(x[0])]),
    lambda t, x, a: jnp.stack([x[1], jnp.where(x[0] > 0, -1.0, 1.0)]),
    lambda t, x, a: x * jnp.heaviside(x[0], 0.5),
    lambda t, x, a: jnp.stack([x[1], x[jnp.argmax(x)]]),  # an index chosen by x
    lambda t, x, a: x.at[jnp.argmin(x)].add(1.0),
    lambda t, x, a: jax.lax.cond(x[0] > 0, lambda: x, lambda: -x),
    lambda t, x, a: jnp.stack([x[1], jnp.arctan2(x[1], x[0])]),  # its branch cut
    lambda t, x, a: x * x[0].astype(int),
    lambda t, x, a: jnp.stack([x[1], jnp.floor(x[0])]),
    lambda t, x, a: x.astype(jnp.float32).astype(x.dtype),  # rounds: steps of f32 ulps
    lambda t, x, a: jnp.sin(x.astype(jnp.float32)).astype(x.dtype) - x,
    lambda t, x, a: jax.lax.while_loop(lambda y: y[0] < 1.0, lambda y: y + 1.0, x),
]


@pytest.mark.parametrize("field", _KINKED)
def test_fields_built_from_continuous_operations_are_continuous(field):
    x = jnp.array([0.3, -0.2])
    assert continuous_in_state(field, 0.5, x, 1.0)
    # also on traced inputs (a user's jit, a batch)
    assert jax.jit(lambda x, t, a: jnp.asarray(continuous_in_state(field, t, x, a)))(x, 0.5, 1.0)
    assert jax.vmap(lambda x: jnp.asarray(continuous_in_state(field, 0.5, x, 1.0)))(
        jnp.stack([x, x])).all()


@pytest.mark.parametrize("field", _CAN_JUMP)
def test_fields_that_may_jump_keep_the_probe(field):
    assert not continuous_in_state(field, 0.5, jnp.array([0.3, -0.2]), 1.0)


def test_which_example_scenes_compile_the_probe():
    """Every example `Scene` has a continuous field (no probe, neither compiled nor run);
    `PiecewiseScene`s choose their field by the mode in the state (probe kept), and so do
    the `sign(·)` scenes, which the probe refuses."""
    from grazejax._simulate import SIMULATE_OPTIONS, prepare

    options = {k: v for k, v in SIMULATE_OPTIONS.items() if k not in ("saveat", "throw")}

    def probes(scene, x0, args):
        _, program = prepare(scene, jnp.asarray(x0, float), 0.0, 1.0, args, saveat=None,
                             **options)
        return program.init.args[0].check_field_jumps  # the loop's context

    continuous = [(ex.ex1dof(), [0.5, 1.0], ex.ex1dof_args(0.2)),
                  (ex.bouncing_ball(), [1.0, 0.0], {"g": 9.81, "e": 0.8}),
                  (ex.impact_oscillator(), [0.0, 0.1], ex.impact_oscillator_args())]
    continuous += [(make(), [0.5, 1.0], make_args()) for make, make_args in ex.PAPER_SCENES.values()]
    assert not any(probes(*case) for case in continuous)
    fo = ex.friction_oscillator()
    assert probes(fo.scene, fo.state(np.array([1.0, 0.5]), "forward"), {"mu": 0.1})
    assert probes(sign_friction_oscillator(), [1.0, 0.5], {"mu": 0.1})
    assert probes(sign_rocking_block(), [0.1, 0.0], ROCK)


# --------------------------------------------------------------------------------------
# No false alarms: every example scene of the package, forward and backward, Zeno and
# sticking, near-grazing starts (slow: one compilation per case)
# --------------------------------------------------------------------------------------


def _grid(center, spread, num, seed):
    rng = np.random.default_rng(seed)
    return jnp.asarray(np.asarray(center) + spread * rng.uniform(-1, 1, (num, len(center))))


def _rings(center, radii, angle):
    """States on circles about `center` (radius r, at `angle`): near-grazing starts."""
    radii = np.asarray(radii)
    return jnp.asarray(np.stack([center[0] + radii * np.cos(angle),
                                 center[1] + radii * np.sin(angle)], axis=1))


# Offsets from the grazing radius: inside, within and beyond the contact floor.
_NEAR = np.array([-1e-6, -1e-9, -1e-12, 0.0, 1e-12, 1e-9, 1e-6])


def campaign_cases():
    """`(name, scene, x0s, t0, t1, args, options)`: one batch of lanes per case.

    Each scene and each options dict is built once and shared by the cases that use it:
    `run_campaign` runs the cases with the same scene object, options and direction of
    time as one compiled program (their t0, t1 and args are traced, per lane). A backward
    case's `x0s` is `("forward from", starts, options)`: it starts where the forward flow
    from `starts` is at its t0, run with `options` (those of the scene's forward case, so
    that the run to t0 adds lanes to that case's program rather than a program of its own).
    """
    ball, ball_args = ex.bouncing_ball(), {"g": 9.81, "e": 0.8}
    table = ex.vibrating_table()
    table_args = {"g": 9.81, "e": 0.5, "A": 0.05, "omega": 10.0}
    osc, osc_args = ex.impact_oscillator(), ex.impact_oscillator_args()
    fourier = ex.fourier_impact_oscillator()
    fourier_args = ex.fourier_impact_oscillator_args([0.0, 1.0, 0.3], [0.0, 0.2, 0.0])
    long = {"max_impacts": 60, "rtol": TOL, "atol": TOL}
    back = {"max_impacts": 20, "rtol": TOL, "atol": TOL}
    cases = [
        ("ball Zeno", ball, _grid([1.0, 0.0], 0.5, 6, 0), 0.0, 10.0, ball_args, {"max_impacts": 200}),
        ("ball stick", ball, _grid([1.0, 0.0], 0.5, 6, 1), 0.0, 10.0, ball_args,
         {"max_impacts": 200, "zeno": "stick"}),
        ("ball backward", ball, _grid([0.3, 1.0], 0.2, 6, 2), 3.0, 0.0, ball_args, {"max_impacts": 20}),
        ("table stick", table, _grid([0.3, 0.0], 0.1, 6, 3), 0.0, 3.0, table_args,
         {"max_impacts": 200, "zeno": "stick"}),
        ("table", table, _grid([0.3, 0.0], 0.1, 6, 4), 0.0, 3.0, table_args, {"max_impacts": 200}),
        ("oscillator", osc, _grid([0.0, 0.0], 0.3, 6, 5), 0.0, 40.0, osc_args, long),
        ("oscillator backward", osc, _grid([0.0, 0.5], 0.1, 6, 6), 20.0, 0.0, osc_args,
         {"max_impacts": 30}),
        ("fourier oscillator", fourier, _grid([0.0, 0.0], 0.3, 6, 7), 0.0, 40.0, fourier_args, long),
    ]
    paper = {name: make() for name, (make, _) in ex.PAPER_SCENES.items()}
    for name, (_, make_args) in ex.PAPER_SCENES.items():
        cases.append((name, paper[name], _grid([0.5, 1.0], 0.4, 6, 8), 0.0, 30.0, make_args(),
                      long))
        # Backward from where the forward flow is at t = 8: through the same impacts.
        cases.append((name + " backward", paper[name],
                      ("forward from", _grid([0.5, 1.0], 0.4, 6, 8), long), 8.0, 0.0,
                      make_args(), back))
    cases += [
        # ex1dof's unperturbed flow circles (1, 0): radius 1 grazes x1 = 0.
        ("ex1dof near grazing", paper["ex1dof"], _rings([1.0, 0.0], 1.0 + _NEAR, 0.0), 0.0,
         30.0, ex.ex1dof_args(0.0), long),
        # exnonaxial's flow is a rotation: radius 1 grazes x1 + x2 = √2 at angle π/4.
        ("exnonaxial near grazing", paper["exnonaxial"], _rings([0.0, 0.0], 1.0 + _NEAR, 0.0),
         0.0, 30.0, ex.exnonaxial_args(), long),
        ("orbex2 near grazing", paper["orbex2"], _rings([0.0, 0.0], 1e-3 * (1.0 + _NEAR), 0.0),
         0.0, 30.0, ex.orbex2_args(), long),
    ]
    rock, fo, belt, relay = (ex.rocking_block(), ex.friction_oscillator(),
                             ex.belt_stick_slip(), ex.relay_feedback())
    with_mode = lambda pw, xs, mode: jnp.stack([pw.state(x, mode) for x in np.asarray(xs)])  # noqa: E731
    cases += [
        ("rocking block", rock.scene, with_mode(rock, _grid([0.1, 0.0], 0.05, 6, 10), "right"),
         0.0, 10.0, ROCK, long),
        ("friction oscillator", fo.scene, with_mode(fo, _grid([1.0, 0.0], 0.0, 1, 11), "backward"),
         0.0, 20.0, {"mu": 0.1}, long),
        ("friction oscillator moving", fo.scene,
         with_mode(fo, np.stack([np.linspace(-1, 1, 5), np.full(5, 0.5)], 1), "forward"),
         0.0, 20.0, {"mu": 0.1}, long),
        ("belt stick-slip", belt.scene, with_mode(belt, _grid([-0.5, 0.0], 0.1, 6, 12), "slow"),
         0.0, 30.0, {"v_b": 0.5, "mu_s": 0.3, "mu_d": 0.2}, long),
        ("relay feedback", relay.scene,
         with_mode(relay, np.stack([np.linspace(-1, 1, 5), np.full(5, 0.5)], 1), "plus"),
         0.0, 30.0, ex.relay_feedback_args(), long),
    ]
    return cases


def _program_key(scene, t0, t1, options):
    """What a batch's compiled program depends on: the scene object, the direction of time
    and the options (x0, t0, t1 and the numbers in args are its traced inputs)."""
    return id(scene), 1 if t1 > t0 else -1, tuple(sorted(options.items()))


def run_cases(cases):
    """Run `(name, scene, x0s, t0, t1, args, options)` cases, those with the same
    `_program_key` as one `jit(vmap(simulate))` over their lanes concatenated (x0, t0, t1
    and args per lane); returns `{name: Solution of its lanes}`."""
    groups = {}
    for case in cases:
        _, scene, _, t0, t1, _, options = case
        groups.setdefault(_program_key(scene, t0, t1, options), []).append(case)
    sols = {}
    for (_, direction, _), group in groups.items():
        scene, options = group[0][1], group[0][6]
        lanes = []  # (in NumPy: no small programs compiled for the bookkeeping)
        for _, _, x0s, t0, t1, args, _ in group:
            n = len(x0s)
            per_lane = lambda v, n=n: np.broadcast_to(np.asarray(v, float),  # noqa: E731
                                                      (n, *np.shape(v)))
            lanes.append((np.asarray(x0s, float), per_lane(t0), per_lane(t1),
                          jax.tree.map(per_lane, args)))
        batch = jax.tree.map(lambda *leaves: np.concatenate(leaves), *lanes)
        # (`quick_jit`: these batches are small, and compiling them is most of their time.)
        run = quick_jit(jax.vmap(lambda x0, t0, t1, args, scene=scene, options=options,
                                 direction=direction:
                                 gj.simulate(scene, x0, t0, t1, args, direction=direction,
                                             **options)))
        sol = jax.tree.map(np.asarray, run(*batch))
        stop = 0
        for name, _, x0s, *_ in group:
            start, stop = stop, stop + len(x0s)
            sols[name] = jax.tree.map(lambda leaf, a=start, b=stop: leaf[a:b], sol)
    return sols


def run_campaign():
    """Run every case (`run_cases`); returns `(name, statuses, num_impacts)` per case, and
    the same for the runs that bring the backward cases to their start."""
    cases = campaign_cases()
    # First the runs to the backward cases' starts (with the forward cases whose program
    # they share), then the backward cases from their ends.
    to_start = {name: (name + " (the run to its start)", scene, x0s[1], 0.0, t0, args, x0s[2])
                for name, scene, x0s, t0, t1, args, options in cases if isinstance(x0s, tuple)}
    first = run_cases([case for case in cases if not isinstance(case[2], tuple)]
                      + list(to_start.values()))
    sols = {**first, **run_cases([
        (name, scene, first[to_start[name][0]].x_final, t0, t1, args, options)
        for name, scene, x0s, t0, t1, args, options in cases if isinstance(x0s, tuple)])}
    summary = lambda name: (name, [gj.Status(int(s)) for s in sols[name].status],  # noqa: E731
                            np.asarray(sols[name].num_impacts))
    starts = [summary(case[0]) for case in to_start.values()]
    # (Each run to a start reaches it: the backward case starts at its t0.)
    assert all(s == gj.Status.SUCCESS for _, status, _ in starts for s in status), starts
    return [summary(case[0]) for case in cases], starts


@pytest.mark.slow
def test_no_false_alarms_on_the_example_scenes(monkeypatch):
    # The probe itself on every scene: most example fields are continuous by construction
    # and their runs leave it out (test above), so it is forced in here.
    monkeypatch.setattr("grazejax._loop.program.continuous_in_state", lambda *a: False)
    results, starts = run_campaign()
    alarms = [(name, i) for name, status, _ in results + starts for i, s in enumerate(status)
              if s == gj.Status.FIELD_DISCONTINUITY]
    lanes = sum(len(status) for _, status, _ in results)
    events = sum(int(np.sum(n)) for _, _, n in results)
    print(f"\nfield-jump campaign: {len(results)} cases, {lanes} runs, {events} events, "
          f"{len(alarms)} alarms")
    for name, status, n in results + starts:
        print(f"  {name:28} {[s.name for s in status]}  events {n.tolist()}")
    assert lanes >= 100 and events >= 1000  # the campaign exercises the check
    assert alarms == []


# Random fields: a static verdict of "continuous" is never contradicted by the probe, and
# one discontinuous operation anywhere in the expression keeps the probe.

_UNARY = [jnp.sin, jnp.tanh, lambda u: jnp.exp(-(u**2)), jnp.abs,
          lambda u: jnp.maximum(u, 0.0), lambda u: u**2, lambda u: jnp.sqrt(1.0 + u**2)]
_BINARY = [jnp.add, jnp.multiply, jnp.maximum, jnp.minimum]
_JUMPS = [jnp.sign, jnp.floor, jnp.round, lambda u: jnp.where(u > 0.1, u, -u),
          lambda u: jnp.heaviside(u, 0.5)]


def _random_field(draw_ops, jump_at=None):
    """x'' built from `draw_ops`, a list of (kind, index) choices; the operation number
    `jump_at` (if any) is replaced by a discontinuous one."""

    def field(t, x, a):
        stack = [x[0], x[1], a * x[0], jnp.cos(t) + 0.0 * x[1]]
        for k, (kind, i) in enumerate(draw_ops):
            if k == jump_at:
                stack.append(_JUMPS[i % len(_JUMPS)](stack[-1]))
            elif kind == "unary":
                stack.append(_UNARY[i % len(_UNARY)](stack[-1]))
            else:
                stack.append(_BINARY[i % len(_BINARY)](stack[-1], stack[-(2 + i % 3)]))
        return jnp.stack([x[1], stack[-1]])

    return field


@settings(max_examples=40, deadline=None, derandomize=True)
@given(ops=st.lists(st.tuples(st.sampled_from(["unary", "binary"]), st.integers(0, 20)),
                    min_size=1, max_size=8),
       where=st.integers(0, 7), x=st.tuples(st.floats(-2, 2), st.floats(-2, 2)))
def test_random_fields_static_verdict_agrees_with_the_probe(ops, where, x):
    x = jnp.asarray(x, float)
    field = _random_field(ops)
    assert continuous_in_state(field, 0.3, x, 1.2)
    # The probe never calls a continuous field a jump (these are C⁰, with kinks at most).
    assert not bool(field_jumps(field, 0.3, x, 1.2, jnp.ones_like(x)))
    assert not continuous_in_state(_random_field(ops, jump_at=where % len(ops)), 0.3, x, 1.2)
