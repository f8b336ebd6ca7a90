"""A forced orbit's period held fixed while a parameter moves: refused where the field's
period moves with the parameter (the solve would answer another problem, silently)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._validate import concrete_value

# How many times of one period the check samples, and the relative size of the change of
# f(t + T) − f(t) against the change of f itself (both per unit change of the parameter)
# above which the field is not T-periodic for every value: round-off in a field that is
# T-periodic at every value is ~1e-16 relative, a forcing of frequency ν gives O(1).
_SAMPLES = 5
_RELATIVE = 1e-6

# The fix, for the functions whose parameters are (μ, ν).
PERIOD_OF_FIX = ("Pass period_of=lambda mu, nu: <the forcing's period> (e.g. 2π/ν for a "
                 "forcing cos(νt)).")


def require_period_fixed_in(scene, args_at, value, t0, x, period, *, caller: str,
                            parameter: str, fix: str) -> None:
    """Raise a `ValueError` naming `fix` unless F(t + T, x, args_at(p)) − F(t, x, args_at(p))
    stays 0 to first order as the parameter p moves from `value`, where F is the scene's
    vector field and its surfaces' gaps (a moving wall is forced too), at `_SAMPLES` times of
    [t0, t0 + T) and the state `x`: with the period T held fixed, the solve is right only for
    scenes whose period does not depend on p. A `value` without a number (inside `jit`) is
    not checked."""
    value = concrete_value(value)
    if value is None:
        return
    value = float(np.asarray(value))
    with jax.ensure_compile_time_eval():
        x = jnp.asarray(x, float)
        ts = float(t0) + float(period) * jnp.arange(_SAMPLES) / _SAMPLES

        def drift_and_field(p):
            args = args_at(p)
            def scene_at(t):
                gaps = [jnp.reshape(s.phi(t, x, args), (1,)) for s in scene.surfaces]
                return jnp.concatenate([scene.vector_field(t, x, args), *gaps])

            field_at = jax.vmap(scene_at)
            now = field_at(ts)
            return field_at(ts + float(period)) - now, now

        _, (d_drift, d_field) = jax.jvp(drift_and_field, (jnp.asarray(value),),
                                        (jnp.ones(()),))
        drift, change = float(jnp.max(jnp.abs(d_drift))), float(jnp.max(jnp.abs(d_field)))
    if drift > _RELATIVE * change + np.finfo(float).tiny:
        raise ValueError(
            f"{caller}: the period is held at T = {float(period):.12g}, but the scene is "
            f"T-periodic only at this value of {parameter}: d/d{parameter} of "
            f"f(t + T) − f(t) (or of a gap Φ) is {drift:.3g} (against {change:.3g} for f and "
            f"Φ), so the solve would answer another problem as {parameter} moves. {fix}"
        )
