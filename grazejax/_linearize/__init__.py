r"""Differentiable analysis through impacts: flow Jacobians, saltation, τ_i, W_i, B_i.

Everything here is built on `grazejax.simulate` and JAX's forward-mode autodiff: no
derivative of a flow is written by hand. `simulate` locates each event with one Newton
step on the time, so `jax.jacfwd` through it carries the implicit-function-theorem
tangent of every impact time, and the Jacobian of a run with impacts is the product of
flow Jacobians and saltation matrices (docs/design.md, *Derivatives*). The closed forms below (the
saltation matrix, eqs. dert and derw of the paper) are evaluated from derivatives of f,
Φ and J *at a point* and from Jacobians of impact-free flows: they are the independent
checks of the autodiff results, and the tests compare the two.

Paper objects (Akhmet & Kıvılcım, *Discontinuous dynamics with grazing points*, §2.1, §3):

- the meeting time τ_i(x): when the flow of x' = f from (θ, x) reaches Γ_i
  (`grazejax.meeting_time`, gradient eq. dert);
- the B-equivalence map W_i(x) = ψ(θ) − x (eq. W-map): flow to Γ_i, jump, flow back to
  θ (`grazejax.w_map`, Jacobian eq. derw), with W_i = 0 when the flow does not meet
  Γ_i near θ;
- the linearization u' = A(t) u, Δu = B_i u (eq. lin1) along a solution
  (`grazejax.variational_transition`), with B_i = W_{ix} = S_i − I at α points;
- the bivalued B_i at β/γ points, as one-sided limits over impacting (N1) and
  non-impacting (N2) neighbours (`grazejax.one_sided_jacobians`), and the (A2)
  diagnostic, the growth exponent of ‖W_x‖ at a grazing point (`grazejax.a2_diagnostic`).

**Reverse mode.** `grazejax.flow_jacobian` and `grazejax.scalar_gradient` take
`simulate`'s `adjoint=`: with the default (`diffrax.ForwardMode()`) they differentiate in
forward mode (one tangent per input coordinate, cheap for small state and parameter
spaces); with `diffrax.RecursiveCheckpointAdjoint()` or `diffrax.DirectAdjoint()`,
`scalar_gradient` uses `jax.grad` (one backward pass, whatever the number of parameters)
and `flow_jacobian` uses `jax.jacrev` where forward mode is unavailable. The pointwise
analyses below (τ_i, W_i, classification) are forward mode only.

**Every result has a status.** Every result carries a `grazejax.DerivativeStatus`. Near
grazing ∇Φ·f → 0 and the true derivatives grow without bound (like 1/(∇Φ·f)); they are
returned as computed. At an exactly tangential contact the derivative does not exist: the
pointwise analyses (τ_i, W_i) hold the (N2) one-sided value (no jump: B = O, S = I), a run's
flow Jacobian and gradient are NaN (the event time of a touch has no derivative: `simulate`
gives it a NaN tangent), each with the status `GRAZING`; use
`grazejax.one_sided_jacobians` for the one-sided linearizations. Divisions by ∇Φ·f use
the double-`where` so that no NaN reaches a tangent elsewhere. Values are otherwise NaN only
together with the status `UNDEFINED` (Φ_i, f or J_i, or their derivatives, are not finite at
the point: outside `jit` this raises a `ValueError` instead) or `SIMULATION_FAILED`.

**Modules.** Each module imports only from those listed before it:

- `common`: `grazejax.DerivativeStatus`, argument preparation (`prepare_point`,
  `prepare_run`), the run-status and finiteness tests, the undefined-point error;
- `jacobians`: `flow_jacobian`, `scalar_gradient` and their results;
- `saltation`: `saltation_matrix` (`saltation_core`, its traceable form, and `saltation_jit`);
- `classify`: `classify_point` (α, β, γ and their primes);
- `meeting`: `meeting_time`, `w_map` (one compiled program for both; `w_maps` at several
  neighbours), `closed_form_linearization`;
- `variational`: `variational_transition`;
- `limits`: `one_sided_jacobians`, `a2_diagnostic` (W-maps at neighbours, extrapolation).

The names these modules share carry no underscore; the public API is `grazejax`'s.
"""

from .classify import PointType as PointType
from .classify import classify_point as classify_point
from .common import DerivativeStatus as DerivativeStatus
from .common import prepare_point as prepare_point
from .jacobians import FlowJacobian as FlowJacobian
from .jacobians import ScalarGradient as ScalarGradient
from .jacobians import flow_jacobian as flow_jacobian
from .jacobians import scalar_gradient as scalar_gradient
from .limits import A2Diagnostic as A2Diagnostic
from .limits import OneSidedLimit as OneSidedLimit
from .limits import OneSidedLinearization as OneSidedLinearization
from .limits import a2_diagnostic as a2_diagnostic
from .limits import one_sided_jacobians as one_sided_jacobians
from .meeting import ClosedForm as ClosedForm
from .meeting import Meeting as Meeting
from .meeting import WMap as WMap
from .meeting import closed_form_linearization as closed_form_linearization
from .meeting import meeting_time as meeting_time
from .meeting import w_map as w_map
from .meeting import w_maps as w_maps
from .saltation import Saltation as Saltation
from .saltation import saltation_matrix as saltation_matrix
from .variational import Variational as Variational
from .variational import variational_transition as variational_transition
