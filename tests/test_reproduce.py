"""Smoke tests of `grazejax reproduce` (the CLI, in-process) and of `grazejax.plot`."""

import json
import sys

import numpy as np
import pytest

import grazejax as gj
from grazejax import _cli, examples, plot


def test_reproduce_two_cheap_figures(tmp_path, capsys):
    out = tmp_path / "out"
    code = _cli.main(
        ["reproduce", "--out", str(out), "--only", "exnonaxial-circle", "orbex2-stability"]
    )
    assert code == 0
    for name in ("exnonaxial-circle.png", "orbex2-stability.png", "report.md", "report.json"):
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    report = json.loads((out / "report.json").read_text())
    assert set(report["figures"]) == {"exnonaxial-circle", "orbex2-stability"}
    fig = report["figures"]["exnonaxial-circle"]
    assert "error" not in fig
    outer, inner = fig["runs"]
    assert outer["start"] == [0.0, 1.32] and outer["num_impacts"] > 0
    assert inner["num_impacts"] == 0  # the inner circle (radius 0.96) never reaches Γ
    # The first impact agrees with the closed form (rotation flow).
    first = fig["checks"]["first_impact_vs_closed_form"]
    assert abs(first["t_error"]) < 1e-7 and first["state_error"] < 1e-7
    # Progress lines: one per figure.
    printed = capsys.readouterr().out
    assert "[1/2] orbex2-stability" in printed and "[2/2] exnonaxial-circle" in printed
    assert "exnonaxial-circle.png" in (out / "report.md").read_text()


def test_unknown_name_lists_valid_names(tmp_path, capsys):
    code = _cli.main(["reproduce", "--out", str(tmp_path), "--only", "orbex3"])
    assert code == 2
    err = capsys.readouterr().err
    assert "unknown figure or example name(s): 'orbex3'" in err
    assert "orbex2-region" in err and "ex1dof-bifurcation" in err and "smalldisc" in err
    assert "Traceback" not in err
    assert not any(tmp_path.iterdir())  # nothing written


def test_unwritable_output_folder(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    code = _cli.main(["reproduce", "--out", str(blocker / "sub"), "--only", "orbex2-region"])
    assert code == 2
    err = capsys.readouterr().err
    assert "cannot write to output folder" in err and str(blocker / "sub") in err
    assert "Traceback" not in err


def test_help_and_list(capsys):
    assert _cli.main(["reproduce", "--help"]) == 0
    assert "./grazejax-output/ in the current directory" in capsys.readouterr().out
    assert _cli.main(["reproduce", "--list"]) == 0
    assert "ex1dof-negative-mu" in capsys.readouterr().out
    assert _cli.main(["no-such-command"]) == 2


def test_bench_without_checkout(monkeypatch, capsys):
    monkeypatch.setattr(_cli, "_find_bench_script", lambda: None)
    assert _cli.main(["bench"]) == 1
    assert "source checkout" in capsys.readouterr().err


def test_flight_segments_break_at_impacts():
    scene, args = examples.exnonaxial(), examples.exnonaxial_args()
    ts = np.linspace(0.0, 12.0, 301)
    sol = gj.simulate(scene, np.array([0.0, 1.32]), 0.0, 12.0, args, saveat=ts)
    log = plot.impacts_of(sol)
    segments = plot.flight_segments(sol)
    assert len(segments) == len(log["times"]) + 1
    for k in range(len(log["times"])):
        np.testing.assert_array_equal(segments[k][-1], log["pre"][k])
        np.testing.assert_array_equal(segments[k + 1][0], log["post"][k])
    # Surface sampling: Γ is the line x1 + x2 = √2; its image J(Γ) lies on the diagonal.
    lines = plot.surface_samples(scene, args, 0, (-1.5, 1.5), (-1.5, 1.5))
    pts = np.concatenate(lines)
    assert np.max(np.abs(pts.sum(axis=1) - np.sqrt(2))) < 1e-12
    images = np.concatenate(plot.image_samples(scene, args, 0, lines))
    np.testing.assert_allclose(images[:, 0], images[:, 1])


def test_missing_scipy_names_the_extra(monkeypatch):
    from grazejax.paper.optional import scipy_module

    monkeypatch.setitem(sys.modules, "scipy.integrate", None)  # as if SciPy were missing
    with pytest.raises(ImportError, match=r"pip install 'grazejax\[paper\]'"):
        scipy_module("integrate")


@pytest.mark.parametrize("name", ["orbex2", "ex1dof"])
def test_example_names_select_their_figures(name):
    from grazejax.paper.figures import FIGURES
    from grazejax.paper.reproduce import resolve_names

    chosen = resolve_names([name])
    assert chosen and all(FIGURES[f].scene == name for f in chosen)


# --------------------------------------------------------------------------------------
# The claims table
# --------------------------------------------------------------------------------------

ROW_KEYS = {"id", "example", "claim", "paper", "grazejax", "check", "check_method", "difference",
            "tolerance", "consistent", "verdict", "reason", "reason_consistent", "facts"}


def _check_fact(fact):
    """A fact's verdict recomputed from its numbers (the rule of docs/audit.md)."""
    if fact["tolerance"] is None:  # structural: equality
        assert fact["difference"] is None
        assert fact["agrees"] == (fact["paper"] == fact["grazejax"]), fact
    else:  # numbers: max-abs over the entries vs the tolerance
        paper, computed = np.asarray(fact["paper"], float), np.asarray(fact["grazejax"], float)
        assert paper.shape == computed.shape, fact
        difference = float(np.max(np.abs(paper - computed))) if paper.size else 0.0
        assert difference == pytest.approx(fact["difference"], rel=1e-12, abs=0.0), fact
        assert fact["agrees"] == (difference <= fact["tolerance"]), fact


def _check_rows(rows):
    for row in rows:
        assert ROW_KEYS <= set(row), row.get("id")
        assert row["verdict"] in ("agrees", "differs"), (row["id"], row["reason"])
        assert row["paper"] and row["grazejax"] and row["check"] and row["check_method"], row["id"]
        # The verdict follows from the facts; a typed-in reason goes with "differs" only.
        assert row["facts"], row["id"]
        for fact in row["facts"]:
            _check_fact(fact)
        expected = "agrees" if all(f["agrees"] for f in row["facts"]) else "differs"
        assert row["verdict"] == expected, row["id"]
        assert row["reason_consistent"] is True, (row["id"], row["verdict"],
                                                  row.get("unused_reason"))
        assert bool(row["reason"]) == (row["verdict"] == "differs"), row["id"]
        # grazejax's value and the independent check agree within the row's tolerance
        # (a multiple of the solver tolerance, scaled by the conditioning where it applies).
        assert row["consistent"] is True, (row["id"], row["difference"], row["tolerance"])
        assert row["difference"] <= row["tolerance"]


def test_fact_rule():
    """Numbers: max |printed − computed| over the entries ≤ tolerance; structural: ==."""
    from grazejax.paper.table import claim_verdict, fact, half_unit, printed_tol

    assert half_unit("0.939") == pytest.approx(5e-4)
    assert half_unit("-0.15") == pytest.approx(5e-3)
    assert half_unit("2") == 0.5 and half_unit("1.5e-3") == pytest.approx(5e-5)
    assert printed_tol([[0.939, -0.0001407], [-0.0003165, 1.0]]) == pytest.approx(5e-4)
    assert printed_tol([0.0, 1.0], exact=1e-7) == 1e-7  # whole numbers are exact
    # A printed 0.939 agrees with every value that rounds to it, and only those.
    tol = printed_tol(0.939)
    assert fact("ρ", 0.939, 0.9394, tol)["agrees"]
    assert not fact("ρ", 0.939, 0.9396, tol)["agrees"]
    assert not fact("ρ", 0.939, 0.99937, tol)["agrees"]
    # Matrices: the worst entry decides.
    printed = np.array([[1.0, 0.0], [0.5, 2.0]])
    assert fact("M", printed, printed + 1e-9, 1e-8)["agrees"]
    bad = printed.copy()
    bad[1, 0] += 2e-8
    worst = fact("M", printed, bad, 1e-8)
    assert not worst["agrees"] and worst["difference"] == pytest.approx(2e-8)
    assert not fact("M", printed, printed[0], 1.0)["agrees"]  # shape mismatch
    assert not fact("x", 0.0, float("nan"), 1.0)["agrees"]  # NaN never agrees
    # Structural facts: equality, no tolerance.
    assert fact("kind", ("GAMMA", True), ("GAMMA", True))["agrees"]
    assert not fact("kind", ("GAMMA", True), ("ALPHA", True))["agrees"]
    assert fact("count", 2, np.int64(2))["agrees"] and not fact("count", 2, 3)["agrees"]
    facts = [fact("count", 2, 2), fact("ρ", 0.939, 0.9391, tol)]
    assert claim_verdict(facts) == "agrees"
    assert claim_verdict(facts + [fact("holds", True, False)]) == "differs"
    with pytest.raises(ValueError, match="at least one fact"):
        claim_verdict([])


def test_reason_must_fit_the_computed_verdict():
    """A reason typed in for a row whose numbers agree (or none for one that differs) is
    flagged, and the reason is shown only for "differs"."""
    from grazejax.paper.table import claim_row, fact

    def row(computed, reason):
        return claim_row("x.y", "x", "claim", paper="1", grazejax=str(computed), check="1",
                      check_method="closed form", difference=0.0, tolerance=1.0,
                      facts=[fact("value", 1.0, computed, 1e-6)], reason=reason)

    good = row(1.0, "")
    assert good["verdict"] == "agrees" and good["reason_consistent"]
    stale = row(1.0, "typo")
    assert stale["verdict"] == "agrees" and not stale["reason_consistent"]
    assert stale["reason"] == "" and stale["unused_reason"] == "typo"
    differs = row(1.1, "typo")
    assert differs["verdict"] == "differs" and differs["reason_consistent"]
    assert differs["reason"] == "typo"
    assert not row(1.1, "")["reason_consistent"]


def test_claims_cheap_groups_and_error_rows(monkeypatch):
    """The cheap groups in-process, a failing group reported as error rows instead of a
    crash, and verdicts that flip when a printed value is changed."""
    from grazejax import paper
    from grazejax.paper.report import claims_markdown
    from grazejax.paper.table import PRINTED, ClaimGroup

    def broken(ctx):
        raise ValueError("boom")

    group = paper.CLAIM_GROUPS["smalldisc"]
    monkeypatch.setitem(paper.CLAIM_GROUPS, "smalldisc",
                        ClaimGroup(group.name, group.example, group.claims, broken))
    lines = []
    claims = paper.compute_claims(["orbex2-psi", "smalldisc", "conditions"],
                                  progress=lines.append)
    rows = {r["id"]: r for r in claims["rows"]}
    assert rows["smalldisc.cycle"]["verdict"] == "error"
    assert "ValueError: boom" in rows["smalldisc.cycle"]["error"]
    good = [r for r in claims["rows"] if r["verdict"] != "error"]
    assert len(good) == 7
    _check_rows(good)
    # What the table says about orbex2: the numbers behind the verdicts, against
    # independent values (closed forms in the row's check, the residual ≈ a/2).
    psi = rows["orbex2.psi-solution"]["facts"][0]
    assert psi["grazejax"] == pytest.approx(5.0e-4, rel=0.01) and not psi["agrees"]
    grazes = rows["orbex2.psi-grazes"]
    assert grazes["verdict"] == "differs" and "ALPHA impact" in grazes["grazejax"]
    assert grazes["facts"][0]["grazejax"] == "ALPHA"
    back = rows["orbex2.psi-periodic"]["facts"][0]
    closing = 0.9 * np.exp(0.0005 * np.pi)  # R2·|y2(θ2)| to first order, ≈ 0.9014
    assert back["grazejax"] == pytest.approx(closing, abs=5e-4) and not back["agrees"]
    assert rows["orbex2.ystar-type"]["verdict"] == "agrees"
    assert rows["conditions.orbex2"]["verdict"] == "agrees"
    assert claims["summary"]["errors"] == 1 and claims["summary"]["reasons_inconsistent"] == []
    assert any("[claims 2/3] smalldisc" in line for line in lines)
    assert any("FAILED: ValueError: boom" in line for line in lines)
    assert not any("differ" in line for line in lines)  # said once, by the final tally
    md = "\n".join(claims_markdown(claims))
    assert "| smalldisc.cycle |" in md and "**error**" in md
    assert "y2 after the Γ2 jump: \\|printed − computed\\|" in md
    # Verdicts are derived: print the computed value and the row agrees (its typed-in
    # reason is then stale and flagged); print another type and the row differs (no
    # reason: flagged too).
    monkeypatch.setitem(PRINTED, "orbex2_psi_return", back["grazejax"])
    monkeypatch.setitem(PRINTED, "orbex2_ystar", ("ALPHA", True))
    lines = []
    again = paper.compute_claims(["orbex2-psi"], progress=lines.append)
    flipped = {r["id"]: r for r in again["rows"]}
    assert flipped["orbex2.psi-periodic"]["verdict"] == "agrees"
    assert flipped["orbex2.ystar-type"]["verdict"] == "differs"
    assert again["summary"]["reasons_inconsistent"] == ["orbex2.ystar-type",
                                                         "orbex2.psi-periodic"]
    assert any("reason does not fit" in line for line in lines)
    assert "the typed-in reason does not fit" in "\n".join(claims_markdown(again))


def _summary(**changes):
    summary = dict(rows=37, agrees=16, differs=21, errors=0, checks_consistent=37,
                   checks_inconsistent=0, reasons_inconsistent=[])
    return {**summary, **changes}


def test_claims_tally():
    """One line for the whole table: the differences from the printed values are expected."""
    from grazejax.paper.report import claims_tally

    assert claims_tally(_summary()) == (
        "claims: 37 checked; an independent check agrees with grazejax's value in 37; 21 differ "
        "from the value printed in the paper (expected: many of the paper's printed numbers are "
        "wrong or approximate; report.md gives the reason for each).")
    assert "expected" not in claims_tally(_summary(agrees=37, differs=0))
    worse = claims_tally(_summary(errors=2, checks_consistent=33, checks_inconsistent=1,
                                  reasons_inconsistent=["ex1dof.A5"]))
    assert worse.startswith("claims: 35 checked; an independent check agrees with grazejax's "
                            "value in 33, NOT in 1 (1 without one); 21 differ")
    assert worse.endswith("; 2 could not be computed; the typed-in reason does not fit the "
                          "computed verdict in ex1dof.A5.")


def _made_up_claims(monkeypatch):
    """A made-up claims table instead of the 2-3 minutes of the real one."""
    from grazejax.paper import reproduce as rp

    claims = {"rows": [], "seconds": 0.1, "group_seconds": {}, "tolerance": {"rtol": 1e-10,
              "atol": 1e-12}, "summary": _summary()}
    monkeypatch.setattr(rp, "compute_claims", lambda context, progress: claims)
    return claims


def test_reproduce_ends_with_the_claims_tally(tmp_path, capsys, monkeypatch):
    from grazejax.paper.report import claims_tally

    claims = _made_up_claims(monkeypatch)
    assert _cli.main(["reproduce", "--out", str(tmp_path), "--only", "claims"]) == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[-1] == claims_tally(claims["summary"])
    assert not any("differ" in line for line in printed[:-1])


def test_reproduce_turns_on_the_compilation_cache(tmp_path, monkeypatch):
    """Through `enable_compilation_cache`: $GRAZEJAX_COMPILATION_CACHE moves it or turns
    it off."""
    import jax
    from jax.experimental.compilation_cache import compilation_cache

    _made_up_claims(monkeypatch)
    monkeypatch.setenv("GRAZEJAX_COMPILATION_CACHE", "off")
    saved = jax.config.jax_compilation_cache_dir
    try:
        assert _cli.main(["reproduce", "--out", str(tmp_path / "a"), "--only", "claims"]) == 0
        assert jax.config.jax_compilation_cache_dir == saved  # "off": nothing changed
        jax.config.update("jax_compilation_cache_dir", None)
        monkeypatch.setenv("GRAZEJAX_COMPILATION_CACHE", str(tmp_path / "xla"))
        assert _cli.main(["reproduce", "--out", str(tmp_path / "b"), "--only", "claims"]) == 0
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xla")
    finally:
        jax.config.update("jax_compilation_cache_dir", saved)
        compilation_cache.reset_cache()  # JAX reopens the test run's folder at its next compile


@pytest.mark.slow  # the whole table: about 2-3 minutes on two cores
def test_reproduce_claims_table(tmp_path, capsys):
    out = tmp_path / "out"
    assert _cli.main(["reproduce", "--out", str(out), "--only", "claims"]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["figures"] == {}
    claims = report["claims"]
    rows = {r["id"]: r for r in claims["rows"]}
    assert len(rows) == len(claims["rows"]) >= 35
    assert claims["summary"]["errors"] == 0
    _check_rows(claims["rows"])
    # Every group of the table is there.
    for group in ("orbex2.Wx", "exnonaxial.Wx", "ex1dof.Wx", "ex1dof.A5", "ex1dof.A6-continuous",
                  "ex1dof.cycles-negative-mu", "orbex2.corrected-wall", "exnonaxial.multipliers"):
        assert group in rows
    for example in ("orbex2", "exnonaxial", "ex1dof"):
        assert rows[f"{example}.A2"]["verdict"] == "differs"  # square-root singularity
        assert abs(rows[f"{example}.Wx"]["norm_exponent"] + 0.5) < 0.01
    assert rows["ex1dof.cycle-positive-mu"]["verdict"] == "agrees"
    assert claims["summary"]["reasons_inconsistent"] == []
    printed = capsys.readouterr().out
    assert "[claims 1/" in printed and "claims:" in printed
    from grazejax.paper.report import claims_tally

    assert printed.rstrip().splitlines()[-1] == claims_tally(claims["summary"])
    md = (out / "report.md").read_text()
    assert "## Claims of the paper, checked" in md and "| ex1dof.A5 |" in md
