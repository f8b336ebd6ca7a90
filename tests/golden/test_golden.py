"""The loop's results against the recording in golden.npz (see runs.py).

Bit-identical on the machine that recorded them (set GRAZEJAX_GOLDEN_EXACT=1 while moving
code); elsewhere XLA may vectorise or fuse differently for another CPU, so the default
comparison allows 1e-10 relative to each quantity's scale, with exact integers (impact
counts, surfaces, kinds, statuses). Step counts may differ by a few on another machine.
"""

import os

import numpy as np
import pytest

from .runs import PATH, runs

EXACT = os.environ.get("GRAZEJAX_GOLDEN_EXACT") == "1"


@pytest.fixture(scope="module")
def fresh():
    return runs()


def test_golden_runs_reproduce(fresh):
    recorded = dict(np.load(PATH))
    assert sorted(recorded) == sorted(fresh)
    for key, want in recorded.items():
        got = fresh[key]
        assert got.shape == want.shape, key
        if EXACT:
            np.testing.assert_array_equal(got, want, err_msg=key)
        elif key.endswith(".num_steps"):
            np.testing.assert_allclose(got, want, rtol=0.02, atol=2, err_msg=key)
        elif np.issubdtype(want.dtype, np.integer):
            np.testing.assert_array_equal(got, want, err_msg=key)
        else:
            finite = np.isfinite(want)
            np.testing.assert_array_equal(np.isfinite(got), finite, err_msg=key)
            scale = np.max(np.abs(want[finite])) if finite.any() else 1.0
            np.testing.assert_allclose(got[finite], want[finite], rtol=0, atol=1e-10 * max(scale, 1e-300), err_msg=key)
