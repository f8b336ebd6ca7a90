"""Input checks that run before tracing, so that bad input fails with a readable message.

Checks that need values (NaN in x0, t0 == t1) run only when the values are concrete; inside
`jit`/`vmap` the same problems end the run with a status instead (never silently).
"""

from typing import NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._scene import Scene


class Checked(NamedTuple):
    x0: jax.Array
    t0: jax.Array
    t1: jax.Array
    sigma: int  # +1 forward, -1 backward: static, it changes which surfaces exist
    ts: jax.Array | None


def _as_array(value, dtype):
    """`value` as an array of `dtype`: a JAX array of that dtype as it is, other values
    (numbers, NumPy) as NumPy arrays (cheap to make; the compiled run takes them as inputs),
    a tracer as a JAX array."""
    if isinstance(value, jax.Array) and value.dtype == dtype:
        return value
    if is_concrete(value):
        return np.asarray(value, dtype=dtype)
    return jnp.asarray(value, dtype=dtype)


def is_concrete(*trees) -> bool:
    """No leaf is a tracer: the values can be checked in Python (outside jit/vmap)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(trees))


def concrete_value(leaf):
    """`leaf`'s value where Python can read one, else None: a tracer of `jit` or `vmap` has
    none; a tracer of an eager `jax.jvp`, `jax.jacfwd` or `jax.grad` has its primal's."""
    return leaf.to_concrete_value() if isinstance(leaf, jax.core.Tracer) else leaf


def has_values(*trees) -> bool:
    """Every leaf has a value that Python can read (`concrete_value`)."""
    return all(concrete_value(leaf) is not None for leaf in jax.tree.leaves(trees))


def validate_inputs(
    scene, x0, t0, t1, args, *, max_impacts, max_steps, direction, allow_float32, saveat,
    check_scene: bool = True,
) -> Checked:
    """The inputs of one run, checked and converted. `check_scene=False` skips tracing the
    scene's functions on the inputs' shapes: for a caller whose run traces this check
    anyway when it compiles (a compiled program runs it once per input shapes, not per
    call)."""
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if not isinstance(max_impacts, (int, np.integer)) or max_impacts < 1:
        raise ValueError(f"max_impacts must be an integer >= 1, got {max_impacts!r}")
    if not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"max_steps must be an integer >= 1, got {max_steps!r}")

    float64 = jax.config.read("jax_enable_x64")
    x0_dtype = jnp.result_type(x0) if eqx.is_array_like(x0) else None
    if x0_dtype is not None and x0_dtype == jnp.float32 and not allow_float32:
        raise TypeError(
            "x0 is float32: grazejax computes in float64 (contact floors, event times and "
            "Jacobians assume it). Pass a float64 x0, or allow_float32=True to opt in."
        )
    if not float64 and not allow_float32:
        raise RuntimeError(
            "jax_enable_x64 is off, so the run would be float32. grazejax enables it on "
            "import; something turned it off. Re-enable it, or pass allow_float32=True."
        )
    dtype = jnp.float32 if (x0_dtype == jnp.float32 and allow_float32) else jnp.float64
    if x0_dtype is not None and jnp.issubdtype(x0_dtype, jnp.complexfloating):
        raise TypeError("x0 must be real, got a complex array")
    concrete_x0 = is_concrete(x0)
    if concrete_x0 and not np.all(np.isfinite(np.asarray(x0, dtype=np.float64))):
        raise ValueError(f"x0 contains NaN or inf: {np.asarray(x0)}")
    x0 = _as_array(x0, dtype)
    if x0.ndim != 1:
        raise ValueError(
            f"x0 must be a 1-D state vector of shape (n,), got shape {x0.shape}. "
            "For a batch, use jax.vmap or grazejax.sweep."
        )
    if x0.shape[0] == 0:
        raise ValueError("x0 is empty: the state needs at least one coordinate")
    if args is not None:
        for path, leaf in jax.tree_util.tree_flatten_with_path(args)[0]:
            if eqx.is_array_like(leaf) and is_concrete(leaf):
                value = np.asarray(leaf)
                if np.issubdtype(value.dtype, np.inexact) and not np.all(np.isfinite(value)):
                    raise ValueError(
                        f"args{jax.tree_util.keystr(path)} contains NaN or inf: {value}"
                    )

    concrete_times = is_concrete(t0) and is_concrete(t1)
    if concrete_times:
        a, b = np.asarray(t0, dtype=np.float64), np.asarray(t1, dtype=np.float64)
    t0 = _as_array(t0, dtype)
    t1 = _as_array(t1, dtype)
    if t0.ndim != 0 or t1.ndim != 0:
        raise ValueError(f"t0 and t1 must be scalars, got shapes {t0.shape} and {t1.shape}")
    if concrete_times:
        a, b = float(a), float(b)
        if not np.isfinite(a):
            raise ValueError(f"t0 must be finite, got {a}")
        if np.isnan(b):
            raise ValueError("t1 is NaN")
        if a == b:
            raise ValueError(f"t0 == t1 == {a}: nothing to simulate")
        sigma = 1 if b > a else -1
        if direction is not None and direction != sigma:
            raise ValueError(f"direction={direction} disagrees with t0={a}, t1={b}")
    else:
        if direction not in (1, -1):
            raise ValueError(
                "t0/t1 are traced (inside jit/vmap): pass direction=+1 or -1, since "
                "forward and backward runs compile different surfaces."
            )
        sigma = int(direction)

    if check_scene:
        _check_scene_shapes(scene, x0, t0, args)

    ts = None
    saveat = saveat_times(saveat, t0, t1)
    if saveat is not None:
        ts = jnp.asarray(saveat, dtype=dtype)
        if ts.ndim != 1 or ts.shape[0] == 0:
            raise ValueError(f"saveat must be a non-empty 1-D array of times, got shape {ts.shape}")
        if is_concrete(ts) and concrete_times:
            values = np.asarray(ts, dtype=np.float64) * sigma
            if np.any(np.diff(values) < 0):
                raise ValueError("saveat times must be monotone in the direction of integration")
            lo, hi = sorted((a, b))
            if np.any(values * sigma < lo) or np.any(values * sigma > hi):
                raise ValueError("saveat times must lie between t0 and t1")
    return Checked(x0, t0, t1, sigma, ts)


# Diffrax's default `fn` (save the state), read from a SubSaveAt: it is not exported.
_SAVE_Y = diffrax.SubSaveAt(t0=True).fn
_SAVEAT_WORKS = (
    "grazejax saves states at given times: pass saveat=diffrax.SaveAt(ts=...), with t0=True "
    "and/or t1=True if wanted, or a 1-D array of times"
)


def saveat_times(saveat, t0, t1):
    """The times asked for by `saveat` (an array of times or a `diffrax.SaveAt`), or None.

    A `SaveAt` is read as Diffrax reads it: `t0=True` saves at t0, `ts` at those times,
    `t1=True` at t1, in that order. What grazejax cannot honour (`steps`, `dense`, `fn`,
    solver or controller state, several `subs`) raises a `ValueError` that names what works.
    """
    if saveat is None or not isinstance(saveat, diffrax.SaveAt):
        return saveat
    for flag in ("dense", "solver_state", "controller_state", "made_jump"):
        if getattr(saveat, flag):
            raise ValueError(
                f"saveat=diffrax.SaveAt({flag}=True) is not supported: {_SAVEAT_WORKS}. "
                "(The impact log already holds every impact's pre and post state.)"
            )
    sub = saveat.subs
    if not isinstance(sub, diffrax.SubSaveAt):
        raise ValueError(
            "saveat=diffrax.SaveAt(subs=...) with several SubSaveAt is not supported (and an "
            f"empty SaveAt saves nothing): {_SAVEAT_WORKS}"
        )
    if sub.steps:
        raise ValueError(
            "saveat=diffrax.SaveAt(steps=True) is not supported: grazejax's loop has no "
            f"per-step output. {_SAVEAT_WORKS}"
        )
    if sub.fn is not _SAVE_Y:
        raise ValueError(
            "saveat=diffrax.SaveAt(fn=...) is not supported: save the states and apply the "
            f"function to sol.ts, sol.xs afterwards. {_SAVEAT_WORKS}"
        )
    parts = []
    if sub.t0:
        parts.append(jnp.reshape(jnp.asarray(t0), (1,)))
    if sub.ts is not None:
        parts.append(jnp.reshape(jnp.asarray(sub.ts), (-1,)))
    if sub.t1:
        if is_concrete(t1) and not np.isfinite(float(np.asarray(t1))):
            raise ValueError(
                "saveat=diffrax.SaveAt(t1=True) with t1 = inf: there is no time t1 to save at; "
                "the state where the run stopped is Solution.t_final, Solution.x_final"
            )
        parts.append(jnp.reshape(jnp.asarray(t1), (1,)))
    dtype = jnp.result_type(*parts)
    return jnp.concatenate([p.astype(dtype) for p in parts])


def _check_scene_shapes(scene: Scene, x0, t0, args):
    """Trace each scene function once on shapes only (no compilation, no FLOPs)."""
    n = x0.shape

    def shape_of(fn, what):
        try:
            return jax.eval_shape(fn, t0, x0, args)
        except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError) as error:
            raise TypeError(
                f"{what} reads a value in Python (`if`, `float()`, NumPy) on a state of shape "
                f"{n}: scene functions are traced, so x, t and every leaf of args (Python "
                "floats included) are JAX values there. Use jnp.where or lax.cond on them, "
                f"or keep a fixed choice out of args (in the function itself). JAX said: {error}"
            ) from error
        except Exception as error:  # noqa: BLE001 - re-raised with context
            context = f"{what} failed on a state of shape {n}"
            try:
                wrapped = type(error)(f"{context}: {error}")
            except Exception:  # noqa: BLE001 - a type that is not built from a message
                error.add_note(f"grazejax: {context}")
                raise error from None
            raise wrapped from error

    out = shape_of(scene.vector_field, "vector_field(t, x, args)")
    if getattr(out, "shape", None) != n:
        raise ValueError(
            f"vector_field(t, x, args) must return shape {n} like x, got {getattr(out, 'shape', type(out))}"
        )
    if scene.project is not None:
        out = shape_of(scene.project, "project(t, x, args)")
        if getattr(out, "shape", None) != n:
            raise ValueError(
                f"project(t, x, args) must return a state of shape {n}, got "
                f"{getattr(out, 'shape', type(out))}"
            )
    for i, surface in enumerate(scene.surfaces):
        label = scene.surface_name(i)
        out = shape_of(surface.phi, f"surface {label}: phi(t, x, args)")
        if getattr(out, "shape", None) != ():
            raise ValueError(
                f"surface {label}: phi(t, x, args) must return a scalar, got shape "
                f"{getattr(out, 'shape', type(out))}"
            )
        if not jnp.issubdtype(out.dtype, jnp.floating):
            raise TypeError(f"surface {label}: phi must return a float, got {out.dtype}")
        out = shape_of(surface.jump, f"surface {label}: jump(t, x, args)")
        if getattr(out, "shape", None) != n:
            raise ValueError(
                f"surface {label}: jump(t, x, args) must return a state of shape {n}, got "
                f"{getattr(out, 'shape', type(out))}"
            )
        if surface.where is not None:
            out = shape_of(surface.where, f"surface {label}: where(t, x, args)")
            if getattr(out, "shape", None) != () or out.dtype != jnp.bool_:
                raise ValueError(
                    f"surface {label}: where(t, x, args) must return a boolean scalar, got "
                    f"{getattr(out, 'dtype', type(out))} of shape {getattr(out, 'shape', None)}"
                )
        if surface.inverse_jump is not None:
            out = shape_of(surface.inverse_jump, f"surface {label}: inverse_jump(t, x, args)")
            if getattr(out, "shape", None) != n:
                raise ValueError(
                    f"surface {label}: inverse_jump must return a state of shape {n}"
                )
