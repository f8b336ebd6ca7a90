"""Ready-made scenes: the seed paper's four systems and classic impact systems.

Each factory returns a `grazejax.Scene`; its parameters live in `args` (use the
matching `*_args(...)` helper for the paper's values). Equations and sources are in each
docstring; "the paper" is Akhmet & Kıvılcım, *Discontinuous dynamics with grazing points*
(LaTeX labels in brackets). Where the paper is ambiguous our reading is stated.

Closed forms for tests and work-precision plots live next to the scenes they describe.
"""

import math

import jax.numpy as jnp
import numpy as np

from ._piecewise import Mode, PiecewiseScene, SwitchingSurface, Transition
from ._scene import Scene, Surface

# --------------------------------------------------------------------------------------
# The paper's systems
# --------------------------------------------------------------------------------------


def ex1dof() -> Scene:
    r"""Impact oscillator with a small parameter μ [ex1dof] (paper Example 5.2).

    x1' = x2,
    x2' = −ε (x2² + (x1 − 1)² − (1 + μ)²) x2 − x1 + 1,
    Γ = {x1 = 0, x2 ≤ 0} (reached with x1 decreasing),
    x2 → x2 − (1 + R x2 + μ x2³) x2 + μ².

    `args = {"mu": μ, "eps": 1e-4, "R": 0.9}` (see `ex1dof_args`). For μ ≤ 0 the circle
    Ψ_μ(t) = (1 + (1+μ) cos t, −(1+μ) sin t) is a periodic solution; at μ = 0 it grazes Γ
    at (0, 0). The jump maps Γ into Γ (post-impact velocity still points into the wall):
    the flight continues into x1 < 0 and comes back up through x1 = 0 without an impact.
    """

    def vector_field(t, x, args):
        x1, x2 = x[0], x[1]
        eps, mu = args["eps"], args["mu"]
        return jnp.stack(
            [x2, -eps * (x2**2 + (x1 - 1) ** 2 - (1 + mu) ** 2) * x2 - x1 + 1]
        )

    def jump(t, x, args):
        x2, mu, R = x[1], args["mu"], args["R"]
        return x.at[1].set(x2 - (1 + R * x2 + mu * x2**3) * x2 + mu**2)

    wall = Surface(
        phi=lambda t, x, args: x[0],
        jump=jump,
        where=lambda t, x, args: x[1] <= 0,
        name="Γ: x1 = 0, x2 ≤ 0",
    )
    return Scene(vector_field, [wall])


def ex1dof_args(mu=0.0, eps=1e-4, R=0.9) -> dict:
    return {"mu": jnp.asarray(mu, float), "eps": jnp.asarray(eps, float), "R": jnp.asarray(R, float)}


def ex1dof_circle(t, mu):
    """The periodic solution Ψ_μ(t) of ex1dof for μ ≤ 0 (closed form)."""
    return np.stack([1 + (1 + mu) * np.cos(t), -(1 + mu) * np.sin(t)], axis=-1)


def orbex2() -> Scene:
    r"""Two walls with a quadratic restitution law [orbex2] (paper Example 3.1).

    y1' = y2, y2' = −y1 + a y2 (a = 0.001),
    Γ1 = {y1 = c, y2 ≥ 0} (reached with y1 increasing), y2 → −R1 y2²,
    Γ2 = {y1 = 0, y2 ≤ 0} (reached with y1 decreasing), y2 → −R2 y2,
    with c = e^{0.00025π}, R1 = e^{−0.0005π}, R2 = 0.9 (see `orbex2_args`).

    The printed cycle Ψ(t) = e^{0.0005t}(sin t, cos t) is a first-order approximation: the
    exact solution from (0, 1) overshoots y1 = c by about 2.5e-7 and so *impacts* Γ1 at low
    speed. The reproduction report shows what the printed parameters really do.
    """

    def vector_field(t, y, args):
        return jnp.stack([y[1], -y[0] + args["a"] * y[1]])

    right = Surface(
        phi=lambda t, y, args: args["c"] - y[0],
        jump=lambda t, y, args: y.at[1].set(-args["R1"] * y[1] ** 2),
        where=lambda t, y, args: y[1] >= 0,
        name="Γ1: y1 = c, y2 ≥ 0",
    )
    left = Surface(
        phi=lambda t, y, args: y[0],
        jump=lambda t, y, args: y.at[1].set(-args["R2"] * y[1]),
        where=lambda t, y, args: y[1] <= 0,
        name="Γ2: y1 = 0, y2 ≤ 0",
    )
    return Scene(vector_field, [right, left])


def orbex2_args(a=0.001, c=None, R1=None, R2=0.9) -> dict:
    c = math.exp(0.00025 * math.pi) if c is None else c
    R1 = math.exp(-0.0005 * math.pi) if R1 is None else R1
    return {k: jnp.asarray(v, float) for k, v in dict(a=a, c=c, R1=R1, R2=R2).items()}


def smalldisc() -> Scene:
    r"""The perturbed two-wall model [smalldisc] (paper Example 5.1).

    x1' = x2, x2' = −a x2 − x1 (a = 0.001; note the sign differs from orbex2, as printed),
    Γ1 = {x1 = c, x2 ≥ 0}: Δx2 = −(1 + R1 x2 + μ x2) x2,
    Γ2 = {x1 = 0, x2 ≤ 0}: Δx2 = −(1 + R2 + μ (x2 − e^{0.001π/2})) x2.

    The paper's parenthesis in the Γ2 law is unbalanced; this closing is our reading
    (docs/design.md, *The paper's examples*). `args = {"mu", "a", "c", "R1", "R2", "v_ref"}` (see `smalldisc_args`).
    """

    def vector_field(t, x, args):
        return jnp.stack([x[1], -args["a"] * x[1] - x[0]])

    def jump_right(t, x, args):
        x2 = x[1]
        return x.at[1].set(x2 - (1 + args["R1"] * x2 + args["mu"] * x2) * x2)

    def jump_left(t, x, args):
        x2 = x[1]
        return x.at[1].set(x2 - (1 + args["R2"] + args["mu"] * (x2 - args["v_ref"])) * x2)

    right = Surface(
        phi=lambda t, x, args: args["c"] - x[0],
        jump=jump_right,
        where=lambda t, x, args: x[1] >= 0,
        name="Γ1: x1 = c, x2 ≥ 0",
    )
    left = Surface(
        phi=lambda t, x, args: x[0],
        jump=jump_left,
        where=lambda t, x, args: x[1] <= 0,
        name="Γ2: x1 = 0, x2 ≤ 0",
    )
    return Scene(vector_field, [right, left])


def smalldisc_args(mu=0.0, a=0.001, c=None, R1=None, R2=0.9) -> dict:
    c = math.exp(0.00025 * math.pi) if c is None else c
    R1 = math.exp(-0.0005 * math.pi) if R1 is None else R1
    values = dict(mu=mu, a=a, c=c, R1=R1, R2=R2, v_ref=math.exp(0.001 * math.pi / 2))
    return {k: jnp.asarray(v, float) for k, v in values.items()}


def exnonaxial() -> Scene:
    r"""A cycle with a non-axial grazing point [exnonaxial] (paper Example 3.3).

    x1' = x2, x2' = −x1 (a rotation), Γ = {x1 + x2 = √2} reached from x1 + x2 < √2,
    x → (1/√2 + K (x2 − x1)²)·(1, 1), K = 0.11 (`args = {"K": 0.11}`).

    The unit circle Ψ(t) = (sin t, cos t) grazes Γ at (1/√2, 1/√2). The jump lands on
    the diagonal Γ̃ = {x1 = x2}, beyond the line (Φ ≤ 0): the flight passes back through Γ
    upward before its next impact. Impact times and states have closed forms
    (`exnonaxial_first_impact`).
    """

    def vector_field(t, x, args):
        return jnp.stack([x[1], -x[0]])

    def jump(t, x, args):
        a = 1 / jnp.sqrt(2.0) + args["K"] * (x[1] - x[0]) ** 2
        return jnp.stack([a, a])

    line = Surface(
        phi=lambda t, x, args: jnp.sqrt(2.0) - x[0] - x[1],
        jump=jump,
        name="Γ: x1 + x2 = √2",
    )
    return Scene(vector_field, [line])


def exnonaxial_args(K=0.11) -> dict:
    return {"K": jnp.asarray(K, float)}


def exnonaxial_first_impact(x0, t0=0.0):
    """Exact first impact of the rotation flow on x1 + x2 = √2 from x0 (free side).

    The flow is x(t) = R(t − t0) x0 with x1 + x2 = √2·r·sin(t − t0 + φ + π/4) written in
    polar form x0 = r (sin φ, cos φ). Returns `(t, x_pre)` or `(inf, None)` if the circle
    of radius r < 1 never reaches the line.
    """
    x1, x2 = float(x0[0]), float(x0[1])
    r = math.hypot(x1, x2)
    if r < 1:
        return math.inf, None
    phi = math.atan2(x1, x2)  # x = r (sin(t + φ), cos(t + φ))
    # x1 + x2 = √2 r sin(t + φ + π/4) = √2  ⇔  sin(θ) = 1/r with θ = t + φ + π/4; the
    # downward-Φ (upward x1 + x2) crossing is where cos θ > 0: θ = asin(1/r) mod 2π.
    theta0 = phi + math.pi / 4
    target = math.asin(1 / r)
    dt = (target - theta0) % (2 * math.pi)
    t = t0 + dt
    x_pre = np.array([r * math.sin(dt + phi), r * math.cos(dt + phi)])
    return t, x_pre


# --------------------------------------------------------------------------------------
# Classic impact systems
# --------------------------------------------------------------------------------------


def bouncing_ball() -> Scene:
    r"""A ball bouncing on a rigid floor: x' = v, v' = −g; floor Φ = x, v → −e v.

    `args = {"g": 9.81, "e": 0.8}`. With e < 1 the impact times accumulate (Zeno) at a
    finite time: see `bouncing_ball_impact_times`. The floor is impenetrable.
    """

    def vector_field(t, x, args):
        return jnp.stack([x[1], -args["g"] * jnp.ones_like(x[0])])

    floor = Surface(
        phi=lambda t, x, args: x[0],
        jump=lambda t, x, args: x.at[1].set(-args["e"] * x[1]),
        inverse_jump=lambda t, x, args: x.at[1].set(-x[1] / args["e"]),
        name="floor",
        impenetrable=True,
    )
    return Scene(vector_field, [floor])


def bouncing_ball_impact_times(h0, v0, g, e, n):
    """Exact impact times t_1..t_n and the accumulation time of a ball from (h0, v0) at t=0.

    First impact at t_1 = (v0 + √(v0² + 2 g h0))/g with speed w = √(v0² + 2 g h0); each
    flight then lasts 2 e^k w / g, so t_∞ = t_1 + 2 e w / (g (1 − e)).
    """
    w = math.sqrt(v0 * v0 + 2 * g * h0)
    t = (v0 + w) / g
    times = [t]
    for k in range(1, n):
        t += 2 * e**k * w / g
        times.append(t)
    accumulation = (v0 + w) / g + 2 * e * w / (g * (1 - e)) if e < 1 else math.inf
    return np.array(times), accumulation


def vibrating_table() -> Scene:
    r"""A ball on a sinusoidally vibrating table (the "bouncing ball" map of Holmes 1982).

    Ball x' = v, v' = −g; table height w(t) = A sin(ω t). Gap Φ = x − w(t) (a moving
    surface); impact law v⁺ = w'(t) − e (v − w'(t)), with w' = A ω cos(ω t).
    `args = {"g", "e", "A", "omega"}`. The table is impenetrable. Below the lift-off
    threshold A ω² < g the ball can come to rest on the table (Zeno, then sticking).
    """

    def vector_field(t, x, args):
        return jnp.stack([x[1], -args["g"] * jnp.ones_like(x[0])])

    def table(t, args):
        return args["A"] * jnp.sin(args["omega"] * t)

    def table_velocity(t, args):
        return args["A"] * args["omega"] * jnp.cos(args["omega"] * t)

    def jump(t, x, args):
        w_dot = table_velocity(t, args)
        return x.at[1].set(w_dot - args["e"] * (x[1] - w_dot))

    def inverse(t, x, args):
        w_dot = table_velocity(t, args)
        return x.at[1].set(w_dot - (x[1] - w_dot) / args["e"])

    surface = Surface(
        phi=lambda t, x, args: x[0] - table(t, args),
        jump=jump,
        inverse_jump=inverse,
        name="table",
        impenetrable=True,
    )
    return Scene(vector_field, [surface])


def _rigid_stop() -> Surface:
    """The impact oscillators' stop at x = σ (Φ = σ − x), Newton's law v → −r v."""
    return Surface(
        phi=lambda t, x, args: args["sigma"] - x[0],
        jump=lambda t, x, args: x.at[1].set(-args["r"] * x[1]),
        inverse_jump=lambda t, x, args: x.at[1].set(-x[1] / args["r"]),
        name="stop",
        impenetrable=True,
    )


def impact_oscillator() -> Scene:
    r"""Forced linear oscillator with a rigid stop (Shaw & Holmes 1983; Nordmark 1991).

    x' = v, v' = −2ζ v − x + A cos(ω t); stop at x = σ (Φ = σ − x, free side x < σ);
    impact law v → −r v. `args = {"zeta", "A", "omega", "sigma", "r"}`. Non-autonomous.
    Grazing bifurcations happen when the non-impacting periodic response just touches the
    stop, i.e. its amplitude equals σ.
    """

    def vector_field(t, x, args):
        return jnp.stack(
            [x[1], -2 * args["zeta"] * x[1] - x[0] + args["A"] * jnp.cos(args["omega"] * t)]
        )

    return Scene(vector_field, [_rigid_stop()])


def impact_oscillator_args(zeta=0.05, A=1.0, omega=1.5, sigma=0.2, r=0.8) -> dict:
    values = dict(zeta=zeta, A=A, omega=omega, sigma=sigma, r=r)
    return {k: jnp.asarray(v, float) for k, v in values.items()}


def fourier_impact_oscillator() -> Scene:
    r"""The impact oscillator forced by a Fourier series: a many-parameter scene.

    x' = v, v' = −2ζ v − x + F(t), F(t) = Σ_{k=1}^{M} a_k cos(k ω t) + b_k sin(k ω t);
    stop at x = σ (Φ = σ − x), impact law v → −r v. `args = {"zeta", "omega", "sigma",
    "r", "a", "b"}` with `a`, `b` arrays of M coefficients (see
    `fourier_impact_oscillator_args`): 2M forcing parameters, the case for `jax.grad`
    (`adjoint=diffrax.RecursiveCheckpointAdjoint()`). With `a = (A, 0, …)`, `b = 0` it is
    `impact_oscillator()`.
    """

    def vector_field(t, x, args):
        k = jnp.arange(1, args["a"].shape[0] + 1, dtype=x.dtype)
        phase = k * args["omega"] * t
        force = jnp.sum(args["a"] * jnp.cos(phase) + args["b"] * jnp.sin(phase))
        return jnp.stack([x[1], -2 * args["zeta"] * x[1] - x[0] + force])

    return Scene(vector_field, [_rigid_stop()])


def fourier_impact_oscillator_args(a, b=None, zeta=0.05, omega=1.5, sigma=0.2, r=0.8) -> dict:
    """Arguments of `fourier_impact_oscillator`: cosine coefficients `a` and sine
    coefficients `b` (zeros like `a` by default)."""
    a = jnp.asarray(a, float)
    b = jnp.zeros_like(a) if b is None else jnp.asarray(b, float)
    if a.shape != b.shape or a.ndim != 1:
        raise ValueError(f"a and b must be vectors of one length, got {a.shape} and {b.shape}")
    values = dict(zeta=zeta, omega=omega, sigma=sigma, r=r)
    return {**{k: jnp.asarray(v, float) for k, v in values.items()}, "a": a, "b": b}


def linear_response(t, args):
    """Steady non-impacting response of the impact oscillator (closed form).

    x_p(t) = a cos(ω t) + b sin(ω t) with a = A (1 − ω²)/D, b = 2ζω A/D,
    D = (1 − ω²)² + (2ζω)².
    """
    A, w, z = float(args["A"]), float(args["omega"]), float(args["zeta"])
    D = (1 - w * w) ** 2 + (2 * z * w) ** 2
    a, b = A * (1 - w * w) / D, 2 * z * w * A / D
    x = a * np.cos(w * t) + b * np.sin(w * t)
    v = -a * w * np.sin(w * t) + b * w * np.cos(w * t)
    return np.stack([x, v], axis=-1)


PAPER_SCENES = {
    "ex1dof": (ex1dof, ex1dof_args),
    "orbex2": (orbex2, orbex2_args),
    "smalldisc": (smalldisc, smalldisc_args),
    "exnonaxial": (exnonaxial, exnonaxial_args),
}


# --------------------------------------------------------------------------------------
# Piecewise-smooth systems (docs/piecewise.md): modes, switching surfaces, sliding
# --------------------------------------------------------------------------------------


def rocking_block() -> PiecewiseScene:
    r"""A rigid block rocking on a rigid floor, linearised (Housner 1963; Hogan 1989).

    θ'' = p² (θ − α) while it pivots on its right corner (θ > 0, mode `"right"`),
    θ'' = p² (θ + α) on its left corner (θ < 0, mode `"left"`), i.e.
    θ'' = p² (θ − α sign θ). At θ = 0 the pivot changes and the angular velocity is
    multiplied by the restitution e: each crossing of θ = 0 is a `Transition` with a jump
    (a guard Φ = θ in `"right"`, Φ = −θ in `"left"`). State (θ, θ', mode);
    `args = {"p", "alpha", "e"}`. Closed form: `rocking_block_impact_times`.
    """

    def pivot(side):
        return lambda t, x, args: jnp.stack([x[1], args["p"] ** 2 * (x[0] - side * args["alpha"])])

    restitution = lambda t, x, args: x.at[1].set(args["e"] * x[1])  # noqa: E731
    return PiecewiseScene(
        [Mode("right", pivot(1.0)), Mode("left", pivot(-1.0))],
        transitions=[
            Transition("right", "left", lambda t, x, args: x[0], restitution, name="impact"),
            Transition("left", "right", lambda t, x, args: -x[0], restitution, name="impact"),
        ],
    )


def rocking_block_impact_times(theta0, p, alpha, e, n):
    """Exact impact times of `rocking_block` released at rest from 0 < θ0 < α at t = 0.

    The first fall takes t1 = acosh(α/(α − θ0))/p and arrives with |θ'| = w1 =
    p (α − θ0) sinh(p t1). Each rock after an impact with speed w lasts (2/p)·atanh(w/(pα))
    (from α (cosh pτ − 1) = (w/p) sinh pτ), and the speeds shrink by e per impact.
    """
    t = math.acosh(alpha / (alpha - theta0)) / p
    w = p * (alpha - theta0) * math.sinh(p * t)
    times = [t]
    for _ in range(1, n):
        w *= e
        t += 2 / p * math.atanh(w / (p * alpha))
        times.append(t)
    return np.array(times)


def friction_oscillator() -> PiecewiseScene:
    r"""The Coulomb friction oscillator x'' + x = −μ sign(x') (Den Hartog 1930).

    Modes `"forward"` (x' > 0: x'' = −x − μ) and `"backward"` (x' < 0: x'' = −x + μ), on
    the switching surface Σ = {x' = 0}, with Filippov sliding mode `"stick"`: both sides
    push into Σ where |x| < μ, and there the Filippov field is (0, 0): the mass sticks.
    `args = {"mu": μ}`. State (x, x', mode). Closed form: `friction_oscillator_turns`.
    """

    def friction(sign):
        return lambda t, x, args: jnp.stack([x[1], -x[0] - sign * args["mu"]])

    return PiecewiseScene(
        [Mode("forward", friction(1.0)), Mode("backward", friction(-1.0))],
        switching=[SwitchingSurface(lambda t, x, args: x[1], minus="backward", plus="forward",
                                    sliding="stick", name="x' = 0")],
    )


def friction_oscillator_turns(x0, mu):
    """Turning times and points of `friction_oscillator` released at rest from x0 at t = 0.

    Each half cycle is a harmonic oscillation about ±μ lasting π, so the k-th turn is at
    t = kπ with x_k = −sign(x_{k−1}) (|x_{k−1}| − 2μ); the mass sticks at the first turn
    with |x_k| ≤ μ and stays there. Returns `(times, points)`; the last pair is the stick.
    """
    times, points, x = [], [], float(x0)
    k = 0
    while abs(x) > mu:
        x = -math.copysign(abs(x) - 2 * mu, x)
        k += 1
        times.append(k * math.pi)
        points.append(x)
    return np.array(times), np.array(points)


def belt_stick_slip() -> PiecewiseScene:
    r"""A mass on a spring dragged by a belt, with static and dynamic friction
    (stick–slip; cf. COCO's `stickslip` demo, and Leine et al. 1998).

    x'' + x = μ_d sign(v_b − x') while slipping, with belt speed v_b > 0. Modes:
    `"slow"` (x' < v_b: x'' = −x + μ_d), `"fast"` (x' > v_b: x'' = −x − μ_d) and
    `"stick"` (x' = v_b: the mass rides the belt, (x, x')' = (v_b, 0)). Sticking holds
    while the spring force is within static friction, |x| ≤ μ_s; at x = μ_s the mass
    slips back (`"slow"`). A slipping mass reaching v_b sticks if |x| < μ_s, else it
    slips on. `args = {"v_b", "mu_s", "mu_d"}`, 0 < μ_d < μ_s. Closed form of the
    stick–slip cycle: `belt_stick_slip_cycle`.
    """

    def slip(sign):
        return lambda t, x, args: jnp.stack([x[1], -x[0] + sign * args["mu_d"]])

    def ride(t, x, args):
        return jnp.stack([args["v_b"] * jnp.ones_like(x[0]), jnp.zeros_like(x[1])])

    holds = lambda t, x, args: jnp.abs(x[0]) < args["mu_s"]  # noqa: E731
    return PiecewiseScene(
        [Mode("slow", slip(1.0)), Mode("fast", slip(-1.0)), Mode("stick", ride)],
        transitions=[
            Transition("stick", "slow", lambda t, x, args: args["mu_s"] - x[0], name="slip"),
            Transition("stick", "fast", lambda t, x, args: args["mu_s"] + x[0], name="slip"),
            Transition("slow", [(holds, "stick"), (None, "fast")],
                       lambda t, x, args: args["v_b"] - x[1], name="reach belt speed"),
            Transition("fast", [(holds, "stick"), (None, "slow")],
                       lambda t, x, args: x[1] - args["v_b"], name="reach belt speed"),
        ],
    )


def belt_stick_slip_cycle(v_b, mu_s, mu_d):
    """The stick–slip cycle of `belt_stick_slip` (closed form).

    Sticking starts at x = 2μ_d − μ_s (with x' = v_b) and lasts 2(μ_s − μ_d)/v_b, up to
    x = μ_s; the slip is an arc of the circle of radius √((μ_s − μ_d)² + v_b²) about
    (μ_d, 0), lasting π + 2 atan2(v_b, μ_s − μ_d), back to x' = v_b at x = 2μ_d − μ_s.
    Returns `(x_stick, stick_duration, slip_duration)`.
    """
    return 2 * mu_d - mu_s, 2 * (mu_s - mu_d) / v_b, math.pi + 2 * math.atan2(v_b, mu_s - mu_d)


def relay_feedback() -> PiecewiseScene:
    r"""Relay feedback x' = A x + b sign(cᵀx) (Johansson, Rantzer & Åström 1999).

    Modes `"plus"` (cᵀx > 0: A x + b) and `"minus"` (A x − b) on Σ = {cᵀx = 0}, with
    Filippov sliding mode `"sliding"`. `args = {"A": (n, n), "b": (n,), "c": (n,)}`.
    With A = [[0, 1], [−1, −2ζ]], b = (0, μ), c = (0, 1) (`relay_feedback_args`), it is a
    damped oscillator pumped by the relay (x'' + 2ζ x' + x = μ sign x'), with a
    symmetric limit cycle x(t + T/2) = −x(t).
    """

    def side(sign):
        return lambda t, x, args: args["A"] @ x + sign * args["b"]

    return PiecewiseScene(
        [Mode("plus", side(1.0)), Mode("minus", side(-1.0))],
        switching=[SwitchingSurface(lambda t, x, args: args["c"] @ x, minus="minus",
                                    plus="plus", sliding="sliding", name="cᵀx = 0")],
    )


def relay_feedback_args(zeta=0.1, mu=1.0) -> dict:
    return {"A": jnp.array([[0.0, 1.0], [-1.0, -2 * zeta]]), "b": jnp.array([0.0, mu]),
            "c": jnp.array([0.0, 1.0])}
