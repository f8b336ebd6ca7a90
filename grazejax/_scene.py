"""Scenes: the static structure of a discontinuous dynamical system.

Everything here is *structure*: Python callables fixed at trace time. Numbers that a user
may vary (μ, restitution, wall position) belong in `args`, so that changing them never
recompiles (docs/design.md, *Structure and numbers*).
"""

from collections.abc import Sequence

import equinox as eqx

from ._custom_types import GapFunction, JumpMap, Predicate, VectorField


class Surface(eqx.Module):
    r"""One surface piece Γ_i = {Φ_i = 0} ∩ {where_i} with its jump law x → J_i(x).

    **Arguments:**

    - `phi`: `phi(t, x, args) -> scalar`, the gap function Φ_i. The free side is Φ > 0.
    - `jump`: `jump(t, x, args) -> state`, the post-impact state J_i(x) = x + I_i(x).
    - `where`: optional `where(t, x, args) -> bool` bounding the piece (the paper's pieces
      are bounded, e.g. `x1 = 0, x2 ≤ 0`). `None` means the whole zero set. The piece is
      taken as closed: points within round-off of its boundary ∂Γ_i belong to it.
    - `inverse_jump`: optional `inverse_jump(t, x, args) -> state`, J_i⁻¹, used in backward
      time on the image surface Γ̃_i = J_i(Γ_i). If omitted it is solved by Newton's
      method from the guess 2x − J(x) (which may pick the wrong branch of a
      non-injective jump: pass it explicitly then).
    - `name`: optional label used in reports and plots.
    - `impenetrable`: if True, a jump (this surface's, or any other's) must leave the
      state on the free side (Φ ≥ 0 to within round-off, and not moving into Φ < 0);
      otherwise the run ends with `Status.BAD_JUMP`. Off by default because the paper's
      examples jump *into* Φ < 0 on purpose (ex1dof, exnonaxial); turn it on for walls
      and floors.

    **Event semantics** (docs/semantics.md): an impact happens when the trajectory *reaches*
    Φ_i = 0 while Φ_i decreases, or touches it tangentially (grazing, γ), at a point where
    `where` holds. An upward crossing passes through; Φ < 0 is allowed. A flight that
    starts on the surface (after a jump, or at x0) never impacts at its start time.

    **Example:** a floor at height 0 with restitution `args["e"]`:

    ```python
    floor = grazejax.Surface(
        phi=lambda t, x, args: x[0],
        jump=lambda t, x, args: x.at[1].set(-args["e"] * x[1]),
    )
    ```
    """

    phi: GapFunction = eqx.field(static=True)
    jump: JumpMap = eqx.field(static=True)
    where: Predicate | None = eqx.field(static=True, default=None)
    inverse_jump: JumpMap | None = eqx.field(static=True, default=None)
    name: str | None = eqx.field(static=True, default=None)
    impenetrable: bool = eqx.field(static=True, default=False)

    def __check_init__(self):
        for field in ("phi", "jump"):
            if not callable(getattr(self, field)):
                raise TypeError(f"Surface.{field} must be callable (t, x, args) -> ...")
        for field in ("where", "inverse_jump"):
            value = getattr(self, field)
            if value is not None and not callable(value):
                raise TypeError(f"Surface.{field} must be callable or None")


    def probe(self) -> "Surface":
        """This piece with a jump that leaves the state as it is: a run with it reports
        the contacts with Γ_i (their times and states) without changing the trajectory."""
        return Surface(phi=self.phi, jump=identity_jump, where=self.where, name=self.name)


def identity_jump(t, x, args):
    """J(x) = x (module level, so probe surfaces compare equal and share programs)."""
    return x


class Scene(eqx.Module):
    r"""A discontinuous dynamical system x' = f(t, x), x → J_i(x) on Γ_i.

    **Arguments:**

    - `vector_field`: `vector_field(t, x, args) -> dx/dt` (diffrax's convention; autonomous
      systems ignore `t`).
    - `surfaces`: a sequence of `grazejax.Surface` pieces. Their order is the order in
      which simultaneous impacts (within round-off of each other) are applied.
    - `project`: optional `project(t, x, args) -> x`, applied to the end state of every
      solver step: a map back onto an invariant manifold of the flow (a constraint, a
      conserved quantity) that the solver keeps only to its tolerance, so that the error
      stays at one step's instead of growing with the time run. It must be the identity on
      the manifold and smooth near it (derivatives pass through it: on the manifold its
      Jacobian projects onto the tangent space, where the flow's tangents already lie).
      E.g. one Gauss–Newton step onto {g = 0}: x − g(x)∇g(x)/|∇g(x)|². States saved
      between step ends (`saveat`) come from the step's dense output, one step's error off
      the manifold at most. A `grazejax.PiecewiseScene` sets it for its sliding modes.

    A scene is static structure: it is hashable, and `jax.jit` treats it as a compile-time
    constant. Keep numbers in `args`.
    """

    vector_field: VectorField = eqx.field(static=True)
    surfaces: tuple[Surface, ...] = eqx.field(static=True)
    project: VectorField | None = eqx.field(static=True, default=None)

    def __init__(self, vector_field: VectorField, surfaces: Sequence[Surface] = (), *,
                 project: VectorField | None = None):
        self.vector_field = vector_field
        self.surfaces = tuple(surfaces)
        self.project = project

    def __check_init__(self):
        if not callable(self.vector_field):
            raise TypeError("Scene.vector_field must be callable (t, x, args) -> dx/dt")
        if self.project is not None and not callable(self.project):
            raise TypeError("Scene.project must be callable (t, x, args) -> x, or None")
        for i, surface in enumerate(self.surfaces):
            if not isinstance(surface, Surface):
                raise TypeError(
                    f"Scene.surfaces[{i}] is a {type(surface).__name__}, not a Surface"
                )

    def with_surfaces(self, surfaces: Sequence[Surface]) -> "Scene":
        """This scene's flow (its field and `project`) with other surfaces: the scenes the
        analyses derive (a probe of one surface, the free flow, all but a grazed one)."""
        return Scene(self.vector_field, surfaces, project=self.project)

    def surface_name(self, index: int) -> str:
        name = self.surfaces[index].name
        return name if name is not None else f"Γ{index + 1}"
