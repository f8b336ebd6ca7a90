"""`retain_freed_memory`: a program's large results reuse freed memory instead of fresh pages.

Run in a child process: the setting is process-wide, and the page-fault counts of a pytest
worker that has run other tests would not be this test's alone.
"""

import platform
import subprocess
import sys
import textwrap

import pytest

import grazejax as gj

CHILD = textwrap.dedent(
    """
    import resource, sys
    import jax, jax.numpy as jnp
    import grazejax as gj

    PAGES = 3 * 1024 * 1024 * 8 // 4096  # a 24 MiB result: below glibc's 32 MiB ceiling
    make = jax.jit(lambda v: jnp.full((3 * 1024 * 1024,), v))

    def faults_per_call(calls=9):
        for _ in range(2):
            jax.block_until_ready(make(1.0))
        counts = []
        for k in range(calls):
            before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
            out = jax.block_until_ready(make(float(k)))
            counts.append(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
            assert float(out[-1]) == k
            del out
        return sorted(counts)[calls // 2]

    default = faults_per_call()
    took = gj.retain_freed_memory()
    print(took, default, faults_per_call(), PAGES)
    """
)


@pytest.mark.skipif(
    platform.system() != "Linux" or platform.libc_ver()[0] != "glibc", reason="glibc only"
)
def test_retained_memory_serves_large_results_without_page_faults():
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True,
                         check=True).stdout.split()
    took, default, retained, pages = out[0] == "True", float(out[1]), float(out[2]), int(out[3])
    assert took
    # Without it each call maps the result's pages afresh (one fault per 4 KiB page, fewer
    # where the kernel maps huge pages); with it, the freed result's memory is reused. The
    # median call: a call served by a thread's malloc arena that has not held such a block
    # yet still takes fresh pages (seen in 1 of 5 runs with the mean of 6 calls).
    assert retained < 0.05 * pages, (default, retained, pages)


def test_retain_freed_memory_says_whether_it_applied():
    took = gj.retain_freed_memory()
    assert took is (platform.system() == "Linux" and platform.libc_ver()[0] == "glibc")
