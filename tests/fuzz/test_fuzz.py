"""Differential fuzzing: random impact systems, grazejax against an independent reference.

The default-suite tests run a few hundred systems (six family × solver pairs covering the
four tested solvers, forward and backward time, fixed / moving / curved surfaces, `where`
pieces, impenetrable walls, several surfaces, vmap lanes) and a small derivative check; the
slow ones (`pytest -m slow tests/fuzz`: `test_large.py`, `test_large_derivatives.py`) run
2,560 systems over every family with two solvers each (5,120 with
`GRAZEJAX_FUZZ_LANES=256`), and derivatives over more families. Every disagreement is
classified (`compare.py`); no grazejax defect may remain. The counts are printed (`-s`).
"""

from . import compare as C
from .checks import assert_derivatives, assert_no_defects, report

# Six of the slow campaign's pairs (`test_large.py`), covering the four solvers: the slow
# job loads their compiled programs from the cache this job fills.
DEFAULT_PAIRS = [
    ("linear2", "Tsit5"),
    ("mech1_imp", "Dopri5"),
    ("linear3", "Vern9"),
    ("mech2", "Dopri8"),
    ("drift", "Vern9"),
    ("rotation_back", "Dopri5"),
]


def test_fuzz_default():
    assert set(DEFAULT_PAIRS) <= set(C.plan(solvers_per_family=2))
    records = C.campaign(DEFAULT_PAIRS, lanes=40, seed=2024)
    report(records, "fuzz (default suite)")
    assert_no_defects(records)


def test_fuzz_derivatives_default():
    rows = C.derivative_campaign([("rotation", "Tsit5")], lanes=16, seed=7)
    assert_derivatives(rows, minimum=4)
