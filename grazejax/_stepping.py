"""Step-size control inside the impact loop: which Diffrax controllers and solvers it accepts.

The loop runs every flight on a local clock s (time since the last impact) and retakes a step
to land on each contact, so a controller must propose the next step from the last one alone.
Diffrax's adaptive controllers do. Diffrax's `ConstantStepSize` does not: since diffrax 0.7 it
places step ends at fractions of the whole interval `[t0, t1]` with a step counter (diffrax
PR #666), which knows nothing of the loop's restarts and landings; used as is, the first step
after an impact jumped to the end of the interval (measured: ex1dof with dt0 = 0.01 ended at
(0.99, 3.82) where the truth is (1.27, −0.98)). `FixedStep` is the loop's own constant step:
every free step is `dt0` long, a landing step ends on the contact, and the next flight starts
with `dt0` again.
"""

import diffrax
import jax.numpy as jnp


class FixedStep(diffrax.AbstractStepSizeController):
    """Constant steps of length `dt0` in the loop's local clock (see the module docstring)."""

    dt0: float

    def wrap(self, direction):
        return self

    def init(self, terms, t0, t1, y0, dt0, args, func, error_order):
        del terms, t1, y0, dt0, args, func, error_order
        return t0 + self.dt0, None

    def adapt_step_size(self, t0, t1, y0, y1_candidate, args, y_error, error_order, state):
        del t0, y0, y1_candidate, args, y_error, error_order
        return True, t1, t1 + self.dt0, False, state, diffrax.RESULTS.successful


def loop_controller(stepsize_controller, solver, *, rtol, atol, dt0, has_error_estimate):
    """The controller the loop runs with, or a `ValueError` that names the fix.

    **Arguments:** as `simulate`'s. **Returns:** a controller with `init` and
    `adapt_step_size` in Diffrax's convention, already wrapped for forward time.
    """
    if stepsize_controller is None:
        stepsize_controller = diffrax.PIDController(rtol=rtol, atol=atol)
    if isinstance(stepsize_controller, diffrax.ConstantStepSize):
        if dt0 is None or not float(dt0) > 0:
            raise ValueError(
                "stepsize_controller=diffrax.ConstantStepSize() needs a positive step: pass "
                "dt0=<step length> (e.g. dt0=0.01)"
            )
        return FixedStep(float(dt0))
    if not isinstance(stepsize_controller, diffrax.AbstractAdaptiveStepSizeController):
        raise ValueError(
            f"simulate supports adaptive Diffrax controllers (e.g. diffrax.PIDController) and "
            f"diffrax.ConstantStepSize(); got {type(stepsize_controller).__name__}. Impacts "
            "restart the clock, so step sequences fixed in advance (StepTo) cannot be followed."
        )
    if not has_error_estimate:
        raise ValueError(
            f"diffrax.{type(solver).__name__} has no error estimate, so an adaptive controller "
            "cannot choose its steps: pass stepsize_controller=diffrax.ConstantStepSize() and "
            "dt0=<step length>, or use a solver with an embedded error estimate (diffrax.Tsit5, "
            "Dopri5, Dopri8, Kvaerno5)"
        )
    return stepsize_controller.wrap(1)


def error_or_zero(y_error, y):
    """A solver's error estimate, or zeros for solvers without one (used with fixed steps)."""
    if y_error is None:
        return jnp.zeros_like(y)
    return y_error
