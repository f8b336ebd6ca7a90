"""Poincaré sections through impacts: stroboscopic points, impact maps and user sections
(`grazejax.poincare`).

A section is read off one run of the impact loop, never by a loop of short runs:

- **stroboscopic** (`period=T`): the states saved at t0 + transient + kT (`saveat`);
- **impact map** (`surface=i`): the post-impact states x(θ+) logged at surface i, run with
  `t1 = inf` until `max_impacts`;
- **user section** (`section=h`): the crossings of h(t, x, args) = 0 are events *without*
  jumps. They are located by the loop exactly as impacts are (crossings and in-step dips,
  a landing step, then a Newton step on the event time: docs/semantics.md), on an extra
  surface piece Φ = ±h whose jump is the identity (`Surface.probe`'s law), marked
  penetrable: the free side of an impact surface is Φ > 0 and only a *decreasing* Φ
  triggers, so Φ = h gives the crossings with h decreasing, Φ = −h those with h
  increasing, and the other direction passes through untouched. The identity jump leaves
  the state as it is; only the step sequence restarts at the crossing, so the trajectory
  changes by no more than the solver's tolerance (tested).

The three kinds are strategies (`_Stroboscopic`, `_ImpactMap`, `_Crossings`): each says
which scene to run, until when, at which times to save, and how to read its points from
the run. The caller never branches on the kind.
"""

from __future__ import annotations

import abc
import dataclasses
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._compiler import compiler_options
from .._scene import Scene, Surface, identity_jump
from .._simulate import SIMULATE_OPTIONS, numeric_options, simulate
from .._solution import Solution
from .._status import ImpactKind, Status
from .._validate import is_concrete, validate_inputs

# --------------------------------------------------------------------------------------
# The result
# --------------------------------------------------------------------------------------


class Section(eqx.Module):
    r"""Points of a Poincaré section (`grazejax.poincare`). Batched calls add a leading
    batch axis to every field.

    **Fields:**

    - `points`: the section points, shape `(num_points, n)`: x(t0 + transient + kT)
      (stroboscopic), the post-impact states x(θ+) at the surface (impact map), or the
      states at the crossings of h = 0 (user section). A point the run did not reach is a
      row of NaN, never zeros.
    - `times`: their times (NaN where missing).
    - `status`: per point, a `grazejax.Status` code: `SUCCESS` where the point was found,
      otherwise why the run stopped before it (`MAX_IMPACTS`: the impact budget ran out;
      raise `max_impacts`. `ZENO`, `MAX_STEPS`, `NONFINITE`, `BAD_START`, ...).
    - `run_status`: the status of the whole run (`grazejax.Status`). Impact maps and user
      sections run until `max_impacts`, so `MAX_IMPACTS` is their normal end.
    - `num_events`: rows of the run's impact log used (impacts, crossings of h included).
    """

    points: Float[Array, "num_points n"]
    times: Float[Array, " num_points"]
    status: Int[Array, " num_points"]
    run_status: Int[Array, ""]
    num_events: Int[Array, ""]

    @property
    def found(self) -> Bool[Array, " num_points"]:
        """Which points were found (`status == SUCCESS`)."""
        return self.status == Status.SUCCESS


# --------------------------------------------------------------------------------------
# The kinds of section
# --------------------------------------------------------------------------------------


class _AbstractSectionKind(eqx.Module):
    """How one kind of section runs and reads its points (all fields static)."""

    @abc.abstractmethod
    def scene_for(self, scene: Scene) -> Scene:
        """The scene to run (the user's, or the user's with extra event surfaces)."""

    @abc.abstractmethod
    def end_time(self, t_start, period, num_points: int):
        """`t1` of the run."""

    @abc.abstractmethod
    def save_times(self, t_start, period, num_points: int):
        """`saveat` of the run (None: no dense output compiled)."""

    @abc.abstractmethod
    def pick(self, sol: Solution, t_start, period, num_points: int):
        """`(points, times, found)` read from the run."""


class _Stroboscopic(_AbstractSectionKind):
    """x(t_start + kT), k = 1..num_points, from the run's saved states."""

    def scene_for(self, scene):
        return scene

    def end_time(self, t_start, period, num_points):
        return t_start + num_points * period

    def save_times(self, t_start, period, num_points):
        return t_start + period * jnp.arange(1, num_points + 1, dtype=jnp.result_type(float))

    def pick(self, sol, t_start, period, num_points):
        # Saves after the run stopped (MAX_IMPACTS, ZENO, a failure) are NaN (simulate).
        found = jnp.all(jnp.isfinite(sol.xs), axis=-1)
        times = jnp.where(found, self.save_times(t_start, period, num_points), jnp.nan)
        return sol.xs, times, found


class _ImpactMap(_AbstractSectionKind):
    """Post-impact states logged at the surfaces `surfaces`, from t_start on."""

    surfaces: tuple[int, ...] = eqx.field(static=True)

    def scene_for(self, scene):
        return scene

    def end_time(self, t_start, period, num_points):
        return jnp.inf

    def save_times(self, t_start, period, num_points):
        return None

    def pick(self, sol, t_start, period, num_points):
        return logged_points(sol, self.surfaces, t_start, num_points)


@dataclasses.dataclass(frozen=True)
class _Gap:
    """Φ = sign · h as a hashable callable: equal sections give equal scenes, and so one
    compiled program (a fresh lambda per call would compile the run again every time)."""

    section: Callable
    sign: int

    def __call__(self, t, x, args):
        return self.sign * self.section(t, x, args)


class _Crossings(_AbstractSectionKind):
    """Crossings of h = 0 in `direction`, as identity-jump events appended to the scene
    after its `first_probe` surfaces."""

    section: Callable = eqx.field(static=True)
    direction: int = eqx.field(static=True)
    first_probe: int = eqx.field(static=True)

    def _signs(self) -> tuple[int, ...]:
        # Φ = h triggers where h decreases (direction −1); Φ = −h where it increases.
        return {-1: (1,), 1: (-1,), 0: (1, -1)}[self.direction]

    def scene_for(self, scene):
        probes = [Surface(phi=_Gap(self.section, s), jump=identity_jump, name="section")
                  for s in self._signs()]
        return scene.with_surfaces((*scene.surfaces, *probes))

    def end_time(self, t_start, period, num_points):
        return jnp.inf

    def save_times(self, t_start, period, num_points):
        return None

    def pick(self, sol, t_start, period, num_points):
        probes = tuple(range(self.first_probe, self.first_probe + len(self._signs())))
        return logged_points(sol, probes, t_start, num_points)


def logged_points(sol: Solution, surfaces: tuple[int, ...], t_start, num_points: int):
    """The first `num_points` logged post-impact states at `surfaces` with θ ≥ t_start.

    Rows of sliding starts and ends (`zeno="stick"`: `STICK`, `RELEASE`) are not impacts
    and are skipped. Returns `(points, times, found)`, NaN where fewer were logged.
    """
    rows = sol.impact_surface.shape[-1]
    at_surface = jnp.zeros(rows, bool)
    for index in surfaces:
        at_surface = at_surface | (sol.impact_surface == index)
    keep = (
        at_surface
        & (jnp.arange(rows) < sol.num_impacts)
        & (sol.impact_kind <= ImpactKind.GAMMA_PRIME)
        & (sol.impact_times >= t_start)
    )
    (index,) = jnp.nonzero(keep, size=num_points, fill_value=rows)
    found = index < rows
    index = jnp.minimum(index, rows - 1)
    points = jnp.where(found[:, None], sol.impact_post[index], jnp.nan)
    times = jnp.where(found, sol.impact_times[index], jnp.nan)
    return points, times, found


# --------------------------------------------------------------------------------------
# One lane: one run, its points
# --------------------------------------------------------------------------------------


def section_lane(scene: Scene, kind: _AbstractSectionKind, num_points: int, options: dict,
                 x0, t0, transient, args, period) -> Section:
    """One run from (t0, x0) and its section points (traceable: under `jit`, `vmap` and
    inside `lax.scan`; forward time, `direction=1`)."""
    t_start = t0 + transient
    sol = simulate(kind.scene_for(scene), x0, t0, kind.end_time(t_start, period, num_points), args,
                   saveat=kind.save_times(t_start, period, num_points), direction=1,
                   **options)
    points, times, found = kind.pick(sol, t_start, period, num_points)
    status = jnp.where(found, jnp.asarray(Status.SUCCESS, sol.status.dtype), sol.status)
    return Section(points=points, times=times, status=status, run_status=sol.status,
                   num_events=sol.num_impacts)


_COMPILED: dict = {}


def compiled_lanes(scene, kind, num_points: int, options: dict, in_axes_args, batched: bool):
    """`section_lane` jitted (and vmapped over lanes when `batched`), once per static
    configuration: numbers (x0, t0, transient, args, period) are inputs."""
    is_none = lambda v: v is None  # noqa: E731
    # The tolerances are inputs too: a new rtol does not compile the program again.
    numbers = numeric_options(options)
    static = {name: value for name, value in options.items() if name not in numbers}
    key = (scene, kind, num_points, tuple(sorted(static.items())), tuple(sorted(numbers)),
           batched, jax.tree.structure(in_axes_args, is_leaf=is_none),
           tuple(jax.tree.leaves(in_axes_args, is_leaf=is_none)))
    run = _COMPILED.get(key)
    if run is None:
        def lane(x0, t0, transient, args, period, numbers):
            return section_lane(scene, kind, num_points, {**static, **numbers}, x0, t0,
                                transient, args, period)

        if batched:
            lane = jax.vmap(lane, in_axes=(0, None, None, in_axes_args, 0, None))
        run = jax.jit(lane, compiler_options=compiler_options(batched=batched))
        _COMPILED[key] = run
    return lambda x0, t0, transient, args, period: run(x0, t0, transient, args, period, numbers)


# --------------------------------------------------------------------------------------
# poincare
# --------------------------------------------------------------------------------------

_NOT_OPTIONS = {"saveat": "the section chooses its saves",
                "direction": "sections run forward in time ('direction' here is the crossing "
                             "direction of `section`)",
                "throw": "each point carries its status"}


def section_kind(scene: Scene, period, surface, section, direction) -> _AbstractSectionKind:
    """The kind of section asked for (exactly one of `period`, `surface`, `section`)."""
    given = [name for name, v in (("period", period), ("surface", surface),
                                  ("section", section)) if v is not None]
    if len(given) != 1:
        raise ValueError(f"pass exactly one of period=, surface=, section= (got {given or 'none'})")
    if surface is not None:
        if not isinstance(surface, (int, np.integer)) or not 0 <= surface < len(scene.surfaces):
            raise ValueError(f"surface must be an index into scene.surfaces (0..."
                             f"{len(scene.surfaces) - 1}), got {surface!r}")
        return _ImpactMap(surfaces=(int(surface),))
    if section is not None:
        if not callable(section):
            raise TypeError("section must be a function h(t, x, args) -> scalar")
        if direction not in (-1, 0, 1):
            raise ValueError(f"direction must be -1, +1 or 0, got {direction!r}")
        return _Crossings(section=section, direction=int(direction),
                          first_probe=len(scene.surfaces))
    return _Stroboscopic()


def run_options(simulate_options: dict, num_points: int) -> dict:
    """simulate's options for a section run, checked; `max_impacts` defaults to
    2·num_points + 64 (impact maps and user sections run until it)."""
    unknown = set(simulate_options) - set(SIMULATE_OPTIONS)
    if unknown:
        raise TypeError(f"unknown simulate options: {sorted(unknown)}")
    for name, why in _NOT_OPTIONS.items():
        if name in simulate_options:
            raise TypeError(f"{name}= is not an option of a section run: {why}")
    options = dict(simulate_options)
    options.setdefault("max_impacts", 2 * int(num_points) + 64)
    return options


def poincare(
    scene: Scene,
    x0,
    t0,
    args=None,
    *,
    period=None,
    surface: int | None = None,
    section: Callable | None = None,
    direction: int = -1,
    num_points: int,
    transient=0.0,
    args_batched=None,
    chunk_size: int | None = None,
    **simulate_options,
) -> Section:
    r"""Points of a Poincaré section of one run (or a batch of runs) through the impacts.

    Exactly one of `period`, `surface`, `section` chooses the section:

    - `period=T`: **stroboscopic** points x(t0 + transient + kT), k = 1..num_points (the
      saved states of one run; at an impact time, the pre-impact state, as `saveat`).
    - `surface=i`: the **impact map**: the post-impact states x(θ+) at surface i (index in
      `scene.surfaces`) with θ ≥ t0 + transient, in time order. The run goes on until
      `max_impacts` impacts of *all* surfaces (`t1 = inf`). Sliding starts and ends
      (`zeno="stick"`) are not points.
    - `section=h`, a function `h(t, x, args) -> scalar`: the **crossings of h = 0** with
      θ ≥ t0 + transient, located as events (root of h on the step's dense output, then a
      landing step and a Newton step on the crossing time, as for impacts) in `direction`:
      −1 where h decreases (default), +1 where it increases, 0 both. A tangential touch of
      h = 0 (within the contact floor, docs/semantics.md) counts as a crossing. Crossings
      and impacts share the impact log, so `max_impacts` bounds both. Pass the same
      function object to reuse the compiled program (a fresh `lambda` per call compiles
      the run again).

    **Arguments:**

    - `scene`, `x0`, `t0`, `args`: as `grazejax.simulate` (forward time only).
      `x0` of shape `(batch, n)`, or `args` leaves marked in `args_batched`, run a batch:
      one vmapped program, in chunks of `chunk_size` lanes (memory bounded by a chunk).
    - `num_points`: points per run.
    - `transient`: time skipped before the first point.
    - `args_batched`: a pytree of bools with the structure of `args` (default: with a 2-D
      `x0`, a leaf is batched iff its leading axis equals the batch size, as in
      `grazejax.sweep`; with a 1-D `x0`, no leaf is).
    - `chunk_size`: lanes per compiled call (default: the whole batch, up to 65536).
    - `**simulate_options`: `grazejax.simulate`'s options (`rtol`, `atol`, `solver`,
      `max_impacts`, `max_steps`, `zeno`, ...), except `saveat`, `direction` and `throw`.
      `max_impacts` (default 2·num_points + 64) is the run's budget of events: an impact
      map or a user section runs until it (so its cost is `max_impacts` events: size it
      as the events during the transient plus num_points times the events per point), and
      a stroboscopic run that meets more impacts stops there too.

    One run (1-D `x0`, no batched args) is one compiled program that works under
    `jax.jit` and `jax.jacfwd`: the derivative of the points with respect to `x0` or `args`
    is that of the run, saltation matrices included (the tangent map of the section).

    **Returns:** a `grazejax.Section` (of JAX arrays for one run; of NumPy arrays with a
    leading batch axis for a batch). A point the run did not reach (the impact budget ran
    out, Zeno, a failure) is a row of NaN with that reason as its `status`: never zeros,
    never a silent number.

    **Example:**

    ```python
    import jax.numpy as jnp
    import grazejax as gj
    from grazejax import examples as ex

    ball = ex.bouncing_ball()
    points = gj.poincare(ball, jnp.array([1.0, 0.0]), 0.0, {"g": 9.81, "e": 1.0},
                         surface=0, num_points=3)
    print(points.times)   # 0.4515, 1.3546, 2.2577: t1 = √(2h/g), then every 2√(2h/g)
    ```
    """
    kind = section_kind(scene, period, surface, section, direction)
    options = run_options(simulate_options, num_points)
    period = jnp.nan if period is None else period
    x0 = np.asarray(x0, dtype=np.float64) if not isinstance(x0, jax.Array) else x0
    if x0.ndim == 1 and args_batched is None:
        return _single(scene, kind, int(num_points), options, x0, t0, transient, args, period)
    in_axes_args, batch = _batch_layout(x0, args, args_batched)
    periods = np.broadcast_to(np.asarray(period, dtype=np.float64), (batch,))
    return run_batched(scene, kind, int(num_points), options, x0, t0, transient, args,
                       in_axes_args, periods, chunk_size)


def _single(scene, kind, num_points, options, x0, t0, transient, args, period) -> Section:
    """One run, in one compiled program (the run and the reading of its points)."""
    if is_concrete(x0, t0, args):
        # simulate's own checks of shapes, types and options, where their values are known.
        validate_inputs(kind.scene_for(scene), x0, t0, jnp.inf, args,
                        max_impacts=options["max_impacts"],
                        max_steps=options.get("max_steps", 100_000), direction=1,
                        allow_float32=options.get("allow_float32", False), saveat=None)
    run = compiled_lanes(scene, kind, num_points, options, None, batched=False)
    return run(jnp.asarray(x0), jnp.asarray(t0, float), jnp.asarray(transient, float), args,
               jnp.asarray(period, float))


def _batch_layout(x0, args, args_batched):
    """`(in_axes of args, batch size)` of a batched call (sweep's rules)."""
    flags = args_batched
    if flags is None:
        batch = x0.shape[0]
        flags = jax.tree.map(lambda leaf: np.ndim(leaf) >= 1 and np.shape(leaf)[0] == batch,
                             args)
    sizes = {np.shape(leaf)[0] for leaf, b in zip(jax.tree.leaves(args), jax.tree.leaves(flags),
                                                   strict=True) if b}
    if x0.ndim == 2:
        sizes.add(x0.shape[0])
    elif x0.ndim != 1:
        raise ValueError(f"x0 must have shape (n,) or (batch, n), got {x0.shape}")
    if len(sizes) != 1:
        raise ValueError(f"mismatched or missing batch sizes: {sorted(sizes)}")
    return jax.tree.map(lambda b: 0 if b else None, flags), sizes.pop()


def run_batched(scene, kind, num_points, options, x0, t0, transient, args, in_axes_args,
                periods, chunk_size=None) -> Section:
    """All lanes through one vmapped program, chunk by chunk (every chunk padded to one
    shape, so that it compiles once). Returns NumPy fields with a leading batch axis."""
    batch = len(periods)
    chunk = min(batch, 65536) if chunk_size is None else int(chunk_size)
    if chunk <= 0:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    chunk = min(chunk, batch)
    x0s = np.broadcast_to(np.asarray(x0, np.float64), (batch, np.shape(x0)[-1]))
    run = compiled_lanes(scene, kind, num_points, options, in_axes_args, batched=True)
    pieces = []
    for start in range(0, batch, chunk):
        index = np.arange(start, min(start + chunk, batch))
        padded = np.concatenate([index, np.full(chunk - len(index), index[0])])
        out = run(x0s[padded], jnp.asarray(t0, float), jnp.asarray(transient, float),
                  _lanes_of(args, in_axes_args, padded), periods[padded])
        pieces.append(_first_lanes(out, len(index)))
    return jax.tree.map(lambda *leaves: np.concatenate(leaves, axis=0), *pieces)


def _lanes_of(args, in_axes_args, lanes):
    """The batched leaves of `args` at `lanes`; the others as they are."""
    return jax.tree.map(lambda leaf, axis: np.asarray(leaf)[lanes] if axis == 0 else leaf,
                        args, in_axes_args, is_leaf=lambda v: v is None)


def _first_lanes(out, count: int):
    """A chunk's result without its padding, on the host."""
    return jax.tree.map(lambda leaf: np.asarray(leaf)[:count], out)
