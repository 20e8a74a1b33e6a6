"""Tar shards (`batch --format webdataset`) read by the real loaders: webdataset, Hugging
Face `datasets` and Ray Data; `write_shards` and `scripts/ray_batch.py` write the bytes of
one `batch` process."""

import io
import json
import os
import pathlib
import shutil
import subprocess
import sys

import numpy as np
import pytest

import cylaov
from conftest import need

ROOT = pathlib.Path(__file__).resolve().parents[2]
VIEWS, SIZE = 7, 3  # three tars: 3 + 3 + 1 views


@pytest.fixture(scope="module")
def dataset(tmp_path_factory, request):
    """A generated input and its shards written by one `batch` process."""
    cli = request.getfixturevalue("cli")
    base = tmp_path_factory.mktemp("shards")
    cli("generate", "--count", VIEWS, "--seed", 2, "--cylinders", 20, "--width", 40,
        "--height", 30, "--out", base / "data")
    cli("batch", base / "data", "--out", base / "cli", "--format", "webdataset",
        "--shard-size", SIZE)
    return base


def tars(out):
    return sorted(str(p) for p in pathlib.Path(out).glob("shard-*.tar"))


def shard_bytes(out):
    out = pathlib.Path(out)
    names = sorted(p.name for p in out.glob("shard-*")) + ["shards.json"]
    return {n: (out / n).read_bytes() for n in names}


def test_write_shards_is_the_cli(dataset):
    assert cylaov.shard_count(dataset / "data", SIZE) == 3
    out = dataset / "py"
    for j in (2, 0, 1):
        r = cylaov.write_shards(dataset / "data", out, shards=[j], shard_size=SIZE)
        assert r["written"] == [j] and r["failed"] == []
    assert r["index_written"]
    assert shard_bytes(out) == shard_bytes(dataset / "cli")
    again = cylaov.write_shards(dataset / "data", out, shard_size=SIZE)
    assert again["skipped"] == [0, 1, 2] and again["written"] == []
    with pytest.raises(ValueError, match="tar 3 does not exist"):
        cylaov.write_shards(dataset / "data", out, shards=[3], shard_size=SIZE)


def test_webdataset_decodes_every_sample(dataset):
    wds = need("webdataset")
    samples = list(wds.WebDataset(tars(dataset / "cli"), shardshuffle=False).decode())
    assert [s["__key__"] for s in samples] == [f"{i:06d}" for i in range(VIEWS)]
    for s in samples:
        assert s["depth.npy"].shape == (30, 40) and s["depth.npy"].dtype == np.float32
        assert s["normal.npy"].shape == (30, 40, 3)
        assert s["mask.npy"].dtype == bool
        assert np.array_equal(s["mask.npy"], s["depth.npy"] > 0)
        assert 0 < s["mask.npy"].sum() < 30 * 40
        n = np.linalg.norm(s["normal.npy"][s["mask.npy"]], axis=-1)
        assert np.allclose(n, 1, atol=1e-5)
        assert s["json"]["key"] == s["__key__"] and s["json"]["width"] == 40


def test_hugging_face_datasets_loads_them(dataset, monkeypatch):
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_DATASETS_CACHE", str(dataset / "hf-cache"))
    datasets = need("datasets")
    ds = datasets.load_dataset("webdataset", data_files={"train": tars(dataset / "cli")},
                               split="train", cache_dir=str(dataset / "hf-cache"))
    assert len(ds) == VIEWS
    row = ds[4]
    assert row["__key__"] == "000004"
    depth = np.asarray(row["depth.npy"])
    assert depth.shape == (30, 40)
    assert np.array_equal(np.asarray(row["mask.npy"]), depth > 0)
    assert row["json"]["key"] == "000004"


@pytest.fixture(scope="module")
def ray_local():
    ray = need("ray")
    ray.init(num_cpus=2, include_dashboard=False, object_store_memory=200_000_000)
    yield ray
    ray.shutdown()


def test_ray_data_reads_them(dataset, ray_local):
    rows = ray_local.data.read_webdataset(tars(dataset / "cli")).take_all()
    assert sorted(r["__key__"] for r in rows) == [f"{i:06d}" for i in range(VIEWS)]
    r = next(r for r in rows if r["__key__"] == "000002")
    depth = r["depth.npy"]
    if isinstance(depth, bytes):
        depth = np.load(io.BytesIO(depth))
    assert np.asarray(depth).shape == (30, 40)


def test_ray_batch_script_is_one_batch_process(dataset):
    need("ray")
    out = dataset / "ray"
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "ray_batch.py"),
                        str(dataset / "data"), "--out", str(out), "--shard-size", str(SIZE)],
                       capture_output=True, text=True, env={**os.environ, "RAY_ADDRESS": ""},
                       timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "3 of 3 tars written" in r.stdout, r.stdout
    assert shard_bytes(out) == shard_bytes(dataset / "cli")


def test_one_dataset_a_folder_and_failures_files_per_call(dataset, tmp_path):
    """Another shard size into the same folder raises ValueError naming the difference and
    leaves the folder as it was; force=True replaces the dataset. Calls for other tars keep
    their own failures files."""
    out = tmp_path / "one"
    first = cylaov.write_shards(dataset / "data", out, shard_size=SIZE)
    assert first["written"] == [0, 1, 2]
    before = shard_bytes(out)
    with pytest.raises(ValueError, match="shard size: 2 now, 3 in the folder"):
        cylaov.write_shards(dataset / "data", out, shard_size=2)
    assert shard_bytes(out) == before
    again = cylaov.write_shards(dataset / "data", out, shard_size=2, force=True)
    assert again["written"] == [0, 1, 2, 3] and again["tars"] == 4
    assert len(tars(out)) == 4
    assert json.loads((out / "shards.settings.json").read_text())["shard_size"] == 2
    cylaov.write_shards(dataset / "data", out, shards=[0, 2], shard_size=2)
    cylaov.write_shards(dataset / "data", out, shards=[1, 3], shard_size=2)
    names = sorted(p.name for p in out.glob("failures.*.jsonl"))
    assert "failures.tars-000000-000002.jsonl" in names
    assert "failures.tars-000001-000003.jsonl" in names


def test_write_shards_takes_scene_objects(dataset, tmp_path):
    """Scenes in memory make the same tars as the same scenes as files in a folder."""
    files = sorted((dataset / "data" / "scenes").glob("*.json"))
    assert len(files) == VIEWS
    scenes = [cylaov.Scene.load(p) for p in files]
    folder = tmp_path / "folder"
    folder.mkdir()
    for i, s in enumerate(scenes):
        (folder / ("scene_%06d.json" % i)).write_text(s.to_json(), encoding="utf-8")
    r = cylaov.write_shards(folder, tmp_path / "from-files", shard_size=SIZE)
    assert r["written"] == [0, 1, 2]
    r = cylaov.write_shards(scenes, tmp_path / "from-list", shard_size=SIZE)
    assert r["written"] == [0, 1, 2] and r["failed"] == [] and r["index_written"]
    # The same tars and sidecars; shards.json differs only in where the scenes were.
    a, b = shard_bytes(tmp_path / "from-list"), shard_bytes(tmp_path / "from-files")
    ja, jb = json.loads(a.pop("shards.json")), json.loads(b.pop("shards.json"))
    assert a == b
    assert ja.pop("scenes_dir") != jb.pop("scenes_dir") == str(folder)
    assert ja == jb
    # A rerun with equal scenes (new objects) skips every tar.
    again = cylaov.write_shards([cylaov.Scene.load(p) for p in files], tmp_path / "from-list",
                                shard_size=SIZE)
    assert again["skipped"] == [0, 1, 2] and again["written"] == []
    # A dict names the samples by its keys; one Scene is one scene.
    r = cylaov.write_shards({"left": scenes[0], "right": scenes[1]}, tmp_path / "dict",
                            shard_size=SIZE)
    wds = need("webdataset")
    keys = [s["__key__"] for s in wds.WebDataset(tars(tmp_path / "dict"), shardshuffle=False)]
    assert keys == ["left", "right"]
    one = cylaov.write_shards(scenes[0], tmp_path / "one", shard_size=SIZE)
    assert one["written"] == [0]
    with pytest.raises(TypeError, match=r"input\['x'\]: a Scene, got int"):
        cylaov.write_shards({"x": 3}, tmp_path / "bad")
    with pytest.raises(ValueError, match="cannot name a scene file"):
        cylaov.write_shards({"a/b": scenes[0]}, tmp_path / "bad")
    with pytest.raises(ValueError, match="no scenes"):
        cylaov.write_shards([], tmp_path / "bad")
    assert not (tmp_path / "bad").exists()


def test_errors_name_the_keyword_not_the_flag(dataset, tmp_path):
    """The library's messages name options neutrally; Python spells them as its keywords."""
    for call in (lambda: cylaov.shard_count(dataset / "data", 0),
                 lambda: cylaov.write_shards(dataset / "data", tmp_path / "out", shard_size=0)):
        with pytest.raises(ValueError, match=r"shard_size: must be >= 1, got 0") as e:
            call()
        assert "--" not in str(e.value)
    assert not (tmp_path / "out").exists()


def test_integer_arguments_name_themselves_and_their_value(dataset, tmp_path):
    """Negative, huge and fractional numbers raise ValueError or TypeError naming the
    argument (and the entry of `shards`) and the value, not pyo3's nameless OverflowError."""
    data, out = dataset / "data", tmp_path / "out"
    for kw, exc, msg in (
        (dict(shard_size=-1), ValueError, r"^shard_size: must be >= 1, got -1"),
        (dict(shard_size=2**70), ValueError,
         r"^shard_size: must be <= 18446744073709551615, got 1180591620717411303424"),
        (dict(shard_size=1.5), TypeError, r"^shard_size: must be an integer, got float 1\.5"),
        (dict(shard_size="3"), TypeError, r"^shard_size: must be an integer, got str '3'"),
        (dict(shards=[-1]), ValueError, r"^shards\[0\]: must be >= 0, got -1"),
        (dict(shards=[0, 2**64]), ValueError,
         r"^shards\[1\]: must be <= 18446744073709551615, got 18446744073709551616"),
        (dict(shards=["a"]), TypeError, r"^shards\[0\]: must be an integer, got str 'a'"),
        (dict(shards=[1.5]), TypeError, r"^shards\[0\]: must be an integer, got float 1\.5"),
        (dict(shards=[None]), TypeError, r"^shards\[0\]: must be an integer, got NoneType None"),
        (dict(shards=3), TypeError, r"^shards: a sequence of tar indices or None, got int 3"),
        (dict(shards="01"), TypeError, r"^shards: a sequence of tar indices or None, got str '01'"),
        (dict(threads=-1), ValueError, r"^threads: must be in 1\.\.=1024, got -1"),
        (dict(threads=2.0), TypeError, r"^threads: must be an integer, got float 2\.0"),
    ):
        with pytest.raises(exc, match=msg):
            cylaov.write_shards(data, out, **kw)
    with pytest.raises(ValueError, match=r"^shard_size: must be >= 1, got -1"):
        cylaov.shard_count(data, -1)
    assert not out.exists()
    # numpy integers are integers.
    r = cylaov.write_shards(data, out, shards=np.array([2]), shard_size=np.int64(SIZE))
    assert r["written"] == [2]


def test_write_shards_refuses_an_empty_out_and_empty_or_repeated_shards(dataset, tmp_path,
                                                                        monkeypatch):
    data = dataset / "data"
    monkeypatch.chdir(tmp_path)
    # The command line refuses an empty --out: here it would write into the working folder.
    with pytest.raises(ValueError, match=r"^out: must name a folder, got ''"):
        cylaov.write_shards(data, "", shard_size=SIZE)
    assert list(tmp_path.iterdir()) == []
    # A file where the folder goes: an OSError naming out and the path, no "[Errno 0]".
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(OSError) as e:
        cylaov.write_shards(data, a_file, shard_size=SIZE)
    assert str(e.value) == f"out {a_file}: is a regular file, not a folder"
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=r"^shards: an empty list"):
        cylaov.write_shards(data, out, shards=[], shard_size=SIZE)
    with pytest.raises(ValueError, match=r"^shards: tar 0, 2 listed more than once"):
        cylaov.write_shards(data, out, shards=[2, 0, 1, 0, 2], shard_size=SIZE)
    assert not out.exists()
    # The failures file is named by the tars, whatever their order in the list.
    assert cylaov.write_shards(data, out, shards=[2, 0], shard_size=SIZE)["written"] == [0, 2]
    assert cylaov.write_shards(data, out, shards=(0, 2), shard_size=SIZE)["skipped"] == [0, 2]
    assert [p.name for p in out.glob("failures.*")] == ["failures.tars-000000-000002.jsonl"]


def test_scenes_in_memory_stay_with_their_dataset(dataset, tmp_path, cli):
    """Scenes in memory are written as OUT/scenes/KEY.json, which shards.json records: equal
    calls write equal bytes, `cylaov verify OUT` finds the scenes, a refused call leaves
    them, and a `scenes` folder of someone else's is never replaced."""
    files = sorted((dataset / "data" / "scenes").glob("*.json"))
    scenes = [cylaov.Scene.load(p) for p in files]
    out = tmp_path / "mem"
    cylaov.write_shards(scenes, out, shard_size=SIZE)
    first = shard_bytes(out)
    assert json.loads(first["shards.json"])["scenes_dir"] == str(out / "scenes")
    names = ["scene_%06d.json" % i for i in range(VIEWS)]
    held = [".cylaov-write-shards", "manifest.jsonl"] + names
    assert sorted(p.name for p in (out / "scenes").iterdir()) == held
    assert (out / "scenes" / names[3]).read_text(encoding="utf-8") == scenes[3].to_json()
    assert not [p.name for p in out.iterdir() if p.name.startswith(".scenes")]
    shutil.rmtree(out)
    cylaov.write_shards(scenes, out, shard_size=SIZE)
    assert shard_bytes(out) == first
    r = cli("verify", out, check=False)
    assert "is gone" not in r.stderr and "scenes' folder" not in r.stderr, r.stderr
    assert r.returncode == 0, r.stderr
    # Other scenes are other inputs: refused, the dataset and its scenes as they were.
    with pytest.raises(ValueError, match="written with other settings"):
        cylaov.write_shards(scenes[:2], out, shard_size=SIZE)
    assert shard_bytes(out) == first
    assert sorted(p.name for p in (out / "scenes").iterdir()) == held
    assert not [p.name for p in out.iterdir() if p.name.startswith(".scenes")]
    # Replaced by force: the folder holds the new scenes only.
    r = cylaov.write_shards({"a": scenes[5], "b": scenes[6]}, out, shard_size=SIZE, force=True)
    assert r["written"] == [0]
    assert sorted(p.name for p in (out / "scenes").iterdir()) == [
        ".cylaov-write-shards", "a.json", "b.json", "manifest.jsonl"]
    assert not [p.name for p in out.iterdir() if p.name.startswith(".scenes")]
    # A refused first call leaves no folder behind.
    with pytest.raises(ValueError, match="unknown AOV"):
        cylaov.write_shards(scenes, tmp_path / "fresh", aovs="nope")
    assert not (tmp_path / "fresh").exists()
    # A generate output's scenes are not this function's to replace.
    gen = tmp_path / "gen"
    shutil.copytree(dataset / "data", gen)
    before = {p.name: p.read_bytes() for p in (gen / "scenes").iterdir()}
    with pytest.raises(ValueError, match=r"^out: .*scenes was not written by write_shards"):
        cylaov.write_shards(scenes[:1], gen, shard_size=SIZE)
    assert {p.name: p.read_bytes() for p in (gen / "scenes").iterdir()} == before


def test_write_shards_takes_a_folder_not_a_scene_file(dataset, tmp_path):
    doc = cylaov.write_shards.__doc__
    assert "one scene file is refused" in doc and "(a scene file," not in doc
    with pytest.raises(ValueError):
        cylaov.write_shards(sorted((dataset / "data" / "scenes").glob("*.json"))[0],
                            tmp_path / "out")


def test_keys_that_cannot_name_a_file_are_refused_by_key(dataset, tmp_path):
    scene = cylaov.Scene.load(sorted((dataset / "data" / "scenes").glob("*.json"))[0])
    for key, msg in (
        (".hidden", r"^input: key '\.hidden' starts with a dot, which hides a file"),
        ("\udcff", r"^input: key '\\udcff' is not valid text \(a lone surrogate\)"),
        ("a" * 300, r"^input: key 'a{20}…\(272 more\)…a{8}' is 300 bytes of UTF-8; a scene "
                    r"file's name takes at most 250 \(and \.json\)$"),
    ):
        with pytest.raises(ValueError, match=msg):
            cylaov.write_shards({key: scene}, tmp_path / "out", shard_size=SIZE)
    assert not (tmp_path / "out").exists()
    # Shorter, a key too long for a tar member is the library's to refuse, by key.
    with pytest.raises(ValueError, match=r"^the view names cannot all be tar shard keys.*\n  input\['k{250}'\]: tar member name is too long"):
        cylaov.write_shards({"k" * 250: scene}, tmp_path / "out", shard_size=SIZE)
    assert not (tmp_path / "out").exists()
    assert cylaov.write_shards({"k" * 80: scene}, tmp_path / "out", shard_size=SIZE)["written"] == [0]


def test_bad_keys_of_scenes_in_memory_are_named_by_key(dataset, tmp_path):
    """The scenes of a dict are written as OUT/scenes/KEY.json: a key that cannot be a
    sample's key is named as the dict's key, not as that file."""
    scene = cylaov.Scene.load(sorted((dataset / "data" / "scenes").glob("*.json"))[0])
    with pytest.raises(ValueError) as e:
        cylaov.write_shards({"ok": scene, "a.b": scene, "ñ": scene, "c.json": scene},
                            tmp_path / "out", shard_size=SIZE)
    msg = str(e.value)
    for key in ("a.b", "ñ", "c.json"):
        assert f"\n  input[{key!r}]: " in msg, msg
    assert "input['ok']" not in msg and "scenes/" not in msg, msg
    assert "rename the keys" in msg and "scene files" not in msg, msg
    assert not (tmp_path / "out").exists()
    # Two views with one key name both scenes, in parentheses, by key too.
    two = json.loads(scene.to_json())
    two["cameras"] = [two.pop("camera")] * 2
    with pytest.raises(ValueError) as e:
        cylaov.write_shards({"s": cylaov.Scene.from_dict(two), "s_c01": scene},
                            tmp_path / "out", shard_size=SIZE)
    msg = str(e.value)
    assert "(input['s'])" in msg and "(input['s_c01'])" in msg, msg
    assert "scenes/" not in msg, msg
