"""Smoke test of the benchmark suite (benchmarks/bench_suite.py, `grazejax bench`).

A tiny subset (`--smoke`: exnonaxial, Tsit5 vs SciPy RK45 vs heyoka, tolerances 1e-4 and
1e-8) runs through the command line and writes a strict-JSON result with every plotted
point; the ground truths of the suite are checked against each other (these tests are
skipped when heyoka, the `bench` extra, is not installed). The suite also runs with its
peers missing (an import blocker in the child process), and so do the other benchmarks'
smoke modes.
"""

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parent.parent
BENCHMARKS = ROOT / "benchmarks"

pytestmark = pytest.mark.skipif(
    not (BENCHMARKS / "bench_suite.py").is_file(),
    reason="the benchmarks live in the source checkout",
)
needs_heyoka = pytest.mark.skipif(
    importlib.util.find_spec("heyoka") is None,
    reason="heyoka is in the `bench` extra (pip install -e '.[bench]')",
)


def _benchmark_module(name):
    sys.path.insert(0, str(BENCHMARKS))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(BENCHMARKS))


def _strict(text):
    def reject(name):
        raise ValueError(f"non-standard JSON constant {name}")

    return json.loads(text, parse_constant=reject)


@needs_heyoka
def test_bench_smoke_writes_parseable_results(tmp_path):
    from grazejax import _cli

    assert _cli.main(["bench", "--smoke", "--out", str(tmp_path)]) == 0
    data = _strict((tmp_path / "suite.json").read_text())
    assert data["mode"] == "smoke"
    assert data["machine"]["cpu_count"] >= 1 and data["versions"]["jax"]
    wp = data["work_precision"]
    case = wp["cases"]["exnonaxial"]
    assert len(case["truth"]["impact_times"]) == 17
    rows = wp["rows"]
    assert {r["tool"] for r in rows} == {"grazejax", "scipy", "heyoka"}
    assert sorted({r["tol"] for r in rows}) == [1e-8, 1e-4]
    for r in rows:  # every plotted point has its coordinates in the JSON
        assert r["time_min_s"] > 0 and r["evals"] > 0 and r["evals_kind"]
    tight = [r for r in rows if r["tol"] == 1e-8]
    for r in tight:
        assert r["ok"], r
        # Near-grazing impacts amplify the state error into the impact times (~1/√depth).
        assert r["err_post"] < 1e-6 and r["err_t"] < 1e-3, r
    for key in ("err_t", "err_post", "err_final"):
        assert isinstance(case["dominance"][key]["dominates_scipy_everywhere"], bool)
    csv_lines = (tmp_path / "work_precision.csv").read_text().splitlines()
    assert len(csv_lines) == len(rows) + 1
    assert (tmp_path / "summary.md").read_text().startswith("# grazejax benchmark suite")
    assert (tmp_path / "wp_exnonaxial.png").stat().st_size > 10_000


@needs_heyoka
def test_closed_form_truths_agree_with_heyoka_long_double():
    """The mpmath closed forms of the suite against heyoka in 80-bit long double."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        import _cases
    finally:
        sys.path.remove(str(BENCHMARKS))
    if np.finfo(np.longdouble).eps >= np.finfo(np.float64).eps:
        pytest.skip("long double is double on this platform")
    cases = _cases.make_cases(include_ball=True)
    for name in ("exnonaxial", "oscillator", "stiff", "ball"):
        case = cases[name]
        truth = case.truth()
        ld = _cases.heyoka_reference(case.peer_system, case.x0, case.t1, case.peer_params)
        assert len(ld["impact_times"]) == len(truth["impact_times"]) > 0, name
        scale = max(1.0, case.t1)
        assert np.max(np.abs(ld["impact_times"] - truth["impact_times"])) <= 1e-14 * scale, name
        assert np.max(np.abs(ld["impact_post"] - truth["impact_post"])) <= 1e-14, name
        assert np.max(np.abs(ld["x_final"] - truth["x_final"])) <= 1e-13, name
    # A dip of depth 1e-8 below the floor: the float start's exact depth and one impact.
    x0, depth, truth = _cases.parabola_grazing_start(1e-8)
    assert math.isclose(depth, 1e-8, rel_tol=1e-6) and len(truth["impact_times"]) == 1
    x0, depth, truth = _cases.exnonaxial_grazing_start(-1e-6)
    assert depth < 0 and len(truth["impact_times"]) == 0


@needs_heyoka
def test_phases_benchmark_smoke(tmp_path):
    """benchmarks/bench_phases.py runs and writes consistent rows (errors at the tolerance)."""
    sys.path.insert(0, str(BENCHMARKS))
    try:
        import bench_phases
    finally:
        sys.path.remove(str(BENCHMARKS))
    rows = bench_phases.main(["--smoke", "--out", str(tmp_path)])
    saved = _strict((tmp_path / "phases.json").read_text())
    assert saved["rows"] == rows and len(rows) == 1
    row = rows[0]
    for key in ("in_phase_us", "random_us", "heyoka_us"):
        assert row[key] > 0
    # Dopri8 at 1e-10 after 10 near-grazing impacts: 7e-9 measured (the grazing
    # amplification, ~1/√depth); heyoka at the same tolerance 1e-10.
    assert row["in_phase_error"] < 1e-7 and row["random_error"] < 1e-7
    assert row["heyoka_error"] < 1e-8


@needs_heyoka
def test_throughput_benchmark_smoke(tmp_path):
    """benchmarks/bench_throughput.py: every tool's rows, errors against the long-double
    reference, the matched-accuracy summary; heyoka's batch runners agree with its scalar
    runner on the impact times."""
    bench_throughput = _benchmark_module("bench_throughput")
    peers = _benchmark_module("peers")
    rows, table = bench_throughput.main(["--smoke", "--all-cores", "--out", str(tmp_path)])
    saved = _strict((tmp_path / "throughput.json").read_text())
    assert len(saved["rows"]) == len(rows)
    tools = {(r["tool"], r["mode"]) for r in rows}
    for tool in ("grazejax", "heyoka batch", "heyoka scalar", "SciPy"):
        assert {(tool, "in_phase"), (tool, "random")} <= tools
    for r in rows:
        assert r["us"] > 0 and r["error"] < 1e-4, r  # every tool at tol ≤ 1e-6 on ex1dof
    # The cheapest row reaching 1e-5 exists for every tool.
    assert all(table[0][f"{t}|random"] for t in ("grazejax", "heyoka batch", "SciPy"))
    x0s = np.array([[0.0, 0.03], [0.5, -0.868], [1.9, -0.44], [1.0, 1.0015], [0.0, 0.045]])
    scalar = peers.HeyokaImpactRunner("ex1dof", tol=1e-12, mu=0.2)
    expected = np.full((len(x0s), 6), np.nan)  # NaN after a lane's last impact before t1
    for lane, x0 in enumerate(x0s):
        found = scalar.run(x0, 0.0, 40.0, 6)["impact_times"]
        expected[lane, : len(found)] = found
    assert np.isfinite(expected).sum() >= 24
    for callback in (False, True):
        batch = peers.HeyokaBatchRunner("ex1dof", tol=1e-12, callback=callback, mu=0.2)
        times, _ = batch.run(x0s, 0.0, 40.0, 6)
        np.testing.assert_allclose(times, expected, rtol=0, atol=1e-12)

# ---------------------------------------------------------------- missing peers -------


def test_bench_suite_runs_without_its_peers(tmp_path, monkeypatch, capfd):
    """heyoka and SciPy blocked in the child process (a sitecustomize import blocker): the
    suite says so in one line naming the extra, runs grazejax's rows and writes its files."""
    from grazejax import _cli

    blocker = tmp_path / "blocker"
    blocker.mkdir()
    (blocker / "sitecustomize.py").write_text(
        "import sys\nsys.modules['heyoka'] = None\nsys.modules['scipy.integrate'] = None\n"
    )
    monkeypatch.setenv("PYTHONPATH", str(blocker))
    real = _cli._installed
    monkeypatch.setattr(_cli, "_installed",
                        lambda name: name not in ("heyoka", "scipy") and real(name))
    out = tmp_path / "out"
    assert _cli.main(["bench", "--smoke", "--out", str(out)]) == 0
    printed = capfd.readouterr().out
    lines = [line for line in printed.splitlines() if "not installed" in line]
    assert len(lines) == 1 and "heyoka, SciPy" in lines[0]
    assert 'pip install -e ".[bench]"' in lines[0]
    data = _strict((out / "suite.json").read_text())
    assert data["have_heyoka"] is False and data["have_scipy"] is False
    rows = data["work_precision"]["rows"]
    assert {r["tool"] for r in rows} == {"grazejax"} and len(rows) == 2
    assert all(r["ok"] for r in rows if r["tol"] == 1e-8)
    dominance = data["work_precision"]["cases"]["exnonaxial"]["dominance"]
    assert all(d["dominates_scipy_everywhere"] is None for d in dominance.values())
    assert "SciPy is not installed: not compared." in (out / "summary.md").read_text()


def test_ex1dof_reference_without_heyoka(monkeypatch):
    """Without heyoka the ex1dof ground truth is SciPy DOP853 at rtol 1e-13 (said in its
    `truth_method`); without SciPy too, the case is left out."""
    C = _benchmark_module("_cases")
    monkeypatch.setattr(C, "HAVE_HEYOKA", False)
    fn, method = C.ex1dof_truth_source()
    assert fn is C.scipy_reference and "SciPy DOP853 at rtol 1e-13" in method
    case = C.make_cases()["ex1dof"]
    assert case.truth_method == method
    ref = fn(case.peer_system, case.x0, 20.0, case.peer_params)
    assert len(ref["impact_times"]) >= 3
    if importlib.util.find_spec("heyoka") is not None:  # against the long-double reference
        ld = C.heyoka_reference(case.peer_system, case.x0, 20.0, case.peer_params)
        assert len(ld["impact_times"]) == len(ref["impact_times"])
        assert np.max(np.abs(ld["impact_times"] - ref["impact_times"])) < 1e-11
        assert np.max(np.abs(ld["impact_post"] - ref["impact_post"])) < 1e-11
    monkeypatch.setattr(C, "HAVE_SCIPY", False)
    assert C.ex1dof_truth_source()[0] is None and "ex1dof" not in C.make_cases()
    assert "heyoka, SciPy" in C.missing_peers_line()


def test_bench_command_checks_what_each_script_needs(monkeypatch, capsys):
    """`grazejax bench` runs the suite without heyoka/SciPy; the older scripts and a missing
    mpmath end with the install command."""
    from grazejax import _cli

    calls = []
    monkeypatch.setattr(_cli.subprocess, "call", lambda cmd, cwd: calls.append(cmd) or 0)
    real = _cli._installed
    monkeypatch.setattr(_cli, "_installed", lambda name: name != "heyoka" and real(name))
    assert _cli.main(["bench", "--quick"]) == 0
    assert calls[-1][1].endswith("bench_suite.py") and "--quick" in calls[-1]
    assert _cli.main(["bench", "--script", "core"]) == 1
    err = capsys.readouterr().err
    assert "heyoka not installed" in err and 'pip install -e ".[bench]"' in err
    monkeypatch.setattr(_cli, "_installed", lambda name: name != "mpmath" and real(name))
    assert _cli.main(["bench"]) == 1
    assert "mpmath not installed" in capsys.readouterr().err
    assert len(calls) == 1


# ---------------------------------------------------------------- bench_gradients -----


def test_gradients_benchmark_smoke(tmp_path):
    """benchmarks/bench_gradients.py --smoke: every section once at a tiny size (10 impacts,
    3 harmonics). Its cost is the compilation of jax.grad/jacfwd through the loop."""
    bench_gradients = _benchmark_module("bench_gradients")
    assert bench_gradients.main(["--smoke", "--out", str(tmp_path)]) == 0
    data = json.loads((tmp_path / "gradients.json").read_text())
    assert data["mode"] == "smoke"
    modes = {r["mode"] for r in data["impacts"]}
    assert modes == {"primal", "jacfwd", "grad_rca_default"}
    for row in data["impacts"]:
        assert row["finite"] and row["impacts"] >= row["target_impacts"] == 10, row
    # Reverse mode equals forward mode (the benchmark times the right thing).
    assert data["agreement"] < 1e-10
    (direct,) = data["direct"]
    assert direct["grad_direct_min_s"] > 0 and direct["max_steps"] > direct["steps"]
    (many,) = data["many"]
    assert many["parameters"] == 6 and many["grad_vs_jacfwd_rel"] < 1e-10
    for name in ("gradients_impacts.csv", "gradients_direct.csv", "gradients_many.csv"):
        assert (tmp_path / name).read_text().count("\n") >= 2, name
    assert (tmp_path / "gradients.md").read_text().startswith("Gradient benchmark (smoke)")


# ---------------------------------------------------------------- bench_compile -------


def test_compile_benchmark_smoke(tmp_path):
    """benchmarks/bench_compile.py --smoke: simulate's compile time and Diffrax's base in
    fresh processes without a compilation cache; the table (with the ratio) and the JSON
    are written."""
    bench_compile = _benchmark_module("bench_compile")
    base, row = bench_compile.main(["--smoke", "--out", str(tmp_path)])
    assert base["case"] == "diffeqsolve" and row["case"] == "simulate"
    for r in (base, row):
        assert r["first_s"] > r["second_s"] > 0
        assert r["compile_s"] == pytest.approx(r["first_s"] - r["second_s"])
    runs = json.loads((tmp_path / "compile.json").read_text())["runs"]
    assert [r["case"] for r in runs] == ["diffeqsolve", "simulate"]
    ratio = f"{row['compile_s'] / base['compile_s']:.2f}×"
    assert f"| {ratio} |" in (tmp_path / "compile.md").read_text()


# ---------------------------------------------------------------- bench_revisions -----


def test_revisions_benchmark_smoke(tmp_path):
    """benchmarks/bench_revisions.py --smoke: the working tree's cases timed in a child
    process that imports this checkout's package; the JSON and the table are written."""
    bench_revisions = _benchmark_module("bench_revisions")
    results = bench_revisions.main(["--smoke", "--out", str(tmp_path)])
    (run,) = results["."]
    assert set(run) == {"one run, Dopri8 2e-12", "one run, Tsit5 1e-10", "sweep 8 in phase",
                        "sweep 8 random phases"}
    assert all(math.isfinite(us) and us > 0 for us in run.values())
    saved = json.loads((tmp_path / "revisions.json").read_text())
    assert saved["revisions"] == ["."] and saved["rounds"]["."] == [run]
    table = (tmp_path / "revisions.md").read_text()
    assert table.splitlines()[0] == "| case | `.` |"
    assert f"| sweep 8 in phase | {run['sweep 8 in phase']:.1f} |" in table


# ---------------------------------------------------------------- bench_taylor --------


@needs_heyoka
def test_taylor_benchmark_smoke(tmp_path):
    """benchmarks/bench_taylor.py --smoke: the `jet` Taylor method chooses its order and
    steps as heyoka does, so it takes heyoka's steps and ends at heyoka's error; the table
    and the JSON are written."""
    bench_taylor = _benchmark_module("bench_taylor")
    rows = {r["method"]: r for r in bench_taylor.main(["--smoke", "--out", str(tmp_path)])}
    assert set(rows) == {"heyoka", "jet", "Dopri8"}
    heyoka, taylor = rows["heyoka"], rows["jet"]
    assert taylor["order"] == heyoka["order"] == 11
    assert abs(taylor["steps"] - heyoka["steps"]) <= 1
    assert taylor["error"] == pytest.approx(heyoka["error"], rel=0.1)
    assert heyoka["error"] < 1e-8
    saved = _strict((tmp_path / "taylor.json").read_text())["rows"]
    assert [r["method"] for r in saved] == ["heyoka", "jet", "Dopri8"]
    assert f"| 1e-08 | jet | 11 | {taylor['steps']} |" in (tmp_path / "taylor.md").read_text()
