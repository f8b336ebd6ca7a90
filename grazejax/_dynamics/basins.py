r"""Attractors and their basins of attraction through impacts, by brute force on a
Poincaré section (`grazejax.basins`).

Every start runs once (a lane of one vmapped program, `grazejax.poincare`'s), and its
section points after a transient are classified on the host, chunk by chunk, so that only
the labels and the table of attractors outlive a chunk (10⁶ starts in bounded memory):

- **recurrences** (default), the simplest sound form of the recurrences mapper of
  Attractors.jl (Datseris & Wagemakers 2022, *Chaos* 32, 023104): a start's point sequence
  is periodic with period p when every point recurs p maps later within the recurrence
  tolerance (`orbit_diagram`'s test) and its recurrence steps have settled (they shrink
  geometrically towards a limit, or are noise: a slow drift along a nearly neutral family
  is not an attractor). Its cycle, the last p points, is matched
  against the known attractors (same period, all points within tolerance up to a cyclic
  shift) or becomes a new attractor.
- **features** (`features=fn`), the featurizing mapper in its simplest form: a feature
  vector per start, grouped by leader clustering with a per-coordinate radius.

Attractors are numbered in the order of the first start that reaches them, whatever the
chunks: the labels do not depend on `chunk_size`.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Float, Int

from .._scene import Scene
from .._simulate import SIMULATE_OPTIONS
from .._status import Status, StatusCode
from .orbit_diagram import RECURRENCE_FACTOR
from .sections import Section, run_batched, run_options, section_kind

_DEFAULT_CHUNK = 65536


class BasinStatus(StatusCode):
    """Why a start has the label it has (`Basins.status`). Every code but `ATTRACTOR`
    comes with the label −1: such a start counts in no basin."""

    ATTRACTOR = 0, "the section points settled on an attractor (recurrence or feature group)"
    """The start's label is its attractor's index."""
    UNDECIDED = (
        1,
        "every point was found, but no settled recurrence within num_points (or no finite "
        "feature)",
    )
    """Chaos, quasi-periodicity, a cycle longer than num_points // 2, a transient too slow
    for the recurrence tolerance, or a sequence that recurs but still drifts (its
    recurrence steps do not shrink: a nearly neutral family): raise `transient` or
    `num_points` to decide more."""
    DIVERGED = 2, "a section point left the box |x_i| <= bound"
    """Only with `bound=`: some section point has a coordinate beyond it."""
    FAILED = 3, "the run stopped before its last section point (see run_status)"
    """The run ended before `num_points` points (`MAX_IMPACTS`, `ZENO`, `MAX_STEPS`,
    `NONFINITE`, ...): `Basins.run_status` says which."""


class Attractor(eqx.Module):
    r"""One attractor found by `grazejax.basins`.

    **Fields:**

    - `points`: its points on the section, `(period, n)`: the cycle, shifted so that it
      starts from its lexicographically smallest point. With `features=`, the cycle of the
      group's first start if its sequence recurred, otherwise that start's last point.
    - `period`: the number of section maps per cycle (0: none detected, features only).
    - `tolerance`: the per-coordinate tolerance the cycle was matched with, `(n,)`; with
      `features=`, the grouping radius, `(d,)`.
    - `feature`: with `features=`, the group's leader feature vector; otherwise `None`.
    - `first_start`: the index of the first start that reached it.
    """

    points: Float[np.ndarray, "period n"]
    period: int
    tolerance: Float[np.ndarray, " n"]
    feature: Float[np.ndarray, " d"] | None
    first_start: int


class Basins(eqx.Module):
    r"""Attractors and basins of attraction (`grazejax.basins`).

    **Fields:**

    - `labels`: per start, the index of its attractor in `attractors`, or −1 when the start
      is in no basin: undecided, diverged or failed (see `status`).
    - `attractors`: a tuple of `grazejax.Attractor`, one per label.
    - `fractions`: per label, the fraction of *all* starts in its basin (the basin
      stability S, Menck et al. 2013). Starts labelled −1 count in the total only, so the
      fractions add up to 1 − `num_undecided` / N.
    - `standard_errors`: per label, √(S(1 − S)/N), the standard error of S as an estimate
      of a basin's volume fraction from N random starts (binomial sampling).
    - `status`: per start, a `grazejax.BasinStatus` code.
    - `run_status`: per start, a `grazejax.Status`: `SUCCESS` when every section point was
      found, otherwise the status of the first missing point (why the run stopped).
    - `period`: per start, the detected period of its point sequence (0: none).
    - `tolerance`: the recurrence tolerance per coordinate that was used, `(N, n)` with
      recurrences, `(N, d)` (the grouping radius) with features.
    """

    labels: Int[np.ndarray, " N"]
    attractors: tuple[Attractor, ...]
    fractions: Float[np.ndarray, " k"]
    standard_errors: Float[np.ndarray, " k"]
    status: Int[np.ndarray, " N"]
    run_status: Int[np.ndarray, " N"]
    period: Int[np.ndarray, " N"]
    tolerance: Float[np.ndarray, "N d"]

    @property
    def num_undecided(self) -> int:
        """The number of starts labelled −1 (undecided, diverged or failed)."""
        return int(np.count_nonzero(self.labels < 0))

    @property
    def num_attractors(self) -> int:
        """The number of attractors found (labels 0 .. num_attractors − 1)."""
        return len(self.attractors)


# --------------------------------------------------------------------------------------
# Recurrences: periods, cycles, matching
# --------------------------------------------------------------------------------------


def recurrence_periods(points, tolerance) -> np.ndarray:
    """Per sequence, the smallest p ≤ N // 2 with |x_{k+p} − x_k| ≤ tolerance for all k,
    else 0 (`orbit_diagram.detect_period`, vectorised over a chunk). `points` is
    `(B, N, n)`, `tolerance` `(B, n)`; a sequence with a NaN row has period 0."""
    points = np.asarray(points)
    period = np.zeros(points.shape[0], dtype=np.int64)
    for p in range(1, points.shape[1] // 2 + 1):
        close = np.abs(points[:, p:] - points[:, :-p]) <= tolerance[:, None, :]
        period = np.where((period == 0) & close.all(axis=(1, 2)), p, period)
    return period


NOISE_FRACTION = 1e-2
"""Recurrence steps |x_{k+p} − x_k| below this fraction of the recurrence tolerance (that is,
below 10·(rtol·|x| + atol) at the default factor) are the solver's noise: such a sequence
has settled, whatever the trend of its steps."""

DRIFT_DISTANCE = 30.0
"""A recurrent sequence whose extrapolated distance to its limit exceeds this many
recurrence tolerances is drifting, not settled (`settled`). Between the two cases met in
the tests: a cycle converging with multipliers of modulus up to ~0.97 (the vibrating
table's period-1 orbit near its period doubling: estimates up to 5 tolerances), and
ex1dof's circles drifting at ε = 1e-4 (over 500 tolerances, most of them infinite)."""


def settled(points, period, tolerance) -> np.ndarray:
    """Whether each recurrent sequence has settled, not merely drifted less than the
    tolerance per map.

    A sequence that converges to a cycle has recurrence steps e_k = |x_{k+p} − x_k| (in
    units of the tolerance) that shrink geometrically, e_k ≈ e_0 ρ^k, and its last points
    lie within e_last·ρ/(1 − ρ) of the limit. Along a nearly neutral family (a slowly
    drifting amplitude, as ex1dof's circles at small ε) the steps do not shrink and that
    distance is unbounded, although each step is below the tolerance. ρ is estimated from
    the largest step of the first and of the second half of the steps (a rough estimate:
    steps of a complex pair of multipliers oscillate); a sequence has settled when its
    last steps are noise (`NOISE_FRACTION`) or that distance is below `DRIFT_DISTANCE`
    tolerances. Sequences without a period (0) are left as they are (True)."""
    done = np.ones(len(period), dtype=bool)
    for p in np.unique(period[period > 0]):
        rows = np.flatnonzero(period == p)
        steps = np.max(np.abs(points[rows, p:] - points[rows, :-p]) / tolerance[rows, None, :],
                       axis=2)
        half = steps.shape[1] // 2
        late = steps[:, half:].max(axis=1)
        if half == 0:  # a single step: no trend to read
            done[rows] = late <= NOISE_FRACTION
            continue
        early = np.maximum(steps[:, :half].max(axis=1), np.finfo(float).tiny)
        rho = np.minimum(late / early, 1.0) ** (1.0 / half)
        with np.errstate(divide="ignore"):
            distance = np.where(rho < 1.0, late * rho / (1.0 - rho), np.inf)
        done[rows] = (late <= NOISE_FRACTION) | (distance <= DRIFT_DISTANCE)
    return done


def cycle_of(points, period: int, tolerance) -> tuple[np.ndarray, int]:
    """The last `period` points of one sequence as a cycle, reduced to its smallest period
    within `tolerance` (a slowly decaying flip, x_k ≈ x* + c(−ρ)^k with ρ near 1, recurs
    with period 2 before it does with period 1 over the whole sequence, though its last
    points already agree), shifted to start from its lexicographically smallest point."""
    cycle = points[-period:]
    for q in range(1, period):
        if period % q == 0 and np.all(np.abs(np.roll(cycle, -q, axis=0) - cycle) <= tolerance):
            cycle = cycle[-q:]
            break
    first = np.lexsort(cycle.T[::-1])[0]
    return np.roll(cycle, -first, axis=0), len(cycle)


def reduced_periods(points, period, tolerance) -> np.ndarray:
    """Per start, the period of its cycle after `cycle_of`'s reduction (the smallest q
    dividing p with which the last p points already recur), vectorised per distinct p."""
    reduced = period.copy()
    for p in np.unique(period[period > 1]):
        rows = np.flatnonzero(period == p)
        cycle = points[rows, -p:]
        tol = tolerance[rows][:, None, :]
        open_rows = np.ones(len(rows), dtype=bool)
        for q in (q for q in range(1, p) if p % q == 0):
            recurs = np.all(np.abs(np.roll(cycle, -q, axis=1) - cycle) <= tol, axis=(1, 2))
            reduced[rows[open_rows & recurs]] = q
            open_rows &= ~recurs
    return reduced


def on_attractor(points, reduced, tolerance, attractor: Attractor) -> np.ndarray:
    """Which starts' cycles are `attractor`'s: same (reduced) period and every point
    within the larger of the two tolerances, for some cyclic shift (the lexicographic
    start of two noisy copies of one cycle may differ when two of its points nearly tie
    in their first coordinate)."""
    q = attractor.period
    last = points[:, -q:]
    tol = np.maximum(tolerance, attractor.tolerance)[:, None, :]
    hit = np.zeros(len(points), dtype=bool)
    for shift in range(q):
        hit |= np.all(np.abs(np.roll(last, -shift, axis=1) - attractor.points) <= tol,
                      axis=(1, 2))
    return (reduced == q) & hit


def _assign(decided, table: list, matches: Callable, leader: Callable) -> np.ndarray:
    """Labels of a chunk's starts: each decided start gets the first attractor, in label
    order, that `matches(attractor)` (a bool per start) puts it on: the known ones first,
    then, from the lowest-numbered start left, a new one at a time (`leader(i)` makes it
    from start i), so that the labels are those of one start after the other, whatever
    the chunks."""
    labels = np.full(len(decided), -1, dtype=np.int64)
    left = decided.copy()
    for label, attractor in enumerate(table):
        hit = left & matches(attractor)
        labels[hit], left = label, left & ~hit
    while left.any():
        first = int(np.flatnonzero(left)[0])
        table.append(leader(first))
        hit = left & matches(table[-1])
        hit[first] = True  # its own attractor, whatever the round-off
        labels[hit], left = len(table) - 1, left & ~hit
    return labels


def _label_recurrent(points, period, tolerance, decided, offset, table: list) -> np.ndarray:
    """Labels of a chunk's starts by their cycles; new attractors are appended to `table`
    (`offset`: the chunk's first start index)."""
    reduced = reduced_periods(points, period, tolerance)

    def leader(i):
        cycle, p = cycle_of(points[i], int(period[i]), tolerance[i])
        return Attractor(points=cycle, period=p, tolerance=tolerance[i], feature=None,
                         first_start=offset + i)

    return _assign(decided, table, lambda a: on_attractor(points, reduced, tolerance, a),
                   leader)


# --------------------------------------------------------------------------------------
# Features: leader clustering
# --------------------------------------------------------------------------------------


def _label_features(points, period, tolerance, feature, radius, decided, offset,
                    table: list) -> np.ndarray:
    """Labels of a chunk's starts by their feature vectors: a start joins the first group
    whose leader's feature is within the larger of the two radii (every coordinate), or
    leads a new group."""

    def leader(i):
        if period[i] > 0:
            cycle, p = cycle_of(points[i], int(period[i]), tolerance[i])
        else:
            cycle, p = points[i][-1:], 0
        return Attractor(points=cycle, period=p, tolerance=radius[i], feature=feature[i],
                         first_start=offset + i)

    def matches(attractor):
        gap = np.abs(feature - attractor.feature)
        return np.all(gap <= np.maximum(radius, attractor.tolerance), axis=1)

    return _assign(decided, table, matches, leader)


_FEATURES: dict = {}


def _features_of(features: Callable, points) -> np.ndarray:
    """`features` of every start of a chunk: one jitted, vmapped program per function."""
    run = _FEATURES.get(features)
    if run is None:
        run = _FEATURES[features] = jax.jit(jax.vmap(lambda p: jnp.atleast_1d(features(p))))
    return np.asarray(run(jnp.asarray(points)), dtype=np.float64)


# --------------------------------------------------------------------------------------
# One chunk
# --------------------------------------------------------------------------------------


def _first_missing(status) -> np.ndarray:
    """Per start: SUCCESS if every point was found, else the first missing point's."""
    missing = status != Status.SUCCESS
    first = np.argmax(missing, axis=1)
    return np.where(missing.any(axis=1), status[np.arange(len(status)), first],
                    int(Status.SUCCESS))


def _classify_chunk(section: Section, offset: int, table: list, config: dict):
    """`(labels, status, run_status, period, tolerance)` of one chunk's starts; extends
    `table` with the attractors first met here."""
    points = np.asarray(section.points)
    run_status = _first_missing(np.asarray(section.status))
    # One scale per start, its largest coordinate: the global error of any coordinate
    # mixes in the others' (a velocity error becomes a position error), so a coordinate
    # that settles near 0 is known to rtol·‖x‖ + atol, not to rtol·|x_i| + atol.
    scale = np.nanmax(np.abs(points), axis=(1, 2), initial=0.0)
    tolerance = config["factor"] * (config["rtol"] * scale + config["atol"])
    tolerance = np.repeat(tolerance[:, None], points.shape[2], axis=1)
    period = recurrence_periods(points, tolerance)
    status = np.full(len(points), int(BasinStatus.ATTRACTOR), dtype=np.int64)
    status[(period == 0) | ~settled(points, period, tolerance)] = BasinStatus.UNDECIDED
    if config["bound"] is not None:
        status[np.any(np.abs(points) > config["bound"], axis=(1, 2))] = BasinStatus.DIVERGED
    status[run_status != Status.SUCCESS] = BasinStatus.FAILED
    if config["features"] is None:
        decided = status == BasinStatus.ATTRACTOR
        labels = _label_recurrent(points, period, tolerance, decided, offset, table)
        return labels, status, run_status, period, tolerance
    feature = _features_of(config["features"], points)
    # With features a start needs no recurrence, only a finite feature vector.
    ran = status <= BasinStatus.UNDECIDED
    finite = np.all(np.isfinite(feature), axis=1)
    status[ran] = np.where(finite, BasinStatus.ATTRACTOR, BasinStatus.UNDECIDED)[ran]
    radius = _feature_radius(feature, config)
    decided = status == BasinStatus.ATTRACTOR
    labels = _label_features(points, period, tolerance, feature, radius, decided, offset, table)
    return labels, status, run_status, period, radius


def _feature_radius(feature, config: dict) -> np.ndarray:
    """The grouping radius per start and feature coordinate: `grid`, or by default the
    recurrence tolerance of the features' own scale."""
    if config["grid"] is not None:
        return np.broadcast_to(np.asarray(config["grid"], np.float64), feature.shape).copy()
    scale = np.where(np.isfinite(feature), np.abs(feature), 0.0)
    return config["factor"] * (config["rtol"] * scale + config["atol"])


# --------------------------------------------------------------------------------------
# basins
# --------------------------------------------------------------------------------------


def basins(
    scene: Scene,
    starts,
    t0,
    args=None,
    *,
    period=None,
    surface: int | None = None,
    section: Callable | None = None,
    direction: int = -1,
    num_points: int = 32,
    transient,
    features: Callable | None = None,
    grid=None,
    bound: float | None = None,
    recurrence_factor: float = RECURRENCE_FACTOR,
    chunk_size: int | None = None,
    **simulate_options,
) -> Basins:
    r"""Attractors and basins of attraction of a set of starts, found on a Poincaré section.

    Each start runs from (t0, x0) through its impacts; its `num_points` section points
    after `transient` decide its label:

    - **recurrences** (default): the points are periodic with period p if every point
      recurs p maps later within the recurrence tolerance
      `recurrence_factor · (rtol · max_{k,i} |x_k,i| + atol)` in every coordinate
      (`grazejax.orbit_diagram`'s test, p ≤ num_points // 2 so that each point recurs at
      least once; the scale is the start's largest coordinate, since the global error of
      a coordinate that settles near 0 carries the others'), and the sequence must have
      settled: its recurrence steps |x_{k+p} − x_k| shrink geometrically, so that its
      extrapolated distance to the limit is below `DRIFT_DISTANCE` (30) tolerances, or
      they are noise (`settled`). Along a nearly neutral family of orbits (an amplitude that drifts by
      less than the tolerance per map) a sequence recurs without settling: UNDECIDED,
      not a continuum of "attractors". The cycle (the last p points, reduced to a smaller
      period if its points already recur with one, started from its lexicographically
      smallest point) is compared with the known attractors: same period and every point
      within tolerance, up to a cyclic shift. A match gives that attractor's label;
      otherwise the cycle is a new attractor.
    - **features** (`features=fn`): `fn(points) -> vector` maps one start's section points
      `(num_points, n)` to a feature vector (traceable: it runs jitted and vmapped over a
      chunk). A start joins the first group whose leader's feature is within `grid` of its
      own in every coordinate (leader clustering), or leads a new group. Groups are
      separated correctly when the features of one attractor spread by less than `grid`
      and those of different attractors differ by more than 2·`grid`.

    **Label −1**: a start in no basin. `status` says why: `UNDECIDED` (no settled
    recurrence within num_points: chaos, quasi-periodicity, a transient too slow for the
    tolerance, a drift; a non-finite feature), `DIVERGED` (a point beyond `bound`),
    `FAILED` (the run stopped before its last point: `run_status` holds why, e.g.
    `MAX_IMPACTS`, `ZENO`). These starts count in no basin, only in the total.

    A stroboscopic section of an autonomous system sees a limit cycle as a quasi-periodic
    sequence (the period T is not the cycle's): use an impact map or a user section there.
    An unstable invariant set hit exactly (a start on a saddle) recurs too and is reported
    as an attractor: brute force reports what the runs did.

    **Arguments:**

    - `scene`, `t0`, `args`: as `grazejax.simulate` (forward time; `args` shared by all
      starts).
    - `starts`: the initial states, `(N, n)`.
    - `period`, `surface`, `section`, `direction`: the section, as `grazejax.poincare`
      (exactly one of the first three).
    - `num_points`: section points per start after the transient (default 32).
    - `transient`: time skipped before the first point.
    - `features`: optional `fn(points) -> vector` (see above).
    - `grid`: with `features`, the grouping radius per feature coordinate (scalar or
      `(d,)`); default: the recurrence tolerance of the features' own scale.
    - `bound`: optional box |x_i| ≤ bound; a start with a point outside is `DIVERGED`.
    - `recurrence_factor`: the recurrence tolerance in units of rtol·|x| + atol (1e3,
      `grazejax.orbit_diagram`'s).
    - `chunk_size`: starts per compiled call (default: all, up to 65536). Only one chunk's
      section points are in memory at a time; labels do not depend on it.
    - `**simulate_options`: `grazejax.simulate`'s options, as `grazejax.poincare`
      (`rtol`, `atol` also set the recurrence tolerance; `max_impacts` defaults to
      2·num_points + 64 and bounds the events of the whole run, transient included).

    **Returns:** a `grazejax.Basins` of NumPy arrays.

    **Example:** the damped Duffing oscillator x'' + 0.5x' − x + x³ = 0 has stable foci at
    x = ±1; at stroboscopic times each start settles on one of them:

    ```python
    import jax.numpy as jnp
    import numpy as np
    import grazejax as gj

    def duffing(t, x, args):
        return jnp.stack([x[1], -args["delta"] * x[1] + x[0] - x[0] ** 3])

    starts = np.array([[0.5, 0.0], [-0.5, 0.0], [1.5, 0.0]])
    result = gj.basins(gj.Scene(duffing), starts, 0.0, {"delta": 0.5}, period=1.0,
                       num_points=8, transient=60.0)
    print(result.labels)                                    # [0 1 0]
    print([a.points[0, 0].round(6) for a in result.attractors])   # [1.0, -1.0]
    ```
    """
    starts = np.asarray(starts, dtype=np.float64)
    if starts.ndim != 2 or len(starts) == 0:
        raise ValueError(f"starts must have shape (N, n) with N ≥ 1, got {starts.shape}")
    if features is not None and not callable(features):
        raise TypeError("features must be a function (num_points, n) -> feature vector")
    if grid is not None and features is None:
        raise TypeError("grid= is the grouping radius of features=: pass features too")
    kind = section_kind(scene, period, surface, section, direction)
    options = run_options(simulate_options, num_points)
    config = dict(features=features, grid=grid, bound=bound, factor=float(recurrence_factor),
                  rtol=float(options.get("rtol", SIMULATE_OPTIONS["rtol"])),
                  atol=float(options.get("atol", SIMULATE_OPTIONS["atol"])))
    chunk = _chunk_length(len(starts), chunk_size)
    def run_chunk(chunk_starts):
        return _run_chunk(scene, kind, int(num_points), options, chunk_starts, chunk, t0,
                          transient, args, period)

    table: list[Attractor] = []
    pieces = []
    for offset in range(0, len(starts), chunk):
        points = run_chunk(starts[offset:offset + chunk])
        pieces.append(_classify_chunk(points, offset, table, config))
    labels, status, run_status, periods_found, tolerance = (
        np.concatenate(parts) for parts in zip(*pieces, strict=True))
    return _result(labels, tuple(table), status, run_status, periods_found, tolerance)


def _run_chunk(scene, kind, num_points: int, options: dict, starts, chunk: int, t0,
               transient, args, period) -> Section:
    """The section points of one chunk of starts (`poincare`'s batched run, `args` shared
    by all lanes), on the host. A short last chunk is padded with copies of its first
    start to the chunk's length, so that every chunk is one call of one compiled shape."""
    count = len(starts)
    padding = np.broadcast_to(starts[:1], (chunk - count, starts.shape[1]))
    padded = np.concatenate([starts, padding])
    periods = np.full(chunk, np.nan if period is None else float(period))
    in_axes_args = jax.tree.map(lambda _: None, args)
    out = run_batched(scene, kind, num_points, options, padded, t0, transient, args,
                      in_axes_args, periods, chunk)
    return jax.tree.map(lambda leaf: leaf[:count], out)


def _chunk_length(num_starts: int, chunk_size) -> int:
    """Starts per compiled call (every chunk is padded to it: one program)."""
    if chunk_size is None:
        return min(num_starts, _DEFAULT_CHUNK)
    if int(chunk_size) <= 0:
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    return min(int(chunk_size), num_starts)


def _result(labels, attractors, status, run_status, period, tolerance) -> Basins:
    """The result, with the basin stabilities S_k = N_k/N and their errors √(S(1−S)/N)."""
    total = len(labels)
    counts = np.bincount(labels[labels >= 0], minlength=len(attractors)).astype(np.float64)
    fractions = counts / total
    return Basins(labels=labels, attractors=attractors, fractions=fractions,
                  standard_errors=np.sqrt(fractions * (1 - fractions) / total), status=status,
                  run_status=run_status, period=period, tolerance=tolerance)
