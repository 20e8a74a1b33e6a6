"""The `uv` AOV, the two-channel AOV: Mitsuba 3's own uv on every side pixel, and the files
and arrays its two channels become (layered and per-AOV EXR read by OpenEXR and OpenCV,
numpy arrays, tar shard members)."""

import io
import json
import subprocess
import sys
import tarfile

import numpy as np
import pytest

import cylaov
from conftest import ROOT, exr_channels, need

# Scenes with side pixels of every kind: outside and inside walls, rims, grazing rows, a
# far camera, the orthographic sensor.
MITSUBA_SCENES = ["single", "asymmetric", "cluster", "tube_inside", "rims", "grazing_fence",
                  "axis_view", "far_camera", "mixed_caps", "rim_seam", "near_clip",
                  "orthographic"]


def test_side_uv_agrees_with_mitsuba(cli, tmp_path):
    """Mitsuba's `uv` AOV (the reference script's `--aov uv`) and cylaov's agree on every
    pixel both hit on the same cylinder's side, `u` taken modulo 1, as `compare` reports it.

    Measured over these 12 scenes (196 000 side pixels): worst 2.4e-4 (far_camera, where
    Mitsuba's float32 hit point is coarse), p99 at most 3.0e-5, median at most 5.1e-6. A
    wrong frame or convention (u from another axis, v from p1, u not wrapped) is off by 0.1
    or more on most pixels.
    """
    need("mitsuba")
    total = 0
    for name in MITSUBA_SCENES:
        scene = ROOT / "scenes" / f"{name}.json"
        ours, xml, ref = (tmp_path / f"{name}.exr", tmp_path / f"{name}.xml",
                          tmp_path / f"{name}.ref.exr")
        cli("render", scene, "-o", ours, "--aov", "uv,shape_id,part,distance")
        cli("export-mitsuba", scene, "-o", xml)
        subprocess.run([sys.executable, ROOT / "scripts" / "mitsuba_reference.py", xml, scene,
                        ref, "--aov", "uv"], check=True, capture_output=True)
        assert {"uv.U", "uv.V"} <= set(exr_channels(ref))
        report = json.loads(cli("compare", ours, ref, "--json").stdout)["report"]
        uv = report["uv_side"]
        assert uv["count"] > 4000, (name, uv)
        assert uv["max"] < 1e-3, (name, uv)
        assert uv["p99"] < 1e-4, (name, uv)
        assert uv["median"] < 2e-5, (name, uv)
        total += uv["count"]
    assert total > 190_000


def test_uv_values_arrays_and_files(cli, tmp_path, monkeypatch):
    """One scene, every container: the numpy array is the EXR's two channels bit for bit;
    u lies in [0, 1), v in [0, 1], a miss is (0, 0); a cap's v is the hit's distance from
    the axis over the radius (from `position`, by numpy); OpenCV reads the per-AOV file
    as B, G, R with B = 0, G = v, R = u; a tar shard's member is (H, W, 2) float32."""
    path = ROOT / "scenes" / "single.json"
    got = cylaov.render(cylaov.Scene.load(path), aovs=("uv", "part", "position"))
    uv, part, pos = got["uv"], got["part"], got["position"]
    assert uv.shape == (240, 320, 2) and uv.dtype == np.float32
    hit = got["mask"]
    assert hit.sum() > 8000
    assert (uv[~hit] == 0).all()
    assert 0.0 <= uv[..., 0].min() and uv[..., 0].max() < 1.0
    assert 0.0 <= uv[..., 1].min() and uv[..., 1].max() <= 1.0
    # Around the whole visible side: u spans more than a third of a turn.
    side = hit & ((part == 1) | (part == 2))
    assert np.ptp(uv[..., 0][side]) > 0.33
    # The cylinder runs along +z from the origin, radius 0.5, height 1.5.
    cap = (part == 3) | (part == 4)
    assert cap.sum() > 500
    r = np.hypot(pos[..., 0], pos[..., 1]).astype(np.float64)
    assert np.abs(uv[..., 1][cap] - r[cap] / 0.5).max() < 1e-5
    assert np.abs(uv[..., 1][side] - pos[..., 2][side] / 1.5).max() < 1e-5

    exr = tmp_path / "v.exr"
    cli("render", path, "-o", exr, "--aov", "uv")
    ch = exr_channels(exr)
    assert np.array_equal(ch["uv.U"].view(np.uint32), uv[..., 0].view(np.uint32))
    assert np.array_equal(ch["uv.V"].view(np.uint32), uv[..., 1].view(np.uint32))

    cli("render", path, "-o", tmp_path / "p.exr", "--aov", "uv", "--exr-layout", "per-aov")
    monkeypatch.setenv("OPENCV_IO_ENABLE_OPENEXR", "1")
    cv2 = need("cv2")
    img = cv2.imread(str(tmp_path / "p.uv.exr"), cv2.IMREAD_UNCHANGED)
    assert img.shape == (240, 320, 3) and img.dtype == np.float32
    assert (img[..., 0] == 0).all()
    assert np.array_equal(img[..., 2], uv[..., 0]) and np.array_equal(img[..., 1], uv[..., 1])
    back = cylaov.read(tmp_path / "p.uv.exr")
    assert np.array_equal(back["uv"], uv)

    data, out = tmp_path / "data", tmp_path / "shards"
    cli("generate", "--count", 3, "--seed", 4, "--cylinders", 10, "--width", 40, "--height",
        30, "--out", data)
    cli("batch", data, "--out", out, "--format", "webdataset", "--aov", "depth,uv")
    with tarfile.open(out / "shard-000000.tar") as t:
        members = [m for m in t.getmembers() if m.name.endswith(".uv.npy")]
        assert len(members) == 3
        arr = np.load(io.BytesIO(t.extractfile(members[0]).read()))
    assert arr.shape == (30, 40, 2) and arr.dtype == np.float32
    assert "uv" in json.loads((out / "shards.json").read_text())["aovs"]


def test_the_stub_lists_every_aov():
    """`__init__.pyi`'s `AovName` names exactly the AOVs `render` accepts (its error lists
    them), so type checkers know every AOV, `uv` and `label` included."""
    import re

    with pytest.raises(ValueError) as e:
        cylaov.render(cylaov.Scene.load(ROOT / "scenes" / "single.json"), aovs=("nope",))
    accepted = str(e.value).split("one of ")[1].split(", ")
    stub = (ROOT / "python" / "cylaov" / "__init__.pyi").read_text()
    named = re.findall(r'"(\w+)"', re.search(r"AovName = Literal\[(.*)\]", stub).group(1))
    assert named == accepted
    assert "uv" in accepted
