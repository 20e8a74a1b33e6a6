"""`cast_rays`: on the camera's own rays it is the EXR's distance bit for bit; on any rays
from any origins it is the double-double oracle's nearest hit."""

import numpy as np
import pytest

import cylaov
from cylaov._cylaov import _testing
from conftest import SCENES


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_camera_rays_give_the_render_distance(path):
    scene = cylaov.Scene.load(path)
    cam = scene.cameras[0]
    want = cylaov.render(scene, aovs=("distance", "normal", "shape_id", "part"))
    o, d = cylaov.camera_rays(scene)
    assert o.shape == d.shape == (cam["height"], cam["width"], 3) and d.dtype == np.float64
    got = cylaov.cast_rays(scene, o, d, t_min=cam["near_clip"], t_max=cam["far_clip"])
    hit = np.isfinite(got["t_hit"])
    assert np.array_equal(hit, want["mask"])
    dist = np.where(hit, got["t_hit"] * np.linalg.norm(d, axis=-1), 0).astype(np.float32)
    assert np.array_equal(dist.view(np.uint32), want["distance"].view(np.uint32))
    assert np.array_equal(got["normal"].astype(np.float32).view(np.uint32), want["normal"].view(np.uint32))
    assert np.array_equal(got["shape_id"], want["shape_id"])
    assert np.array_equal(got["part"], want["part"])
    # The directions' camera-space z is 1: t_hit is planar depth.
    depth = cylaov.render(scene, aovs=("depth",))["depth"]
    assert np.allclose(got["t_hit"][hit], depth[hit], rtol=1e-6)


def random_rays(scene_path, n, seed):
    rng = np.random.default_rng(seed)
    scene = cylaov.Scene.load(scene_path)
    import json

    cyl = json.loads(scene.to_json())["cylinders"]
    p0 = np.array([c["p0"] for c in cyl])
    p1 = np.array([c["p1"] for c in cyl])
    lo, hi = np.minimum(p0, p1).min(0) - 1, np.maximum(p0, p1).max(0) + 1
    origins = rng.uniform(lo, hi, size=(n, 3))
    k = rng.integers(0, len(cyl), size=n)
    aim = p0[k] + (p1[k] - p0[k]) * rng.uniform(0, 1, size=(n, 1))
    dirs = (aim - origins) * rng.uniform(0.1, 10, size=(n, 1))
    return scene, origins, dirs


@pytest.mark.parametrize("name", ["cluster", "mixed_caps", "tube_inside", "asymmetric"])
def test_random_rays_from_random_origins_match_the_oracle(name):
    path = next(p for p in SCENES if p.stem == name)
    scene, origins, dirs = random_rays(path, 400, 7)
    got = cylaov.cast_rays(scene, origins, dirs, aovs=("t_hit", "shape_id"))
    t_or, index = _testing._oracle_cast(scene, origins.tolist(), dirs.tolist())
    t_or = np.array(t_or)
    hit = np.isfinite(t_or)
    assert hit.sum() > 200, hit.sum()
    assert np.array_equal(np.isfinite(got["t_hit"]), hit)
    rel = np.abs(got["t_hit"][hit] - t_or[hit]) / t_or[hit]
    assert rel.max() < 1e-9, rel.max()
    # The same rays from one shared origin (one prepared scene, through the BVH).
    one = np.broadcast_to(origins[0], origins.shape)
    got1 = cylaov.cast_rays(scene, origins[0], dirs)
    t1, _ = _testing._oracle_cast(scene, one.tolist(), dirs.tolist())
    t1 = np.array(t1)
    assert np.array_equal(np.isfinite(got1["t_hit"]), np.isfinite(t1))
    f = np.isfinite(t1)
    assert np.max(np.abs(got1["t_hit"][f] - t1[f]) / t1[f]) < 1e-9


def test_shapes_units_and_misses():
    scene = cylaov.Scene.from_dict({
        "camera": {"origin": [5, 0, 0.5], "target": [0, 0, 0.5], "up": [0, 0, 1], "fov_deg": 40,
                   "width": 8, "height": 6},
        "cylinders": [{"p0": [0, 0, 0], "p1": [0, 0, 1], "radius": 0.5, "id": 7}],
    })
    # A ray along -x from x = 3 meets the side at x = 0.5: t = 2.5 / |d|.
    o = np.array([[3.0, 0, 0.5], [3.0, 0, 0.5], [3.0, 0, 5]])
    d = np.array([[-1.0, 0, 0], [-4.0, 0, 0], [-1.0, 0, 0]])
    r = cylaov.cast_rays(scene, o, d, aovs=("t_hit", "normal", "shape_id", "part", "position"))
    assert r["t_hit"][0] == 2.5 and r["t_hit"][1] == 0.625 and r["t_hit"][2] == np.inf
    assert r["normal"][0].tolist() == [1.0, 0.0, 0.0] and r["normal"][2].tolist() == [0, 0, 0]
    assert r["shape_id"].tolist() == [7, 7, 0] and r["part"].tolist() == [1, 1, 0]
    assert r["shape_id"].dtype == np.uint32
    assert r["position"][1].tolist() == [0.5, 0.0, 0.5]
    # From inside the tube: the inner face (part 2), and t_max cuts the hit off.
    inside = cylaov.cast_rays(scene, [0, 0, 0.5], [[1.0, 0, 0]], t_max=[0.4])
    assert inside["t_hit"][0] == np.inf
    inside = cylaov.cast_rays(scene, [0, 0, 0.5], [[1.0, 0, 0]])
    assert inside["t_hit"][0] == 0.5 and inside["part"][0] == 2
    grid = cylaov.cast_rays(scene, [3, 0, 0.5], np.tile([-1.0, 0, 0], (4, 5, 1)))
    assert grid["t_hit"].shape == (4, 5) and grid["normal"].shape == (4, 5, 3)
    with pytest.raises(ValueError, match=r"rays\[1\]\.direction: must be finite and non-zero"):
        cylaov.cast_rays(scene, o[:2], [[1.0, 0, 0], [0, 0, 0]])
    with pytest.raises(ValueError, match=r"rays\[0\]\.t_min"):
        cylaov.cast_rays(scene, o[:1], d[:1], t_min=-1)
    with pytest.raises(ValueError, match=r"shape must be \(\.\.\., 3\)"):
        cylaov.cast_rays(scene, o, d[:, :2])


def test_many_rays_give_the_bits_of_few_and_name_a_bad_ray_by_its_index():
    """A hit does not depend on which rays share the call: 600 000 rays from three origins
    taking turns hit as the same rays cast origin by origin, 1 000 at a time, and one
    origin given once as given per ray. A bad ray is named by its index among all."""
    scene = cylaov.Scene.load(SCENES[0])
    rng = np.random.default_rng(5)
    n = 600_000
    starts = rng.uniform(-3, 3, (3, 3))
    origins = np.tile(starts, (n // 3, 1))
    dirs = rng.normal(size=(n, 3))
    aovs = ("t_hit", "normal", "shape_id", "part", "position", "position_error")
    got = cylaov.cast_rays(scene, origins, dirs, aovs=aovs, t_max=40.0)
    assert np.isfinite(got["t_hit"]).sum() > 1000
    for k in range(3):
        for at in (0, 123_456, 199_000):
            ids = np.arange(3 * at + k, 3 * (at + 1000) + k, 3)
            want = cylaov.cast_rays(scene, starts[k], dirs[ids], aovs=aovs, t_max=40.0)
            for a in aovs:
                assert want[a].tobytes() == got[a][ids].tobytes(), (k, at, a)
    # One origin for all of them: the same bits as the origin given per ray.
    one = cylaov.cast_rays(scene, starts[1], dirs, aovs=("t_hit",), t_max=40.0)
    per = cylaov.cast_rays(scene, np.tile(starts[1], (n, 1)), dirs, aovs=("t_hit",), t_max=40.0)
    assert one["t_hit"].tobytes() == per["t_hit"].tobytes()
    dirs[599_998] = 0.0
    for o in (origins, starts[2]):
        with pytest.raises(ValueError, match=r"^rays\[599998\]\.direction: must be finite"):
            cylaov.cast_rays(scene, o, dirs)


# `cast_rays` reads only the cylinders; a scene needs a camera all the same.
_CAMERA = {"origin": [5, 0, 0.5], "target": [0, 0, 0.5], "up": [0, 0, 1], "fov_deg": 40,
           "width": 8, "height": 6}


def test_spawned_rays_leave_their_surface_and_find_the_far_wall():
    """From hits on 200 random closed cylinders (radius and height 1e-2..1e2, up to 1e6
    from the origin), rays into the outward hemisphere started by ``spawn_rays`` never
    re-hit the cylinder, and rays into the inward one find its far wall (the oracle's exit
    from the spawned origin, within half its distance): 20 each way per hit, half of them
    within 1e-3..1e-10 rad of the tangent plane, half of the directions unnormalised."""
    rng = np.random.default_rng(3)
    checked = 0
    for _ in range(200):
        p0 = rng.normal(size=3) * 10.0 ** rng.uniform(0, 6)
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        h, r = 10.0 ** rng.uniform(-2, 2, size=2)
        scene = cylaov.Scene.from_arrays(p0[None], (p0 + h * axis)[None], [r], camera=_CAMERA)
        side = np.cross(axis, rng.normal(size=3))
        side /= np.linalg.norm(side)
        aim = p0 + axis * h * rng.uniform(0.05, 0.95) + side * r
        origin = aim + side * r * 10.0 ** rng.uniform(-1, 3) + rng.normal(size=3) * r
        want = ("t_hit", "normal", "position", "position_error", "shape_id")
        hit = cylaov.cast_rays(scene, origin, (aim - origin) * 10.0 ** rng.uniform(-3, 3), aovs=want)
        if not np.isfinite(hit["t_hit"]):
            continue
        n = hit["normal"]
        assert np.all(hit["position_error"] > 0) and np.all(hit["position_error"] < 1e-6 * (r + h + np.abs(p0).max()))
        dirs = []
        for sign in (1.0, -1.0):
            w = rng.normal(size=(20, 3))
            w -= np.outer(w @ n, n)  # tangent
            w /= np.linalg.norm(w, axis=1)[:, None]
            tilt = np.where(np.arange(20) % 2 == 0, rng.uniform(0.05, 1, 20), 10.0 ** rng.uniform(-10, -3, 20))
            w = w + sign * tilt[:, None] * n
            w *= np.where(np.arange(20) % 4 < 2, 1.0, 10.0 ** rng.uniform(-3, 3, 20))[:, None]
            dirs.append(w)
        dirs = np.concatenate(dirs)
        hits = {k: np.broadcast_to(v, (40,) + v.shape) for k, v in hit.items()}
        o2 = cylaov.spawn_rays(hits, dirs)
        assert o2.shape == (40, 3) and np.all(np.isfinite(o2))
        again = cylaov.cast_rays(scene, o2, dirs)
        assert np.all(np.isinf(again["t_hit"][:20])), again["t_hit"][:20]
        t_o, _ = _testing._oracle_cast(scene, o2[20:].tolist(), dirs[20:].tolist())
        t_o = np.array(t_o)
        assert np.all(np.isfinite(t_o))
        assert np.all(np.abs(again["t_hit"][20:] - t_o) <= 0.5 * t_o), (again["t_hit"][20:], t_o)
        checked += 1
    assert checked > 150


def test_spawn_rays_needs_the_error_and_marks_misses():
    scene = cylaov.Scene.from_arrays([[0.0, 0, 0]], [[0.0, 0, 1]], [0.5], camera=_CAMERA)
    d = np.array([[-1.0, 0, 0], [1.0, 0, 0]])
    o = np.array([[3.0, 0, 0.5], [3.0, 0, 0.5]])
    r = cylaov.cast_rays(scene, o, d, aovs=("t_hit", "normal", "position", "position_error"))
    assert r["position"][0].tolist() == [0.5, 0.0, 0.5]
    assert r["position_error"][1].tolist() == [0, 0, 0]
    out = cylaov.spawn_rays(r, [[1.0, 0, 0], [1.0, 0, 0]])
    # Outward along +x: one float at least past the box, y and z (normal 0 there) as they were.
    assert out[0, 0] > 0.5 + r["position_error"][0, 0] and out[0, 1:].tolist() == [0.0, 0.5]
    assert np.all(np.isnan(out[1]))
    inward = cylaov.spawn_rays(r, [-1.0, 0, 0])
    assert inward[0, 0] < 0.5 - r["position_error"][0, 0]
    with pytest.raises(ValueError, match="position_error"):
        cylaov.spawn_rays({"position": r["position"], "normal": r["normal"]}, d)


LENS_MODELS = {
    "opencv": {"model": "opencv", "fx": 40, "fy": 42, "cx": 31.2, "cy": 23.7,
               "k1": -0.21, "k2": 0.04, "p1": 0.0012, "p2": -0.0017, "k3": 0.005},
    "opencv_fisheye": {"model": "opencv_fisheye", "fx": 18, "fy": 18.5, "cx": 31.6, "cy": 23.4,
                       "k1": 0.03, "k2": -0.004, "k3": 0.0006, "k4": -0.00003},
    "equirectangular": {"model": "equirectangular"},
}


@pytest.mark.parametrize("model", sorted(LENS_MODELS))
def test_lens_camera_rays_give_the_render(model, tmp_path):
    """A lens model's `camera_rays` are its own rays: cast with the clips, they see what the
    render sees, at its distance (to float32 rounding of t · |d|)."""
    import json
    import math

    cyl = [{"p0": [0, 0, -4], "p1": [0, 0, 4], "radius": 6, "id": 100}]
    for k in range(12):
        a = 2 * math.pi * k / 12
        cyl.append({"p0": [3 * math.cos(a), 3 * math.sin(a), -1.5 + 0.1 * k],
                    "p1": [3 * math.cos(a), 3 * math.sin(a), 1.0 + 0.1 * k],
                    "radius": 0.35 + 0.03 * k, "id": k + 1})
    cam = {"origin": [0.2, -0.4, 0.3], "target": [1.0, 3.0, 0.0], "up": [0, 0, 1],
           "width": 64, "height": 48, "near_clip": 0.01, **LENS_MODELS[model]}
    path = tmp_path / "lens.json"
    path.write_text(json.dumps({"camera": cam, "cylinders": cyl}))
    scene = cylaov.Scene.load(path)
    want = cylaov.render(scene, aovs=("distance", "shape_id", "part"))
    o, d = cylaov.camera_rays(scene)
    got = cylaov.cast_rays(scene, o, d, t_min=0.01, t_max=scene.cameras[0]["far_clip"])
    hit = np.isfinite(got["t_hit"])
    assert np.array_equal(hit, want["mask"])
    assert np.array_equal(got["shape_id"], want["shape_id"])
    assert np.array_equal(got["part"], want["part"])
    dist = got["t_hit"][hit] * np.linalg.norm(d, axis=-1)[hit]
    rel = np.abs(dist - want["distance"][hit]) / want["distance"][hit]
    # Measured: at most one float32 rounding (6e-8) apart.
    assert rel.max() < 1.2e-7, rel.max()
