"""grazejax: differentiable simulation of impact systems with grazing, on JAX and Diffrax.

Importing grazejax enables JAX's float64 mode (`jax_enable_x64`): event floors, impact
times and Jacobians are computed in double precision unless a user opts out per call.
"""

import jax

jax.config.update("jax_enable_x64", True)

from ._compilation_cache import enable_compilation_cache as enable_compilation_cache
from ._compiler import compiler_options as compiler_options
from ._conditions import ConditionReport as ConditionReport
from ._conditions import ConditionResult as ConditionResult
from ._conditions import check_conditions as check_conditions
from ._dynamics.basin_continuation import BasinsCurve as BasinsCurve
from ._dynamics.basin_continuation import continue_basins as continue_basins
from ._dynamics.basins import Attractor as Attractor
from ._dynamics.basins import Basins as Basins
from ._dynamics.basins import BasinStatus as BasinStatus
from ._dynamics.basins import basins as basins
from ._dynamics.lyapunov import LyapunovSpectrum as LyapunovSpectrum
from ._dynamics.lyapunov import LyapunovStatus as LyapunovStatus
from ._dynamics.lyapunov import lyapunov_spectrum as lyapunov_spectrum
from ._dynamics.lyapunov import maximal_lyapunov_exponent as maximal_lyapunov_exponent
from ._dynamics.orbit_diagram import OrbitDiagram as OrbitDiagram
from ._dynamics.orbit_diagram import orbit_diagram as orbit_diagram
from ._dynamics.sections import Section as Section
from ._dynamics.sections import poincare as poincare
from ._linearize import A2Diagnostic as A2Diagnostic
from ._linearize import ClosedForm as ClosedForm
from ._linearize import DerivativeStatus as DerivativeStatus
from ._linearize import FlowJacobian as FlowJacobian
from ._linearize import Meeting as Meeting
from ._linearize import OneSidedLimit as OneSidedLimit
from ._linearize import OneSidedLinearization as OneSidedLinearization
from ._linearize import PointType as PointType
from ._linearize import Saltation as Saltation
from ._linearize import ScalarGradient as ScalarGradient
from ._linearize import Variational as Variational
from ._linearize import WMap as WMap
from ._linearize import a2_diagnostic as a2_diagnostic
from ._linearize import classify_point as classify_point
from ._linearize import closed_form_linearization as closed_form_linearization
from ._linearize import flow_jacobian as flow_jacobian
from ._linearize import meeting_time as meeting_time
from ._linearize import one_sided_jacobians as one_sided_jacobians
from ._linearize import saltation_matrix as saltation_matrix
from ._linearize import scalar_gradient as scalar_gradient
from ._linearize import variational_transition as variational_transition
from ._linearize import w_map as w_map
from ._loop.policies import AbstractZenoPolicy as AbstractZenoPolicy
from ._loop.policies import ZenoStick as ZenoStick
from ._loop.policies import ZenoStop as ZenoStop
from ._memory import retain_freed_memory as retain_freed_memory
from ._orbits.bifurcation import BifurcationPoint as BifurcationPoint
from ._orbits.bifurcation_curve import BifurcationCurve as BifurcationCurve
from ._orbits.bifurcation_curve import Codim2Point as Codim2Point
from ._orbits.bifurcation_curve import continue_bifurcation as continue_bifurcation
from ._orbits.branch import Branch as Branch
from ._orbits.branch import GrazingPoint as GrazingPoint
from ._orbits.branch import SpecialPoint as SpecialPoint
from ._orbits.contacts import Contacts as Contacts
from ._orbits.contacts import GrazingBranches as GrazingBranches
from ._orbits.contacts import grazing_branches as grazing_branches
from ._orbits.contacts import orbit_contacts as orbit_contacts
from ._orbits.continuation import continue_orbit as continue_orbit
from ._orbits.continuation import period_doubled_orbit as period_doubled_orbit
from ._orbits.floquet import Floquet as Floquet
from ._orbits.floquet import floquet_multipliers as floquet_multipliers
from ._orbits.grazing_curve import GrazingCurve as GrazingCurve
from ._orbits.grazing_curve import continue_grazing as continue_grazing
from ._orbits.grazing_curve import locate_grazing as locate_grazing
from ._orbits.locate import locate_bifurcation as locate_bifurcation
from ._orbits.period_map import SolverSettings as SolverSettings
from ._orbits.periodic import Orbit as Orbit
from ._orbits.periodic import OrbitStatus as OrbitStatus
from ._orbits.periodic import find_periodic_orbit as find_periodic_orbit
from ._piecewise import Event as Event
from ._piecewise import FieldCheck as FieldCheck
from ._piecewise import Mode as Mode
from ._piecewise import PiecewiseScene as PiecewiseScene
from ._piecewise import SwitchingSurface as SwitchingSurface
from ._piecewise import Transition as Transition
from ._piecewise import check_field_continuity as check_field_continuity
from ._roots import ITP as ITP
from ._roots import AbstractBracketedRootFinder as AbstractBracketedRootFinder
from ._roots import BracketedNewton as BracketedNewton
from ._roots import Chandrupatla as Chandrupatla
from ._scene import Scene as Scene
from ._scene import Surface as Surface
from ._simulate import simulate as simulate
from ._solution import FailedLanesWarning as FailedLanesWarning
from ._solution import ImpactLog as ImpactLog
from ._solution import SimulationError as SimulationError
from ._solution import Solution as Solution
from ._status import ContinuationStatus as ContinuationStatus
from ._status import ImpactKind as ImpactKind
from ._status import Status as Status
from ._sweep import sweep as sweep
from ._vern9 import Vern9 as Vern9
from .plot import plot_basins as plot_basins
from .plot import plot_bifurcation_diagram as plot_bifurcation_diagram
from .plot import plot_orbit_diagram as plot_orbit_diagram

__version__ = "0.1.0"
