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


def test_corrugated_floors_default_campaign():
    """A few hundred systems per solver, as vmapped lanes of one program per solver."""
    report = C.run_campaign(96, seed=11)
    print(report)
    _assert_clean(report)


# Known misses, kept failing on purpose until the search is fixed (strict: the test fails
# once it passes, so the mark goes with the defect): systems 761 and 798 of seed 2026 (the
# counts are in docs/hard_cases.md). System 798: a shaking floor
# whose gap oscillates five times in one exact step after a landing (ω·h ≈ 31, more than a
# period per part); the five samples' differences show a quarter of the true curvature, so
# even twice that (the safety factor) bounds too little, and a dip 0.039 deep in the first
# part is "proved" clear. Every solver misses it the same way (the flights are exact).
KNOWN_MISS = pytest.mark.xfail(
    strict=True,
    reason="seed 2026 systems 761, 798: the samples underestimate the gap's curvature by more than "
           "the safety factor where a part spans more than one corrugation (docs/hard_cases.md)",
)


def test_the_known_miss_is_still_missed_with_tsit5():
    """The known miss of the slow campaign, as one cheap run: its flight after the third
    landing dips 0.039 below the floor before the logged impact. When the search finds it,
    this test fails: drop it and `KNOWN_MISS` together."""
    x0, p = C.draw(1000, 2026)
    x0, p = x0[798:799], {key: value[798:799] for key, value in p.items()}
    args = {key: jnp.asarray(value[0]) for key, value in p.items()}
    sol = gj.simulate(C.SCENE, jnp.asarray(x0[0]), 0.0, C.T1, args, rtol=1e-10, atol=1e-10,
                      max_impacts=C.MAX_IMPACTS)
    out = [np.asarray(a)[None] for a in (sol.status, sol.num_impacts, sol.impact_times,
                                         sol.impact_post, sol.impact_pre, sol.t_final)]
    misses, _, depth = C.judge(x0, p, *out)
    assert int(misses[0]) == 1 and 0.03 < depth.max() < 0.05


@pytest.mark.slow
@pytest.mark.parametrize("solver", sorted(C.SOLVERS))
@KNOWN_MISS
def test_corrugated_floors_slow_campaign(solver):
    """`GRAZEJAX_CORRUGATED_SYSTEMS` systems per solver (1,000 by default)."""
    n = int(os.environ.get("GRAZEJAX_CORRUGATED_SYSTEMS", "1000"))
    report = C.run_campaign(n, seed=2026, solvers=(solver,))
    print(report)
    _assert_clean(report)
