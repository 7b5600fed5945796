"""The JSON problem form and the `ocp-jax` command line."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import ocp_jax as ocp
from ocp_jax import scenes
from ocp_jax._io import cli as _cli
from ocp_jax._io.problem_file import load_problem, problem_to_json

# the problem of tests/test_place.py (shares its compiled optimiser)
PROBLEM = {
    "curves": [
        {"type": "circle", "center": [-1.5, 0.0], "radius": 1.0},
        {"type": "circle", "center": [1.8, 0.6], "radius": 0.7},
    ],
    "placement": {"type": "rectangle", "center": [0.5, 0.0], "width": 10.0, "height": 8.0},
    "objective": "foreshortened",
}


def write(tmp_path, data, name="problem.json"):
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def test_round_trip_of_every_kind(tmp_path):
    scene = ocp.Scene(
        [
            scenes.banana().curves[0],
            ocp.BSplineCurve(jnp.array([[0.0, 0], [1, 0], [1, 1], [0, 1]]), degree=2),
            ocp.Circle(jnp.array([3.0, 3.0]), 0.5),
            ocp.Ellipse(jnp.array([-3.0, 3.0]), jnp.array([1.0, 0.4]), 0.3),
        ]
    )
    placements = [
        ocp.RectangleBoundary(jnp.array([0.0, 20.0]), 100.0, 80.0),
        ocp.PolygonBoundary(jnp.array([[-9.0, -9], [9, -9], [0, 9]])),
        ocp.Region(jnp.array([-9.0, -9]), jnp.array([9.0, 9]), clearance=0.5),
        ocp.Region(
            jnp.array([-9.0, -9]), jnp.array([9.0, 9]), jnp.array([[-9.0, -9], [9, -9], [0, 9]])
        ),
        ocp.FreePlacement(jnp.array([-9.0, -9]), jnp.array([9.0, 9])),
    ]
    for placement, objective in zip(placements, [ocp.VisibleLength(), ocp.Foreshortened()] * 3):
        path = write(tmp_path, problem_to_json(scene, placement, objective))
        loaded = load_problem(path)
        assert type(loaded.objective) is type(objective)
        assert type(loaded.placement) is type(placement)
        for a, b in zip(jax_leaves(loaded.scene), jax_leaves(scene)):
            np.testing.assert_array_equal(a, b)
        for a, b in zip(jax_leaves(loaded.placement), jax_leaves(placement)):
            np.testing.assert_array_equal(a, b)
        assert loaded.scene.curves[1].degree == 2


def jax_leaves(tree):
    return [np.asarray(x) for x in jax.tree.leaves(tree)]


@pytest.mark.parametrize(
    "data,match",
    [
        ("{not json", r"is not valid JSON: .* line 1, column 2"),
        ([1, 2], "must hold a JSON object"),
        ({"curves": [], "placement": {}}, "non-empty list of curve objects"),
        ({"curves": [{"type": "spline"}], "placement": {}}, r"curves\[0\]: unknown type 'spline'"),
        (
            {"curves": [{"type": "circle", "center": [0, 0]}], "placement": {}},
            r"curves\[0\] \(circle\): missing radius \(a circle takes center, radius\)",
        ),
        (
            {
                "curves": [{"type": "circle", "center": [0, 0], "radius": 1, "colour": 2}],
                "placement": {},
            },
            r"unknown colour",
        ),
        (
            {
                "curves": [{"type": "bezier", "control_points": [[0, 0], [1, 0], [1, 1], [0, 1]]}],
                "placement": {},
            },
            r"curves\[0\] \(bezier\): BezierCurve must be closed",
        ),
        ({"curves": PROBLEM["curves"]}, 'needs a "placement"'),
        (
            {
                **PROBLEM,
                "placement": {"type": "rectangle", "center": [0, 0], "width": -1, "height": 1},
            },
            r"placement \(rectangle\): .*width and height must be positive",
        ),
        ({**PROBLEM, "objective": "area"}, "objective: unknown type 'area'"),
        (
            {**PROBLEM, "objective": {"type": "smoothed", "width": 0.1}},
            r"objective \(smoothed\): missing objective \(",
        ),
        (
            {**PROBLEM, "objective": {"type": "smoothed", "objective": "fs", "width": 0.1}},
            "objective.objective: unknown type 'fs'",
        ),
        (
            {**PROBLEM, "objective": {"type": "coverage", "m": 0}},
            r"objective \(coverage\): Coverage.m must be a positive int",
        ),
        ({**PROBLEM, "cameras": 2}, r"Unknown top-level keys \['cameras'\]"),
    ],
)
def test_malformed_files_are_explained(tmp_path, data, match):
    with pytest.raises(ValueError, match=match):
        load_problem(write(tmp_path, data))


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="No problem file at"):
        load_problem(tmp_path / "nowhere.json")


def run_cli(path, capsys, starts: int, steps: int):
    """`ocp-jax optimize` with 2 cameras: what it prints, the Q it prints, and the Q the
    library gives for the same problem and settings (the CLI prints 6 decimals)."""
    _cli.main(
        [
            "optimize",
            str(path),
            "--cameras",
            "2",
            "--starts",
            str(starts),
            "--max-steps",
            str(steps),
        ]
    )
    out = capsys.readouterr().out
    problem = load_problem(path)
    solver = ocp.MultiStart(n_starts=starts, max_steps=steps)
    expected = ocp.place(problem.scene, problem.objective, problem.placement, 2, solver=solver)
    value = float(out.split("Q = ")[1].split()[0])
    assert value == pytest.approx(float(expected.value), abs=5e-7)
    return out, value


def test_cli_optimize(tmp_path, capsys):
    out, value = run_cli(write(tmp_path, PROBLEM), capsys, 4, 60)
    assert "2 curve(s), RectangleBoundary, Foreshortened" in out
    # tests/test_place.py finds the same optimum from other starts
    assert value == pytest.approx(4.7047495, abs=1e-6)


def test_objectives_round_trip(tmp_path):
    """Every objective with parameters, a smoothed one nested, through the JSON form."""
    scene = ocp.Scene([ocp.Circle(jnp.zeros(2), 1.0)])
    placement = ocp.RectangleBoundary(jnp.zeros(2), 8.0, 8.0)
    objectives = [
        ocp.Reconstruction(area=0.05, delta=0.02),
        ocp.Coverage(3),
        ocp.Smoothed(ocp.Reconstruction(area=0.1), 0.05, delta=0.2, nodes=64),
        ocp.Smoothed(ocp.VisibleLength(), 0.1),
    ]
    for objective in objectives:
        loaded = load_problem(write(tmp_path, problem_to_json(scene, placement, objective)))
        assert jax.tree.structure(loaded.objective) == jax.tree.structure(objective)
        for a, b in zip(jax_leaves(loaded.objective), jax_leaves(objective)):
            np.testing.assert_array_equal(a, b)
    with pytest.raises(TypeError, match="LocalObjective has no JSON form"):
        problem_to_json(scene, placement, ocp.LocalObjective(lambda x, t, c: 1.0))


def test_cli_optimize_reconstruction(tmp_path, capsys):
    """The command line takes an objective of camera pairs from the file, and says
    clearly when there are too few cameras for it."""
    objective = {"type": "reconstruction", "area": 0.05, "delta": 0.05}
    path = write(tmp_path, {**PROBLEM, "objective": objective})
    out, value = run_cli(path, capsys, 2, 20)
    assert "2 curve(s), RectangleBoundary, Reconstruction" in out and value > 0
    with pytest.raises(SystemExit, match="Reconstruction values groups of 2 cameras"):
        _cli.main(["optimize", str(path), "--cameras", "1"])


def test_cli_reports_bad_files(tmp_path):
    """One line naming the cause, in the file's own words, and no traceback."""
    with pytest.raises(SystemExit, match="is not valid JSON"):
        _cli.main(["optimize", str(write(tmp_path, "{"))])
    with pytest.raises(SystemExit):
        _cli.main(["optimize", str(write(tmp_path, PROBLEM)), "--cameras", "0"])
    two_vertices = {**PROBLEM, "curves": [{"type": "polygon", "vertices": [[0, 0], [1, 0]]}]}
    with pytest.raises(SystemExit) as error:
        _cli.main(["optimize", str(write(tmp_path, two_vertices))])
    message = str(error.value)
    assert "curves[0] (polygon): vertices must be a list of at least 3 [x, y] points" in message
    assert "\n" not in message and "control points" not in message
    no_radius = {**PROBLEM, "curves": [{"type": "circle", "center": [0, 0]}]}
    with pytest.raises(SystemExit, match=r"curves\[0\] \(circle\): missing radius \("):
        _cli.main(["optimize", str(write(tmp_path, no_radius))])
    with pytest.raises(ValueError, match="vertices must be a list"):  # --debug: the error
        _cli.main(["--debug", "optimize", str(write(tmp_path, two_vertices))])


def test_cli_infeasible_placement_is_one_line(tmp_path):
    inside = {**PROBLEM, "placement": {"type": "free", "lower": [-1.6, -0.1], "upper": [-1.4, 0.1]}}
    with pytest.raises(SystemExit, match="every start is infeasible") as error:
        _cli.main(["optimize", str(write(tmp_path, inside)), "--starts", "2"])
    assert "\n" not in str(error.value) and "more starts" not in str(error.value)


def test_cli_without_a_command_prints_help(capsys):
    _cli.main([])
    assert "usage: ocp-jax" in capsys.readouterr().out


def test_cli_example_is_a_loadable_problem(tmp_path, capsys):
    _cli.main(["example"])
    text = capsys.readouterr().out
    assert "[4.0, 31.8]," in text  # float64, one point per line
    loaded = load_problem(write(tmp_path, text))
    assert loaded.scene.curves[0].degree == 18


def test_cli_compilation_cache_follows_xdg(tmp_path, monkeypatch):
    """The cache directory: OCP_JAX_CACHE_DIR, else $XDG_CACHE_HOME/ocp_jax/jax;
    "off" turns it off. (The settings are restored: the suite runs without a cache.)"""
    saved = {
        name: getattr(jax.config, name)
        for name in (
            "jax_compilation_cache_dir",
            "jax_persistent_cache_min_compile_time_secs",
            "jax_persistent_cache_min_entry_size_bytes",
        )
    }
    try:
        monkeypatch.delenv("OCP_JAX_CACHE_DIR")
        monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
        assert _cli.compilation_cache(None) == tmp_path / "xdg" / "ocp_jax" / "jax"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path / "xdg" / "ocp_jax" / "jax")
        monkeypatch.setenv("OCP_JAX_CACHE_DIR", str(tmp_path / "mine"))
        assert _cli.compilation_cache(None) == tmp_path / "mine"
        assert _cli.compilation_cache(str(tmp_path / "flag")) == tmp_path / "flag"
        monkeypatch.setenv("OCP_JAX_CACHE_DIR", "off")
        assert _cli.compilation_cache(None) is None
    finally:
        for name, value in saved.items():
            jax.config.update(name, value)
