#!/usr/bin/env python3
"""Print the table of agreement with Mitsuba 3.9.1 (scalar_rgb) in docs/verification.md, as Markdown.

    python3 scripts/agreement_table.py [--cylaov PATH]

For every scenes/*.json (not scenes/stress/, whose reference is the oracle) it renders the
scene with cylaov's stable kernel in f64 and in f32 (distance, depth, normal, shape_id,
part), compares each render with the committed reference/<stem>.exr through
`cylaov compare --scene --json` (the rule of `cylaov verify`: identity is cylinder and part),
and prints one row per scene: the maximum relative distance and depth error and normal
angle over the pixels where both hit the same part of the same cylinder (f64 / f32), the
f64 normal angle's p99, and the mismatched pixels (f64 / f32; all on silhouettes or
part seams, or `cylaov compare` would fail). The last line gives the largest median
and p99 of the relative distance error over all scenes.

Deterministic: cylaov renders the same bits on every machine and the references are
committed, so the output changes only when the kernels, the comparison or a reference
does; tests/docs.rs fails when the page's copy drifts from it. Needs only the
standard library (no Mitsuba: the references are already rendered).
"""

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile

ROOT = pathlib.Path(__file__).resolve().parent.parent
AOVS = ["distance", "depth", "normal", "shape_id", "part"]


def sci(x):
    """2 significant digits, `4.2e-6` (no padded exponent)."""
    m, e = f"{x:.1e}".split("e")
    return f"{m}e{int(e)}"


def deg(x):
    """2 significant digits in plain notation, e.g. 0.0029, 0.031, 0.00002 (one digit below 1e-4)."""
    if x == 0:
        return "0"
    digits = max(0, 1 - int(f"{x:e}".split("e")[1]))
    return f"{x:.{digits}f}"


def compare(cylaov, scene, precision, work):
    exr = work / f"{scene.stem}-{precision}.exr"
    args = [cylaov, "render", str(scene), "-o", str(exr), "--precision", precision]
    for a in AOVS:
        args += ["--aov", a]
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL)
    ref = ROOT / "reference" / f"{scene.stem}.exr"
    out = subprocess.run(
        [cylaov, "compare", str(exr), str(ref), "--scene", str(scene), "--json"],
        stdout=subprocess.PIPE,
        check=False,
    )
    if out.returncode not in (0, 1):
        sys.exit(f"agreement_table: cylaov compare failed on {scene.name}")
    return json.loads(out.stdout)["report"]


def mismatches(r):
    parts = []
    if r["silhouette_mismatches"]:
        parts.append(f"{r['silhouette_mismatches']} on silhouettes")
    if r["seams"]:
        parts.append(f"{r['seams']} seam pixel{'s' if r['seams'] > 1 else ''}")
    return ", ".join(parts) or "0"


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cylaov", default=str(ROOT / "target" / "release" / "cylaov"))
    cylaov = p.parse_args().cylaov
    scenes = sorted((ROOT / "scenes").glob("*.json"))
    print("| scene | rel distance | rel depth | normal ° | normal ° p99 | mismatched pixels |")
    print("|---|--:|--:|--:|--:|---|")
    medians, p99s = [], []
    with tempfile.TemporaryDirectory(prefix="cylaov-agreement-") as work:
        work = pathlib.Path(work)
        for scene in scenes:
            f64 = compare(cylaov, scene, "f64", work)
            f32 = compare(cylaov, scene, "f32", work)
            pair = lambda key: f"{sci(f64[key]['all']['max'])} / {sci(f32[key]['all']['max'])}"
            normal = f"{deg(f64['normal_deg']['all']['max'])} / {deg(f32['normal_deg']['all']['max'])}"
            for r in (f64, f32):
                medians.append(r["rel_distance"]["all"]["median"])
                p99s.append(r["rel_distance"]["all"]["p99"])
            print(
                f"| {scene.stem} | {pair('rel_distance')} | {pair('rel_depth')} | {normal} "
                f"| {deg(f64['normal_deg']['all']['p99'])} | {mismatches(f64)} / {mismatches(f32)} |"
            )
    print()
    print(
        f"Over all {len(scenes)} scenes and both precisions the median relative distance error is at "
        f"most {sci(max(medians))} and the p99 at most {sci(max(p99s))}."
    )


if __name__ == "__main__":
    main()
