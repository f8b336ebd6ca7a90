"""Explicit Runge–Kutta steps with their stages unrolled.

Diffrax runs the stages of every Runge–Kutta step as a loop (`eqxi.while_loop`, one
iteration per stage: the loop lets one code path serve explicit and implicit tableaus and
bounds what reverse mode stores). Inside grazejax's impact loop that inner loop costs more
than the arithmetic it runs. An explicit tableau needs no loop: each stage is a fixed
linear combination of the previous ones, so the step is written out as straight-line code
that XLA fuses (`benchmarks/README.md`: sweeps and single runs both gain). Straight-line code also differentiates in both modes (forward mode cannot enter a
checkpointed stage loop, reverse mode cannot enter a `lax` one), so the same step serves
`jax.jacfwd` and `jax.grad`.

`UnrolledERK(solver)` takes the tableau, interpolation and orders of the Diffrax solver it
wraps; `simulate` wraps Diffrax's explicit solvers in it unless the solver sets its own
`scan_kind`.
"""

from typing import ClassVar

import diffrax
import jax.numpy as jnp
import numpy as np


def unrollable(solver) -> bool:
    """Whether `solver` is one of Diffrax's explicit Runge–Kutta methods on an ODE term,
    with the stage loop's kind left to the caller (`scan_kind=None`)."""
    return (
        isinstance(solver, diffrax.AbstractERK)
        and getattr(solver, "scan_kind", None) is None
        and isinstance(getattr(type(solver), "tableau", None), diffrax.ButcherTableau)
        and type(solver).term_structure is diffrax.AbstractTerm
    )


def _weighted_sum(weights, ks):
    """Σ_j w_j k_j summed as a balanced tree of products (None if all weights are zero).

    Straight-line products and adds fuse into one loop per stage. Diffrax's form, a
    contraction with the stacked stages (`tensordot`), is a dot per stage that XLA's CPU
    backend does not fuse (under `vmap` it costs several times this sum). The order is
    chosen for rounding: a sequential chain w₀k₀ + w₁k₁ + … rounds worse than a balanced
    tree.
    """
    weights = np.asarray(weights)
    weighted = zip(weights, ks[: len(weights)], strict=True)
    terms = [jnp.asarray(w, k.dtype) * k for w, k in weighted if w != 0]
    if not terms:
        return None
    while len(terms) > 1:
        pairs = [a + b for a, b in zip(terms[0::2], terms[1::2], strict=False)]
        terms = pairs + terms[len(pairs) * 2:]
    return terms[0]


def _combination(y0, weights, total, ks, rises):
    """y0 + Σ_j w_j k_j, summed relative to the first stage:
    y0 + (total·k₀ + Σ_{j≥1} w_j (k_j − k₀)), where `total` is Σ_j w_j as the tableau means
    it (c_i for a stage, 1 for the solution, 0 for the error estimate) and
    `rises[j] = k_j − k₀` (computed as h·(f_j − f₀)). `y0=None`: the increment alone.

    A tableau's weights are not exact in binary and their sum in floating point misses c_i
    (or 1) by ulps, so a constant field — every stage equal — gains the same relative error
    in every step. Over identical flights (an elastic ball) that error is coherent: the
    speed gained tens of ulps per bounce and impact times drifted like k². Relative to the
    first stage a constant field is exact to one rounding of total·k₀, and the rounding of
    the rest scales with how much the stages differ, not with their size.
    """
    rest = _weighted_sum(np.asarray(weights)[1:], rises[1: len(weights)])
    base = None if total == 0 else jnp.asarray(total, ks[0].dtype) * ks[0]
    parts = [p for p in (base, rest) if p is not None]
    increment = None if not parts else parts[0] if len(parts) == 1 else parts[0] + parts[1]
    if y0 is None:
        return increment
    return y0 if increment is None else y0 + increment


class UnrolledERK(diffrax.AbstractAdaptiveSolver):
    """The explicit Runge–Kutta method of `solver` with its stages written out.

    Same tableau, FSAL handling, dense output and error estimate as `solver`; only the
    stage loop is gone. The step's arithmetic differs from Diffrax's in the order of the
    sums (Diffrax takes a dot product with the whole stage buffer), so results agree to
    rounding, not bit for bit.
    """

    solver: diffrax.AbstractERK
    term_structure: ClassVar = diffrax.AbstractTerm

    @property
    def interpolation_cls(self):
        return self.solver.interpolation_cls

    def order(self, terms):
        return self.solver.order(terms)

    def error_order(self, terms):
        return self.solver.error_order(terms)

    @property
    def end_stage(self):
        """Index in the dense output's stages of h·f(t₁, y₁), the FSAL stage (None if the
        tableau has none). With the first stage, h·f(t₀, y₀), it gives the state's rate at
        both ends of the step without evaluating the interpolant."""
        tableau = type(self.solver).tableau
        return len(tableau.c) if tableau.fsal else None

    def init(self, terms, t0, t1, y0, args):
        return self.solver.init(terms, t0, t1, y0, args)

    def func(self, terms, t0, y0, args):
        return self.solver.func(terms, t0, y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        tableau = type(self.solver).tableau
        num_stages = len(tableau.c) + 1
        a_lower = [np.asarray(a) for a in tableau.a_lower]
        c = np.asarray(tableau.c)
        dt = terms.contr(t0, t1)
        if solver_state is None:  # not FSAL (or a term Diffrax deems expensive)
            f0 = terms.vf(t0, y0, args)
        else:
            first_step, f0 = solver_state
            # The stored f0 is f at the end of the previous step; after a jump (or on the
            # first step) it is evaluated again, for the lanes that jumped only. Diffrax
            # re-evaluates it for every lane whenever any lane jumped (a `cond` on any
            # lane), and a re-evaluated f(t0, y0) need not have the stored value's bits
            # (it is compiled in another context than the last stage's): a lane's result
            # then moved with its neighbours' impacts and with the batch's shape (sweeps on
            # 4 devices vs 1 differed in the last digits of impact times). One more field
            # evaluation per step, within the noise of single runs.
            needs_f0 = first_step | made_jump
            f0 = jnp.where(needs_f0, terms.vf(t0, y0, args), f0)
        ks = [terms.prod(f0, dt)]
        # k_j − k₀ as h·(f_j − f₀): the same in every program. (Written as h·f_j − h·f₀,
        # XLA's simplifier may factor it in one program and not in another, depending on
        # who else reads h·f_j: a sweep's lanes then differed in the last bit from the same
        # lanes under plain `vmap`.)
        rises = [None]
        fi = f0
        yi = y0
        for i in range(1, num_stages):
            ci = float(c[i - 1])
            yi = _combination(y0, a_lower[i - 1], ci, ks, rises)
            ti = t1 if ci == 1 else t0 + ci * dt
            fi = terms.vf(ti, yi, args)
            ks.append(terms.prod(fi, dt))
            rises.append(terms.prod(fi - f0, dt))
        y1 = yi if tableau.ssal else _combination(y0, tableau.b_sol, 1.0, ks, rises)
        y_error = _combination(None, tableau.b_error, 0.0, ks, rises)
        if y_error is None:
            y_error = jnp.zeros_like(y0)
        new_state = None if solver_state is None else (jnp.array(False), fi)
        # Stages that only the dense output reads (`Vern9`'s interpolant).
        for ci, row in getattr(type(self.solver), "dense_stages", ()):
            yi = _combination(y0, row, float(ci), ks, rises)
            fi = terms.vf(t0 + float(ci) * dt, yi, args)
            ks.append(terms.prod(fi, dt))
            rises.append(terms.prod(fi - f0, dt))
        dense_info = dict(y0=y0, y1=y1, k=jnp.stack(ks))
        return y1, y_error, dense_info, new_state, diffrax.RESULTS.successful
