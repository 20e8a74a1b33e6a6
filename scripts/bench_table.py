#!/usr/bin/env python3
"""Print a timing table of the docs, as Markdown, from the committed bench CSVs.

    python3 scripts/bench_table.py --table cylaov|anchors|kernel|formats|python|exr_writer|scaling|verify-sweep [--csv PATH]

`cylaov`, `anchors`, `kernel` (docs/performance.md): the CSVs one `cylaov bench --csv
reference/bench/bench.csv` run writes (`bench.csv`, `bench.kernel.csv`,
`bench.anchors.csv`), together with the figure `reference/figures/bench.png` (`--plot`), so
the tables, the figure and the CSVs always come from one run. `formats`
(docs/performance.md): `reference/bench/batch_formats.csv`, from `cylaov bench
--batch-formats --csv`; `exr_writer` (docs/performance.md): `reference/bench/exr_writer.csv`,
from `cylaov bench --exr-writer --csv`; `scaling` (docs/performance.md):
`reference/bench/scaling.csv`, from `cylaov bench --scaling --csv`. `python` (docs/python.md): `reference/bench/python.csv`, from
`cylaov bench --python --csv`. `verify-sweep` (docs/verification.md):
`reference/bench/verify_sweep.csv`, from `scripts/verify-sweep --csv`. Timings cannot be re-measured in CI: tests/docs.rs checks that
the pages' tables are what this script prints from the committed CSVs. Needs only the
standard library.
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


def sig3(x):
    """Three significant digits, e.g. `0.0582`, `1.25`."""
    return f"{float(x):#.3g}".rstrip(".")


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


# Where each table's CSV is, unless --csv says.
DEFAULT_CSV = {
    "cylaov": "bench.csv",
    "anchors": "bench.csv",
    "kernel": "bench.csv",
    "formats": "batch_formats.csv",
    "python": "python.csv",
    "exr_writer": "exr_writer.csv",
    "scaling": "scaling.csv",
    "verify-sweep": "verify_sweep.csv",
}

# The workloads of `cylaov bench --scaling`, in the table's order.
SCALING = ["render", "batch files", "batch webdataset", "DataLoader"]

# The Python measures, in the order of the table, and how each reads.
PYTHON_ROWS = {
    "views": ("views timed, 320×240 depth + normal, 100 cylinders", count),
    "dataset": ("`Dataset[i]`, views a second", lambda v: count(round(float(v)))),
    "openexr": ("OpenEXR reading the same views' EXRs, views a second", lambda v: count(round(float(v)))),
    "ratio": ("`Dataset[i]` / OpenEXR", lambda v: f"{float(v):.2f}×"),
    "render_16x16_call": ("`render()` on a 16×16 view, ms a call", sig3),
    "render_16x16_rust": ("the same render inside Rust, ms", sig3),
    "render_16x16_overhead": ("the call's overhead, ms", sig3),
}

RENDERER = {"llvm_ad_rgb": "Mitsuba llvm", "scalar_rgb": "Mitsuba scalar", "open3d_embree": "Open3D"}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--table", required=True, choices=list(DEFAULT_CSV))
    ap.add_argument("--csv", help="the table's CSV (default: reference/bench/ as above)")
    a = ap.parse_args()
    base = pathlib.Path(a.csv or ROOT / "reference/bench" / DEFAULT_CSV[a.table])
    sibling = lambda kind: base.with_name(base.stem + f".{kind}.csv")
    out = []
    if a.table == "formats":
        out.append("| format | views | views/s | MiB | MB/s |")
        out.append("|---|--:|--:|--:|--:|")
        for r in rows(base):
            label = r["format"].replace("--no-png", "`--no-png`")
            mb_s = int(r["bytes"]) / float(r["seconds"]) / 1e6
            out.append(
                f"| {label} | {count(r['views'])} | {count(round(float(r['views_per_s'])))} "
                f"| {count(round(int(r['bytes']) / 2**20))} | {count(round(mb_s))} |"
            )
        sys.stdout.write("\n".join(out) + "\n")
        return
    if a.table == "exr_writer":
        out.append("| AOVs | into | size | MiB | from the AOV buffers, ms | from planes, ms | planes / buffers |")
        out.append("|---|---|--:|--:|--:|--:|--:|")
        for r in rows(base):
            aovs = "every AOV" if r["aovs"].count(",") >= 6 else r["aovs"].replace(",", " + ")
            out.append(
                f"| {aovs} | {r['target']} | {r['width']}×{r['height']} "
                f"| {int(r['bytes']) / 2**20:.1f} | {float(r['buffers_ms']):.2f} "
                f"| {float(r['planes_ms']):.2f} | {float(r['speed_ratio']):.2f} |"
            )
        sys.stdout.write("\n".join(out) + "\n")
        return
    if a.table == "scaling":
        got = rows(base)
        present = [w for w in SCALING if any(r["workload"] == w for r in got)]
        head = " | ".join(f"{w}, views/s (efficiency)" for w in present)
        out.append(f"| threads | {head} | webdataset / files |")
        out.append("|--:|" + "--:|" * (len(present) + 1))
        for n in sorted({int(r["threads"]) for r in got}):
            at = {r["workload"]: r for r in got if int(r["threads"]) == n}
            cells = [
                f"{count(round(float(at[w]['views_per_s'])))} ({float(at[w]['efficiency']):.2f})"
                if w in at else "–"
                for w in present
            ]
            tw, fi = at.get("batch webdataset"), at.get("batch files")
            r = f"{float(tw['views_per_s']) / float(fi['views_per_s']):.2f}×" if tw and fi else "–"
            out.append(f"| {n} | " + " | ".join(cells) + f" | {r} |")
        sys.stdout.write("\n".join(out) + "\n")
        return
    if a.table == "verify-sweep":
        out.append(
            "| setting | scenes | views checked | failed | hit pixels judged | reference errors "
            "| proven reference errors | their scripts reproduced | input rounding | unexplained "
            "| candidate errors |"
        )
        out.append("|---|---|--:|--:|--:|--:|--:|--:|--:|--:|--:|")
        for r in rows(base):
            cells = [count(r[k]) for k in ["views", "failed", "hit_pixels_judged",
                                            "reference_errors", "proven_reference_errors"]]
            run = int(r["scripts_run"])
            cells.append(f"{count(r['scripts_reproduced'])} of {count(run)}" if run else "–")
            cells += [count(r[k]) for k in ["input_rounding", "unexplained", "candidate_errors"]]
            out.append(f"| {r['setting']} | `{r['options']}` | " + " | ".join(cells) + " |")
        sys.stdout.write("\n".join(out) + "\n")
        return
    if a.table == "python":
        out.append("| measure | value |")
        out.append("|---|--:|")
        got = {r["measure"]: r["value"] for r in rows(base)}
        for measure, (label, fmt) in PYTHON_ROWS.items():
            out.append(f"| {label} | {fmt(got[measure])} |")
        sys.stdout.write("\n".join(out) + "\n")
        return
    cy = cylaov_rows(base)
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
