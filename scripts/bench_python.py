#!/usr/bin/env python3
"""The Python package against reading files: `Dataset[i]` views per second on 320x240
depth + normal views of 100 cylinders, against reading the same views' EXRs with the
OpenEXR package from a warm page cache; and the call overhead of `render` on a 16x16 view
over its trace. Needs the package installed (`pip install .`) and OpenEXR.

Usage: bench_python.py [--views N] [--repeats R] [--cli PATH] [--json] [--csv PATH]
Prints one line per measure and the ratio; `--json` prints them as one JSON object;
`--csv PATH` also writes them as `measure,value,unit` rows (`cylaov bench --python --csv
reference/bench/python.csv` writes the CSV that docs/python.md's table is printed from, by
scripts/bench_table.py).
"""

import argparse
import csv
import json
import os
import pathlib
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

import cylaov
from cylaov._cylaov import _testing

ROOT = pathlib.Path(__file__).resolve().parents[1]
SETTINGS = {"cylinders": 100, "width": 320, "height": 240}


def best(f, repeats):
    """The fastest of `repeats` runs of `f()`, seconds."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return min(times)


# The CSV's rows: measure, the key of the report, unit.
CSV_ROWS = [
    ("views", "views", "views"),
    ("dataset", "dataset_views_per_s", "views/s"),
    ("openexr", "openexr_views_per_s", "views/s"),
    ("ratio", "ratio", "x"),
    ("render_16x16_call", "render_16x16_call_ms", "ms"),
    ("render_16x16_rust", "render_16x16_rust_ms", "ms"),
    ("render_16x16_overhead", "render_16x16_overhead_ms", "ms"),
]


def write_csv(path, out):
    """The measures as `measure,value,unit`, written to a temporary file then renamed."""
    path = pathlib.Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    with open(tmp, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(["measure", "value", "unit"])
        for measure, key, unit in CSV_ROWS:
            w.writerow([measure, repr(out[key]), unit])
    os.replace(tmp, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cli", default=os.environ.get("CYLAOV_BIN", str(ROOT / "target/release/cylaov")))
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--csv", metavar="PATH")
    args = ap.parse_args()
    import OpenEXR

    n = args.views
    ds = cylaov.Dataset(SETTINGS, seed=0, length=n, aovs=("depth", "normal"))
    tmp = pathlib.Path(tempfile.mkdtemp(prefix="cylaov-bench-python-"))
    try:
        # The same views as files: generate + batch would add PNGs; render each scene.
        (tmp / "generate.json").write_text(json.dumps(SETTINGS))
        for i in range(n):
            path = tmp / f"{i:06d}.json"
            path.write_text(cylaov.generate(SETTINGS, 0, i).to_json())
            subprocess.run([args.cli, "render", str(path), "-o", str(tmp / f"{i:06d}.exr"),
                            "--aov", "depth,normal"], check=True, capture_output=True)
        exrs = [tmp / f"{i:06d}.exr" for i in range(n)]

        def read_all():
            for p in exrs:
                with OpenEXR.File(str(p), separate_channels=True) as f:
                    ch = f.channels()
                    depth = ch["depth"].pixels
                    normal = np.stack([ch[f"normal.{c}"].pixels for c in "XYZ"], axis=-1)
                    assert depth.shape == (240, 320) and normal.shape == (240, 320, 3)

        def render_all():
            for i in range(n):
                ds[i]

        read_all()  # warm the page cache
        t_read = best(read_all, args.repeats)
        t_ds = best(render_all, args.repeats)
        # Per-call overhead: render() on a 16x16 view against the same trace inside Rust.
        tiny = cylaov.Scene.from_dict(dict(json.loads(cylaov.generate(SETTINGS, 0, 0).to_json()),
                                           camera=dict(json.loads(cylaov.generate(SETTINGS, 0, 0).to_json())["camera"], width=16, height=16)))
        calls = 2000
        t_call = best(lambda: [cylaov.render(tiny) for _ in range(calls)], args.repeats) / calls
        t_rust = min(_testing._time_render(tiny, calls) for _ in range(args.repeats))
        rays = cylaov.camera_rays(tiny)
        cam = tiny.cameras[0]
        t_cast = best(lambda: [cylaov._cylaov._cast_rays(tiny, rays[0].reshape(-1, 3), rays[1].reshape(-1, 3),
                                                         np.full(256, cam["near_clip"]), np.full(256, cam["far_clip"]),
                                                         ["t_hit"], "f64", "stable", None) for _ in range(calls)],
                      args.repeats) / calls
        out = {
            "views": n,
            "dataset_views_per_s": n / t_ds,
            "openexr_views_per_s": n / t_read,
            "ratio": t_read / t_ds,
            "render_16x16_call_ms": t_call * 1e3,
            "render_16x16_rust_ms": t_rust * 1e3,
            "render_16x16_overhead_ms": (t_call - t_rust) * 1e3,
            "cast_16x16_call_ms": t_cast * 1e3,
        }
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if args.csv:
        write_csv(args.csv, out)
    if args.json:
        print(json.dumps(out))
        return
    print(f"Dataset[i] (render {n} views 320x240 depth+normal, 100 cylinders): "
          f"{out['dataset_views_per_s']:.0f} views/s ({1e3 / out['dataset_views_per_s']:.3f} ms a view)")
    print(f"OpenEXR reading the same {n} EXRs (warm page cache): "
          f"{out['openexr_views_per_s']:.0f} views/s ({1e3 / out['openexr_views_per_s']:.3f} ms a view)")
    print(f"ratio Dataset / OpenEXR: {out['ratio']:.2f}x (target >= 1.0)")
    print(f"render() on a 16x16 view: {out['render_16x16_call_ms']:.4f} ms a call, "
          f"{out['render_16x16_rust_ms']:.4f} ms of it the render in Rust: overhead "
          f"{out['render_16x16_overhead_ms']:.4f} ms (target <= 0.2) "
          f"(cast_rays of its 256 pixel rays: {out['cast_16x16_call_ms']:.4f} ms)")
    if args.csv:
        print(f"wrote {args.csv}")


if __name__ == "__main__":
    sys.exit(main())
