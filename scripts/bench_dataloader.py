#!/usr/bin/env python3
"""Views a second of the package's `Dataset` through a PyTorch `DataLoader`, beside the same
views rendered in one process. The `DataLoader` is what a user writes: `--workers N` worker
processes (`threads=1` each, so N workers use N cores), batches of `--batch-size` views
collated by PyTorch's default collation into tensors, depth + normal. The workers start in
an untimed first pass over a few batches and stay (`persistent_workers`), so a timed pass
measures rendering and handing batches over, not process start. The reference renders the
same views in this process, `Dataset.__getitems__` a batch on a pool of N threads, with no
collation: what the workers' cores could give with nothing to hand over. The two alternate,
`--repeats` passes each, and each reports its fastest pass, so a load that comes and goes
(other jobs on the machine) weighs on both alike. `--plain-items` hands the `DataLoader` the
same items as plain dicts, which PyTorch's default collation copies into a fresh
shared-memory block a tensor: what a dataset of plain dicts gets, for comparison.

Usage: bench_dataloader.py --views V --workers N [--seed S] [--cylinders C] [--width W]
       [--height H] [--batch-size B] [--repeats R] [--plain-items]
Prints the reference, the DataLoader and their ratio, then `VIEWS SECONDS` of the
DataLoader's fastest pass on its last line (`cylaov bench --scaling` runs it).
"""

import argparse
import itertools
import time

import torch

import cylaov


class PlainItems(cylaov.Dataset):
    """The items as plain dicts: default collation stacks their arrays afresh."""

    def __getitems__(self, indices):
        return [dict(item) for item in super().__getitems__(indices)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--views", type=int, required=True)
    ap.add_argument("--workers", type=int, required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cylinders", type=int, default=100)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--batch-size", type=int, default=32)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--plain-items", action="store_true")
    a = ap.parse_args()
    settings = {"cylinders": a.cylinders, "width": a.width, "height": a.height}
    ds = (PlainItems if a.plain_items else cylaov.Dataset)(settings, seed=a.seed, length=a.views, aovs=("depth", "normal"),
                        threads=1)
    one = cylaov.Dataset(settings, seed=a.seed, length=a.views, aovs=("depth", "normal"),
                         threads=max(a.workers, 1))
    batches = [range(s, min(a.views, s + a.batch_size)) for s in range(0, a.views, a.batch_size)]
    loader = torch.utils.data.DataLoader(ds, batch_size=a.batch_size, num_workers=a.workers,
                                         persistent_workers=a.workers > 0)
    for _ in itertools.islice(iter(loader), 2):
        pass
    one.__getitems__(batches[0])
    best_one, best_loader, views = float("inf"), float("inf"), 0
    for _ in range(max(a.repeats, 1)):
        t = time.perf_counter()
        for b in batches:
            one.__getitems__(b)
        best_one = min(best_one, time.perf_counter() - t)
        views = 0
        t = time.perf_counter()
        for batch in loader:
            views += batch["depth"].shape[0]
        best_loader = min(best_loader, time.perf_counter() - t)
    one_rate, loader_rate = a.views / best_one, views / best_loader
    print(f"one process, {max(a.workers, 1)} threads: {one_rate:.1f} views/s")
    what = "plain-dict items" if a.plain_items else "items"
    print(f"DataLoader, {a.workers} workers, {what}: {loader_rate:.1f} views/s, "
          f"{loader_rate / one_rate:.2f}x the one process")
    print(f"{views} {best_loader:.6f}")


if __name__ == "__main__":
    main()
