#!/usr/bin/env python3
"""Print a timing table of docs/performance.md, as Markdown, from the committed bench CSVs.

    python3 scripts/bench_table.py --table cylaov|anchors|kernel [--csv PATH]

The CSVs are the ones one `cylaov bench --csv reference/bench/bench.csv` run writes
(`bench.csv`, `bench.kernel.csv`, `bench.anchors.csv`), together with the figure
`reference/figures/bench.png` (`--plot`), so the tables, the figure and the CSVs always come
from one run. Timings cannot be re-measured in CI: tests/docs.rs checks that the page's
tables are what this script prints from the committed CSVs. Needs only the standard library.
"""

import argparse
import csv
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parent.parent


def ms(x):
    """Milliseconds with one decimal and a thin-space thousands separator (`1 091.8`)."""
    return f"{float(x):,.1f}".replace(",", " ")


def sec(x):
    return f"{float(x):.3f}"


def ratio(x):
    """Three significant digits, e.g. `98.4×`, `154×`."""
    return f"{x:.1f}×" if x < 100 else f"{x:.0f}×"


def count(n):
    return f"{int(n):,}".replace(",", " ")


def rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def cylaov_rows(base):
    """The default kernel's depth+normal rows, the ones the ratios are taken to."""
    return [
        r
        for r in rows(base)
        if r["kernel"] == "stable-f64" and r["aovs"] == "depth+normal"
    ]


def process_ms(cy, family, n):
    for r in cy:
        if r["family"] == family and r["cylinders"] == n:
            return float(r["process_ms"])
    return None


RENDERER = {"llvm_ad_rgb": "Mitsuba llvm", "scalar_rgb": "Mitsuba scalar", "open3d_embree": "Open3D"}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", required=True, choices=["cylaov", "anchors", "kernel"])
    ap.add_argument("--csv", default=str(ROOT / "reference/bench/bench.csv"))
    a = ap.parse_args()
    base = pathlib.Path(a.csv)
    sibling = lambda kind: base.with_name(base.stem + f".{kind}.csv")
    cy = cylaov_rows(base)
    out = []
    if a.table == "cylaov":
        out.append("| family | cylinders | parse ms | prep ms | build ms | trace ms | write ms | process ms | peak MiB |")
        out.append("|---|--:|--:|--:|--:|--:|--:|--:|--:|")
        for r in cy:
            out.append(
                f"| {r['family']} | {count(r['cylinders'])} | {ms(r['parse_ms'])} | {ms(r['prepare_ms'])} "
                f"| {ms(r['build_ms'])} | {ms(r['trace_ms'])} | {ms(r['write_ms'])} | {ms(r['process_ms'])} "
                f"| {float(r['peak_mib']):.0f} |"
            )
    elif a.table == "anchors":
        out.append("| family | cylinders | renderer | load s | first render s | warm render s | process s | process ratio | warm ratio |")
        out.append("|---|--:|---|--:|--:|--:|--:|--:|--:|")
        for r in rows(sibling("anchors")):
            p = process_ms(cy, r["family"], r["cylinders"]) / 1e3
            out.append(
                f"| {r['family']} | {count(r['cylinders'])} | {RENDERER.get(r['variant'], r['variant'])} "
                f"| {sec(r['load_s'])} | {sec(r['render1_s'])} | {sec(r['render2_s'])} | {sec(r['process_s'])} "
                f"| {ratio(float(r['process_s']) / p)} | {ratio(float(r['render2_s']) / p)} |"
            )
    else:
        out.append("| kernel | form | million ray–cylinder tests a second, one thread |")
        out.append("|---|---|--:|")
        for r in rows(sibling("kernel")):
            out.append(f"| {r['kernel']} | {r['form']} | {float(r['mtests_per_s']):.1f} |")
    sys.stdout.write("\n".join(out) + "\n")


if __name__ == "__main__":
    main()
