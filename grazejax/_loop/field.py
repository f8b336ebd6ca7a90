r"""The field-jump probe of the landing phase: is the vector field discontinuous at the
state a flight restarts from?

A field written with `sign(Φ)` (or `jnp.where` on the state) on an event surface switches
exactly where the loop restarts: the post-event state sits at Φ ≈ 1e-31, and which side
`sign` picks there is round-off. The first Runge–Kutta stage of the next flight may then
use the other side's field, and the run loses accuracy silently (a rocking block's time
to rest, a friction oscillator's turns drift far beyond the tolerance). The remedy is structural (modes: `PiecewiseScene`), so the loop
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

**Fields that cannot jump** are not probed (`continuous_in_state`): with t and args fixed,
as in the probe, a field whose every operation on x is a continuous function of its
operands is continuous in x, and the probe could only ever answer "no". The run reads
this from the field's jaxpr when it builds its loop; any doubt keeps the probe (what a
run does not use costs nothing: the probe is a tenth of a run's fusions). A continuous field with a steep Hölder singularity at the
surface (|x|^0.1) is no longer refused as a jump.
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


# ---- which fields cannot jump: read from their jaxpr ----------------------------------

# Primitives whose outputs are continuous functions of every input (where defined: a
# pole such as 1/x is not a jump the probe would report either). A field built from
# these alone, with t and args fixed, is continuous in x, so the probe cannot find a
# jump and is left out of the program. `atan2` (its branch cut), `rem`, `sign`, `floor`,
# comparisons, `sort` (argsort: its permuted operands jump) and the rest are not here.
_CONTINUOUS = frozenset({
    "abs", "acos", "acosh", "add", "asin", "asinh", "atan", "atanh", "broadcast_in_dim",
    "cbrt", "complex", "concatenate", "conj", "copy", "cos", "cosh", "cumlogsumexp",
    "cummax", "cummin", "cumprod", "cumsum", "digamma", "div", "dot_general", "erf",
    "erf_inv", "erfc", "exp", "exp2", "expm1", "imag", "integer_pow", "lgamma", "log",
    "log1p", "logistic", "max", "min", "mul", "neg", "pad", "pow", "real", "reduce_max",
    "reduce_min", "reduce_prod", "reduce_sum", "reshape", "rev", "rsqrt", "sin", "sinh",
    "slice", "sqrt", "square", "squeeze", "sub", "tan", "tanh", "transpose", "clamp",
    "split", "stack", "unstack", "tile",
})
# Primitives that move (or add, multiply, take the min of) data: continuous in their data
# operands, discontinuous in their index operands (these positions), which must not
# depend on x.
_INDEXED = {"dynamic_slice": slice(1, None), "gather": slice(1, 2),
            "dynamic_update_slice": slice(2, None), "scatter": slice(1, 2),
            "scatter-add": slice(1, 2), "scatter-sub": slice(1, 2), "scatter-mul": slice(1, 2),
            "scatter-min": slice(1, 2), "scatter-max": slice(1, 2)}
# Calls whose one sub-jaxpr takes the call's operands in order.
_CALLS = {"pjit": "jaxpr", "jit": "jaxpr", "closed_call": "call_jaxpr",
          "core_call": "call_jaxpr", "custom_jvp_call": "call_jaxpr",
          "custom_vjp_call": "call_jaxpr", "custom_vjp_call_jaxpr": "fun_jaxpr",
          "checkpoint": "jaxpr", "remat2": "jaxpr"}


def continuous_in_state(vector_field, t, x, args) -> bool:
    """Whether `vector_field(t, ·, args)` is, by construction, a continuous function of
    the state: every operation that depends on x is in a list of continuous primitives
    (selects, conditionals and indices that depend on x are not). True only where that
    holds for the traced program; any doubt (an unknown primitive, a `while` on x, a
    field that does not trace) is False, and the landing keeps its probe."""
    try:
        closed = jax.make_jaxpr(lambda y: vector_field(t, y, args))(x)
    except Exception:  # noqa: BLE001 - the run itself reports a field that fails
        return False
    return _continuous(closed.jaxpr, [True] * len(closed.jaxpr.invars)) is not None


def _continuous(jaxpr, tainted_in):
    """Which outputs depend on the inputs marked in `tainted_in`, if every operation on
    them is continuous; None if one is not."""
    tainted = {v for v, mark in zip(jaxpr.invars, tainted_in, strict=True) if mark}
    depends = lambda v: not isinstance(v, jax.extend.core.Literal) and v in tainted  # noqa: E731
    for eqn in jaxpr.eqns:
        marks = [depends(v) for v in eqn.invars]
        if not any(marks):
            continue
        name = eqn.primitive.name
        if name in _CONTINUOUS:
            outs = [True] * len(eqn.outvars)
        elif name == "select_n" and not marks[0]:  # the choice does not depend on x
            outs = [True]
        elif name in _INDEXED and not any(marks[_INDEXED[name]]):
            outs = [True] * len(eqn.outvars)
        elif name in _CALLS and _CALLS[name] in eqn.params:
            outs = _continuous(_open(eqn.params[_CALLS[name]]), marks)
        elif name == "cond" and not marks[0]:
            branches = [_continuous(_open(b), marks[1:]) for b in eqn.params["branches"]]
            outs = None if None in branches else [any(o) for o in zip(*branches, strict=True)]
        elif name == "convert_element_type" and _widening(eqn.invars[0], eqn.outvars[0]):
            # (a narrowing one rounds: steps of an ulp of the narrower type)
            outs = [True]
        else:
            return None
        if outs is None:
            return None
        tainted.update(v for v, mark in zip(eqn.outvars, outs, strict=True) if mark)
    return [depends(v) for v in jaxpr.outvars]


def _open(jaxpr):
    return getattr(jaxpr, "jaxpr", jaxpr)


def _widening(source, target) -> bool:
    """A float-to-float conversion that loses no bits (f32 → f64, or the same type)."""
    a, b = source.aval.dtype, target.aval.dtype
    floats = jnp.issubdtype(a, jnp.inexact) and jnp.issubdtype(b, jnp.inexact)
    return floats and jnp.finfo(b).nmant >= jnp.finfo(a).nmant
