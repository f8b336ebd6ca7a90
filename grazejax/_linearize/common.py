"""What every analysis shares: the derivative status, argument preparation (numbers become
arrays, so that changing them never recompiles), the run-status and finiteness tests, and the
usage error raised outside `jit` at a point where Φ, f or J is undefined."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._scene import Scene
from .._status import Status, StatusCode
from .._validate import is_concrete

# --------------------------------------------------------------------------------------
# Status
# --------------------------------------------------------------------------------------


class DerivativeStatus(StatusCode):
    """How trustworthy a derivative is. Stored as an integer array in each result's `status`.

    Inside `jax.jit` / `jax.vmap` nothing raises: `DerivativeStatus(int(r.status))` reads it.
    """

    OK = 0, "derivative of a run with transversal contacts only"
    """A derivative of a run whose contacts are all transversal (α, β)."""
    GRAZING = 1, "tangential contact (γ): derivative does not exist; (N2) value returned"
    """A contact is tangential (γ): the derivative does not exist there. The result holds
    the (N2) one-sided value (no jump); the (N1) side diverges like 1/(∇Φ·f)."""
    NO_CONTACT = 2, "the flow does not meet the surface in the window (W = 0)"
    """The flow does not meet Γ_i within the search window: τ_i = inf, W_i = 0 and W_{ix} = 0
    (the paper's convention for (N2) neighbours)."""
    SIMULATION_FAILED = 3, "simulate did not reach t1 (see the solution's status)"
    """`simulate` ended with a status other than SUCCESS / MAX_IMPACTS (see `solution`)."""
    UNDEFINED = 4, "Φ, f or J (or a first derivative) is not finite at the point"
    """Φ_i, f or J_i (or their first derivatives) are not finite at the point."""
    NONFINITE = 5, "the derivative is not finite"
    """The derivative itself came out non-finite."""


# --------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------


def float_array(x):
    # An explicit dtype: Python scalars would otherwise give weakly-typed arrays, and a
    # weak and a strong float64 are different signatures to jit (a silent recompile).
    x = jnp.asarray(x)
    dtype = x.dtype if jnp.issubdtype(x.dtype, jnp.inexact) else jnp.float64
    return jnp.asarray(x, dtype=dtype)


def _args_arrays(args):
    """Numbers in `args` become arrays, so that changing them never recompiles."""
    if args is None:
        return None
    return jax.tree.map(
        lambda leaf: (
            float_array(leaf)
            if isinstance(leaf, (int, float, np.ndarray, np.generic, jax.Array))
            and not isinstance(leaf, bool)
            else leaf
        ),
        args,
    )


def simulation_ok(status):
    return (status == int(Status.SUCCESS)) | (status == int(Status.MAX_IMPACTS))


def tree_finite(tree):
    leaves = [jnp.all(jnp.isfinite(leaf)) for leaf in jax.tree.leaves(tree)]
    return jnp.all(jnp.stack(leaves)) if leaves else jnp.array(True)


def _direction(t0, t1, kw):
    if kw.get("direction") is not None:
        return int(kw["direction"])
    if not is_concrete(t0, t1):
        raise ValueError(
            "t0/t1 are traced (inside jit/vmap): pass direction=+1 or -1 (as for simulate)"
        )
    return 1 if float(t1) > float(t0) else -1


def _check_surface_index(scene, surface_index):
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if not isinstance(surface_index, (int, np.integer)) or not (
        0 <= surface_index < len(scene.surfaces)
    ):
        raise ValueError(
            f"surface_index must be an integer in [0, {len(scene.surfaces)}), got {surface_index!r}"
        )
    return int(surface_index)


def raise_if_undefined(result, scene, surface_index, t, x, args, what):
    """Outside jit, an undefined point is a usage error: say exactly what is undefined."""
    if not is_concrete(result.status, t, x, args):
        return
    if int(result.status) != DerivativeStatus.UNDEFINED:
        return
    surface = scene.surfaces[surface_index]
    label = scene.surface_name(surface_index)
    checks = [
        ("Φ", lambda: surface.phi(t, x, args)),
        ("∇Φ", lambda: jax.jacfwd(surface.phi, argnums=(0, 1))(t, x, args)),
        ("f", lambda: scene.vector_field(t, x, args)),
        ("∂f/∂x", lambda: jax.jacfwd(scene.vector_field, argnums=1)(t, x, args)),
        ("J", lambda: surface.jump(t, x, args)),
        ("DJ", lambda: jax.jacfwd(surface.jump, argnums=(0, 1))(t, x, args)),
    ]
    bad = [name for name, fn in checks if not bool(tree_finite(fn()))]
    names = ", ".join(bad) if bad else "a derived quantity (J⁻¹, or Φ̃ on the image surface)"
    raise ValueError(
        f"{what}: {names} of surface {label} not finite at t = {float(t)!r}, "
        f"x = {np.asarray(x).tolist()}: the derivative is undefined there"
    )


def prepare_point(scene, surface_index, t, x, args):
    i = _check_surface_index(scene, surface_index)
    x = float_array(x)
    if x.ndim != 1:
        raise ValueError(f"x must be a state vector of shape (n,), got shape {x.shape}")
    t = float_array(t)
    if t.ndim != 0:
        raise ValueError(f"t must be a scalar, got shape {t.shape}")
    return i, t, x, _args_arrays(args)


def prepare_run(scene, x0, t0, t1, args, wrt, kw):
    if wrt not in ("x0", "args"):
        raise ValueError(f'wrt must be "x0" or "args", got {wrt!r}')
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if wrt == "args" and args is None:
        raise ValueError('wrt="args" needs args')
    kw = dict(kw)
    kw["direction"] = _direction(t0, t1, kw)
    if kw.pop("throw", False):
        raise ValueError("throw=True is not supported here: read the result's status")
    return float_array(x0), float_array(t0), float_array(t1), _args_arrays(args), kw
