r"""Basin stability continued over a parameter, attractors matched from one value to the
next (`grazejax.continue_basins`).

The same starts run at every parameter value (`grazejax.basins`: `args` are inputs of its
compiled program, so every value reuses one program), and each value's attractors are
matched with the previous value's, as the find-and-match continuation of Attractors.jl
(Datseris, Rossi & Wagemakers 2023, *Chaos* 33, 073151): the pairs are taken in order of
increasing distance, each attractor at most once, up to `match_distance`. An attractor
that matches none is new and takes the next global id; one that has vanished keeps its id
and has fraction 0 from there on (a later attractor never inherits it).

The distance between two attractors is the Hausdorff distance of their point sets on the
section (so a period-doubling, whose two points split off the old fixed point, stays the
same attractor, and a cyclic relabelling of a cycle's points changes nothing), or, with
`features=`, the largest coordinate difference of their features.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import equinox as eqx
import numpy as np
from jaxtyping import Float, Int

from .._scene import Scene
from .basins import Attractor, basins


class BasinsCurve(eqx.Module):
    r"""Basin stability along a parameter (`grazejax.continue_basins`).

    **Fields** (m parameter values, N starts, K attractors over all values):

    - `mu`: the parameter values, `(m,)`.
    - `fractions`: `(m, K)`, the basin stability of each attractor (by global id) at each
      value; 0 where that attractor does not exist (or no start reaches it).
    - `standard_errors`: `(m, K)`, √(S(1 − S)/N).
    - `labels`: `(m, N)`, each start's attractor by global id, −1 in no basin.
    - `attractors`: per value, a dict `{global id: grazejax.Attractor}` of the attractors
      found there.
    - `num_undecided`: `(m,)`, the starts in no basin at each value.
    """

    mu: Float[np.ndarray, " m"]
    fractions: Float[np.ndarray, "m K"]
    standard_errors: Float[np.ndarray, "m K"]
    labels: Int[np.ndarray, "m N"]
    attractors: tuple[dict, ...]
    num_undecided: Int[np.ndarray, " m"]


def attractor_distance(a: Attractor, b: Attractor) -> float:
    """The Hausdorff distance of the two point sets on the section, or with features the
    largest coordinate difference of the features (∞ between the two kinds)."""
    if (a.feature is None) != (b.feature is None):
        return math.inf
    if a.feature is not None:
        return float(np.max(np.abs(np.asarray(a.feature) - np.asarray(b.feature))))
    p, q = np.asarray(a.points), np.asarray(b.points)
    d = np.linalg.norm(p[:, None, :] - q[None, :, :], axis=-1)
    return float(max(d.min(axis=1).max(), d.min(axis=0).max()))


def match_attractors(previous: dict, current: Sequence[Attractor], next_id: int,
                     match_distance: float) -> tuple[list[int], int]:
    """Global ids for `current` (in its label order): the closest pairs with `previous`
    (`{id: Attractor}`) first, each id and each attractor at most once, up to
    `match_distance`; the rest take new ids from `next_id`. Returns the ids and the next
    free id."""
    pairs = sorted(
        (attractor_distance(old, new), key, j)
        for key, old in previous.items() for j, new in enumerate(current)
    )
    ids: list[int | None] = [None] * len(current)
    taken = set()
    for distance, key, j in pairs:
        if distance > match_distance or ids[j] is not None or key in taken:
            continue
        ids[j] = key
        taken.add(key)
    for j in range(len(current)):
        if ids[j] is None:
            ids[j], next_id = next_id, next_id + 1
    return ids, next_id


def continue_basins(
    scene: Scene,
    starts,
    t0,
    args_of: Callable,
    mus,
    *,
    match_distance: float = math.inf,
    **basins_options,
) -> BasinsCurve:
    r"""Basin stability of every attractor along a parameter μ, the attractors matched
    from one value of μ to the next.

    At each μ in `mus` (in the order given), `grazejax.basins(scene, starts, t0,
    args_of(μ), **basins_options)` labels the starts; its attractors are matched with those
    of the previous μ (see the module: closest pairs first, Hausdorff distance of the
    section points or distance of the features, up to `match_distance`), so that one
    attractor keeps one id along the curve, through a period-doubling too. Every μ runs
    the same compiled program: `args_of` must return the same structure at every μ.

    **Arguments:**

    - `scene`, `starts`, `t0`: as `grazejax.basins`.
    - `args_of`: `mu -> args`.
    - `mus`: the parameter values, in the order of continuation.
    - `match_distance`: the largest distance at which two attractors are the same (default
      ∞: every attractor is matched while the previous value has one left; lower it so
      that an attractor that jumps far becomes a new one).
    - `**basins_options`: `grazejax.basins`' keywords (the section, `num_points`,
      `transient`, `features`, simulate's options...).

    **Returns:** a `grazejax.BasinsCurve`.

    **Example:** the damped Duffing oscillator keeps its two foci x = ±1 as the damping
    changes; each keeps its id and about half the starts:

    ```python
    import jax.numpy as jnp
    import numpy as np
    import grazejax as gj

    def duffing(t, x, args):
        return jnp.stack([x[1], -args["delta"] * x[1] + x[0] - x[0] ** 3])

    starts = np.stack([np.linspace(-2.0, 2.0, 9), np.full(9, 0.3)], axis=1)
    curve = gj.continue_basins(gj.Scene(duffing), starts, 0.0,
                               lambda d: {"delta": d}, [0.4, 0.6, 0.8],
                               period=1.0, num_points=8, transient=60.0)
    print(curve.fractions.shape)                      # (3, 2)
    print([float(a[0].points[0, 0].round(6)) for a in curve.attractors])   # [1.0, 1.0, 1.0]
    ```
    """
    mus = np.asarray(mus, dtype=np.float64).reshape(-1)
    if len(mus) == 0:
        raise ValueError("mus must hold at least one parameter value")
    if not match_distance >= 0:
        raise ValueError(f"match_distance must be ≥ 0, got {match_distance!r}")
    previous: dict = {}
    next_id = 0
    rows, labels, found, undecided = [], [], [], []
    for mu in mus:
        result = basins(scene, starts, t0, args_of(float(mu)), **basins_options)
        ids, next_id = match_attractors(previous, result.attractors, next_id, match_distance)
        mapping = np.asarray(ids + [-1], dtype=np.int64)  # (label −1 maps to the last entry)
        labels.append(mapping[result.labels])
        rows.append(dict(zip(ids, result.fractions, strict=True)))
        previous = dict(zip(ids, result.attractors, strict=True))
        found.append(previous)
        undecided.append(result.num_undecided)
    fractions = np.zeros((len(mus), next_id))
    for i, row in enumerate(rows):
        for key, value in row.items():
            fractions[i, key] = value
    total = np.asarray(starts).shape[0]
    return BasinsCurve(
        mu=mus, fractions=fractions,
        standard_errors=np.sqrt(fractions * (1 - fractions) / total),
        labels=np.stack(labels), attractors=tuple(found),
        num_undecided=np.asarray(undecided, dtype=np.int64),
    )
