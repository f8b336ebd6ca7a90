"""Brute-force orbit diagrams: section points against a parameter, with the period of each
point sequence detected by recurrence (`grazejax.orbit_diagram`)."""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._compiler import compiler_options
from .._scene import Scene
from .._simulate import SIMULATE_OPTIONS
from .._status import Status
from .sections import Section, run_batched, run_options, section_kind, section_lane

RECURRENCE_FACTOR = 1e3
"""Default recurrence tolerance, in units of the solver's error budget rtol·|x| + atol.

Two section points of a converged periodic orbit differ by the solver's error in each map
(a few hundred local errors ~ rtol·|x| + atol per point: the numerical map is close to the
true one, not equal) plus what is left of the transient. 1e3 such errors separate that
from a true difference between points of a period-doubled or chaotic sequence for any
attractor resolved by the tolerance; where the transient has not died down below it
(slow convergence near a bifurcation, where a multiplier approaches the unit circle) the
period is reported as 0, not guessed."""


class OrbitDiagram(eqx.Module):
    r"""Section points against a parameter (`grazejax.orbit_diagram`).

    **Fields:**

    - `mu`: the parameter values, shape `(m,)`.
    - `points`: the section points of each μ, `(m, num_points, n)` (rows of NaN where a
      point was not reached).
    - `times`: their times, `(m, num_points)`.
    - `period`: the detected period of each μ's point sequence: the smallest p ≥ 1 with
      |x_{k+p} − x_k| ≤ `tolerance` (every coordinate) for every k, tried up to
      num_points // 2 (so that each point recurs at least once); 0 when none is found
      (chaos, quasi-periodicity, a transient not yet decayed, or points missing).
    - `tolerance`: the recurrence tolerance per μ and coordinate, `(m, n)`:
      `recurrence_factor · (rtol · max_k |x_k| + atol)` (see `RECURRENCE_FACTOR`).
    - `status`: per μ, a `grazejax.Status` code: `SUCCESS` when all points were found,
      otherwise the status of the first missing point (why its run stopped before it).
    - `section`: the underlying `grazejax.Section` (batch axis = μ).
    """

    mu: Float[Array, " m"]
    points: Float[Array, "m num_points n"]
    times: Float[Array, "m num_points"]
    period: Int[Array, " m"]
    tolerance: Float[Array, "m n"]
    status: Int[Array, " m"]
    section: Section


def detect_period(points, tolerance) -> int:
    """The smallest p with |x_{k+p} − x_k| ≤ tolerance for all k (p ≤ N // 2), else 0.

    `points` is one sequence, `(N, n)`; a sequence with a NaN row has no period (0).
    """
    points = np.asarray(points)
    if not np.all(np.isfinite(points)):
        return 0
    for p in range(1, len(points) // 2 + 1):
        if np.all(np.abs(points[p:] - points[:-p]) <= tolerance):
            return p
    return 0


def recurrence_tolerance(points, rtol: float, atol: float, factor: float):
    """factor · (rtol · max_k |x_k| + atol) per coordinate of one sequence `(N, n)`."""
    scale = np.nanmax(np.abs(np.asarray(points)), axis=0, initial=0.0)
    return factor * (rtol * scale + atol)


def _first_missing_status(status) -> np.ndarray:
    """Per sequence: SUCCESS if every point was found, else the first missing point's."""
    status = np.asarray(status)
    missing = status != Status.SUCCESS
    first = np.argmax(missing, axis=-1)
    return np.where(missing.any(axis=-1), np.take_along_axis(status, first[:, None], -1)[:, 0],
                    int(Status.SUCCESS))


def _stack_args(args_of: Callable, mus: np.ndarray):
    """args_of(μ) for every μ, stacked leaf by leaf (leading axis: μ)."""
    trees = [args_of(mu) for mu in mus]
    return jax.tree.map(lambda *leaves: np.stack([np.asarray(v) for v in leaves]), *trees)


def orbit_diagram(
    scene: Scene,
    x0,
    args_of: Callable,
    mus,
    *,
    t0=0.0,
    period=None,
    surface: int | None = None,
    section: Callable | None = None,
    direction: int = -1,
    num_points: int,
    transient,
    continue_state: bool = False,
    recurrence_factor: float = RECURRENCE_FACTOR,
    chunk_size: int | None = None,
    **simulate_options,
) -> OrbitDiagram:
    r"""A brute-force orbit (bifurcation) diagram: for each μ, the points of a Poincaré
    section after a transient, and the period of their sequence.

    **Arguments:**

    - `scene`: a `grazejax.Scene`.
    - `x0`: the start, `(n,)` for every μ or `(len(mus), n)`, one per μ.
    - `args_of`: `args_of(mu) -> args`, the scene's parameters at μ.
    - `mus`: the parameter values, 1-D.
    - `t0`: start time.
    - `period`, `surface`, `section`, `direction`: the section, as `grazejax.poincare`.
      `period` may also be a function of μ (a forcing period that changes with μ).
    - `num_points`: points per μ (the period is looked for up to `num_points // 2`).
    - `transient`: time skipped before the first point of each μ.
    - `continue_state`: `False` (default): every μ runs from `x0` at `t0`, all μ as lanes
      of one vmapped program (in chunks of `chunk_size`). `True`: μ in the given order,
      each from the previous μ's last point (state and time; a `lax.scan`, one program),
      as one sweeps a parameter slowly in an experiment, to follow one attractor through
      hysteresis. A μ whose last point is missing hands on the start it got. Starting an
      impact map at the last post-impact state needs a surface that does not move with μ
      (otherwise that state may lie inside it for the next μ: `BAD_START`).
      `args_of` must then be traceable (jnp, not math).
    - `recurrence_factor`: the recurrence tolerance in units of rtol·|x| + atol
      (`RECURRENCE_FACTOR`, 1e3).
    - `**simulate_options`: `grazejax.simulate`'s options, as `grazejax.poincare`.

    **Returns:** a `grazejax.OrbitDiagram`. Points that a run did not reach are NaN with
    their reason in `diagram.section.status`; such a μ has `period` 0 and a non-success
    `status`.

    **Example:**

    ```python
    import math
    import grazejax as gj
    from grazejax import examples as ex

    omega, g = 2 * math.pi, 9.81
    args_of = lambda gamma: dict(g=g, e=0.5, A=gamma * g / omega**2, omega=omega)
    diagram = gj.orbit_diagram(ex.vibrating_table(), [0.2, 4.0], args_of, [1.3, 1.6],
                               surface=0, num_points=8, transient=60.0, max_impacts=96)
    print(diagram.period)   # [1 2]: the period doubling is at Γ_PD(e = 0.5) = 1.5268
    ```
    """
    mus = np.asarray(mus, dtype=np.float64)
    if mus.ndim != 1 or len(mus) == 0:
        raise ValueError(f"mus must be a non-empty 1-D array, got shape {mus.shape}")
    kind = section_kind(scene, 1.0 if period is not None else None, surface, section, direction)
    options = run_options(simulate_options, num_points)
    periods = _periods(period, mus)
    x0 = np.asarray(x0, dtype=np.float64)
    if continue_state and x0.ndim != 1:
        raise ValueError("continue_state=True starts the first μ from x0: pass one state (n,)")
    if continue_state:
        result = _continued(scene, kind, int(num_points), options, x0, t0, transient, args_of,
                            mus, periods)
    else:
        args = _stack_args(args_of, mus)
        in_axes_args = jax.tree.map(lambda _: 0, args)
        result = run_batched(scene, kind, int(num_points), options, x0, t0, transient, args,
                             in_axes_args, periods, chunk_size)
    return _diagram(mus, result, options, recurrence_factor)


def _periods(period, mus) -> np.ndarray:
    """The stroboscopic period of each μ (NaN for the other kinds of section)."""
    if period is None:
        return np.full(len(mus), np.nan)
    if callable(period):
        return np.asarray([float(period(mu)) for mu in mus])
    return np.full(len(mus), float(period))


def _diagram(mus, section: Section, options: dict, factor: float) -> OrbitDiagram:
    """Periods and statuses per μ from the section points."""
    rtol = float(options.get("rtol", SIMULATE_OPTIONS["rtol"]))
    atol = float(options.get("atol", SIMULATE_OPTIONS["atol"]))
    points = np.asarray(section.points)
    tolerance = np.stack([recurrence_tolerance(p, rtol, atol, factor) for p in points])
    period = np.array([detect_period(p, tol) for p, tol in zip(points, tolerance, strict=True)])
    return OrbitDiagram(
        mu=jnp.asarray(mus), points=jnp.asarray(points), times=jnp.asarray(section.times),
        period=jnp.asarray(period), tolerance=jnp.asarray(tolerance),
        status=jnp.asarray(_first_missing_status(section.status)), section=section,
    )


_CONTINUED: dict = {}


def _continued(scene, kind, num_points, options, x0, t0, transient, args_of, mus, periods):
    """μ in order, each run from the previous μ's last point: one `lax.scan` program."""
    key = (scene, kind, num_points, tuple(sorted(options.items())), args_of)
    run = _CONTINUED.get(key)
    if run is None:
        def one_mu(carry, inputs):
            x_start, t_start = carry
            mu, period = inputs
            out = section_lane(scene, kind, num_points, options, x_start, t_start, transient,
                               args_of(mu), period)
            last_ok = out.status[-1] == Status.SUCCESS
            carry = (jnp.where(last_ok, out.points[-1], x_start),
                     jnp.where(last_ok, out.times[-1], t_start))
            return carry, out

        def scan(x0, t0, mus, periods):
            return jax.lax.scan(one_mu, (x0, t0), (mus, periods))[1]

        run = jax.jit(scan, compiler_options=compiler_options(batched=False))
        _CONTINUED[key] = run
    return jax.tree.map(np.asarray, run(jnp.asarray(x0), jnp.asarray(t0, float),
                                        jnp.asarray(mus), jnp.asarray(periods)))
