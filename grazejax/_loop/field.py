r"""The field-jump probe of the landing phase: is the vector field discontinuous at the
state a flight restarts from?

A field written with `sign(Φ)` (or `jnp.where` on the state) on an event surface switches
exactly where the loop restarts: the post-event state sits at Φ ≈ 1e-31, and which side
`sign` picks there is round-off. The first Runge–Kutta stage of the next flight may then
use the other side's field, and the run loses accuracy silently (issue 13: the rocking
block's time to rest off by 5.5e-4, the friction oscillator's turns drifting by 2.4e-8 per
half cycle at rtol 1e-10). The remedy is structural (modes: `PiecewiseScene`), so the loop
refuses such a scene at its first landing with `Status.FIELD_DISCONTINUITY`.

**The rule.** Probe f along the flight's own direction v = f(t, x⁺), t fixed, with the
one-sided second differences on each side s = ±1, at two spacings:

    D_s(δ) = f(x⁺ + 2sδv) − 2 f(x⁺ + sδv) + f(x⁺).

For a C² field D_s(δ) = δ² D²f[v, v] + O(δ³): it grows like δ². If f jumps across a
surface through x⁺ that v crosses, then on the side s beyond the surface the two probes
see that side's smooth field f_s and x⁺ does not: D_s(δ) = f(x⁺) − f_s(x⁺) + O(δ²), the
jump (whole if round-off put x⁺ on the other side, half if `sign(0) = 0` put f(x⁺)
halfway, where a centred difference would cancel it exactly). Either way one side sees it,
so the verdict does not depend on the coin toss of the last bits of x⁺. A field that jumps
is one whose second difference does not grow with δ. A power law D ∝ δ^p has
D(2δ)/D(δ) = 2^p; we call it a jump when ‖D_s(2δ) − D_s(δ)‖ ≤ ¼‖D_s(δ)‖ on some side,
i.e. 2^p ≤ 1.25, p ≤ 0.32. A jump has p = 0, a smooth field p = 2; a kink (a continuous
field whose Jacobian jumps, e.g. a one-sided spring max(−x, 0)) is smooth on each side of
x⁺, and so is Hertz-type (−x)^{3/2}: neither is refused, only genuine jumps of f.

**The spacing** δ‖v‖∞ = √ε·L, L the largest |x_k| met in the flight (the loop's
round-off scale): far above the contact floor (64 ulps of L, so the probes do cross the
surface that x⁺ sits on), far below any length of the dynamics (the probe only sees what
happens within 4√ε·L ≈ 6e-8·L of x⁺).

**The round-off floor.** Each evaluation of f carries an error of a few ulps of the terms
it sums, which are of size ‖f‖ plus the linear terms ‖∂f/∂x‖·L. With G the slope of f
along v from the outer probes (‖f(x⁺ + 4δv) − f(x⁺ − 4δv)‖∞ / (8δ‖v‖∞), no extra
evaluation) the noise in D is a few ε·(F + L·G), F the largest ‖f‖∞ among the probes. A
jump must exceed τ = 1e3·ε·(F + L·G): a factor ~100 over that noise, so the power-law
test above only ever sees signal. (A jump inflates G by [f]/(8√ε·L), which raises τ to
~1e-6·‖[f]‖: the jump still exceeds it.) Jumps of f below ~1e-12 of the field's scale are
not seen; they also cost no more than round-off.

The probe costs seven evaluations of f per landing (none differentiated: its inputs are
`stop_gradient`-ed, and it only returns a bool), only in the landing phase, and gives no
verdict where v = 0 or where a probe is not finite.
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
    sizes, threshold, growths = field_probe(vector_field, t, x, args, x_scale)
    # NaN anywhere (a field undefined off the trajectory) compares False: no verdict.
    return jnp.any((sizes > threshold) & (growths <= _JUMP_GROWTH - 1))


def field_probe(vector_field, t, x, args, x_scale):
    """The probe's numbers: per side s = (+1, −1), `‖D_s(δ)‖∞` and
    `‖D_s(2δ) − D_s(δ)‖∞ / ‖D_s(δ)‖∞`, and the floor τ: `(sizes, τ, growths)`. A jump is a
    side with `size > τ` and a growth of at most ¼. Where v = 0 the sizes are 0."""
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
    # Points x + kδv, k = ±1, ±2, ±4: a one-sided second difference on each side, at
    # spacings δ and 2δ (one-sided: sign(0) = 0 puts f(x) halfway, where a centred
    # difference would cancel the jump exactly).
    ks = jnp.array([1.0, 2.0, 4.0, -1.0, -2.0, -4.0], dtype)
    probes = jax.vmap(lambda k: f(x + k * delta * f0))(ks)
    norm = lambda z: jnp.max(jnp.abs(z), axis=-1)  # noqa: E731
    d1 = jnp.stack([probes[1] - 2 * probes[0], probes[4] - 2 * probes[3]]) + f0
    d2 = jnp.stack([probes[2] - 2 * probes[1], probes[5] - 2 * probes[4]]) + f0
    slope = norm(probes[2] - probes[5]) / jnp.where(moving, 8 * delta * speed, 1.0)
    scale = jnp.maximum(norm(f0), jnp.max(jnp.abs(probes))) + length * slope
    sizes = jnp.where(moving, norm(d1), 0.0)
    growths = norm(d2 - d1) / jnp.where(sizes > 0, sizes, 1.0)
    return sizes, _NOISE_FACTOR * eps * scale, growths
