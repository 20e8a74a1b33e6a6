"""Time Open3D's ray caster (Embree) on a cylaov scene, for `cylaov bench --open3d`.

usage: bench_open3d.py SCENE.json OUT.npy [RAYS.npy]

The anchor of how fast a general triangle ray tracer is on the same scene: each cylinder
becomes a 16-segment triangle mesh (32 side triangles, and 32 cap triangles when capped),
built with numpy in one go; all go into one `open3d.t.geometry.RaycastingScene`, and one
ray per pixel comes from `RaycastingScene.create_rays_pinhole` with the scene's camera
(its field of view taken as Open3D's `fov_deg`: a timing anchor, not an image to compare).
`cast_rays` returns the hit distance and the triangle normal, as depth + normal.

Prints one JSON line: seconds for `import open3d` (import_s), building the meshes and
adding them (load_s), the first `cast_rays` (render1_s: Embree builds its BVH here),
saving the distances with numpy (write_s), and a second, warm `cast_rays` (render2_s).
The whole process time is measured by the caller around this process.

With RAYS.npy ((N, 6) float32: origin, unit direction), those rays are cast instead of the
camera's: `cylaov bench --scan` times a LiDAR rotation's beams (first hits) this way.
"""
import json
import sys
import time

t0 = time.perf_counter()
import numpy as np  # noqa: E402
import open3d as o3d  # noqa: E402

SEGMENTS = 16

scene_path, out = sys.argv[1], sys.argv[2]
t1 = time.perf_counter()
with open(scene_path) as f:
    scene = json.load(f)
cyl = scene["cylinders"]
p0 = np.array([c["p0"] for c in cyl], dtype=np.float64)
p1 = np.array([c["p1"] for c in cyl], dtype=np.float64)
r = np.array([c["radius"] for c in cyl], dtype=np.float64)
caps = np.array([c.get("caps", True) for c in cyl], dtype=bool)
n = len(cyl)

# An orthonormal frame (u, v) around each axis.
axis = p1 - p0
axis /= np.linalg.norm(axis, axis=1)[:, None]
helper = np.where(np.abs(axis[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
u = np.cross(axis, helper)
u /= np.linalg.norm(u, axis=1)[:, None]
v = np.cross(axis, u)
ang = 2 * np.pi * np.arange(SEGMENTS) / SEGMENTS
ring = np.cos(ang)[None, :, None] * u[:, None, :] + np.sin(ang)[None, :, None] * v[:, None, :]
ring *= r[:, None, None]
# Per cylinder: 16 bottom ring, 16 top ring, bottom centre, top centre.
verts = np.concatenate(
    [p0[:, None, :] + ring, p1[:, None, :] + ring, p0[:, None, :], p1[:, None, :]], axis=1
)
k = np.arange(SEGMENTS)
k1 = (k + 1) % SEGMENTS
side = np.concatenate([np.stack([k, k1, SEGMENTS + k], 1), np.stack([k1, SEGMENTS + k1, SEGMENTS + k], 1)])
cap = np.concatenate(
    [np.stack([np.full(SEGMENTS, 2 * SEGMENTS), k1, k], 1),
     np.stack([np.full(SEGMENTS, 2 * SEGMENTS + 1), SEGMENTS + k, SEGMENTS + k1], 1)]
)
base = (np.arange(n) * (2 * SEGMENTS + 2))[:, None, None]
tris = [(side[None] + base).reshape(-1, 3)]
if caps.any():
    tris.append((cap[None] + base[caps]).reshape(-1, 3))
tris = np.concatenate(tris)
rs = o3d.t.geometry.RaycastingScene()
rs.add_triangles(
    o3d.core.Tensor(verts.reshape(-1, 3).astype(np.float32)),
    o3d.core.Tensor(tris.astype(np.uint32)),
)
cam = scene["camera"]
rays = o3d.core.Tensor(np.load(sys.argv[3])) if len(sys.argv) > 3 else o3d.t.geometry.RaycastingScene.create_rays_pinhole(
    fov_deg=float(cam["fov_deg"]),
    center=cam["target"],
    eye=cam["origin"],
    up=cam["up"],
    width_px=int(cam["width"]),
    height_px=int(cam["height"]),
)
t2 = time.perf_counter()
ans = rs.cast_rays(rays)
t_hit = ans["t_hit"].numpy()
ans["primitive_normals"].numpy()
t3 = time.perf_counter()
np.save(out, t_hit)
t4 = time.perf_counter()
ans = rs.cast_rays(rays)
ans["t_hit"].numpy()
ans["primitive_normals"].numpy()
t5 = time.perf_counter()
print(json.dumps({
    "variant": "open3d_embree",
    "import_s": t1 - t0,
    "load_s": t2 - t1,
    "render1_s": t3 - t2,
    "write_s": t4 - t3,
    "render2_s": t5 - t4,
    "hits": int(np.isfinite(t_hit).sum()),
}))
