#!/usr/bin/env python3
"""Render the Mitsuba 3 reference AOVs of a cylaov scene.

Usage: mitsuba_reference.py SCENE.xml SCENE.json OUT.exr [SENSOR] [--aov uv]

SCENE.xml comes from `cylaov export-mitsuba SCENE.json`; SCENE.json gives the camera for
the depth conversion. SENSOR (default 0) picks the camera of a scene with several
(`"cameras"`): the export writes one sensor per camera, in file order. Renders with the `scalar_rgb` variant of mitsuba 3.9.1 (there the
cylinder quadratic is solved in float64, and the render is deterministic) and writes OUT.exr
(float32, lossless PIZ) with cylaov's channel names:

  distance    = Mitsuba depth + near_clip / cos(theta)   (Mitsuba's ray starts on the near
                plane; theta = angle between the pixel ray and the view direction; 0 for
                the orthographic camera, whose rays start on the near plane too and are
                measured from the image plane through the camera origin, as cylaov does)
  depth       = distance * cos(theta)                    (planar depth)
  normal.X/Y/Z, position.X/Y/Z  = Mitsuba sh_normal and position
  shape_id    = our cylinder id of Mitsuba's shape_index (float32; 0 = miss)
  part        = which part of it was hit (float32; 0 = miss): 1 side seen from outside,
                2 side seen from inside (normal . ray > 0: the wall's inner face),
                3 bottom cap (at p0), 4 top cap (at p1)

The shape_index -> (shape_id, part) map is read from the loaded scene itself: every exported
shape has the XML id `c<file index>_id<shape_id>_<side|bottom|top>` (see
src/output/format/mitsuba.rs), and Mitsuba's shape_index is 1 + the shape's position in
`scene.shapes()`. Side, bottom and top are separate Mitsuba shapes, so the part is exact;
only the side's facing is computed, from Mitsuba's outward normal and the pixel ray.

--aov uv adds Mitsuba's `uv` AOV as uv.U, uv.V (0 on a miss): the integrator of the
loaded scene gets `uv:uv` after the exported list (the XML file is not changed). On a side,
u = angle / 2pi in [0, 1) in the frame Mitsuba builds from p0 to p1, v = axial fraction;
the caps are Mitsuba disks, whose uv is their own (cylaov compares side pixels).

cos(theta) and the pixel ray come from the pixel-centre ray built exactly as cylaov's camera
(src/scene/camera.rs) builds it, in float64 (`"model": "orthographic"`: every ray along the
view direction, cos(theta) = 1). Every channel of a missed pixel is 0.
"""

import json
import os
import re
import sys

import numpy as np

import mitsuba as mi

CHANNELS = [
    "distance",
    "depth",
    "normal.X",
    "normal.Y",
    "normal.Z",
    "position.X",
    "position.Y",
    "position.Z",
    "shape_id",
    "part",
]
MITSUBA_AOVS = ["dd.y.T", "nn.X", "nn.Y", "nn.Z", "pp.X", "pp.Y", "pp.Z", "ii.I"]
AOVS_RE = re.compile(r'(<string name="aovs" value=")([^"]*)(")')
SHAPE_ID_RE = re.compile(r"^c(\d+)_id(\d+)_(side|bottom|top)$")
# The part AOV of each exported shape kind (the side's 1 becomes 2 when seen from inside).
PART = {"side": 1, "bottom": 3, "top": 4}


def fail(msg):
    print(f"mitsuba_reference.py: error: {msg}", file=sys.stderr)
    sys.exit(1)


def normalize(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def pixel_rays(cam):
    """Unit pixel-centre ray directions (H, W, 3) and their cos to `forward` (H, W), float64."""
    origin = np.array(cam["origin"], dtype=np.float64)
    target = np.array(cam["target"], dtype=np.float64)
    up = np.array(cam["up"], dtype=np.float64)
    w, h = int(cam["width"]), int(cam["height"])
    forward = normalize(target - origin)
    model = cam.get("model", "perspective")
    if model == "orthographic":
        # Parallel rays: every pixel looks along `forward`.
        d = np.broadcast_to(forward, (h, w, 3)).copy()
        return d, np.ones((h, w))
    if model != "perspective":
        fail(f"camera.model: Mitsuba has no {model!r} camera")
    left = normalize(np.cross(up, forward))
    true_up = np.cross(forward, left)
    aspect = w / h
    t = np.tan(np.radians(float(cam["fov_deg"])) / 2.0)
    axis = cam.get("fov_axis", "x")
    # Half width at unit distance: Mitsuba converts every fov_axis to an x fov.
    if axis == "x":
        tan_x = t
    elif axis == "y":
        tan_x = t * aspect
    elif axis == "diagonal":
        tan_x = t * aspect / np.sqrt(1.0 + aspect * aspect)
    elif axis == "smaller":
        tan_x = t * aspect if aspect > 1.0 else t
    elif axis == "larger":
        tan_x = t if aspect > 1.0 else t * aspect
    else:
        fail(f"camera.fov_axis: unknown value {axis!r}")
    tan_y = tan_x / aspect
    x = ((np.arange(w, dtype=np.float64) + 0.5) / w) * 2.0 - 1.0
    y = 1.0 - ((np.arange(h, dtype=np.float64) + 0.5) / h) * 2.0
    d = (
        forward[None, None, :]
        - left[None, None, :] * (x[None, :, None] * tan_x)
        + true_up[None, None, :] * (y[:, None, None] * tan_y)
    )
    d = normalize(d)
    return d, d @ forward


def shape_lut(scene):
    """ids[shape_index] = our shape_id, parts[shape_index] = its part; index 0 = miss."""
    lut = [0]
    parts = [0]
    last_cyl = -1
    for k, shape in enumerate(scene.shapes()):
        m = SHAPE_ID_RE.match(shape.id())
        if not m:
            fail(f"shape {k} has id {shape.id()!r}: not exported by cylaov export-mitsuba")
        cyl = int(m.group(1))
        if cyl < last_cyl:
            fail(f"shape {k} ({shape.id()}) out of export order: Mitsuba reordered shapes")
        last_cyl = cyl
        lut.append(int(m.group(2)))
        parts.append(PART[m.group(3)])
    return np.array(lut, dtype=np.float64), np.array(parts, dtype=np.float64)


def main(argv):
    argv = list(argv)
    extra = []
    while "--aov" in argv:
        i = argv.index("--aov")
        if argv[i + 1:i + 2] != ["uv"]:
            fail("--aov: only uv is rendered on request (every other AOV always is)")
        extra.append("uv")
        del argv[i:i + 2]
    if len(argv) not in (4, 5):
        fail("usage: mitsuba_reference.py SCENE.xml SCENE.json OUT.exr [SENSOR] [--aov uv]")
    xml_path, json_path, out_path = argv[1:4]
    try:
        sensor = int(argv[4]) if len(argv) == 5 else 0
    except ValueError:
        fail(f"SENSOR: expected a camera index (0, 1, ...), got {argv[4]!r}")
    try:
        with open(json_path) as f:
            doc = json.load(f)
        cams = doc["cameras"] if "cameras" in doc else [doc["camera"]]
        if not isinstance(cams, list):
            fail(f"{json_path}: \"cameras\" is a camera rig ({', '.join(map(str, cams))}), not a "
                 "list: give the script a scene whose cameras are listed (`cylaov verify` "
                 "expands a rig itself)")
        if not 0 <= sensor < len(cams):
            fail(f"SENSOR: {json_path} has {len(cams)} camera(s), got {sensor}")
        cam = cams[sensor]
    except (OSError, ValueError, KeyError, TypeError) as e:
        fail(f"{json_path}: cannot read the camera: {e}")
    near = float(cam.get("near_clip", 0.01))
    if not os.path.isfile(xml_path):
        fail(f"{xml_path}: no such file")

    mi.set_variant("scalar_rgb")
    if extra:
        with open(xml_path) as f:
            xml = f.read()
        xml, n = AOVS_RE.subn(lambda m: m.group(1) + m.group(2) + ",uv:uv" + m.group(3), xml)
        if n != 1:
            fail(f"{xml_path}: no aov integrator list to add uv to")
        scene = mi.load_string(xml)
    else:
        scene = mi.load_file(xml_path)
    if len(scene.sensors()) != len(cams):
        fail(f"{xml_path}: {len(scene.sensors())} sensors, {json_path} has {len(cams)} cameras")
    film = scene.sensors()[sensor].film()
    size = tuple(film.size())
    if size != (int(cam["width"]), int(cam["height"])):
        fail(f"{xml_path}: film {size} differs from {json_path} camera size")
    img = np.array(mi.render(scene, sensor=sensor), dtype=np.float32)
    want = MITSUBA_AOVS + (["uv.U", "uv.V"] if extra else [])
    if img.shape[2] != len(want):
        fail(f"expected {len(want)} AOV channels {want}, got {img.shape[2]}")

    t = img[..., 0].astype(np.float64)
    index = img[..., 7]
    lut, parts = shape_lut(scene)
    if not (np.all(index == np.round(index)) and index.min() >= 0 and index.max() < len(lut)):
        fail(f"shape_index outside 0..{len(lut) - 1}")
    hit = index > 0
    rays, cos = pixel_rays(cam)
    distance = np.where(hit, t + near / cos, 0.0)
    depth = distance * cos

    channels = CHANNELS + (["uv.U", "uv.V"] if extra else [])
    out = np.zeros(img.shape[:2] + (len(channels),), dtype=np.float32)
    out[..., 0] = distance
    out[..., 1] = depth
    out[..., 2:8] = np.where(hit[..., None], img[..., 1:7], 0.0)
    out[..., 8] = lut[index.astype(np.int64)]
    part = parts[index.astype(np.int64)]
    facing = np.sum(img[..., 1:4].astype(np.float64) * rays, axis=-1)
    part = np.where((part == 1) & (facing > 0.0), 2.0, part)
    out[..., 9] = part
    if extra:
        out[..., 10:12] = np.where(hit[..., None], img[..., 8:10], 0.0)

    bitmap = mi.Bitmap(out, mi.Bitmap.PixelFormat.MultiChannel, channel_names=channels)
    out_dir = os.path.dirname(os.path.abspath(out_path))
    os.makedirs(out_dir, exist_ok=True)
    tmp = os.path.join(out_dir, f".{os.path.basename(out_path)}.{os.getpid()}.tmp")
    try:
        # quality -1: lossless PIZ compression.
        bitmap.write(tmp, mi.Bitmap.FileFormat.OpenEXR)
        os.replace(tmp, out_path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    print(f"{out_path}: {size[0]}x{size[1]}, {int(hit.sum())} hits, {len(lut) - 1} shapes")


if __name__ == "__main__":
    main(sys.argv)
