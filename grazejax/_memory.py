"""Large results without page faults: keep freed memory in the process (glibc).

Every call of a compiled program returns fresh output buffers, and the caller frees the
last call's. glibc's `malloc` serves a block above its mmap threshold (adjusted as blocks
are freed, at most 32 MiB) with newly mapped pages and unmaps it when it is freed; smaller
blocks come from the heap, whose top goes back to the system once more than the trim
threshold is free. So a program that returns large buffers gets pages from the kernel at
every call, and the kernel zeroes each 4 KiB page on its first touch (a page fault). An
impact log of 4096 rows at 256 lanes is 56 MB of buffers, thousands of page faults a call
(`benchmarks/bench_unused.py` measures what they cost a sweep, and what keeping the freed
memory saves; the rest is the writing of the NaN-filled rows).

`retain_freed_memory()` asks glibc for that: blocks up to 32 MiB (its maximum threshold)
come from the heap, and freed heap memory stays in the process for the next call. The
price is that the process keeps its peak memory. It changes the whole process's allocator,
so grazejax never calls it on import: the `grazejax` command calls it (it owns its process),
scripts opt in. A buffer above 32 MiB (e.g. the states of a 4096-row log at 1024 lanes) is
still mapped afresh at each call. The same from the shell, without code:
`MALLOC_MMAP_THRESHOLD_=33554432 MALLOC_TRIM_THRESHOLD_=2147483647`.
"""

import ctypes
import functools
import platform

# mallopt's parameters (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_THRESHOLD_MAX = 32 * 1024 * 1024  # glibc's largest mmap threshold on 64-bit systems
_TRIM_NEVER = 2**31 - 1  # mallopt takes an int


@functools.cache
def retain_freed_memory() -> bool:
    """Keep memory freed by the process for its next allocations (glibc's `malloc` only).

    Programs that return large arrays (a long impact log over many lanes, dense output at
    many times) then reuse the memory of the last call's results instead of taking fresh
    pages from the kernel at every call (see this module's docstring for the numbers). The
    process keeps its peak memory. Call it once, before or after compiling.

    **Returns:** True if glibc took both settings, False where the C library is not glibc
    (macOS, Windows, musl): nothing is changed there.
    """
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    took_mmap = mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX)
    took_trim = mallopt(_M_TRIM_THRESHOLD, _TRIM_NEVER)
    return bool(took_mmap and took_trim)
