"""How the impact loop is differentiated: Diffrax's adjoint objects, read as loop kinds.

The loop is a while loop of solver steps, and each Runge–Kutta step has a loop over its
stages. JAX differentiates while loops in forward mode only (`lax.while_loop`); reverse mode
needs Equinox's checkpointed loop or grazejax's loop that stores each step's linearisation
(`_loop/stored.py`; both `custom_vjp`s, which forward mode cannot enter), and Equinox's
bounded loop (nested scans) supports both at the price of storing every step.
So the choice is the user's, in Diffrax's words:

| `adjoint=`                                | jax.jacfwd | jax.grad | cost                                |
|-------------------------------------------|------------|----------|-------------------------------------|
| `None`, `diffrax.ForwardMode()`           | yes        | no       | the primal's                        |
| `diffrax.RecursiveCheckpointAdjoint()`    | no         | yes      | a 2nd forward pass, √max_steps carries and residual rows (carries: large residuals, vmap) |
| `diffrax.RecursiveCheckpointAdjoint(n)`   | no         | yes      | recomputation, n carries            |
| `RecursiveCheckpointAdjoint(n ≥ max_steps)` | no       | yes      | no recomputation, a residual row per step |
| `diffrax.DirectAdjoint()`                 | yes        | yes      | memory for every step               |

Event times never need a loop's derivative: the root searches locate them without
tangents, and one Newton step outside the searches carries the implicit-function-theorem
tangent (see `_loop/land.py`), identical in both modes.
"""

from typing import Literal, NamedTuple

import diffrax

Kind = Literal["lax", "checkpointed", "bounded"]

REVERSE_HINT = (
    "reverse-mode differentiation (jax.grad, jax.vjp) of grazejax.simulate needs "
    "adjoint=diffrax.RecursiveCheckpointAdjoint() (reverse only) or "
    "adjoint=diffrax.DirectAdjoint() (both modes, stores every step); the default "
    "adjoint (diffrax.ForwardMode()) supports jax.jvp/jax.jacfwd only"
)


class LoopKinds(NamedTuple):
    """The Equinox loop kinds for the impact loop and the Runge–Kutta stage loop."""

    outer: Kind
    stages: Kind | None  # None: Diffrax's default (checkpointed)
    checkpoints: int | None
    forward: bool  # jax.jvp / jacfwd supported
    reverse: bool  # jax.grad / vjp supported


def loop_kinds(adjoint) -> LoopKinds:
    """Map a Diffrax adjoint to loop kinds, or raise a `ValueError` naming the choices."""
    if adjoint is None or isinstance(adjoint, diffrax.ForwardMode):
        return LoopKinds("lax", "lax", None, forward=True, reverse=False)
    if isinstance(adjoint, diffrax.RecursiveCheckpointAdjoint):
        return LoopKinds("checkpointed", None, adjoint.checkpoints, forward=False, reverse=True)
    if isinstance(adjoint, diffrax.DirectAdjoint):
        return LoopKinds("bounded", "bounded", None, forward=True, reverse=True)
    raise ValueError(
        f"adjoint={type(adjoint).__name__}() is not supported by grazejax.simulate: use "
        "diffrax.ForwardMode() (default; jax.jacfwd), diffrax.RecursiveCheckpointAdjoint() "
        "(jax.grad) or diffrax.DirectAdjoint() (both). Backsolve and implicit adjoints "
        "would need the adjoint equation solved backward through every impact."
    )


def require_forward_mode(adjoint, caller: str, what: str) -> None:
    """Raise a `ValueError` naming the fix if `adjoint` cannot run forward mode, which
    Newton's method needs (`caller` linearises `what` with `jax.jacfwd`)."""
    if not loop_kinds(adjoint).forward:
        raise ValueError(
            f"{caller}: Newton's method linearises {what} in forward mode, which "
            f"adjoint={type(adjoint).__name__}() does not support; pass "
            "adjoint=diffrax.DirectAdjoint() to differentiate the result with jax.grad, or "
            "leave adjoint out for jax.jacfwd"
        )
