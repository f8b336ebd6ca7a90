r"""The field-jump probe of the landing phase: is the vector field discontinuous at the
state a flight restarts from?

A field written with `sign(Φ)` (or `jnp.where` on the state) on an event surface switches
exactly where the loop restarts: the post-event state sits at Φ ≈ 1e-31, and which side
`sign` picks there is round-off. The first Runge–Kutta stage of the next flight may then
use the other side's field, and the run loses accuracy silently (issue 13: the rocking
block's time to rest off by 5.5e-4, the friction oscillator's turns drifting by 2.4e-8 per
half cycle at rtol 1e-10). The remedy is structural (modes: `PiecewiseScene`), so the loop
refuses such a scene at its first landing with `Status.FIELD_DISCONTINUITY`.

**The rule.** Probe f along the flight's own direction v = f(t, x⁺) with the centred second
differences at two spacings, t fixed:

    D(δ) = f(x⁺ + δv) − 2 f(x⁺) + f(x⁺ − δv).

For a C² field D(δ) = δ² D²f[v, v] + O(δ⁴): it grows like δ². If f jumps by [f] across a
surface through x⁺ that v crosses, one of the two probes lies on the other side and
D(δ) = ±[f] + O(δ²) (whichever side the round-off put x⁺ on: the probe is symmetric, so
the verdict does not depend on that coin toss). A field that jumps is one whose second
difference does not grow with δ. A power law D ∝ δ^p has D(2δ)/D(δ) = 2^p; we call it a
jump when ‖D(2δ) − D(δ)‖ ≤ ¼‖D(δ)‖, i.e. 2^p ≤ 1.25, p ≤ 0.32. A jump has p = 0, a smooth
field p = 2, a kink of f (a continuous field whose Jacobian jumps, e.g. a one-sided
spring max(−x, 0)) p = 1 and Hertz-type (−x)^{3/2} p = 1.5: none of those are refused,
only genuine jumps of f.

**The spacing** δ‖v‖∞ = √ε·L, L the largest |x_k| met in the flight (the loop's
round-off scale): far above the contact floor (64 ulps of L, so the probes do cross the
surface that x⁺ sits on), far below any length of the dynamics (the probe only sees what
happens at x⁺).

**The round-off floor.** Each evaluation of f carries an error of a few ulps of the terms
it sums, which are of size ‖f‖ plus the linear terms ‖∂f/∂x‖·L. With G the slope of f
along v from the outer probes (‖f(x⁺ + 2δv) − f(x⁺ − 2δv)‖∞ / (4δ‖v‖∞), no extra
evaluation) the noise in D is a few ε·(F + L·G), F the largest ‖f‖∞ among the probes. A
jump must exceed τ = 1e3·ε·(F + L·G): a factor ~100 over that noise, so the power-law
test above only ever sees signal. (A jump inflates G by [f]/(4√ε·L), which raises τ to
~2.5e-6·‖[f]‖: the jump still exceeds it.) Jumps of f smaller than ~1e-12 of the field's
scale are not seen; they also cost no more than round-off.

The probe costs five evaluations of f per landing (none of them differentiated: its
inputs are `stop_gradient`-ed, and it only returns a bool), and is skipped where v = 0.
"""

import jax
import jax.numpy as jnp

# A second difference that grows by at most this factor when the spacing doubles is a
# jump (2^p ≤ 1.25: exponent p ≤ 0.32; smooth fields have p = 2, kinks p = 1).
_JUMP_GROWTH = 1.25
# Threshold over the round-off estimate ε·(F + L·G) of the probe's second differences.
_NOISE_FACTOR = 1e3


def field_jumps(vector_field, t, x, args, x_scale):
    """Whether `vector_field(t, ·, args)` jumps at `x` along its own direction (see the
    module docstring). Returns a bool scalar; carries no derivative."""
    t, x, args, x_scale = jax.lax.stop_gradient((t, x, args, x_scale))
    dtype = x.dtype
    eps = jnp.finfo(dtype).eps

    def f(y):
        return jnp.asarray(vector_field(t, y, args), dtype)

    f0 = f(x)
    speed = jnp.max(jnp.abs(f0))
    length = jnp.max(jnp.abs(x_scale))
    moving = (speed > 0) & (length > 0) & jnp.all(jnp.isfinite(f0))
    # v = 0 (at rest) or no scale: nothing to probe; keep δ finite so that the unused
    # evaluations below stay finite.
    delta = jnp.where(moving, jnp.sqrt(eps) * length / jnp.where(moving, speed, 1.0), 0.0)
    probes = jax.vmap(lambda k: f(x + k * delta * f0))(jnp.array([1.0, -1.0, 2.0, -2.0], dtype))
    d1 = probes[0] - 2 * f0 + probes[1]
    d2 = probes[2] - 2 * f0 + probes[3]
    norm = lambda z: jnp.max(jnp.abs(z))  # noqa: E731
    slope = norm(probes[2] - probes[3]) / jnp.where(moving, 4 * delta * speed, 1.0)
    scale = jnp.maximum(norm(f0), jnp.max(jnp.abs(probes))) + length * slope
    above_noise = norm(d1) > _NOISE_FACTOR * eps * scale
    flat = norm(d2 - d1) <= (_JUMP_GROWTH - 1) * norm(d1)
    # NaN anywhere (a field undefined off the trajectory) compares False: no verdict.
    return moving & above_noise & flat
