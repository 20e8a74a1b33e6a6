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
