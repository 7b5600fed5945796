"""ocp_jax: optimal camera placement in 2D scenes with exact, differentiable visibility.

The implementation follows A. A. Steinitz, *Optimal Camera Placement* (Berkeley MS
thesis); equation numbers in docstrings refer to it.
"""

from . import scenes as scenes
from ._baselines import SearchResult as SearchResult
from ._baselines import exhaustive as exhaustive
from ._baselines import greedy as greedy
from ._baselines import slsqp as slsqp
from ._camera import Camera as Camera
from ._compile import compiler_options as compiler_options
from ._curves import AbstractConic as AbstractConic
from ._curves import AbstractCurve as AbstractCurve
from ._curves import BezierCurve as BezierCurve
from ._curves import BSplineCurve as BSplineCurve
from ._curves import Circle as Circle
from ._curves import Ellipse as Ellipse
from ._curves import PiecewiseCurve as PiecewiseCurve
from ._objectives import AbstractLocalObjective as AbstractLocalObjective
from ._objectives import Coverage as Coverage
from ._objectives import Foreshortened as Foreshortened
from ._objectives import LocalObjective as LocalObjective
from ._objectives import Reconstruction as Reconstruction
from ._objectives import VisibleLength as VisibleLength
from ._optimize import OptimizeResult as OptimizeResult
from ._optimize import optimize as optimize
from ._placement import AbstractPlacement as AbstractPlacement
from ._placement import Constraints as Constraints
from ._placement import DirectionalPlacement as DirectionalPlacement
from ._placement import EqualityConstraint as EqualityConstraint
from ._placement import FreePlacement as FreePlacement
from ._placement import PolygonBoundary as PolygonBoundary
from ._placement import RectangleBoundary as RectangleBoundary
from ._placement import Region as Region
from ._problem_file import PlacementProblem as PlacementProblem
from ._problem_file import load_problem as load_problem
from ._problem_file import problem_to_json as problem_to_json
from ._scene import Scene as Scene
from ._smoothed import Smoothed as Smoothed
from ._svg import load_svg as load_svg
from ._visibility import VisibilityOptions as VisibilityOptions
from ._visibility import VisibleIntervals as VisibleIntervals
from ._visibility import fit_options as fit_options
from ._visibility import visibility as visibility
from ._visibility import visible_intervals as visible_intervals

__version__ = "0.1.0"
