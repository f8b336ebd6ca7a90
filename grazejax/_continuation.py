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
import enum
import math
from collections.abc import Callable, Sequence
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from ._periodic import (
    Orbit,
    OrbitStatus,
    _a5,
    _linearize,
    _PeriodMap,
    _sampled,
    _state_at,
    find_periodic_orbit,
    orbit_contacts,
)
from ._scene import Scene

# --------------------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------------------


class ContinuationStatus(enum.IntEnum):
    """Why a continuation stopped (`Branch.status`)."""

    REACHED_STOP = 0
    """μ reached `mu_stop`."""
    MAX_POINTS = 1
    """`max_points` points were computed."""
    STEP_TOO_SMALL = 2
    """The corrector kept failing down to `ds_min`, away from any grazing contact."""
    BRANCH_ENDS = 3
    """The family ends at a grazing point and no other family continues from there."""
    START_FAILED = 4
    """The starting orbit could not be (re)solved at `mu_start`."""

    @property
    def message(self) -> str:
        return {
            ContinuationStatus.REACHED_STOP: "reached mu_stop",
            ContinuationStatus.MAX_POINTS: "stopped after max_points points",
            ContinuationStatus.STEP_TOO_SMALL: "the corrector failed down to ds_min "
            "(a fold that pseudo-arclength could not pass, or a non-smooth point)",
            ContinuationStatus.BRANCH_ENDS: "the family ends at a grazing point: no periodic "
            "orbit continues from there on either side",
            ContinuationStatus.START_FAILED: "the starting orbit could not be solved at mu_start",
        }[self]


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

    @property
    def message(self) -> str:
        return ContinuationStatus(self.status).message

    def __len__(self) -> int:
        return len(self.mu)


# --------------------------------------------------------------------------------------
# Compiled kernels
# --------------------------------------------------------------------------------------


class _Family(eqx.Module):
    pmap: _PeriodMap = eqx.field(static=True)
    args_of: Callable = eqx.field(static=True)
    period_of: Callable | None = eqx.field(static=True)
    fixed_period: bool = eqx.field(static=True)
    root_finder: Any = eqx.field(static=True)
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


@eqx.filter_jit
def _corrector(fam: _Family, Y_pred, tangent, t0, e_j, c, T_fixed):
    """Newton on [F(Y); tangent·(Y − Y_pred)] = 0 (the only program compiled for continuation)."""

    def bordered(Y, _):
        rows, _aux = _criterion(fam, Y, t0, e_j, c, T_fixed)
        return jnp.concatenate([rows, jnp.dot(tangent, Y - Y_pred)[None]])

    solution = optx.root_find(bordered, fam.root_finder, Y_pred, None, max_steps=fam.max_steps,
                              throw=False)
    return solution.value, solution.result == optx.RESULTS.successful, solution.stats["num_steps"]


def _correct(fam: _Family, Y_pred, tangent, t0, e_j, c, T_fixed, ts_unit):
    """Corrector, then the point's diagnostics from programs shared with `find_periodic_orbit`.

    ∂F/∂(T, x) and the monodromy come from the period map's linearization; ∂F/∂μ, needed
    only for the next tangent, from central differences of the period map.
    """
    Y, converged, steps = _corrector(fam, jnp.asarray(Y_pred), jnp.asarray(tangent), t0, e_j, c,
                                     T_fixed)
    Y_np = np.asarray(Y)
    n = Y_np.shape[0] - (1 if fam.fixed_period else 2)
    T, x, mu = (np.asarray(v) for v in _unpack(fam, Y, T_fixed))
    bad = dict(Y=Y, tangent=jnp.asarray(tangent), good=False, num_impacts=-1, steps=steps)
    if not (bool(converged) and np.all(np.isfinite(Y_np)) and float(T) > 0):
        return bad
    args, args_dot = jax.jvp(fam.args_of, (jnp.asarray(mu),), (jnp.ones(()),))
    x_end, M, dP_dT, ok, sol, dP_dargs = _linearize(fam.pmap, jnp.asarray(x), t0, jnp.asarray(T),
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
    # Next tangent: the null vector of J, oriented along the old one ([J; tᵀ] τ = e_last).
    A = np.vstack([J, np.asarray(tangent)[None]])
    rhs = np.zeros(Y_np.shape[0])
    rhs[-1] = 1.0
    new_tangent = np.linalg.solve(A, rhs)
    new_tangent /= np.linalg.norm(new_tangent)
    multipliers = _eig_sorted(M)
    # Extremes along the orbit (amplitude), from samples plus the impact states.
    ts = t0 + float(T) * ts_unit
    samples = _sampled(fam.pmap, jnp.asarray(x), t0, t0 + jnp.asarray(T), args, ts)
    k = int(sol.num_impacts)
    states = np.concatenate([np.asarray(samples.xs), np.asarray(sol.impact_pre[:k]),
                             np.asarray(sol.impact_post[:k])], axis=0)
    f_x = np.asarray(fam.pmap.scene.vector_field(t0, jnp.asarray(x), args))
    return dict(
        Y=Y, tangent=jnp.asarray(new_tangent), good=bool(np.all(np.isfinite(new_tangent))),
        num_impacts=k, monodromy=M, multipliers=multipliers,
        stable=bool(_a5(jnp.asarray(multipliers), fam.fixed_period)), a6=float(np.linalg.det(a6)),
        x_min=states.min(axis=0), x_max=states.max(axis=0), f_x=f_x, steps=steps, period=float(T),
    )


def _eig_sorted(matrix):
    w = np.linalg.eigvals(np.asarray(matrix))
    return w[np.argsort(-np.abs(w), kind="stable")].astype(complex)


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
    pmap = _PeriodMap(scene=scene, end_impacts=0, **kw)
    return t_s, _state_at(pmap, np.asarray(orbit.x0, float), t0, t_s, args)


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
    atol: float = 1e-12,
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
      so that changes of the impact count show up as grazing, not as a moving start.
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
    - `rtol`, `atol`, `solver`: for [`grazejax.simulate`][]; `newton_tol`,
      `max_newton_steps`: the corrector.
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
    kw = dict(solver=solver, rtol=float(rtol), atol=float(atol), max_impacts=64,
              max_solver_steps=50_000)
    pmap = _PeriodMap(scene=scene, end_impacts=0, **kw)
    fam = _Family(
        pmap=pmap, args_of=args_of, period_of=period_of, fixed_period=fixed,
        root_finder=optx.Newton(rtol=newton_tol, atol=newton_tol), max_steps=int(max_newton_steps),
    )
    ts_unit = jnp.linspace(0.0, 1.0, int(num_samples), endpoint=False)
    direction = 1.0 if mu_stop > mu_start else -1.0
    T_fixed = jnp.asarray(float(orbit.period))

    # ---- the start: re-phased, re-solved in the period map used here ----
    t_s, x_s = _rephase(scene, orbit, args_of(mu_start), kw)
    start = find_periodic_orbit(
        scene, x_s, float(orbit.period), args_of(mu_start), t0=t_s, fixed_period=fixed,
        start_at_impact=False, rtol=rtol, atol=atol, solver=solver, newton_tol=newton_tol,
    )
    n = x_s.shape[0]
    if int(start.status) != OrbitStatus.SUCCESS:
        return _empty_branch(n, ContinuationStatus.START_FAILED)
    t0 = jnp.asarray(t_s)

    def phase_of(x, f_x, j_old=None):
        if fixed:
            return jnp.zeros(n), 0.0, -1
        f_x = np.asarray(f_x)
        j = j_old
        if j is None or abs(f_x[j]) < 0.1 * np.max(np.abs(f_x)):
            j = int(np.argmax(np.abs(f_x)))
        return jnp.asarray(np.eye(n)[j]), float(x[j]), j

    def pack(T, x, mu):
        return jnp.asarray(np.concatenate([[] if fixed else [T], x, [mu]]))

    Y = pack(float(start.period), np.asarray(start.x0), mu_start)
    f0 = np.asarray(scene.vector_field(t0, start.x0, args_of(mu_start)))
    e_j, c, j = phase_of(np.asarray(start.x0), f0)
    # The first point at μ = mu_start exactly (the bordered row fixes μ); its tangent
    # comes out oriented towards increasing μ.
    e_mu = jnp.zeros(Y.shape[0]).at[-1].set(1.0)
    first = _correct(fam, Y, e_mu, t0, e_j, c, T_fixed, ts_unit)
    if not bool(first["good"]):
        return _empty_branch(n, ContinuationStatus.START_FAILED)
    first = dict(first, tangent=direction * first["tangent"])
    points = [_record(first, fixed)]
    current = first
    grazing: list[GrazingPoint] = []
    status = ContinuationStatus.MAX_POINTS
    h = float(ds)

    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=max_points, desc="grazejax.continue_orbit", unit="pt")
        bar.update(1)

    def correct_from(point, step, tangent_):
        e, cc, _ = phase_of(np.asarray(_x_of(point["Y"], fixed)), point["f_x"], j)
        Y_pred = point["Y"] + step * tangent_
        return _correct(fam, Y_pred, tangent_, t0, e, cc, T_fixed, ts_unit)

    while len(points) < max_points:
        mu_now = float(current["Y"][-1])
        if (mu_now - mu_stop) * direction >= 0:
            status = ContinuationStatus.REACHED_STOP
            break
        e_j, c, j = phase_of(np.asarray(_x_of(current["Y"], fixed)), current["f_x"], j)
        tangent = current["tangent"]
        mu_pred = mu_now + h * float(tangent[-1])
        if (mu_pred - mu_stop) * direction > 0 and float(tangent[-1]) * direction > 0:
            # Land on mu_stop exactly: a corrector at fixed μ from the interpolated guess.
            frac = (mu_stop - mu_now) / (mu_pred - mu_now)
            guess = (current["Y"] + frac * h * tangent).at[-1].set(mu_stop)
            last = _natural(fam, guess, t0, e_j, c, T_fixed, ts_unit)
            if bool(last["good"]) and int(last["num_impacts"]) == int(current["num_impacts"]):
                points.append(_record(last, fixed))
                status = ContinuationStatus.REACHED_STOP
                if bar is not None:
                    bar.update(1)
                break
        Y_pred = current["Y"] + h * tangent
        new = _correct(fam, Y_pred, tangent, t0, e_j, c, T_fixed, ts_unit)
        k_now = int(current["num_impacts"])
        scale = 1.0 + float(jnp.max(jnp.abs(current["Y"])))
        accepted = (
            bool(new["good"]) and float(jnp.dot(new["tangent"], tangent)) > 0.5
            and float(jnp.linalg.norm(new["Y"] - Y_pred)) <= 3 * h
        )
        boundary = None
        if accepted and int(new["num_impacts"]) != k_now:
            # The impact count changed: bisect along the arclength for the grazing point.
            graze, inner = _locate(correct_from, current, h, tangent, k_now, locate_tol)
            gap = float(jnp.max(jnp.abs((inner["Y"] - graze["Y"])[:-1])))
            if inner is not graze and gap <= 1e-2 * scale:
                # Persistence: the family goes on, with the other impact count.
                grazing.append(_grazing_point(scene, graze, args_of, fam, t0, T_fixed, fixed,
                                              k_now, int(new["num_impacts"]), "persistence", kw))
                points.extend([_record(graze, fixed), _record(inner, fixed)])
            else:
                # The other count was found far away: the family ends at `graze`.
                accepted, boundary = False, graze
        if accepted:
            points.append(_record(new, fixed))
            current = new
            if int(new["steps"]) <= 3:
                h = min(1.5 * h, ds_max)
            if bar is not None:
                bar.update(1)
                bar.set_postfix(mu=f"{float(new['Y'][-1]):.5g}", impacts=int(new["num_impacts"]),
                                ds=f"{h:.2g}")
            continue
        if boundary is None:
            h *= 0.5
            if h >= ds_min:
                continue
            h = float(ds_min)
            # The corrector fails at every step size: locate where the family ends (the
            # last arclength at which it converges with k_now impacts).
            boundary, _ = _locate(correct_from, current, 2 * ds_min, tangent, k_now, locate_tol)
        located = _grazing_point(scene, boundary, args_of, fam, t0, T_fixed, fixed, k_now, None,
                                 "end", kw)
        if not located.depth_is_small:
            status = ContinuationStatus.STEP_TOO_SMALL
            break
        family = [pt for pt in points[-4:] if int(pt["num_impacts"]) == k_now]
        if boundary is not current:
            family.append(boundary)
        located = _extrapolate_end(scene, located, family, args_of, fam, t0, T_fixed, fixed,
                                   k_now, kw)
        switched = None
        if switch_branches:
            arrival = 1.0 if float(tangent[-1]) >= 0 else -1.0
            switched = _switch(fam, boundary, args_of, t0, T_fixed, fixed, k_now, arrival, ds,
                               phase_of, j, ts_unit)
        if boundary is not current:
            points.append(_record(boundary, fixed))
        if switched is None:
            grazing.append(located.point)
            status = ContinuationStatus.BRANCH_ENDS
            break
        other, kind = switched
        grazing.append(dataclasses.replace(located.point, impacts_after=int(other["num_impacts"]),
                                           kind=kind))
        points.append(_record(other, fixed))
        current = other
        h = float(ds)
        if bar is not None:
            bar.update(2)
    if bar is not None:
        bar.close()
    return _branch(points, grazing, status, n, float(t_s))


def _x_of(Y, fixed):
    Y = np.asarray(Y)
    return Y[:-1] if fixed else Y[1:-1]


def _record(point, fixed=None) -> dict:
    return {k: np.asarray(v) for k, v in point.items()}


def _empty_branch(n, status) -> Branch:
    z = np.zeros((0,))
    return Branch(mu=z, period=z, x0=np.zeros((0, n)), t0=z, multipliers=np.zeros((0, n), complex),
                  num_impacts=np.zeros((0,), int), stable=np.zeros((0,), bool),
                  x_min=np.zeros((0, n)), x_max=np.zeros((0, n)), poincare_determinant=z,
                  grazing=(), status=int(status))


def _branch(points, grazing, status, n, t0) -> Branch:
    def stack(key):
        return np.stack([p[key] for p in points])

    Ys = stack("Y")
    fixed = Ys.shape[1] == n + 1
    return Branch(
        mu=Ys[:, -1], period=stack("period"), x0=Ys[:, :-1] if fixed else Ys[:, 1:-1],
        t0=np.full(len(points), t0), multipliers=stack("multipliers"),
        num_impacts=stack("num_impacts").astype(int), stable=stack("stable").astype(bool),
        x_min=stack("x_min"), x_max=stack("x_max"), poincare_determinant=stack("a6"),
        grazing=tuple(grazing), status=int(status),
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
        same = bool(trial["good"]) and int(trial["num_impacts"]) == k_from
        if same:
            lo, boundary = mid, trial
        else:
            hi = mid
            if bool(trial["good"]):
                inside = trial
        mu_b = float(boundary["Y"][-1])
        mu_o = float(inside["Y"][-1]) if inside is not None else mu_b + (hi - lo) * tangent_mu
        if abs(mu_o - mu_b) <= tol * max(1.0, abs(mu_b)) or hi - lo <= 1e-15 * h:
            break
    return boundary, inside if inside is not None else boundary


@dataclasses.dataclass
class _Located:
    point: GrazingPoint
    depth_is_small: bool


def _grazing_point(scene, point, args_of, fam, t0, T_fixed, fixed, k_before, k_after, kind, kw):
    Y = np.asarray(point["Y"])
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
    mus = [float(np.asarray(pt["Y"])[-1]) for pt in recent]
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


def _natural(fam: _Family, Y_guess, t0, e_j, c, T_fixed, ts_unit):
    """Newton at fixed μ (the last component of Y_guess): the corrector with the bordered
    row (Y − Y_guess)·e_μ = 0. Same compiled program as `_correct`."""
    e_mu = jnp.zeros_like(Y_guess).at[-1].set(1.0)
    return _correct(fam, Y_guess, e_mu, t0, e_j, c, T_fixed, ts_unit)


def _switch(fam, end, args_of, t0, T_fixed, fixed, k_from, direction, ds, phase_of, j, ts_unit):
    """Look for another family next to the grazing orbit `end`.

    First beyond it in the direction of arrival (`direction`: persistence), then on the
    side it came from (a non-smooth fold)."""
    Y = np.asarray(end["Y"])
    e_j, c, _ = phase_of(_x_of(Y, fixed), end["f_x"], j)
    scale = 1.0 + float(np.max(np.abs(Y[:-1])))
    for side, kind in ((direction, "persistence"), (-direction, "fold")):
        # A family that bifurcates here comes closer as the distance in μ shrinks (like
        # √δμ on an impacting side); an orbit found far away at every distance does not.
        found = []
        for h in (1e-4 * ds, 1e-3 * ds, 1e-2 * ds):
            guess = Y.copy()
            guess[-1] += side * h
            trial = _natural(fam, jnp.asarray(guess), t0, e_j, c, T_fixed, ts_unit)
            if bool(trial["good"]) and int(trial["num_impacts"]) != k_from:
                found.append((float(np.max(np.abs(np.asarray(trial["Y"])[:-1] - Y[:-1]))), trial))
        if not found or len({int(t["num_impacts"]) for _, t in found}) > 1:
            continue
        near, trial = found[0]
        far = found[-1][0]
        if not (near <= 1e-3 * scale or (len(found) > 1 and near <= 0.5 * far and near <= 1e-2 * scale)):
            continue
        # Continue from the farthest point found, its tangent along the side it lives on.
        trial = found[-1][1]
        if float(trial["tangent"][-1]) * side < 0:
            trial = dict(trial, tangent=-trial["tangent"])
        return trial, kind
    return None


# --------------------------------------------------------------------------------------
# Bifurcation diagram
# --------------------------------------------------------------------------------------


def plot_bifurcation_diagram(
    branches: Branch | Sequence[Branch],
    path=None,
    *,
    coordinate: int = 0,
    measure: str = "max",
    ax=None,
    title: str | None = None,
    mu_label: str = "μ",
    dpi: int = 150,
):
    r"""Draw branches of periodic orbits: amplitude vs μ, stability, impacts per period.

    **Arguments:**

    - `branches`: one [`grazejax.Branch`][] or several.
    - `path`: if given, the figure is saved there as a PNG.
    - `coordinate`: which state coordinate measures the orbit.
    - `measure`: `"max"` (largest value of the coordinate along the orbit), `"min"`, or
      `"amplitude"` (max − min).
    - `ax`: a Matplotlib `Axes` to draw on (default: a new figure).
    - `title`, `mu_label`, `dpi`: labels and resolution.

    Stable orbits ((A5) holds) are solid lines, unstable ones dashed; the colour is the
    number of impacts per period; grazing points are black diamonds (labelled with their
    kind: persistence, fold, end).

    **Returns:** the Matplotlib `Figure`.
    """
    import matplotlib

    if ax is None and path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    if isinstance(branches, Branch):
        branches = [branches]
    if measure not in ("max", "min", "amplitude"):
        raise ValueError(f"measure must be 'max', 'min' or 'amplitude', got {measure!r}")
    if ax is None:
        fig, ax = plt.subplots(figsize=(7.5, 4.8))
    else:
        fig = ax.figure
    counts = sorted({int(k) for b in branches for k in np.asarray(b.num_impacts)})
    cmap = plt.get_cmap("tab10")
    colour = {k: cmap(i % 10) for i, k in enumerate(counts)}

    def value(b, idx):
        lo, hi = np.asarray(b.x_min)[idx, coordinate], np.asarray(b.x_max)[idx, coordinate]
        return {"max": hi, "min": lo, "amplitude": hi - lo}[measure]

    seen = set()
    for b in branches:
        mu = np.asarray(b.mu)
        if len(mu) == 0:
            continue
        k = np.asarray(b.num_impacts)
        stable = np.asarray(b.stable)
        y = value(b, slice(None))
        # One line per run of equal (impacts, stability).
        start = 0
        for i in range(1, len(mu) + 1):
            if i < len(mu) and k[i] == k[start] and stable[i] == stable[start]:
                continue
            seg = slice(start, i + 1 if i < len(mu) and k[i] == k[start] else i)
            label_key = (int(k[start]), bool(stable[start]))
            label = None
            if label_key not in seen:
                seen.add(label_key)
                label = f"{int(k[start])} impact(s)/period, {'stable' if stable[start] else 'unstable'}"
            ax.plot(mu[seg], y[seg], "-" if stable[start] else "--", color=colour[int(k[start])],
                    lw=1.8, label=label, marker="." if i - start < 3 else None)
            start = i
        for g in b.grazing:
            idx = int(np.argmin(np.abs(mu - g.mu)))
            ax.plot([g.mu], [y[idx]], "D", color="k", ms=6, zorder=5)
            ax.annotate(f"grazing ({g.kind})\nμ = {g.mu:.6g}", (g.mu, y[idx]),
                        textcoords="offset points", xytext=(6, -22), fontsize=8)
    ax.set_xlabel(mu_label)
    ax.set_ylabel({"max": f"max x{coordinate + 1}", "min": f"min x{coordinate + 1}",
                   "amplitude": f"amplitude of x{coordinate + 1}"}[measure])
    if title:
        ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    if path is not None:
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return fig
