#!/usr/bin/env python3
"""Back-project one cylaov view into a world-space point cloud (numpy only).

    python3 scripts/backproject.py OUT/000042.exr [--out points.npy | points.ply]

Reads `NAME.exr` (its `depth` channel: planar depth, camera-space z, 0 = miss) and
`NAME.camera.json` beside it (written by `cylaov render` and `cylaov batch`), and maps pixel
(i, j) to the world point

    p_cam   = depth * ((i + 0.5 - cx) / fl_x, (j + 0.5 - cy) / fl_y, 1)   # OpenCV axes
    p_world = camera_to_world_opencv @ (p_cam, 1)

(pixel centres at i + 0.5; cx = W/2, cy = H/2). Prints the point count; `--out` saves the
points as an N x 3 float64 `.npy`, or an ASCII `.ply` that Open3D, MeshLab and Blender open.

EXR reading: numpy has no EXR reader, and the usual choices (`OpenEXR`, `imageio` with a
plugin, Mitsuba's `Bitmap`) are extra installs that may not be there where the dataset is
used. cylaov writes single-part scanline EXRs, so this script reads them itself with numpy
and the standard library's zlib: compression none, ZIP and ZIPS (cylaov's `--compression
none|zip|zips`); PIZ and RLE files need the `OpenEXR` package instead.
"""

import argparse
import json
import struct
import zlib
from pathlib import Path

import numpy as np

_TYPES = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}
_LINES_PER_CHUNK = {0: 1, 2: 1, 3: 16}  # none, ZIPS, ZIP


def read_exr(path):
    """All channels of a single-part scanline EXR as {name: (H, W) array}."""
    data = Path(path).read_bytes()
    if data[:4] != b"\x76\x2f\x31\x01":
        raise ValueError(f"{path}: not an OpenEXR file")
    flags = struct.unpack_from("<I", data, 4)[0]
    if flags & 0x1200:
        raise ValueError(f"{path}: tiled or multi-part EXR: use the OpenEXR package")
    pos, attrs = 8, {}
    while data[pos] != 0:
        end = data.index(b"\0", pos)
        name = data[pos:end].decode()
        tend = data.index(b"\0", end + 1)
        size = struct.unpack_from("<i", data, tend + 1)[0]
        attrs[name] = data[tend + 5 : tend + 5 + size]
        pos = tend + 5 + size
    pos += 1  # end of header
    channels, raw, k = [], attrs["channels"], 0
    while raw[k] != 0:
        end = raw.index(b"\0", k)
        ptype = struct.unpack_from("<i", raw, end + 1)[0]
        channels.append((raw[k:end].decode(), _TYPES[ptype]))
        k = end + 17
    compression = attrs["compression"][0]
    if compression not in _LINES_PER_CHUNK:
        raise ValueError(f"{path}: EXR compression {compression} needs the OpenEXR package")
    x0, y0, x1, y1 = struct.unpack("<4i", attrs["dataWindow"])
    width, height = x1 - x0 + 1, y1 - y0 + 1
    lines = _LINES_PER_CHUNK[compression]
    chunks = -(-height // lines)
    offsets = struct.unpack_from(f"<{chunks}Q", data, pos)
    out = {name: np.zeros((height, width), dt) for name, dt in channels}
    for off in offsets:
        y, size = struct.unpack_from("<ii", data, off)
        block = data[off + 8 : off + 8 + size]
        n = min(lines, y1 + 1 - y)
        expected = n * width * sum(dt.itemsize for _, dt in channels)
        if compression != 0 and size < expected:  # stored raw when ZIP would not shrink it
            t = np.frombuffer(zlib.decompress(block), np.uint8).astype(np.int64)
            t[1:] -= 128
            t = (np.cumsum(t) & 0xFF).astype(np.uint8)
            half = (len(t) + 1) // 2
            block = np.empty_like(t)
            block[0::2], block[1::2] = t[:half], t[half:]
            block = block.tobytes()
        p = 0
        for row in range(y - y0, y - y0 + n):
            for name, dt in channels:
                out[name][row] = np.frombuffer(block, dt, width, p)
                p += width * dt.itemsize
    return out


def backproject(exr_path, camera_path=None):
    """World points (N x 3) of the hit pixels, and their (row, column) indices."""
    exr_path = Path(exr_path)
    if camera_path is None:
        camera_path = exr_path.with_name(exr_path.name[: -len(".exr")] + ".camera.json")
    cam = json.loads(Path(camera_path).read_text())
    depth = read_exr(exr_path)["depth"].astype(np.float64)
    rows, cols = np.nonzero(depth > 0)
    z = depth[rows, cols]
    p_cam = np.stack(
        [z * (cols + 0.5 - cam["cx"]) / cam["fl_x"], z * (rows + 0.5 - cam["cy"]) / cam["fl_y"], z],
        axis=1,
    )
    m = np.array(cam["camera_to_world_opencv"], dtype=np.float64)
    return p_cam @ m[:3, :3].T + m[:3, 3], (rows, cols)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("exr", help="a view's EXR (with a depth channel)")
    ap.add_argument("--camera", help="its camera JSON (default: NAME.camera.json beside it)")
    ap.add_argument("--out", help="save the points: .npy (N x 3 float64) or .ply (ASCII)")
    args = ap.parse_args()
    points, _ = backproject(args.exr, args.camera)
    if args.out:
        if args.out.endswith(".ply"):
            header = f"ply\nformat ascii 1.0\nelement vertex {len(points)}\n"
            header += "property double x\nproperty double y\nproperty double z\nend_header"
            np.savetxt(args.out, points, fmt="%.17g", header=header, comments="")
        else:
            np.save(args.out, points)
    print(f"{len(points)} points" + (f" -> {args.out}" if args.out else ""))


if __name__ == "__main__":
    main()
