"""Balls over corrugated floors, fixed and shaking: no impact is missed wherever the steps
fall (`campaign_corrugated.py` has the judge: the exact parabola from each of the run's own
landings). The counts of the slow campaign are in docs/hard_cases.md."""

import os

import jax.numpy as jnp
import numpy as np
import pytest

import grazejax as gj

from . import campaign_corrugated as C

# The example a step placed after a landing let through: from the 5th impact's landing
# (t = 3.7424383863830255) the exact parabola meets the floor at t = 3.856068021686851 and
# would pass 0.0535 below it; the run logged its next impact at 4.120083 instead.
EXAMPLE = dict(g=8.60633054686484, A=0.12300663022595551, k=6.606380458047694,
               theta=3.610559489969243, e=0.9362893220520314, a=0.0, omega=1.0, phase=0.0)
EXAMPLE_X0 = [-0.44645112292734, 1.1304856803142314, -1.0047284254382611, 0.2244924174168088]
EXAMPLE_T1 = 5.9778398684320635


def test_a_landing_step_over_several_corrugations_finds_the_first_contact():
    args = {key: jnp.asarray(value) for key, value in EXAMPLE.items()}
    sol = gj.simulate(C.SCENE, jnp.asarray(EXAMPLE_X0), 0.0, EXAMPLE_T1, args, rtol=1e-10,
                      atol=1e-10, max_impacts=C.MAX_IMPACTS)
    assert gj.Status(int(sol.status)) == gj.Status.SUCCESS
    times = np.asarray(sol.impact_times)
    # The first contact after the landing at 3.7424 is the exact one (the closed form's
    # root, to the solver's tolerance), not the later one at 4.1201.
    after = times[(times > 3.75) & (times < 4.2)]
    assert abs(after[0] - 3.856068021686851) < 1e-8
    p = {key: np.array([value]) for key, value in EXAMPLE.items()}
    out = [np.asarray(a)[None] for a in (sol.status, sol.num_impacts, sol.impact_times,
                                         sol.impact_post, sol.impact_pre, sol.t_final)]
    misses, false_alarms, _ = C.judge(np.asarray([EXAMPLE_X0]), p, *out)
    assert int(misses[0]) == 0 and int(false_alarms[0]) == 0


def _assert_clean(report):
    for name, row in report.items():
        assert row["misses"] == 0, (name, row)
        assert row["false_alarms"] == 0, (name, row)
        assert row["tunnelled"] == 0, (name, row)
        assert set(row["statuses"]) <= {"SUCCESS", "MAX_IMPACTS", "ZENO"}, (name, row)


# Lanes per call of the campaigns' program: the default and slow jobs share it (and the
# persistent compilation cache serves the slow job the default job's programs).
CHUNK = 512


def test_corrugated_floors_default_campaign():
    """512 systems per solver, 2-D and 3-D floors as lanes of one program per solver."""
    report = C.run_campaign(CHUNK, seed=11, dim=0, chunk=CHUNK)
    print(report)
    _assert_clean(report)


def test_single_runs_find_what_their_lanes_find():
    """Four systems of the default campaign (2-D and 3-D floors) run one at a time, eager, and
    as lanes of the campaign's program: no miss either way, and the same first impacts
    (later ones may part: the floors are chaotic, and lanes round differently)."""
    x0, p = C.draw_mixed(CHUNK, 11)
    rows = np.array([0, 1, CHUNK - 2, CHUNK - 1])
    x0, p = x0[rows], {key: value[rows] for key, value in p.items()}
    lanes = C.run_lanes("Tsit5", 1e-10, x0, p, chunk=CHUNK)
    for j in range(len(rows)):
        args = {key: jnp.asarray(value[j]) for key, value in p.items()}
        sol = gj.simulate(C.SCENE, jnp.asarray(x0[j]), 0.0, C.T1, args,
                          solver=C.SOLVERS["Tsit5"](), rtol=1e-10, atol=1e-10,
                          max_impacts=C.MAX_IMPACTS, max_steps=20_000)
        out = [np.asarray(a)[None] for a in (sol.status, sol.num_impacts, sol.impact_times,
                                             sol.impact_post, sol.impact_pre, sol.t_final)]
        misses, false_alarms, _ = C.judge(x0[j:j + 1], {k: v[j:j + 1] for k, v in p.items()},
                                          *out)
        assert int(misses[0]) == 0 and int(false_alarms[0]) == 0
        np.testing.assert_allclose(np.asarray(sol.impact_times[:3]), lanes[2][j, :3],
                                   rtol=0, atol=1e-9)


@pytest.mark.parametrize("system", [761, 798])
def test_steps_that_hid_a_dip_from_their_samples_find_it(system):
    """Two systems of seed 2026 where a step after a landing held several oscillations of
    the gap (system 798: a shaking floor, ω·h ≈ 31 in one exact step): the samples'
    differences showed a quarter of the gap's curvature, and a dip 0.048 (761) and 0.039
    (798) deep was "proved" clear. With the gap's second derivative read at the samples
    (`gaps.curvatures_at`) the bound holds and the contact is found. Single runs, the
    program of the example above."""
    x0, p = C.draw(1000, 2026)
    x0, p = x0[system:system + 1], {key: value[system:system + 1] for key, value in p.items()}
    args = {key: jnp.asarray(value[0]) for key, value in p.items()}
    sol = gj.simulate(C.SCENE, jnp.asarray(x0[0]), 0.0, C.T1, args, rtol=1e-10, atol=1e-10,
                      max_impacts=C.MAX_IMPACTS)
    assert gj.Status(int(sol.status)) in (gj.Status.SUCCESS, gj.Status.MAX_IMPACTS)
    out = [np.asarray(a)[None] for a in (sol.status, sol.num_impacts, sol.impact_times,
                                         sol.impact_post, sol.impact_pre, sol.t_final)]
    misses, false_alarms, _ = C.judge(x0, p, *out)
    assert int(misses[0]) == 0 and int(false_alarms[0]) == 0


@pytest.mark.slow
@pytest.mark.parametrize("solver", sorted(C.SOLVERS))
def test_corrugated_floors_slow_campaign(solver):
    """`GRAZEJAX_CORRUGATED_SYSTEMS` systems per solver (10,240 by default: 2-D and 3-D
    floors in equal numbers), in calls of the default campaign's program."""
    n = int(os.environ.get("GRAZEJAX_CORRUGATED_SYSTEMS", str(20 * CHUNK)))
    report = C.run_campaign(n, seed=2026, solvers=(solver,), dim=0, chunk=CHUNK)
    print(report)
    _assert_clean(report)
