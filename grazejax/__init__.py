"""grazejax: differentiable simulation of impact systems with grazing, on JAX and Diffrax.

Importing grazejax enables JAX's float64 mode (`jax_enable_x64`): event floors, impact
times and Jacobians are computed in double precision unless a user opts out per call.
"""

import jax

jax.config.update("jax_enable_x64", True)

from ._scene import Scene as Scene, Surface as Surface  # noqa: E402
from ._simulate import simulate as simulate  # noqa: E402
from ._solution import Solution as Solution  # noqa: E402
from ._sweep import sweep as sweep  # noqa: E402
from ._status import ImpactKind as ImpactKind, Status as Status  # noqa: E402

__version__ = "0.1.0"
