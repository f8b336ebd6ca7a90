"""Keep a test process under Linux's cap on memory mappings.

Every program XLA compiles for the CPU keeps its code in memory mappings of its own, and
Linux caps a process at vm.max_map_count (65530 by default) of them; past it XLA crashes
(SIGSEGV/SIGABRT while compiling, or while loading a program from the persistent cache).
"""

import gc

import jax

# Well below the default cap, with room for the largest single test or campaign part.
HIGH_WATER = 20_000


def memory_mappings() -> int:
    """How many memory mappings this process holds (0 where /proc is not there: no cap)."""
    try:
        with open("/proc/self/maps") as maps:
            return sum(1 for _ in maps)
    except OSError:
        return 0


def release_compiled_programs(high_water: int = HIGH_WATER) -> bool:
    """Drop JAX's compiled programs (`jax.clear_caches()`) once this process holds more than
    `high_water` memory mappings; returns whether it did. A dropped program is compiled
    again (or loaded from the persistent cache) when it next runs."""
    if memory_mappings() <= high_water:
        return False
    jax.clear_caches()
    gc.collect()
    return True
