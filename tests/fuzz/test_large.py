"""The slow job's fuzz campaign: every family with two solvers in rotation, 128 random
systems per pair, 2,560 in all (`docs/hard_cases.md` has the counts).

`GRAZEJAX_FUZZ_LANES=256` runs the whole campaign, 5,120 systems (as CI did until its time
ran out on a machine with a cold compilation cache: the campaign's reference, a Python
event loop, is most of its time); `python -m tests.fuzz.campaign --systems 5120 --seed 4096
--solvers-per-family 2` runs the same systems and prints their table.

One test per (family, solver) pair, each drawing the systems the whole campaign draws for
it: a failure names its pair. The slow job's workers start on this module, its longest
(`tests/conftest.py: longest_modules_first`), so that it runs beside the rest of the job
instead of after it.
"""

import os

import pytest

from . import compare as C
from .checks import assert_no_defects, report

PLAN = C.plan(solvers_per_family=2)
LANES = int(os.environ.get("GRAZEJAX_FUZZ_LANES", "128"))
SEED = 4096


def test_the_campaign_runs_2500_systems_over_every_family_and_solver():
    assert len(PLAN) * LANES >= 2500
    assert {f for f, _ in PLAN} == set(C.families())
    assert {s for _, s in PLAN} == set(C.SOLVERS)


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(PLAN)), ids=[f"{f}-{s}" for f, s in PLAN])
def test_fuzz_large(index):
    records = C.campaign(PLAN[index : index + 1], lanes=LANES, seed=SEED, first=index)
    assert len(records) == LANES
    report(records, f"fuzz (slow): {PLAN[index]}")
    assert_no_defects(records)
