"""Seeded families of random impact systems for the differential fuzzer.

A *family* fixes the structure of a scene (state size, which surfaces, which `where` pieces,
which walls are impenetrable, the direction of time) and leaves every number to `args`, so
that one compiled `jit(vmap(simulate))` serves all the systems of the family. Every scene
function is written once, generic in the array module `xp` (NumPy or `jax.numpy`): grazejax
gets the `jnp` version, the independent reference (`reference.py`) the NumPy one. Gaps and
`where` margins are also vectorised over a trailing axis of the state (shape `(n, M)`) so
that the reference can scan many times at once.

Conventions: surface 0 of every family is Φ₀ = base₀(t, x) − `args["d0"]`, so that a system
can be placed near grazing by moving `d0` to the minimum of base₀ along the free flow
(`place_near_grazing`, a quarter of the systems). A `where` piece is given by a margin
function, the piece being margin ≥ 0.
"""

import dataclasses
import functools
from collections.abc import Callable

import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import minimize_scalar


def col(v, x):
    """`v` (shape (k,)) broadcast against a state `x` of shape (n,) or (n, M)."""
    return v.reshape(v.shape + (1,) * (x.ndim - 1))


def dot(u, x):
    """u · x over the first axis of x (x of shape (k,) or (k, M))."""
    return sum(u[i] * x[i] for i in range(u.shape[0]))


@dataclasses.dataclass(frozen=True)
class SurfaceSpec:
    """One surface piece, generic in the array module: `phi(t, x, a, xp)`,
    `jump(t, x, a, xp)`, `inverse(t, x, a, xp)` (J⁻¹, or None), `margin(t, x, a, xp)`
    (the piece is margin ≥ 0; None: the whole zero set)."""

    phi: Callable
    jump: Callable
    inverse: Callable | None = None
    margin: Callable | None = None
    impenetrable: bool = False
    name: str = ""


@dataclasses.dataclass
class Batch:
    """Random systems of one family: lane i is (x0[i], args[k][i], t0[i], t1[i]).

    `freq` bounds the fastest frequency in the lane (for the reference's scan density),
    `grazing` marks the lanes placed near grazing."""

    x0: np.ndarray
    args: dict
    t0: np.ndarray
    t1: np.ndarray
    freq: np.ndarray
    grazing: np.ndarray

    def __len__(self):
        return self.x0.shape[0]

    def lane(self, i):
        return {k: v[i] for k, v in self.args.items()}


@dataclasses.dataclass(frozen=True, eq=False)
class Family:
    name: str
    n: int
    field: Callable  # field(t, x, a, xp) for x of shape (n,)
    surfaces: tuple[SurfaceSpec, ...]
    sampler: Callable  # sampler(rng, m) -> Batch (near grazing not yet placed)
    direction: int = 1
    exact_flow: Callable | None = None  # exact_flow(t0, x0, t, a): (n, M) for t of shape (M,)
    max_impacts: int = 20
    derivatives: bool = False  # used by the derivative fuzzer

    @functools.cached_property
    def scene(self):
        import grazejax as gj

        def surface(spec):
            return gj.Surface(
                phi=lambda t, x, a: spec.phi(t, x, a, jnp),
                jump=lambda t, x, a: spec.jump(t, x, a, jnp),
                inverse_jump=None
                if spec.inverse is None
                else (lambda t, x, a: spec.inverse(t, x, a, jnp)),
                where=None
                if spec.margin is None
                else (lambda t, x, a: spec.margin(t, x, a, jnp) >= 0),
                impenetrable=spec.impenetrable,
                name=spec.name or None,
            )

        return gj.Scene(
            lambda t, x, a: self.field(t, x, a, jnp), [surface(s) for s in self.surfaces]
        )

    def sample(self, rng: np.random.Generator, m: int, grazing_fraction: float = 0.25) -> Batch:
        batch = self.sampler(rng, m)
        if self.direction == 1 and grazing_fraction > 0:
            lanes = np.flatnonzero(rng.uniform(size=m) < grazing_fraction)
            place_near_grazing(self, batch, lanes, rng)
        return batch


# --------------------------------------------------------------------------------------
# Building blocks


def _unit(rng, k):
    v = rng.normal(size=k)
    return v / np.linalg.norm(v)


def quadratic(Q, x, xp):
    """Q(x, x)_i = Σ_jk Q_ijk x_j x_k. NumPy's `einsum` costs several times two products
    on arrays this small, and the reference evaluates fields ~10⁵ times per family."""
    if xp is np:
        return (Q @ x) @ x
    return xp.einsum("ijk,j,k->i", Q, x, x)


def linear_field(t, x, a, xp):
    """x' = A x + b + Q(x, x) + c sin(w t + p) + (√s − 1)·1 (NaN where s < 0)."""
    out = a["A"] @ x + a["b"] + quadratic(a["Q"], x, xp)
    out = out + a["c"] * xp.sin(a["w"] * t + a["p"])
    if "s" in a:
        out = out + (xp.sqrt(a["s"]) - 1.0)
    return out


def mechanical_field(t, x, a, xp):
    """q' = v, v' = −K q − C v + F + Q(q, q) + c sin(w t + p), k = n/2 degrees of freedom."""
    k = x.shape[0] // 2
    q, v = x[:k], x[k:]
    acc = -a["K"] @ q - a["C"] @ v + a["F"] + quadratic(a["Q"], q, xp)
    acc = acc + a["c"] * xp.sin(a["w"] * t + a["p"])
    return xp.concatenate([v, acc])


def affine_jump(key):
    """J(x) = (I + L) x + s u and its inverse, parameters `args[key]` = (L, s·u)."""

    def jump(t, x, a, xp):
        L, su = a[key + "_L"], a[key + "_su"]
        return x + L @ x + col(su, x)

    def inverse(t, x, a, xp):
        L, su = a[key + "_L"], a[key + "_su"]
        n = L.shape[0]
        return xp.linalg.solve(xp.eye(n) + L, x - col(su, x))

    return jump, inverse


def sample_affine(rng, m, n, normals, key, args, eta=0.08, shift=(0.05, 0.3)):
    """Affine jump parameters pushing off the plane with normal `normals[i]`."""
    L = eta * rng.uniform(size=(m, 1, 1)) * rng.normal(size=(m, n, n))
    u = normals + 0.4 * rng.normal(size=(m, n))
    u = u + np.maximum(0.3 - np.sum(u * normals, axis=1), 0)[:, None] * normals
    args[key + "_L"] = L
    args[key + "_su"] = rng.uniform(*shift, size=(m, 1)) * u


def restitution_jump(key, k, normal, wall_velocity):
    """Newton's law relative to a wall: v_n ← u − e (v_n − u), with unit normal
    `normal(t, q, a, xp)` (shape (k,) or (k, M)) and wall normal velocity `u(t, a, xp)`."""

    def jump(t, x, a, xp, inverse=False):
        q, v = x[:k], x[k:]
        nv = normal(t, q, a, xp)
        u = wall_velocity(t, a, xp)
        vn = dot(nv, v)
        e = a[key + "_e"]
        factor = (1 + 1 / e) if inverse else (1 + e)
        return xp.concatenate([q, v - factor * (vn - u) * nv])

    return jump, functools.partial(jump, inverse=True)


def _zero_velocity(t, a, xp):
    return 0.0 * t


# --------------------------------------------------------------------------------------
# Near grazing


def free_flow(family, x0, t0, t1, a):
    """The free flow (no surfaces) on [t0, t1]: a callable t (M,) -> (n, M)."""
    if family.exact_flow is not None:
        return lambda ts: family.exact_flow(t0, x0, np.asarray(ts), a)
    with np.errstate(all="ignore"):
        if not np.all(np.isfinite(family.field(t0, x0, a, np))):
            return None  # (DOP853 loops forever on a NaN field)
        sol = solve_ivp(
            lambda t, x: family.field(t, x, a, np),
            (t0, t1),
            x0,
            method="DOP853",
            rtol=1e-11,
            atol=1e-11,
            dense_output=True,
        )
    if sol.status != 0:
        return None
    return sol.sol


def place_near_grazing(family, batch, lanes, rng):
    """Move `d0` of the given lanes to within δ of the minimum of base₀ = Φ₀ + d0 over the
    first third of the free flight: δ = ±10^U(−8, −2) (a shallow hit or a near miss)."""
    phi = family.surfaces[0].phi
    for i in lanes:
        a = batch.lane(i)
        t0, t1 = batch.t0[i], batch.t1[i]
        window = t0 + (t1 - t0) / 3
        flow = free_flow(family, batch.x0[i], t0, window, a)
        if flow is None:
            continue
        with np.errstate(all="ignore"):
            ts = np.linspace(t0, window, 4000)
            base = phi(ts, flow(ts), a, np) + a["d0"]
            if not np.all(np.isfinite(base)):
                continue
            k = int(np.argmin(base))
            lo, hi = ts[max(k - 1, 0)], ts[min(k + 1, len(ts) - 1)]
            res = minimize_scalar(
                lambda s, flow=flow, a=a: float(phi(s, flow(np.array([s]))[:, 0], a, np)) + a["d0"],
                bounds=(lo, hi),
                method="bounded",
                options={"xatol": 1e-13},
            )
        low = min(float(res.fun), float(base[k]))
        delta = rng.choice([-1.0, 1.0]) * 10 ** rng.uniform(-8, -2)
        d0 = low - delta
        start = phi(t0, batch.x0[i], {**a, "d0": d0}, np)
        if start <= 1e-3:  # keep x0 clearly on the free side
            continue
        batch.args["d0"][i] = d0
        batch.grazing[i] = True


def _batch(x0, args, t0, t1, freq):
    m = x0.shape[0]
    return Batch(
        x0,
        args,
        np.asarray(t0, float) * np.ones(m),
        np.asarray(t1, float),
        np.asarray(freq, float),
        np.zeros(m, bool),
    )


def _rotation_matrix(rng, m, n, omega, gamma, noise):
    A = noise * rng.normal(size=(m, n, n))
    A[:, 0, 0] -= gamma
    A[:, 1, 1] -= gamma
    A[:, 0, 1] += omega
    A[:, 1, 0] -= omega
    return A


# --------------------------------------------------------------------------------------
# Families


def _plane(key, margin_key=None, impenetrable=False, jump=None):
    """Φ = n·x − d (key "d0" for surface 0), piece m·x ≥ w if `margin_key`."""

    def phi(t, x, a, xp):
        return dot(a[key + "_n"], x) - a["d" + key[1:]]

    margin = None
    if margin_key is not None:

        def margin(t, x, a, xp):
            return dot(a[margin_key + "_m"], x) - a[margin_key + "_w"]

    jump, inverse = jump if jump is not None else affine_jump(key)
    return SurfaceSpec(phi, jump, inverse, margin, impenetrable, key)


def _linear_planes_sampler(n, backward=False, nan_fraction=0.0):
    def sampler(rng, m):
        omega = rng.uniform(0.7, 1.5, m)
        gamma = rng.uniform(-0.02, 0.06, m) * (0.3 if backward else 1.0)
        A = _rotation_matrix(rng, m, n, omega, gamma, 0.12)
        if n > 2:
            A[:, 2, 2] -= rng.uniform(0.2, 1.0, m)
        b = 0.3 * rng.normal(size=(m, n))
        center = -np.linalg.solve(A, b[..., None])[..., 0]
        args = {
            "A": A,
            "b": b,
            "Q": 0.03 * rng.normal(size=(m, n, n, n)),
            "c": 0.2 * rng.normal(size=(m, n)) * (rng.uniform(size=(m, 1)) < 0.5),
            "w": rng.uniform(0.5, 3.0, m),
            "p": rng.uniform(0, 2 * np.pi, m),
        }
        radius = rng.uniform(0.5, 1.5, m)
        direction = np.stack([_unit(rng, n) for _ in range(m)])
        x0 = center + radius[:, None] * direction
        for key in ("s0", "s1", "s2")[: 2 if n == 2 else 3]:
            normal = np.stack([_unit(rng, n) for _ in range(m)])
            args[key + "_n"] = normal
            cut = rng.uniform(0.2, 0.9, m)
            args["d" + key[1:]] = np.sum(normal * center, 1) - cut * radius
            # keep x0 on the free side
            args["d" + key[1:]] = np.minimum(args["d" + key[1:]], np.sum(normal * x0, 1) - 0.05)
            sample_affine(rng, m, n, normal, key, args)
        args["p1_m"] = np.stack([_unit(rng, n) for _ in range(m)])
        args["p1_w"] = np.sum(args["p1_m"] * center, 1) + rng.uniform(-0.8, 0.3, m) * radius
        if nan_fraction:
            args["s"] = np.where(rng.uniform(size=m) < nan_fraction, -1.0, 1.0)
        T = rng.uniform(10, 35, m) if not backward else rng.uniform(6, 20, m)
        t0 = rng.uniform(-1, 1, m)
        t1 = t0 - T if backward else t0 + T
        return _batch(x0, args, t0, t1, np.maximum(omega, args["w"]) + 1)

    return sampler


def linear2(backward=False):
    surfaces = (_plane("s0"), _plane("s1", margin_key="p1"))
    return Family(
        "linear2_back" if backward else "linear2",
        2,
        linear_field,
        surfaces,
        _linear_planes_sampler(2, backward, nan_fraction=0.0 if backward else 0.03),
        direction=-1 if backward else 1,
        derivatives=not backward,
    )


def _sphere():
    """Φ = ρ² − |x − c|² (free inside the ball), jump x ← c + κ (x − c)."""

    def phi(t, x, a, xp):
        y = x - col(a["c2"], x)
        return a["rho2"] ** 2 - dot(y, y)

    def jump(t, x, a, xp):
        return col(a["c2"], x) + a["kappa2"] * (x - col(a["c2"], x))

    def inverse(t, x, a, xp):
        return col(a["c2"], x) + (x - col(a["c2"], x)) / a["kappa2"]

    return SurfaceSpec(phi, jump, inverse, None, False, "sphere")


def linear3():
    def phi0(t, x, a, xp):
        return dot(a["s0_n"], x) - a["d0"]

    def jump0(t, x, a, xp):  # a pure shift off the plane: lands on the free side
        return x + col(a["s0_su"], x)

    def inverse0(t, x, a, xp):
        return x - col(a["s0_su"], x)

    wall = SurfaceSpec(phi0, jump0, inverse0, None, True, "s0")
    base = _linear_planes_sampler(3)

    def sampler(rng, m):
        batch = base(rng, m)
        a = batch.args
        a["c2"] = batch.x0 + 0.3 * rng.normal(size=batch.x0.shape)
        a["rho2"] = np.linalg.norm(batch.x0 - a["c2"], axis=1) + rng.uniform(0.3, 1.5, m)
        a["kappa2"] = rng.uniform(0.6, 0.95, m)
        return batch

    return Family(
        "linear3", 3, linear_field, (wall, _plane("s1", margin_key="p1"), _sphere()), sampler
    )


def _moving_floor(key, k, normal_key=None):
    """Φ = n·q − d − a sin(ω t + φ) (n = args[normal_key], or +1 for k = 1) with Newton's
    law relative to the wall's normal velocity a ω cos(ω t + φ)."""

    def normal(t, q, a, xp):
        if normal_key is None:
            return xp.ones((1,) + q.shape[1:])
        return col(a[normal_key], q) + 0 * q

    def wall_velocity(t, a, xp):
        return a[key + "_a"] * a[key + "_om"] * xp.cos(a[key + "_om"] * t + a[key + "_ph"])

    def phi(t, x, a, xp):
        q = x[:k]
        n = a[normal_key] if normal_key is not None else xp.ones(1)
        d = a["d0"] if key == "s0" else a[key + "_d"]
        return dot(n, q) - d - a[key + "_a"] * xp.sin(a[key + "_om"] * t + a[key + "_ph"])

    jump, inverse = restitution_jump(key, k, normal, wall_velocity)
    return phi, jump, inverse


def _sample_wall(rng, m, key, args, fast_fraction=0.5):
    fast = rng.uniform(size=m) < fast_fraction
    args[key + "_om"] = np.where(fast, rng.uniform(10, 40, m), rng.uniform(0.5, 3, m))
    args[key + "_a"] = rng.uniform(0, 0.08, m) * (rng.uniform(size=m) < 0.8)
    args[key + "_ph"] = rng.uniform(0, 2 * np.pi, m)
    args[key + "_e"] = rng.uniform(0.6, 1.0, m)
    return args[key + "_om"]


def mech1(impenetrable=False, backward=False):
    """One degree of freedom between a moving floor and a fixed ceiling."""
    phi0, jump0, inverse0 = _moving_floor("s0", 1)

    def phi1(t, x, a, xp):
        return a["s1_d"] - x[0]

    jump1, inverse1 = restitution_jump(
        "s1", 1, lambda t, q, a, xp: -xp.ones((1,) + q.shape[1:]), _zero_velocity
    )
    surfaces = (
        SurfaceSpec(phi0, jump0, inverse0, None, impenetrable, "floor"),
        SurfaceSpec(phi1, jump1, inverse1, None, False, "ceiling"),
    )

    def sampler(rng, m):
        args = {
            "K": rng.uniform(0.5, 2.0, (m, 1, 1)),
            "C": rng.uniform(0, 0.1, (m, 1, 1)),
            "F": rng.uniform(-0.5, 0.5, (m, 1)),
            "Q": 0.05 * rng.normal(size=(m, 1, 1, 1)),
            "c": rng.uniform(0, 0.5, (m, 1)) * (rng.uniform(size=(m, 1)) < 0.6),
            "w": rng.uniform(0.5, 3, m),
            "p": rng.uniform(0, 2 * np.pi, m),
        }
        om = _sample_wall(rng, m, "s0", args)
        args["s1_e"] = rng.uniform(0.6, 1.0, m)
        eq = args["F"][:, 0] / args["K"][:, 0, 0]
        amp = rng.uniform(0.5, 1.5, m)
        args["d0"] = eq - rng.uniform(0.2, 0.9, m) * amp
        args["s1_d"] = eq + rng.uniform(0.3, 1.2, m) * amp
        t0 = rng.uniform(-1, 1, m)
        gap = args["s1_d"] - args["d0"]
        q0 = (
            args["d0"]
            + args["s0_a"]
            + rng.uniform(0.1, 0.9, m) * np.maximum(gap - args["s0_a"], 0.05)
        )
        q0 = np.minimum(q0, args["s1_d"] - 0.01)
        x0 = np.stack([q0, rng.normal(size=m) * amp], axis=1)
        # start above the moving floor
        wall = args["d0"] + args["s0_a"] * np.sin(args["s0_om"] * t0 + args["s0_ph"])
        x0[:, 0] = np.maximum(x0[:, 0], wall + 0.02)
        T = rng.uniform(5, 15, m) if backward else rng.uniform(10, 30, m)
        t1 = t0 - T if backward else t0 + T
        return _batch(x0, args, t0, t1, np.maximum(om, args["w"]) + 2)

    name = "mech1" + ("_imp" if impenetrable else "") + ("_back" if backward else "")
    return Family(
        name,
        2,
        mechanical_field,
        surfaces,
        sampler,
        direction=-1 if backward else 1,
        derivatives=not (backward or impenetrable),
    )


def mech2():
    """Two degrees of freedom: a corrugated impenetrable floor, a moving wall on a ledge
    piece (q1 ≥ w), a fixed slanted wall."""

    def phi0(t, x, a, xp):
        return x[1] - a["s0_beta"] * xp.cos(a["s0_kap"] * x[0] + a["s0_psi"]) - a["d0"]

    def normal0(t, q, a, xp):
        g0 = a["s0_beta"] * a["s0_kap"] * xp.sin(a["s0_kap"] * q[0] + a["s0_psi"])
        g1 = 1.0 + 0 * g0
        norm = xp.sqrt(g0 * g0 + g1 * g1)
        return xp.stack([g0 / norm, g1 / norm])

    jump0, inverse0 = restitution_jump("s0", 2, normal0, _zero_velocity)
    phi1, jump1, inverse1 = _moving_floor("s1", 2, normal_key="s1_n")

    def margin1(t, x, a, xp):
        return x[1] - a["s1_w"]

    def phi2(t, x, a, xp):
        return dot(a["s2_n"], x[:2]) - a["s2_d"]

    jump2, inverse2 = restitution_jump(
        "s2", 2, lambda t, q, a, xp: col(a["s2_n"], q) + 0 * q, _zero_velocity
    )
    surfaces = (
        SurfaceSpec(phi0, jump0, inverse0, None, True, "corrugated"),
        SurfaceSpec(phi1, jump1, inverse1, margin1, False, "ledge wall"),
        SurfaceSpec(phi2, jump2, inverse2, None, False, "slanted wall"),
    )

    def sampler(rng, m):
        B = rng.normal(size=(m, 2, 2)) * 0.4
        K = np.eye(2) * rng.uniform(0.6, 1.5, (m, 1, 1)) + B @ np.swapaxes(B, 1, 2) * 0.5
        args = {
            "K": K,
            "C": rng.uniform(0, 0.06, (m, 1, 1)) * np.eye(2),
            "F": 0.3 * rng.normal(size=(m, 2)),
            "Q": 0.03 * rng.normal(size=(m, 2, 2, 2)),
            "c": 0.3 * rng.normal(size=(m, 2)) * (rng.uniform(size=(m, 1)) < 0.5),
            "w": rng.uniform(0.5, 3, m),
            "p": rng.uniform(0, 2 * np.pi, m),
        }
        eq = np.linalg.solve(K, args["F"][..., None])[..., 0]
        amp = rng.uniform(0.6, 1.4, m)
        args["s0_beta"] = rng.uniform(0, 0.3, m)
        args["s0_kap"] = rng.uniform(0.5, 4, m)
        args["s0_psi"] = rng.uniform(0, 2 * np.pi, m)
        args["s0_e"] = rng.uniform(0.6, 1.0, m)
        args["d0"] = eq[:, 1] - rng.uniform(0.3, 0.9, m) * amp
        om = _sample_wall(rng, m, "s1", args)
        angle = rng.uniform(-0.6, 0.6, m)
        args["s1_n"] = np.stack([-np.cos(angle), np.sin(angle)], 1)  # a wall on the right
        args["s1_d"] = np.sum(args["s1_n"] * eq, 1) - rng.uniform(0.3, 0.9, m) * amp
        args["s1_w"] = eq[:, 1] + rng.uniform(-0.8, 0.3, m) * amp
        n2 = np.stack([_unit(rng, 2) for _ in range(m)])
        args["s2_n"] = n2
        args["s2_d"] = np.sum(n2 * eq, 1) - rng.uniform(0.4, 1.0, m) * amp
        args["s2_e"] = rng.uniform(0.6, 1.0, m)
        t0 = rng.uniform(-1, 1, m)
        q0 = eq + 0.25 * amp[:, None] * rng.normal(size=(m, 2))
        v0 = amp[:, None] * rng.normal(size=(m, 2))
        x0 = np.concatenate([q0, v0], 1)
        # keep x0 on the free side of every surface (moving the offsets otherwise)
        s0 = phi0(t0, x0.T, args, np)
        args["d0"] = args["d0"] + np.minimum(s0 - 0.05, 0)
        s1 = (
            np.sum(args["s1_n"] * q0, 1)
            - args["s1_d"]
            - args["s1_a"] * np.sin(args["s1_om"] * t0 + args["s1_ph"])
        )
        args["s1_d"] = args["s1_d"] + np.minimum(s1 - 0.05, 0)
        s2 = np.sum(n2 * q0, 1) - args["s2_d"]
        args["s2_d"] = args["s2_d"] + np.minimum(s2 - 0.05, 0)
        T = rng.uniform(10, 25, m)
        freq = np.maximum(np.maximum(om, args["w"]), args["s0_kap"] * 3) + 2
        return _batch(x0, args, t0, t0 + T, freq)

    return Family("mech2", 4, mechanical_field, surfaces, sampler, derivatives=True)


def drift():
    """x' = c (exact flow: straight lines): a cos-shaped gap whose dips are shorter than any
    step the solver takes, and a fast moving plane on a half-plane piece."""

    def field(t, x, a, xp):
        return a["vel"] + 0 * x

    def flow(t0, x0, t, a):
        return x0[:, None] + a["vel"][:, None] * (t - t0)[None, :]

    def phi0(t, x, a, xp):
        return xp.cos(dot(a["s0_k"], x) + a["s0_psi"]) - a["d0"]

    def jump0(t, x, a, xp):
        return x - col(a["s0_back"], x)

    def inverse0(t, x, a, xp):
        return x + col(a["s0_back"], x)

    def phi1(t, x, a, xp):
        return dot(a["s1_n"], x) - a["s1_d"] - a["s1_a"] * xp.sin(a["s1_om"] * t + a["s1_ph"])

    def margin1(t, x, a, xp):
        return dot(a["p1_m"], x) - a["p1_w"]

    jump1, inverse1 = affine_jump("s1")
    surfaces = (
        SurfaceSpec(phi0, jump0, inverse0, None, False, "cos gap"),
        SurfaceSpec(phi1, jump1, inverse1, margin1, False, "fast plane"),
    )

    def sampler(rng, m):
        speed = rng.uniform(0.5, 2.0, m)
        vel = speed[:, None] * np.stack([_unit(rng, 2) for _ in range(m)])
        k = rng.uniform(0.7, 2.0, m)[:, None] * (
            vel / speed[:, None] + 0.3 * rng.normal(size=(m, 2))
        )
        args = {
            "vel": vel,
            "s0_k": k,
            "s0_psi": rng.uniform(0, 2 * np.pi, m),
            "d0": -rng.uniform(0.5, 0.999, m),
        }
        x0 = rng.normal(size=(m, 2))
        # start where the gap is positive
        phase = np.sum(k * x0, 1) + args["s0_psi"]
        args["s0_psi"] = args["s0_psi"] - phase + rng.uniform(-1.5, 1.5, m)
        args["s0_back"] = vel * rng.uniform(0.3, 1.2, (m, 1))
        normal = -vel / speed[:, None] + 0.5 * rng.normal(size=(m, 2))
        normal /= np.linalg.norm(normal, axis=1, keepdims=True)
        args["s1_n"] = normal
        args["s1_a"] = rng.uniform(0, 0.1, m)
        args["s1_om"] = rng.uniform(5, 60, m)
        args["s1_ph"] = rng.uniform(0, 2 * np.pi, m)
        args["s1_d"] = np.sum(normal * x0, 1) - args["s1_a"] - rng.uniform(0.5, 3, m)
        sample_affine(rng, m, 2, normal, "s1", args, shift=(0.2, 1.0))
        args["p1_m"] = np.stack([_unit(rng, 2) for _ in range(m)])
        args["p1_w"] = np.sum(args["p1_m"] * x0, 1) + rng.uniform(-2, 1, m)
        T = rng.uniform(4, 12, m)
        t0 = rng.uniform(-1, 1, m)
        freq = np.maximum(args["s1_om"], np.linalg.norm(k, axis=1) * speed) + 1
        return _batch(x0, args, t0, t0 + T, freq)

    return Family("drift", 2, field, surfaces, sampler, exact_flow=flow)


def rotation(backward=False):
    """x' = ω J (x − c), exact flow: a plane on a half-plane piece and a cos-curved wall,
    both with affine jumps (inverses given: backward time too)."""

    def field(t, x, a, xp):
        y = x - a["ctr"]
        return a["om"] * xp.stack([y[1], -y[0]])

    def flow(t0, x0, t, a):
        th = a["om"] * (t - t0)
        y = x0 - a["ctr"]
        c, s = np.cos(th), np.sin(th)
        return np.stack([c * y[0] + s * y[1], -s * y[0] + c * y[1]]) + a["ctr"][:, None]

    def phi1(t, x, a, xp):
        return x[1] - a["s1_beta"] * xp.cos(a["s1_kap"] * x[0] + a["s1_psi"]) - a["d1"]

    jump1, inverse1 = affine_jump("s1")
    surfaces = (
        _plane("s0", margin_key="p0"),
        SurfaceSpec(phi1, jump1, inverse1, None, False, "curved"),
    )

    def sampler(rng, m):
        om = rng.uniform(0.6, 2.0, m)
        ctr = 0.3 * rng.normal(size=(m, 2))
        radius = rng.uniform(0.5, 1.5, m)
        x0 = ctr + radius[:, None] * np.stack([_unit(rng, 2) for _ in range(m)])
        args = {"om": om, "ctr": ctr}
        n0 = np.stack([_unit(rng, 2) for _ in range(m)])
        args["s0_n"] = n0
        args["d0"] = np.minimum(
            np.sum(n0 * ctr, 1) - rng.uniform(0.2, 0.9, m) * radius, np.sum(n0 * x0, 1) - 0.05
        )
        sample_affine(rng, m, 2, n0, "s0", args)
        args["p0_m"] = np.stack([_unit(rng, 2) for _ in range(m)])
        args["p0_w"] = np.sum(args["p0_m"] * ctr, 1) + rng.uniform(-0.8, 0.3, m) * radius
        args["s1_beta"] = rng.uniform(0, 0.3, m)
        args["s1_kap"] = rng.uniform(0.5, 4, m)
        args["s1_psi"] = rng.uniform(0, 2 * np.pi, m)
        args["d1"] = np.minimum(
            ctr[:, 1] - rng.uniform(0.2, 0.9, m) * radius,
            phi1(0, x0.T, {**args, "d1": 0.0}, np) - 0.05,
        )
        sample_affine(rng, m, 2, np.tile([0.0, 1.0], (m, 1)), "s1", args)
        T = rng.uniform(6, 20, m) if backward else rng.uniform(10, 30, m)
        t0 = rng.uniform(-1, 1, m)
        freq = np.maximum(om, args["s1_kap"] * radius * om) + 1
        return _batch(x0, args, t0, t0 - T if backward else t0 + T, freq)

    return Family(
        "rotation_back" if backward else "rotation",
        2,
        field,
        surfaces,
        sampler,
        direction=-1 if backward else 1,
        exact_flow=flow,
        derivatives=not backward,
    )


@functools.cache
def families() -> dict[str, Family]:
    """Every family, by name (built once per process: the scenes are compile-cache keys)."""
    out = [
        linear2(),
        linear2(backward=True),
        linear3(),
        mech1(),
        mech1(impenetrable=True),
        mech1(backward=True),
        mech2(),
        drift(),
        rotation(),
        rotation(backward=True),
    ]
    return {f.name: f for f in out}
