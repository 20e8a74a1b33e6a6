"""Arguments and inputs at their edges: each refused with one error naming the argument (or
field) and the value, each accepted where it is what the documentation promises."""

import inspect
import warnings

import numpy as np
import pytest

import cylaov
from conftest import ROOT, need

SINGLE = ROOT / "scenes" / "single.json"
TABLE = ROOT / "scenes" / "tables" / "tree_cyl_data.txt"
CAM = {"origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1], "fov_deg": 40,
       "width": 32, "height": 24}


def test_compare_takes_the_dicts_render_and_read_return_uv_included(cli, tmp_path):
    scene = cylaov.Scene.load(SINGLE)
    a = cylaov.render(scene, aovs=("depth", "uv", "normal"))
    assert a["uv"].shape == a["depth"].shape + (2,)
    r = cylaov.compare(a, a)
    assert r["passed"] and r["failures"] == []
    # As `read` returns a file's arrays, and against that file's path.
    cli("render", SINGLE, "-o", tmp_path / "v.exr", "--aov", "depth,uv,normal")
    back = cylaov.read(tmp_path / "v.exr")
    assert np.array_equal(back["uv"], a["uv"])
    assert cylaov.compare(back, a)["passed"]
    assert cylaov.compare(tmp_path / "v.exr", a)["passed"]
    # A shape that is not the AOV's says the one it must have.
    with pytest.raises(ValueError, match=r"^a\[\"uv\"\]: shape \[24, 32, 3\] is not \(H, W, 2\)$"):
        cylaov.compare({"uv": np.zeros((24, 32, 3), np.float32)}, a)
    with pytest.raises(ValueError, match=r"^b\[\"depth\"\]: shape \[24, 32, 1\] is not \(H, W\)$"):
        cylaov.compare(a, {"depth": np.zeros((24, 32, 1), np.float32)})


def test_compare_takes_scene_none_as_no_scene():
    a = cylaov.render(cylaov.Scene.load(SINGLE), aovs="depth")
    assert cylaov.compare(a, a, scene=None) == cylaov.compare(a, a)


def test_a_dataset_is_at_most_what_len_can_return():
    big = cylaov.Dataset(None, seed=0, length=2**63 - 1, aovs="depth")
    assert len(big) == 2**63 - 1
    assert big[-1]["depth"].shape == (240, 320)
    with pytest.raises(ValueError, match=r"^length: must be <= 9223372036854775807, got 9223372036854775808"):
        cylaov.Dataset(None, seed=0, length=2**63)


def test_views_per_scene_comes_from_the_settings_unless_given(cli, tmp_path):
    cli("generate", "--count", 2, "--seed", 9, "--out", tmp_path / "g", "--views-per-scene", 3,
        "--width", 16, "--height", 12)
    settings = tmp_path / "g" / "generate.json"
    ds = cylaov.Dataset(settings, seed=9, length=6, aovs="depth", threads=1)
    assert ds.views_per_scene == 3 and len(ds) == 6
    given = cylaov.Dataset(settings, seed=9, length=6, aovs="depth", views_per_scene=3, threads=1)
    # Item 4 is camera 1 of scene 1, as given explicitly.
    assert np.array_equal(ds[4]["depth"], given[4]["depth"])
    assert np.array_equal(ds[4]["depth"], cylaov.render(
        cylaov.generate(settings, 9, 1), aovs="depth", camera=1)["depth"])
    with pytest.raises(ValueError, match=r"^settings\.views_per_scene: 3 differs from the views_per_scene argument 1$"):
        cylaov.Dataset(settings, seed=9, length=6, views_per_scene=1)
    assert cylaov.Dataset(None, seed=9, length=2).views_per_scene == 1
    # It pickles as what it resolved.
    assert ds.__reduce__()[1][4] == 3


def test_arguments_of_the_wrong_type_name_themselves_and_their_value():
    scene = cylaov.Scene.load(SINGLE)
    ones = {"depth": np.ones((2, 2), np.float32)}
    for call, exc, msg in (
        (lambda: cylaov.render(scene, precision=None), TypeError, r"^precision: must be a str, got NoneType None$"),
        (lambda: cylaov.render(scene, accel=1), TypeError, r"^accel: must be a str, got int 1$"),
        (lambda: cylaov.render(scene, aovs="depth", precision=b"f64"), TypeError, r"^precision: must be a str, got bytes b'f64'$"),
        (lambda: cylaov.render(scene, None, 0, "f64", 7), TypeError, r"^formula: must be a str, got int 7$"),
        (lambda: cylaov.cast_rays(scene, [0, 0, 5], [[0, 0, -1]], formula=None), TypeError, r"^formula: must be a str, got NoneType None$"),
        (lambda: cylaov.write_shards(scene, "/nonexistent/x", force=1), TypeError, r"^force: must be a bool, got int 1$"),
        (lambda: cylaov.write_shards(scene, "/nonexistent/x", depth_scale="x"), TypeError, r"^depth_scale: must be a real number, got str 'x'$"),
        (lambda: cylaov.compare(ones, ones, rel_depth="x"), TypeError, r"^rel_depth: must be a real number, got str 'x'$"),
        (lambda: cylaov.Scene.from_table(TABLE, caps=0), TypeError, r"^caps: must be a bool, got int 0$"),
        (lambda: cylaov.Scene.from_table(TABLE, format=3), TypeError, r"^format: must be a str, got int 3$"),
        (lambda: cylaov.scan(scene, "vlp16", pose="0,0,1"), TypeError, r"^pose: \(x, y, z\) or \(x, y, z, yaw, pitch, roll\) in numbers, got str '0,0,1'$"),
        (lambda: cylaov.scan(scene, "vlp16", pose=(0, "a", 1)), TypeError, r"^pose\[1\]: must be a real number, got str 'a'$"),
        (lambda: cylaov.scan(scene, "vlp16", range_noise="x"), TypeError, r"^range_noise: must be a real number, got str 'x'$"),
        (lambda: cylaov.Dataset({"fov": float("nan")}, 0, 1), ValueError, r"^settings\['fov'\]: must be a finite number, got float nan$"),
        (lambda: cylaov.generate({"width": [object()]}, 0, 0), TypeError, r"^settings\['width'\]\[0\]: not JSON data .*, got object <object object at"),
        (lambda: cylaov.scan(scene, {"rotation_hz": float("inf")}), ValueError, r"^sensor\['rotation_hz'\]: must be a finite number, got float inf$"),
    ):
        with pytest.raises(exc, match=msg):
            call()
    # numpy numbers are numbers: in settings, and where a float or a bool goes.
    assert cylaov.generate({"width": np.int64(8), "height": np.int32(6)}, 0, 0) == \
        cylaov.generate({"width": 8, "height": 6}, 0, 0)
    assert cylaov.Scene.from_table(TABLE, caps=np.bool_(False)) == cylaov.Scene.from_table(TABLE, caps=False)
    a = cylaov.render(scene, aovs="depth")
    assert cylaov.compare(a, a, rel_depth=np.float32(0.5), normal_deg=1)["passed"]
    # The checked functions keep their signatures and help.
    assert str(inspect.signature(cylaov.render)).startswith("(scene, aovs=None, camera=0, precision='f64'")
    assert cylaov.render.__text_signature__.startswith("(scene, aovs=")
    assert "bit for bit" in cylaov.render.__doc__


def test_long_values_are_shortened_in_messages():
    scene = cylaov.Scene.load(SINGLE)
    for call, name in (
        (lambda: cylaov.render(scene, accel="x" * 10**6), "accel"),
        (lambda: cylaov.render(scene, aovs="x" * 10**6), "aovs[0]"),
        (lambda: cylaov.Scene.from_table(TABLE, label="z" * 10**5), "label"),
        (lambda: cylaov.render(scene, formula=["w" * 10**5]), "formula"),
    ):
        with pytest.raises((ValueError, TypeError)) as e:
            call()
        msg = str(e.value)
        assert msg.startswith(f"{name}: ") and len(msg) < 300 and "more)…" in msg, msg[:300]


def test_shard_count_shows_its_default():
    assert str(inspect.signature(cylaov.shard_count)) == "(input, shard_size=1000)"
    assert inspect.signature(cylaov.write_shards).parameters["shard_size"].default == 1000


def test_the_stub_admits_what_the_functions_take():
    stub = (ROOT / "python" / "cylaov" / "__init__.pyi").read_text()
    assert 'MemberName = Literal["exr", "depth.png", "ply"]' in stub
    assert 'Literal["csv", "npz", "treeqsm", "simpleforest", "archi"]' in stub
    assert "views_per_scene: Optional[int] = None" in stub


def test_cast_rays_takes_any_finite_direction_and_refuses_complex():
    scene = cylaov.Scene.load(SINGLE)
    o = [0.0, -5.0, 0.5]
    unit = cylaov.cast_rays(scene, o, [[0.0, 1.0, 0.0]])
    assert np.isfinite(unit["t_hit"][0])
    for scale in (1e300, 1e-300):
        got = cylaov.cast_rays(scene, o, [[0.0, scale, 0.0]])
        assert got["shape_id"][0] == unit["shape_id"][0]
        assert got["t_hit"][0] * scale == pytest.approx(unit["t_hit"][0], rel=1e-12)
        assert np.array_equal(got["normal"], unit["normal"])
    both = cylaov.cast_rays(scene, o, [[0.0, 1e200, 1e200]])
    assert both["t_hit"].shape == (1,)
    with pytest.raises(ValueError, match=r"^rays\[0\]\.direction: its length must be at most"):
        cylaov.cast_rays(scene, o, [[1.5e308, 1.5e308, 0.0]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ValueError, match=r"^directions: complex values; rays take real numbers$"):
            cylaov.cast_rays(scene, o, np.array([[1 + 5j, 0, 0]]))
        with pytest.raises(ValueError, match=r"^origins: complex values"):
            cylaov.cast_rays(scene, np.array([0j, 0, 0]), [[1.0, 0, 0]])
        with pytest.raises(ValueError, match=r"^t_max: complex values"):
            cylaov.cast_rays(scene, o, [[1.0, 0, 0]], t_max=np.array([1j]))


def test_ids_too_large_for_any_dtype_are_named_by_index():
    with pytest.raises(ValueError, match=r"^ids\[0\]: must be a whole number in 1\.\.=4294967295, got int 18446744073709551616$"):
        cylaov.Scene.from_arrays([[0, 0, 0], [1, 0, 0]], [[0, 0, 1], [1, 0, 1]], [0.5, 0.2],
                                 ids=[2**64, 2], camera=CAM)
    with pytest.raises(ValueError, match=r"^ids\[1\]: must be a whole number in 1\.\.=4294967295, got NoneType None$"):
        cylaov.Scene.from_arrays([[0, 0, 0], [1, 0, 0]], [[0, 0, 1], [1, 0, 1]], [0.5, 0.2],
                                 ids=[1, None], camera=CAM)


def test_read_gives_the_mask_where_the_files_aovs_tell_it(cli, tmp_path):
    cli("render", SINGLE, "-o", tmp_path / "pa.exr", "--aov", "depth,uv,label,position",
        "--exr-layout", "per-aov")
    mask = cylaov.read(tmp_path / "pa.depth.exr")["mask"]
    assert mask.any() and not mask.all()
    assert np.array_equal(mask, cylaov.render(cylaov.Scene.load(SINGLE), aovs="uv")["mask"])
    for aov in ("uv", "position"):
        got = cylaov.read(tmp_path / f"pa.{aov}.exr")
        assert np.array_equal(got["mask"], mask), aov
    # `label` 0 is also a cylinder without one: no mask to give.
    assert sorted(cylaov.read(tmp_path / "pa.label.exr")) == ["header", "label"]


def test_read_refuses_channels_it_cannot_interpret(tmp_path):
    OpenEXR = need("OpenEXR")

    def write(name, channels, **attrs):
        path = tmp_path / name
        header = {"type": OpenEXR.scanlineimage, **attrs}
        OpenEXR.File(header, channels).write(str(path))
        return path

    plane = np.ones((4, 5), np.float32)
    bad = (
        (write("y.exr", {"Y": plane}, **{"cylaov:channel:normal": "normal"}),
         r"y\.exr: its channels \[Y\] are not those of the AOV normal its header names \(cylaov:channel:normal\): \[R, G, B\]$"),
        (write("du.exr", {"depth": np.ones((4, 5), np.uint32)}),
         r"du\.exr: depth is stored as uint32; cylaov writes it as float32$"),
        (write("nx.exr", {"depth": plane, "normal.X": plane}),
         r"nx\.exr: channels \[normal\.X\] are of no whole AOV"),
        (write("a.exr", {"depth": plane, "A": plane}), r"a\.exr: channels \[A\] are of no whole AOV"),
    )
    for path, msg in bad:
        with pytest.raises(ValueError, match=msg):
            cylaov.read(path)
    # Whole AOVs read as they are: ids stored as float32 or uint32, a normal's three.
    good = write("ok.exr", {"depth": plane, "shape_id": plane, "normal.X": plane,
                            "normal.Y": plane * 0, "normal.Z": plane * 0})
    got = cylaov.read(good)
    assert got["shape_id"].dtype == np.uint32 and (got["shape_id"] == 1).all()
    assert got["normal"].shape == (4, 5, 3) and got["mask"].all()
