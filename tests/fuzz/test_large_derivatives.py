"""The slow job's derivative fuzz: `jax.jacfwd` and reverse-mode `jax.grad` of final
states against central differences of the reference, on transversal systems of three
families (one solver each: Dopri5, Tsit5, Dopri8; the default job's `test_fuzz.py` adds
rotation/Tsit5). Vern9's derivatives through impacts are checked in the default job
(`tests/test_vern9.py`, forward and reverse mode); its pair here (mech2/Vern9, 18
systems, the module's longest at ~270 s, tracing and compiling Vern9's jacfwd and grad
under vmap) was taken out to keep CI within its time.

One test per pair, in a module of its own: the slow job's second worker takes it while
the first runs `test_large.py`.
"""

import numpy as np
import pytest

from . import compare as C
from .checks import assert_derivatives

# (family, solver, its index in the campaign, which seeds its systems: unchanged since the
# four-pair campaign, so each pair draws the systems it drew then)
PAIRS = [("linear2", "Dopri5", 0), ("mech1", "Tsit5", 1), ("rotation", "Dopri8", 3)]
# Of 32 systems per pair, the transversal ones whose central differences keep the impact
# sequence (14 to 22 per pair, 54 in all, with these seeds).
MINIMUM = 10


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(PAIRS)), ids=[f"{f}-{s}" for f, s, _ in PAIRS])
def test_fuzz_derivatives_large(index):
    family, solver, first = PAIRS[index]
    rows = C.derivative_campaign([(family, solver)], lanes=32, seed=11, first=first)
    assert_derivatives(rows, minimum=MINIMUM)
    assert np.isfinite([r[3] for r in rows]).all()
