"""Pictures: rendered headless (Agg) and checked pixel by pixel where it matters."""

import matplotlib

matplotlib.use("Agg")

import jax.numpy as jnp  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402
from test_place import BOX, CIRCLE, SQUARE, TWO_CIRCLES, box_result, square_result  # noqa: E402

import ocp_jax as ocp  # noqa: E402
from ocp_jax import plot  # noqa: E402


def render(ax):
    fig = ax.figure
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3] / 255.0


def colour_at(ax, image, point):
    """The 3 x 3 pixels around a data point (antialiasing blurs a line's edge)."""
    x, y = ax.transData.transform(point)
    row, column = image.shape[0] - int(round(y)), int(round(x))
    return image[row - 1 : row + 2, column - 1 : column + 2].reshape(-1, 3)


def assert_colour(pixels, expected, tol=0.08):
    """Some pixel of the neighbourhood has the expected colour."""
    distance = np.abs(pixels - np.asarray(to_rgb(expected))).max(axis=1)
    assert distance.min() <= tol, f"no pixel near {to_rgb(expected)} among {pixels.round(2)}"


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def test_seen_arcs_are_drawn_where_the_engine_says():
    """A unit circle and cameras at (3, 0) and (0, 3): camera 0 sees the points with
    x > 1/3, camera 1 those with y > 1/3, both the arc between."""
    ax = plot.plot_scene(CIRCLE, jnp.array([[3.0, 0.0], [0.0, 3.0]]))
    image = render(ax)
    assert_colour(colour_at(ax, image, (1.0, 0.0)), plot.CAMERA_COLOURS[0])
    assert_colour(colour_at(ax, image, (0.0, 1.0)), plot.CAMERA_COLOURS[1])
    assert_colour(colour_at(ax, image, (np.sqrt(0.5), np.sqrt(0.5))), plot.SHARED_COLOUR)
    for hidden in ((-1.0, 0.0), (0.0, -1.0), (-np.sqrt(0.5), -np.sqrt(0.5))):
        assert_colour(colour_at(ax, image, hidden), plot.OBJECT_COLOUR)
    # just inside and outside camera 0's tangency point at angle acos(1/3) below the axis
    angle = np.arccos(1 / 3)
    for offset, colour in ((-0.08, plot.CAMERA_COLOURS[0]), (0.08, plot.OBJECT_COLOUR)):
        a = angle + offset
        assert_colour(colour_at(ax, image, (np.cos(a), -np.sin(a))), colour)


def test_events_are_drawn():
    """With events: the tangency points of the camera at (3, 0) on the unit circle are at
    (1/3, +-sqrt(8)/3), marked in the camera's colour on its lines of sight."""
    ax = plot.plot_scene(TWO_CIRCLES, jnp.array([[-5.0, 0.5]]), SQUARE, events=True)
    image = render(ax)
    # a point on the line of sight from the camera to the upper tangency point of the
    # first circle (centre (-1.5, 0), radius 1)
    camera, centre = np.array([-5.0, 0.5]), np.array([-1.5, 0.0])
    rel = centre - camera
    d = np.linalg.norm(rel)
    angle = np.arctan2(rel[1], rel[0]) + np.arcsin(1.0 / d)
    tangent = camera + np.sqrt(d**2 - 1) * np.array([np.cos(angle), np.sin(angle)])
    assert_colour(colour_at(ax, image, 0.5 * (camera + tangent)), plot.CAMERA_COLOURS[0], 0.25)
    assert len(ax.lines) > 5


def not_blank(image):
    return len(np.unique((image * 16).astype(int).reshape(-1, 3), axis=0)) > 8


def test_landscape_along_a_boundary(tmp_path):
    result = square_result()
    ax = plot.plot_landscape(
        TWO_CIRCLES, SQUARE, result.cameras, index=1, result=result, resolution=128
    )
    line = ax.lines[0]
    s, q = line.get_data()
    assert len(s) == 128 and np.nanmax(q) <= float(result.value) + 1e-9
    # the moving camera's best position on the line is the optimiser's value
    assert np.nanmax(q) >= float(result.value) * 0.99
    ax.figure.savefig(tmp_path / "landscape.png")
    assert not_blank(plt.imread(tmp_path / "landscape.png")[..., :3])


def test_landscape_heat_map_and_optimization_paths(tmp_path):
    ax = plot.plot_landscape(
        CIRCLE, BOX, objective=ocp.VisibleLength(), result=box_result(), resolution=24
    )
    ax.figure.savefig(tmp_path / "heat.png")
    assert not_blank(plt.imread(tmp_path / "heat.png")[..., :3])
    ax = plot.plot_optimization(square_result(), TWO_CIRCLES, SQUARE)
    paths = square_result().paths
    assert paths.shape[1:] == (4, 2, 1)
    np.testing.assert_allclose(SQUARE.cameras(paths[-1]), square_result().start_cameras, atol=1e-12)
    # drawn along the walls: every point of every path lies on the rectangle
    points_per_path = 16 * (len(paths) - 1) + 1  # 16 substeps between records
    lines = [line.get_xydata() for line in ax.lines if len(line.get_xydata()) == points_per_path]
    assert len(lines) == 4 * 2  # one per start and camera
    drawn = np.concatenate(lines)
    assert len(drawn) > 100 and float(SQUARE.violation(drawn)) < 1e-9
    ax.figure.savefig(tmp_path / "paths.png")
    assert not_blank(plt.imread(tmp_path / "paths.png")[..., :3])


def test_landscape_stars_the_moving_cameras_optimum():
    result = square_result()
    ax = plot.plot_landscape(TWO_CIRCLES, SQUARE, result.cameras, index=0, result=result)
    stars = [line for line in ax.lines if line.get_marker() == "*"]
    assert len(stars) == 1
    s, q = (float(v[0]) for v in stars[0].get_data())
    assert s == pytest.approx(float(SQUARE.arc_fraction(result.cameras[:1])[0]))
    assert q == pytest.approx(float(result.value))
