"""Placement problems as JSON: the curves, where cameras may go, and the objective.

    {
      "curves": [
        {"type": "bezier", "control_points": [[x, y], ...]},       # closed: first == last
        {"type": "bspline", "control_points": [[x, y], ...], "degree": 3},
        {"type": "circle", "center": [x, y], "radius": r},
        {"type": "ellipse", "center": [x, y], "semi_axes": [a, b], "angle": 0.0},
        {"type": "polygon", "vertices": [[x, y], ...]},
        {"type": "path", "points": [[[x, y], ...], ...]}         # PiecewiseCurve points
      ],
      "room": {"type": "polygon", "vertices": [[x, y], ...]}    (optional: any curve type)
      "placement": {"type": "rectangle", "center": [x, y], "width": w, "height": h}
                 | {"type": "polygon", "corners": [[x, y], ...]}
                 | {"type": "region", "lower": [x, y], "upper": [x, y],
                    "polygon": [[x, y], ...] (optional), "clearance": 0.0 (optional)}
                 | {"type": "free", "lower": [x, y], "upper": [x, y]},
      "objective": "foreshortened" | "visible_length"      (optional, default foreshortened)
                 | {"type": "reconstruction", "area": a, "delta": 0.01 (optional)}
                 | {"type": "coverage", "m": 2}
                 | {"type": "smoothed", "objective": <an objective>, "width": w,
                    "delta": d (optional), "nodes": 128 (optional)}
    }

Keys are the constructors' arguments. `load_problem` says which entry is wrong and why;
`problem_to_json` writes the same form (not for an `EqualityConstraint`, whose g is code).
"""

import json
import pathlib
from typing import Any, NamedTuple

import numpy as np

from .._geometry.curves import BezierCurve, BSplineCurve, Circle, Ellipse, PiecewiseCurve
from .._geometry.scene import Scene
from .._objectives.local import (
    AbstractLocalObjective,
    Coverage,
    Foreshortened,
    Reconstruction,
    VisibleLength,
)
from .._objectives.smoothed import Smoothed
from .._placement.placement import (
    AbstractPlacement,
    FreePlacement,
    PolygonBoundary,
    RectangleBoundary,
    Region,
)

__all__ = ["PlacementProblem", "load_problem", "problem_to_json"]


def _polygon(vertices) -> PiecewiseCurve:
    """A closed polygon, its vertices checked in the file's own words."""
    vertices = np.asarray(vertices, float)
    if vertices.ndim != 2 or vertices.shape[1] != 2 or len(vertices) < 3:
        raise ValueError(
            f"vertices must be a list of at least 3 [x, y] points, got shape {vertices.shape}."
        )
    return PiecewiseCurve.polygon(vertices)


# type name -> (class, required fields, optional fields)
CURVES = {
    "bezier": (BezierCurve, ("control_points",), ()),
    "bspline": (BSplineCurve, ("control_points",), ("degree",)),
    "circle": (Circle, ("center", "radius"), ()),
    "ellipse": (Ellipse, ("center", "semi_axes"), ("angle",)),
    "path": (PiecewiseCurve, ("points",), ()),
    "polygon": (_polygon, ("vertices",), ()),
}
PLACEMENTS = {
    "rectangle": (RectangleBoundary, ("center", "width", "height"), ()),
    "polygon": (PolygonBoundary, ("corners",), ()),
    "region": (Region, ("lower", "upper"), ("polygon", "clearance")),
    "free": (FreePlacement, ("lower", "upper"), ()),
}
OBJECTIVES = {
    "foreshortened": (Foreshortened, (), ()),
    "visible_length": (VisibleLength, (), ()),
    "reconstruction": (Reconstruction, ("area",), ("delta",)),
    "coverage": (Coverage, (), ("m",)),
    "smoothed": (Smoothed, ("objective", "width"), ("delta", "nodes")),
}
INTEGER_FIELDS = ("degree", "m", "nodes")


class PlacementProblem(NamedTuple):
    scene: Scene
    placement: AbstractPlacement
    objective: AbstractLocalObjective


def _real(value: Any) -> float | np.ndarray:
    """A field's number as a float, its list of numbers as a float array."""
    array = np.asarray(value, float)
    return float(array) if array.ndim == 0 else array


def _build(entry: Any, kinds: dict, where: str):
    if not isinstance(entry, dict) or "type" not in entry:
        raise ValueError(f'{where} must be an object with a "type" ({", ".join(kinds)}).')
    kind = entry["type"]
    if kind not in kinds:
        raise ValueError(f"{where}: unknown type {kind!r}; expected one of {', '.join(kinds)}.")
    cls, required, optional = kinds[kind]
    missing = [f for f in required if f not in entry]
    unknown = sorted(set(entry) - {"type", *required, *optional})
    if missing or unknown:
        problems = [f"missing {', '.join(missing)}"] if missing else []
        problems += [f"unknown {', '.join(unknown)}"] if unknown else []
        takes = f"a {kind} takes {', '.join(required) or 'no fields'}"
        takes += f" and optionally {', '.join(optional)}" if optional else ""
        raise ValueError(f"{where} ({kind}): {'; '.join(problems)} ({takes}).")
    fields = {k: v for k, v in entry.items() if k != "type"}
    if "objective" in fields:
        fields["objective"] = _objective(fields["objective"], f"{where}.objective")
    try:
        values = {
            k: v if k in (*INTEGER_FIELDS, "objective") else _real(v) for k, v in fields.items()
        }
        return cls(**values)
    except (ValueError, TypeError) as error:
        raise ValueError(f"{where} ({kind}): {error}") from None


def problem_from_dict(data: Any) -> PlacementProblem:
    """A `PlacementProblem` from the JSON form's dictionary."""
    if not isinstance(data, dict):
        raise ValueError('A problem file must hold a JSON object with "curves" and "placement".')
    unknown = sorted(set(data) - {"curves", "room", "placement", "objective"})
    if unknown:
        raise ValueError(
            f"Unknown top-level keys {unknown}; expected curves, room, placement, objective."
        )
    curves = data.get("curves")
    if not isinstance(curves, list) or not curves:
        raise ValueError('"curves" must be a non-empty list of curve objects.')
    room = _build(data["room"], CURVES, "room") if "room" in data else None
    scene = Scene([_build(c, CURVES, f"curves[{i}]") for i, c in enumerate(curves)], room=room)
    if "placement" not in data:
        raise ValueError('The problem needs a "placement" (where cameras may go).')
    placement = _build(data["placement"], PLACEMENTS, "placement")
    objective = _objective(data.get("objective", "foreshortened"), "objective")
    return PlacementProblem(scene, placement, objective)


def _objective(entry: Any, where: str) -> AbstractLocalObjective:
    """An objective from its JSON form (a bare name for one without parameters)."""
    return _build({"type": entry} if isinstance(entry, str) else entry, OBJECTIVES, where)


def load_problem(path: str | pathlib.Path) -> PlacementProblem:
    """Read a problem file (the JSON form above)."""
    path = pathlib.Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"No problem file at {path}.") from None
    except json.JSONDecodeError as error:
        raise ValueError(
            f"{path} is not valid JSON: {error.msg} at line {error.lineno}, column {error.colno}."
        ) from None
    try:
        return problem_from_dict(data)
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None


def _entry(item, kinds: dict) -> dict:
    for kind, (cls, required, optional) in kinds.items():
        if type(item) is cls:
            out = {"type": kind}
            for name in (*required, *optional):
                value = getattr(item, name)
                if isinstance(value, AbstractLocalObjective):
                    out[name] = _entry(value, kinds)
                elif value is not None:
                    out[name] = value if isinstance(value, int) else np.asarray(value).tolist()
            return out
    raise TypeError(f"{type(item).__name__} has no JSON form.")


def problem_to_json(scene: Scene, placement: AbstractPlacement, objective=None) -> str:
    """The JSON form of a problem (the inverse of `load_problem`)."""
    objective = objective if objective is not None else Foreshortened()
    data: dict[str, Any] = {"curves": [_entry(c, CURVES) for c in scene.objects]}
    if scene.room:
        data["room"] = _entry(scene.curves[-1], CURVES)
    data["placement"] = _entry(placement, PLACEMENTS)
    entry = _entry(objective, OBJECTIVES)
    data["objective"] = entry["type"] if len(entry) == 1 else entry
    return _json(data)


def _json(value, indent: str = "") -> str:
    """JSON with one entry per line, and each point or list of numbers on one line."""
    inner = indent + "  "
    if isinstance(value, dict):
        items = [f"{inner}{json.dumps(k)}: {_json(v, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + f"\n{indent}}}"
    if isinstance(value, list) and value and isinstance(value[0], (list, dict)):
        return "[\n" + ",\n".join(inner + _json(v, inner) for v in value) + f"\n{indent}]"
    return json.dumps(value)
