"""Where an orbit meets or nearly meets its surfaces: impacts, near-grazing passes
(`grazejax.orbit_contacts`) and the branches they lead to
(`grazejax.grazing_branches`)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._compiler import single_run_jit
from .._geometry import gap_rates
from .._scene import Scene
from .period_map import (
    PeriodMap,
    a5_holds,
    atol_for,
    gap_rates_at,
    linearize,
    run_period_map,
    sampled_states,
    state_at,
)
from .periodic import Orbit

# --------------------------------------------------------------------------------------
# Contacts along an orbit: impacts and near-grazing passes
# --------------------------------------------------------------------------------------


class Contacts(eqx.Module):
    r"""Where an orbit meets or nearly meets its surfaces (`grazejax.orbit_contacts`).

    One row per impact and per local minimum of a gap Φ_i along a flight (inside the
    closed piece), sorted by time. NumPy arrays.

    **Fields:**

    - `times`, `points`: time and state of the contact (pre-impact state for impacts;
      the state at the minimum of Φ_i for passes).
    - `surfaces`: surface index.
    - `is_impact`: True for impacts, False for passes without an impact.
    - `depth`: the signed *virtual depth*, a grazing indicator continuous across grazing:
      for a pass, the minimum of Φ_i (≥ 0: the clearance); for an impact, −v²/(2a), the
      minimum the flight would reach without the impact (v = dΦ/dt < 0 and a = d²Φ/dt² at
      the pre-impact state; −inf if a ≤ 0). depth = 0 is a grazing contact (γ).
    - `speed`, `acceleration`: dΦ/dt and d²Φ/dt² at the contact.
    """

    times: Any
    points: Any
    surfaces: Any
    is_impact: Any
    depth: Any
    speed: Any
    acceleration: Any

    def grazing(self, tol: float) -> np.ndarray:
        """Boolean mask of the contacts with |depth| ≤ tol."""
        return np.abs(np.asarray(self.depth)) <= tol


@single_run_jit
def _gap_table(scene: Scene, ts, xs, args):
    """Φ_i, dΦ_i/dt, d²Φ_i/dt² and `where_i` at many (t, x), for every surface."""
    rows = []
    for i, surface in enumerate(scene.surfaces):
        g, gd, gdd = jax.vmap(lambda t, x, i=i: gap_rates(scene.surfaces[i].phi, scene.vector_field, t, x, args))(ts, xs)
        if surface.where is None:
            inside = jnp.ones_like(g, dtype=bool)
        else:
            inside = jax.vmap(lambda t, x, s=surface: jnp.asarray(s.where(t, x, args), bool))(ts, xs)
        rows.append((g, gd, gdd, inside))
    return rows


def _refine_minimum(pmap, scene, i, x0, t0, t_guess, args, lo, hi):
    """One Newton step on dΦ/dt = 0 from t_guess, with the exact state there."""
    t_guess = float(np.clip(t_guess, lo, hi))
    x = state_at(pmap, x0, t0, t_guess, args)
    g, gd, gdd = (float(v) for v in gap_rates_at(scene.surfaces[i].phi, scene.vector_field, jnp.asarray(t_guess), jnp.asarray(x), args))
    if gdd > 0:
        dt = float(np.clip(-gd / gdd, lo - t_guess, hi - t_guess))
        t_min = t_guess + dt
        depth = g + gd * dt + 0.5 * gdd * dt * dt
        x_min = state_at(pmap, x0, t0, t_min, args)
        return t_min, x_min, depth, gd + gdd * dt, gdd
    return t_guess, x, g, gd, gdd


def orbit_contacts(scene: Scene, orbit: Orbit, args=None, *, num_samples: int = 400,
                   max_depth: float = 0.05, solver=None, rtol: float = 1e-10,
                   atol: float | None = None) -> Contacts:
    r"""The impacts of an orbit and its near-grazing passes, with a grazing indicator.

    Passes are local minima of Φ_i along the flights, found on `num_samples` samples of
    one period and refined by a Newton step on dΦ/dt = 0 with the exact state; only those
    inside the closed piece with |min Φ_i| ≤ `max_depth` are kept. See `grazejax.Contacts`
    for the signed depth (the indicator used to locate grazing bifurcations).
    `atol=None`: scaled to the orbit's size, as in `grazejax.find_periodic_orbit`.
    """
    atol = atol_for(orbit, rtol, atol)
    pmap = PeriodMap(scene=scene, end_impacts=0, solver=solver, rtol=float(rtol),
                      atol=float(atol), max_impacts=64, max_solver_steps=50_000)
    t0, T = float(orbit.t0), float(orbit.period)
    x0 = np.asarray(orbit.x0, float)
    k = int(orbit.num_impacts)
    rows = []  # (time, point, surface, is_impact, depth, speed, accel)
    times = np.asarray(orbit.impact_times[:k], float)
    for m in range(k):
        i = int(orbit.impact_surface[m])
        pre = np.asarray(orbit.impact_pre[m], float)
        g, gd, gdd = (float(v) for v in gap_rates_at(scene.surfaces[i].phi, scene.vector_field, jnp.asarray(times[m]), jnp.asarray(pre), args))
        depth = -gd * gd / (2 * gdd) if gdd > 0 else -math.inf
        rows.append((times[m], pre, i, True, depth, gd, gdd))
    if scene.surfaces:
        ts = t0 + T * (np.arange(num_samples) + 0.5) / num_samples
        sol = sampled_states(pmap, jnp.asarray(x0), jnp.asarray(t0), jnp.asarray(t0 + T), args, jnp.asarray(ts))
        xs = np.asarray(sol.xs)
        table = _gap_table(scene, jnp.asarray(ts), jnp.asarray(xs), args)
        h = T / num_samples
        # Samples whose neighbourhood contains an impact see a jump, not a minimum.
        near_impact = np.zeros(num_samples, bool)
        for tm in times:
            near_impact |= np.abs(ts - tm) <= 1.5 * h
        for i, (g, _, _, inside) in enumerate(table):
            g = np.asarray(g)
            for m in range(1, num_samples - 1):
                if near_impact[m] or not (g[m - 1] > g[m] <= g[m + 1]):
                    continue
                # The piece is closed: at a grazing pass on ∂Γ (ex1dof: x2 = 0) the sample
                # nearest the minimum may fall just outside `where`.
                if abs(g[m]) > max_depth or not np.any(np.asarray(inside)[m - 1 : m + 2]):
                    continue
                # Vertex of the parabola through three samples, then one exact Newton step.
                denom = g[m - 1] - 2 * g[m] + g[m + 1]
                shift = 0.5 * (g[m - 1] - g[m + 1]) / denom if denom > 0 else 0.0
                t_min, x_min, depth, speed, accel = _refine_minimum(
                    pmap, scene, i, x0, t0, ts[m] + shift * h, args, ts[m - 1], ts[m + 1]
                )
                rows.append((t_min, x_min, i, False, depth, speed, accel))
    rows.sort(key=lambda r: r[0])
    n = x0.shape[0]

    def col(j, dtype, shape=()):
        return np.array([r[j] for r in rows], dtype=dtype).reshape((len(rows),) + shape)

    return Contacts(times=col(0, float), points=col(1, float, (n,)), surfaces=col(2, int),
                    is_impact=col(3, bool), depth=col(4, float), speed=col(5, float),
                    acceleration=col(6, float))


# --------------------------------------------------------------------------------------
# Branches of the variational system at grazing contacts (A4), (A5)
# --------------------------------------------------------------------------------------


class GrazingBranches(eqx.Module):
    r"""The one-sided linearizations of a grazing orbit (`grazejax.grazing_branches`).

    With l grazing contacts, a neighbouring solution impacts or not at each of them, and
    the paper's (A4) splits the variational system into m ≤ 2^l periodic systems. Row b
    describes branch b. NumPy arrays.

    **Fields:**

    - `contact_times`, `contact_points`, `contact_surfaces`: the l grazing contacts.
    - `impacts`: `(m, l)` bool: whether branch b impacts at each contact.
    - `section_jacobian`: `(m, d, d)` the one-sided limit of the Jacobian of the return
      map to the section Σ through `base_point` (autonomous: d = n − 1, Σ ⟂ f; forced:
      d = n, the time-T map). NaN where the limit is infinite.
    - `monodromy`: `(m, n, n)` the branch monodromy at `base_point`, phase-normalised for
      autonomous orbits (identity along f, `section_jacobian` on Σ; the coupling of Σ into
      the phase, which diverges like 1/v on impacting branches, is dropped), the limit of
      the time-T map's Jacobian for forced ones.
    - `multipliers`: `(m, n)` complex, modulus descending (the trivial 1 included for
      autonomous orbits).
    - `finite`: `(m,)` whether the one-sided limit exists (Nordmark's square-root
      singularity makes it infinite on the impacting side of most grazings).
    - `realized`: `(m,)` whether neighbours with that impact pattern were found.
    - `a5`: `(m,)` the (A5) verdict per branch.
    - `base_time`, `base_point`, `section_basis`: where the Jacobians are taken (a point
      of the orbit away from all contacts) and the orthonormal basis Q of Σ used.
    - `depths`: the neighbour depths δ the limits were extrapolated from.
    """

    contact_times: Any
    contact_points: Any
    contact_surfaces: Any
    impacts: Any
    section_jacobian: Any
    monodromy: Any
    multipliers: Any
    finite: Any
    realized: Any
    a5: Any
    base_time: Any
    base_point: Any
    section_basis: Any
    depths: Any


def _contact_depths(pmap, scene, start, t_start, t_end, contacts, args, window):
    """Signed depth at each contact for the trajectory from (t_start, start).

    Impact near t_c on the contact's surface: −v²/(2a) from the log; else the refined
    minimum of Φ near t_c. Returns (depths, impacted, solution).
    """
    sol = run_period_map(pmap, jnp.asarray(start), jnp.asarray(t_start), jnp.asarray(t_end), args)
    k = int(sol.num_impacts)
    times = np.asarray(sol.impact_times[:k])
    surfaces = np.asarray(sol.impact_surface[:k])
    depths, impacted = [], []
    for (t_c, i), w in zip(contacts, window, strict=True):
        hits = [m for m in range(k) if surfaces[m] == i and abs(times[m] - t_c) <= w]
        if hits:
            m = min(hits, key=lambda m_: abs(times[m_] - t_c))
            g, gd, gdd = (float(v) for v in gap_rates_at(
                scene.surfaces[i].phi, scene.vector_field, jnp.asarray(times[m]), sol.impact_pre[m], args))
            depths.append(-gd * gd / (2 * gdd) if gdd > 0 else -math.inf)
            impacted.append(True)
        else:
            _, _, depth, _, _ = _refine_minimum(pmap, scene, i, start, t_start, t_c, args,
                                                t_c - w, t_c + w)
            depths.append(depth)
            impacted.append(False)
    return np.array(depths), np.array(impacted, bool), sol


def grazing_branches(scene: Scene, orbit: Orbit, args=None, *, contact_tol: float = 1e-6,
                     depths=None, solver=None, rtol: float = 1e-10,
                     atol: float | None = None) -> GrazingBranches:
    r"""Monodromy matrices and multipliers of each branch of a grazing orbit's linearization.

    At a grazing contact the variational system is bivalued (paper eq. beta / betaexi): a
    neighbour that misses the surface sees no jump (B = O), one that impacts sees the
    saltation matrix of an impact with a small normal speed v. With l contacts there are
    up to 2^l branches (assumption (A4)); (A5) asks each to have the multiplier 1 simple
    and all others inside the unit circle.

    **What is computed.** The saltation matrix diverges like 1/v as v → 0, so it cannot
    simply be evaluated on the grazing orbit. Instead, for each impact pattern, we take
    neighbours of the orbit that realize it (each contact's depth set to ±δ through a
    perturbation of the start inside the section Σ), compute the Jacobian of their return
    map to Σ with `jax.jacfwd` through `grazejax.simulate`, and extrapolate to δ → 0
    by least squares in (1, √δ, δ) (the impacting side converges like v ∝ √δ). For an
    autonomous orbit the return map to Σ removes the phase: the 1/v divergence of an
    impact is along the flow (a time shift of order √δ) and does not survive the
    projection when the scene's jump law cancels it, as the paper's (A2) requires
    (ex1dof). When the limit still grows like δ^(−1/2) (Nordmark's square-root
    singularity, e.g. any forced impact oscillator with Newtonian restitution), the branch
    is reported with `finite = False` and infinite multipliers: (A5) fails.

    **Arguments:**

    - `scene`, `orbit`, `args`: the orbit (from `grazejax.find_periodic_orbit`).
    - `contact_tol`: contacts with |virtual depth| ≤ this are grazing
      (see `grazejax.orbit_contacts`).
    - `depths`: neighbour depths δ (default 1e-4·4^(−m), m = 0…5, in units of Φ).
    - `solver`, `rtol`, `atol`: for `grazejax.simulate`.

    **Returns:** a `grazejax.GrazingBranches`. An orbit without grazing contacts has a
    single branch (its own linearization).
    """
    atol = atol_for(orbit, rtol, atol)
    depths = np.asarray([1e-4 * 4.0 ** (-m) for m in range(6)] if depths is None else depths, float)
    pmap = PeriodMap(scene=scene, end_impacts=0, solver=solver, rtol=float(rtol),
                      atol=float(atol), max_impacts=64, max_solver_steps=50_000)
    contacts = orbit_contacts(scene, orbit, args, solver=solver, rtol=rtol, atol=atol)
    section = _base_section(pmap, orbit, contacts, contact_tol, args)
    t0, T = float(orbit.t0), section.period
    n, d = section.basis.shape
    num_contacts = len(section.contact_times)
    if num_contacts == 0:
        patterns = [()]
    else:
        patterns = [tuple(bool(b) for b in bits) for bits in np.ndindex(*(2,) * num_contacts)]
        gradient = section.depth_gradients()

    m_branches = len(patterns)
    jac = np.full((m_branches, d, d), np.nan)
    mono = np.full((m_branches, n, n), np.nan)
    mult = np.full((m_branches, n), np.nan + 0j)
    finite = np.zeros(m_branches, bool)
    realized = np.zeros(m_branches, bool)
    for b, pattern in enumerate(patterns):
        if num_contacts == 0:
            samples, used = [section.return_jacobian(section.x_s)], [0.0]
            realized[b] = True
        else:
            samples, used = section.pattern_samples(pattern, gradient, depths)
            realized[b] = len(samples) >= 3
        if not realized[b]:
            continue
        limit, grows = _extrapolated_limit(np.stack(samples), np.asarray(used), num_contacts)
        if grows or not np.all(np.isfinite(limit)):
            mult[b] = np.inf
            continue
        finite[b] = True
        jac[b] = limit
        mono[b], mult[b] = section.monodromy(limit)
    a5 = np.asarray(a5_holds(jnp.asarray(mult), orbit.fixed_period)) & finite
    c_times = section.contact_times
    return GrazingBranches(
        contact_times=np.where(c_times >= t0 + T, c_times - T, c_times),
        contact_points=section.contact_points, contact_surfaces=section.contact_surfaces,
        impacts=np.array(patterns, bool).reshape(m_branches, num_contacts), section_jacobian=jac,
        monodromy=mono, multipliers=mult, finite=finite, realized=realized, a5=a5,
        base_time=section.t_s, base_point=section.x_s, section_basis=section.basis,
        depths=depths,
    )


@dataclasses.dataclass(frozen=True)
class _Section:
    """The section Σ of a grazing orbit's branches: through the point (t_s, x_s) of the
    orbit away from all contacts, normal to the flow there for an autonomous orbit (`normal`;
    None for a forced one, whose map is the time-T map), with an orthonormal `basis` of Σ,
    and the grazing contacts in the order the loop from t_s meets them."""

    pmap: PeriodMap
    args: Any
    period: float
    t_s: float
    x_s: np.ndarray
    normal: np.ndarray | None
    basis: np.ndarray
    contact_times: np.ndarray  # on the loop from t_s (may exceed t0 + T)
    contact_surfaces: np.ndarray
    contact_points: np.ndarray
    window: list  # how far from each contact time an impact counts as that contact's

    def return_jacobian(self, start):
        """Jacobian of the return map to Σ (or of the time-T map) at `start`."""
        pmap, args, t_s = self.pmap, self.args, self.t_s
        field = pmap.scene.vector_field
        tau = self.period
        if self.normal is None:
            return np.asarray(linearize(pmap, jnp.asarray(start), jnp.asarray(t_s),
                                        jnp.asarray(tau), args)[1])
        for _ in range(3):
            end = np.asarray(run_period_map(pmap, jnp.asarray(start), jnp.asarray(t_s),
                                            jnp.asarray(t_s + tau), args).x_final)
            f_end = np.asarray(field(jnp.asarray(t_s + tau), jnp.asarray(end), args))
            tau -= float(self.normal @ (end - self.x_s)) / float(self.normal @ f_end)
        M = np.asarray(linearize(pmap, jnp.asarray(start), jnp.asarray(t_s), jnp.asarray(tau),
                                 args)[1])
        end = np.asarray(run_period_map(pmap, jnp.asarray(start), jnp.asarray(t_s),
                                        jnp.asarray(t_s + tau), args).x_final)
        f_end = np.asarray(field(jnp.asarray(t_s + tau), jnp.asarray(end), args))
        n = self.x_s.shape[0]
        project = np.eye(n) - np.outer(f_end, self.normal) / float(self.normal @ f_end)
        return self.basis.T @ project @ M @ self.basis

    def measure(self, delta_vec):
        """Signed depths at the contacts, and whether each was an impact, for the neighbour
        that starts at x_s + basis · delta_vec."""
        start = self.x_s + self.basis @ delta_vec
        key = list(zip(self.contact_times, self.contact_surfaces.tolist(), strict=True))
        dep, hit, _ = _contact_depths(self.pmap, self.pmap.scene, start, self.t_s,
                                      self.t_s + 1.05 * self.period, key, self.args, self.window)
        return dep, hit

    def depth_gradients(self):
        """The contacts' depths' gradients in Σ, by central differences (a depth is
        continuous across grazing)."""
        h = 1e-6 * max(1.0, float(np.max(np.abs(self.x_s))))
        d = self.basis.shape[1]
        G = np.zeros((len(self.contact_times), d))
        for j in range(d):
            e = np.zeros(d)
            e[j] = h
            G[:, j] = (self.measure(e)[0] - self.measure(-e)[0]) / (2 * h)
        return G

    def pattern_samples(self, pattern, gradient, depths):
        """Return-map Jacobians of neighbours that realize the impact `pattern` at each
        depth δ (each contact's depth set to ±δ), and the depths that were realized."""
        sign = np.array([-1.0 if hit else 1.0 for hit in pattern])
        pinv = np.linalg.pinv(gradient)
        samples, used = [], []
        for delta in depths:
            target = sign * delta
            dv = pinv @ target
            ok = False
            for _ in range(3):  # correct the linear model with the measured depths
                dep, hit = self.measure(dv)
                if np.array_equal(hit, np.array(pattern)) and np.all(np.sign(dep) == sign):
                    ok = True
                    break
                dv = dv + pinv @ (target - np.where(np.isfinite(dep), dep, 0.0))
            if ok:
                samples.append(self.return_jacobian(self.x_s + self.basis @ dv))
                used.append(delta)
        return samples, used

    def monodromy(self, limit):
        """The full monodromy matrix and its multipliers (modulus descending) from a
        branch's limit Jacobian on Σ (the flow direction's multiplier 1 restored)."""
        if self.normal is None:
            mono, rho = limit, np.linalg.eigvals(limit).astype(complex)
        else:
            mono = np.outer(self.normal, self.normal) + self.basis @ limit @ self.basis.T
            rho = np.concatenate([[1.0 + 0j], np.linalg.eigvals(limit)])
        return mono, rho[np.argsort(-np.abs(rho), kind="stable")]


def _base_section(pmap, orbit, contacts, contact_tol, args) -> _Section:
    """Σ through the middle of the longest stretch of the orbit between events (impacts,
    contacts), with the grazing contacts (|virtual depth| ≤ `contact_tol`)."""
    scene = pmap.scene
    graze = contacts.grazing(contact_tol)
    t0, T = float(orbit.t0), float(orbit.period)
    x0 = np.asarray(orbit.x0, float)
    n = x0.shape[0]
    events = np.sort(np.concatenate([np.asarray(contacts.times, float), [t0]]))
    gaps = np.diff(np.concatenate([events, [events[0] + T]]))
    m = int(np.argmax(gaps))
    t_s = events[m] + 0.5 * gaps[m]
    if t_s >= t0 + T:
        t_s -= T
    x_s = state_at(pmap, x0, t0, t_s, args)
    f_s = np.asarray(scene.vector_field(jnp.asarray(t_s), jnp.asarray(x_s), args), float)
    if orbit.fixed_period:
        normal, basis = None, np.eye(n)
    else:
        normal = f_s / np.linalg.norm(f_s)
        q, _ = np.linalg.qr(np.column_stack([normal, np.eye(n)]))
        basis = q[:, 1:n]
    c_times = np.asarray(contacts.times, float)[graze]
    c_times = np.where(c_times < t_s, c_times + T, c_times)  # times on the loop from t_s
    c_surfaces = np.asarray(contacts.surfaces)[graze]
    order = np.argsort(c_times)
    all_times = np.sort(np.concatenate([np.asarray(contacts.times, float), [t_s, t_s + T]]))
    spacing = np.min(np.diff(np.unique(np.concatenate([all_times, all_times + T]))))
    return _Section(
        pmap=pmap, args=args, period=T, t_s=t_s, x_s=x_s, normal=normal, basis=basis,
        contact_times=c_times[order], contact_surfaces=c_surfaces[order],
        contact_points=np.asarray(contacts.points, float)[graze][order],
        window=[0.25 * spacing] * len(c_times),
    )


def _extrapolated_limit(samples, used, num_contacts):
    """The δ → 0 limit of a branch's Jacobians by least squares in (1, √δ, δ), and whether
    they grow like δ^(−1/2) instead (Nordmark's square-root singularity: no limit)."""
    if num_contacts == 0:
        return samples[0], False
    d = samples.shape[-1]
    norms = np.array([np.linalg.norm(s) for s in samples])
    slope = np.polyfit(np.log(used[-3:]), np.log(norms[-3:]), 1)[0]
    design = np.column_stack([np.ones_like(used), np.sqrt(used), used])
    coef, *_ = np.linalg.lstsq(design, samples.reshape(len(used), -1), rcond=None)
    return coef[0].reshape(d, d), slope < -0.25
