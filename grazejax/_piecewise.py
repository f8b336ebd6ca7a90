r"""Piecewise-smooth scenes: discrete modes, switching surfaces and Filippov sliding.

A `grazejax.PiecewiseScene` compiles a description in modes into an ordinary
`grazejax.Scene` whose state is y = (x, m): the physical state x followed by one float
component m, the index of the current mode. The mode is constant along a flight (its
derivative is 0, so every Runge–Kutta stage sees the same m) and only a jump changes it, so
the impact loop locates every mode change exactly as it locates an impact, lands it with a
real solver step, and differentiates through it (docs/piecewise.md; design note 4b).

Why not `sign(·)` in the field: a Runge–Kutta step across a discontinuity of f evaluates
stages on both sides, and its error estimate is no longer that of a smooth problem (orders
of magnitude worse at the same tolerance; after an event a state at Φ ≈ 1e-31 may take the
wrong side). Here the field of mode k is evaluated only with m = k.
"""

import dataclasses
import functools
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._geometry import newton_step_to_surface, on_surface
from ._scene import Scene, Surface
from ._simulate import simulate


class Mode(eqx.Module):
    r"""One discrete mode of a `grazejax.PiecewiseScene`: a name and its vector field.

    **Arguments:**

    - `name`: the mode's label (unique within the scene).
    - `vector_field`: `vector_field(t, x, args) -> dx/dt` on the physical state x (without
      the mode component).
    """

    name: str = eqx.field(static=True)
    vector_field: Callable = eqx.field(static=True)


class Transition(eqx.Module):
    r"""A guarded mode change: in mode `source`, when Φ reaches 0 from Φ > 0 (the loop's
    impact rule, docs/semantics.md), x → `jump(x)` and the mode becomes `target`.

    **Arguments:**

    - `source`: the mode in which the guard is live.
    - `target`: the mode after the event: a name (it may equal `source`: an impact that
      keeps the mode), or a sequence of `(condition, name)` pairs, the first whose
      `condition(t, x, args)` holds at the pre-event state winning (`None`: always; the
      last pair should have it). E.g. a slipping mass that reaches the belt's speed sticks
      if the spring force is within static friction, else slips on:
      `[(lambda t, x, a: abs(x[0]) < a["mu_s"], "stick"), (None, "fast")]`.
    - `phi`: `phi(t, x, args) -> scalar`, the guard's gap function in `source` (free side
      Φ > 0). It is not looked at in other modes.
    - `jump`: optional `jump(t, x, args) -> x`, the reset of x (default: identity, a pure
      mode switch; e.g. a rocking block's restitution law when the pivot changes).
    - `where`: optional `where(t, x, args) -> bool` bounding the guard (as in `Surface`).
    - `name`: a label for the event log (`grazejax.PiecewiseScene.events`).
    """

    source: str = eqx.field(static=True)
    target: str | tuple = eqx.field(static=True, converter=lambda v: v if isinstance(v, str) else tuple(tuple(r) for r in v))
    phi: Callable = eqx.field(static=True)
    jump: Callable | None = eqx.field(static=True, default=None)
    where: Callable | None = eqx.field(static=True, default=None)
    name: str | None = eqx.field(static=True, default=None)


class SwitchingSurface(eqx.Module):
    r"""A surface Σ = {Φ = 0} across which the field changes without a jump of x.

    Mode `plus` lives on Φ > 0 with field f₊, mode `minus` on Φ < 0 with field f₋. Let
    a = dΦ/dt along f₋ and b = dΦ/dt along f₊ (a = ∇Φ·f₋ + ∂Φ/∂t). Reaching Σ in `plus`
    (b < 0) switches to `minus` if a < 0 (crossing), and in `minus` (a > 0) to `plus` if
    b > 0. If both fields push into Σ (a > 0 > b) the state **slides** on Σ in mode
    `sliding` (when given) with the Filippov field

        F = (1 − λ) f₋ + λ f₊,   λ = a / (a − b) ∈ (0, 1),

    which keeps dΦ/dt = 0. Sliding ends where λ reaches 0 (a = 0: leaves into `minus`) or
    1 (b = 0: leaves into `plus`). Both are gap functions of the sliding mode (a and −b),
    so the exit is an event located as exactly as an impact. Without `sliding`, a
    sliding-type arrival crosses anyway (and will chatter: give `sliding`).

    For a linear Φ the sliding field keeps Φ constant to round-off (Runge–Kutta methods
    preserve linear invariants); for a curved Φ every step's end state is moved back onto
    Σ (the compiled scene's `project`), so the error does not grow with the time slid.

    **Arguments:**

    - `phi`: `phi(t, x, args) -> scalar`.
    - `minus`, `plus`: names of the modes on each side (must be defined in the scene).
    - `sliding`: name of the sliding mode to create (its field is built here), or `None`.
    - `name`: a label for the event log.
    """

    phi: Callable = eqx.field(static=True)
    minus: str = eqx.field(static=True)
    plus: str = eqx.field(static=True)
    sliding: str | None = eqx.field(static=True, default=None)
    name: str | None = eqx.field(static=True, default=None)


@dataclasses.dataclass(frozen=True)
class Event:
    """One row of a run's event log, read by `grazejax.PiecewiseScene.events`.

    `label` is one of `"CROSS"` (a switching surface crossed), `"SLIDE"` (sliding starts),
    `"RELEASE"` (sliding ends), `"TRANSITION"` (a `Transition` fired) or `"IMPACT"` (one of
    the scene's ordinary surfaces).
    """

    time: float
    label: str
    name: str
    source: str
    target: str
    x_pre: np.ndarray
    x_post: np.ndarray


def _rate(phi, t, x, args, field):
    """dΦ/dt along `field` at (t, x): ∂Φ/∂t + ∇Φ·f, by one forward-mode product."""
    f = field(t, x, args)
    _, rate = jax.jvp(lambda s, y: phi(s, y, args), (t, x), (jnp.ones_like(t), f))
    return rate


class PiecewiseScene(eqx.Module):
    r"""A piecewise-smooth system with discrete modes, compiled into an ordinary `Scene`.

    The compiled `grazejax.Scene` (`.scene`) acts on y = (x, m): m, the last
    component, is the mode's index (a float holding an exact integer). Its vector field is
    the field of mode m (`lax.switch` on m: a single run evaluates only that mode's field;
    under `vmap` XLA evaluates every branch and selects, so no other mode's field
    *contributes* to a stage, which is what matters for accuracy). Derivatives with
    respect to m are zero. Every guard (transitions, both sides of each switching surface,
    the sliding exits) is a `Surface` of the compiled scene whose gap is the guard's Φ in
    its source mode and 1 in the other modes, so the loop locates mode changes like
    impacts and `jax.jacfwd` through them gives the saltation matrices (for sliding: the
    projection onto Σ at entry, the identity at exit).

    **Arguments:**

    - `modes`: a sequence of `grazejax.Mode` (the sliding modes of `switching` are
      added after them).
    - `transitions`: `grazejax.Transition` guards.
    - `switching`: `grazejax.SwitchingSurface` surfaces (with Filippov sliding).
    - `surfaces`: ordinary `grazejax.Surface` pieces on x, active in every mode (their
      jumps keep the mode).

    **Example:** the Coulomb friction oscillator x'' + x = −μ sign(x'):

    ```python
    import jax.numpy as jnp
    import grazejax as gj

    friction = lambda s: lambda t, x, a: jnp.stack([x[1], -x[0] - s * a["mu"]])
    pw = gj.PiecewiseScene(
        [gj.Mode("forward", friction(1.0)), gj.Mode("backward", friction(-1.0))],
        switching=[gj.SwitchingSurface(lambda t, x, a: x[1], minus="backward",
                                       plus="forward", sliding="stick")],
    )
    sol = gj.simulate(pw.scene, pw.state([1.0, 0.0], "backward"), 0.0, 20.0, {"mu": 0.1})
    print([(round(e.time, 6), e.label) for e in pw.events(sol)])  # stick at t = 5π
    ```
    """

    modes: tuple[Mode, ...] = eqx.field(static=True)
    transitions: tuple[Transition, ...] = eqx.field(static=True)
    switching: tuple[SwitchingSurface, ...] = eqx.field(static=True)
    surfaces: tuple[Surface, ...] = eqx.field(static=True)
    scene: Scene = eqx.field(static=True)
    # One row per surface of the compiled scene: (label, name) for `events`.
    _log: tuple = eqx.field(static=True)
    _names: tuple[str, ...] = eqx.field(static=True)

    def __init__(
        self,
        modes: Sequence[Mode],
        transitions: Sequence[Transition] = (),
        switching: Sequence[SwitchingSurface] = (),
        surfaces: Sequence[Surface] = (),
    ):
        self.modes = tuple(modes)
        self.transitions = tuple(transitions)
        self.switching = tuple(switching)
        self.surfaces = tuple(surfaces)
        names = [m.name for m in self.modes]
        for s in self.switching:
            if s.sliding is not None:
                names.append(s.sliding)
        if len(set(names)) != len(names):
            raise ValueError(f"mode names must be unique, got {names}")
        index = {name: k for k, name in enumerate(names)}

        def mode_index(name):
            if name not in index:
                raise ValueError(f"unknown mode {name!r}; the modes are {list(index)}")
            return index[name]

        fields = [m.vector_field for m in self.modes]
        for s in self.switching:
            if s.sliding is not None:
                fields.append(_filippov_field(s.phi, fields[mode_index(s.minus)],
                                              fields[mode_index(s.plus)]))
        fields = tuple(fields)

        pieces, log = [], []
        for tr in self.transitions:
            pieces.append(_guard(mode_index(tr.source), tr.phi,
                                 _choose(tr.target, mode_index), tr.jump, tr.where, tr.name))
            log.append(("TRANSITION", tr.name or f"{tr.source}→{tr.target}"))
        for i, s in enumerate(self.switching):
            name = s.name or f"Σ{i + 1}"
            minus, plus = mode_index(s.minus), mode_index(s.plus)
            f_minus, f_plus = fields[minus], fields[plus]
            slide = None if s.sliding is None else mode_index(s.sliding)
            phi = s.phi

            def from_plus(t, x, args, phi=phi, f=f_minus, minus=minus, slide=slide):
                if slide is None:
                    return jnp.asarray(minus, x.dtype)
                # f₋ pushes back up (a > 0): both sides push into Σ, slide.
                return jnp.where(_rate(phi, t, x, args, f) > 0, slide, minus).astype(x.dtype)

            def from_minus(t, x, args, phi=phi, f=f_plus, plus=plus, slide=slide):
                if slide is None:
                    return jnp.asarray(plus, x.dtype)
                return jnp.where(_rate(phi, t, x, args, f) < 0, slide, plus).astype(x.dtype)

            neg = lambda t, x, args, phi=phi: -phi(t, x, args)  # noqa: E731
            pieces.append(_guard(plus, phi, from_plus, None, None, name + "+"))
            pieces.append(_guard(minus, neg, from_minus, None, None, name + "−"))
            log += [("CROSS", name), ("CROSS", name)]
            if slide is not None:
                a = lambda t, x, args, phi=phi, f=f_minus: _rate(phi, t, x, args, f)  # noqa: E731
                minus_b = lambda t, x, args, phi=phi, f=f_plus: -_rate(phi, t, x, args, f)  # noqa: E731
                pieces.append(_guard(slide, a, _const(minus), None, None, name + ": λ = 0"))
                pieces.append(_guard(slide, minus_b, _const(plus), None, None, name + ": λ = 1"))
                log += [("RELEASE", name), ("RELEASE", name)]
        for j, surface in enumerate(self.surfaces):
            pieces.append(_lift_surface(surface))
            log.append(("IMPACT", surface.name or f"surface {j}"))
        self._log = tuple(log)
        self._names = tuple(names)
        slides = tuple((mode_index(s.sliding), s.phi) for s in self.switching
                       if s.sliding is not None)
        self.scene = Scene(_moded_field(fields), pieces,
                           project=_onto_sliding_surface(slides) if slides else None)

    @property
    def mode_names(self) -> tuple[str, ...]:
        """All modes, in index order (the given modes, then the sliding modes)."""
        return self._names

    def mode_index(self, name: str) -> int:
        """The index m of mode `name` (the value of the state's last component)."""
        return self._names.index(name)

    def state(self, x, mode: str):
        """The compiled scene's state y = (x, m) for physical state `x` in mode `mode`."""
        x = jnp.asarray(x, float)
        return jnp.concatenate([x, jnp.full((1,), float(self.mode_index(mode)), x.dtype)])

    def start(self, x, mode: str, args=None, t0=0.0):
        """The state to start from in `mode`, with the mode corrected by the switching
        surfaces (outside `jit`).

        A flight never has an event at its start time, so a state on Σ = {Φ = 0} must
        start in the mode it moves into: `plus` if f₊ leaves Σ upward (b > 0), `minus` if
        f₋ leaves it downward (a < 0), else the sliding mode (a ≥ 0 ≥ b). Off Σ the side
        decides. Only the switching surface that has `mode` as a side (or as its sliding
        mode) is looked at; other modes are returned as given.
        """
        x = jnp.asarray(x, float)
        for s in self.switching:
            sides = (s.minus, s.plus, s.sliding)
            if mode not in sides:
                continue
            f_minus = self.modes[self.mode_index(s.minus)].vector_field
            f_plus = self.modes[self.mode_index(s.plus)].vector_field
            t = jnp.asarray(t0, float)
            phi = float(s.phi(t, x, args))
            # On Σ: |Φ| within the contact floor, the loop's own definition (_geometry).
            if not bool(on_surface(s.phi, t, x, args)):
                mode = s.plus if phi > 0 else s.minus
            elif float(_rate(s.phi, t, x, args, f_plus)) > 0:
                mode = s.plus
            elif float(_rate(s.phi, t, x, args, f_minus)) < 0:
                mode = s.minus
            else:
                mode = s.sliding if s.sliding is not None else mode
            break
        return self.state(x, mode)

    @staticmethod
    def split(y):
        """`(x, m)` from a state (or states, along the last axis) of the compiled scene."""
        return y[..., :-1], y[..., -1]

    def mode_of(self, y) -> str:
        """The name of the mode of one state y (outside `jit`)."""
        return self._names[int(round(float(np.asarray(y)[-1])))]

    def events(self, sol, lane: int | None = None) -> list[Event]:
        """The run's impact log as labelled events (outside `jit`; for a batch from
        `jax.vmap`, pass the `lane`).

        Each logged row of `sol` (a `grazejax.Solution` of `.scene`) becomes an
        `grazejax.Event`: `"SLIDE"` when the row enters a sliding mode, `"RELEASE"`
        when it leaves one, `"CROSS"` for a crossing of a switching surface,
        `"TRANSITION"` or `"IMPACT"` otherwise; with the mode names before and after.
        """
        if lane is not None:
            sol = jax.tree.map(lambda leaf: leaf[lane], sol)
        if np.ndim(sol.status) > 0:
            raise ValueError("events() reads one run: pass the lane of a batch (lane=i)")
        sliding = {s.sliding for s in self.switching if s.sliding is not None}
        out = []
        for i in range(int(sol.num_impacts)):
            surface = int(sol.impact_surface[i])
            if surface < 0:
                continue
            label, name = self._log[surface]
            pre, post = np.asarray(sol.impact_pre[i]), np.asarray(sol.impact_post[i])
            source, target = self.mode_of(pre), self.mode_of(post)
            if label == "CROSS" and target in sliding:
                label = "SLIDE"
            out.append(Event(float(sol.impact_times[i]), label, name, source, target,
                             pre[:-1], post[:-1]))
        return out


def _const(k):
    return lambda t, x, args: jnp.asarray(k, x.dtype)


def _choose(target, mode_index):
    if isinstance(target, str):
        return _const(mode_index(target))
    rules = [(cond, mode_index(name)) for cond, name in target]
    if not rules or rules[-1][0] is not None:
        raise ValueError("a Transition's target list must end with a (None, name) default")

    def choose(t, x, args):
        k = jnp.asarray(rules[-1][1], x.dtype)
        for cond, index in reversed(rules[:-1]):
            k = jnp.where(cond(t, x, args), jnp.asarray(index, x.dtype), k)
        return k

    return choose


def _moded_field(fields):
    def vector_field(t, y, args):
        x, m = y[:-1], y[-1]
        k = jnp.clip(jnp.round(m), 0, len(fields) - 1).astype(jnp.int32)
        branches = [lambda t, x, f=f: f(t, x, args) for f in fields]
        dx = jax.lax.switch(k, branches, t, x)
        # The mode is constant along a flight: every stage of a step sees the same m.
        return jnp.concatenate([dx, jnp.zeros((1,), y.dtype)])

    return vector_field


def _filippov_field(phi, f_minus, f_plus):
    def vector_field(t, x, args):
        fm, fp = f_minus(t, x, args), f_plus(t, x, args)
        _, a = jax.jvp(lambda s, y: phi(s, y, args), (t, x), (jnp.ones_like(t), fm))
        _, b = jax.jvp(lambda s, y: phi(s, y, args), (t, x), (jnp.ones_like(t), fp))
        # a − b > 0 throughout a sliding phase (a > 0 > b); it only nears 0 where both
        # fields are tangent, where the exits fire first. Under vmap this field is also
        # evaluated (and discarded) for lanes in other modes, where a − b may vanish:
        # keep those values finite.
        gap = a - b
        lam = a / jnp.where(gap == 0, jnp.ones_like(gap), gap)
        return (1 - lam) * fm + lam * fp

    return vector_field


def _onto_sliding_surface(slides):
    """The compiled scene's `project`: in a sliding mode, x moved back onto its Σ.

    The Filippov field keeps dΦ/dt = 0, so Φ stays where the solver leaves it: constant
    for a linear Φ, but on a curved Σ each step's error adds to it and the state drifts off
    Σ, linearly in the time slid. One Gauss–Newton step x − Φ∇Φ/|∇Φ|² per solver step
    keeps it on Σ to the square of one step's error (Φ is itself of a step's error, so
    one step suffices). Off the sliding modes, x is unchanged."""

    def onto_surface(t, y, args):
        x, m = y[:-1], y[-1]
        out = x
        for k, phi in slides:
            out = jnp.where(m == k, newton_step_to_surface(phi, t, x, args), out)
        return jnp.concatenate([out, y[-1:]])

    def project(t, y, args):
        sliding = functools.reduce(jnp.logical_or, [y[-1] == k for k, _ in slides])
        # A single run computes it only while it slides: inline, XLA fuses a copy of it
        # into each consumer of the step's end state, and every step pays for it.
        return jax.lax.cond(sliding, onto_surface, lambda t, y, args: y, t, y, args)

    return project


def _guard(source, phi, target, jump, where, name):
    """A compiled `Surface` on y = (x, m), live only in mode `source`."""

    def gap(t, y, args):
        x, m = y[:-1], y[-1]
        # Other modes see a constant positive gap: the guard can neither fire nor be
        # approached there, and no dip search looks at it.
        return jnp.where(m == source, phi(t, x, args), jnp.ones((), y.dtype))

    def new_state(t, y, args):
        x = y[:-1]
        x_new = x if jump is None else jnp.asarray(jump(t, x, args), y.dtype)
        return jnp.concatenate([x_new, jnp.reshape(target(t, x, args), (1,))])

    def live(t, y, args):
        ok = y[-1] == source
        return ok if where is None else jnp.logical_and(ok, where(t, y[:-1], args))

    return Surface(phi=gap, jump=new_state, where=live, name=name)


def _lift_surface(surface: Surface) -> Surface:
    def lift(fn):
        return None if fn is None else (lambda t, y, args: fn(t, y[:-1], args))

    def lift_map(fn):
        if fn is None:
            return None
        return lambda t, y, args: jnp.concatenate([fn(t, y[:-1], args), y[-1:]])

    return Surface(phi=lift(surface.phi), jump=lift_map(surface.jump),
                   where=lift(surface.where), inverse_jump=lift_map(surface.inverse_jump),
                   name=surface.name, impenetrable=surface.impenetrable)


@dataclasses.dataclass(frozen=True)
class FieldCheck:
    """What `grazejax.check_field_continuity` found.

    `ok` is False when the vector field jumps along the trajectory away from every event of
    the scene; then `time` is the sample interval `(t_k, t_{k+1})` of the first jump,
    `state` the state at t_k, `jump` the defect of f over the interval (a smooth field
    leaves only O(Δt³)), and `message` says what to do.
    """

    ok: bool
    message: str
    time: tuple[float, float] | None = None
    state: np.ndarray | None = None
    jump: np.ndarray | None = None


def check_field_continuity(scene: Scene, x0, t0, t1, args=None, *, num_samples: int = 1001,
                           throw: bool = True, **simulate_options) -> FieldCheck:
    r"""Check that a scene's vector field is smooth along a trajectory between its events.

    A field written with `sign(Φ)` (or `jnp.where` on the state) has a hidden switching
    surface. `simulate` cannot see it: its Runge–Kutta stages straddle the discontinuity,
    the error estimate no longer measures the error, and accuracy falls by orders of
    magnitude at the same tolerance (the friction oscillator's turning times drift by
    2e-8 per half cycle at rtol = 1e-10 instead of 1e-11), and sticking, where the true
    solution slides on the surface, becomes chattering or ends the run. This check runs
    the scene, samples the field f along the computed trajectory at `num_samples` times,
    and compares f(t_{k+1}) − f(t_k) with the trapezoidal prediction from the Jacobian of
    f; sample intervals holding an event of the scene are skipped (mode changes of a
    `grazejax.PiecewiseScene` are events). A jump is a defect larger than half the
    change of f and than √ε times its size.

    **Arguments:**

    - `scene`, `x0`, `t0`, `t1`, `args`, `simulate_options`: as for `grazejax.simulate`.
    - `num_samples`: sample times; jumps of f smaller than about the O(Δt³) defect of the
      smooth part are not seen.
    - `throw`: raise a `ValueError` naming the fix (default) instead of returning a
      failing `grazejax.FieldCheck`.

    **Returns:** a `grazejax.FieldCheck`.
    """
    ts = jnp.linspace(t0, t1, num_samples)
    sol = simulate(scene, x0, t0, t1, args, saveat=ts, **simulate_options)
    ts_np, xs = np.asarray(sol.ts), np.asarray(sol.xs)
    keep = np.isfinite(ts_np) & np.all(np.isfinite(xs), axis=1)
    ts_np, xs = ts_np[keep], xs[keep]
    field = lambda t, x: scene.vector_field(t, x, args)  # noqa: E731
    fs = np.asarray(jax.vmap(field)(jnp.asarray(ts_np), jnp.asarray(xs)))
    jac = jax.vmap(jax.jacfwd(field, argnums=(0, 1)))(jnp.asarray(ts_np), jnp.asarray(xs))
    ft, fx = np.asarray(jac[0]), np.asarray(jac[1])
    dt, dx = np.diff(ts_np), np.diff(xs, axis=0)
    predicted = 0.5 * (np.einsum("kij,kj->ki", fx[:-1] + fx[1:], dx)
                       + (ft[:-1] + ft[1:]) * dt[:, None])
    change = fs[1:] - fs[:-1]
    defect = np.linalg.norm(change - predicted, axis=1)
    scale = np.max(np.linalg.norm(fs, axis=1)) if len(fs) else 0.0
    events = np.asarray(sol.impact_times)[: int(sol.num_impacts)]
    has_event = np.zeros(len(dt), bool)
    for time in events:
        has_event |= (ts_np[:-1] <= time) & (time <= ts_np[1:])
    jumps = ((defect > 0.5 * np.linalg.norm(change, axis=1))
             & (defect > np.sqrt(np.finfo(float).eps) * max(scale, 1.0)) & ~has_event)
    if not np.any(jumps):
        return FieldCheck(True, "the vector field is smooth between the scene's events")
    k = int(np.argmax(jumps))
    message = (
        f"the vector field jumps by {change[k]} between t = {ts_np[k]:.12g} and "
        f"{ts_np[k + 1]:.12g} (state {xs[k]}), where the scene has no event: it switches "
        "on a surface that the scene does not declare (sign(·), abs(·)' or jnp.where on the "
        "state). Runge–Kutta stages then straddle the switch and the run loses accuracy "
        "(and cannot slide on the surface). Fix: declare the surface and one mode per side "
        "with grazejax.PiecewiseScene(modes, switching=[grazejax.SwitchingSurface(phi, "
        "minus=..., plus=..., sliding=...)]) (docs/piecewise.md)."
    )
    if throw:
        raise ValueError("grazejax.check_field_continuity: " + message)
    return FieldCheck(False, message, (float(ts_np[k]), float(ts_np[k + 1])), xs[k], change[k])
