"""Events along a branch of periodic orbits: grazing located by bisection of the arclength,
switching to the family with the other impact count, and special points (period doubling,
Neimark–Sacker) between accepted points."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .branch import GrazingPoint, SpecialPoint
from .contacts import orbit_contacts
from .family import (
    natural_corrector,
    natural_point,
    x_of,
)
from .period_map import (
    PeriodMap,
    gap_rates_at,
    orbit_kernel,
)
from .periodic import find_periodic_orbit


class OneParameter(eqx.Module):
    """`fn(mu)` as a function of (μ, ν) (ν unused), for the defining systems of
    `locate_special`. A Module: the same `fn` gives equal systems, which share their
    compiled programs."""

    fn: Callable = eqx.field(static=True)

    def __call__(self, mu, nu):
        return self.fn(mu)


def locate_count_change(correct_from, point, h, tangent, k_from, tol, failing_is_other=False):
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
class LocatedGrazing:
    point: GrazingPoint
    depth_is_small: bool


def grazing_point(scene, point, args_of, fam, t0, T_fixed, fixed, k_before, k_after, kind, kw):
    Y = np.asarray(point.Y)
    mu = float(Y[-1])
    x = x_of(Y, fixed)
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
    return LocatedGrazing(point=gp, depth_is_small=abs(depth) <= 1e-4 * scale)


def extrapolate_end(scene, located, recent, args_of, fam, t0, T_fixed, fixed, k_now, kw):
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
        grazing_point(scene, recent[i], args_of, fam, t0, T_fixed, fixed, k_now, None, "end",
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


def special_test_functions(multipliers, fixed):
    """(period doubling, Neimark–Sacker) test functions on the non-trivial multipliers."""
    rho = np.asarray(multipliers, complex)
    if not fixed and len(rho):
        rho = np.delete(rho, int(np.argmin(np.abs(rho - 1))))
    pd = float(np.real(np.prod(1 + rho)))
    pairs = [rho[a] * rho[b] - 1 for a in range(len(rho)) for b in range(a + 1, len(rho))]
    ns = float(np.real(np.prod(pairs))) if pairs else 1.0
    return pd, ns


def special_point(kind, point, fixed, t0, mu=None, eigenvector=None):
    Y = np.asarray(point.Y)
    return SpecialPoint(kind=kind, mu=float(Y[-1]) if mu is None else float(mu),
                        x0=x_of(Y, fixed), t0=t0, period=float(point.period),
                        multipliers=np.asarray(point.multipliers),
                        num_impacts=int(point.num_impacts), eigenvector=eigenvector)


def special_points_between(natural, before, a, b, fixed, tol, t0, max_solves=16):
    """Special points between consecutive points `a`, `b` of one smooth family."""
    found = []
    mu_a, mu_b = float(np.asarray(a.Y)[-1]), float(np.asarray(b.Y)[-1])
    pd_a, ns_a = special_test_functions(a.multipliers, fixed)
    pd_b, ns_b = special_test_functions(b.multipliers, fixed)
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
            f = special_test_functions(trial.multipliers, fixed)[0]
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
            found.append(special_point("period-doubling", best, fixed, t0, eigenvector=vec / np.linalg.norm(vec)))
    if ns_a * ns_b < 0:
        rho = np.asarray(b.multipliers)
        complex_pair = np.any((np.abs(rho.imag) > 1e-8) & (np.abs(np.abs(rho) - 1) < 0.5))
        if complex_pair:
            w = ns_a / (ns_a - ns_b)
            found.append(special_point("neimark-sacker", b, fixed, t0, mu=(1 - w) * mu_a + w * mu_b))
    if before is not None:
        mu_0 = float(np.asarray(before.Y)[-1])
        if (mu_a - mu_0) * (mu_b - mu_a) < 0:
            # μ turned back at `a`: the vertex of the parabola through the three points
            # (parametrised by their index: the arclength steps are comparable).
            c2, c1, _ = np.polyfit([-1.0, 0.0, 1.0], [mu_0, mu_a, mu_b], 2)
            s_v = -c1 / (2 * c2) if c2 != 0 else 0.0
            mu_fold = float(np.polyval([c2, c1, mu_a], np.clip(s_v, -1, 1)))
            found.append(special_point("fold", a, fixed, t0, mu=mu_fold))
    return found


@orbit_kernel
def impact_closure(free: PeriodMap, surface, fixed: bool, z, time, args):
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


def impacting_family(fam, located, end, args_of, t0, T_fixed, fixed, arrival, ds, phase_of, j,
                      ts_unit):
    """The one-impact family born at the grazing point of a non-impacting family.

    Near grazing the period map's Jacobian grows like 1/v (the impact speed) and Newton's
    basin shrinks with it, so the corrector cannot reach the impacting orbits from the
    grazing one. Instead, each is solved first as a flight closed by its impact
    (`impact_closure`, smooth at v = 0: the hspo formulation of COCO), started at the
    grazing contact, on each side of μ*; then the corrector polishes it. The side where
    such orbits exist, with an impact speed that shrinks towards μ*, is the new family.
    Returns `(point, kind)` or None."""
    graze = located.point
    if graze.surface < 0 or not np.isfinite(graze.time):
        return None
    scene = fam.pmap.scene
    surface = scene.surfaces[graze.surface]
    free = dataclasses.replace(fam.pmap, scene=scene.with_surfaces(()), max_impacts=1)
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
                r, J = impact_closure(free, surface, fixed, jnp.asarray(z),
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
            natural = natural_corrector(fam, end, phase_of, j, fixed, t0, T_fixed, ts_unit)
            point = natural(jnp.asarray(guess))
            if bool(point.good) and int(point.num_impacts) == 1:
                found.append((abs(float(rate)), point))
        if len(found) == 2 and found[0][0] < found[1][0]:
            point = found[-1][1]
            if float(point.tangent[-1]) * side < 0:
                point = point._replace(tangent=-point.tangent)
            return point, kind
    return None


def approach_grazing(natural, history, k_from, locate_tol, reach=math.inf, max_solves=12):
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


def switch_family(fam, end, args_of, t0, T_fixed, fixed, k_from, direction, ds, phase_of, j, ts_unit):
    """Look for another family next to the grazing orbit `end`.

    First beyond it in the direction of arrival (`direction`: persistence), then on the
    side it came from (a non-smooth fold)."""
    Y = np.asarray(end.Y)
    e_j, c, _ = phase_of(x_of(Y, fixed), end.f_x, j)
    scale = 1.0 + float(np.max(np.abs(Y[:-1])))
    for side, kind in ((direction, "persistence"), (-direction, "fold")):
        # A family that bifurcates here comes closer as the distance in μ shrinks (like
        # √δμ on an impacting side); an orbit found far away at every distance does not.
        found = []
        for h in (1e-4 * ds, 1e-3 * ds, 1e-2 * ds):
            guess = Y.copy()
            guess[-1] += side * h
            trial = natural_point(fam, jnp.asarray(guess), t0, e_j, c, T_fixed, ts_unit)
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

