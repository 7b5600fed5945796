"""The program the dev tools study: value+grad of Foreshortened Q with respect to the
cameras, under `jax.jit`, with budgets fitted to the scene (`ocp.fit_options`), on a
random floor (`ocp.scenes.floor`) or a built-in scene, at seeded free camera points."""

import jax

jax.config.update("jax_enable_x64", True)

import ocp_jax as ocp


def value_and_grad_program(scene_name: str, cells: int, cameras: int, seed: int):
    """(the jitted value+grad, its cameras (k, 2), the scene) for `scene_name` 'floor'
    (of `cells` grid cells, half as many objects) or a built-in scene's function name."""
    if scene_name == "floor":
        scene = ocp.scenes.floor(seed, cells, max(1, cells // 2), jagged=1.0)
    else:
        scene = getattr(ocp.scenes, scene_name)()
    positions = ocp.scenes.free_points(scene, cameras, seed)
    objective = ocp.Foreshortened()
    options = ocp.fit_options(scene, positions, objective)
    fn = jax.jit(jax.value_and_grad(lambda c: ocp.visibility(scene, c, objective, options)))
    return fn, positions, scene
