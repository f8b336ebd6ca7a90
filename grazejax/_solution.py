"""`Solution`: what one run (or one batch of runs) of `simulate` returns."""

import equinox as eqx
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._status import ImpactKind, Status


class Solution(eqx.Module):
    r"""The result of [`grazejax.simulate`][]. Under `jax.vmap` every field gains a
    leading batch axis.

    Solutions are left-continuous (the paper's convention): at an impact time θ,
    `impact_pre` is x(θ) and `impact_post` is x(θ+) = J(x(θ)). The impact log has
    `max_impacts` rows; rows past `num_impacts` are padded with NaN (times, states),
    `-1` (surface) and `ImpactKind.NONE`.

    **Fields:**

    - `t_final`, `x_final`: where the run stopped: `t1` on success, else the time and
      post-impact state of the last impact (`MAX_IMPACTS`, `ZENO`), or the last accepted
      state (`MAX_STEPS`, `NONFINITE`, ...).
    - `num_impacts`: number of rows used in the impact log: impacts applied (simultaneous
      impacts count once each) plus, with `zeno="stick"`, the starts and ends of sliding
      (kinds `STICK`, `RELEASE`; count impacts with `impact_kind <= GAMMA_PRIME`).
    - `impact_times`, `impact_pre`, `impact_post`, `impact_surface`, `impact_kind`: the log.
      In backward time (`t1 < t0`) "pre" is the state met first (on Γ̃) and "post" the
      state after the inverse jump; kinds are the primed ones.
    - `status`: a [`grazejax.Status`][] code.
    - `zeno_time`: estimated accumulation time when `status == ZENO` (with
      `zeno="stick"`: of the last Zeno sequence before sliding), else NaN.
    - `num_steps`, `num_accepted_steps`: solver steps (all / accepted), for cost accounting.
    - `ts`, `xs`: saved times and states, only when `saveat` was given (else `None`).
    """

    t_final: Float[Array, ""]
    x_final: Float[Array, " n"]
    num_impacts: Int[Array, ""]
    impact_times: Float[Array, " max_impacts"]
    impact_pre: Float[Array, "max_impacts n"]
    impact_post: Float[Array, "max_impacts n"]
    impact_surface: Int[Array, " max_impacts"]
    impact_kind: Int[Array, " max_impacts"]
    status: Int[Array, ""]
    zeno_time: Float[Array, ""]
    num_steps: Int[Array, ""]
    num_accepted_steps: Int[Array, ""]
    ts: Float[Array, " num_saves"] | None = None
    xs: Float[Array, "num_saves n"] | None = None

    @property
    def succeeded(self) -> Bool[Array, ""]:
        return self.status == Status.SUCCESS

    def summary(self) -> str:
        """A short human-readable account of an unbatched run (outside jit)."""
        status = Status(int(self.status))
        k = int(self.num_impacts)
        lines = [
            f"status: {status.name} ({status.message}); t_final = {float(self.t_final):.17g}",
            f"x_final = {np.asarray(self.x_final)}",
            f"{k} impact(s); {int(self.num_accepted_steps)} accepted of {int(self.num_steps)} steps",
        ]
        for i in range(min(k, len(self.impact_times))):
            kind = ImpactKind(int(self.impact_kind[i]))
            lines.append(
                f"  #{i}: t = {float(self.impact_times[i]):.15g}  surface {int(self.impact_surface[i])}"
                f"  {kind.name}  pre = {np.asarray(self.impact_pre[i])}  post = {np.asarray(self.impact_post[i])}"
            )
        if status == Status.ZENO:
            lines.append(f"estimated accumulation time: {float(self.zeno_time):.15g}")
        return "\n".join(lines)
