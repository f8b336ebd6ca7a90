"""Verner's 9(8) Runge–Kutta pair with an eighth-order interpolant, as a Diffrax solver.

At tight tolerances a sweep's cost is set by the number of steps more than by the stages
in each: inside the impact loop every step also pays for the event test, the controller
and the loop's own bookkeeping. A ninth-order pair takes fewer steps than Dormand–Prince
8(7) for the same error, each dearer (`benchmarks/README.md` measures both).

The pair is J. H. Verner's "most efficient" 9(8) pair (Verner, *Numerically optimal
Runge–Kutta pairs with interpolants*, Numer. Algorithms 53 (2010) 383–396; coefficients
as published on his web page, 40 digits, here rounded to double): 16 stages, a 17th at
(t₁, y₁) that is the next step's first (FSAL), and four more, 18–21, that only the
interpolant uses. The interpolant on the step, with θ = (t − t₀)/(t₁ − t₀) and
kᵢ = h f(stage i), is

    y(θ) = y₀ + Σᵢ wᵢ(θ) kᵢ,   wᵢ(θ) = bᵢ θ + θ (1 − θ) Qᵢ(θ),

Verner's degree-8 weights rewritten (exactly, in rational arithmetic from the published
decimals; the remainders are below 1e-35) so that y(0) = y₀ and y(1) = y₀ + Σ bᵢkᵢ hold
without cancellation: in the published monomial form the weights' coefficients reach
1.3e4 and their sum at θ = 1 misses bᵢ by 1.4e-12 in double precision.

`Vern9` runs its stages as straight-line code (`_loop.unrolled.UnrolledERK`), with or without
`grazejax.simulate`. The tests check the tableau's order conditions, the measured orders
of the step (9) and of the interpolant (8), and simulations against closed forms
(`tests/test_vern9.py`).
"""

from typing import ClassVar

import diffrax
import jax.numpy as jnp
import numpy as np

from ._loop.unrolled import UnrolledERK
from ._roots import safe_divide

_C = (  # nodes c_2 … c_21 (c_1 = 0)
    0.03462,
    0.09702435063878044,
    0.14553652595817068,
    0.561,
    0.229007911590485,
    0.544992088409515,
    0.645,
    0.48375,
    0.06757,
    0.25,
    0.6590650618730999,
    0.8206,
    0.9012,
    1.0,
    1.0,
    1.0,
    0.7404185470631561,
    0.888,
    0.696,
    0.487,
)
_A = (  # rows 2 … 21 of the lower triangle (row i has i − 1 entries)
    (0.03462,),
    (-0.038933543885728734, 0.13595789452450918,),
    (0.03638413148954267, 0.0, 0.109152394468628,),
    (2.02576391439397, 0.0, -7.638023836496292, 6.173259922102322,),
    (0.05112275589406061, 0.0, 0.0, 0.17708237945550215, 0.0008027762409222502,),
    (0.13160063579752163, 0.0, 0.0, -0.29572762526696367, 0.08781378035642952, 0.6213052975225275,),
    (0.07166666666666667, 0.0, 0.0, 0.0, 0.0, 0.33055335789153195, 0.24277997544180138,),
    (0.071806640625, 0.0, 0.0, 0.0, 0.0, 0.3294380283228177, 0.11651900292718229, -0.034013671875,),
    (0.04836757646340647, 0.0, 0.0, 0.0, 0.0, 0.03928989925676164, 0.10547409458903446, -0.021438652846483126, -0.10412291746271944,),
    (-0.026645614872014785, 0.0, 0.0, 0.0, 0.0, 0.03333333333333333, -0.1631072244872467, 0.033960816841277615, 0.1572319413814626, 0.21522674780318796,),
    (0.036890092487086225, 0.0, 0.0, 0.0, 0.0, -0.1465181576725543, 0.22425777681720244, 0.022944057170660725, -0.003585005290572876, 0.08669223316444385, 0.43838406519683376,),
    (-0.48660122151133406, 0.0, 0.0, 0.0, 0.0, -6.304602650282853, -0.2812456182894726, -2.6790192362198493, 0.5188156639241576, 1.3653531876033418, 5.8850910885039465, 2.8028087862720628,),
    (0.41853674577534716, 0.0, 0.0, 0.0, 0.0, 6.724547581906459, -0.4254442801646118, 3.3432791530012658, 0.6170816631175378, -0.9299661239399328, -6.099948804751011, -3.002206187889399, 0.2553202529443446,),
    (-0.7793740861228846, 0.0, 0.0, 0.0, 0.0, -13.937342538107776, 1.2520488533793572, -14.69150040801687, -0.4947050585331417, 2.2429749091462368, 13.367893803828643, 14.396650486650687, -0.79758133317768, 0.4409353709534278,),
    (2.0580513374668863, 0.0, 0.0, 0.0, 0.0, 22.357937727968032, 0.9094981099755634, 35.89110098240264, -3.4425150276244536, -4.8654813580363685, -18.909803813543427, -34.26354448030452, 1.2647565216956427, 0.0, 0.0,),
    (0.014611976858423152, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.3915211862331339, 0.23109325002895065, 0.12747667699928525, 0.2246434176204158, 0.5684352689748513, 0.058258715572158275, 0.13643174034822156, 0.030570139830827976, 0.0,),
    (0.015499736681895594, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3355153219059635, 0.20036139441918607, 0.12520606592835493, 0.22986763931842066, -0.20202506534761813, 0.05917103230665457, -0.026518347830476387, -0.023840946021309713, 0.0, 0.027181715702085017,),
    (0.013024539431143383, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.7452850902413112, 0.2643867896429301, 0.1313961758372754, 0.21672538151229273, 0.8734117564076053, 0.011859056439357767, 0.05876002941689551, 0.003266518630202088, 0.0, -0.00895930864841793, 0.06941415157202692,),
    (0.013970899969259426, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.46657653359576745, 0.24163727872162571, 0.12903633413456747, 0.22167006717351054, 0.6257275123364645, 0.04355312415679284, 0.10119624916672908, 0.01808582254679721, 0.0, -0.020798755876891697, -0.09022232517086219, -0.12127967356222542,),
    (0.016046388883181127, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.09517712399458336, 0.13591872646553177, 0.1237765280959854, 0.2335656264102966, -0.09051508172625873, -0.02537574270006131, -0.13596316968871622, -0.04679214284145113, 0.0, 0.05177958859391748, 0.09672595677476774, 0.14773126903407427, -0.11507507129585039,),
)
_B = (  # ninth-order weights b_1 … b_16
    0.014611976858423152, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -0.3915211862331339, 0.23109325002895065, 0.12747667699928525, 0.2246434176204158, 0.5684352689748513, 0.058258715572158275, 0.13643174034822156, 0.030570139830827976, 0.0,
)
_B_ERROR = (  # (eighth-order − ninth-order) weights
    0.005357988290444578, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 2.583020491182464, -0.14252253154686625, -0.013420653512688676, 0.028672962914094935, -2.624999655215792, 0.2825509643291537, -0.13643174034822156, -0.030570139830827976, 0.048342313738239585,
)
_Q = (  # per stage: coefficients of θ⁰ … θ⁶ of Q_i (module docstring)
    (0.9853880231415768, -11.764277394574185, 56.76653027214904, -138.04544426326936, 179.79719287201647, -119.91834808732317, 32.19357055471806),
    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    (0.3915211862331339, 141.4611304396044, -1142.3073202069893, 3487.9727415596917, -5160.528234540624, 3730.2839265263947, -1057.6652861505438),
    (-0.23109325002895065, -51.98210648454433, 434.0591442467488, -1343.4164421217752, 2002.0817965280164, -1453.6806834793497, 413.4004778109618),
    (-0.12747667699928525, 16.19334340995968, -102.51393068671499, 277.3841346427506, -381.81388332543094, 263.1988261714561, -72.1935368580219),
    (-0.2246434176204158, -6.122431345133154, 83.49184022088966, -297.89694748438706, 475.19947250238795, -358.9217811259383, 104.69913406742172),
    (-0.5684352689748513, -212.14379309836912, 1710.0059541095875, -5217.538692953815, 7716.352618538022, -5576.369903823071, 1580.8306877655953),
    (-0.058258715572158275, -29.701410265306023, 235.91473500157426, -715.3999029137042, 1054.476725040404, -760.4494336918376, 215.2758042600138),
    (-0.13643174034822156, -78.85533996255144, 623.3477564072572, -1886.4358621205342, 2777.4488252828196, -2001.6009382510154, 566.3684221247208),
    (-0.030570139830827976, -20.22338580663521, 159.14033998827665, -480.67228608499244, 706.9507495124477, -509.13239696646315, 143.99811963702805),
    (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
    (6.7e-37, 22.255291729370043, -180.02159653628635, 561.4288070596527, -858.7425687599937, 648.0841905239159, -194.00412401665866),
    (1.59e-36, 14.877639873605062, -297.4064114049296, 1545.1002058112238, -3323.799443051855, 3184.5472451514124, -1123.3192363794567),
    (-4.7e-37, 94.98456650525378, -725.5929989242896, 2092.7542579743595, -2899.895467183163, 1935.9091802526418, -498.15953862480217),
    (-1.7e-37, 63.46082596146032, -324.1636436167845, 328.4372290871536, 550.4393266872336, -1146.116036657953, 527.94229853889),
    (-3.9e-37, 57.559946437860184, -530.7203988704888, 1786.328201807646, -2837.9671101022805, 2164.1661534571294, -639.3667927298665),
)

_NUM_STEP_STAGES = 17  # 16 stages and the FSAL stage at (t₁, y₁)

_TABLEAU = diffrax.ButcherTableau(
    c=np.asarray(_C[: _NUM_STEP_STAGES - 1]),
    b_sol=np.asarray(_B + (0.0,)),
    b_error=np.asarray(_B_ERROR + (0.0,)),
    a_lower=tuple(np.asarray(row) for row in _A[: _NUM_STEP_STAGES - 1]),
)


class _Vern9Interpolation(diffrax.AbstractLocalInterpolation):
    """The eighth-order dense output on one step (module docstring)."""

    t0: float
    t1: float
    y0: jnp.ndarray
    y1: jnp.ndarray
    k: jnp.ndarray  # the 21 stages, h f(stage i)

    def evaluate(self, t0, t1=None, left=True):
        del left
        if t1 is not None:
            return self.evaluate(t1) - self.evaluate(t0)
        h = self.t1 - self.t0
        theta = safe_divide(t0 - self.t0, h, h != 0)
        # Σᵢ wᵢ(θ) = θ exactly, so y(θ) = y₀ + θ k₁ + Σᵢ₌₂ wᵢ(θ)(kᵢ − k₁): the weights reach
        # ~1e3 and cancel over stages that differ by O(h²) only; summed over the
        # differences, their rounding scales with h²|f'| rather than h|f|. (w₁ is not
        # needed.)
        weights = theta * jnp.asarray(_WEIGHTS_AT_END[1:], theta.dtype) + theta * (1 - theta) * (
            jnp.polyval(jnp.asarray(_Q_DESCENDING[1:], theta.dtype).T, theta)
        )
        k = self.k
        return self.y0 + theta.astype(k.dtype) * k[0] + jnp.tensordot(
            weights.astype(k.dtype), k[1:] - k[0], axes=1
        )


_WEIGHTS_AT_END = np.asarray(_B + (0.0,) * 5)
_Q_DESCENDING = np.asarray(_Q)[:, ::-1]  # jnp.polyval wants the highest power first


class Vern9(diffrax.AbstractERK):
    """Verner's 9(8) pair with an eighth-order interpolant (see the module docstring).

    Ninth order, eighth-order error estimate, 16 new vector-field evaluations per step
    (FSAL) and 4 more for the dense output that event location reads. At tight
    tolerances it takes fewer steps than `diffrax.Dopri8`, each dearer: with a cheap field
    (near-grazing ex1dof sweeps) Dopri8 stays faster. Consider it where vector-field
    evaluations dominate the cost of a step.
    """

    tableau: ClassVar[diffrax.ButcherTableau] = _TABLEAU
    interpolation_cls: ClassVar = _Vern9Interpolation
    # Stages computed after the step's own, for the dense output: (c, row of a) each.
    dense_stages: ClassVar[tuple] = tuple(
        (c, np.asarray(row))
        for c, row in zip(_C[_NUM_STEP_STAGES - 1:], _A[_NUM_STEP_STAGES - 1:], strict=True)
    )

    def order(self, terms):
        del terms
        return 9

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        # Diffrax's stage loop knows only the tableau's stages, not the dense output's.
        return UnrolledERK(self).step(terms, t0, t1, y0, args, solver_state, made_jump)
