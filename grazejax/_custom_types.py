"""Type aliases shared across grazejax (one place, as in diffrax's `_custom_types.py`)."""

from collections.abc import Callable
from typing import Any, TypeAlias

from jaxtyping import Array, ArrayLike, Bool, Float, Int, PyTree

State: TypeAlias = Float[Array, " n"]
"""A state vector x (the paper's x ∈ R^n)."""

Args: TypeAlias = PyTree[Any]
"""Parameters of a scene (μ, restitution, wall position, ...): arrays, never recompiled."""

Time: TypeAlias = Float[ArrayLike, ""]
RealScalar: TypeAlias = Float[Array, ""]
BoolScalar: TypeAlias = Bool[Array, ""]
IntScalar: TypeAlias = Int[Array, ""]

VectorField: TypeAlias = Callable[[Time, State, Args], State]
"""`vector_field(t, x, args) -> dx/dt` (diffrax's convention)."""

GapFunction: TypeAlias = Callable[[Time, State, Args], RealScalar]
"""`phi(t, x, args) -> scalar`; the free side is phi > 0."""

JumpMap: TypeAlias = Callable[[Time, State, Args], State]
"""`jump(t, x, args) -> x⁺ = J(x)`; the paper's impulse is I = J − id."""

Predicate: TypeAlias = Callable[[Time, State, Args], BoolScalar]
"""`where(t, x, args) -> bool`: which part of {phi = 0} is the surface piece Γ_i."""
