"""What `continue_orbit` returns: a `Branch` of periodic orbits with its grazing and special
points (`GrazingPoint`, `SpecialPoint`)."""

from __future__ import annotations

import dataclasses
from typing import Any

import equinox as eqx
import numpy as np

from .._status import ContinuationStatus
from .arclength import (
    write_text,
)
from .period_map import (
    SolverSettings,
)
from .periodic import Orbit


@dataclasses.dataclass(frozen=True)
class GrazingPoint:
    r"""A grazing bifurcation found by `grazejax.continue_orbit`.

    - `mu`: its parameter value: located to `locate_tol` by bisection where two families
      meet; where a family ends, extrapolated to zero virtual depth (−v²/(2a) is linear in
      μ near the end, whose bisection stops short of the square-root tip).
    - `orbit`: the grazing orbit (`grazejax.Orbit`) at `mu`.
    - `surface`, `time`, `point`, `depth`: the grazing contact (the contact of `orbit` with
      the smallest |virtual depth|, see `grazejax.Contacts`).
    - `impacts_before`, `impacts_after`: impacts per period on the family continuation
      came from and on the one it went on with (None if it ended).
    - `kind`: `"persistence"` (the family goes on with the other impact count),
      `"fold"` (the other family turns back: a non-smooth fold) or `"end"`.
    """

    mu: float
    orbit: Orbit
    surface: int
    time: float
    point: np.ndarray
    depth: float
    impacts_before: int
    impacts_after: int | None
    kind: str


@dataclasses.dataclass(frozen=True, eq=False)
class SpecialPoint:
    r"""A bifurcation of a smooth family found by `grazejax.continue_orbit`.

    Each is detected between two points of the branch by its test function and then
    solved by its defining system (`grazejax.locate_bifurcation`: the orbit, μ and the
    test function together, by Newton's method, to the corrector's tolerance):

    - `kind`: `"period-doubling"` (a real multiplier through −1: Π(1 + ρ_i) changes sign),
      `"fold"` (μ turns back along the arclength: a second multiplier 1) or
      `"neimark-sacker"` (a complex pair through the unit circle: Π_{i<j}(ρ_i ρ_j − 1)
      changes sign with a complex pair of modulus near 1).
    - `mu`: where; `x0`, `t0`, `period`: the orbit there; `multipliers` (modulus
      descending); `num_impacts`.
    - `solved`: True where the defining system converged on the branch's family (within
      the points around the detection); False: the detection's estimate (a secant search
      for period doubling, the vertex of a parabola through three points for a fold,
      linear interpolation for Neimark–Sacker), kept because Newton failed there.
    - `fixed_period`: the family's orbits have a fixed (forced) period.
    - `eigenvector`: for period doubling, the real eigenvector of the multiplier −1
      (the direction of the period-2 orbits: `grazejax.period_doubled_orbit`).
    - `label`: a short label for diagrams (`"PD"`, `"LP"`, `"NS"`).

    A `SpecialPoint` is the start `point` of `grazejax.locate_bifurcation` and
    `grazejax.continue_bifurcation`.
    """

    kind: str
    mu: float
    x0: np.ndarray
    t0: float
    period: float
    multipliers: np.ndarray
    num_impacts: int
    eigenvector: np.ndarray | None = None
    solved: bool = False
    fixed_period: bool = True

    @property
    def label(self) -> str:
        return {"period-doubling": "PD", "fold": "LP", "neimark-sacker": "NS"}[self.kind]


class Branch(eqx.Module):
    r"""A continued family of periodic orbits (`grazejax.continue_orbit`). NumPy arrays.

    **Fields:**

    - `mu`, `period`, `x0`: one row per point (`x0` at phase `t0`, per point).
    - `t0`: the start time of each point's orbit.
    - `multipliers`: `(N, n)` complex, modulus descending.
    - `num_impacts`: impacts per period.
    - `stable`: (A5) per point.
    - `x_min`, `x_max`: `(N, n)` extremes of each coordinate along the orbit
      (amplitude for bifurcation diagrams).
    - `poincare_determinant`: the (A6) determinant per point.
    - `grazing`: the `grazejax.GrazingPoint`s met, in order.
    - `status`: a `grazejax.ContinuationStatus` (shown by name; equal to its
      integer code); `message` reads it.
    - `settings`: the `grazejax.SolverSettings` of the continuation (every point is a
      converged orbit: a point whose corrector fails is never recorded).
    - `special_points`: the `grazejax.SpecialPoint`s (period doubling, folds,
      Neimark–Sacker) met on smooth stretches, in order.
    """

    mu: Any
    period: Any
    x0: Any
    t0: Any
    multipliers: Any
    num_impacts: Any
    stable: Any
    x_min: Any
    x_max: Any
    poincare_determinant: Any
    grazing: tuple = eqx.field(static=True)
    status: ContinuationStatus = eqx.field(static=True, converter=ContinuationStatus)
    settings: SolverSettings | None = eqx.field(static=True, default=None)
    special_points: tuple = eqx.field(static=True, default=())

    @property
    def message(self) -> str:
        return ContinuationStatus(self.status).message

    def __len__(self) -> int:
        return len(self.mu)

    def to_dict(self) -> dict:
        """Plain Python data (lists, floats, strings): points, special and grazing points,
        status and settings. Complex multipliers are split into `_re` / `_im` lists."""
        mult = np.asarray(self.multipliers)
        return {
            "points": {
                "mu": np.asarray(self.mu).tolist(), "period": np.asarray(self.period).tolist(),
                "t0": np.asarray(self.t0).tolist(), "x0": np.asarray(self.x0).tolist(),
                "num_impacts": np.asarray(self.num_impacts).tolist(),
                "stable": np.asarray(self.stable).tolist(),
                "multipliers_re": mult.real.tolist(), "multipliers_im": mult.imag.tolist(),
                "x_min": np.asarray(self.x_min).tolist(), "x_max": np.asarray(self.x_max).tolist(),
                "poincare_determinant": np.asarray(self.poincare_determinant).tolist(),
            },
            "special_points": [
                {"kind": p.kind, "label": p.label, "mu": p.mu, "period": p.period,
                 "x0": np.asarray(p.x0).tolist(), "num_impacts": p.num_impacts,
                 "solved": p.solved,
                 "multipliers_re": np.asarray(p.multipliers).real.tolist(),
                 "multipliers_im": np.asarray(p.multipliers).imag.tolist()}
                for p in self.special_points
            ],
            "grazing": [
                {"mu": g.mu, "kind": g.kind, "impacts_before": g.impacts_before,
                 "impacts_after": g.impacts_after, "surface": g.surface, "time": g.time,
                 "point": np.asarray(g.point).tolist(), "depth": g.depth}
                for g in self.grazing
            ],
            "status": ContinuationStatus(self.status).name,
            "settings": None if self.settings is None else dataclasses.asdict(self.settings),
        }

    def to_json(self, path=None) -> str:
        """The branch as JSON (`to_dict`); written to `path` if given."""
        import json

        text = json.dumps(self.to_dict(), indent=1)
        if path is not None:
            with open(path, "w") as f:
                f.write(text)
        return text

    def to_csv(self, path=None) -> str:
        """One row per point: mu, period, num_impacts, stable, x0_i, x_min_i, x_max_i,
        |rho|_i, rho_i (re, im), and `special` (the labels of special points located
        between this point and the previous one; `G` for grazing). Written to `path` if
        given."""
        import csv
        import io

        mu = np.asarray(self.mu)
        n = np.asarray(self.x0).shape[1] if len(mu) else 0
        labels = [[] for _ in range(len(mu))]
        marks = [(p.mu, p.label) for p in self.special_points] + [(g.mu, "G") for g in self.grazing]
        for m, label in marks:
            if len(mu):
                labels[int(np.argmin(np.abs(mu - m)))].append(label)
        out = io.StringIO()
        w = csv.writer(out)
        w.writerow(["mu", "period", "num_impacts", "stable"]
                   + [f"x0_{i}" for i in range(n)] + [f"x_min_{i}" for i in range(n)]
                   + [f"x_max_{i}" for i in range(n)] + [f"abs_rho_{i}" for i in range(n)]
                   + [f"rho_{i}_re" for i in range(n)] + [f"rho_{i}_im" for i in range(n)]
                   + ["special"])
        mult = np.asarray(self.multipliers)
        for i in range(len(mu)):
            w.writerow([repr(float(mu[i])), repr(float(self.period[i])), int(self.num_impacts[i]),
                        bool(self.stable[i])]
                       + [repr(float(v)) for v in np.concatenate([
                           self.x0[i], self.x_min[i], self.x_max[i], np.abs(mult[i]),
                           mult[i].real, mult[i].imag])]
                       + [" ".join(labels[i])])
        return write_text(out.getvalue(), path)


def empty_branch(n, status, settings=None) -> Branch:
    z = np.zeros((0,))
    return Branch(mu=z, period=z, x0=np.zeros((0, n)), t0=z, multipliers=np.zeros((0, n), complex),
                  num_impacts=np.zeros((0,), int), stable=np.zeros((0,), bool),
                  x_min=np.zeros((0, n)), x_max=np.zeros((0, n)), poincare_determinant=z,
                  grazing=(), status=int(status), settings=settings)


def branch_of(points, grazing, status, n, t0, settings=None, special=()) -> Branch:
    def stack(key):
        return np.stack([getattr(p, key) for p in points])

    Ys = stack("Y")
    fixed = Ys.shape[1] == n + 1
    return Branch(
        mu=Ys[:, -1], period=stack("period"), x0=Ys[:, :-1] if fixed else Ys[:, 1:-1],
        t0=np.full(len(points), t0), multipliers=stack("multipliers"),
        num_impacts=stack("num_impacts").astype(int), stable=stack("stable").astype(bool),
        x_min=stack("x_min"), x_max=stack("x_max"), poincare_determinant=stack("a6"),
        grazing=tuple(grazing), status=int(status), settings=settings,
        special_points=tuple(special),
    )

