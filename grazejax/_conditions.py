r"""Numerical checks of the paper's standing conditions (C1)–(C7) and of (A1).

Akhmet & Kıvılcım (§2) assume, for Φ: D^r → R, Γ = Φ⁻¹(0), J: Γ^r → D^r, Γ̃ = J(Γ),
Φ̃ = Φ ∘ J⁻¹ and J̃ = J⁻¹ on Γ̃ (quoted as printed; ∂Γ is the boundary of the piece):

- (C1) ∇Φ(x) ≠ 0 for all x ∈ Γ;
- (C2) J ∈ C¹(Γ^r) and det[∂J(x)/∂x] ≠ 0 for all x ∈ Γ^r \ ∂Γ;
- (C3) Γ ∩ Γ̃ ⊆ ∂Γ ∩ ∂Γ̃;
- (C4) ⟨∇Φ(x), f(x)⟩ ≠ 0 if x ∈ Γ \ ∂Γ;
- (C5) ⟨∇Φ̃(x), f(x)⟩ ≠ 0 if x ∈ Γ̃ \ ∂Γ̃;
- (C6) J(x) = x for all x ∈ ∂Γ;
- (C7) J̃(x) = x for all x ∈ ∂Γ̃;
- (A1) a grazing point is isolated.

(C8)–(C10) (boundedness, continuation, the group property) are statements about whole
solutions and are not sampled here.

A sampling test can find violations but cannot prove a condition: a condition "holds"
below means "no violation was found at the samples, nor between neighbouring samples".
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._geometry import inverse_jump, project_to_surface
from ._scene import Scene, Surface
from ._simulate import simulate
from ._status import Status

STATEMENTS = {
    "C1": "∇Φ(x) ≠ 0 for all x ∈ Γ",
    "C2": "J ∈ C¹(Γ^r) and det[∂J/∂x] ≠ 0 for all x ∈ Γ^r \\ ∂Γ",
    "C4": "⟨∇Φ(x), f(x)⟩ ≠ 0 if x ∈ Γ \\ ∂Γ",
    "C5": "⟨∇Φ̃(x), f(x)⟩ ≠ 0 if x ∈ Γ̃ \\ ∂Γ̃ (Γ̃ = J(Γ), Φ̃ = Φ ∘ J⁻¹)",
    "C6": "J(x) = x for all x ∈ ∂Γ",
    "C7": "J̃(x) = x for all x ∈ ∂Γ̃ (J̃ = J⁻¹ on Γ̃)",
    "C3": "Γ ∩ Γ̃ ⊆ ∂Γ ∩ ∂Γ̃",
    "A1": "a grazing point is isolated (no other grazing points in a neighbourhood)",
    "C8": "sup_D ‖f‖ < ∞ and inf over x0 ∈ Γ̃ of ζ(x0) > 0 (ζ: first meeting with Γ)",
    "C9": "every solution of y' = f is continuable to ∞ or Γ forward, to −∞ or Γ̃ backward",
    "C10": "no solution of y' = f meets Γ̃ before it meets Γ as time increases",
}


class ConditionResult(eqx.Module):
    """One condition on one surface piece.

    **Fields:**

    - `condition`: `"C1"`, `"C2"`, `"C4"`, ..., `"C7"`.
    - `surface`, `surface_name`: the piece's index and label.
    - `holds`: True (no violation found), False (violated), or None (not testable, e.g.
      C5 where J is not invertible).
    - `statement`: the condition as the paper writes it.
    - `detail`: what was tested and what was found, in words.
    - `points`: up to five violating points `(t, x_1, ..., x_n)`, as a NumPy array.
    """

    condition: str
    surface: int
    surface_name: str
    holds: bool | None
    statement: str
    detail: str
    points: np.ndarray


class ConditionReport(eqx.Module):
    """Result of `grazejax.check_conditions`; `str(report)` lists violations first.

    **Fields:** `results` (a tuple of `grazejax.ConditionResult`), `samples` (the
    number drawn per surface), `box` (the sampling box, shape `(n, 2)`), `t_range`.
    """

    results: tuple[ConditionResult, ...]
    samples: int
    box: np.ndarray
    t_range: tuple[float, float]

    @property
    def ok(self) -> bool:
        """True if no tested condition is violated (untestable ones do not count)."""
        return all(r.holds is not False for r in self.results)

    @property
    def violations(self) -> tuple[ConditionResult, ...]:
        return tuple(r for r in self.results if r.holds is False)

    def holds(self, condition: str, surface: int | None = None) -> bool | None:
        """Whether `condition` holds on `surface` (or on every surface if None)."""
        found = [
            r.holds
            for r in self.results
            if r.condition == condition and (surface is None or r.surface == surface)
        ]
        if not found:
            raise KeyError(f"no result for {condition} on surface {surface}")
        if any(h is False for h in found):
            return False
        if any(h is None for h in found):
            return None
        return True

    def __str__(self) -> str:
        bad = self.violations
        head = (
            f"Conditions (C1)-(C10), (A1): {len(bad)} violation(s) "
            f"({self.samples} samples per surface in the box {self.box.tolist()}, t in {list(self.t_range)})"
        )
        lines = [head]
        order = sorted(self.results, key=lambda r: {False: 0, None: 1, True: 2}[r.holds])
        for r in order:
            mark = {False: "VIOLATED", None: "untested", True: "ok"}[r.holds]
            lines.append(f"  ({r.condition}) {r.surface_name}: {mark} - {r.statement}")
            lines.append(f"      {r.detail}")
            if r.holds is False and len(r.points):
                for p in r.points:
                    lines.append(
                        f"      at t = {p[0]:.6g}, x = {np.array2string(p[1:], precision=8)}"
                    )
        return "\n".join(lines)


# --------------------------------------------------------------------------------------
# Sampling the pieces (jit-compiled per scene and surface)
# --------------------------------------------------------------------------------------


@eqx.filter_jit
def _sample_surface(scene: Scene, i: int, ts, xs, args):
    """Project the box samples onto Φ = 0; also ‖∇Φ‖ at the box samples (C1's scale)."""
    phi = scene.surfaces[i].phi
    projected = jax.vmap(lambda t, x: project_to_surface(phi, t, x, args))(ts, xs)
    grad_norms = jax.vmap(lambda t, x: jnp.linalg.norm(jax.grad(phi, argnums=1)(t, x, args)))(
        ts, xs
    )
    return projected, grad_norms


@eqx.filter_jit
def _evaluate(scene: Scene, i: int, ts, xs, args, delta):
    surface = scene.surfaces[i]
    f = scene.vector_field

    def one(t, x):
        phi = surface.phi(t, x, args)
        phi_t, grad = jax.jacfwd(surface.phi, argnums=(0, 1))(t, x, args)
        fx = f(t, x, args)
        x_post = surface.jump(t, x, args)
        J_t, DJ = jax.jacfwd(surface.jump, argnums=(0, 1))(t, x, args)
        f_post = f(t, x_post, args)
        # Second derivatives of J: a kink of J between two neighbouring samples shows as a
        # jump of DJ that the trapezoid rule with D²J cannot explain (see _check_surface).
        D2J = jax.jacfwd(jax.jacfwd(surface.jump, argnums=1), argnums=1)(t, x, args)
        if surface.where is None:
            inside = jnp.array(True)
            near_boundary = jnp.array(False)
        else:
            offsets = jnp.concatenate([jnp.diag(delta), -jnp.diag(delta)], axis=0)
            inside = jnp.asarray(surface.where(t, x, args), bool)
            around = jax.vmap(lambda dx: jnp.asarray(surface.where(t, x + dx, args), bool))(offsets)
            near_boundary = jnp.any(around != inside)
        return dict(
            phi=phi,
            phi_t=phi_t,
            grad=grad,
            f=fx,
            x_post=x_post,
            J_t=J_t,
            DJ=DJ,
            D2J=D2J,
            f_post=f_post,
            inside=inside,
            near_boundary=near_boundary,
        )

    return jax.vmap(one)(ts, xs)


@eqx.filter_jit
def _bisect_segments(scene: Scene, i: int, kind: str, ta, xa, tb, xb, args):
    """Locate a zero of a sampled quantity between two surface samples of opposite sign.

    Bisection along the segment, each midpoint projected back onto Γ_i. `kind` is
    "rate" (C4), "image_rate" (C5), "det" (C2) or "where" (∂Γ: the piece's boundary).
    """
    surface = scene.surfaces[i]
    f = scene.vector_field

    def value(t, x):
        if kind == "where":
            return jnp.where(jnp.asarray(surface.where(t, x, args), bool), 1.0, -1.0)
        phi_t, grad = jax.jacfwd(surface.phi, argnums=(0, 1))(t, x, args)
        if kind == "rate":
            return phi_t + grad @ f(t, x, args)
        J_t, DJ = jax.jacfwd(surface.jump, argnums=(0, 1))(t, x, args)
        if kind == "det":
            return jnp.linalg.det(DJ)
        w = jnp.linalg.solve(DJ.T, grad)
        return phi_t + w @ (f(t, surface.jump(t, x, args), args) - J_t)

    def one(ta_, xa_, tb_, xb_):
        va = value(ta_, xa_)

        def step(_, carry):
            ta_, xa_, tb_, xb_, va = carry
            tm = 0.5 * (ta_ + tb_)
            xm = project_to_surface(surface.phi, tm, 0.5 * (xa_ + xb_), args)
            vm = value(tm, xm)
            same = jnp.sign(vm) == jnp.sign(va)
            ta_, xa_, va = (
                jnp.where(same, tm, ta_),
                jnp.where(same, xm, xa_),
                jnp.where(same, vm, va),
            )
            tb_, xb_ = jnp.where(same, tb_, tm), jnp.where(same, xb_, xm)
            return ta_, xa_, tb_, xb_, va

        ta_, xa_, tb_, xb_, _ = jax.lax.fori_loop(0, 50, step, (ta_, xa_, tb_, xb_, va))
        tm, xm = (
            0.5 * (ta_ + tb_),
            project_to_surface(surface.phi, 0.5 * (ta_ + tb_), 0.5 * (xa_ + xb_), args),
        )
        inside = (
            jnp.array(True)
            if surface.where is None
            else jnp.asarray(surface.where(tm, xm, args), bool)
        )
        return tm, xm, inside

    return jax.vmap(one)(ta, xa, tb, xb)


@eqx.filter_jit
def _inverse_at(scene: Scene, i: int, ts, ys, args):
    surface = scene.surfaces[i]
    return jax.vmap(lambda t, y: inverse_jump(surface, t, y, args))(ts, ys)


@eqx.filter_jit
def _critical_points(scene: Scene, i: int, ts, xs, args):
    """Newton on ∇Φ(t, x) = 0 (least squares steps) from the given starts."""
    phi = scene.surfaces[i].phi

    def one(t, x):
        def step(_, x_):
            grad = jax.grad(phi, argnums=1)(t, x_, args)
            H = jax.hessian(phi, argnums=1)(t, x_, args)
            dx, *_ = jnp.linalg.lstsq(H, grad)
            return jnp.where(jnp.all(jnp.isfinite(dx)), x_ - dx, x_)

        x_ = jax.lax.fori_loop(0, 40, step, x)
        return x_, phi(t, x_, args), jax.grad(phi, argnums=1)(t, x_, args)

    return jax.vmap(one)(ts, xs)


# --------------------------------------------------------------------------------------
# check_conditions
# --------------------------------------------------------------------------------------


def _neighbour_pairs(points, k):
    """Index pairs (a, b), a < b, with b among the k nearest neighbours of a."""
    m = len(points)
    if m < 2:
        return np.zeros((0, 2), int)
    k = min(k, m - 1)
    d2 = np.sum((points[:, None, :] - points[None, :, :]) ** 2, axis=-1)
    np.fill_diagonal(d2, np.inf)
    nearest = np.argpartition(d2, k - 1, axis=1)[:, :k]
    pairs = np.stack([np.repeat(np.arange(m), k), nearest.reshape(-1)], axis=1)
    pairs = np.sort(pairs, axis=1)
    return np.unique(pairs, axis=0)


def _dedupe(points, scale):
    points = np.asarray(points, float)
    if points.size == 0:
        return points.reshape(0, points.shape[-1] if points.ndim == 2 else 0)
    kept = []
    for p in points:
        if all(np.max(np.abs(p - q)) > 1e-6 * scale for q in kept):
            kept.append(p)
    return np.array(kept)


def _sign_change_zeros(scene, i, kind, tx, values, mask, pairs, args, scale):
    """Zeros of `values` between neighbouring samples (both in `mask`) of opposite sign."""
    if len(pairs) == 0:
        return np.zeros((0, tx.shape[1]))
    a, b = pairs[:, 0], pairs[:, 1]
    keep = mask[a] & mask[b] & (np.sign(values[a]) * np.sign(values[b]) < 0)
    a, b = a[keep], b[keep]
    if len(a) == 0:
        return np.zeros((0, tx.shape[1]))
    # One representative pair per 16: enough to locate each zero, bounded cost.
    if len(a) > 64:
        a, b = a[:: len(a) // 64], b[:: len(b) // 64]
    tm, xm, inside = _bisect_segments(
        scene,
        i,
        kind,
        jnp.asarray(tx[a, 0]),
        jnp.asarray(tx[a, 1:]),
        jnp.asarray(tx[b, 0]),
        jnp.asarray(tx[b, 1:]),
        args,
    )
    found = np.concatenate([np.asarray(tm)[:, None], np.asarray(xm)], axis=1)
    if kind != "where":
        found = found[np.asarray(inside)]
    return _dedupe(found, scale)


def check_conditions(
    scene: Scene,
    args=None,
    *,
    samples: int = 1000,
    key=None,
    box=None,
    t_range: tuple[float, float] = (0.0, 0.0),
    rtol: float = 1e-9,
    flights: int = 0,
    horizon: float = 10.0,
) -> ConditionReport:
    r"""Test the paper's (C1)–(C7) and (A1) numerically on every surface piece.

    **How each piece is sampled.** `samples` points are drawn uniformly in `box` (and
    times uniformly in `t_range`) and projected onto {Φ_i(t, ·) = 0} by Newton steps
    along ∇Φ_i; points that converge inside the box are kept and split by `where_i` into
    the piece Γ_i and the rest of the zero set. The boundary ∂Γ_i is located by
    bisection (with projection) between neighbouring samples on either side of `where_i`;
    a sample is *interior* if `where_i` does not change within δ = 1e-6 of the box size.
    "Neighbouring" means among each sample's 6 nearest samples.

    **How each condition is tested** (a violation is reported with its location):

    - (C1) ∇Φ ≠ 0 on Γ: ‖∇Φ‖ > `rtol`·(median ‖∇Φ‖) at every sample of Γ_i; and Newton
      on ∇Φ = 0 from the 8 samples of smallest ‖∇Φ‖: a critical point of Φ on Γ_i is a
      violation.
    - (C2) J ∈ C¹ and det DJ ≠ 0 off ∂Γ: at interior samples DJ is finite; between
      neighbouring interior samples a, b, DJ(b) − DJ(a) agrees with the trapezoid rule
      ½(D²J(a) + D²J(b))(b − a) to 1e-3·(1 + ‖DJ‖) (a kink of J, from `abs` or
      `jnp.where`, leaves an O(1) jump of DJ); |det DJ| > `rtol`·‖DJ‖₂ⁿ, and det DJ does not
      change sign between neighbouring interior samples (a sign change is bisected to the
      zero). We sample Γ_i \ ∂Γ_i, not the neighbourhood Γ^r: J is only ever applied on Γ.
    - (C4) ⟨∇Φ, f⟩ ≠ 0 on Γ \ ∂Γ: the approach rate ∂Φ/∂t + ∇Φ·f (the paper's ⟨∇Φ, f⟩
      for autonomous scenes; the ∂Φ/∂t term is that of moving surfaces) is tested like
      det DJ: |rate| > `rtol`·(‖∇Φ‖·‖f‖ + |∂Φ/∂t|) at interior samples (so an equilibrium
      on Γ violates it), and no sign change between neighbouring interior samples.
    - (C5) ⟨∇Φ̃, f⟩ ≠ 0 on Γ̃ \ ∂Γ̃: at y = J(x) for interior samples x, with
      ∇Φ̃(y) = DJ(x)⁻ᵀ∇Φ(x) and ∂Φ̃/∂t = ∂Φ/∂t − ∇Φᵀ DJ⁻¹ ∂J/∂t, the rate
      ∂Φ/∂t + ∇Φᵀ DJ(x)⁻¹ (f(t, J(x)) − ∂J/∂t) is tested as in (C4). Where DJ is singular
      Φ̃ is undefined: (C5) is then reported untested (None).
    - (C6) J = id on ∂Γ: ‖J(b) − b‖∞ ≤ 1e-8·(1 + ‖b‖∞) at every located boundary point b.
    - (C7) J̃ = id on ∂Γ̃: at b̃ = J(b), J⁻¹(b̃) (from `inverse_jump`, else Newton) equals
      b̃ to the same tolerance; untested where J⁻¹ cannot be solved.

    A piece without `where`, or whose boundary is outside the box, has no boundary: (C6)
    and (C7) then hold vacuously (the detail says so).

    - (C3) Γ ∩ Γ̃ ⊆ ∂Γ ∩ ∂Γ̃: interior samples of Γ_i that lie on Γ̃_i (J⁻¹ solved by
      `inverse_jump`, Φ(J⁻¹x) = 0 to 1e-8 of the box scale, J⁻¹x in the piece), and sign
      changes of Φ ∘ J⁻¹ between neighbouring interior samples, are violations; untested
      where J⁻¹ cannot be solved at any sample.
    - (A1) grazing points are isolated: two neighbouring interior samples that are both
      tangential in the (C4) test mean a continuum of grazing points.

    (C8)–(C10) are statements about whole solutions of the free flow y' = f; with
    `flights > 0` they are sampled by flying it (`simulate`, rtol = atol = 1e-10, no jumps)
    from the first `flights` box samples that lie in the domain D, taken as the free side
    of every surface (Φ_j ≥ 0 for all j), for `horizon` in each time direction, saving the
    state at 256 evenly spaced times:
    (C9) a flight that ends non-finite or by a step failure before meeting Γ_i (forward) or
    Γ̃_i (backward: Φ̃_i changes sign along the saved states first) is a violation; (C10) a forward flight along which
    Φ̃_i = Φ_i ∘ J_i⁻¹ changes sign (with J_i⁻¹ solved and in the piece at both saved
    states) before it meets Γ_i is a violation — a crossing of Γ̃ between two saved states
    only is seen if Φ̃ changes sign there; (C8) sup‖f‖ over the box samples, and ζ, the time
    from y0 = J(x) ∈ Γ̃ (x: the first `flights` points of the piece) to the first meeting with
    Γ: the smallest ζ found must be > 0 (a sampled infimum: a limit ζ → 0, e.g. towards
    ∂Γ̃, is not seen; the detail names the smallest ζ).

    **Arguments:**

    - `scene`, `args`: the scene and its parameters.
    - `samples`: points drawn per surface (default 1000).
    - `key`: a `jax.random` key (default `PRNGKey(0)`: reproducible).
    - `box`: `(n, 2)` bounds of the region to test (default [−2, 2] in every coordinate,
      the scale of the paper's examples, with n the smallest state size at which
      `scene.vector_field` evaluates: pass `box` for a field written for any n).
    - `t_range`: times to sample (default t = 0; give a period for non-autonomous scenes).
    - `rtol`: relative tolerance of the "≠ 0" tests.
    - `flights`, `horizon`: free flights per surface for (C8)–(C10) (default 0: not
      tested; e.g. 64), each `horizon` long in each time direction.

    **Returns:** a `grazejax.ConditionReport`; `print(report)` lists violations first,
    `report.ok`, `report.holds("C4", 0)` and `report.violations` query it.

    **Example:**

    ```python
    report = grazejax.check_conditions(examples.exnonaxial(), examples.exnonaxial_args())
    print(report)   # (C2) det DJ ≡ 0; (C4) tangency at (1/√2, 1/√2), interior of Γ
    ```
    """
    if not isinstance(scene, Scene):
        raise TypeError(f"scene must be a grazejax.Scene, got {type(scene).__name__}")
    if not isinstance(samples, (int, np.integer)) or samples < 10:
        raise ValueError(f"samples must be an integer >= 10, got {samples!r}")
    if len(scene.surfaces) == 0:
        raise ValueError("the scene has no surfaces: nothing to check")
    n = _state_dimension(scene, args)
    box = np.array([[-2.0, 2.0]] * n) if box is None else np.asarray(box, float)
    if box.shape != (n, 2) or np.any(box[:, 1] <= box[:, 0]):
        raise ValueError(
            f"box must have shape ({n}, 2) with lower < upper bounds, got {box.tolist()}"
        )
    t_lo, t_hi = (float(v) for v in t_range)
    key = jax.random.PRNGKey(0) if key is None else key
    if args is not None:
        args = jax.tree.map(
            lambda a: (
                jnp.asarray(a) if isinstance(a, (float, int)) and not isinstance(a, bool) else a
            ),
            args,
        )
    width = box[:, 1] - box[:, 0]
    scale = float(np.max(np.abs(box)))
    delta = jnp.asarray(1e-6 * width)

    results = []
    for i in range(len(scene.surfaces)):
        key, k_x, k_t = jax.random.split(key, 3)
        xs = box[:, 0] + width * np.asarray(jax.random.uniform(k_x, (samples, n)))
        ts = t_lo + (t_hi - t_lo) * np.asarray(jax.random.uniform(k_t, (samples,)))
        results.extend(_check_surface(scene, i, ts, xs, args, box, delta, scale, rtol))
        if flights > 0:
            results.extend(_flight_conditions(scene, i, ts, xs, args, flights, horizon, scale))
    return ConditionReport(tuple(results), int(samples), box, (t_lo, t_hi))


def _state_dimension(scene, args):
    # The scene does not know n; find it from the vector field by trying small sizes.
    for n in range(1, 33):
        try:
            out = jax.eval_shape(scene.vector_field, 0.0, jnp.zeros(n), args)
        except Exception:  # noqa: BLE001 - wrong size: try the next one
            continue
        if getattr(out, "shape", None) == (n,):
            return n
    raise ValueError("could not determine the state dimension from scene.vector_field")


def _result(condition, i, name, holds, detail, points=(), width=1):
    points = np.asarray(points, float)
    points = points.reshape(-1, points.shape[-1]) if points.size else np.zeros((0, width))
    return ConditionResult(condition, i, name, holds, STATEMENTS[condition], detail, points[:5])


class _Piece(NamedTuple):
    """The samples of one surface piece that the sampled conditions read."""

    scene: Scene
    i: int
    args: object
    box: np.ndarray
    scale: float
    rtol: float
    ts: np.ndarray  # sample times
    projected: np.ndarray  # samples projected onto Φ_i = 0
    tx: np.ndarray  # (t, x) rows
    ev: dict  # Φ, ∇Φ, f, DJ, ... at the projected samples (`_evaluate`)
    box_grad: np.ndarray  # ‖∇Φ‖ at the unprojected box samples
    grad_norm: np.ndarray
    converged: np.ndarray  # projected onto Φ = 0, inside the box
    on_piece: np.ndarray  # converged and `where` true
    interior: np.ndarray  # on the piece, `where` constant within δ
    pairs: np.ndarray  # neighbouring sample indices

    @property
    def name(self) -> str:
        return self.scene.surface_name(self.i)

    @property
    def surface(self) -> Surface:
        return self.scene.surfaces[self.i]

    @property
    def width(self) -> int:
        return self.tx.shape[1]

    def result(self, condition, holds, detail, points=()):
        return _result(condition, self.i, self.name, holds, detail, points, self.width)


def _check_surface(scene, i, ts, xs, args, box, delta, scale, rtol):
    piece = _sample_piece(scene, i, ts, xs, args, box, delta, scale, rtol)
    if not piece.on_piece.any():
        detail = "no point of this piece was found in the box: nothing tested"
        return [piece.result(c, None, detail)
                for c in ("C1", "C2", "C3", "C4", "C5", "C6", "C7", "A1")]
    c2, finite, singular, det = _c2(piece)
    c4, flat_rate = _c4(piece)
    return [_c1(piece), c2, c4, _c5(piece, finite, singular, det),
            *_c3_a1(piece, flat_rate),
            *_c6_c7(piece)]


def _sample_piece(scene, i, ts, xs, args, box, delta, scale, rtol) -> _Piece:
    """Project the box samples onto Φ_i = 0, evaluate everything the conditions read
    there, and sort the samples: converged, on the piece, interior; neighbouring pairs."""
    projected, box_grad = (
        np.asarray(v) for v in _sample_surface(scene, i, jnp.asarray(ts), jnp.asarray(xs), args)
    )
    ev = jax.tree.map(
        np.asarray, _evaluate(scene, i, jnp.asarray(ts), jnp.asarray(projected), args, delta)
    )
    grad_norm = np.linalg.norm(ev["grad"], axis=1)
    in_box = np.all(
        (projected >= box[:, 0] - 1e-9 * scale) & (projected <= box[:, 1] + 1e-9 * scale), axis=1
    )
    converged = (
        np.isfinite(ev["phi"])
        & in_box
        & (np.abs(ev["phi"]) <= 1e-10 * (1 + grad_norm * np.max(np.abs(projected), axis=1)))
    )
    on_piece = converged & ev["inside"]
    tx = np.concatenate([ts[:, None], projected], axis=1)
    pairs = np.zeros((0, 2), int)
    if on_piece.any():
        pairs = _neighbour_pairs(
            tx[converged] / np.concatenate([[max(1.0, abs(ts).max())], box[:, 1] - box[:, 0]]), 6
        )
        # Pair indices refer to the converged subset: map back to sample indices.
        pairs = np.flatnonzero(converged)[pairs] if len(pairs) else pairs
    return _Piece(scene, i, args, box, scale, rtol, ts, projected, tx, ev, box_grad,
                  grad_norm, converged, on_piece, on_piece & ~ev["near_boundary"], pairs)


def _c1(p: _Piece) -> ConditionResult:
    """(C1): small ‖∇Φ‖ at the samples, and Newton on ∇Φ = 0 from the flattest ones."""
    on_piece, grad_norm, box, args = p.on_piece, p.grad_norm, p.box, p.args
    m = int(on_piece.sum())
    # The scale of ∇Φ is taken over the whole box, not over Γ: if ∇Φ vanishes on all of
    # Γ (Φ = x³), its median on Γ is tiny too.
    median = float(np.median(p.box_grad[np.isfinite(p.box_grad)]))
    small = on_piece & (grad_norm <= p.rtol * median)
    c1_points = list(p.tx[small])
    starts = np.argsort(np.where(on_piece, grad_norm, np.inf))[: min(8, m)]
    xc, phic, gradc = (
        np.asarray(v)
        for v in _critical_points(
            p.scene, p.i, jnp.asarray(p.ts[starts]), jnp.asarray(p.projected[starts]), args
        )
    )
    for t_, x_, p_, g_ in zip(p.ts[starts], xc, phic, gradc, strict=True):
        on = abs(p_) <= 1e-9 * (1 + p.scale) and np.linalg.norm(g_) <= 1e-9 * max(median, 1e-300)
        in_piece = p.surface.where is None or bool(p.surface.where(t_, jnp.asarray(x_), args))
        if on and in_piece and np.all((x_ >= box[:, 0]) & (x_ <= box[:, 1])):
            c1_points.append(np.concatenate([[t_], x_]))
    c1_points = _dedupe(np.array(c1_points).reshape(-1, p.width), p.scale) if c1_points else []
    return p.result(
        "C1",
        len(c1_points) == 0,
        f"‖∇Φ‖ at {m} points of the piece: min {grad_norm[on_piece].min():.3g} (median over the box {median:.3g}); "
        f"critical points of Φ on the piece: {len(c1_points)}",
        c1_points,
    )


def _c2(p: _Piece):
    """(C2): DJ finite and C¹ between neighbours, det DJ ≠ 0 and without sign changes.
    Returns the result and, per sample, whether DJ is finite, whether it is singular, and
    det DJ (for (C5))."""
    DJ, interior, pairs, tx = p.ev["DJ"], p.interior, p.pairs, p.tx
    k_int = int(interior.sum())
    finite = np.all(np.isfinite(DJ), axis=(1, 2))
    # C¹: for a C³ law, DJ(b) − DJ(a) = ½(D²J(a) + D²J(b))(b − a) + O(|b − a|³) between
    # neighbouring samples; a kink (abs, where) leaves an O(1) jump of DJ instead.
    kink = interior & ~finite
    if len(pairs):
        a, b = pairs[:, 0], pairs[:, 1]
        use = interior[a] & interior[b] & finite[a] & finite[b] & (p.ts[a] == p.ts[b])
        a, b = a[use], b[use]
        step = p.projected[b] - p.projected[a]
        trapezoid = 0.5 * np.einsum("kijl,kl->kij", p.ev["D2J"][a] + p.ev["D2J"][b], step)
        miss = np.linalg.norm(DJ[b] - DJ[a] - trapezoid, axis=(1, 2))
        bad = miss > 1e-3 * (1 + np.linalg.norm(DJ[a], axis=(1, 2)))
        kink_points = 0.5 * (tx[a[bad]] + tx[b[bad]])
    else:
        kink_points = np.zeros((0, p.width))
    kink_points = _dedupe(np.concatenate([tx[kink], kink_points]), 1e3 * p.scale)
    dets = np.where(finite[:, None, None], DJ, 0.0)
    det = np.linalg.det(dets)
    norm2 = np.linalg.norm(dets, ord=2, axis=(1, 2))
    n = p.projected.shape[1]
    singular = interior & finite & (np.abs(det) <= p.rtol * np.maximum(norm2, 1e-300) ** n)
    zeros = _sign_change_zeros(p.scene, p.i, "det", tx, det, interior & finite, pairs, p.args,
                               p.scale)
    c2_points = list(kink_points) + list(tx[singular]) + list(zeros)
    parts = [f"at {k_int} interior points"]
    if len(kink_points):
        parts.append(
            "J is not C¹ (DJ not finite, or it jumps between neighbouring samples) "
            f"near {len(kink_points)} point(s)"
        )
    if singular.any():
        parts.append(f"det DJ = 0 at {int(singular.sum())} (J is not invertible there)")
    if len(zeros):
        parts.append(f"det DJ changes sign: {len(zeros)} zero(s) located")
    if len(parts) == 1 and k_int:
        parts.append(f"min |det DJ| = {np.abs(det[interior]).min():.3g}")
    result = p.result("C2", None if k_int == 0 else len(c2_points) == 0, "; ".join(parts),
                      c2_points)
    return result, finite, singular, det


def _c4(p: _Piece):
    """(C4): the approach rate ∂Φ/∂t + ∇Φ·f nonzero and without sign changes at interior
    samples. Returns the result and the tangential samples (for (A1))."""
    ev, interior, tx = p.ev, p.interior, p.tx
    k_int = int(interior.sum())
    f = ev["f"]
    rate = ev["phi_t"] + np.einsum("ij,ij->i", ev["grad"], f)
    size = p.grad_norm * np.linalg.norm(f, axis=1) + np.abs(ev["phi_t"])
    flat = interior & (np.abs(rate) <= p.rtol * size + 1e-300)
    zeros = _sign_change_zeros(p.scene, p.i, "rate", tx, rate, interior, p.pairs, p.args, p.scale)
    c4_points = list(tx[flat]) + list(zeros)
    detail = f"approach rate ∂Φ/∂t + ∇Φ·f at {k_int} interior points"
    if k_int:
        detail += f": range [{rate[interior].min():.3g}, {rate[interior].max():.3g}]"
    if flat.any():
        detail += f"; zero (tangency or f = 0) at {int(flat.sum())} points"
    if len(zeros):
        detail += f"; changes sign: tangency located at {len(zeros)} interior point(s)"
    return p.result("C4", None if k_int == 0 else len(c4_points) == 0, detail, c4_points), flat


def _c5(p: _Piece, finite, singular, det) -> ConditionResult:
    """(C5): the rate of Φ̃ = Φ ∘ J⁻¹ along f at the images J(x) of interior samples."""
    ev, interior, tx = p.ev, p.interior, p.tx
    invertible = interior & finite & ~singular & (np.abs(det) > 0)
    if not invertible.any():
        return p.result(
            "C5",
            None,
            "not testable: DJ is singular at every interior sample, so Φ̃ = Φ ∘ J⁻¹ is undefined",
        )
    DJ = ev["DJ"]
    w = np.zeros_like(ev["grad"])
    w[invertible] = np.linalg.solve(
        np.transpose(DJ[invertible], (0, 2, 1)), ev["grad"][invertible][..., None]
    )[..., 0]
    img_rate = ev["phi_t"] + np.einsum("ij,ij->i", w, ev["f_post"] - ev["J_t"])
    img_size = np.linalg.norm(w, axis=1) * np.linalg.norm(ev["f_post"], axis=1) + np.abs(
        ev["phi_t"]
    )
    flat = invertible & (np.abs(img_rate) <= p.rtol * img_size + 1e-300)
    zeros = _sign_change_zeros(
        p.scene, p.i, "image_rate", tx, img_rate, invertible, p.pairs, p.args, p.scale
    )
    c5_points = [
        np.concatenate([[q[0]], np.asarray(p.surface.jump(q[0], jnp.asarray(q[1:]), p.args))])
        for q in list(tx[flat]) + list(zeros)
    ]
    detail = (
        f"rate of Φ̃ along f at the images J(x) of {int(invertible.sum())} interior points: "
        f"range [{img_rate[invertible].min():.3g}, {img_rate[invertible].max():.3g}]"
    )
    if len(c5_points):
        detail += f"; zero at {len(c5_points)} image point(s) (reported as points of Γ̃)"
    skipped = int(interior.sum() - invertible.sum())
    if skipped:
        detail += f"; {skipped} samples skipped (DJ singular)"
    return p.result("C5", len(c5_points) == 0, detail, c5_points)


def _c6_c7(p: _Piece) -> list[ConditionResult]:
    """∂Γ located between neighbours on either side of `where`; (C6) J = id there, (C7)
    J⁻¹ = id on its image."""
    surface, args = p.surface, p.args
    if surface.where is None:
        boundary = np.zeros((0, p.width))
        where_note = "the piece has no `where`, so no boundary"
    else:
        side = np.where(p.ev["inside"], 1.0, -1.0)
        boundary = _sign_change_zeros(p.scene, p.i, "where", p.tx, side, p.converged, p.pairs,
                                      args, p.scale)
        where_note = f"{len(boundary)} boundary point(s) located in the box"
    if len(boundary) == 0:
        return [p.result("C6", True, f"vacuous: {where_note}"),
                p.result("C7", True, f"vacuous: {where_note}")]
    bt, bx = boundary[:, 0], boundary[:, 1:]
    post = np.asarray(
        jax.vmap(lambda t_, x_: surface.jump(t_, x_, args))(jnp.asarray(bt), jnp.asarray(bx))
    )
    moved = np.max(np.abs(post - bx), axis=1)
    bad6 = moved > 1e-8 * (1 + np.max(np.abs(bx), axis=1))
    c6 = p.result("C6", not bad6.any(), f"{where_note}; max ‖J(b) − b‖∞ = {moved.max():.3g}",
                  boundary[bad6])
    inv, ok = (
        np.asarray(v) for v in _inverse_at(p.scene, p.i, jnp.asarray(bt), jnp.asarray(post), args)
    )
    if not ok.any():
        return [c6, p.result(
            "C7",
            None,
            f"not testable: J⁻¹ could not be solved at the {len(post)} point(s) of ∂Γ̃ = J(∂Γ)",
        )]
    moved7 = np.max(np.abs(inv - post), axis=1)
    bad7 = ok & (moved7 > 1e-8 * (1 + np.max(np.abs(post), axis=1)))
    pts = np.concatenate([bt[:, None], post], axis=1)[bad7]
    note = "" if ok.all() else f"; J⁻¹ not solved at {int((~ok).sum())} point(s)"
    return [c6, p.result(
        "C7",
        not bad7.any(),
        f"at {int(ok.sum())} point(s) of ∂Γ̃ = J(∂Γ): max ‖J⁻¹(b̃) − b̃‖∞ = {moved7[ok].max():.3g}{note}",
        pts,
    )]


def _c3_a1(p: _Piece, flat_rate):
    """(C3) and (A1) from the samples of the piece (no flights).

    (C3): an interior sample x of Γ_i that also lies on Γ̃_i = J_i(Γ_i) — J⁻¹(x) exists
    (`inverse_jump`), lies on Φ = 0 within 1e-8 of the box scale and in the closed piece —
    is a violation; so is a sign change of Φ̃ = Φ ∘ J⁻¹ between neighbouring interior
    samples (a point of Γ ∩ Γ̃ between them: its midpoint is reported).
    (A1): the tangency set of (C4) (interior samples with a zero approach rate) must be
    isolated points: two neighbouring samples that are both tangential mean a continuum
    of grazing points (a violation); isolated sign changes of the rate do not.
    """
    scene, i, name, tx, width = p.scene, p.i, p.name, p.tx, p.width
    interior, pairs, args, scale = p.interior, p.pairs, p.args, p.scale
    image_gap, on_image, solved = (np.asarray(v) for v in _image_gaps(
        scene, i, jnp.asarray(tx[:, 0]), jnp.asarray(tx[:, 1:]), args, scale))
    both = interior & on_image
    points = list(tx[both])
    if len(pairs):
        a, b = pairs[:, 0], pairs[:, 1]
        use = interior[a] & interior[b] & np.isfinite(image_gap[a]) & np.isfinite(image_gap[b])
        change = use & (np.sign(image_gap[a]) * np.sign(image_gap[b]) < 0)
        points += list(0.5 * (tx[a[change]] + tx[b[change]]))
    points = _dedupe(np.array(points).reshape(-1, width), scale) if points else []
    k = int(interior.sum())
    testable = k > 0 and bool((solved & interior).any())
    c3 = _result(
        "C3", i, name, None if not testable else len(points) == 0,
        f"{k} interior samples of Γ tested against Γ̃ = J(Γ) (J⁻¹ then Φ = 0 in the piece): "
        f"{int(both.sum())} on Γ̃" + (f", {len(points)} point(s) of Γ ∩ Γ̃ off ∂Γ" if len(points) else "")
        + ("" if testable else "; not testable: J⁻¹ could not be solved at any sample"),
        points, width,
    )
    run = np.zeros((0, width))
    if len(pairs):
        a, b = pairs[:, 0], pairs[:, 1]
        continuum = flat_rate[a] & flat_rate[b] & (np.max(np.abs(tx[a] - tx[b]), axis=1) > 0)
        run = 0.5 * (tx[a[continuum]] + tx[b[continuum]])
    a1 = _result(
        "A1", i, name, None if k == 0 else len(run) == 0,
        f"{int(flat_rate.sum())} tangential interior samples; "
        + (f"{len(run)} neighbouring pair(s) both tangential: a continuum of grazing points"
           if len(run) else "none neighbouring another: grazing points are isolated"),
        run, width,
    )
    return [c3, a1]


@eqx.filter_jit
def _image_gaps(scene: Scene, i: int, ts, xs, args, scale):
    """Φ̃ = Φ ∘ J⁻¹ at the samples, and whether each lies on Γ̃ (J⁻¹ solved, in the piece)."""
    surface = scene.surfaces[i]

    def one(t, x):
        z, ok = inverse_jump(surface, t, x, args)
        g = surface.phi(t, z, args)
        if surface.where is None:
            inside = jnp.array(True)
        else:
            inside = jnp.asarray(surface.where(t, z, args), bool)
        on = ok & inside & (jnp.abs(g) <= 1e-8 * (1.0 + scale))
        return jnp.where(ok & inside, g, jnp.nan), on, ok

    return jax.vmap(one)(ts, xs)



_FLIGHT_TOL = dict(rtol=1e-10, atol=1e-10)
_SAVES = 256
_FAILED = (int(Status.NONFINITE), int(Status.MAX_STEPS), int(Status.STEP_SIZE_UNDERFLOW))


@eqx.filter_jit
def _flights(scene: Scene, i: int, ts, xs, args, horizon):
    """Free flights from (t, x): forward until Γ_i is met (its time, status, saved states)
    and backward to the horizon (status, saved states). No jump is applied."""
    surface = scene.surfaces[i]
    probe = scene.with_surfaces([surface.probe()])
    free = scene.with_surfaces([])
    fractions = jnp.linspace(0.0, 1.0, _SAVES + 1)[1:]

    def one(t, x):
        forward = simulate(probe, x, t, t + horizon, args, max_impacts=1, direction=1,
                           saveat=t + horizon * fractions, max_steps=50_000, **_FLIGHT_TOL)
        backward = simulate(free, x, t, t - horizon, args, direction=-1,
                            saveat=t - horizon * fractions, max_steps=50_000, **_FLIGHT_TOL)
        met = forward.num_impacts > 0
        tau = jnp.where(met, forward.impact_times[0] - t, jnp.inf)
        return tau, forward.status, forward.xs, backward.status, backward.xs

    return jax.vmap(one)(ts, xs)


def _in_domain(scene, ts, xs, args):
    gaps = [np.asarray(jax.vmap(lambda t, x, s=s: s.phi(t, x, args))(jnp.asarray(ts), jnp.asarray(xs)))
            for s in scene.surfaces]
    return np.all(np.stack(gaps) >= 0, axis=0)


def _crosses_image(scene, i, times, states, before, args, scale):
    """Per flight: does Φ̃_i change sign between consecutive saved states before `before`?"""
    k, m, n = states.shape
    g, _, _ = (np.asarray(v) for v in _image_gaps(
        scene, i, jnp.asarray(times.reshape(-1)), jnp.asarray(states.reshape(-1, n)), args, scale))
    g = g.reshape(k, m)
    valid = np.isfinite(g[:, 1:]) & np.isfinite(g[:, :-1]) & (times[:, 1:] < before[:, None])
    return np.any(valid & (np.sign(g[:, 1:]) * np.sign(g[:, :-1]) < 0), axis=1)


def _flight_conditions(scene, i, ts, xs, args, flights, horizon, scale):
    """(C8), (C9), (C10) on surface i (see `check_conditions`)."""
    name, surface = scene.surface_name(i), scene.surfaces[i]
    width = xs.shape[1] + 1
    start = np.flatnonzero(_in_domain(scene, ts, xs, args))[:flights]
    if len(start) == 0:
        note = "no box sample lies on the free side of every surface: nothing flown"
        return [_result(c, i, name, None, note, width=width) for c in ("C8", "C9", "C10")]
    t0, x0 = ts[start], xs[start]
    tau, fwd, saved, bwd, saved_back = (np.asarray(v) for v in _flights(
        scene, i, jnp.asarray(t0), jnp.asarray(x0), args, float(horizon)))
    tx = np.concatenate([t0[:, None], x0], axis=1)
    steps = horizon * np.linspace(0.0, 1.0, _SAVES + 1)[1:]
    times = t0[:, None] + steps[None, :]
    blow_fwd = np.isin(fwd, _FAILED) & ~np.isfinite(tau)
    # Backward, meeting Γ̃ first is an allowed end (C9 b): only a blow-up before it counts.
    back_times = t0[:, None] - steps[None, :]
    met_image_back = _crosses_image(scene, i, back_times, np.nan_to_num(saved_back, nan=np.inf),
                                    np.full(len(t0), np.inf), args, scale)
    blow_bwd = np.isin(bwd, _FAILED) & ~met_image_back
    c9 = _result("C9", i, name, not (blow_fwd.any() or blow_bwd.any()),
                 f"{len(start)} flights of ±{horizon:g} from D: {int(blow_fwd.sum())} forward, "
                 f"{int(blow_bwd.sum())} backward ended by blow-up or step failure",
                 tx[blow_fwd | blow_bwd], width)
    first = _crosses_image(scene, i, times, np.nan_to_num(saved, nan=np.inf), t0 + tau, args, scale)
    c10 = _result("C10", i, name, not first.any(),
                  f"{len(start)} forward flights from D: {int(np.isfinite(tau).sum())} meet Γ "
                  f"within {horizon:g}, {int(first.sum())} cross Γ̃ = J(Γ) before meeting Γ",
                  tx[first], width)
    fx = np.asarray(jax.vmap(lambda t, x: scene.vector_field(t, x, args))(jnp.asarray(ts), jnp.asarray(xs)))
    sup_f = float(np.max(np.linalg.norm(fx, axis=1)))
    on = _points_on(scene, i, ts, xs, args)[:flights]
    if len(on) == 0:
        return [_result("C8", i, name, None, f"sup ‖f‖ = {sup_f:.3g}; no point of Γ found", width=width),
                c9, c10]
    post = np.asarray(jax.vmap(lambda t, x: surface.jump(t, x, args))(jnp.asarray(on[:, 0]), jnp.asarray(on[:, 1:])))
    pad = flights - len(on)  # the same batch size as above: one compiled program
    zeta = np.asarray(_flights(scene, i, jnp.asarray(np.pad(on[:, 0], (0, max(pad, 0)), mode="edge")),
                               jnp.asarray(np.pad(post, ((0, max(pad, 0)), (0, 0)), mode="edge")),
                               args, float(horizon))[0])[: len(on)]
    met = np.isfinite(zeta)
    detail = f"sup ‖f‖ = {sup_f:.3g} on the box samples; "
    if not met.any():
        return [_result("C8", i, name, bool(np.isfinite(sup_f)),
                        detail + f"no flight from {len(on)} points of Γ̃ met Γ within {horizon:g}",
                        width=width), c9, c10]
    k = int(np.argmin(np.where(met, zeta, np.inf)))
    c8 = _result("C8", i, name, bool(np.isfinite(sup_f) and zeta[k] > 0),
                 detail + f"ζ from {int(met.sum())} of {len(on)} points of Γ̃ = J(Γ): smallest "
                 f"{zeta[k]:.3g}, from y0 = {np.array2string(post[k], precision=6)} (a sampled "
                 "infimum: a limit ζ → 0 is not seen)", width=width)
    return [c8, c9, c10]


def _points_on(scene, i, ts, xs, args):
    """Box samples projected onto Γ_i and in the piece: rows (t, x)."""
    phi, where = scene.surfaces[i].phi, scene.surfaces[i].where
    projected = np.asarray(jax.vmap(lambda t, x: project_to_surface(phi, t, x, args))(
        jnp.asarray(ts), jnp.asarray(xs)))
    gaps = np.asarray(jax.vmap(lambda t, x: phi(t, x, args))(jnp.asarray(ts), jnp.asarray(projected)))
    ok = np.isfinite(gaps) & (np.abs(gaps) <= 1e-10 * (1 + np.max(np.abs(projected), axis=1)))
    if where is not None:
        safe = np.where(ok[:, None], projected, 0.0)
        ok &= np.asarray(jax.vmap(lambda t, x: jnp.asarray(where(t, x, args), bool))(
            jnp.asarray(ts), jnp.asarray(safe)))
    return np.concatenate([ts[:, None], projected], axis=1)[ok]
