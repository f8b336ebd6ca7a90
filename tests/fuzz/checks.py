"""The fuzz tests' verdicts on a campaign's records (shared by the default and slow tests)."""

from . import compare as C


def report(records, title):
    """Print the campaign's counts and its first defects (shown with `pytest -s`)."""
    print(f"\n\n{title}\n{C.table(records)}")
    for rec in C.defects(records)[:20]:
        print(f"  defect: {rec.family} {rec.solver} lane {rec.lane}: {'; '.join(rec.reasons)}")


def assert_no_defects(records):
    """No grazejax defect, and most systems agree (so that the comparison is not vacuous)."""
    found = C.defects(records)
    summary = "\n".join(
        f"{r.family}/{r.solver} lane {r.lane}: {'; '.join(r.reasons)}" for r in found[:10]
    )
    assert not found, f"{len(found)} grazejax defect(s):\n{summary}"
    assert sum(r.outcome == "agree" for r in records) >= 0.8 * len(records)


def assert_derivatives(rows, minimum):
    """At least `minimum` transversal systems compared, each within its tolerance in both
    modes (rows from `compare.derivative_campaign`)."""
    assert len(rows) >= minimum, len(rows)
    bad = [row for row in rows if not (row[3] <= row[5] and row[4] <= row[5])]
    worst = max(max(r[3], r[4]) / r[5] for r in rows)
    print(f"\nderivatives: {len(rows)} transversal systems, worst error / tolerance {worst:.3g}")
    assert not bad, bad[:10]
