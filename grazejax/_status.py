"""Outcome codes: one `Status` per run (per lane of a batch), one `ImpactKind` per impact,
and `StatusCode`, the base of every status enum with a message."""

import enum


class StatusCode(enum.IntEnum):
    """An outcome code stored as an integer in a result's `status` array, with a message.

    Each member is declared with its message, `NAME = value, "message"`, and read back by
    `Kind(int(result.status)).message` outside `jit`.
    """

    def __new__(cls, value: int, message: str):
        member = int.__new__(cls, value)
        member._value_ = value
        member._message = message
        return member

    @property
    def message(self) -> str:
        return self._message


class Status(StatusCode):
    """How a run ended. Stored as an integer array in `Solution.status`.

    Inside `jax.jit` / `jax.vmap` nothing raises: every run (every lane) carries its own
    status, and `Status(int(sol.status))` turns it back into a readable member.
    """

    SUCCESS = 0, "reached t1"
    """Reached `t1`."""
    MAX_IMPACTS = 1, "stopped after max_impacts impacts"
    """Stopped right after the `max_impacts`-th impact (the usual way to run "N impacts")."""
    ZENO = 2, "impact times accumulate (Zeno) or the state sticks to a surface"
    """Impact times accumulate (or the state sticks to a surface): stopped after the last
    resolved impact; `Solution.zeno_time` estimates the accumulation time. With
    `simulate(..., zeno="stick")` the run slides on the surface instead, and ends ZENO only
    when it would have to slide on two surfaces at once."""
    MAX_STEPS = 3, "max_steps solver steps taken before t1"
    """`max_steps` solver steps were taken before reaching `t1`."""
    NONFINITE = 4, "non-finite state (NaN/inf) from the vector field, a jump or input"
    """The vector field or a jump produced NaN/inf (or x0/args were non-finite)."""
    STEP_SIZE_UNDERFLOW = 5, "step size fell below the resolution of t"
    """The step size controller shrank the step below the resolution of t."""
    BAD_JUMP = 6, "a jump left the state inside an impenetrable surface or moving into it"
    """A jump left the state inside an `impenetrable` surface piece (Φ < 0 beyond
    round-off) or on it still moving in, its own or another's: the scene's jump law
    contradicts its surfaces."""
    BAD_START = (
        7,
        "x0 lies inside an impenetrable surface (Φ < 0 beyond round-off) or on it moving in",
    )
    """`x0` lies strictly inside an `impenetrable` surface piece (Φ < 0 beyond round-off,
    inside its `where`), or on it moving in across it (the first flight would start
    inside): no trajectory of the scene starts there. (On it at rest, pushed in, is
    sticking: `ZENO` at `t0`, or sliding with `zeno="stick"`.) Outside `jit`/`vmap`,
    `simulate` raises a `ValueError` instead."""
    FIELD_DISCONTINUITY = (
        8,
        "the vector field jumps at an event surface (sign(·) on the state): the side after the "
        "event is round-off",
    )
    """The vector field jumps at the state a flight restarts from (after an impact or a
    crossing, or x0 on a surface): it switches on the event surface itself, written with `sign(·)` or
    `jnp.where` on the state, so the side whose field the next flight uses is decided by
    round-off. Stopped at that event (logged), or at t0. Fix: one mode per side
    (`grazejax.PiecewiseScene`, docs/piecewise.md), or the side as a state component
    that the jump flips. Outside `jit`/`vmap`, `simulate` raises a `ValueError` instead;
    `simulate(..., check_field_jumps=False)` turns the check off."""
    BAD_TIMES = 9, "t1 lies on the other side of t0 from direction: the run did not start"
    """`t1` lies on the other side of `t0` from `direction`: times traced inside
    `jit`/`vmap`, where `direction` fixes which way the compiled run goes. The run did
    not start (`x_final` = x0, `t_final` = t0). Outside `jit`/`vmap`, `simulate` raises a
    `ValueError` instead."""



class ImpactKind(enum.IntEnum):
    """The paper's classification of a discontinuity point (§2).

    α: interior of Γ, transversal; β: boundary ∂Γ, transversal; γ: tangential contact
    (grazing). Primes are the same types on the image surface Γ̃ = J(Γ), met in backward
    time. `NONE` pads unused rows of the impact log. With `simulate(..., zeno="stick")`
    the log also holds the starts (`STICK`) and ends (`RELEASE`) of sliding phases.
    """

    NONE = -1
    ALPHA = 0
    BETA = 1
    GAMMA = 2
    ALPHA_PRIME = 3
    BETA_PRIME = 4
    GAMMA_PRIME = 5
    STICK = 6
    """Not an impact: the state starts sliding on the surface (`zeno="stick"`); the
    logged post state is the pre state projected onto {Φ = 0, Φ̇ = 0}."""
    RELEASE = 7
    """Not an impact: the sliding state leaves the surface (the free Φ̈ reaches 0)."""

    @property
    def is_grazing(self) -> bool:
        return self in (ImpactKind.GAMMA, ImpactKind.GAMMA_PRIME)


class ContinuationStatus(StatusCode):
    """Why a continuation stopped (`Branch.status`)."""

    REACHED_STOP = 0, "reached mu_stop"
    """μ reached `mu_stop`."""
    MAX_POINTS = 1, "stopped after max_points points"
    """`max_points` points were computed."""
    STEP_TOO_SMALL = (
        2,
        "the corrector failed down to ds_min (a fold that pseudo-arclength could not pass, or a"
        " non-smooth point)",
    )
    """The corrector kept failing down to `ds_min`, away from any grazing contact."""
    BRANCH_ENDS = (
        3,
        "the family ends at a grazing point: no periodic orbit continues from there on either "
        "side",
    )
    """The family ends at a grazing point and no other family continues from there."""
    START_FAILED = 4, "the starting orbit could not be solved at mu_start"
    """The starting orbit could not be (re)solved at `mu_start`."""
    LEFT_RANGE = 5, "nu left nu_range"
    """ν left `nu_range` (`grazejax.continue_grazing`)."""
