"""Step-size control inside the impact loop: which Diffrax controllers and solvers it accepts.

The loop runs every flight on a local clock s (time since the last impact) and retakes a step
to land on each contact, so a controller must propose the next step from the last one alone.
Diffrax's adaptive controllers do. Diffrax's `ConstantStepSize` does not: since diffrax 0.7 it
places step ends at fractions of the whole interval `[t0, t1]` with a step counter (diffrax
PR #666), which knows nothing of the loop's restarts and landings; used as is, the first step
after an impact jumped to the end of the interval, and a run ended far from the truth.
`FixedStep` is the loop's own constant step: every free step is `dt0` long, a landing step
ends on the contact, and the next flight starts with `dt0` again.
"""

import math

import diffrax
import jax
import jax.numpy as jnp
import optimistix as optx


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


class IntegralController(diffrax.PIDController):
    """`diffrax.PIDController(rtol, atol)` with its default coefficients (an integral
    controller: next step = step · clip(safety · (1/error)^(1/order))), the loop's default.

    The same decisions as Diffrax's, the power taken as exp(log(·)/order): XLA's CPU
    backend calls the scalar libm `pow` for a power, lane by lane, but vectorises exp and
    log, and `pow` was a visible share of a sweep's time.
    The step factor differs from Diffrax's by an ulp or so. With other coefficients, or
    with dtmin/dtmax, Diffrax's own `adapt_step_size` runs.
    """

    def adapt_step_size(self, t0, t1, y0, y1_candidate, args, y_error, error_order,
                        controller_state):
        if self.pcoeff != 0 or self.dcoeff != 0 or self.dtmin is not None or (
            self.dtmax is not None
        ):
            return super().adapt_step_size(
                t0, t1, y0, y1_candidate, args, y_error, error_order, controller_state
            )
        order = error_order if self.error_order is None else self.error_order
        if order is None:  # (the loop always knows its solver's order)
            raise ValueError("pass PIDController(..., error_order=...): the solver has none")
        # Error relative to atol + rtol·max(|y0|, |y1|), a NaN candidate read as y0.
        y1 = jnp.where(jnp.isnan(y1_candidate).any(), y0, y1_candidate)
        scale = self.atol + jnp.maximum(jnp.abs(y0), jnp.abs(y1)) * self.rtol
        scaled_error = error_norm(self.norm, y_error / scale)
        keep = scaled_error < 1
        inv = jax.lax.stop_gradient(1 / jnp.asarray(scaled_error))
        power = jnp.exp(jnp.log(inv) * (self.icoeff / order))  # inv ** (icoeff / order)
        factor = jnp.clip(
            self.safety * power,
            min=jnp.where(keep, 1, self.factormin),
            max=jnp.where(keep, self.factormax, self.safety),
        )
        factor = jax.lax.stop_gradient(factor)
        dt = (t1 - t0) * factor.astype(jnp.result_type(t1 - t0))
        next_t0 = jnp.where(keep, t1, t0)
        # An integral controller reads no history: its state passes through unchanged.
        # (Diffrax's PIDController records the last two errors, which nothing here reads;
        # XLA drops such dead carries from `simulate`'s loop but not from the nested loops
        # of `sweep`'s pool, where every lane carried and selected them at every step.)
        return keep, next_t0, next_t0 + dt, False, controller_state, diffrax.RESULTS.successful


# The largest state whose RMS error norm is written out term by term (`error_norm`).
UNROLLED_NORM_MAX = 8


def error_norm(norm, ratio):
    """`norm(ratio)`; for Diffrax's default `rms_norm` of a small state, the same sum of
    squares written out term by term.

    `optx.rms_norm` takes the sum of squares as a `dot`. Under `vmap` that is one dot per
    lane over the state's n entries, which XLA:CPU runs as a reduction kernel of its own
    (a YNNPACK fusion) at every step; the terms written out are an elementwise part of
    the controller's kernels instead. The sum differs from the dot's in the last bit in
    some lanes (the dot's reduction rounds in another order), so step sizes may differ by
    an ulp. The controller's decisions
    carry no derivative, hence the `stop_gradient` (no NaN tangent of √0 either).
    """
    if norm is not optx.rms_norm or not isinstance(ratio, jax.Array) or ratio.ndim != 1 or (
        not 0 < ratio.shape[0] <= UNROLLED_NORM_MAX
    ):
        return norm(ratio)
    ratio = jax.lax.stop_gradient(ratio)
    n = ratio.shape[0]
    if n == 1:
        return jnp.abs(ratio[0])  # (as rms_norm: no squaring and rooting)
    squares = ratio[0] * ratio[0]
    for i in range(1, n):
        squares = squares + ratio[i] * ratio[i]
    return jnp.sqrt(squares) / math.sqrt(n)


def loop_controller(stepsize_controller, solver, *, rtol, atol, dt0, has_error_estimate):
    """The controller the loop runs with, or a `ValueError` that names the fix.

    **Arguments:** as `simulate`'s. **Returns:** a controller with `init` and
    `adapt_step_size` in Diffrax's convention, already wrapped for forward time.
    """
    if stepsize_controller is None:
        stepsize_controller = IntegralController(rtol=rtol, atol=atol)
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
