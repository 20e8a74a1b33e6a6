"""Time Mitsuba 3 on an exported scene, for `cylaov bench --mitsuba`.

usage: bench_mitsuba.py SCENE.xml OUT.exr VARIANT [--once]

Prints one JSON line: seconds for import (+ set_variant), load_file, the first render()
(JIT included for llvm variants), writing the EXR, and a second (warm) render(); with
--once (for scalar variants, which have nothing to warm up) the second render is skipped and
reported as equal to the first. The whole
process time (Python start, load, render, write) is measured by the caller around this
process; it subtracts `render2` to get the cold process cost.
"""
import json
import sys
import time

t0 = time.perf_counter()
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

xml, out, variant = sys.argv[1], sys.argv[2], sys.argv[3]
once = "--once" in sys.argv[4:]
mi.set_variant(variant)
t1 = time.perf_counter()
scene = mi.load_file(xml)
t2 = time.perf_counter()
img = mi.render(scene)
dr.eval(img)
dr.sync_thread()
t3 = time.perf_counter()
mi.Bitmap(img).write(out)
t4 = time.perf_counter()
if not once:
    img2 = mi.render(scene)
    dr.eval(img2)
    dr.sync_thread()
t5 = time.perf_counter()
print(json.dumps({
    "variant": variant,
    "import_s": t1 - t0,
    "load_s": t2 - t1,
    "render1_s": t3 - t2,
    "write_s": t4 - t3,
    "render2_s": (t3 - t2) if once else (t5 - t4),
}))
