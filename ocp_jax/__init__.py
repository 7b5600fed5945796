"""ocp_jax: optimal camera placement in 2D scenes with exact, differentiable visibility.

The implementation follows A. A. Steinitz, *Optimal Camera Placement* (Berkeley MS
thesis); equation numbers in docstrings refer to it.
"""

from . import scenes as scenes
from ._geometry.camera import Camera as Camera
from ._geometry.curves import AbstractConic as AbstractConic
from ._geometry.curves import AbstractCurve as AbstractCurve
from ._geometry.curves import BezierCurve as BezierCurve
from ._geometry.curves import BSplineCurve as BSplineCurve
from ._geometry.curves import Circle as Circle
from ._geometry.curves import Ellipse as Ellipse
from ._geometry.curves import PiecewiseCurve as PiecewiseCurve
from ._geometry.scene import Scene as Scene
from ._io.problem_file import PlacementProblem as PlacementProblem
from ._io.problem_file import load_problem as load_problem
from ._io.problem_file import problem_to_json as problem_to_json
from ._io.svg import load_svg as load_svg
from ._objectives.local import AbstractLocalObjective as AbstractLocalObjective
from ._objectives.local import Coverage as Coverage
from ._objectives.local import Foreshortened as Foreshortened
from ._objectives.local import LocalObjective as LocalObjective
from ._objectives.local import Reconstruction as Reconstruction
from ._objectives.local import VisibleLength as VisibleLength
from ._objectives.smoothed import Smoothed as Smoothed
from ._placement.placement import AbstractPlacement as AbstractPlacement
from ._placement.placement import Constraints as Constraints
from ._placement.placement import DirectionalPlacement as DirectionalPlacement
from ._placement.placement import EqualityConstraint as EqualityConstraint
from ._placement.placement import FreePlacement as FreePlacement
from ._placement.placement import PolygonBoundary as PolygonBoundary
from ._placement.placement import RectangleBoundary as RectangleBoundary
from ._placement.placement import Region as Region
from ._solvers.discrete import Exhaustive as Exhaustive
from ._solvers.discrete import Greedy as Greedy
from ._solvers.multistart import MultiStart as MultiStart
from ._solvers.place import place as place
from ._solvers.problem import AbstractPlacementSolver as AbstractPlacementSolver
from ._solvers.problem import Solution as Solution
from ._solvers.slsqp import SLSQP as SLSQP
from ._types import RESULTS as RESULTS
from ._visibility.visibility import VisibilityOptions as VisibilityOptions
from ._visibility.visibility import VisibleIntervals as VisibleIntervals
from ._visibility.visibility import fit_options as fit_options
from ._visibility.visibility import visibility as visibility
from ._visibility.visibility import visible_intervals as visible_intervals
from ._visibility.xla_cpu import compiler_options as compiler_options

__version__ = "0.1.0"
