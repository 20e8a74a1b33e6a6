#!/usr/bin/env python3
"""Render a cylaov dataset's tar shards as Ray tasks: one task per tar shard.

    python scripts/ray_batch.py INPUT --out DIR [--shard-size N] [--aov A,B] [--members exr,depth.png]

Each task calls ``cylaov.write_shards(INPUT, DIR, shards=[j], ...)``, the code behind
``cylaov batch INPUT --out DIR --format webdataset``, so the shards are byte for byte those
of one ``batch`` process; the task that writes the last shard also writes DIR/shards.json.
Re-running resumes: a shard whose sidecar vouches for it is skipped.

With RAY_ADDRESS set the tasks go to that cluster (every worker needs the ``cylaov``
package and INPUT and DIR on a shared file system); else a local Ray is started with two
CPUs. Exit 1 when any view failed (each is listed in DIR/failures.tar-00000J.jsonl).
"""

import argparse
import os
import sys

import ray

import cylaov


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("input", help="folder of scene files, or a .jsonl manifest")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--shard-size", type=int, default=1000, help="views per tar (1000)")
    p.add_argument("--aov", default=None, help="AOVs, comma-separated (default: the scenes')")
    p.add_argument("--members", default="", help="extra members: exr,depth.png")
    p.add_argument("--precision", default="f64", choices=("f64", "f32"))
    p.add_argument("--formula", default="stable", choices=("stable", "literal"))
    p.add_argument("--depth-scale", type=float, default=1000.0)
    p.add_argument("--threads", type=int, default=1, help="threads per task (1)")
    a = p.parse_args(argv)
    options = dict(
        shard_size=a.shard_size,
        aovs=a.aov.split(",") if a.aov else None,
        members=[m for m in a.members.split(",") if m],
        precision=a.precision,
        formula=a.formula,
        depth_scale=a.depth_scale,
        threads=a.threads,
    )
    inp, out = os.path.abspath(a.input), os.path.abspath(a.out)
    count = cylaov.shard_count(inp, a.shard_size)
    if os.environ.get("RAY_ADDRESS"):
        ray.init()
    else:
        ray.init(num_cpus=2, include_dashboard=False, object_store_memory=200_000_000)

    @ray.remote(num_cpus=a.threads)
    def shard(j):
        return cylaov.write_shards(inp, out, shards=[j], **options)

    results = ray.get([shard.remote(j) for j in range(count)])
    failed = [f for r in results for f in r["failed"]]
    written = sum(len(r["written"]) for r in results)
    indexed = any(r["index_written"] for r in results)
    print(f"ray_batch: {written} of {count} tars written, {count - written} skipped; "
          f"{len(failed)} views failed; shards.json {'written' if indexed else 'NOT written'}")
    for key, error in failed:
        print(f"  {key}: {error}", file=sys.stderr)
    return 1 if failed or not indexed else 0


if __name__ == "__main__":
    sys.exit(main())
