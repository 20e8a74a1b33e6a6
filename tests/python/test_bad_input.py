"""Bad scenes raise `SceneError` with the command line's message: the table the Rust test
reads (tests/data/bad_input.json), through `Scene.from_json` and `Scene.load`."""

import json

import pytest

import cylaov
from conftest import ROOT

CASES = json.loads((ROOT / "tests" / "data" / "bad_input.json").read_text())["cases"]


def data(case):
    return bytes.fromhex(case["bytes_hex"]) if "bytes_hex" in case else case["text"].encode()


def test_the_table_is_there():
    assert len(CASES) >= 37


@pytest.mark.parametrize("case", CASES, ids=lambda c: c["name"])
def test_bad_scene_raises_scene_error_with_the_cli_message(case, cli, tmp_path):
    raw = data(case)
    # From text (or bytes, for what is not UTF-8), with no path in the message.
    with pytest.raises(cylaov.SceneError) as e:
        cylaov.Scene.from_json(raw if "bytes_hex" in case else case["text"])
    msg = str(e.value)
    assert isinstance(e.value, ValueError)
    assert len(msg.splitlines()) == 1, msg
    for needle in case["needles"]:
        assert needle in msg, (needle, msg)
    # From a file: the command line's line without `error: `, word for word.
    path = tmp_path / f"{case['name']}.json"
    path.write_bytes(raw)
    with pytest.raises(cylaov.SceneError) as e:
        cylaov.Scene.load(path)
    r = cli("render", path, "-o", tmp_path / "x.exr", check=False)
    assert r.returncode == 1
    assert str(e.value) == r.stderr.strip().removeprefix("error: ")


def test_file_errors_are_os_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.json"):
        cylaov.Scene.load(tmp_path / "nope.json")
    with pytest.raises(IsADirectoryError, match="not a regular file but a folder"):
        cylaov.Scene.load(tmp_path)
    with pytest.raises(FileNotFoundError):
        cylaov.read(tmp_path / "nope.exr")
    (tmp_path / "bad.exr").write_bytes(b"not an exr")
    with pytest.raises(OSError, match="bad.exr"):
        cylaov.read(tmp_path / "bad.exr")


def test_from_arrays_validates_and_names_the_index():
    import numpy as np

    cam = {"origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1], "fov_deg": 40,
           "width": 32, "height": 24}
    p0 = np.zeros((3, 3))
    p1 = np.array([[0, 0, 1.0], [1, 0, 1], [0, 1, 1]])
    ok = cylaov.Scene.from_arrays(p0, p1, np.array([0.5, 0.2, 0.3]), caps=[True, False, True],
                                  camera=cam)
    assert len(ok) == 3 and ok.cameras[0]["width"] == 32
    want = cylaov.Scene.from_dict({"camera": cam, "cylinders": [
        {"p0": [0, 0, 0], "p1": list(b), "radius": r, "caps": c}
        for b, r, c in zip(p1.tolist(), [0.5, 0.2, 0.3], [True, False, True])]})
    assert ok == want
    with pytest.raises(cylaov.SceneError, match=r"cylinders\[1\]\.radius: must be > 0"):
        cylaov.Scene.from_arrays(p0, p1, np.array([0.5, -1, 0.3]), camera=cam)
    with pytest.raises(cylaov.SceneError, match=r"cylinders\[2\]\.p1: must differ from p0"):
        cylaov.Scene.from_arrays(p0, np.array([[0, 0, 1.0], [1, 0, 1], [0, 0, 0]]),
                                 np.ones(3), camera=cam)
    with pytest.raises(cylaov.SceneError, match=r"cylinders\[0\]\.id"):
        cylaov.Scene.from_arrays(p0, p1, np.ones(3), ids=np.array([0, 2, 3]), camera=cam)
    with pytest.raises(cylaov.SceneError, match="camera.fov_deg"):
        cylaov.Scene.from_arrays(p0, p1, np.ones(3), camera=dict(cam, fov_deg=0))
    with pytest.raises(ValueError, match=r"p1: shape must be \(3, 3\)"):
        cylaov.Scene.from_arrays(p0, p1[:2], np.ones(3), camera=cam)
