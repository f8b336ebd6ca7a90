"""Shared test helpers: central differences, tree comparisons, the scenes several test
modules use, and an independent scipy reference.

Nothing here runs at import beyond defining functions: scenes are built by the functions
below (or by the test modules themselves), never registered in a shared table.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

import grazejax as gj


def quick_jit(fn):
    """`jax.jit` with XLA's quicker emitters, as `simulate` compiles outside `jit`
    (`grazejax/_compiler.py`): compiling is most of a test's time."""
    return jax.jit(fn, compiler_options=gj.compiler_options(batched=False))


def central_differences(fn, x, h):
    """Central differences of `fn` at `x`: (fn(x + h e_k) - fn(x - h e_k)) / 2h, one column
    per coordinate k of `x` (a scalar `x` gives the derivative itself).

    Their error is O(h^2 |third derivative|) plus O(eps |fn| / h) from round-off: pick `h`
    for the test.
    """
    x = np.asarray(x, np.float64)
    if x.ndim == 0:
        return (np.asarray(fn(x + h)) - np.asarray(fn(x - h))) / (2 * h)
    columns = [
        (np.asarray(fn(x + h * e)) - np.asarray(fn(x - h * e))) / (2 * h) for e in np.eye(x.size)
    ]
    return np.stack(columns, axis=-1)


def tree_allclose(a, b, *, rtol=0.0, atol=0.0) -> bool:
    """Whether two pytrees have the same structure and leaves equal within rtol/atol
    (NaN equal to NaN: padding rows of impact logs are NaN)."""
    import jax

    leaves_a, tree_a = jax.tree.flatten(a)
    leaves_b, tree_b = jax.tree.flatten(b)
    if tree_a != tree_b:
        return False
    return all(
        np.shape(u) == np.shape(v) and np.allclose(u, v, rtol=rtol, atol=atol, equal_nan=True)
        for u, v in zip(leaves_a, leaves_b, strict=True)
    )


def rotation_field(t, x, args):
    """x1' = x2, x2' = -x1: circles about the origin (a harmonic oscillator)."""
    return jnp.stack([x[1], -x[0]])


def clockwise(phi):
    """The rotation by −phi: the flow of `rotation_field` over a time phi."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[c, s], [-s, c]])


def projected_circle_scene():
    """`rotation_field` on its invariant unit circle, kept there by `project` (x/|x|), with
    a wall Φ = x2 met downward at angle 0 whose jump turns the state on by args["alpha"]
    (J = the rotation by −α, 0 < α < π). From x0 on the circle at angle θ0 ∈ (0, π), for
    θ0 < t1 < θ0 + 2π − α: one impact at t = θ0 and x(t1) = R(−(t1 + α)) x0/|x0|, so
    ∂x(t1)/∂x0 = R(−(t1 + α))(I − x0 x0ᵀ) (the projection's Jacobian on the circle;
    R(−(t1 + α)) without it) and ∂x(t1)/∂α = (sin(θ0 − t1 − α), −cos(θ0 − t1 − α))."""

    def turn(t, x, args):
        c, s = jnp.cos(args["alpha"]), jnp.sin(args["alpha"])
        return jnp.stack([c * x[0] + s * x[1], -s * x[0] + c * x[1]])

    wall = gj.Surface(phi=lambda t, x, args: x[1], jump=turn)
    return gj.Scene(rotation_field, [wall], project=lambda t, x, args: x / jnp.linalg.norm(x))


def free_fall_scene(restitution=0.8):
    """x' = v, v' = a (args["a"]) above a floor Φ = x; polynomial, so RK is exact."""

    def vector_field(t, x, args):
        return jnp.stack([x[1], args["a"] * jnp.ones_like(x[0])])

    floor = gj.Surface(
        phi=lambda t, x, args: x[0],
        jump=lambda t, x, args: x.at[1].set(-restitution * x[1]),
    )
    return gj.Scene(vector_field, [floor])


def unit_box(order=(0, 1, 2, 3)):
    """A free particle (x, y, vx, vy) in the unit box, walls in `order` of (x = 1, y = 1,
    x = 0, y = 0): at wall x_axis = 1 or 0 the velocity component is reversed and
    multiplied by args["rx"] (axis 0) or args["ry"] (axis 1). Impenetrable walls."""

    def field(t, x, args):
        return jnp.concatenate([x[2:], jnp.zeros(2)])

    def wall(axis, at_one):
        r = "rx" if axis == 0 else "ry"
        phi = (lambda t, x, a: 1.0 - x[axis]) if at_one else (lambda t, x, a: x[axis])
        return gj.Surface(
            phi=phi,
            jump=lambda t, x, a: x.at[2 + axis].set(-a[r] * x[2 + axis]),
            name=f"{'xy'[axis]}={int(at_one)}",
            impenetrable=True,
        )

    walls = [wall(0, True), wall(1, True), wall(0, False), wall(1, False)]
    return gj.Scene(field, [walls[i] for i in order])


def dip_start(delta, a, v0):
    """Start (h, v0) of a parabola x = h + v0 t + a t²/2 whose minimum is −delta.

    Returns (x0, exact impact time, exact impact speed) for delta > 0.
    """
    h = v0 * v0 / (2 * a) - delta
    x0 = np.array([h, v0])
    if delta <= 0:
        return x0, math.inf, 0.0
    disc = math.sqrt(2 * a * delta)  # = sqrt(v0² − 2 a h)
    # Stable root of h + v0 t + a t²/2 = 0 (v0 < 0): t = 2h / (−v0 + disc).
    t_hit = 2 * h / (-v0 + disc) if h != 0 else 0.0
    return x0, t_hit, -disc


def scipy_field(scene, args):
    """The scene's vector field as SciPy calls it: `f(t, x)` on NumPy arrays, jitted once
    (scipy calls it ~10^5 times per reference; op-by-op dispatch took minutes)."""
    field = jax.jit(lambda t, x: scene.vector_field(t, x, args))
    return lambda t, x: np.asarray(field(t, np.asarray(x, float)), float)


def scipy_reference(scene, x0, t0, t1, args, *, max_impacts, rtol=1e-13, atol=1e-13, max_step=0.01):
    """An independent impact loop: scipy DOP853 with terminal events and restarts.

    Uses the scene's own functions (evaluated as numpy), `max_step` small enough not to
    step over the dips of the test problems, and an exact restart rule: when a flight
    starts on a surface moving inwards (ġ <= 0), or crosses it outside the piece, no
    impact on that surface is possible until ġ has turned positive, so the surface's
    event is replaced by the event "ġ crosses 0 upwards" until then.
    Returns (impact times, pre-states, post-states, final state).
    """
    # The scene's functions jitted once (see `scipy_field`).
    phis = [jax.jit(lambda t, x, s=s: s.phi(t, x, args)) for s in scene.surfaces]
    grads = [jax.jit(jax.grad(lambda x, t, s=s: s.phi(t, x, args))) for s in scene.surfaces]
    f = scipy_field(scene, args)
    times, pres, posts = [], [], []
    t, x = float(t0), np.asarray(x0, float)
    blocked = set()

    def slope_of(i, tt, xx):
        return float(np.dot(np.asarray(grads[i](np.asarray(xx, float), tt)), f(tt, xx)))

    while t < t1 and len(times) < max_impacts:
        events = []
        for i in range(len(scene.surfaces)):
            if i in blocked:
                ev = lambda tt, xx, i=i: slope_of(i, tt, xx)
                ev.terminal, ev.direction = True, 1
            else:
                ev = lambda tt, xx, i=i: float(phis[i](tt, np.asarray(xx, float)))
                ev.terminal, ev.direction = True, -1
            events.append(ev)
        sol = solve_ivp(f, (t, t1), x, method="DOP853", rtol=rtol, atol=atol, events=events,
                        max_step=max_step)
        hit = [i for i, te in enumerate(sol.t_events) if len(te) and te[0] > t]
        if not hit:
            return np.array(times), np.array(pres), np.array(posts), sol.y[:, -1]
        i = min(hit, key=lambda j: sol.t_events[j][0])
        t, x = float(sol.t_events[i][0]), sol.y_events[i][0]
        if i in blocked:
            blocked.discard(i)
            continue
        s = scene.surfaces[i]
        if s.where is not None and not bool(s.where(t, jnp.asarray(x), args)):
            blocked.add(i)
            continue
        x_new = np.asarray(s.jump(t, jnp.asarray(x), args), float)
        times.append(t)
        pres.append(x)
        posts.append(x_new)
        x = x_new
        if slope_of(i, t, x) <= 0:
            blocked.add(i)
    return np.array(times), np.array(pres), np.array(posts), x
