"""The slow job's derivative fuzz: `jax.jacfwd` and reverse-mode `jax.grad` of final
states against central differences of the reference, on transversal systems of four
families (one solver each, the four tested solvers).

One test per pair, in a module of its own: the slow job's second worker takes it while
the first runs `test_large.py`.
"""

import numpy as np
import pytest

from . import compare as C
from .checks import assert_derivatives

PAIRS = [("linear2", "Dopri5"), ("mech1", "Tsit5"), ("mech2", "Vern9"), ("rotation", "Dopri8")]
# Of 32 systems per pair, the transversal ones whose central differences keep the impact
# sequence (14 to 22 per pair, 72 in all, with these seeds).
MINIMUM = 10


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(PAIRS)), ids=[f"{f}-{s}" for f, s in PAIRS])
def test_fuzz_derivatives_large(index):
    rows = C.derivative_campaign(PAIRS[index : index + 1], lanes=32, seed=11, first=index)
    assert_derivatives(rows, minimum=MINIMUM)
    assert np.isfinite([r[3] for r in rows]).all()
