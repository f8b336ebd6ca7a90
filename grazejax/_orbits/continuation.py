r"""Continuation of periodic orbits in a scalar parameter μ, through grazing bifurcations.

[`grazejax.continue_orbit`][] follows a family of periodic orbits by pseudo-arclength
continuation in (T, x0, μ) (or (x0, μ) for forced systems): a secant/tangent predictor,
an `optimistix` Newton corrector on the Poincaré criterion (paper eq. periodpar) bordered
by the arclength condition, and an adaptive step. The period map is the full impact
system's (impacts included), so a family keeps its physical meaning: when an orbit
becomes tangent to a surface piece and its number of impacts per period changes, that
is a *grazing bifurcation* (paper §5). It is detected as a change of the impact count
between two accepted points and located by bisection along the arclength, to
`locate_tol` in μ. Then:

- if the family continues on the far side with the other impact count (*persistence*,
  ex1dof at μ = 0: the continuous cycle Ψ_μ becomes the impacting cycle), continuation
  simply goes on: the new points are on the other family;
- if the corrector fails past the grazing point, the other families are looked for on
  both sides of it (*branch switching*): a solution close to the grazing orbit with a
  different impact count on the near side (a non-smooth fold) or the far side is taken
  up and continued; if there is none the branch ends there (the family disappears:
  ex1dof's impacting cycle at μ ≈ −0.106, whose impact speed tends to 0).

[`grazejax.plot_bifurcation_diagram`][] draws the branches (amplitude vs μ, stable solid,
unstable dashed, coloured by impacts per period, grazing points marked) and saves a PNG.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._scene import Scene
from .._status import ContinuationStatus
from .arclength import (
    FALL_THROUGH,
    Front,
    Run,
    Steps,
    bordered_newton,
    continuation_settings,
    eigvals_descending,
    next_tangent,
    step_accepted,
    trace,
    write_text,
)
from .bifurcation import locate_special
from .contacts import orbit_contacts
from .period_map import (
    PeriodMap,
    SolverSettings,
    a5_holds,
    gap_rates_at,
    linearize,
    newton_for,
    orbit_kernel,
    sampled_states,
    state_at,
)
from .periodic import Orbit, OrbitStatus, find_periodic_orbit

# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class GrazingPoint:
    r"""A grazing bifurcation found by [`grazejax.continue_orbit`][].

    - `mu`: its parameter value: located to `locate_tol` by bisection where two families
      meet; where a family ends, extrapolated to zero virtual depth (−v²/(2a) is linear in
      μ near the end, whose bisection stops short of the square-root tip).
    - `orbit`: the grazing orbit ([`grazejax.Orbit`][]) at `mu`.
    - `surface`, `time`, `point`, `depth`: the grazing contact (the contact of `orbit` with
      the smallest |virtual depth|, see [`grazejax.Contacts`][]).
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
    r"""A bifurcation of a smooth family found by [`grazejax.continue_orbit`][].

    Each is detected between two points of the branch by its test function and then
    solved by its defining system ([`grazejax.locate_bifurcation`][]: the orbit, μ and the
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
      (the direction of the period-2 orbits: [`grazejax.period_doubled_orbit`][]).
    - `label`: a short label for diagrams (`"PD"`, `"LP"`, `"NS"`).

    A `SpecialPoint` is the start `point` of [`grazejax.locate_bifurcation`][] and
    [`grazejax.continue_bifurcation`][].
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
    r"""A continued family of periodic orbits ([`grazejax.continue_orbit`][]). NumPy arrays.

    **Fields:**

    - `mu`, `period`, `x0`: one row per point (`x0` at phase `t0`, per point).
    - `t0`: the start time of each point's orbit.
    - `multipliers`: `(N, n)` complex, modulus descending.
    - `num_impacts`: impacts per period.
    - `stable`: (A5) per point.
    - `x_min`, `x_max`: `(N, n)` extremes of each coordinate along the orbit
      (amplitude for bifurcation diagrams).
    - `poincare_determinant`: the (A6) determinant per point.
    - `grazing`: the [`grazejax.GrazingPoint`][]s met, in order.
    - `status`: a [`grazejax.ContinuationStatus`][] code; `message` reads it.
    - `settings`: the [`grazejax.SolverSettings`][] of the continuation (every point is a
      converged orbit: a point whose corrector fails is never recorded).
    - `special_points`: the [`grazejax.SpecialPoint`][]s (period doubling, folds,
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
    status: int = eqx.field(static=True)
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


# --------------------------------------------------------------------------------------
# Compiled kernels
# --------------------------------------------------------------------------------------


class _Family(eqx.Module):
    pmap: PeriodMap = eqx.field(static=True)
    args_of: Callable = eqx.field(static=True)
    period_of: Callable | None = eqx.field(static=True)
    fixed_period: bool = eqx.field(static=True)
    root_finder: Any  # (its tolerances are arrays: see `newton_for`)
    max_steps: int = eqx.field(static=True)


def _unpack(fam: _Family, Y, T_fixed):
    mu = Y[-1]
    if fam.fixed_period:
        T = T_fixed if fam.period_of is None else fam.period_of(mu)
        x = Y[:-1]
    else:
        T, x = Y[0], Y[1:-1]
    return T, x, mu


def _criterion(fam: _Family, Y, t0, e_j, c, T_fixed):
    """The Poincaré criterion F(Y) (plus the phase row), and the run behind it."""
    T, x, mu = _unpack(fam, Y, T_fixed)
    x_end, ok, sol = fam.pmap(x, t0, T, fam.args_of(mu))
    rows = x_end - x
    if not fam.fixed_period:
        rows = jnp.concatenate([rows, (jnp.dot(x, e_j) - c)[None]])
    return jnp.where(ok, rows, jnp.nan), (ok, sol)


class _BranchPoint(NamedTuple):
    """One corrected point of a branch, with what the tracer needs of it.

    `Y` is the corrector's unknown ((x, μ) for a fixed period, (T, x, μ) otherwise) and
    `tangent` the unit tangent there (the predictor's when `good` is False). A point the
    corrector could not place (`good` False, `num_impacts` −1) carries only those and the
    Newton step count; the diagnostics after `steps` are None for it.
    """

    Y: Any
    tangent: Any
    good: bool
    num_impacts: int
    steps: Any
    monodromy: Any = None
    multipliers: Any = None
    stable: Any = None
    a6: Any = None  # det of the (A6) matrix: the Jacobian of the Poincaré criterion
    x_min: Any = None  # extremes of the state along the orbit (amplitude)
    x_max: Any = None
    f_x: Any = None  # the vector field at the point's start (the phase condition's normal)
    period: Any = None
    impact_speed: float = math.inf  # the smallest normal impact speed (grazing monitor)


@orbit_kernel
def _corrector(fam: _Family, Y_pred, tangent, t0, e_j, c, T_fixed):
    """Newton on [F(Y); tangent·(Y − Y_pred)] = 0 (the only program compiled for continuation)."""
    return bordered_newton(lambda Y: _criterion(fam, Y, t0, e_j, c, T_fixed)[0],
                            fam.root_finder, fam.max_steps, Y_pred, tangent)


def _correct(fam: _Family, Y_pred, tangent, t0, e_j, c, T_fixed, ts_unit):
    """Corrector, then the point's diagnostics from programs shared with `find_periodic_orbit`.

    ∂F/∂(T, x) and the monodromy come from the period map's linearization; ∂F/∂μ, needed
    only for the next tangent, from central differences of the period map.
    """
    # `c` as an array: `filter_jit` treats a Python float as static, and the phase value
    # x_j changes at every step of an autonomous family (a recompilation per point).
    Y, converged, steps = _corrector(fam, jnp.asarray(Y_pred), jnp.asarray(tangent), t0, e_j,
                                     jnp.asarray(c, float), T_fixed)
    Y_np = np.asarray(Y)
    n = Y_np.shape[0] - (1 if fam.fixed_period else 2)
    T, x, mu = (np.asarray(v) for v in _unpack(fam, Y, T_fixed))
    bad = _BranchPoint(Y=Y, tangent=jnp.asarray(tangent), good=False, num_impacts=-1, steps=steps)
    if not (bool(converged) and np.all(np.isfinite(Y_np)) and float(T) > 0):
        return bad
    args, args_dot = jax.jvp(fam.args_of, (jnp.asarray(mu),), (jnp.ones(()),))
    x_end, M, dP_dT, ok, sol, dP_dargs = linearize(fam.pmap, jnp.asarray(x), t0, jnp.asarray(T),
                                                     args, args_dot)
    M, dP_dT = np.asarray(M), np.asarray(dP_dT)
    if not bool(ok) or not np.all(np.isfinite(M)):
        return bad
    dP_dmu = np.asarray(dP_dargs)
    if fam.fixed_period and fam.period_of is not None:
        dP_dmu = dP_dmu + dP_dT * float(jax.jvp(fam.period_of, (jnp.asarray(mu),), (jnp.ones(()),))[1])
    e = np.asarray(e_j)
    if fam.fixed_period:
        J = np.column_stack([M - np.eye(n), dP_dmu])
        a6 = M - np.eye(n)
    else:
        top = np.column_stack([dP_dT, M - np.eye(n), dP_dmu])
        J = np.vstack([top, np.concatenate([[0.0], e, [0.0]])])
        j = int(np.argmax(e))
        free = [k for k in range(n) if k != j]
        a6 = np.column_stack([dP_dT, (M - np.eye(n))[:, free]])
    new_tangent = next_tangent(J, tangent)
    multipliers = eigvals_descending(M)
    # Extremes along the orbit (amplitude), from samples plus the impact states.
    ts = t0 + float(T) * ts_unit
    samples = sampled_states(fam.pmap, jnp.asarray(x), t0, t0 + jnp.asarray(T), args, ts)
    k = int(sol.num_impacts)
    states = np.concatenate([np.asarray(samples.xs), np.asarray(sol.impact_pre[:k]),
                             np.asarray(sol.impact_post[:k])], axis=0)
    f_x = np.asarray(fam.pmap.scene.vector_field(t0, jnp.asarray(x), args))
    # The grazing monitor of an impacting orbit: the smallest normal impact speed |∇Φ·f⁻|
    # (→ 0 at grazing; the family is smooth in it, Nordmark's normal form).
    speed = math.inf
    for m in range(k):
        phi = fam.pmap.scene.surfaces[int(sol.impact_surface[m])].phi
        _, rate, _ = gap_rates_at(phi, fam.pmap.scene.vector_field, sol.impact_times[m],
                               sol.impact_pre[m], args)
        speed = min(speed, abs(float(rate)))
    return _BranchPoint(
        Y=Y, tangent=jnp.asarray(new_tangent), good=bool(np.all(np.isfinite(new_tangent))),
        num_impacts=k, monodromy=M, multipliers=multipliers,
        stable=bool(a5_holds(jnp.asarray(multipliers), fam.fixed_period)), a6=float(np.linalg.det(a6)),
        x_min=states.min(axis=0), x_max=states.max(axis=0), f_x=f_x, steps=steps, period=float(T),
        impact_speed=speed,
    )


# --------------------------------------------------------------------------------------
# continue_orbit
# --------------------------------------------------------------------------------------


def _rephase(scene, orbit: Orbit, args, kw) -> tuple[float, np.ndarray]:
    """A start (t, x) on the orbit half-way between its contacts (impacts, close passes)."""
    t0, T = float(orbit.t0), float(orbit.period)
    contacts = orbit_contacts(scene, orbit, args, solver=kw["solver"], rtol=kw["rtol"],
                              atol=kw["atol"], max_depth=math.inf)
    events = np.asarray(contacts.times, float)
    if len(events) == 0:
        return t0, np.asarray(orbit.x0, float)
    events = np.sort(events)
    gaps = np.diff(np.concatenate([events, [events[0] + T]]))
    m = int(np.argmax(gaps))
    t_s = float(events[m] + 0.5 * gaps[m])
    if t_s >= t0 + T:
        t_s -= T
    pmap = PeriodMap(scene=scene, end_impacts=0, **kw)
    return t_s, state_at(pmap, np.asarray(orbit.x0, float), t0, t_s, args)


def continue_orbit(
    scene: Scene,
    orbit: Orbit,
    args_of: Callable[[Any], Any],
    mu_start: float,
    mu_stop: float,
    *,
    ds: float = 0.02,
    ds_min: float | None = None,
    ds_max: float = 0.1,
    max_points: int = 200,
    period_of: Callable[[Any], Any] | None = None,
    locate_tol: float = 1e-9,
    switch_branches: bool = True,
    progress: bool = True,
    rtol: float = 1e-10,
    atol: float | None = None,
    solver: diffrax.AbstractSolver | None = None,
    newton_tol: float = 1e-8,
    max_newton_steps: int = 8,
    num_samples: int = 400,
) -> Branch:
    r"""Follow a periodic orbit as μ goes from `mu_start` to `mu_stop`, through grazing.

    **Arguments:**

    - `scene`: a [`grazejax.Scene`][].
    - `orbit`: a periodic orbit at `mu_start` (from [`grazejax.find_periodic_orbit`][]).
      It is re-phased to start in the middle of its longest flight (away from impacts),
      so that changes of the impact count show up as grazing, not as a moving start, and
      solved again there by the continuation's own corrector (with μ = mu_start held).
      An orbit whose status is neither SUCCESS nor LOOSE_ATOL, or whose re-solve fails,
      ends the branch at once with status START_FAILED.
    - `args_of`: `args_of(mu) -> args`, traceable (it runs inside `jit`). Pass the same
      function object across calls to reuse the compiled program.
    - `mu_start`, `mu_stop`: the parameter range; the first step goes towards `mu_stop`.
    - `ds`, `ds_min`, `ds_max`: initial, smallest (default `1e-3 * ds`) and largest
      arclength step in (T, x0, μ) space. The step grows by 1.5 after an easy correction
      (≤ 3 Newton steps) and halves after a failure; below `ds_min` the branch end is
      located and other families are looked for.
    - `max_points`: bound on the number of points.
    - `period_of`: forced systems (`orbit.fixed_period`): the period as a function of μ
      (e.g. `lambda mu: 2 * jnp.pi / omega(mu)`); default: the orbit's period, fixed.
    - `locate_tol`: grazing points are located to this accuracy in μ.
    - `switch_branches`: look for the other family where the continued one ends at a
      grazing point.
    - `progress`: a tqdm progress bar (points computed).
    - `rtol`, `atol`, `solver`: for [`grazejax.simulate`][] (`atol=None`: `1e-2 · rtol`
      times the starting orbit's size, as in [`grazejax.find_periodic_orbit`][]);
      `newton_tol`, `max_newton_steps`: the corrector (its absolute tolerance is
      `newton_tol` times the orbit's size).
    - `num_samples`: samples per orbit for `x_min`, `x_max`.

    **Returns:** a [`grazejax.Branch`][] (its points in order of computation, across any
    branch switch; `grazing` lists the grazing points).

    **Example** (ex1dof: the continuous cycle Ψ_μ, grazing at μ = 0, then the impacting
    cycle):

    ```python
    from grazejax import examples as ex
    scene, args_of = ex.ex1dof(), ex.ex1dof_args
    orbit = gj.find_periodic_orbit(scene, [1.7, 0.0], 6.28, args_of(-0.3), fix=1)
    branch = gj.continue_orbit(scene, orbit, args_of, -0.3, 0.3)
    print(branch.grazing[0].mu)   # ≈ 0
    ```
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if not callable(args_of):
        raise TypeError("args_of must be a function mu -> args")
    if int(orbit.status) != OrbitStatus.SUCCESS:
        raise ValueError(f"the starting orbit did not converge: {orbit.message}")
    ds_min = 1e-3 * ds if ds_min is None else ds_min
    if not (ds_min > 0 and ds_max >= ds >= ds_min):
        raise ValueError("need 0 < ds_min <= ds <= ds_max")
    if mu_start == mu_stop:
        raise ValueError("mu_start == mu_stop: nothing to continue")
    fixed = bool(orbit.fixed_period)
    kw, settings, scale = continuation_settings(orbit, rtol, atol, solver, newton_tol,
                                                 max_newton_steps)
    atol = kw["atol"]
    pmap = PeriodMap(scene=scene, end_impacts=0, **kw)
    fam = _Family(
        pmap=pmap, args_of=args_of, period_of=period_of, fixed_period=fixed,
        root_finder=newton_for(newton_tol, scale),
        max_steps=int(max_newton_steps),
    )
    ts_unit = jnp.linspace(0.0, 1.0, int(num_samples), endpoint=False)
    direction = 1.0 if mu_stop > mu_start else -1.0
    T_fixed = jnp.asarray(float(orbit.period))

    # ---- the start: re-phased, then re-solved in the period map used here by the
    # corrector itself (its bordered row fixes μ = mu_start): a separate Newton solve
    # would compile a second Newton program ----
    t_s, x_s = _rephase(scene, orbit, args_of(mu_start), kw)
    n = x_s.shape[0]
    usable = int(orbit.status) in (OrbitStatus.SUCCESS, OrbitStatus.LOOSE_ATOL)
    if not usable or not np.all(np.isfinite(x_s)):
        return _empty_branch(n, ContinuationStatus.START_FAILED, settings)
    tracer = _Tracer(scene=scene, fam=fam, args_of=args_of, kw=kw, fixed=fixed, n=n,
                     t0=jnp.asarray(t_s), T_fixed=T_fixed, ts_unit=ts_unit, ds=float(ds),
                     ds_min=float(ds_min), locate_tol=locate_tol,
                     switch_branches=switch_branches, newton_tol=float(newton_tol))
    first = tracer.begin(x_s, float(orbit.period), mu_start)
    if first is None:
        return _empty_branch(n, ContinuationStatus.START_FAILED, settings)
    first = first._replace(tangent=direction * first.tangent)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_points, desc="grazejax.continue_orbit", unit="pt")
        bar.update(1)
    tracer.bar = bar
    try:
        points, status = trace(
            tracer, first, index=-1, stop=mu_stop, direction=direction,
            steps=Steps(float(ds), float(ds_min), float(ds_max), max_points),
            progress=tracer.progress,
        )
    finally:
        if bar is not None:
            bar.close()
    return _branch(points, tracer.grazing, status, n, float(t_s), settings,
                   tuple(tracer.special))


@dataclasses.dataclass(eq=False)
class _Tracer(Front):
    """`continue_orbit`'s front end of the arclength engine (host side, mutable).

    The engine predicts, corrects, lands on `mu_stop` and adapts the step; this front end
    adds the events of a family of periodic orbits: special points between accepted points
    (solved by their defining systems), a change of the impact count (a grazing point,
    crossed by persistence or ending the family), an impacting family that the corrector
    cannot follow (approached along its impact speed), and branch switching at the end of
    a family (which moves the engine's run to the other family).
    """

    scene: Scene
    fam: _Family
    args_of: Callable
    kw: dict
    fixed: bool
    n: int
    t0: Any
    T_fixed: Any
    ts_unit: Any
    ds: float
    ds_min: float
    locate_tol: float
    switch_branches: bool
    newton_tol: float = 1e-8
    max_refine_steps: int = 30
    bar: Any = None
    j: int = -1
    approach_tried: int = -1
    boundary: Any = None  # where a corrected point found the family's end (`accepts`)
    grazing: list = dataclasses.field(default_factory=list)
    special: list = dataclasses.field(default_factory=list)

    def phase_of(self, x, f_x, j_old=None):
        if self.fixed:
            return jnp.zeros(self.n), 0.0, -1
        f_x = np.asarray(f_x)
        j = j_old
        if j is None or abs(f_x[j]) < 0.1 * np.max(np.abs(f_x)):
            j = int(np.argmax(np.abs(f_x)))
        return jnp.asarray(np.eye(self.n)[j]), float(x[j]), j

    def correct_from(self, point, step, tangent_):
        e, cc, _ = self.phase_of(np.asarray(_x_of(point.Y, self.fixed)), point.f_x, self.j)
        Y_pred = point.Y + step * tangent_
        return _correct(self.fam, Y_pred, tangent_, self.t0, e, cc, self.T_fixed, self.ts_unit)

    def _phase(self, run: Run):
        """The phase condition through the current point (its index j kept while usable)."""
        e_j, c, self.j = self.phase_of(np.asarray(_x_of(run.current.Y, self.fixed)),
                                       run.current.f_x, self.j)
        return e_j, c

    def _natural(self, run: Run):
        return _natural_at(self.fam, run.current, self.phase_of, self.j, self.fixed, self.t0,
                           self.T_fixed, self.ts_unit)

    def _tick(self, count=1, **postfix):
        if self.bar is not None:
            self.bar.update(count)
            if postfix:
                self.bar.set_postfix(**postfix)

    def progress(self, new, h):
        self._tick(mu=f"{float(new.Y[-1]):.5g}", impacts=int(new.num_impacts), ds=f"{h:.2g}")

    def begin(self, x0, period: float, mu_start):
        """The first point at μ = mu_start exactly (the bordered row fixes μ), corrected
        from the start (t0, x0) on the orbit, its tangent oriented towards mu_stop
        (`direction`); None if the corrector fails there."""
        x0 = np.asarray(x0, float)
        Y = jnp.asarray(np.concatenate([[] if self.fixed else [period], x0, [mu_start]]))
        f0 = np.asarray(self.scene.vector_field(self.t0, jnp.asarray(x0), self.args_of(mu_start)))
        e_j, c, self.j = self.phase_of(x0, f0)
        e_mu = jnp.zeros(Y.shape[0]).at[-1].set(1.0)
        first = _correct(self.fam, Y, e_mu, self.t0, e_j, c, self.T_fixed, self.ts_unit)
        if not bool(first.good):
            return None
        return _record(first)

    # ---- the engine's hooks ----

    def correct(self, run: Run, Y_pred, tangent):
        e_j, c = self._phase(run)
        return _record(_correct(self.fam, Y_pred, tangent, self.t0, e_j, c, self.T_fixed,
                                self.ts_unit))

    def land(self, run: Run, guess, e_stop):
        """The corrector at μ = mu_stop from the interpolated guess, kept if it stays on the
        same family (impact count)."""
        e_j, c = self._phase(run)
        last = _natural(self.fam, guess, self.t0, e_j, c, self.T_fixed, self.ts_unit)
        if not (bool(last.good) and int(last.num_impacts) == int(run.current.num_impacts)):
            return None
        self._add_special(run, last)
        self._tick()
        return _record(last)

    def accepts(self, run: Run, new, Y_pred, tangent) -> bool:
        self.boundary = None
        accepted = bool(new.good) and step_accepted(new.Y, new.tangent, Y_pred, tangent, run.h)
        k_now = int(run.current.num_impacts)
        if accepted and int(new.num_impacts) != k_now:
            accepted, self.boundary = self._cross_grazing(run, new, tangent, k_now)
        return accepted

    def accepted(self, run: Run, new) -> None:
        if int(new.num_impacts) == int(run.current.num_impacts):
            self._add_special(run, new)

    def rejected(self, run: Run, tangent):
        k_now = int(run.current.num_impacts)
        if self.boundary is not None:
            return self._family_ends(run, self.boundary, tangent, k_now)
        if k_now > 0 and self.approach_tried != len(run.points):
            return self._approach(run, tangent, k_now)
        return FALL_THROUGH

    def stuck(self, run: Run, tangent):
        # The corrector fails at every step size: locate where the family ends (the last
        # arclength at which it converges with the current impact count).
        run.h = self.ds_min
        k_now = int(run.current.num_impacts)
        boundary, _ = _locate(self.correct_from, run.current, 2 * self.ds_min, tangent, k_now,
                              self.locate_tol)
        return self._family_ends(run, boundary, tangent, k_now)

    # ---- the family's events ----

    def _add_special(self, run: Run, new):
        before = run.points[-2] if len(run.points) > 1 else None
        found = _special_points(self._natural(run), before, run.current, new, self.fixed,
                                self.locate_tol, float(self.t0))
        mus = [float(np.asarray(p.Y)[-1]) for p in (before, run.current, new) if p is not None]
        self.special.extend(self._solved(p, min(mus), max(mus)) for p in found)

    def _solved(self, special: SpecialPoint, lo: float, hi: float) -> SpecialPoint:
        """`special` solved by its defining system, where Newton converges on this family
        (the same impact count, μ within [lo, hi] widened by its width); else as detected."""
        period_of = self.fam.period_of
        point = locate_special(
            self.scene, special, _OneParameter(self.args_of), 0.0, kind=special.kind,
            fixed_period=self.fixed,
            period_of=None if period_of is None else _OneParameter(period_of),
            fix=None if self.fixed else self.j, rtol=self.kw["rtol"], atol=self.kw["atol"],
            solver=self.kw["solver"], newton_tol=self.newton_tol,
            max_steps=self.max_refine_steps,
        )
        mu, width = float(point.mu), hi - lo
        on_family = (int(point.status) == OrbitStatus.SUCCESS
                     and int(point.num_impacts) == special.num_impacts
                     and lo - width <= mu <= hi + width)
        if not on_family:
            return dataclasses.replace(special, fixed_period=self.fixed)
        return dataclasses.replace(
            special, mu=mu, x0=np.asarray(point.x0), period=float(point.period),
            multipliers=np.asarray(point.multipliers), solved=True, fixed_period=self.fixed,
        )

    def _take_other(self, run: Run, located, other, kind):
        """Record the grazing point and go on along the other family from `other`."""
        self.grazing.append(dataclasses.replace(
            located, impacts_after=int(other.num_impacts), kind=kind))
        run.points.append(_record(other))
        run.current = other
        run.h = self.ds

    def _cross_grazing(self, run: Run, new, tangent, k_now):
        """The impact count changed: bisect along the arclength for the grazing point.
        Returns (accepted, boundary)."""
        current = run.current
        scale = 1.0 + float(jnp.max(jnp.abs(current.Y)))
        graze, inner = _locate(self.correct_from, current, run.h, tangent, k_now,
                               self.locate_tol)
        gap = float(jnp.max(jnp.abs((inner.Y - graze.Y)[:-1])))
        if inner is not graze and gap <= 1e-2 * scale:
            # Persistence: the family goes on, with the other impact count.
            self.grazing.append(_grazing_point(
                self.scene, graze, self.args_of, self.fam, self.t0, self.T_fixed, self.fixed,
                k_now, int(new.num_impacts), "persistence", self.kw))
            run.points.extend([_record(graze), _record(inner)])
            return True, None
        # The other count was found far away: the family ends at `graze`.
        return False, graze

    def _approach(self, run: Run, tangent, k_now):
        """An impacting family that the corrector cannot follow: if its impact speed is
        going to 0, approach grazing along the family parametrised by that speed. Returns
        a status, None (go on, on the other family) or FALL_THROUGH (nothing found)."""
        current = run.current
        self.approach_tried = len(run.points)
        reach = 4 * run.h * abs(float(tangent[-1]))
        found = _approach_grazing(self._natural(run), run.points, k_now, self.locate_tol,
                                  reach=reach)
        if found is None:
            return FALL_THROUGH
        mu_star, Y_star, new_points = found
        run.points.extend(_record(pt) for pt in new_points)
        last = new_points[-1] if new_points else current
        end = last._replace(Y=jnp.asarray(Y_star))
        located = _grazing_point(self.scene, end, self.args_of, self.fam, self.t0, self.T_fixed,
                                 self.fixed, k_now, None, "end", self.kw).point
        located = dataclasses.replace(located, mu=mu_star)
        switched = None
        if self.switch_branches:
            # Arrival: from the family's last point towards μ* (near a fold the
            # tangent's μ component can point either way).
            gap_mu = mu_star - float(np.asarray(last.Y)[-1])
            arrival = float(np.sign(gap_mu)) if gap_mu != 0 else (
                1.0 if float(tangent[-1]) >= 0 else -1.0)
            switched = _switch(self.fam, end, self.args_of, self.t0, self.T_fixed, self.fixed,
                               k_now, arrival, self.ds, self.phase_of, self.j, self.ts_unit)
        if switched is None:
            self.grazing.append(located)
            return ContinuationStatus.BRANCH_ENDS
        self._take_other(run, located, *switched)
        self._tick(len(new_points) + 1)
        return None

    def _family_ends(self, run: Run, boundary, tangent, k_now):
        """The family ends at `boundary`: locate the grazing point there and switch to
        another family if one continues."""
        current, fixed = run.current, self.fixed
        located = _grazing_point(self.scene, boundary, self.args_of, self.fam, self.t0,
                                 self.T_fixed, fixed, k_now, None, "end", self.kw)
        if not located.depth_is_small:
            return ContinuationStatus.STEP_TOO_SMALL
        family = [pt for pt in run.points[-4:] if int(pt.num_impacts) == k_now]
        if boundary is not current:
            family.append(boundary)
        located = _extrapolate_end(self.scene, located, family, self.args_of, self.fam,
                                   self.t0, self.T_fixed, fixed, k_now, self.kw)
        switched = None
        if self.switch_branches:
            arrival = 1.0 if float(tangent[-1]) >= 0 else -1.0
            switched = _switch(self.fam, boundary, self.args_of, self.t0, self.T_fixed, fixed,
                               k_now, arrival, self.ds, self.phase_of, self.j, self.ts_unit)
        if switched is None and self.switch_branches and k_now == 0:
            switched = _impacting_family(self.fam, located, boundary, self.args_of, self.t0,
                                         self.T_fixed, fixed, arrival, self.ds, self.phase_of,
                                         self.j, self.ts_unit)
        if boundary is not current:
            run.points.append(_record(boundary))
        if switched is None:
            self.grazing.append(located.point)
            return ContinuationStatus.BRANCH_ENDS
        self._take_other(run, located.point, *switched)
        self._tick(2)
        return None


class _OneParameter(eqx.Module):
    """`fn(mu)` as a function of (μ, ν) (ν unused), for the defining systems of
    `locate_special`. A Module: the same `fn` gives equal systems, which share their
    compiled programs."""

    fn: Callable = eqx.field(static=True)

    def __call__(self, mu, nu):
        return self.fn(mu)



def _x_of(Y, fixed):
    Y = np.asarray(Y)
    return Y[:-1] if fixed else Y[1:-1]


def _record(point: _BranchPoint) -> _BranchPoint:
    """The point with host arrays (what the branch keeps)."""
    return _BranchPoint(*(None if v is None else np.asarray(v) for v in point))


def _empty_branch(n, status, settings=None) -> Branch:
    z = np.zeros((0,))
    return Branch(mu=z, period=z, x0=np.zeros((0, n)), t0=z, multipliers=np.zeros((0, n), complex),
                  num_impacts=np.zeros((0,), int), stable=np.zeros((0,), bool),
                  x_min=np.zeros((0, n)), x_max=np.zeros((0, n)), poincare_determinant=z,
                  grazing=(), status=int(status), settings=settings)


def _branch(points, grazing, status, n, t0, settings=None, special=()) -> Branch:
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


def _locate(correct_from, point, h, tangent, k_from, tol, failing_is_other=False):
    """Bisect the arclength in (0, h] for where the impact count leaves `k_from`.

    Returns `(boundary, inside)`: the last point with `k_from` impacts and the first with
    another count (or, with `failing_is_other`, the last converged point twice).
    """
    lo, hi = 0.0, h
    inside, boundary = None, point
    tangent_mu = abs(float(tangent[-1]))
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        trial = correct_from(point, mid, tangent)
        same = bool(trial.good) and int(trial.num_impacts) == k_from
        if same:
            lo, boundary = mid, trial
        else:
            hi = mid
            if bool(trial.good):
                inside = trial
        mu_b = float(boundary.Y[-1])
        mu_o = float(inside.Y[-1]) if inside is not None else mu_b + (hi - lo) * tangent_mu
        if abs(mu_o - mu_b) <= tol * max(1.0, abs(mu_b)) or hi - lo <= 1e-15 * h:
            break
    return boundary, inside if inside is not None else boundary


@dataclasses.dataclass
class _Located:
    point: GrazingPoint
    depth_is_small: bool


def _grazing_point(scene, point, args_of, fam, t0, T_fixed, fixed, k_before, k_after, kind, kw):
    Y = np.asarray(point.Y)
    mu = float(Y[-1])
    x = _x_of(Y, fixed)
    T = float(T_fixed) if fixed else float(Y[0])
    if fixed and fam.period_of is not None:
        T = float(fam.period_of(mu))
    args = args_of(mu)
    orbit = find_periodic_orbit(scene, x, T, args, t0=float(t0), fixed_period=fixed,
                                start_at_impact=False, rtol=kw["rtol"], atol=kw["atol"],
                                solver=kw["solver"])
    contacts = orbit_contacts(scene, orbit, args, solver=kw["solver"], rtol=kw["rtol"], atol=kw["atol"])
    if len(contacts.depth):
        m = int(np.argmin(np.abs(contacts.depth)))
        surface, time, where, depth = (int(contacts.surfaces[m]), float(contacts.times[m]),
                                       np.asarray(contacts.points[m]), float(contacts.depth[m]))
    else:
        surface, time, where, depth = -1, math.nan, np.full(x.shape, np.nan), math.inf
    gp = GrazingPoint(mu=mu, orbit=orbit, surface=surface, time=time, point=where, depth=depth,
                      impacts_before=int(k_before), impacts_after=k_after, kind=kind)
    scale = 1.0 + float(np.max(np.abs(x)))
    if kind == "persistence":
        return gp
    return _Located(point=gp, depth_is_small=abs(depth) <= 1e-4 * scale)


def _extrapolate_end(scene, located, recent, args_of, fam, t0, T_fixed, fixed, k_now, kw):
    """μ* where a family ends at grazing: its virtual depth extrapolated to 0.

    The end is a square-root tip in (x, μ) (x − x* ∝ √(μ − μ*)): the pseudo-arclength
    corrector fails before reaching it, and at fixed μ Newton's basin shrinks with the
    impact speed v (an impact oscillator's unstable impacting orbit lies within O(v) of
    the non-impacting one). The depth −v²/(2a) is smooth along the family,
    so the last points of the family (approaching the end monotonically in μ) give μ* by a
    fit of μ in powers of √|d| ∝ v (up to four points).
    """
    mus = [float(np.asarray(pt.Y)[-1]) for pt in recent]
    keep = [len(recent) - 1]
    for i in range(len(recent) - 2, -1, -1):
        step_now = mus[keep[-1]] - mus[i]
        step_last = mus[keep[-2]] - mus[keep[-1]] if len(keep) > 1 else step_now
        if step_now == 0 or np.sign(step_now) != np.sign(step_last) or len(keep) == 4:
            break
        keep.append(i)
    if len(keep) < 2:
        return located
    depths = [located.point.depth] + [
        _grazing_point(scene, recent[i], args_of, fam, t0, T_fixed, fixed, k_now, None, "end",
                       kw).point.depth
        for i in keep[1:]
    ]
    d = np.array(depths)
    m = np.array([mus[i] for i in keep])
    if not np.all(np.isfinite(d)) or np.any(np.diff(d) == 0):
        return located
    # Powers of √|d| ∝ v: μ − μ* ∝ v for a forced oscillator (the square-root map),
    # ∝ v² for ex1dof's energy balance; the fit takes both.
    root = np.sqrt(np.abs(d))
    design = np.column_stack([root**p for p in range(len(d))])
    mu_star = float(np.linalg.solve(design, m)[0])
    beyond = np.sign(mu_star - m[0]) == np.sign(m[0] - m[1])
    if not beyond or abs(mu_star - m[0]) > 1e3 * abs(m[1] - m[0]):
        return located
    return dataclasses.replace(located, point=dataclasses.replace(located.point, mu=mu_star))


def _test_functions(multipliers, fixed):
    """(period doubling, Neimark–Sacker) test functions on the non-trivial multipliers."""
    rho = np.asarray(multipliers, complex)
    if not fixed and len(rho):
        rho = np.delete(rho, int(np.argmin(np.abs(rho - 1))))
    pd = float(np.real(np.prod(1 + rho)))
    pairs = [rho[a] * rho[b] - 1 for a in range(len(rho)) for b in range(a + 1, len(rho))]
    ns = float(np.real(np.prod(pairs))) if pairs else 1.0
    return pd, ns


def _special(kind, point, fixed, t0, mu=None, eigenvector=None):
    Y = np.asarray(point.Y)
    return SpecialPoint(kind=kind, mu=float(Y[-1]) if mu is None else float(mu),
                        x0=_x_of(Y, fixed), t0=t0, period=float(point.period),
                        multipliers=np.asarray(point.multipliers),
                        num_impacts=int(point.num_impacts), eigenvector=eigenvector)


def _special_points(natural, before, a, b, fixed, tol, t0, max_solves=16):
    """Special points between consecutive points `a`, `b` of one smooth family."""
    found = []
    mu_a, mu_b = float(np.asarray(a.Y)[-1]), float(np.asarray(b.Y)[-1])
    pd_a, ns_a = _test_functions(a.multipliers, fixed)
    pd_b, ns_b = _test_functions(b.multipliers, fixed)
    if pd_a * pd_b < 0 and mu_a != mu_b:
        # Regula falsi (Illinois) in μ on Π(1 + ρ), a corrector at fixed μ per step.
        lo, hi, f_lo, f_hi = (a, b, pd_a, pd_b)
        best, side = None, 0
        for _ in range(max_solves):
            m_lo, m_hi = float(np.asarray(lo.Y)[-1]), float(np.asarray(hi.Y)[-1])
            w = f_lo / (f_lo - f_hi)
            guess = (1 - w) * np.asarray(lo.Y) + w * np.asarray(hi.Y)
            trial = natural(jnp.asarray(guess))
            if not bool(trial.good) or int(trial.num_impacts) != int(a.num_impacts):
                break
            best = trial
            f = _test_functions(trial.multipliers, fixed)[0]
            if abs(m_hi - m_lo) <= tol * max(1.0, abs(m_lo)) or f == 0:
                break
            if f * f_lo > 0:
                lo, f_lo = trial, f
                f_hi = f_hi / 2 if side == -1 else f_hi
                side = -1
            else:
                hi, f_hi = trial, f
                f_lo = f_lo / 2 if side == 1 else f_lo
                side = 1
            if abs(float(np.asarray(hi.Y)[-1]) - float(np.asarray(lo.Y)[-1])) <= tol * max(1.0, abs(m_lo)):
                break
        if best is not None:
            w, v = np.linalg.eig(np.asarray(best.monodromy))
            m = int(np.argmin(np.abs(w + 1)))
            vec = np.real(v[:, m])
            found.append(_special("period-doubling", best, fixed, t0, eigenvector=vec / np.linalg.norm(vec)))
    if ns_a * ns_b < 0:
        rho = np.asarray(b.multipliers)
        complex_pair = np.any((np.abs(rho.imag) > 1e-8) & (np.abs(np.abs(rho) - 1) < 0.5))
        if complex_pair:
            w = ns_a / (ns_a - ns_b)
            found.append(_special("neimark-sacker", b, fixed, t0, mu=(1 - w) * mu_a + w * mu_b))
    if before is not None:
        mu_0 = float(np.asarray(before.Y)[-1])
        if (mu_a - mu_0) * (mu_b - mu_a) < 0:
            # μ turned back at `a`: the vertex of the parabola through the three points
            # (parametrised by their index: the arclength steps are comparable).
            c2, c1, _ = np.polyfit([-1.0, 0.0, 1.0], [mu_0, mu_a, mu_b], 2)
            s_v = -c1 / (2 * c2) if c2 != 0 else 0.0
            mu_fold = float(np.polyval([c2, c1, mu_a], np.clip(s_v, -1, 1)))
            found.append(_special("fold", a, fixed, t0, mu=mu_fold))
    return found


@orbit_kernel
def _impact_closure(free: PeriodMap, surface, fixed: bool, z, time, args):
    """Residual and Jacobian of an orbit closed by one impact, as a flight (no impacts
    inside): unknowns z = (s, x⁻) with s the impact time θ (forced: the period is `time`)
    or the period T (autonomous: θ = `time`); equations x(θ + T; θ, J(x⁻)) = x⁻ and
    Φ(θ, x⁻) = 0. Smooth in z even at zero impact speed, unlike the period map."""

    def residual(z):
        theta, T = (z[0], time) if fixed else (time, z[0])
        x_pre = z[1:]
        x_post = surface.jump(theta, x_pre, args)
        sol = free.run(x_post, theta, theta + T, args, free.max_impacts)
        return jnp.concatenate([sol.x_final - x_pre, surface.phi(theta, x_pre, args)[None]])

    return residual(z), jax.jacfwd(residual)(z)


def _impacting_family(fam, located, end, args_of, t0, T_fixed, fixed, arrival, ds, phase_of, j,
                      ts_unit):
    """The one-impact family born at the grazing point of a non-impacting family.

    Near grazing the period map's Jacobian grows like 1/v (the impact speed) and Newton's
    basin shrinks with it, so the corrector cannot reach the impacting orbits from the
    grazing one. Instead, each is solved first as a flight closed by its impact
    (`_impact_closure`, smooth at v = 0: the hspo formulation of COCO), started at the
    grazing contact, on each side of μ*; then the corrector polishes it. The side where
    such orbits exist, with an impact speed that shrinks towards μ*, is the new family.
    Returns `(point, kind)` or None."""
    graze = located.point
    if graze.surface < 0 or not np.isfinite(graze.time):
        return None
    scene = fam.pmap.scene
    surface = scene.surfaces[graze.surface]
    free = dataclasses.replace(fam.pmap, scene=Scene(scene.vector_field, ()), max_impacts=1)
    Y_end = np.asarray(end.Y)
    T0 = float(T_fixed) if fixed else float(Y_end[0])
    mu_star = float(graze.mu)
    scale = 1.0 + float(np.max(np.abs(Y_end[:-1])))
    for side, kind in ((arrival, "persistence"), (-arrival, "fold")):
        found = []
        for h in (1e-2 * ds, 1e-1 * ds):
            mu = mu_star + side * h
            args = args_of(jnp.asarray(mu))
            T = T0 if not fixed or fam.period_of is None else float(fam.period_of(mu))
            z = np.concatenate([[graze.time if fixed else T], np.asarray(graze.point, float)])
            ok = False
            for _ in range(30):
                r, J = _impact_closure(free, surface, fixed, jnp.asarray(z),
                                       jnp.asarray(T if fixed else graze.time), args)
                r, J = np.asarray(r), np.asarray(J)
                if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
                    break
                try:
                    dz = np.linalg.solve(J, r)
                except np.linalg.LinAlgError:
                    break
                z = z - dz
                if np.max(np.abs(dz)) <= 1e-13 * scale:
                    ok = True
                    break
            if not ok:
                continue
            theta = float(z[0]) if fixed else float(graze.time)
            period = T if fixed else float(z[0])
            x_pre = jnp.asarray(z[1:])
            # An impact, not a departure: the gap must be closing at θ.
            _, rate, _ = gap_rates_at(surface.phi, scene.vector_field, jnp.asarray(theta), x_pre, args)
            if not float(rate) < 0:
                continue
            x_post = surface.jump(jnp.asarray(theta), x_pre, args)
            # The state at the continuation's phase t0 (mod the period), by the free flight.
            t_target = theta + (float(t0) - theta) % period
            if t_target - theta > 0:
                x_t = np.asarray(free.run(x_post, jnp.asarray(theta), jnp.asarray(t_target), args,
                                          1).x_final)
            else:
                x_t = np.asarray(x_post)
            guess = np.concatenate([[] if fixed else [period], x_t, [mu]])
            natural = _natural_at(fam, end, phase_of, j, fixed, t0, T_fixed, ts_unit)
            point = natural(jnp.asarray(guess))
            if bool(point.good) and int(point.num_impacts) == 1:
                found.append((abs(float(rate)), point))
        if len(found) == 2 and found[0][0] < found[1][0]:
            point = found[-1][1]
            if float(point.tangent[-1]) * side < 0:
                point = point._replace(tangent=-point.tangent)
            return point, kind
    return None


def _natural_at(fam, point, phase_of, j, fixed, t0, T_fixed, ts_unit):
    """`Y ↦ ` the corrector at fixed μ = Y[-1], with the phase condition of `point`."""
    e_j, c, _ = phase_of(np.asarray(_x_of(point.Y, fixed)), point.f_x, j)

    def natural(Y_guess):
        e, cc = e_j, c
        if not fixed:  # the section through the guess itself
            cc = float(np.asarray(Y_guess)[1:-1] @ np.asarray(e_j))
        return _natural(fam, jnp.asarray(Y_guess), t0, e, cc, T_fixed, ts_unit)

    return natural


def _approach_grazing(natural, history, k_from, locate_tol, reach=math.inf, max_solves=12):
    """Locate where an impacting family grazes, from its impacting side.

    Near grazing the family is not smooth in μ (its impact speed v behaves like a power of
    the distance to grazing, Nordmark's normal form), but it is smooth in v. So the last
    points of the family are fitted as polynomials Y(v) (degree ≤ 2), and natural-parameter
    solves at μ = μ(v/4) (from the fit) bring v down geometrically; the grazing μ* = μ(0)
    is extrapolated, to `locate_tol` once two successive estimates agree.

    `natural(Y_guess)` corrects at the fixed μ = Y_guess[-1]. Returns `(mu_star, Y_star,
    points)` (Y_star the fit at v = 0, `points` the new family points in order), or None.
    """
    pts = [p for p in history if int(p.num_impacts) == k_from and math.isfinite(p.impact_speed)]
    pts = pts[-4:]
    if len(pts) < 2:
        return None
    new_points, estimates = [], []
    for _ in range(max_solves):
        v = np.array([p.impact_speed for p in pts[-3:]])
        Ys = np.stack([np.asarray(p.Y) for p in pts[-3:]])
        if v[-1] >= v[-2]:
            return None  # the impact speed is not going to 0 along these points
        degree = min(len(v) - 1, 2)
        coef = np.polyfit(v, Ys, degree)

        def at(value, coef=coef):
            return np.stack([np.polyval(coef[:, i], value) for i in range(coef.shape[1])])

        mu_star = float(at(0.0)[-1])
        if not estimates and abs(mu_star - float(Ys[-1, -1])) > reach:
            return None  # grazing is not within reach of the failed step
        estimates.append(mu_star)
        if len(estimates) >= 2 and abs(estimates[-1] - estimates[-2]) <= locate_tol * max(1.0, abs(mu_star)):
            return mu_star, at(0.0), new_points
        trial = None
        for shrink in (0.25, 0.5, 0.75):
            candidate = natural(jnp.asarray(at(shrink * v[-1])))
            if bool(candidate.good) and int(candidate.num_impacts) == k_from and \
                    candidate.impact_speed < v[-1]:
                trial = candidate
                break
        if trial is None:
            break
        pts.append(trial)
        new_points.append(trial)
    if len(estimates) >= 2 and abs(estimates[-1] - estimates[-2]) <= 1e3 * locate_tol * max(1.0, abs(estimates[-1])):
        return estimates[-1], at(0.0), new_points
    return None


def _natural(fam: _Family, Y_guess, t0, e_j, c, T_fixed, ts_unit):
    """Newton at fixed μ (the last component of Y_guess): the corrector with the bordered
    row (Y − Y_guess)·e_μ = 0. Same compiled program as `_correct`."""
    e_mu = jnp.zeros_like(Y_guess).at[-1].set(1.0)
    return _correct(fam, Y_guess, e_mu, t0, e_j, c, T_fixed, ts_unit)


def _switch(fam, end, args_of, t0, T_fixed, fixed, k_from, direction, ds, phase_of, j, ts_unit):
    """Look for another family next to the grazing orbit `end`.

    First beyond it in the direction of arrival (`direction`: persistence), then on the
    side it came from (a non-smooth fold)."""
    Y = np.asarray(end.Y)
    e_j, c, _ = phase_of(_x_of(Y, fixed), end.f_x, j)
    scale = 1.0 + float(np.max(np.abs(Y[:-1])))
    for side, kind in ((direction, "persistence"), (-direction, "fold")):
        # A family that bifurcates here comes closer as the distance in μ shrinks (like
        # √δμ on an impacting side); an orbit found far away at every distance does not.
        found = []
        for h in (1e-4 * ds, 1e-3 * ds, 1e-2 * ds):
            guess = Y.copy()
            guess[-1] += side * h
            trial = _natural(fam, jnp.asarray(guess), t0, e_j, c, T_fixed, ts_unit)
            if bool(trial.good) and int(trial.num_impacts) != k_from:
                found.append((float(np.max(np.abs(np.asarray(trial.Y)[:-1] - Y[:-1]))), trial))
        if not found or len({int(t.num_impacts) for _, t in found}) > 1:
            continue
        near, trial = found[0]
        far = found[-1][0]
        if not (near <= 1e-3 * scale or (len(found) > 1 and near <= 0.5 * far and near <= 1e-2 * scale)):
            continue
        # Continue from the farthest point found, its tangent along the side it lives on.
        trial = found[-1][1]
        if float(trial.tangent[-1]) * side < 0:
            trial = trial._replace(tangent=-trial.tangent)
        return trial, kind
    return None


def period_doubled_orbit(scene: Scene, point: SpecialPoint, args, *, epsilon: float = 1e-2,
                         **kwargs) -> Orbit:
    r"""Branch switching at a period-doubling point: the period-2 orbit nearby.

    The period-2 orbits bifurcating at a multiplier −1 lie, to first order, along its
    eigenvector e, at a distance ∝ √|μ − μ_PD| on the side where they exist. Newton
    ([`grazejax.find_periodic_orbit`][]) is started from x0 ± ε·|x0|·e with twice the
    period, ε = `epsilon`, 10·`epsilon`, `epsilon`/10; the first start that converges to an
    orbit that is not the period-1 orbit (its half-period map moves x0) is returned. Ask
    for it close to the period-doubling point (|μ − μ_PD| ≲ 1e-2), then continue it.

    **Arguments:** `scene`; `point` (a `"period-doubling"` [`grazejax.SpecialPoint`][]);
    `args` at the parameter where the period-2 orbit is wanted (near `point.mu`); `epsilon`;
    `kwargs` for [`grazejax.find_periodic_orbit`][] (`rtol`, `atol`, ...;
    `fixed_period=False` for an autonomous orbit, default True).

    **Returns:** an [`grazejax.Orbit`][] (check `orbit.status`); continue it with
    [`grazejax.continue_orbit`][] (the period-2 family). Where every start converges to
    the period-1 orbit run twice, that orbit with status `OrbitStatus.NOT_DOUBLED`.
    """
    if point.kind != "period-doubling" or point.eigenvector is None:
        raise ValueError("period_doubled_orbit needs a period-doubling SpecialPoint")
    fixed = bool(kwargs.pop("fixed_period", True))  # forced systems; False: autonomous
    x0 = np.asarray(point.x0, float)
    size = float(np.max(np.abs(x0))) or 1.0
    last = None
    starts = [(sign, eps) for eps in (epsilon, 10 * epsilon, 0.1 * epsilon) for sign in (1.0, -1.0)]
    for sign, eps in starts:
        guess = x0 + sign * eps * size * np.asarray(point.eigenvector)
        orbit = find_periodic_orbit(scene, guess, 2 * point.period, args, t0=point.t0,
                                    fixed_period=fixed, start_at_impact=False, **kwargs)
        last = orbit
        if int(orbit.status) != OrbitStatus.SUCCESS:
            continue
        pmap = PeriodMap(scene=scene, end_impacts=0, solver=kwargs.get("solver"),
                          rtol=float(kwargs.get("rtol", 1e-10)),
                          atol=float(orbit.settings.atol), max_impacts=64, max_solver_steps=50_000)
        half = state_at(pmap, np.asarray(orbit.x0), float(orbit.t0),
                         float(orbit.t0) + float(orbit.period) / 2, args)
        if np.max(np.abs(half - np.asarray(orbit.x0))) > 1e-6 * size:
            return orbit
        last = eqx.tree_at(
            lambda o: o.status, orbit, jnp.asarray(int(OrbitStatus.NOT_DOUBLED), orbit.status.dtype)
        )
    return last


# --------------------------------------------------------------------------------------
# Bifurcation diagram
# --------------------------------------------------------------------------------------
