import gc
import os

import jax
import pytest

jax.config.update("jax_enable_x64", True)
# `grazejax reproduce` (called in-process by test_reproduce) turns on JAX's persistent
# compilation cache under the user's cache folder; tests run cold and write nothing there.
os.environ.setdefault("GRAZEJAX_COMPILATION_CACHE", "off")

# Every program XLA compiles for the CPU keeps its code in memory mappings of its own, and
# Linux caps a process at vm.max_map_count (65530 by default) of them. The whole suite
# compiles a few hundred simulators in one process: by test ~200 it passed 60000 mappings
# and XLA crashed (SIGSEGV/SIGABRT in the compiler). Dropping the compiled programs between
# test modules once the count is high keeps the suite under the cap.
_MAPS_HIGH_WATER = 20_000


def _memory_mappings() -> int:
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:  # not Linux: no such cap to watch
        return 0


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
    yield
    if _memory_mappings() > _MAPS_HIGH_WATER:
        jax.clear_caches()
        gc.collect()


def pytest_collection_modifyitems(config, items):
    # `-m slow` selects the slow job; the default run (no -m) skips slow tests.
    if config.getoption("-m"):
        return
    skip = pytest.mark.skip(reason="slow: run with `pytest -m slow`")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
