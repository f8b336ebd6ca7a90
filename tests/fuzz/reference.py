"""An independent event loop for the fuzzer's scenes: SciPy only, no grazejax code.

Written from docs/semantics.md (and DESIGN.md §2):

- the free side is Φ > 0; an impact is the first time Φ reaches 0 while decreasing, or
  touches it, at a point of the piece (`margin ≥ 0`); upward crossings pass through;
- a flight that starts on a surface never impacts at its start time (the start value of a
  gap within round-off of 0 takes the sign of its rate: the surface is hit again only
  after the flight leaves it);
- backward time (t1 < t0) meets the image surfaces Φ̃ = Φ ∘ J⁻¹ from either side; x on Γ̃
  is an impact point iff z = J⁻¹(x) lies in the piece and was met with Φ̇(z) ≤ 0;
- simultaneous contacts (within 1e3 ulps) are applied in surface order, each only while
  still approached; impenetrable surfaces: BAD_START / BAD_JUMP;
- Zeno: the last three inter-impact times shrink geometrically (ratios within 5%) and the
  predicted time left is below zeno_rtol·|t − t0|.

Each flight is integrated by DOP853 at rtol = atol = 1e-13 step by step (or follows the
exact flow of a closed-form family in short pseudo-steps); on every step each gap is
sampled on the dense output (≥ 32 points, more for fast walls), local minima are refined
with a bounded minimisation, roots with brentq. Quantities that decide close calls (the
depth of the shallowest dip, the smallest `where` margin at a crossing, the distance of
competing contacts, the landing gap of jumps onto impenetrable walls, t1 against the events)
are kept in `RefResult.diag`, for `compare.py` to classify disagreements.
"""

import dataclasses
import math

import numpy as np
from scipy.integrate import DOP853
from scipy.optimize import brentq, minimize_scalar

# Status codes (compare.py checks that they match grazejax.Status by name).
SUCCESS, MAX_IMPACTS, ZENO, MAX_STEPS, NONFINITE, STEP_SIZE_UNDERFLOW = 0, 1, 2, 3, 4, 5
BAD_JUMP, BAD_START = 6, 7
STATUS_NAMES = {
    SUCCESS: "SUCCESS",
    MAX_IMPACTS: "MAX_IMPACTS",
    ZENO: "ZENO",
    MAX_STEPS: "MAX_STEPS",
    NONFINITE: "NONFINITE",
    STEP_SIZE_UNDERFLOW: "STEP_SIZE_UNDERFLOW",
    BAD_JUMP: "BAD_JUMP",
    BAD_START: "BAD_START",
}

EPS = np.finfo(float).eps
ROUND = 1e-11  # round-off band of a landing gap / start gap (unit-size states)
RATE_ROUND = 1e-9  # round-off band of a rate dΦ/dt


@dataclasses.dataclass
class RefResult:
    status: int
    t_final: float
    x_final: np.ndarray
    times: list
    surfaces: list
    pre: list
    post: list
    rates: list  # |dΦ/ds| at each impact (transversality)
    diag: dict  # key -> [(t, |value|)]: the quantities that decide close calls
    failed: str | None = None  # why the reference itself could not finish
    steps: int = 0

    @property
    def num_impacts(self):
        return len(self.times)


def _note(diag, key, t, value):
    """Record a close-call quantity |value| met at time t."""
    value = float(abs(value))
    if math.isfinite(value):
        diag.setdefault(key, []).append((float(t), value))


class _Scene:
    """The family's functions bound to one lane's args, in NumPy, with the loop's pairs
    (surface, side): forward (i, +1); backward (i, +1) and (i, −1)."""

    def __init__(self, family, a, sigma):
        self.f, self.a, self.sigma = family, a, sigma
        self.specs = family.surfaces
        sides = (1,) if sigma > 0 else (1, -1)
        self.pairs = [(i, d) for i in range(len(self.specs)) for d in sides]

    def field(self, t, x):
        v = self.f.field(t, x, self.a, np)
        if not np.isfinite(v).all():  # DOP853 would shrink its step forever
            raise _NonFinite(t, x)
        return v

    def gap(self, i, t, x):
        """Φ_i forward, Φ̃_i = Φ_i ∘ J_i⁻¹ backward; x of shape (n,) or (n, M)."""
        spec = self.specs[i]
        if self.sigma < 0:
            x = spec.inverse(t, x, self.a, np)
        return spec.phi(t, x, self.a, np)

    def gaps(self, t, x):
        values = [self.gap(i, t, x) for i in range(len(self.specs))]
        return np.array([d * values[i] for i, d in self.pairs])

    def rate(self, fn, t, x):
        """d fn(t, x(t)) / ds along the flow, s the loop's clock (complex step)."""
        h = 1e-30
        v = self.field(t, x)
        return float(np.imag(fn(t + 1j * h * self.sigma, x + 1j * h * self.sigma * v)) / h)

    def phi_rate(self, i, t, x):
        """Forward dΦ_i/dt at x."""
        h = 1e-30
        v = self.field(t, x)
        return float(np.imag(self.specs[i].phi(t + 1j * h, x + 1j * h * v, self.a, np)) / h)

    def margin(self, i, t, x):
        spec = self.specs[i]
        return math.inf if spec.margin is None else float(spec.margin(t, x, self.a, np))


def _flight_steps(scene, t_start, x_start, t1, rtol, atol, exact, freq):
    """Steps (ta, tb, interp) of one flight; interp(ts) -> (n, M)."""
    if exact is not None:
        h = min(0.25, 1.0 / freq)
        count = max(1, math.ceil(abs(t1 - t_start) / h))
        edges = np.linspace(t_start, t1, count + 1)
        flow = lambda ts: exact(t_start, x_start, np.atleast_1d(ts), scene.a)  # noqa: E731
        for ta, tb in zip(edges[:-1], edges[1:], strict=True):
            yield ta, tb, flow
        return
    solver = DOP853(scene.field, t_start, x_start, t1, rtol=rtol, atol=atol)
    while solver.status == "running":
        message = solver.step()
        if solver.status == "failed":
            raise _Failure(f"DOP853: {message}")
        if not np.all(np.isfinite(solver.y)):
            raise _NonFinite(solver.t_old, solver.y)
        dense = solver.dense_output()
        yield solver.t_old, solver.t, lambda ts, dense=dense: np.asarray(dense(np.atleast_1d(ts)))


class _Failure(Exception):
    pass


class _NonFinite(Exception):
    pass


def _scan_step(scene, ta, tb, interp, prev, start_signs, t_start, scan, freq, diag):
    """Candidate contacts in one step, sorted in the loop's time order: (t, pair index).

    `prev` = (t, g, interp) of the previous step's second-to-last sample (for minima on
    the boundary between steps); `start_signs[p]` replaces a start gap within round-off of
    0 on the flight's first step."""
    m = max(scan, int(math.ceil(scan * abs(tb - ta) * freq / 4)))
    ts = np.linspace(ta, tb, m + 1)
    xs = interp(ts)
    with np.errstate(all="ignore"):
        g = scene.gaps(ts, xs)
    if not np.all(np.isfinite(g)):
        raise _NonFinite(ta, xs[:, 0])
    first = prev is None
    if first:
        for p, sign in start_signs.items():
            g[p, 0] = sign * 1e-300
        T, G, offset = ts, g, 0
    else:
        T = np.concatenate([[prev[0]], ts])
        G = np.concatenate([prev[1][:, None], g], axis=1)
        offset = 1

    def value(p, t):
        if not first and scene.sigma * (t - ta) < 0:
            x = prev[2](t)[:, 0]
        else:
            x = interp(t)[:, 0]
        i, d = scene.pairs[p]
        return d * float(scene.gap(i, t, x))

    candidates = []
    for p in range(len(scene.pairs)):
        gp = G[p]
        # crossings from above, in this step's intervals
        for k in np.flatnonzero((gp[offset:-1] > 0) & (gp[offset + 1 :] <= 0)) + offset:
            lo, hi = T[k], T[k + 1]
            if first and k == 0 and p in start_signs:
                res = minimize_scalar(
                    lambda s, p=p: -value(p, s),
                    bounds=sorted((lo, hi)),
                    method="bounded",
                    options={"xatol": 1e-15},
                )
                if -res.fun <= 0:
                    continue
                lo = res.x
            candidates.append(_root(value, p, lo, hi))
        # interior minima above 0 (and those on this step's start boundary)
        inner = np.arange(1, G.shape[1] - 1)
        is_min = (gp[inner - 1] > gp[inner]) & (gp[inner] <= gp[inner + 1]) & (gp[inner] > 0)
        for k in inner[is_min]:
            lo, hi = sorted((T[k - 1], T[k + 1]))
            res = minimize_scalar(
                lambda s, p=p: value(p, s),
                bounds=(lo, hi),
                method="bounded",
                options={"xatol": 1e-15},
            )
            t_min, g_min = float(res.x), float(res.fun)
            if gp[k] < g_min:
                t_min, g_min = T[k], gp[k]
            if first and p in start_signs and abs(t_min - t_start) <= 1e-12 * (1 + abs(t_start)):
                continue
            i, _ = scene.pairs[p]
            x_min = (
                interp(t_min)[:, 0]
                if first or scene.sigma * (t_min - ta) >= 0
                else prev[2](t_min)[:, 0]
            )
            near_piece = _piece_margin(scene, i, t_min, x_min) > -0.05
            if near_piece:
                _note(diag, "dip", t_min, g_min)
            if g_min <= 0:
                candidates.append(_root(value, p, T[k - 1], t_min) if g_min < 0 else (t_min, p))
    candidates.sort(key=lambda c: scene.sigma * c[0])
    return candidates, (ts[-2], g[:, -2], interp)


def _root(value, p, lo, hi):
    """The root of the pair's gap in (lo, hi] with g(lo) > 0 >= g(hi)."""
    g_hi = value(p, hi)
    if g_hi == 0:
        return hi, p
    g_lo = value(p, lo)
    if not g_lo > 0:
        return lo, p
    return brentq(lambda s: value(p, s), lo, hi, xtol=1e-16, rtol=4 * EPS, maxiter=200), p


def _piece_margin(scene, i, t, x):
    """`where` margin of surface i at the contact x (backward: at z = J⁻¹(x))."""
    if scene.sigma < 0:
        x = scene.specs[i].inverse(t, x, scene.a, np)
    return scene.margin(i, t, x)


def _valid(scene, i, t, x, diag):
    """Whether a contact of surface i at (t, x) is an impact (in the closed piece; backward:
    J⁻¹(x) in the piece and met with Φ̇ ≤ 0)."""
    if scene.sigma > 0:
        margin = scene.margin(i, t, x)
        _note(diag, "where", t, margin)
        return margin >= 0
    z = scene.specs[i].inverse(t, x, scene.a, np)
    margin = scene.margin(i, t, z)
    _note(diag, "where", t, margin)
    approach = scene.phi_rate(i, t, z)
    if margin >= 0:
        _note(diag, "approach", t, approach)
    return margin >= 0 and approach <= RATE_ROUND * (1 + np.max(np.abs(scene.field(t, z))))


def _impenetrable_bad(scene, t, x, diag):
    """Whether x lies inside an impenetrable piece, or on one moving in (forward only)."""
    for i, spec in enumerate(scene.specs):
        if not spec.impenetrable or scene.margin(i, t, x) < 0:
            continue
        g = float(spec.phi(t, x, scene.a, np))
        r = scene.phi_rate(i, t, x)
        if r <= RATE_ROUND or g < 0:
            _note(diag, "jump", t, g if r <= RATE_ROUND else (g if g < -ROUND else math.inf))
        if g < -ROUND or (g <= ROUND and r < -RATE_ROUND):
            return True
    return False


def run(
    family,
    x0,
    t0,
    t1,
    a,
    *,
    max_impacts=20,
    rtol=1e-13,
    atol=1e-13,
    scan=32,
    freq=1.0,
    zeno_rtol=1e-6,
    max_steps=200_000,
):
    """The reference solution of one system (see the module docstring)."""
    sigma = 1 if t1 >= t0 else -1
    scene = _Scene(family, a, sigma)
    x = np.asarray(x0, float)
    t = float(t0)
    times, surfaces, pre, post, rates = [], [], [], [], []
    diag = {}

    def result(status, tf, xf, failed=None):
        return RefResult(
            status,
            tf,
            np.asarray(xf, float),
            times,
            surfaces,
            pre,
            post,
            rates,
            diag,
            failed,
            steps,
        )

    steps = 0
    with np.errstate(all="ignore"):
        try:
            finite = np.all(np.isfinite(x)) and np.all(np.isfinite(scene.field(t, x)))
        except _NonFinite:
            finite = False
        if not finite:
            return result(NONFINITE, t, x)
        if sigma > 0 and _impenetrable_bad(scene, t, x, diag):
            return result(BAD_START, t, x)
    restart_pairs = None  # gaps at the start of the flight that are on a surface
    x_end, t_end = x, t
    while True:
        start_signs = _start_signs(scene, t, x, restart_pairs)
        prev = None
        event = None
        try:
            with np.errstate(all="ignore"):
                for ta, tb, interp in _flight_steps(
                    scene, t, x, float(t1), rtol, atol, family.exact_flow, freq
                ):
                    steps += 1
                    if steps > max_steps:
                        return result(MAX_STEPS, ta, interp(ta)[:, 0], "max steps")
                    candidates, prev_next = _scan_step(
                        scene, ta, tb, interp, prev, start_signs, t, scan, freq, diag
                    )
                    for tc, p in candidates:
                        i, _ = scene.pairs[p]
                        xc = (
                            interp(tc)[:, 0]
                            if prev is None or sigma * (tc - ta) >= 0
                            else prev[2](tc)[:, 0]
                        )
                        if _valid(scene, i, tc, xc, diag):
                            if event is None:
                                event = (tc, i, xc, interp)
                            elif i != event[1]:
                                _note(diag, "simultaneous", tc, tc - event[0])
                    if event is not None:
                        break
                    prev = prev_next
                    x_end, t_end = interp(tb)[:, 0], tb
        except _Failure as err:
            # DOP853 could not go on: the solution blows up (a step below the spacing of t)
            if "spacing" in str(err):
                return result(STEP_SIZE_UNDERFLOW, t, x)
            return result(SUCCESS, t, x, failed=str(err))
        except _NonFinite as err:
            return result(NONFINITE, float(err.args[0]), err.args[1])
        if event is None:
            with np.errstate(all="ignore"):
                g_end = scene.gaps(t_end, x_end)
            for g in g_end:
                _note(diag, "t1_gap", t_end, g)
            return result(SUCCESS, t_end, x_end)
        tc, i, xc, _ = event
        _note(diag, "t1", tc, tc - t1)
        with np.errstate(all="ignore"):
            x_post = _apply(scene, i, tc, xc)
            rates.append(abs(scene.rate(lambda tt, xx, i=i: scene.gap(i, tt, xx), tc, xc)))
            times.append(tc)
            surfaces.append(i)
            pre.append(xc)
            post.append(x_post)
            if not np.all(np.isfinite(x_post)):
                return result(NONFINITE, tc, x_post)
            # simultaneous contacts of later surfaces: applied in order while approached
            on = _simultaneous(scene, i, tc, x_post)
            for j in on:
                if len(times) >= max_impacts:
                    break
                pre.append(x_post)
                x_post = _apply(scene, j, tc, x_post)
                times.append(tc)
                surfaces.append(j)
                post.append(x_post)
                rates.append(0.0)
            if sigma > 0 and _impenetrable_bad(scene, tc, x_post, diag):
                return result(BAD_JUMP, tc, x_post)
        t, x = tc, x_post
        restart_pairs = True
        if len(times) >= max_impacts:
            return result(MAX_IMPACTS, t, x)
        if _zeno(times, t0, zeno_rtol, diag):
            return result(ZENO, t, x)


def _apply(scene, i, t, x):
    spec = scene.specs[i]
    law = spec.jump if scene.sigma > 0 else spec.inverse
    return np.asarray(law(t, x, scene.a, np), float)


def _simultaneous(scene, i, t, x):
    """Later surfaces still met at (t, x) after surface i's jump: on them within round-off,
    approached, in the piece."""
    out = []
    for j in range(i + 1, len(scene.specs)):
        g = float(scene.gap(j, t, x))
        if abs(g) <= 1e3 * EPS * (1 + np.max(np.abs(x))):
            r = scene.rate(lambda tt, xx, j=j: scene.gap(j, tt, xx), t, x)
            if (r <= 0 or scene.sigma < 0) and _piece_margin(scene, j, t, x) >= 0:
                out.append(j)
    return out


def _start_signs(scene, t, x, restart):
    """For every pair whose gap is within round-off of 0 at the flight's start: the sign the
    gap takes just after the start (its rate's, or + for a tangential start)."""
    out = {}
    with np.errstate(all="ignore"):
        g = scene.gaps(t, x)
    scale = 1 + np.max(np.abs(x))
    for p, (i, d) in enumerate(scene.pairs):
        if abs(g[p]) > 1e3 * EPS * scale * 10:
            continue
        rate = d * scene.rate(lambda tt, xx, i=i: scene.gap(i, tt, xx), t, x)
        out[p] = 1.0 if rate >= -RATE_ROUND * scale else -1.0
    return out


def _zeno(times, t0, zeno_rtol, diag):
    if len(times) < 4:
        return False
    d1, d2, d3 = (
        abs(times[-3] - times[-4]),
        abs(times[-2] - times[-3]),
        abs(times[-1] - times[-2]),
    )
    if d1 <= 0 or d2 <= 0:
        return False
    r1, r2 = d2 / d1, d3 / d2
    if r1 < 1 and r2 < 1:
        _note(diag, "zeno_ratio", times[-1], (r1 - r2) / max(r1, r2))
        if abs(r1 - r2) <= 0.05 * max(r1, r2):
            left = d3 * r2 / (1 - r2)
            return left <= zeno_rtol * abs(times[-1] - t0)
    return False
