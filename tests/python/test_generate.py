"""`generate` is `cylaov generate`'s scene; `Dataset` items are pure functions of
(settings, seed, index) in every process, forked or spawned."""

import json
import multiprocessing as mp
import pickle

import numpy as np
import pytest

import cylaov

SETTINGS = {"cylinders": "20..40", "width": 48, "height": 32, "count": 99}


def test_generate_is_the_cli_scene_file(cli, tmp_path):
    cli("generate", "--count", 4, "--seed", 5, "--cylinders", "20..40", "--width", 48,
        "--height", 32, "--views-per-scene", 2, "--out", tmp_path)
    settings = json.loads((tmp_path / "generate.json").read_text())
    for i in range(4):
        text = (tmp_path / "scenes" / f"{i:06d}.json").read_text()
        got = cylaov.generate(settings, 5, i)
        assert json.loads(got.to_json()) == json.loads(text), i
        assert got.to_json() == text
        assert got == cylaov.Scene.from_json(text)
        assert len(got.cameras) == 2
    # From the file's path too, and the defaults with None.
    assert cylaov.generate(tmp_path / "generate.json", 5, 1) == cylaov.generate(settings, 5, 1)
    assert cylaov.generate(None, 0, 0) == cylaov.generate({}, 0, 0)
    with pytest.raises(ValueError, match="settings.seed: 5 differs from the seed argument 6"):
        cylaov.generate(settings, 6, 0)
    with pytest.raises(ValueError, match="settings.colour"):
        cylaov.generate({"colour": 1}, 0, 0)
    # A second object in the file was ignored, its seed and radius with it.
    two = tmp_path / "two.json"
    two.write_text('{"count": 2} {"count": 5, "seed": 3, "radius": "1..2"}')
    with pytest.raises(ValueError, match="settings: text after the end of the JSON object at line 1 column 14"):
        cylaov.generate(two, 0, 0)


def _items(args):
    ds, indices = args
    return [{k: v for k, v in ds[i].items() if k != "camera_info"} for i in indices]


def _same(a, b):
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k], b[k]), k


@pytest.mark.parametrize("method", ["spawn", "fork"])
def test_dataset_items_are_the_same_in_every_process(method):
    ds = cylaov.Dataset(SETTINGS, seed=3, length=6, aovs=("depth", "normal", "shape_id"))
    # Render in the parent first, so a forked child inherits a used thread pool.
    here = _items((ds, range(6)))
    ctx = mp.get_context(method)
    with ctx.Pool(2) as pool:
        there = pool.map(_items, [(ds, [0, 1, 2]), (ds, [5, 4, 3])])
    for i, item in zip([0, 1, 2, 5, 4, 3], there[0] + there[1]):
        _same(item, here[i])
    # And an item is render(generate(...)) of its index.
    for i in range(6):
        want = cylaov.render(cylaov.generate(SETTINGS, 3, i), aovs=("depth", "normal", "shape_id"))
        _same(here[i], want)
        assert here[i]["mask"].any()


def test_dataset_views_and_info():
    ds = cylaov.Dataset(SETTINGS, seed=3, length=7, views_per_scene=3, threads=1)
    assert len(ds) == 7
    item = ds[5]
    scene = cylaov.generate(dict(SETTINGS, views_per_scene=3), 3, 1)
    _same({k: v for k, v in item.items() if k != "camera_info"}, cylaov.render(scene, camera=2))
    assert item["camera_info"] == cylaov.camera_info(scene, camera=2)
    assert ds[-1]["depth"].shape == (32, 48)
    with pytest.raises(IndexError):
        ds[7]
    with pytest.raises(ValueError, match="views_per_scene: 2 differs"):
        cylaov.Dataset(dict(SETTINGS, views_per_scene=2), seed=3, length=7, views_per_scene=3)
    with pytest.raises(ValueError, match="settings.seed"):
        cylaov.Dataset(dict(SETTINGS, seed=1), seed=3, length=7)
    back = pickle.loads(pickle.dumps(ds))
    _same({k: v for k, v in back[2].items() if k != "camera_info"},
          {k: v for k, v in ds[2].items() if k != "camera_info"})


def test_getitems_is_a_batch_of_items():
    """`__getitems__` (one call a DataLoader batch) gives exactly the items one by one."""
    ds = cylaov.Dataset(SETTINGS, seed=3, length=9, views_per_scene=2, aovs=("depth", "shape_id"))
    batch = ds.__getitems__([8, 0, -1, 3, 3])
    assert len(batch) == 5
    for got, i in zip(batch, [8, 0, -1, 3, 3]):
        one = ds[i]
        assert got["camera_info"] == one["camera_info"]
        _same({k: v for k, v in got.items() if k != "camera_info"},
              {k: v for k, v in one.items() if k != "camera_info"})
    assert ds.__getitems__([]) == []
    with pytest.raises(IndexError, match="index 9 out of range for a dataset of 9 views"):
        ds.__getitems__([0, 9])


def test_dataloader_fetches_a_batch_in_one_call():
    """PyTorch's DataLoader calls `__getitems__` once a batch, and collates its items."""
    torch = pytest.importorskip("torch")  # scripts/test's venv has it; under CI a skip fails

    calls = []

    class Counted(cylaov.Dataset):
        def __getitems__(self, indices):
            calls.append(list(indices))
            return super().__getitems__(indices)

    ds = Counted(SETTINGS, seed=3, length=10, aovs=("depth",), threads=1)
    loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=0,
                                         collate_fn=lambda items: items)
    batches = list(loader)
    assert calls == [[0, 1, 2, 3], [4, 5, 6, 7], [8, 9]]
    assert [len(b) for b in batches] == [4, 4, 2]
    assert np.array_equal(batches[2][1]["depth"], ds[9]["depth"])
