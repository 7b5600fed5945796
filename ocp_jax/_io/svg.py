"""Scenes from SVG files: every closed path or shape becomes a `PiecewiseCurve`.

The file is read with `svgelements`, which applies the transforms, turns rectangles,
circles, ellipses, polygons into paths, and approximates elliptical arcs by cubic
Bezier segments. Lines, quadratic and cubic Bezier segments are taken exactly.
"""

import io
import pathlib

import jax.numpy as jnp
import numpy as np
import svgelements

from .._geometry.curves import PiecewiseCurve
from .._geometry.scene import Scene

__all__ = ["load_svg"]


def _segments(subpath, flip: float, name: str) -> list[np.ndarray]:
    """The Bezier control points of one subpath's segments (a closing line included)."""

    def xy(point):
        return [float(point.x), flip * float(point.y)]

    out = []
    for seg in subpath:
        if isinstance(seg, svgelements.Move):
            continue
        if isinstance(seg, svgelements.Line):
            out.append([xy(seg.start), xy(seg.end)])
        elif isinstance(seg, svgelements.QuadraticBezier):
            out.append([xy(seg.start), xy(seg.control), xy(seg.end)])
        elif isinstance(seg, svgelements.CubicBezier):
            out.append([xy(seg.start), xy(seg.control1), xy(seg.control2), xy(seg.end)])
        elif isinstance(seg, svgelements.Close):
            if seg.start is not None and seg.end is not None and seg.start != seg.end:
                out.append([xy(seg.start), xy(seg.end)])
        else:  # pragma: no cover (arcs are approximated before)
            raise ValueError(f"{name}: unsupported SVG segment {type(seg).__name__}.")
    segments = [np.array(s) for s in out if np.ptp(np.array(s), axis=0).max() > 0]
    if not segments:
        raise ValueError(f"{name}: an empty path.")
    return segments


def load_svg(source: str | pathlib.Path, *, room: str | None = None, flip_y: bool = True) -> Scene:
    """A `Scene` from the closed paths and shapes of an SVG file.

    **Arguments:**

    - `source`: a file name, or the SVG text itself.
    - `room`: the id of the element that is the room (its inside is the free space; see
      `Scene`), or None.
    - `flip_y`: negate y, so that the scene looks as the SVG is drawn (SVG's y axis
      points down).

    **Returns:** a Scene with one `PiecewiseCurve` per closed subpath, in document
    order (the room, if any, last).

    Raises ValueError for an open path, an empty file, or a `room` id that is missing.
    """
    text = str(source)
    stream = io.StringIO(text) if text.lstrip().startswith("<") else text
    document = svgelements.SVG.parse(stream)
    flip = -1.0 if flip_y else 1.0
    objects, walls = [], None
    for element in document.elements():
        if not isinstance(element, svgelements.Shape):
            continue
        name = f"SVG {type(element).__name__.lower()} {element.id or ''}".rstrip()
        path = svgelements.Path(element)
        path.reify()
        path.approximate_arcs_with_cubics()
        for subpath in path.as_subpaths():
            if not any(not isinstance(s, svgelements.Move) for s in subpath):
                continue
            segments = _segments(subpath, flip, name)
            try:  # from_segments checks that the path is closed
                curve = PiecewiseCurve.from_segments([jnp.asarray(s) for s in segments])
            except ValueError as error:
                raise ValueError(
                    f"{name}: {error} Only closed paths are objects: close it with 'Z'."
                ) from None
            if room is not None and element.id == room:
                if walls is not None:
                    raise ValueError(f"The room {room!r} must be one closed path.")
                walls = curve
            else:
                objects.append(curve)
    if room is not None and walls is None:
        raise ValueError(f"No closed path with id {room!r} (the room) in the SVG.")
    if not objects:
        raise ValueError("The SVG holds no closed paths or shapes.")
    return Scene(objects, room=walls)
