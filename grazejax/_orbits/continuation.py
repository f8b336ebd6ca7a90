r"""Continuation of periodic orbits in a scalar parameter μ, through grazing bifurcations.

`grazejax.continue_orbit` follows a family of periodic orbits by pseudo-arclength
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

`grazejax.plot_bifurcation_diagram` draws the branches (amplitude vs μ, stable solid,
unstable dashed, coloured by impacts per period, grazing points marked) and saves a PNG.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._scene import Scene
from .._status import ContinuationStatus
from .arclength import (
    FALL_THROUGH,
    Front,
    Run,
    Steps,
    continuation_settings,
    step_accepted,
    trace,
)
from .bifurcation import locate_special
from .branch import Branch, SpecialPoint, branch_of, empty_branch
from .contacts import orbit_contacts
from .family import (
    OrbitFamily,
    correct_point,
    natural_corrector,
    natural_point,
    record_point,
    x_of,
)
from .forced_period import require_period_fixed_in
from .period_map import (
    PeriodMap,
    newton_for,
    state_at,
)
from .periodic import Orbit, OrbitStatus, find_periodic_orbit
from .switching import (
    OneParameter,
    approach_grazing,
    extrapolate_end,
    grazing_point,
    impacting_family,
    locate_count_change,
    special_points_between,
    switch_family,
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

    - `scene`: a `grazejax.Scene`.
    - `orbit`: a periodic orbit at `mu_start` (from `grazejax.find_periodic_orbit`).
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
    - `rtol`, `atol`, `solver`: for `grazejax.simulate` (`atol=None`: `1e-2 · rtol`
      times the starting orbit's size, as in `grazejax.find_periodic_orbit`);
      `newton_tol`, `max_newton_steps`: the corrector (its absolute tolerance is
      `newton_tol` times the orbit's size).
    - `num_samples`: samples per orbit for `x_min`, `x_max`.

    **Returns:** a `grazejax.Branch` (its points in order of computation, across any
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
    if fixed and period_of is None:
        require_period_fixed_in(
            scene, args_of, mu_start, orbit.t0, orbit.x0, orbit.period,
            caller="continue_orbit", parameter="μ",
            fix="Pass period_of=lambda mu: <the forcing's period> (e.g. 2π/μ for a forcing "
                "cos(μt)).")
    kw, settings, scale = continuation_settings(orbit, rtol, atol, solver, newton_tol,
                                                 max_newton_steps)
    atol = kw["atol"]
    pmap = PeriodMap(scene=scene, end_impacts=0, **kw)
    fam = OrbitFamily(
        pmap=pmap, args_of=args_of, period_of=period_of, fixed_period=fixed,
        root_finder=newton_for(newton_tol, scale),
        max_newton_steps=int(max_newton_steps),
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
        return empty_branch(n, ContinuationStatus.START_FAILED, settings)
    tracer = _Tracer(scene=scene, fam=fam, args_of=args_of, kw=kw, fixed=fixed, n=n,
                     t0=jnp.asarray(t_s), T_fixed=T_fixed, ts_unit=ts_unit, ds=float(ds),
                     ds_min=float(ds_min), locate_tol=locate_tol,
                     switch_branches=switch_branches, newton_tol=float(newton_tol))
    first = tracer.begin(x_s, float(orbit.period), mu_start)
    if first is None:
        return empty_branch(n, ContinuationStatus.START_FAILED, settings)
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
    return branch_of(points, tracer.grazing, status, n, float(t_s), settings,
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
    fam: OrbitFamily
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
        e, cc, _ = self.phase_of(np.asarray(x_of(point.Y, self.fixed)), point.f_x, self.j)
        Y_pred = point.Y + step * tangent_
        return correct_point(self.fam, Y_pred, tangent_, self.t0, e, cc, self.T_fixed, self.ts_unit)

    def _phase(self, run: Run):
        """The phase condition through the current point (its index j kept while usable)."""
        e_j, c, self.j = self.phase_of(np.asarray(x_of(run.current.Y, self.fixed)),
                                       run.current.f_x, self.j)
        return e_j, c

    def _natural(self, run: Run):
        return natural_corrector(self.fam, run.current, self.phase_of, self.j, self.fixed, self.t0,
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
        first = correct_point(self.fam, Y, e_mu, self.t0, e_j, c, self.T_fixed, self.ts_unit)
        if not bool(first.good):
            return None
        return record_point(first)

    # ---- the engine's hooks ----

    def correct(self, run: Run, Y_pred, tangent):
        e_j, c = self._phase(run)
        return record_point(correct_point(self.fam, Y_pred, tangent, self.t0, e_j, c, self.T_fixed,
                                self.ts_unit))

    def land(self, run: Run, guess, e_stop):
        """The corrector at μ = mu_stop from the interpolated guess, kept if it stays on the
        same family (impact count)."""
        e_j, c = self._phase(run)
        last = natural_point(self.fam, guess, self.t0, e_j, c, self.T_fixed, self.ts_unit)
        if not (bool(last.good) and int(last.num_impacts) == int(run.current.num_impacts)):
            return None
        self._add_special(run, last)
        self._tick()
        return record_point(last)

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
        boundary, _ = locate_count_change(self.correct_from, run.current, 2 * self.ds_min, tangent, k_now,
                              self.locate_tol)
        return self._family_ends(run, boundary, tangent, k_now)

    # ---- the family's events ----

    def _add_special(self, run: Run, new):
        before = run.points[-2] if len(run.points) > 1 else None
        found = special_points_between(self._natural(run), before, run.current, new, self.fixed,
                                self.locate_tol, float(self.t0))
        mus = [float(np.asarray(p.Y)[-1]) for p in (before, run.current, new) if p is not None]
        self.special.extend(self._solved(p, min(mus), max(mus)) for p in found)

    def _solved(self, special: SpecialPoint, lo: float, hi: float) -> SpecialPoint:
        """`special` solved by its defining system, where Newton converges on this family
        (the same impact count, μ within [lo, hi] widened by its width); else as detected."""
        period_of = self.fam.period_of
        point = locate_special(
            self.scene, special, OneParameter(self.args_of), 0.0, kind=special.kind,
            fixed_period=self.fixed,
            period_of=None if period_of is None else OneParameter(period_of),
            fix=None if self.fixed else self.j, rtol=self.kw["rtol"], atol=self.kw["atol"],
            solver=self.kw["solver"], newton_tol=self.newton_tol,
            max_newton_steps=self.max_refine_steps,
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
        run.points.append(record_point(other))
        run.current = other
        run.h = self.ds

    def _cross_grazing(self, run: Run, new, tangent, k_now):
        """The impact count changed: bisect along the arclength for the grazing point.
        Returns (accepted, boundary)."""
        current = run.current
        scale = 1.0 + float(jnp.max(jnp.abs(current.Y)))
        graze, inner = locate_count_change(self.correct_from, current, run.h, tangent, k_now,
                               self.locate_tol)
        gap = float(jnp.max(jnp.abs((inner.Y - graze.Y)[:-1])))
        if inner is not graze and gap <= 1e-2 * scale:
            # Persistence: the family goes on, with the other impact count.
            self.grazing.append(grazing_point(
                self.scene, graze, self.args_of, self.fam, self.t0, self.T_fixed, self.fixed,
                k_now, int(new.num_impacts), "persistence", self.kw))
            run.points.extend([record_point(graze), record_point(inner)])
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
        found = approach_grazing(self._natural(run), run.points, k_now, self.locate_tol,
                                  reach=reach)
        if found is None:
            return FALL_THROUGH
        mu_star, Y_star, new_points = found
        run.points.extend(record_point(pt) for pt in new_points)
        last = new_points[-1] if new_points else current
        end = last._replace(Y=jnp.asarray(Y_star))
        located = grazing_point(self.scene, end, self.args_of, self.fam, self.t0, self.T_fixed,
                                 self.fixed, k_now, None, "end", self.kw).point
        located = dataclasses.replace(located, mu=mu_star)
        switched = None
        if self.switch_branches:
            # Arrival: from the family's last point towards μ* (near a fold the
            # tangent's μ component can point either way).
            gap_mu = mu_star - float(np.asarray(last.Y)[-1])
            arrival = float(np.sign(gap_mu)) if gap_mu != 0 else (
                1.0 if float(tangent[-1]) >= 0 else -1.0)
            switched = switch_family(self.fam, end, self.args_of, self.t0, self.T_fixed, self.fixed,
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
        located = grazing_point(self.scene, boundary, self.args_of, self.fam, self.t0,
                                 self.T_fixed, fixed, k_now, None, "end", self.kw)
        if not located.depth_is_small:
            return ContinuationStatus.STEP_TOO_SMALL
        family = [pt for pt in run.points[-4:] if int(pt.num_impacts) == k_now]
        if boundary is not current:
            family.append(boundary)
        located = extrapolate_end(self.scene, located, family, self.args_of, self.fam,
                                   self.t0, self.T_fixed, fixed, k_now, self.kw)
        switched = None
        if self.switch_branches:
            arrival = 1.0 if float(tangent[-1]) >= 0 else -1.0
            switched = switch_family(self.fam, boundary, self.args_of, self.t0, self.T_fixed, fixed,
                               k_now, arrival, self.ds, self.phase_of, self.j, self.ts_unit)
        if switched is None and self.switch_branches and k_now == 0:
            switched = impacting_family(self.fam, located, boundary, self.args_of, self.t0,
                                         self.T_fixed, fixed, arrival, self.ds, self.phase_of,
                                         self.j, self.ts_unit)
        if boundary is not current:
            run.points.append(record_point(boundary))
        if switched is None:
            self.grazing.append(located.point)
            return ContinuationStatus.BRANCH_ENDS
        self._take_other(run, located.point, *switched)
        self._tick(2)
        return None


def period_doubled_orbit(scene: Scene, point: SpecialPoint, args, *, epsilon: float = 1e-2,
                         **kwargs) -> Orbit:
    r"""Branch switching at a period-doubling point: the period-2 orbit nearby.

    The period-2 orbits bifurcating at a multiplier −1 lie, to first order, along its
    eigenvector e, at a distance ∝ √|μ − μ_PD| on the side where they exist. Newton
    (`grazejax.find_periodic_orbit`) is started from x0 ± ε·|x0|·e with twice the
    period, ε = `epsilon`, 10·`epsilon`, `epsilon`/10; the first start that converges to an
    orbit that is not the period-1 orbit (its half-period map moves x0) is returned. Ask
    for it close to the period-doubling point (|μ − μ_PD| ≲ 1e-2), then continue it.

    **Arguments:** `scene`; `point` (a `"period-doubling"` `grazejax.SpecialPoint`);
    `args` at the parameter where the period-2 orbit is wanted (near `point.mu`); `epsilon`;
    `kwargs` for `grazejax.find_periodic_orbit` (`rtol`, `atol`, ...;
    `fixed_period=False` for an autonomous orbit, default True).

    **Returns:** an `grazejax.Orbit` (check `orbit.status`); continue it with
    `grazejax.continue_orbit` (the period-2 family). Where every start converges to
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
