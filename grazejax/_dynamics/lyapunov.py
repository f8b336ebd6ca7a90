r"""Lyapunov spectra through impacts: Benettin's method with QR re-orthonormalisation
(`grazejax.lyapunov_spectrum`, `grazejax.maximal_lyapunov_exponent`).

The tangent map of a time-τ run is `jax.jacfwd` of `grazejax.simulate` along k directions:
the saltation matrices of the impacts are in it by construction (forward-mode derivatives
through the event times, docs/linearization.md). Each window pushes an orthonormal frame Q
through that map, re-orthonormalises by QR (signs fixed so that diag R > 0), and adds
log R_ii; the exponents are the sums divided by the averaged time (Benettin, Galgani,
Giorgilli & Strelcyn 1980; for impact systems Müller 1995, *Chaos Solitons Fractals* 5).

Near a grazing contact the saltation matrix has a 1/(dΦ/dt) factor (the square-root
singularity of the discontinuity map, Nordmark 1991), so a finite-time estimate can jump
there: such windows are flagged (`grazing_windows`) and the result's status says so.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._compiler import single_run_jit
from .._scene import Scene
from .._simulate import SIMULATE_OPTIONS, _traced_numbers, numeric_options, simulate
from .._status import ImpactKind, Status, StatusCode

# Default number of renormalisation windows when `renormalize` is not given.
DEFAULT_NUM_WINDOWS = 100
# Relative approach speed |dΦ/dt| / (|∂Φ/∂t| + |∇Φ|·|f|) below which an impact counts as
# near-grazing, as a multiple of sqrt(rtol): a trajectory known to rtol (relative) has its
# minimum gap known to about rtol·L, so an impact speed below ~sqrt(2·rtol·L·|Φ̈|), i.e. a
# relative speed below ~sqrt(rtol), cannot be told from a miss or a touch.
GRAZING_SPEED_PER_SQRT_RTOL = 10.0
# A window is too long when the frame's smallest stretch R_kk falls below this fraction of
# its largest R_11: the k-th pushed vector is dominated by the growing directions, and what
# QR leaves of it, orthogonal to them, is a difference of numbers of size ~R_11, so it
# carries a round-off of about eps·R_11. At 1e8·eps that is a relative error of ~1e-8 in
# R_kk (finite-time stretches inside a window vary more than their ratio at its end, so
# the error seen is larger: on Lorenz about 1e-6 per window at a ratio of 1e-7).
STRETCH_RATIO_FLOOR = 1e8 * float(np.finfo(np.float64).eps)


class LyapunovStatus(StatusCode):
    """How a Lyapunov-spectrum run ended (`LyapunovSpectrum.status`)."""

    SUCCESS = 0, "every window reached its end; no grazing contact"
    """Every window (and the transient) reached its end with `Status.SUCCESS`."""
    GRAZING = (
        1,
        "a window held a grazing or near-grazing impact, or a non-finite tangent map: the "
        "finite-time estimate there is not trustworthy (see grazing_windows)",
    )
    """Some window held a grazing contact (`ImpactKind.GAMMA`), an impact slower than the
    near-grazing floor, or a non-finite tangent map (`grazing_windows` says which). The
    saltation matrix grows like 1/(dΦ/dt) there, so the numbers are finite-time
    estimates dominated by one contact."""
    WINDOW_TOO_LONG = (
        2,
        "the frame's stretches differed by more than 1/(1e8·eps) in a window: the smallest "
        "exponents are round-off; renormalize more often",
    )
    """In some window the smallest stretch R_kk fell below 1e8·eps·R_11 (about 2e-8·R_11):
    round-off in the pushed frame (about eps·R_11 in every direction) then spoils the
    smallest exponents. Pass a shorter `renormalize`."""
    MAX_IMPACTS = 3, "a window (or the transient) stopped at max_impacts: raise max_impacts"
    """A window (or the transient) stopped at `max_impacts`, which bounds the impacts of
    *one* window: raise it or shorten `renormalize`. Exponents average the windows before."""
    ZENO = 4, "a window (or the transient) ended in a Zeno accumulation"
    """A window (or the transient) ended with `Status.ZENO`: the exponents average the
    windows before it."""
    SIMULATION_FAILED = 5, "a window's (or the transient's) simulation failed"
    """A window (or the transient) ended with another failing `grazejax.Status`
    (`simulation_status` says which): the exponents average the windows before it."""


class LyapunovSpectrum(eqx.Module):
    r"""Result of `grazejax.lyapunov_spectrum` (and `grazejax.maximal_lyapunov_exponent`).

    **Fields:**

    - `exponents`: the k largest Lyapunov exponents, descending: (1/T) Σ_windows log R_ii
      over the averaged windows (those before a failed one).
    - `history`: the running estimates after each window, shape `(num_windows, k)`, column
      i the running average of log R_ii (column order, unsorted), NaN after a failed window.
    - `num_impacts`: impacts in the averaged windows.
    - `averaging_time`: T, the length of the averaged windows (number × `window_length`).
    - `window_length`: τ, the time between renormalisations.
    - `status`: a `grazejax.LyapunovStatus` code (SUCCESS, GRAZING, WINDOW_TOO_LONG,
      MAX_IMPACTS, ZENO, SIMULATION_FAILED: a failure takes precedence).
    - `simulation_status`: the `grazejax.Status` of the first run that did not reach its
      end (the transient or a window), `Status.SUCCESS` if none.
    - `grazing_windows`: per window, whether it held a grazing or near-grazing impact, or
      a non-finite tangent map.

    With k = n (the state's dimension) the sum identity holds: Σλ_i·T = ∫ div f dt +
    Σ_j log|det S_j| over the averaged windows (Liouville's formula across impacts).
    """

    exponents: Float[Array, " k"]
    history: Float[Array, "num_windows k"]
    num_impacts: Int[Array, ""]
    averaging_time: Float[Array, ""]
    window_length: Float[Array, ""]
    status: Int[Array, ""]
    simulation_status: Int[Array, ""]
    grazing_windows: Bool[Array, " num_windows"]

    @property
    def succeeded(self) -> Bool[Array, ""]:
        return self.status == LyapunovStatus.SUCCESS

    @property
    def message(self) -> str:
        """The status in words (outside `jit`)."""
        status = LyapunovStatus(int(self.status))
        if status in (LyapunovStatus.SUCCESS, LyapunovStatus.GRAZING,
                      LyapunovStatus.WINDOW_TOO_LONG):
            return status.message
        return f"{status.message} ({Status(int(self.simulation_status)).name})"


# --------------------------------------------------------------------------------------
# Public entry points
# --------------------------------------------------------------------------------------


def lyapunov_spectrum(scene: Scene, x0, t0, t1, args=None, *, k: int | None = None,
                      transient=0.0, renormalize=None, grazing_speed: float | None = None,
                      **simulate_options) -> LyapunovSpectrum:
    r"""The k largest Lyapunov exponents of a trajectory through impacts (Benettin + QR).

    The state runs from `t0` to `t0 + transient` (state only), then through windows of
    length τ = `renormalize` up to `t1`. In each window a frame Q of k orthonormal
    tangent vectors is pushed through the window's tangent map — `jax.jacfwd` of
    `grazejax.simulate`, which contains the saltation matrix of every impact — and
    re-orthonormalised, M = QR with diag R > 0; the exponents are
    λ_i = (1/T) Σ_windows log R_ii over the averaged time T. The whole run is one compiled
    program (a `lax.scan` over windows), compiled once per scene, k, number of windows and
    options, and it works under `jax.vmap` over `x0` and `args`.

    **Arguments:**

    - `scene`: a `grazejax.Scene`.
    - `x0`: the initial state, shape `(n,)`.
    - `t0`, `t1`: start and end times, Python or NumPy numbers (they fix the number of
      windows, part of the program); forward time only (`t1 > t0 + transient`, else a
      `ValueError`).
    - `args`: the scene's parameters (batched under `jax.vmap` as in `simulate`).
    - `k`: how many exponents (default n, the whole spectrum). The start frame is a
      fixed generic orthonormal frame (QR of a seeded Gaussian matrix), so that no
      exponent is missed because the frame lies in an invariant subspace.
    - `transient`: time run before the averaging starts (state only).
    - `renormalize`: τ, the window length. Windows of exactly τ fill [t0 + transient, t1]
      as far as they fit (the end remainder, below τ, is dropped: `averaging_time` says
      how much was averaged); a forced system's period makes the windows stroboscopic.
      Default: (t1 − t0 − transient)/100. Choose τ so that the frame's stretches stay
      within a factor 1/(1e8·eps) ≈ 5e7 of each other ((λ_1 − λ_k)·τ ≲ 17), and so that
      `max_impacts` bounds one window's impacts; a window that breaks either is reported.
    - `grazing_speed`: relative approach speed |dΦ/dt| / (|∂Φ/∂t| + |∇Φ|·|f⁻|) below
      which an impact flags its window as near-grazing (default 10·√rtol: below ~√rtol a
      solver at rtol cannot tell an impact from a miss or a touch).
    - `**simulate_options`: passed to every `grazejax.simulate` call (`rtol`, `atol`,
      `solver`, `max_impacts` (per window), `max_steps`, ...).

    **Returns:** a `grazejax.LyapunovSpectrum`. Its `status` is `SUCCESS` only if every
    run reached its end and no window grazed; otherwise the exponents are those of the
    averaged windows, and the status says what is doubtful (a grazing window's contact
    dominates its finite-time estimate; a failed run ends the averaging).

    **Example:**

    ```python
    import jax.numpy as jnp
    import grazejax as gj

    lorenz = gj.Scene(lambda t, x, a: jnp.stack([
        10.0 * (x[1] - x[0]), x[0] * (28.0 - x[2]) - x[1], x[0] * x[1] - 8.0 / 3.0 * x[2]]))
    result = gj.lyapunov_spectrum(lorenz, jnp.array([1.0, 1.0, 20.0]), 0.0, 20.0,
                                  renormalize=0.5)
    print(result.exponents, float(result.exponents.sum()))  # the sum is -(10 + 1 + 8/3)
    ```
    """
    return _spectrum(scene, x0, t0, t1, args, k=k, transient=transient,
                     renormalize=renormalize, grazing_speed=grazing_speed,
                     options=simulate_options)


def maximal_lyapunov_exponent(scene: Scene, x0, t0, t1, args=None, *, transient=0.0,
                              renormalize=None, grazing_speed: float | None = None,
                              **simulate_options) -> LyapunovSpectrum:
    r"""The largest Lyapunov exponent: one tangent vector, renormalised by its norm.

    `grazejax.lyapunov_spectrum` with k = 1 (one tangent direction per window, the
    cheapest run): the same arguments but `k`, and the same `grazejax.LyapunovSpectrum`,
    whose `exponents` has one entry.
    """
    return _spectrum(scene, x0, t0, t1, args, k=1, transient=transient,
                     renormalize=renormalize, grazing_speed=grazing_speed,
                     options=simulate_options)


def _spectrum(scene, x0, t0, t1, args, *, k, transient, renormalize, grazing_speed, options):
    """Check the inputs, fix the window grid, and run the compiled program."""
    if not isinstance(scene, Scene):
        raise TypeError(f"lyapunov_spectrum takes a grazejax.Scene, got {type(scene).__name__}")
    for name in ("direction", "saveat", "throw"):
        if name in options:
            raise ValueError(f"lyapunov_spectrum sets simulate's `{name}` itself: do not pass it")
    x0 = jnp.asarray(x0, dtype=float)
    n = x0.shape[-1]
    k = n if k is None else int(k)
    if not 1 <= k <= n:
        raise ValueError(f"k must be in 1..{n} (the state's dimension), got {k}")
    start, tau, num_windows = _window_grid(t0, t1, transient, renormalize)
    rtol = _rtol_of(options)
    speed = GRAZING_SPEED_PER_SQRT_RTOL * math.sqrt(rtol) if grazing_speed is None else grazing_speed
    # Python floats in `args` and the tolerances are inputs of the compiled program, so
    # that new values do not compile it again.
    return _run_windows(
        scene, x0, _traced_numbers(args), jnp.asarray(float(t0)), jnp.asarray(start),
        jnp.asarray(tau), jnp.asarray(float(speed)), jnp.asarray(STRETCH_RATIO_FLOOR),
        k=k, num_windows=num_windows, has_transient=start > float(t0),
        options={**options, **numeric_options(options)},
    )


def _window_grid(t0, t1, transient, renormalize) -> tuple[float, float, int]:
    """(start of the averaging, τ, number of windows) from concrete times."""
    try:
        t0, t1, transient = float(t0), float(t1), float(transient)
        tau = None if renormalize is None else float(renormalize)
    except (TypeError, jax.errors.ConcretizationTypeError) as error:
        raise TypeError(
            "lyapunov_spectrum: t0, t1, transient and renormalize must be concrete numbers "
            "(they fix the number of windows, part of the compiled program); vmap over x0 "
            "and args instead"
        ) from error
    if not (math.isfinite(t0) and math.isfinite(t1)):
        raise ValueError(f"t0 and t1 must be finite, got {t0}, {t1}")
    if transient < 0:
        raise ValueError(f"transient must be >= 0, got {transient}")
    start = t0 + transient
    span = t1 - start
    if not span > 0:
        raise ValueError(
            f"lyapunov_spectrum runs forward in time: need t1 > t0 + transient, got t0 = {t0}, "
            f"transient = {transient}, t1 = {t1}"
        )
    if tau is None:
        return start, span / DEFAULT_NUM_WINDOWS, DEFAULT_NUM_WINDOWS
    if not tau > 0:
        raise ValueError(f"renormalize must be > 0, got {tau}")
    # Windows of exactly τ, as many as fit (to rounding: 10 ulps of the count).
    num_windows = int(math.floor(span / tau * (1 + 1e-15) + 1e-12))
    if num_windows < 1:
        raise ValueError(f"renormalize = {tau} is longer than t1 - t0 - transient = {span}")
    return start, tau, num_windows


def _rtol_of(options) -> float:
    """The relative tolerance the runs use (their controller's, if one is given)."""
    controller = options.get("stepsize_controller")
    rtol = getattr(controller, "rtol", None) if controller is not None else None
    return float(options.get("rtol", SIMULATE_OPTIONS["rtol"]) if rtol is None else rtol)


# --------------------------------------------------------------------------------------
# The compiled program: transient, then a scan over windows
# --------------------------------------------------------------------------------------


def start_frame(n: int, k: int) -> np.ndarray:
    """A fixed generic orthonormal (n, k) frame: the first k columns of the QR of a seeded
    Gaussian n × n matrix (signs fixed so that diag R > 0). Generic, so that it lies in no
    invariant subspace of the flow; its first columns do not depend on k, so the k = 1 run
    follows the first vector of every larger frame."""
    q, r = np.linalg.qr(np.random.default_rng(0).standard_normal((n, n)))
    return (q * np.sign(np.diag(r)))[:, :k]


@single_run_jit
def _run_windows(scene, x0, args, t0, start, tau, speed_floor, stretch_floor, *, k,
                 num_windows, has_transient, options) -> LyapunovSpectrum:
    """Transient, then `num_windows` windows in one `lax.scan` (see `lyapunov_spectrum`)."""
    status0 = jnp.asarray(int(Status.SUCCESS))
    if has_transient:
        sol = simulate(scene, x0, t0, start, args, direction=1, **options)
        x0, status0 = sol.x_final, sol.status
    frame = jnp.asarray(start_frame(x0.shape[0], k), dtype=x0.dtype)

    def window(carry, i):
        x, q, alive = carry
        t_a, t_b = start + i * tau, start + (i + 1) * tau
        pushed, sol = _push_frame(scene, x, q, t_a, t_b, args, options)
        q_next, stretches = _orthonormalise(pushed)
        log_r = jnp.log(stretches)
        finite = jnp.all(jnp.isfinite(log_r)) & jnp.all(jnp.isfinite(q_next))
        ok = alive & (sol.status == Status.SUCCESS)
        grazed = ok & (~finite | _grazes(scene, sol, args, speed_floor))
        stretched = ok & finite & (jnp.min(stretches) < stretch_floor * jnp.max(stretches))
        keep = ok & finite
        carry = (jnp.where(ok, sol.x_final, x), jnp.where(keep, q_next, q), ok)
        out = dict(log_r=jnp.where(ok, log_r, jnp.nan), ok=ok, grazed=grazed,
                   stretched=stretched, impacts=jnp.where(ok, sol.num_impacts, 0),
                   failure=jnp.where(alive & ~ok, sol.status, int(Status.SUCCESS)))
        return carry, out

    alive0 = status0 == Status.SUCCESS
    _, out = jax.lax.scan(window, (x0, frame, alive0), jnp.arange(num_windows))
    return _summarise(out, tau, status0)


def _push_frame(scene, x, q, t_a, t_b, args, options):
    """The window's run from (t_a, x) to t_b and its tangent map applied to the frame:
    d x(t_b) / dc at c = 0 of the run from x + q c (`jax.jacfwd`, saltation included)."""

    def run(c):
        sol = simulate(scene, x + q @ c, t_a, t_b, args, direction=1, **options)
        return sol.x_final, sol

    zero = jnp.zeros(q.shape[1], dtype=q.dtype)
    return jax.jacfwd(run, has_aux=True)(zero)


def _orthonormalise(pushed):
    """QR of the pushed frame with diag R > 0: (new frame, stretches R_ii)."""
    if pushed.shape[1] == 1:  # one vector: renormalise by its norm
        norm = jnp.linalg.norm(pushed[:, 0])
        return pushed / norm, norm[None]
    q, r = jnp.linalg.qr(pushed)
    diagonal = jnp.diagonal(r)
    signs = jnp.where(diagonal < 0, -1.0, 1.0).astype(pushed.dtype)
    return q * signs, jnp.abs(diagonal)


def _grazes(scene: Scene, sol, args, speed_floor):
    """Whether the window's impact log holds a grazing contact (γ) or an impact whose
    relative approach speed |dΦ/dt| / (|∂Φ/∂t| + |∇Φ|·|f⁻|) is below `speed_floor`."""
    rows = jnp.arange(sol.impact_kind.shape[0])
    used = rows < sol.num_impacts
    kinds = sol.impact_kind
    tangential = (kinds == ImpactKind.GAMMA) | (kinds == ImpactKind.GAMMA_PRIME)
    impact = (kinds >= ImpactKind.ALPHA) & (kinds <= ImpactKind.GAMMA_PRIME)
    if scene.surfaces:
        speeds = jax.vmap(lambda t, x, s: _relative_speed(scene, t, x, s, args))(
            jnp.nan_to_num(sol.impact_times), jnp.nan_to_num(sol.impact_pre),
            jnp.maximum(sol.impact_surface, 0))
        slow = impact & ~(speeds > speed_floor)  # NaN speed counts as slow
    else:
        slow = jnp.zeros_like(used)
    return jnp.any(used & (tangential | slow))


def _relative_speed(scene: Scene, t, x, surface, args):
    """|dΦ/dt| / (|∂Φ/∂t| + |∇Φ|·|f|) of surface `surface` at (t, x): the sine of the angle
    at which the flow meets it in (t, x) space."""

    f = scene.vector_field(t, x, args)  # (one field evaluation for every surface)

    def speed_on(i):
        phi = scene.surfaces[i].phi
        phi_t, grad = jax.jacfwd(phi, argnums=(0, 1))(t, x, args)
        rate = phi_t + grad @ f
        scale = jnp.abs(phi_t) + jnp.linalg.norm(grad) * jnp.linalg.norm(f)
        return jnp.abs(rate) / scale

    speeds = jnp.stack([speed_on(i) for i in range(len(scene.surfaces))])
    return speeds[surface]


def _summarise(out, tau, status0) -> LyapunovSpectrum:
    """Exponents, history and status from the per-window outputs of the scan."""
    log_r, ok = out["log_r"], out["ok"]
    num_ok = jnp.sum(ok)
    averaged = num_ok * tau
    sums = jnp.sum(jnp.where(ok[:, None], log_r, 0.0), axis=0)
    exponents = jnp.where(num_ok > 0, sums / averaged, jnp.nan)
    counts = jnp.arange(1, log_r.shape[0] + 1, dtype=log_r.dtype)[:, None]
    history = jnp.cumsum(log_r, axis=0) / (counts * tau)  # NaN from the first failure on
    failures = out["failure"]
    first_failure = failures[jnp.argmax(failures != Status.SUCCESS)]
    simulation_status = jnp.where(status0 != Status.SUCCESS, status0, first_failure)
    status = _status_code(simulation_status, jnp.any(out["grazed"]), jnp.any(out["stretched"]))
    return LyapunovSpectrum(
        exponents=-jnp.sort(-exponents),
        history=history,
        num_impacts=jnp.sum(out["impacts"]),
        averaging_time=averaged,
        window_length=jnp.asarray(tau),
        status=status,
        simulation_status=simulation_status,
        grazing_windows=out["grazed"],
    )


def _status_code(simulation_status, grazed, stretched):
    """A failed run first, then grazing, then a too-long window, else SUCCESS."""
    failure = jnp.select(
        [simulation_status == Status.MAX_IMPACTS, simulation_status == Status.ZENO],
        [int(LyapunovStatus.MAX_IMPACTS), int(LyapunovStatus.ZENO)],
        int(LyapunovStatus.SIMULATION_FAILED),
    )
    return jnp.where(
        simulation_status != Status.SUCCESS, failure,
        jnp.where(grazed, int(LyapunovStatus.GRAZING),
                  jnp.where(stretched, int(LyapunovStatus.WINDOW_TOO_LONG),
                            int(LyapunovStatus.SUCCESS))),
    )
