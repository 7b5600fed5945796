"""The README's tour runs as written: its Python blocks, in order, in one namespace."""

import pathlib
import re

README = pathlib.Path(__file__).parent.parent / "README.md"


def test_readme_tour_runs_as_written():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), re.S)
    assert len(blocks) == 2  # the tour, then rooms, directional cameras and placement
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, str(README), "exec"), namespace)
    ocp, jnp = namespace["ocp"], namespace["jnp"]
    assert float(namespace["Q"]) > 0 and namespace["Qs"].shape == (3,)
    assert namespace["result"] == ocp.RESULTS.successful
    assert isinstance(namespace["solution"], ocp.Solution)
    assert isinstance(namespace["solution"].cameras, ocp.Camera)
    assert bool(jnp.all(jnp.isfinite(namespace["dcam"].position)))
