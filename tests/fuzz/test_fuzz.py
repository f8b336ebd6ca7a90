"""Differential fuzzing: random impact systems, grazejax against an independent reference.

The default-suite tests run a few hundred systems (six family × solver pairs covering the
four tested solvers, forward and backward time, fixed / moving / curved surfaces, `where`
pieces, impenetrable walls, several surfaces, vmap lanes) and a small derivative check; the
slow ones (`pytest -m slow tests/fuzz`) run ≥ 5,000 systems over every family with two
solvers each, and derivatives over more families. Every disagreement is classified
(`compare.py`); no grazejax defect may remain. The counts are printed (`-s`).
"""

import numpy as np
import pytest

from . import compare as C

DEFAULT_PAIRS = [
    ("linear2", "Tsit5"),
    ("mech1_imp", "Dopri5"),
    ("linear3", "Dopri5"),
    ("mech2", "Dopri8"),
    ("drift", "Vern9"),
    ("rotation_back", "Vern9"),
]


def _report(records, title):
    print(f"\n\n{title}\n{C.table(records)}")
    for rec in C.defects(records)[:20]:
        print(f"  defect: {rec.family} {rec.solver} lane {rec.lane}: {'; '.join(rec.reasons)}")


def _assert_no_defects(records):
    found = C.defects(records)
    summary = "\n".join(
        f"{r.family}/{r.solver} lane {r.lane}: {'; '.join(r.reasons)}" for r in found[:10]
    )
    assert not found, f"{len(found)} grazejax defect(s):\n{summary}"
    assert sum(r.outcome == "agree" for r in records) >= 0.8 * len(records)


def test_fuzz_default():
    records = C.campaign(DEFAULT_PAIRS, lanes=40, seed=2024)
    _report(records, "fuzz (default suite)")
    _assert_no_defects(records)


def _assert_derivatives(rows, minimum):
    assert len(rows) >= minimum, len(rows)
    bad = [row for row in rows if not (row[3] <= row[5] and row[4] <= row[5])]
    worst = max(max(r[3], r[4]) / r[5] for r in rows)
    print(f"\nderivatives: {len(rows)} transversal systems, worst error / tolerance {worst:.3g}")
    assert not bad, bad[:10]


def test_fuzz_derivatives_default():
    rows = C.derivative_campaign([("rotation", "Tsit5")], lanes=16, seed=7)
    _assert_derivatives(rows, minimum=4)


@pytest.mark.slow
def test_fuzz_large():
    records = C.campaign(C.plan(solvers_per_family=2), lanes=256, seed=4096)
    assert len(records) >= 5000
    _report(records, "fuzz (slow)")
    _assert_no_defects(records)


@pytest.mark.slow
def test_fuzz_derivatives_large():
    pairs = [("linear2", "Dopri5"), ("mech1", "Tsit5"), ("mech2", "Vern9"), ("rotation", "Dopri8")]
    rows = C.derivative_campaign(pairs, lanes=32, seed=11)
    _assert_derivatives(rows, minimum=20)
    assert np.isfinite([r[3] for r in rows]).all()
