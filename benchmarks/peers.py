"""Reference ("peer") impact simulators used by the benchmarks.

Two independent implementations of the same hybrid-system semantics as
grazejax, built on mature CPU integrators:

* SciPy ``solve_ivp`` (DOP853 by default) with terminal events and a manual
  restart loop;
* heyoka (Taylor method, events located as polynomial roots of the Taylor
  expansion), with the jump applied inside the terminal-event callback.

Event semantics (shared with grazejax)
--------------------------------------
The free side is ``Phi > 0``.  An impact happens when ``Phi`` crosses zero
while DECREASING, at a point where the system's ``where`` predicate holds;
the state then jumps ``x -> J(x)``.  Upward crossings (and downward crossings
where ``where`` is false) pass through unchanged.

Restart guard ("arming")
------------------------
After a jump the state sits on the surface, so a naive restart re-detects a
root at its own start time.  Worse, some jumps (ex1dof for large |x2|) leave
the state on the surface still moving INTO the wall: the flight then dips into
``Phi < 0`` and comes back up, and the downward root at the start is not an
impact.  Neither a fixed time guard nor a "tiny first step" is exact: the dip
can be arbitrarily short (``~2|x2+|`` for ex1dof near ``x2+ = 0``), and
heyoka's automatic cooldown (~1e-14 here) is deduced at the trigger, i.e. from
the PRE-jump flow, so it can be too short when the post-jump ``dPhi/dt`` is
small (the spurious root sits at ``-residual / (dPhi/dt)``).

Both peers therefore use the same exact rule: a flight that starts on/inside
the surface with ``dPhi/dt < 0`` is *disarmed*; it cannot produce an impact
until ``dPhi/dt`` has crossed zero upwards (any genuine later downward
crossing of Phi = 0 must be preceded by Phi rising again, hence by such a
crossing).  Arming on ``dPhi/dt`` rather than on the upward crossing of Phi
also survives dips so shallow that, in floating point, Phi never goes
negative.  Flights starting with ``dPhi/dt >= 0`` (or strictly in the free
side) are armed immediately.

Public API (plain numpy in / out)
---------------------------------
``scipy_impacts(system, x0, t0, t1, *, method, rtol, atol, max_impacts, **params)``
``heyoka_impacts(system, x0, t0, t1, *, tol, max_impacts, **params)``
``ScipyImpactRunner(system, method, rtol, atol, **params).run(x0, t0, t1, max_impacts, **params)``
``HeyokaImpactRunner(system, tol, **params).run(x0, t0, t1, max_impacts, **params)``

All return ``dict(t_final, x_final, impact_times (k,), impact_pre (k, n),
impact_post (k, n), nfev)``.  ``t_final``/``x_final`` are the time and
post-jump state of the last impact when ``max_impacts`` is reached, otherwise
``t1`` and the state there.  For heyoka ``nfev`` is the number of Taylor steps
(one Taylor-jet evaluation each), so it is not comparable with SciPy's count.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from types import SimpleNamespace

import numpy as np

__all__ = [
    "SYSTEMS",
    "ImpactSystem",
    "ScipyImpactRunner",
    "HeyokaImpactRunner",
    "scipy_impacts",
    "heyoka_impacts",
]

SQRT2 = math.sqrt(2.0)

# Each system's flow and surface are written once, against a tiny "lib"
# namespace, so the SAME expression is evaluated with floats (SciPy) and
# traced into heyoka expressions (heyoka).  Only the functions listed here may
# be used inside rhs / phi / phidot.
_FLOAT_LIB = SimpleNamespace(cos=math.cos)


@dataclass(frozen=True)
class ImpactSystem:
    """One impacting system.

    ``rhs``, ``phi`` and ``phidot`` take ``(t, x, p, lib)``; ``phidot`` is the
    time derivative of ``phi`` along the flow (used for arming, see module
    docstring).  ``where`` and ``jump`` take ``(t, x, p)`` with floats/numpy
    only: they run in Python in both peers.  ``flow_params`` are the parameters
    that appear in rhs/phi/phidot; in heyoka they become runtime parameters
    ``par[i]`` in that order, so changing them never recompiles.  ``defaults``
    lists every parameter; ``None`` means "must be given".
    """

    name: str
    n: int
    rhs: Callable
    phi: Callable
    phidot: Callable
    where: Callable
    jump: Callable
    flow_params: tuple
    defaults: dict = field(default_factory=dict)

    def check_names(self, params: dict) -> None:
        unknown = set(params) - set(self.defaults)
        if unknown:
            raise TypeError(f"{self.name}: unknown parameter(s) {sorted(unknown)}")

    def params(self, base: dict | None = None, overrides: dict | None = None) -> dict:
        p = dict(self.defaults)
        for src in (base, overrides):
            if src:
                self.check_names(src)
                p.update(src)
        missing = [k for k, v in p.items() if v is None]
        if missing:
            raise TypeError(f"{self.name}: missing parameter(s) {missing}")
        return {k: float(v) for k, v in p.items()}


def _always(t, x, p):
    return True


# --- ex1dof -----------------------------------------------------------------
def _ex1dof_rhs(t, x, p, lib):
    x1, x2 = x[0], x[1]
    return [
        x2,
        -p["eps"] * (x2 * x2 + (x1 - 1.0) * (x1 - 1.0) - (1.0 + p["mu"]) * (1.0 + p["mu"])) * x2
        - x1
        + 1.0,
    ]


def _ex1dof_jump(t, x, p):
    x1, x2 = x[0], x[1]
    mu = p["mu"]
    return np.array([x1, x2 - (1.0 + p["R"] * x2 + mu * x2**3) * x2 + mu * mu])


EX1DOF = ImpactSystem(
    name="ex1dof",
    n=2,
    rhs=_ex1dof_rhs,
    phi=lambda t, x, p, lib: x[0],
    phidot=lambda t, x, p, lib: x[1],
    where=lambda t, x, p: x[1] <= 0.0,
    jump=_ex1dof_jump,
    flow_params=("mu", "eps"),
    defaults={"mu": None, "eps": 1e-4, "R": 0.9},
)

# --- bouncing ball ----------------------------------------------------------
BALL = ImpactSystem(
    name="ball",
    n=2,
    rhs=lambda t, x, p, lib: [x[1], -p["g"]],
    phi=lambda t, x, p, lib: x[0],
    phidot=lambda t, x, p, lib: x[1],
    where=_always,
    jump=lambda t, x, p: np.array([x[0], -p["e"] * x[1]]),
    flow_params=("g",),
    defaults={"g": 9.81, "e": 0.8},
)

# --- forced linear impact oscillator with a rigid stop at x = sigma ---------
OSCILLATOR = ImpactSystem(
    name="oscillator",
    n=2,
    # Non-autonomous: t is heyoka's ``hy.time`` on the heyoka side.
    rhs=lambda t, x, p, lib: [
        x[1],
        -2.0 * p["zeta"] * x[1] - x[0] + p["A"] * lib.cos(p["w"] * t),
    ],
    phi=lambda t, x, p, lib: p["sigma"] - x[0],
    phidot=lambda t, x, p, lib: -x[1],
    where=_always,
    jump=lambda t, x, p: np.array([x[0], -p["r"] * x[1]]),
    flow_params=("zeta", "A", "w", "sigma"),
    defaults={"zeta": None, "A": None, "w": None, "sigma": None, "r": None},
)


# --- exnonaxial -------------------------------------------------------------
def _exnonaxial_jump(t, x, p):
    c = 1.0 / SQRT2 + p["K"] * (x[1] - x[0]) ** 2
    # NOTE: lands at Phi = -2 K (x2-x1)^2 <= 0, i.e. slightly INSIDE the wall,
    # with dPhi/dt = 0; the flight then rises through Phi = 0 (pass-through).
    return np.array([c, c])


EXNONAXIAL = ImpactSystem(
    name="exnonaxial",
    n=2,
    rhs=lambda t, x, p, lib: [x[1], -x[0]],
    phi=lambda t, x, p, lib: SQRT2 - x[0] - x[1],
    phidot=lambda t, x, p, lib: x[0] - x[1],
    where=_always,
    jump=_exnonaxial_jump,
    flow_params=(),
    defaults={"K": 0.11},
)

SYSTEMS = {s.name: s for s in (EX1DOF, BALL, OSCILLATOR, EXNONAXIAL)}
# Convenience aliases.
SYSTEMS["bouncing_ball"] = BALL
SYSTEMS["impact_oscillator"] = OSCILLATOR


def _get_system(system) -> ImpactSystem:
    if isinstance(system, ImpactSystem):
        return system
    try:
        return SYSTEMS[system]
    except KeyError:
        raise ValueError(f"unknown system {system!r}; known: {sorted(SYSTEMS)}") from None


def _armed_at_start(sysm, t, x, p, after_event):
    """Whether a flight starting at (t, x) may register an impact right away.

    After an event the state is on the surface by construction (its Phi is
    only a root-finding residual), so only the sign of dPhi/dt matters.  For a
    user initial condition, a state strictly in the free side is armed even
    if it moves toward the wall (a genuine impact may come first).
    """
    into_wall = sysm.phidot(t, x, p, _FLOAT_LIB) < 0.0
    if after_event:
        return not into_wall
    return not (into_wall and sysm.phi(t, x, p, _FLOAT_LIB) <= 0.0)


def _result(t, x, times, pre, post, nfev, n):
    return dict(
        t_final=float(t),
        x_final=np.array(x, dtype=float),
        impact_times=np.array(times, dtype=float),
        impact_pre=np.array(pre, dtype=float).reshape(-1, n),
        impact_post=np.array(post, dtype=float).reshape(-1, n),
        nfev=int(nfev),
    )


# =============================================================================
# SciPy peer
# =============================================================================
class ScipyImpactRunner:
    """solve_ivp with a manual restart loop; re-runnable with new x0/params.

    Each flight is one solve_ivp call with a single terminal event:
    ``Phi`` (direction -1) while armed, ``dPhi/dt`` (direction +1) while
    disarmed.  The disarmed phase ends exactly where the flow turns back
    toward the free side, so no time-window guard or "tiny step" is needed
    (solve_ivp would otherwise report the start-time root of ``Phi`` as a
    downward crossing, because its detector treats ``g == 0`` at the step
    start followed by ``g < 0`` as a crossing).

    Caveat: solve_ivp only looks for sign changes of ``Phi`` between step
    endpoints, so a near-grazing impact whose dip below the surface fits
    inside one step is silently missed (heyoka, which root-finds on the
    Taylor polynomial, catches it).  ``max_step`` bounds the step to reduce
    this risk when grazing matters.
    """

    def __init__(
        self, system, method="DOP853", rtol=1e-10, atol=1e-10, *, max_step=np.inf, **params
    ):
        self.system = _get_system(system)
        self.method = method
        self.rtol = rtol
        self.atol = atol
        self.max_step = max_step
        self._base_params = params
        self.system.check_names(params)  # missing values may still come with run()

    def run(self, x0, t0, t1, max_impacts=10**9, **params):
        # Imported here: SciPy is an optional peer (the `bench` extra); the suite runs
        # without it (benchmarks/_cases.py: HAVE_SCIPY).
        from scipy.integrate import solve_ivp

        sysm = self.system
        p = sysm.params(self._base_params, params)
        lib = _FLOAT_LIB
        rhs, phi, phidot = sysm.rhs, sysm.phi, sysm.phidot

        def fun(t, y):
            return rhs(t, y, p, lib)

        def ev_impact(t, y):
            return phi(t, y, p, lib)

        ev_impact.terminal = True
        ev_impact.direction = -1

        def ev_arm(t, y):
            return phidot(t, y, p, lib)

        ev_arm.terminal = True
        ev_arm.direction = 1

        t, t1 = float(t0), float(t1)
        x = np.array(x0, dtype=float)
        armed = _armed_at_start(sysm, t, x, p, after_event=False)
        times, pre, post = [], [], []
        nfev = 0
        while t < t1:
            sol = solve_ivp(
                fun,
                (t, t1),
                x,
                method=self.method,
                rtol=self.rtol,
                atol=self.atol,
                max_step=self.max_step,
                events=ev_impact if armed else ev_arm,
            )
            nfev += sol.nfev
            if sol.status == -1:
                raise RuntimeError(f"solve_ivp failed at t={t}: {sol.message}")
            if sol.status == 0:  # reached t1 without a terminal event
                t, x = float(sol.t[-1]), sol.y[:, -1].copy()
                break
            t = float(sol.t_events[0][-1])
            x = sol.y_events[0][-1].copy()
            if not armed:
                armed = True
                continue
            if sysm.where(t, x, p):
                times.append(t)
                pre.append(x)
                x = np.asarray(sysm.jump(t, x, p), dtype=float)
                post.append(x)
                if len(times) >= max_impacts:
                    break
            # A pass-through (where false) also leaves us on the surface
            # moving inward: same guard as after a jump.
            armed = _armed_at_start(sysm, t, x, p, after_event=True)
        return _result(t, x, times, pre, post, nfev, sysm.n)


def scipy_impacts(
    system,
    x0,
    t0,
    t1,
    *,
    method="DOP853",
    rtol=1e-10,
    atol=1e-10,
    max_impacts=10**9,
    max_step=np.inf,
    **params,
):
    runner = ScipyImpactRunner(system, method, rtol, atol, max_step=max_step, **params)
    return runner.run(x0, t0, t1, max_impacts)


# =============================================================================
# heyoka peer
# =============================================================================
class _SharedCallback:
    """Base for callbacks that must stay attached to their runner.

    heyoka deep-copies event callbacks when events and integrators are built;
    returning ``self`` keeps the runner's bookkeeping shared.
    """

    def __init__(self, runner):
        self.runner = runner

    def __deepcopy__(self, memo):
        return self


class _ImpactCallback(_SharedCallback):
    # Terminal event on Phi (direction negative).  heyoka has already
    # propagated the integrator to the trigger time.  Returning True resumes
    # propagate_until; False stops it (max_impacts reached).
    def __call__(self, ta, d_sgn):
        r = self.runner
        if not r.armed:
            # Spurious root right after an into-the-wall jump (beyond the
            # automatic cooldown); ignore it.
            return True
        t = ta.time
        x = ta.state.copy()
        p = r.p
        sysm = r.system
        if sysm.where(t, x, p):
            xp = np.asarray(sysm.jump(t, x, p), dtype=x.dtype)
            ta.state[:] = xp
            r.times.append(t)
            r.pre.append(x)
            r.post.append(xp)
            x = xp
        r.armed = _armed_at_start(sysm, t, x, p, after_event=True)
        return len(r.times) < r.max_impacts


class _ArmCallback(_SharedCallback):
    # Non-terminal event on dPhi/dt (direction positive).  heyoka runs the
    # non-terminal callbacks that precede a terminal event in the same step
    # before the terminal callback, so arming is seen in time.
    def __call__(self, ta, time, d_sgn):
        self.runner.armed = True


class HeyokaImpactRunner:
    """heyoka integrator compiled once; ``run`` re-uses it.

    Flow/surface parameters are heyoka runtime parameters (``par[i]`` in
    ``system.flow_params`` order) and jump parameters are plain Python
    floats, so ``run(..., mu=0.3)`` never recompiles.
    """

    def __init__(self, system, tol=1e-15, *, fp_type=float, **params):
        """``fp_type=numpy.longdouble`` builds an extended-precision integrator
        (x86-64: 80-bit), e.g. for reference solutions; the jumps are then
        evaluated in that precision too, and results are returned as float64.
        """
        import heyoka as hy

        self.system = sysm = _get_system(system)
        self.tol = tol
        self._base_params = params
        self.system.check_names(params)

        xs = hy.make_vars(*[f"x{i}" for i in range(sysm.n)])
        xs = list(xs) if sysm.n > 1 else [xs]
        ppar = {name: hy.par[i] for i, name in enumerate(sysm.flow_params)}
        lib = SimpleNamespace(cos=hy.cos)
        rhs = sysm.rhs(hy.time, xs, ppar, lib)
        phi = sysm.phi(hy.time, xs, ppar, lib)
        phidot = sysm.phidot(hy.time, xs, ppar, lib)
        # taylor_adaptive wants expressions; a system could return a plain
        # float for a constant component.
        rhs = [e if isinstance(e, hy.expression) else hy.expression(e) for e in rhs]

        self.armed = True
        self.p = {}
        self.times, self.pre, self.post = [], [], []
        self.max_impacts = 0

        # Default (automatic) cooldown: it only has to suppress the root at
        # the trigger time itself; later spurious roots are handled by the
        # arming logic, not by widening the cooldown (which could hide real
        # impacts).
        t_ev = hy.t_event(
            phi,
            callback=_ImpactCallback(self),
            direction=hy.event_direction.negative,
            fp_type=fp_type,
        )
        nt_ev = hy.nt_event(
            phidot, _ArmCallback(self), direction=hy.event_direction.positive, fp_type=fp_type
        )
        self.fp_type = fp_type
        self.ta = hy.taylor_adaptive(
            list(zip(xs, rhs, strict=True)),
            [fp_type(0.0)] * sysm.n,
            tol=fp_type(tol),
            fp_type=fp_type,
            pars=[fp_type(0.0)] * len(sysm.flow_params),
            t_events=[t_ev],
            nt_events=[nt_ev],
        )
        self._hy = hy

    def run(self, x0, t0, t1, max_impacts=10**9, **params):
        sysm = self.system
        ta = self.ta
        p = sysm.params(self._base_params, params)
        if sysm.flow_params:
            ta.pars[:] = [p[k] for k in sysm.flow_params]
        x0 = np.array(x0, dtype=float)
        ta.time = self.fp_type(t0)
        ta.state[:] = x0
        # Cooldowns survive manual state/time changes; clear them so a fresh
        # run cannot inherit a suppression window from the previous one.
        ta.reset_cooldowns()
        self.p = p
        self.times, self.pre, self.post = [], [], []
        self.max_impacts = max_impacts
        self.armed = _armed_at_start(sysm, float(t0), x0, p, after_event=False)
        nsteps = 0
        if max_impacts > 0 and t1 > t0:
            res = ta.propagate_until(self.fp_type(t1))
            oc, nsteps = res[0], res[3]
            hy = self._hy
            # time_limit: reached t1; -1: our callback asked to stop.
            if oc != hy.taylor_outcome.time_limit and int(oc) != -1:
                raise RuntimeError(f"heyoka propagation failed: {oc} at t={ta.time}")
        return _result(ta.time, ta.state, self.times, self.pre, self.post, nsteps, sysm.n)


@cache
def _cached_heyoka_runner(system_name, tol):
    return HeyokaImpactRunner(system_name, tol)


def heyoka_impacts(system, x0, t0, t1, *, tol=1e-15, max_impacts=10**9, **params):
    """One-shot heyoka run; the compiled integrator is cached per (system, tol)."""
    sysm = _get_system(system)
    if SYSTEMS.get(sysm.name) is sysm:
        runner = _cached_heyoka_runner(sysm.name, float(tol))
    else:  # a user-built ImpactSystem: not cacheable by name
        runner = HeyokaImpactRunner(sysm, tol)
    return runner.run(x0, t0, t1, max_impacts, **params)


# =============================================================================
# heyoka, batch (SIMD) mode: the fastest heyoka configuration for sweeps
# =============================================================================
class HeyokaBatchRunner:
    """heyoka's batch integrator (``taylor_adaptive_batch``): ``simd`` lanes per SIMD
    vector (``heyoka.recommended_simd_size()``: 8 with AVX-512, 4 with AVX2), one terminal
    event on ``Phi`` (direction negative) without a callback, the jumps applied with NumPy
    between ``propagate_until`` calls.

    Measured on ex1dof (``benchmarks/bench_throughput.py``) this is heyoka's fastest
    single-core configuration for many starts: ~2.5x the scalar integrator with the jump in
    a callback (``HeyokaImpactRunner``), and faster than batch mode with the jump in a
    Python callback (a callback per event costs more than a NumPy update per flight).

    Limitation (checked, never silent): the restart guard is heyoka's automatic cooldown
    only. A jump that leaves a lane moving into the wall (``dPhi/dt < 0`` after the jump:
    the "disarmed" flights of ``HeyokaImpactRunner``) raises ``ValueError``: use the scalar
    runner for such systems.
    """

    def __init__(self, system, tol=1e-15, *, callback=False, **params):
        """``callback=True`` applies each jump in an event callback instead (the
        propagation then goes on for the other lanes; with ``False`` a terminal event in
        one lane stops the whole batch, which costs most on lanes out of phase)."""
        import heyoka as hy

        self.system = sysm = _get_system(system)
        self._base_params = params
        sysm.check_names(params)
        self.simd = hy.recommended_simd_size()
        self.callback = _BatchJumpCallback(self) if callback else None
        xs = hy.make_vars(*[f"x{i}" for i in range(sysm.n)])
        xs = list(xs) if sysm.n > 1 else [xs]
        ppar = {name: hy.par[i] for i, name in enumerate(sysm.flow_params)}
        lib = SimpleNamespace(cos=hy.cos)
        rhs = sysm.rhs(hy.time, xs, ppar, lib)
        rhs = [e if isinstance(e, hy.expression) else hy.expression(e) for e in rhs]
        phi = sysm.phi(hy.time, xs, ppar, lib)
        event = hy.t_event_batch(
            phi, direction=hy.event_direction.negative, callback=self.callback
        )
        self.ta = hy.taylor_adaptive_batch(
            list(zip(xs, rhs, strict=True)), np.zeros((sysm.n, self.simd)), tol=tol,
            pars=np.zeros((len(sysm.flow_params), self.simd)), t_events=[event],
        )

    def run(self, x0s, t0, t1, max_impacts, **params):
        """Impact times of every lane: ``(lanes, max_impacts)``, NaN where a lane made fewer
        impacts before ``t1``; and the lanes' final states ``(lanes, n)``."""
        sysm, ta, simd = self.system, self.ta, self.simd
        p = sysm.params(self._base_params, params)
        x0s = np.asarray(x0s, dtype=float)
        lanes = x0s.shape[0]
        padded = -(-lanes // simd) * simd
        x0s = np.concatenate([x0s, np.repeat(x0s[-1:], padded - lanes, axis=0)])
        times = np.full((padded, max_impacts), np.nan)
        finals = np.empty((padded, sysm.n))
        if sysm.flow_params:
            ta.pars[:] = np.array([[p[k]] * simd for k in sysm.flow_params])
        self.core_seconds = 0.0  # time inside propagate_until: heyoka without this driver
        for b in range(0, padded, simd):
            self._run_batch(x0s[b:b + simd], t0, t1, max_impacts, p, times[b:b + simd])
            finals[b:b + simd] = ta.state.T
        return times[:lanes], finals[:lanes]

    def _run_batch(self, x0, t0, t1, max_impacts, p, times):
        sysm, ta, simd = self.system, self.ta, self.simd
        ta.set_time(np.full(simd, float(t0)))
        ta.state[:] = x0.T
        ta.reset_cooldowns()
        count = np.zeros(simd, dtype=int)
        target = np.full(simd, float(t1))
        if self.callback is not None:
            self.callback.arm(p, times, count, max_impacts)
            while True:
                start = time.process_time()
                ta.propagate_until(target)
                self.core_seconds += time.process_time() - start
                done = count == max_impacts
                target[done] = ta.time[done]  # frozen where its last impact left it
                if np.all(ta.time >= target):
                    return
        while True:
            start = time.process_time()
            ta.propagate_until(target)
            self.core_seconds += time.process_time() - start
            # A terminal event in one lane stops every lane of the batch: only the lanes whose
            # outcome is the event (-1: event 0) are at an impact.
            hit = np.array([int(r[0]) == -1 for r in ta.propagate_res])
            t = ta.time.copy()
            if not hit.any():
                return  # every lane at t1 or frozen
            # The system's where/jump/phidot are NumPy expressions: one call for the batch.
            x = ta.state.copy()
            impact = hit & np.asarray(sysm.where(t, x, p), bool)
            if not impact.any():
                continue  # downward crossings outside the piece pass through
            post = np.asarray(sysm.jump(t, x, p), dtype=float)
            bad = impact & (np.asarray(sysm.phidot(t, post, p, _FLOAT_LIB)) < 0.0)
            if bad.any():
                raise ValueError(
                    f"{sysm.name}: a jump leaves a lane moving into the wall; "
                    "HeyokaBatchRunner has no restart guard for it (use HeyokaImpactRunner)"
                )
            ta.state[:] = np.where(impact, post, x)
            lanes = np.flatnonzero(impact)
            times[lanes, count[lanes]] = t[lanes]
            count[lanes] += 1
            done = impact & (count == max_impacts)
            target[done] = t[done]  # frozen: propagate_until leaves these lanes where they are


class _BatchJumpCallback(_SharedCallback):
    """Terminal-event callback of ``HeyokaBatchRunner(callback=True)``: applies the jump
    to lane ``i`` alone; returns False (stop) when that lane has made its last impact."""

    def arm(self, p, times, count, max_impacts):
        self.p, self.times, self.count, self.max_impacts = p, times, count, max_impacts

    def __call__(self, ta, d_sgn, i):
        sysm = self.runner.system
        t, x = float(ta.time[i]), ta.state[:, i].copy()
        if not sysm.where(t, x, self.p):
            return True
        post = np.asarray(sysm.jump(t, x, self.p), dtype=float)
        if sysm.phidot(t, post, self.p, _FLOAT_LIB) < 0.0:
            raise ValueError(f"{sysm.name}: a jump leaves a lane moving into the wall")
        ta.state[:, i] = post
        self.times[i, self.count[i]] = t
        self.count[i] += 1
        return bool(self.count[i] < self.max_impacts)
