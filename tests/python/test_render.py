"""`render` is, bit for bit, the EXR `cylaov render` writes; `read` gives it back."""

import numpy as np
import pytest

import cylaov
from conftest import ALL_AOVS, SCENES, exr_channels

CHANNELS = {
    "distance": ["distance"],
    "depth": ["depth"],
    "normal": ["normal.X", "normal.Y", "normal.Z"],
    "position": ["position.X", "position.Y", "position.Z"],
    "shape_id": ["shape_id"],
    "part": ["part"],
    "normal_camera": ["normal_camera.X", "normal_camera.Y", "normal_camera.Z"],
}


def bits(a):
    a = np.ascontiguousarray(a)
    return a.view(np.uint32) if a.dtype == np.float32 else a


@pytest.mark.parametrize("path", SCENES, ids=lambda p: p.stem)
def test_render_is_the_cli_exr_bit_for_bit(path, cli, tmp_path):
    scene = cylaov.Scene.load(path)
    for camera in range(len(scene.cameras)):
        exr = tmp_path / f"{path.stem}_{camera}.exr"
        cli("render", path, "-o", exr, "--aov", ",".join(ALL_AOVS), "--camera", camera)
        want = exr_channels(exr)
        got = cylaov.render(scene, aovs=ALL_AOVS, camera=camera)
        h, w = scene.cameras[camera]["height"], scene.cameras[camera]["width"]
        assert set(got) == set(ALL_AOVS) | {"mask"}
        for aov, names in CHANNELS.items():
            arr = got[aov]
            assert arr.shape == ((h, w) if len(names) == 1 else (h, w, 3)), aov
            assert arr.dtype == (np.uint32 if aov in ("shape_id", "part") else np.float32), aov
            for k, name in enumerate(names):
                plane = arr if len(names) == 1 else arr[..., k]
                ref = want[name].reshape(h, w)
                assert np.array_equal(bits(plane), bits(ref)), f"{path.stem} camera {camera}: {name}"
        assert got["mask"].dtype == np.bool_
        assert np.array_equal(got["mask"], got["depth"] > 0)
        assert got["mask"].any(), f"{path.stem}: no hit at all"
        # `read` gives the file back as the same arrays.
        back = cylaov.read(exr)
        for aov in ALL_AOVS + ("mask",):
            assert np.array_equal(bits(back[aov]), bits(got[aov])), aov
        assert back["header"]["cylaov:version"] == cylaov.__version__


def test_read_per_aov_files(cli, tmp_path):
    path = SCENES[0]
    cli("render", path, "-o", tmp_path / "v.exr", "--aov", "depth,normal,shape_id",
        "--exr-layout", "per-aov")
    got = cylaov.render(cylaov.Scene.load(path), aovs=("depth", "normal", "shape_id"))
    for aov in ("depth", "normal", "shape_id"):
        one = cylaov.read(tmp_path / f"v.{aov}.exr")
        assert set(one) == {aov, "mask", "header"}
        assert np.array_equal(bits(one[aov]), bits(got[aov])), aov
        assert np.array_equal(one["mask"], got["mask"])


def test_arrays_own_the_rust_buffers():
    """No copy: each array's memory belongs to a Rust container object, not to numpy."""
    out = cylaov.render(cylaov.Scene.load(SCENES[0]), aovs=("depth", "normal", "shape_id"))
    for name, arr in out.items():
        assert not arr.flags.owndata, name
        base = arr.base
        while isinstance(base, np.ndarray):
            base = base.base
        assert type(base).__name__ == "PySliceContainer", (name, type(base))


def test_options_and_their_errors():
    scene = cylaov.Scene.load(SCENES[0])
    ref = cylaov.render(scene, aovs=("distance",))["distance"]
    for accel in ("tiles", "frustum", "bvh"):
        got = cylaov.render(scene, aovs=("distance",), accel=accel, threads=1)["distance"]
        assert np.array_equal(bits(got), bits(ref)), accel
    f32 = cylaov.render(scene, aovs=("distance",), precision="f32")["distance"]
    hit = ref > 0
    assert np.max(np.abs(f32[hit] - ref[hit]) / ref[hit]) < 1e-4
    with pytest.raises(ValueError, match=r"aovs\[1\]: unknown AOV \"albedo\""):
        cylaov.render(scene, aovs=("depth", "albedo"))
    with pytest.raises(ValueError, match="precision"):
        cylaov.render(scene, precision="f16")
    with pytest.raises(IndexError, match="1 camera"):
        cylaov.render(scene, camera=3)
    with pytest.raises(ValueError, match="threads"):
        cylaov.render(scene, threads=0)


def test_camera_info_is_the_camera_json(cli, tmp_path):
    import json

    path = SCENES[0]
    cli("render", path, "-o", tmp_path / "v.exr")
    want = json.loads((tmp_path / "v.camera.json").read_text())
    got = cylaov.camera_info(cylaov.Scene.load(path))
    for key in ("K", "K_opencv", "camera_to_world_opencv", "camera_to_world_opengl", "width", "height"):
        assert got[key] == want[key], key
    w, h = got["width"], got["height"]
    assert got["K"][0][2] == w / 2 and got["K_opencv"][0][2] == w / 2 - 0.5
    assert np.allclose(np.array(got["camera_to_world_opencv"])[:3, 3], cylaov.Scene.load(path).cameras[0]["origin"])
