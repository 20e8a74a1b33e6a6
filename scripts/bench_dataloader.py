#!/usr/bin/env python3
"""Views a second of the package's `Dataset` through a PyTorch `DataLoader`: `--workers N`
worker processes (`threads=1` each, so N workers use N cores), batches of `--batch-size`
views collated by PyTorch's default collation into tensors, depth + normal. The workers
start in an untimed first pass over a few batches and stay (`persistent_workers`), so the
timed pass over all views measures rendering and handing batches over, not process start.

Usage: bench_dataloader.py --views V --workers N [--seed S] [--cylinders C] [--width W]
       [--height H] [--batch-size B]
Prints `VIEWS SECONDS` on its last line (`cylaov bench --scaling` runs it).
"""

import argparse
import itertools
import time

import torch

import cylaov


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, required=True)
    ap.add_argument("--workers", type=int, required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cylinders", type=int, default=100)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--batch-size", type=int, default=32)
    a = ap.parse_args()
    settings = {"cylinders": a.cylinders, "width": a.width, "height": a.height}
    ds = cylaov.Dataset(settings, seed=a.seed, length=a.views, aovs=("depth", "normal"),
                        threads=1)
    loader = torch.utils.data.DataLoader(ds, batch_size=a.batch_size, num_workers=a.workers,
                                         persistent_workers=True)
    for _ in itertools.islice(iter(loader), 2):
        pass
    views = 0
    t = time.perf_counter()
    for batch in loader:
        views += batch["depth"].shape[0]
    seconds = time.perf_counter() - t
    print(f"{views} {seconds:.6f}")


if __name__ == "__main__":
    main()
