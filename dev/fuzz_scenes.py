"""Seeded fuzz with a scene generator unrelated to `ocp.scenes.floor`: objects of random
kind, size, rotation and place (rejected where the Scene refuses them), in a random
convex or star-shaped room or none; point or directional cameras (k = 1-8). Foreshortened
Q under jit with default options against the NumPy reference (tests/reference.py); one
row per seed, FAIL past 1e-7 relative.

    python dev/fuzz_scenes.py 0 40

Seed 38 (two polygons, no room, five cameras: two of them beside one long edge) found
the crossovers that the grid missed near cameras (dev/HISTORY.md, "A missed crossover").
"""

import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
import numpy as np

import ocp_jax as ocp

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from helpers import to_reference
from reference import reference_visibility


def star(rng, c, r, n):
    a = np.sort(rng.uniform(0, 2 * np.pi, n))
    rr = r * rng.uniform(0.4, 1.0, n)
    return np.stack([c[0] + rr * np.cos(a), c[1] + rr * np.sin(a)], 1)


def make_object(rng, c, r):
    kind = rng.integers(8)
    if kind == 0:  # rotated rectangle
        w, h, th = r * rng.uniform(0.2, 1.0), r * rng.uniform(0.1, 0.7), rng.uniform(0, np.pi)
        R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        p = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) @ R.T + c
        return ocp.PiecewiseCurve.polygon(jnp.asarray(p))
    if kind == 1:  # star polygon
        return ocp.PiecewiseCurve.polygon(jnp.asarray(star(rng, c, r, int(rng.integers(3, 12)))))
    if kind == 2:
        return ocp.Circle(jnp.asarray(c), r * rng.uniform(0.2, 1.0))
    if kind == 3:
        return ocp.Ellipse(
            jnp.asarray(c), jnp.asarray(r * rng.uniform(0.1, 1.0, 2)), rng.uniform(0, np.pi)
        )
    if kind == 4:
        return ocp.BSplineCurve(jnp.asarray(star(rng, c, r, int(rng.integers(5, 13)))))
    if kind == 5:
        return ocp.BezierCurve.closed_c2(jnp.asarray(star(rng, c, r, int(rng.integers(3, 7)))))
    if kind == 6:
        w, h = r * rng.uniform(0.5, 1.8, 2)
        return ocp.PiecewiseCurve.rounded_rectangle(
            jnp.asarray(c), w, h, rng.uniform(0.05, 0.45) * min(w, h)
        )
    return ocp.scenes.blob(c, r, int(rng.integers(2**31)), int(rng.integers(5, 12)))


def draw(seed):
    rng = np.random.default_rng(seed)
    size = rng.uniform(6, 20)
    room_kind = rng.integers(3)
    room = None
    if room_kind == 1:  # convex room
        room = ocp.PiecewiseCurve.polygon(jnp.asarray(_convex(rng, size)))
    elif room_kind == 2:
        room = ocp.PiecewiseCurve.polygon(jnp.asarray(_star_room(rng, size)))
    n = int(rng.integers(1, 9))
    objects = []
    tries = 0
    while len(objects) < n and tries < 200:
        tries += 1
        c = rng.uniform(-0.6 * size, 0.6 * size, 2)
        r = rng.uniform(0.3, 0.25 * size)
        obj = make_object(rng, c, r)
        try:
            ocp.Scene(objects + [obj], room=room)
        except ValueError:
            continue
        objects.append(obj)
    if not objects:
        return None
    scene = ocp.Scene(objects, room=room)
    k = int(rng.integers(1, 9))
    clearance = float(rng.choice([0.01, 0.05, 0.3]))
    if room is None:
        low, high = (np.asarray(b) for b in scene.bounds())
        mid, half = (low + high) / 2, (high - low) / 2 + 2.0
        from ocp_jax._visibility.visibility import signed_distances

        found = np.zeros((0, 2))
        while len(found) < k:
            trial = rng.uniform(mid - half, mid + half, (4 * k, 2))
            free = np.all(np.asarray(signed_distances(scene, jnp.asarray(trial))) > clearance, 1)
            found = np.concatenate([found, trial[free]])
        positions = found[:k]
    else:
        positions = np.asarray(ocp.scenes.free_points(scene, k, seed=seed, clearance=clearance))
    poses = None
    cameras = jnp.asarray(positions)
    if rng.uniform() < 0.4:
        heading = rng.uniform(-np.pi, np.pi, k)
        fov = rng.uniform(0.2, 1.5, k)
        reach = rng.uniform(2, 2 * size, k) if rng.uniform() < 0.5 else None
        cameras = ocp.Camera(
            jnp.asarray(positions),
            jnp.asarray(heading),
            jnp.asarray(fov),
            None if reach is None else jnp.asarray(reach),
        )
        poses = [
            {
                "heading": heading[i],
                "half_fov": fov[i],
                "range": None if reach is None else reach[i],
            }
            for i in range(k)
        ]
    return (
        scene,
        cameras,
        positions,
        poses,
        f"room{room_kind} n={len(objects)} k={k} cl={clearance} dir={poses is not None}",
    )


def _convex(rng, size):
    a = np.sort(rng.uniform(0, 2 * np.pi, int(rng.integers(4, 9))))
    while float(np.max(np.diff(np.concatenate([a, [a[0] + 2 * np.pi]])))) > 2.5:
        a = np.sort(rng.uniform(0, 2 * np.pi, len(a)))
    return 1.2 * size * np.stack([np.cos(a), np.sin(a)], 1) / np.cos(np.pi / len(a))


def _star_room(rng, size):
    n = int(rng.integers(5, 14))
    a = 2 * np.pi * (np.arange(n) + rng.uniform(-0.3, 0.3, n)) / n
    r = size * rng.uniform(0.9, 1.6, n)
    return np.stack([r * np.cos(a), r * np.sin(a)], 1)


def main():
    lo, hi = int(sys.argv[1]), int(sys.argv[2])
    fs = ocp.Foreshortened()
    worst = 0.0
    for seed in range(lo, hi):
        try:
            drawn = draw(seed)
        except Exception as e:
            print(seed, "draw failed", type(e).__name__, str(e)[:150], flush=True)
            continue
        if drawn is None:
            continue
        scene, cameras, positions, poses, desc = drawn
        t0 = time.perf_counter()
        try:
            got = float(jax.jit(lambda c: ocp.visibility(scene, c, fs))(cameras))
        except Exception as e:
            print(seed, desc, "RAISED", type(e).__name__, str(e)[:300], flush=True)
            continue
        t1 = time.perf_counter()
        want = reference_visibility(
            to_reference(scene),
            np.asarray(positions),
            "foreshortened",
            poses=poses,
            observed=list(np.asarray(scene.observed())),
        )
        err = abs(got / want - 1) if want else abs(got)
        worst = max(worst, err)
        flag = "  <<<<< FAIL" if err > 1e-7 else ""
        print(
            f"{seed} {desc} Q={got:.10g} ref={want:.10g} err={err:.1e} ({t1 - t0:.0f}s){flag}",
            flush=True,
        )
    print("worst", worst)


if __name__ == "__main__":
    main()
