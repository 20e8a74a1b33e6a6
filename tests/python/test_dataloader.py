"""`Dataset` through PyTorch's `DataLoader`: each batch is, bit for bit, PyTorch's default
collation of the items `ds[i]`, whether the batch was made in this process or in forked or
spawned workers (which hand it over as one reused shared-memory buffer), including batches
that are kept while later ones are made, and items changed before collation."""

import numpy as np
import pytest

import cylaov
from conftest import need

SETTINGS = {"cylinders": "20..40", "width": 48, "height": 32}
AOVS = ("depth", "normal", "shape_id")
LENGTH = 21


def _same(want, got, path="batch"):
    """Equal structure, types, dtypes, shapes and bits."""
    torch = need("torch")
    assert type(got) is type(want), (path, type(want), type(got))
    if isinstance(want, dict):
        assert list(got) == list(want), path
        for k in want:
            _same(want[k], got[k], f"{path}[{k!r}]")
    elif isinstance(want, list):
        assert len(got) == len(want), path
        for i, (w, g) in enumerate(zip(want, got)):
            _same(w, g, f"{path}[{i}]")
    elif isinstance(want, torch.Tensor):
        assert (got.dtype, got.shape) == (want.dtype, want.shape), path
        if want.dtype == torch.uint32:  # no comparison kernels for uint32 in torch
            want, got = want.view(torch.int32), got.view(torch.int32)
        assert torch.equal(got, want), path
    else:
        assert got == want, path


def _expected(ds, indices):
    torch = need("torch")
    return torch.utils.data.default_collate([ds[i] for i in indices])


@pytest.mark.parametrize("workers,method", [(0, None), (2, "fork"), (2, "spawn")])
def test_batches_are_the_default_collation_of_the_items(workers, method):
    torch = need("torch")
    ds = cylaov.Dataset(SETTINGS, seed=3, length=LENGTH, aovs=AOVS, threads=1)
    loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=workers,
                                         multiprocessing_context=method,
                                         persistent_workers=workers > 0)
    for epoch in range(2):
        # Kept: a later batch must not land in a buffer that an earlier one still uses.
        kept = list(loader)
        assert [len(b["depth"]) for b in kept] == [4, 4, 4, 4, 4, 1]
        for j, batch in enumerate(kept):
            _same(_expected(ds, range(4 * j, min(LENGTH, 4 * j + 4))), batch)
    # Each batch freed before the next: the workers' buffers are reused.
    for j, batch in enumerate(loader):
        _same(_expected(ds, range(4 * j, min(LENGTH, 4 * j + 4))), batch)
        del batch


@pytest.mark.parametrize("method", ["fork", "spawn"])
def test_a_batch_is_one_buffer_in_the_main_process(method):
    """The arrays of a worker's batch lie in one block, each AOV's after the previous one
    (64-byte aligned), as `__getitems__` wrote them: collation copied nothing."""
    torch = need("torch")
    ds = cylaov.Dataset(SETTINGS, seed=3, length=8, aovs=("depth", "normal"), threads=1)
    loader = torch.utils.data.DataLoader(ds, batch_size=8, num_workers=1,
                                         multiprocessing_context=method)
    batch = next(iter(loader))
    depth, normal, mask = batch["depth"], batch["normal"], batch["mask"]
    assert normal.data_ptr() - depth.data_ptr() == 8 * 48 * 32 * 4
    assert mask.data_ptr() - normal.data_ptr() == 8 * 48 * 32 * 12
    assert all(t.is_contiguous() for t in (depth, normal, mask))
    assert mask.dtype == torch.bool and depth.dtype == torch.float32


class _Scaled(cylaov.Dataset):
    """Replaces each item's depth (a new array) and changes its normal in place."""

    def __getitems__(self, indices):
        items = super().__getitems__(indices)
        for item in items:
            item["depth"] = item["depth"] * 2
            item["normal"] *= -1
        return items


@pytest.mark.parametrize("workers", [0, 2])
def test_items_changed_before_collation_are_collated_as_changed(workers):
    torch = need("torch")
    ds = _Scaled(SETTINGS, seed=3, length=6, aovs=AOVS, threads=1)
    plain = cylaov.Dataset(SETTINGS, seed=3, length=6, aovs=AOVS, threads=1)
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=6, num_workers=workers)))
    want = _expected(plain, range(6))
    want["depth"] = want["depth"] * 2
    want["normal"] = want["normal"] * -1
    _same(want, batch)


def test_items_of_getitems_equal_ds_i_and_pickle():
    import pickle

    ds = cylaov.Dataset(SETTINGS, seed=3, length=5, aovs=AOVS)
    items = ds.__getitems__([4, 0, 4])
    for item, i in zip(items, [4, 0, 4]):
        one = ds[i]
        assert isinstance(item, dict) and list(item) == list(one)
        assert item["camera_info"] == one["camera_info"]
        for k in AOVS + ("mask",):
            assert item[k].dtype == one[k].dtype and np.array_equal(item[k], one[k]), k
        back = pickle.loads(pickle.dumps(item))
        assert type(back) is dict and all(np.array_equal(back[k], one[k]) for k in AOVS)
    # Pickled, a list of items is a plain list of plain dicts, each with its own arrays
    # (not the batch's whole buffer once an item).
    data = pickle.dumps(items)
    assert len(data) < 3 * 48 * 32 * (4 + 12 + 4 + 1) + 3 * 4096
    back = pickle.loads(data)
    assert type(back) is list and [type(b) for b in back] == [dict] * 3
    assert np.array_equal(back[1]["normal"], ds[0]["normal"])


def test_collate_fn_list_gives_the_items():
    torch = need("torch")
    ds = cylaov.Dataset(SETTINGS, seed=3, length=6, aovs="depth", threads=1)
    loader = torch.utils.data.DataLoader(ds, batch_size=3, num_workers=2, collate_fn=list)
    got = [item for batch in loader for item in batch]
    assert len(got) == 6
    for i, item in enumerate(got):
        assert np.array_equal(item["depth"], ds[i]["depth"]) and item["camera_info"] == ds[i]["camera_info"]


def test_threads_fetching_batches_at_once_get_their_own_buffers():
    """The GIL is released while a batch renders: batches fetched from several threads at
    once, some kept and some freed, each hold their own items."""
    from concurrent.futures import ThreadPoolExecutor

    ds = cylaov.Dataset(SETTINGS, seed=3, length=12, aovs="depth", threads=1)
    want = [ds[i]["depth"] for i in range(12)]
    kept = []

    def fetch(k):
        indices = [(k + j) % 12 for j in range(3)]
        items = ds.__getitems__(indices)
        if k % 2:
            kept.append((indices, items))
        return all(np.array_equal(it["depth"], want[i]) for i, it in zip(indices, items))

    with ThreadPoolExecutor(4) as pool:
        assert all(pool.map(fetch, range(40)))
    for indices, items in kept:
        assert all(np.array_equal(it["depth"], want[i]) for i, it in zip(indices, items))


def _held_batches_hold_their_items(ds, held):
    for indices, items in held:
        for i, item in zip(indices, items):
            one = ds[i]
            for k in AOVS + ("mask",):
                assert np.array_equal(item[k], one[k]), (i, k)


def test_a_free_buffer_behind_busy_ones_is_dropped_by_identity(monkeypatch):
    """A fifth buffer drops a free one (the cache keeps four): found by identity, not by
    `list.remove`'s `==`, which compared the entries' numpy arrays and raised."""
    monkeypatch.setattr(cylaov, "_BUFFERS", cylaov._Buffers())  # this test's cache alone
    ds = cylaov.Dataset(SETTINGS, seed=5, length=14, aovs=AOVS, threads=1)
    held = [([0, 1, 2], ds.__getitems__([0, 1, 2]))]
    small = ds.__getitems__([3])  # the second buffer: freed below, too small after
    held += [(b, ds.__getitems__(b)) for b in ([4, 5, 6], [7, 8, 9])]
    del small
    held.append(([10, 11, 12, 13], ds.__getitems__([10, 11, 12, 13])))
    assert len(cylaov._BUFFERS.entries) == cylaov._Buffers.KEEP
    _held_batches_hold_their_items(ds, held)


def test_growing_batches_while_the_first_is_kept(monkeypatch):
    torch = need("torch")
    monkeypatch.setattr(cylaov, "_BUFFERS", cylaov._Buffers())
    ds = cylaov.Dataset(SETTINGS, seed=1, length=36, aovs=AOVS, threads=1)
    batches, at = [], 0
    for size in range(1, 9):
        batches.append(list(range(at, at + size)))
        at += size
    loader = torch.utils.data.DataLoader(ds, batch_sampler=batches)
    # Each batch is larger than the buffers freed before it, so each needs a new one, and
    # the cache drops a free buffer behind the first, kept one.
    first, sizes = None, []
    for indices, batch in zip(batches, loader):
        _same(_expected(ds, indices), batch)
        first = batch if first is None else first
        sizes.append(len(batch["depth"]))
    assert sizes == list(range(1, 9))
    _same(_expected(ds, batches[0]), first)


def _doubled_depth(items):
    batch = need("torch").utils.data.default_collate(items)
    batch["depth"] = batch["depth"] * 2
    return batch


def _negated_normal(items):
    batch = need("torch").utils.data.default_collate(items)
    batch["normal"].mul_(-1)
    return batch


@pytest.mark.parametrize("collate", [_doubled_depth, _negated_normal])
def test_a_worker_batch_changed_after_collation_arrives_as_changed(collate):
    """A collate_fn that changes default collation's dict in the worker: a replaced tensor
    sends the dict as PyTorch sends any dict, a tensor changed in place travels in the
    buffer; either way the main process gets what the worker made."""
    torch = need("torch")
    ds = cylaov.Dataset(SETTINGS, seed=3, length=8, aovs=AOVS, threads=1)
    loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=1, collate_fn=collate)
    for j, batch in enumerate(loader):
        _same(collate([ds[i] for i in range(4 * j, 4 * j + 4)]), batch)
