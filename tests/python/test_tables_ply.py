"""Tables in, point clouds out: ``Scene.from_table`` reads a TreeQSM table as ``cylaov
import`` does, and the hit points of a view (``to_ply``, ``render --ply``) are what Open3D
reads back: points and normals equal to the position and normal AOVs."""

import json

import numpy as np
import pytest

import cylaov

# radius, length, start x y z, axis x y z, parent, extension, branch, BranchOrder,
# PositionInBranch, added, UnmodRadius: TreeQSM 2.3 without a header.
TREE = """\
0.2 1.5 1 2 0 0 0 1 0 2 1 0 1 0 0.2
0.15 1.25 1 2 1.5 0 0 1 1 3 1 0 2 0 0.15
0.06 0.8 1 2 1.5 0.6 0 0.8 1 0 2 1 1 0 0.06
0.04 0.6 1 2 2.75 -0.8 0.6 0 2 0 3 2 1 0 0.04
"""

PLY_AOVS = ("position", "normal", "shape_id", "part", "label")


def _tree(tmp_path):
    path = tmp_path / "cyl_data.txt"
    path.write_text(TREE)
    return path


def test_from_table_reads_treeqsm_like_import(cli, tmp_path):
    table = _tree(tmp_path)
    scene = cylaov.Scene.from_table(table, label="branch_order")
    assert len(scene) == 4
    d = json.loads(scene.to_json())
    cyl = d["cylinders"]
    assert [c["id"] for c in cyl] == [1, 2, 3, 4]
    assert [c.get("label", 0) for c in cyl] == [1, 1, 2, 3]
    assert [c["radius"] for c in cyl] == [0.2, 0.15, 0.06, 0.04]
    # p1 = start + length * unit axis: (0.6, 0, 0.8) is a unit vector.
    np.testing.assert_allclose(cyl[2]["p1"], [1 + 0.48, 2, 1.5 + 0.64], rtol=0, atol=1e-12)
    # The same scene as the command line's.
    out = tmp_path / "tree.json"
    cli("import", table, "-o", out, "--label", "branch_order")
    assert cylaov.Scene.load(out) == scene
    # A bad row names its line and column.
    bad = tmp_path / "bad.txt"
    bad.write_text(TREE.replace("0.06 0.8", "0.06 -0.8"))
    with pytest.raises(cylaov.SceneError, match=r"line 3, column 2 \(length\): must be > 0"):
        cylaov.Scene.from_table(bad)
    with pytest.raises(ValueError, match="format"):
        cylaov.Scene.from_table(table, format="xls")


def _arrays(n=40, seed=3):
    rng = np.random.default_rng(seed)
    p0 = rng.uniform(-2, 2, (n, 3))
    p1 = p0 + rng.uniform(0.2, 1.0, (n, 3))
    return p0, p1, rng.uniform(0.02, 0.2, n)


@pytest.mark.parametrize("save", ["savez", "savez_compressed"])
def test_from_table_reads_numpy_npz(cli, tmp_path, save):
    """Whatever numpy writes (stored or deflated members, float32 or float64, C or Fortran
    order, int64 ids counted from 0) reads back to the same numbers."""
    p0, p1, radius = _arrays()
    n = len(radius)
    path = tmp_path / "tree.npz"
    getattr(np, save)(
        path,
        p0=np.asfortranarray(p0),
        p1=p1.astype(np.float32),
        radius=radius,
        id=np.arange(n, dtype=np.int64),
        label=(np.arange(n) % 4).astype(np.uint8),
        caps=np.arange(n) % 2 == 0,
        notes=np.zeros(3),
    )
    scene = cylaov.Scene.from_table(path)
    cyl = json.loads(scene.to_json())["cylinders"]
    assert len(cyl) == n
    np.testing.assert_array_equal([c["p0"] for c in cyl], p0)
    np.testing.assert_array_equal([c["p1"] for c in cyl], p1.astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal([c["radius"] for c in cyl], radius)
    assert [c["id"] for c in cyl] == list(range(1, n + 1))
    assert [c.get("label", 0) for c in cyl] == [k % 4 for k in range(n)]
    assert [c["caps"] for c in cyl] == [k % 2 == 0 for k in range(n)]
    # The command line reads the same file to the same scene, and so does a scene that
    # names the table.
    out = tmp_path / "tree.json"
    cli("import", path, "-o", out)
    assert cylaov.Scene.load(out) == scene
    ref = tmp_path / "ref.json"
    ref.write_text(json.dumps({"camera": json.loads(out.read_text())["camera"], "cylinders": {"file": "tree.npz"}}))
    assert [c["p0"] for c in json.loads(cylaov.Scene.load(ref).to_json())["cylinders"]] == [c["p0"] for c in cyl]


def test_a_bad_npz_names_its_array_and_index(tmp_path):
    p0, p1, radius = _arrays()
    bad = radius.copy()
    bad[16] = -1.0
    cases = {
        "radius": (dict(p0=p0, p1=p1, radius=bad), r"radius\[16\]: must be > 0, got -1"),
        "shape": (dict(p0=p0, p1=p1[:10], radius=radius), r"array p1 must have shape \(N, 3\) with N = 40, the rows of p0, got \(10, 3\)"),
        "missing": (dict(p0=p0, p1=p1), r"no array radius; .* it holds \[p0, p1\]"),
        "float ids": (dict(p0=p0, p1=p1, radius=radius, id=np.arange(40.0)), r"array id: must hold integers or bools, got dtype <f8"),
        "nan": (dict(p0=p0, p1=np.where(np.arange(40)[:, None] == 7, np.nan, p1), radius=radius), r"p1\[7, 0\]: must be finite"),
        "zero length": (dict(p0=p0, p1=np.where(np.arange(40)[:, None] == 5, p0, p1), radius=radius), r"p1\[5\]: zero length"),
    }
    for name, (arrays, message) in cases.items():
        path = tmp_path / f"{name.replace(' ', '_')}.npz"
        np.savez(path, **arrays)
        with pytest.raises(cylaov.SceneError, match=message):
            cylaov.Scene.from_table(path)
    # A text table told to be npz, and an npz told to be csv, say what each is.
    text = tmp_path / "t.csv"
    text.write_text("x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,1,1\n")
    with pytest.raises(cylaov.SceneError, match="an npz table is a zip archive"):
        cylaov.Scene.from_table(text, format="npz")
    good = tmp_path / "good.npz"
    np.savez(good, p0=p0, p1=p1, radius=radius)
    with pytest.raises(cylaov.SceneError, match="not a csv text table"):
        cylaov.Scene.from_table(good, format="csv")


def _read_ply_ids(path):
    """The uint properties of our PLY, read with numpy from the header's vertex count."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    n = int(next(l for l in data[:end].decode().splitlines() if l.startswith("element vertex")).split()[2])
    rec = np.dtype([("p", "<f4", 3), ("n", "<f4", 3), ("shape_id", "<u4"), ("part", "<u4"), ("label", "<u4")])
    assert len(data) - end == n * rec.itemsize
    return np.frombuffer(data[end:], dtype=rec)


def _assert_ply_holds_the_hits(o3d, ply, exr, more_than):
    """Open3D reads `ply` to the position and normal of every hit pixel of `exr` (which
    holds the PLY AOVs), in pixel order, and the labels ride along."""
    img = cylaov.read(exr)
    hit = img["shape_id"] != 0
    pc = o3d.io.read_point_cloud(str(ply))
    assert len(pc.points) == int(hit.sum()) > more_than
    assert np.array_equal(np.asarray(pc.points), img["position"][hit].astype(np.float64))
    assert np.array_equal(np.asarray(pc.normals), img["normal"][hit].astype(np.float64))
    assert np.array_equal(_read_ply_ids(ply)["label"], img["label"][hit])


def test_to_ply_is_what_open3d_reads(tmp_path):
    o3d = pytest.importorskip("open3d")
    scene = cylaov.Scene.from_table(_tree(tmp_path), label="branch_order")
    out = cylaov.render(scene, aovs=PLY_AOVS)
    path = tmp_path / "view.ply"
    n = cylaov.to_ply(out, path)
    hit = out["shape_id"] != 0
    assert n == int(hit.sum()) and n > 10000, n
    pc = o3d.io.read_point_cloud(str(path))
    assert np.array_equal(np.asarray(pc.points), out["position"][hit].astype(np.float64))
    assert np.array_equal(np.asarray(pc.normals), out["normal"][hit].astype(np.float64))
    rec = _read_ply_ids(path)
    assert np.array_equal(rec["shape_id"], out["shape_id"][hit])
    assert np.array_equal(rec["part"], out["part"][hit])
    assert np.array_equal(rec["label"], out["label"][hit])
    assert set(np.unique(rec["label"])) == {1, 2, 3}
    with pytest.raises(ValueError, match="position"):
        cylaov.to_ply({"shape_id": out["shape_id"]}, tmp_path / "x.ply")
    assert not (tmp_path / "x.ply").exists()


def test_render_ply_matches_the_exr(cli, tmp_path):
    o3d = pytest.importorskip("open3d")
    scene = tmp_path / "tree.json"
    cli("import", _tree(tmp_path), "-o", scene, "--label", "branch")
    exr, ply = tmp_path / "v.exr", tmp_path / "v.ply"
    cli("render", scene, "-o", exr, "--aov", ",".join(PLY_AOVS), "--ply", ply)
    _assert_ply_holds_the_hits(o3d, ply, exr, more_than=10000)
    # A name that is not .ply, or a link at the target, is refused before any work.
    r = cli("render", scene, "-o", tmp_path / "w.exr", "--ply", tmp_path / "w.xyz", check=False)
    assert r.returncode == 1 and "must end in .ply" in r.stderr
    assert not (tmp_path / "w.exr").exists()
    (tmp_path / "link.ply").symlink_to(tmp_path / "elsewhere.ply")
    r = cli("render", scene, "-o", tmp_path / "w.exr", "--ply", tmp_path / "link.ply", check=False)
    assert r.returncode == 1 and "--ply" in r.stderr, r.stderr
    assert not (tmp_path / "elsewhere.ply").exists()


def test_tar_ply_member_is_what_open3d_reads(cli, tmp_path):
    """``--members ply`` puts ``KEY.ply`` in the tar: the bytes ``render --ply`` writes for
    the view, which Open3D reads to the position and normal of every hit pixel."""
    import tarfile

    o3d = pytest.importorskip("open3d")
    data = tmp_path / "data"
    data.mkdir()
    cli("import", _tree(tmp_path), "-o", data / "tree.json", "--label", "branch", "--width", "160", "--height", "120")
    out = tmp_path / "shards"
    cli("batch", data, "--out", out, "--format", "webdataset", "--members", "ply", "--aov", "depth")
    with tarfile.open(out / "shard-000000.tar") as tar:
        names = tar.getnames()
        ply_bytes = tar.extractfile("tree.ply").read()
    assert names == ["tree.depth.npy", "tree.normal.npy", "tree.mask.npy", "tree.json", "tree.ply"]
    ply = tmp_path / "tree.ply"
    ply.write_bytes(ply_bytes)
    exr, alone = tmp_path / "v.exr", tmp_path / "alone.ply"
    cli("render", data / "tree.json", "-o", exr, "--aov", ",".join(PLY_AOVS), "--ply", alone)
    body = lambda b: b[b.index(b"end_header\n"):]
    assert body(ply_bytes) == body(alone.read_bytes())
    _assert_ply_holds_the_hits(o3d, ply, exr, more_than=1000)
