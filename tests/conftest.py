import collections
import json
import os
import tempfile
from pathlib import Path

import jax
import pytest
from hypothesis import settings

from tests.mappings import release_compiled_programs

jax.config.update("jax_enable_x64", True)

# Compiling is most of the suite's time, and most of a compile is XLA:CPU's fusion emitters
# (MLIR). The suite compiles with XLA's older LLVM emitters, as grazejax's own one-run
# programs do (`grazejax/_compiler.py`): a cold simulate compiled in 2.7 s instead of 7.7,
# its jacfwd in 4.0 s instead of 11.3, with the same bits. The two emitters are compared
# on one program in tests/test_compiler.py, which asks for each explicitly (an option given
# to `jax.jit` wins over XLA_FLAGS). The flag is set before the backend starts, so it holds
# in this process and in the child processes the tests start (notebook kernels, snippets,
# `grazejax bench`); a user's own XLA_FLAGS setting of it wins, and
# GRAZEJAX_TEST_XLA_DEFAULTS=1 runs the whole suite with XLA's defaults.
_QUICK_EMITTERS = "--xla_cpu_use_fusion_emitters=false"
if (os.environ.get("GRAZEJAX_TEST_XLA_DEFAULTS") != "1"
        and "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", "")):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_QUICK_EMITTERS}".strip()

# Property tests run the same examples on every run (derandomize: the seed is a hash of the
# test), so that a default-job failure is reproducible and never a matter of luck. This
# profile is the parent of every `@settings(...)` in the tests, which only set their example
# counts and deadlines. `HYPOTHESIS_PROFILE=random` explores new examples (locally, or in
# a scheduled job), with the same counts.
settings.register_profile("derandomized", derandomize=True)
settings.register_profile("random", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "derandomized"))

# Compiling is most of the suite's time, and many tests compile the same program again: a
# scene built afresh (`examples.ex1dof()` makes new closures, so `jit` misses) or a module
# run after `jax.clear_caches()` (below) gives the same XLA program. JAX's persistent cache
# (keyed on the program, not on source locations) loads those instead of recompiling them:
# a repeated ex1dof simulator took 5-6 s to compile, 1.7 s from the cache. The folder is the
# test run's own, in the temp folder, shared by both CI jobs and by the child processes the
# tests start (notebook kernels, `grazejax bench`, multi-process sweeps): they read it from
# the environment, this process from the config. Set JAX_COMPILATION_CACHE_DIR to move it.
# JAX writes no program with a host callback there (the callbacks are baked into it): a
# sweep's progress bar, `eqx.error_if` (`throw=True`; lineax's check of the linear solve
# in an implicit derivative), a `jax.pure_callback`. Such a program compiles again in every
# process and after every `jax.clear_caches()`: keep them out of grazejax's own programs.
_TEST_CACHE = Path(tempfile.gettempdir()) / f"grazejax-tests-xla-cache-{os.getuid()}"
os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", str(_TEST_CACHE))
os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.5")
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])
jax.config.update("jax_persistent_cache_min_compile_time_secs",
                  float(os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"]))
# `grazejax reproduce` (called in-process by test_reproduce) turns on JAX's persistent
# compilation cache under the user's cache folder; tests write nothing there (they use the
# folder above).
os.environ.setdefault("GRAZEJAX_COMPILATION_CACHE", "off")

# A worker compiles a few hundred programs, each holding memory mappings of its own, and
# crashes past Linux's cap on them (tests/mappings.py). The compiled programs are dropped
# after any test that leaves the count high; the fuzz campaigns, which compile tens of
# thousands of mappings in one test, also drop them between their parts.


@pytest.fixture(autouse=True)
def _release_compiled_programs():
    yield
    release_compiled_programs()


# Each job reports how many programs XLA compiled and how long that took, how long JAX
# spent tracing programs (Python: the persistent cache cannot save it) (this process and
# its xdist workers; not the child processes the tests start), and how many programs the
# persistent cache served instead: compiling and tracing are most of the suite's time.
_compiles = {"programs": 0, "seconds": 0.0, "tracing": 0.0, "cache hits": 0}


def _on_duration(event, duration, **_):
    if event == "/jax/core/compile/backend_compile_duration":
        _compiles["programs"] += 1
        _compiles["seconds"] += duration
    elif event == "/jax/core/compile/jaxpr_trace_duration":
        _compiles["tracing"] += duration


def _on_event(event, **_):
    if event == "/jax/compilation_cache/cache_hits":
        _compiles["cache hits"] += 1


jax.monitoring.register_event_duration_secs_listener(_on_duration)
jax.monitoring.register_event_listener(_on_event)


def pytest_testnodedown(node, error):
    """(xdist controller) Add a worker's compile counts to this process's."""
    for key, value in json.loads(node.workeroutput.get("compiles", "{}")).items():
        _compiles[key] += value


def pytest_terminal_summary(terminalreporter):
    if hasattr(terminalreporter.config, "workerinput"):
        return
    terminalreporter.write_line(
        f"[{_job(terminalreporter.config)} job] XLA compiled {_compiles['programs']} programs "
        f"in {_compiles['seconds']:.0f} s; JAX traced for {_compiles['tracing']:.0f} s; "
        f"the persistent cache served {_compiles['cache hits']}")


def pytest_collection_modifyitems(config, items):
    job = _job(config)
    if job == "default":
        skip = pytest.mark.skip(reason="slow: run with `pytest -m slow`")
        for item in items:
            if "slow" in item.keywords:
                item.add_marker(skip)
    longest_modules_first(items, job)


# Each job's two workers take whole modules (`--dist loadfile`) in the order collected
# (`--no-loadscope-reorder`: xdist would otherwise order them by their number of tests).
# A long module handed out last runs alone while the other worker idles, so modules are
# ordered by their measured time in the job, longest first (the greedy schedule that
# keeps the two workers' ends close). The times live in `module_seconds.json`; update them
# after a change that moves them with `pytest -n 2 --record-module-seconds` and
# `pytest -n 2 -m slow --record-module-seconds` (each job writes its own entry). A module
# the file does not know runs after the known ones, in collection order.
_MODULE_SECONDS = Path(__file__).with_name("module_seconds.json")


def _job(config):
    """`-m slow` selects the slow job; the default run (no -m) skips slow tests."""
    return "slow" if config.getoption("-m") else "default"


def _module(nodeid):
    return nodeid.split("::", 1)[0]


def _module_seconds():
    return json.loads(_MODULE_SECONDS.read_text()) if _MODULE_SECONDS.exists() else {}


def longest_modules_first(items, job):
    seconds = _module_seconds().get(job, {})
    items.sort(key=lambda item: -seconds.get(_module(item.nodeid), 0.0))  # (a stable sort)


def pytest_addoption(parser):
    parser.addoption("--record-module-seconds", action="store_true",
                     help="write this job's time per test module to tests/module_seconds.json")


_recorded = collections.defaultdict(float)


def pytest_runtest_logreport(report):
    _recorded[_module(report.nodeid)] += report.duration


def pytest_sessionfinish(session):
    config = session.config
    if hasattr(config, "workerinput"):  # (xdist worker: hand the compile counts over)
        config.workeroutput["compiles"] = json.dumps(_compiles)
    if not config.getoption("--record-module-seconds") or hasattr(config, "workerinput"):
        return  # (under xdist the controller records: it receives every worker's reports)
    job = _job(config)
    table = _module_seconds()
    # (merged: a run of some modules updates theirs and keeps the others')
    seconds = {**table.get(job, {}), **{m: round(s, 1) for m, s in _recorded.items()}}
    table[job] = dict(sorted(seconds.items(), key=lambda kv: -kv[1]))
    _MODULE_SECONDS.write_text(json.dumps(table, indent=1) + "\n")
