"""The package itself: version, help, pickling, the GIL, compare, the Mitsuba export."""

import pickle
import re
import threading
import time

import numpy as np
import pytest

import cylaov
from conftest import ROOT, SCENES


def test_version_is_the_crate_version():
    toml = (ROOT / "Cargo.toml").read_text()
    assert cylaov.__version__ == re.search(r'^version = "(.*)"', toml, re.M).group(1)


def test_internal_hooks_stay_out_of_the_public_module():
    """The tests' and the bench's hooks live in the private submodule `_testing` only."""
    import importlib

    assert not hasattr(cylaov._cylaov, "_oracle_cast")
    assert not hasattr(cylaov._cylaov, "_time_render")
    assert not [n for n in dir(cylaov) if n.startswith(("_oracle", "_time"))]
    assert not [n for n in dir(cylaov._cylaov) if n.startswith(("_oracle", "_time"))]
    from cylaov._cylaov import _testing
    assert importlib.import_module("cylaov._cylaov._testing") is _testing
    assert callable(_testing._oracle_cast) and callable(_testing._time_render)


def test_help_teaches():
    for f in (cylaov.render, cylaov.cast_rays, cylaov.camera_rays, cylaov.camera_info,
              cylaov.generate, cylaov.read, cylaov.compare, cylaov.Dataset, cylaov.Scene,
              cylaov.Scene.from_arrays):
        assert f.__doc__ and len(f.__doc__) > 120, f
    assert "bit for bit" in cylaov.render.__doc__
    assert "(H, W, 3) float32" in cylaov.render.__doc__
    assert "threads=1" in cylaov.Dataset.__doc__
    assert cylaov.render.__text_signature__.startswith("(scene, aovs=")
    assert issubclass(cylaov.SceneError, ValueError)
    stub = (ROOT / "python" / "cylaov" / "__init__.pyi").read_text()
    for name in cylaov.__all__:
        assert re.search(rf"^(def|class) {re.escape(name)}\b|^{re.escape(name)}:", stub, re.M), name


def test_scene_pickles_exactly_and_exports():
    for path in SCENES:
        s = cylaov.Scene.load(path)
        back = pickle.loads(pickle.dumps(s))
        assert back == s, path.stem
        a = cylaov.render(s, aovs=("distance",))["distance"]
        b = cylaov.render(back, aovs=("distance",))["distance"]
        assert np.array_equal(a.view(np.uint32), b.view(np.uint32))
    s = cylaov.Scene.load(SCENES[0])
    xml = s.to_mitsuba_xml()
    assert xml.lstrip().startswith("<") and "<sensor" in xml and xml.count('type="cylinder"') == len(s)
    assert cylaov.Scene.from_json(s.to_json()) == s or len(cylaov.Scene.from_json(s.to_json())) == len(s)


def test_the_gil_is_released_while_tracing():
    """A Python thread keeps counting while a large render runs."""
    big = cylaov.generate({"cylinders": 3000, "width": 1600, "height": 1200}, 1, 0)
    counts = []
    stop = threading.Event()

    def count():
        n = 0
        while not stop.is_set():
            n += 1
            if n % 1000 == 0:
                counts.append((time.perf_counter(), n))

    t = threading.Thread(target=count)
    t.start()
    time.sleep(0.05)
    t0 = time.perf_counter()
    cylaov.render(big, aovs=("depth", "normal", "shape_id"), threads=1)
    t1 = time.perf_counter()
    stop.set()
    t.join()
    during = [n for (ts, n) in counts if t0 <= ts <= t1]
    assert t1 - t0 > 0.05, "render too quick to tell"
    # Holding the GIL, the counter would stand still for the whole render.
    assert len(during) >= 10, (len(during), t1 - t0)


def test_compare_takes_dicts_and_paths(cli, tmp_path):
    path = next(p for p in SCENES if p.stem == "cluster")
    scene = cylaov.Scene.load(path)
    aovs = ("distance", "depth", "normal", "shape_id", "part")
    a = cylaov.render(scene, aovs=aovs)
    rep = cylaov.compare(a, a)
    assert rep["passed"] and rep["failures"] == []
    assert rep["report"]["pixels"] == 320 * 240
    cli("render", path, "-o", tmp_path / "a.exr", "--aov", ",".join(aovs))
    rep = cylaov.compare(tmp_path / "a.exr", a, scene=scene)
    assert rep["passed"] and rep["report"]["conditioned"]
    f32 = cylaov.render(scene, aovs=aovs, precision="f32", formula="literal")
    cli_json = cli("compare", tmp_path / "a.exr", tmp_path / "a.exr", "--json").stdout
    import json
    assert json.loads(cli_json)["tolerances"] == rep["tolerances"]
    strict = cylaov.compare(f32, a, rel_distance=0.0, rel_depth=0.0, normal_deg=0.0)
    assert not strict["passed"] and strict["failures"]
    assert strict["tolerances"]["rel_distance"] == 0.0
    with pytest.raises(TypeError, match="unknown option \"tolerance\""):
        cylaov.compare(a, a, tolerance=1)
    with pytest.raises(ValueError, match="rel_depth: must be >= 0"):
        cylaov.compare(a, a, rel_depth=-1)
