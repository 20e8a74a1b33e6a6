"""Bad calls raise exceptions of the package, never a panic, an abort or a hang: arrays of
different sizes, huge headers, FIFOs, thread counts; the mask beside a lone position; one
string for `aovs`."""

import os
import subprocess
import sys
import time

import numpy as np
import pytest

import cylaov
from conftest import ROOT

SCENE = ROOT / "scenes" / "cluster.json"


def test_compare_refuses_dicts_of_different_sizes():
    a = {"depth": np.ones((10, 10), np.float32), "shape_id": np.ones((5, 5), np.uint32)}
    with pytest.raises(ValueError, match=r"different sizes: \"shape_id\" is 5 x 5, the AOVs before it 10 x 10"):
        cylaov.compare(a, a)
    b = {"depth": np.ones((5, 5), np.float32), "normal": np.ones((10, 10, 3), np.float32)}
    with pytest.raises(ValueError, match="different sizes"):
        cylaov.compare(b, b)


def _huge_exr(cli, tmp_path):
    """A cylaov EXR whose header claims 80 000 x 80 000 pixels."""
    path = tmp_path / "a.exr"
    cli("render", SCENE, "-o", path, "--aov", "depth")
    data = bytearray(path.read_bytes())
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    data[at:at + 16] = np.array([0, 0, 79999, 79999], "<i4").tobytes()
    path.write_bytes(bytes(data))
    return path


def test_a_huge_header_is_refused_not_an_abort(cli, tmp_path):
    path = _huge_exr(cli, tmp_path)
    with pytest.raises((MemoryError, OSError)):
        cylaov.read(path)
    with pytest.raises((MemoryError, OSError)):
        cylaov.compare(path, path)


def test_a_fifo_is_refused_not_read(tmp_path):
    fifo = tmp_path / "f.exr"
    os.mkfifo(fifo)
    code = ("import cylaov, sys\n"
            "for f in (lambda: cylaov.read(sys.argv[1]), lambda: cylaov.compare(sys.argv[1], sys.argv[1])):\n"
            "    try:\n        f()\n    except OSError as e:\n        assert 'not a regular file' in str(e), e\n"
            "    else:\n        raise SystemExit('no error')\n")
    r = subprocess.run([sys.executable, "-c", code, str(fifo)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0, r.stderr


def test_mask_beside_a_lone_position(cli, tmp_path):
    scene = cylaov.Scene.load(SCENE)
    want = cylaov.render(scene, aovs=("depth",))["mask"]
    assert want.any() and not want.all()
    out = cylaov.render(scene, aovs=("position",))
    assert set(out) == {"position", "mask"}
    np.testing.assert_array_equal(out["mask"], want)
    item = cylaov.Dataset(None, 3, 2, aovs=("position",))[1]
    np.testing.assert_array_equal(item["mask"], cylaov.Dataset(None, 3, 2, aovs="depth")[1]["mask"])
    cli("render", SCENE, "-o", tmp_path / "x.exr", "--aov", "position", "--aov", "depth",
        "--exr-layout", "per-aov")
    got = cylaov.read(next(tmp_path.glob("x*position*.exr")))
    np.testing.assert_array_equal(got["mask"], want)


def test_mask_beside_a_lone_label():
    # label 0 is a miss and an unlabelled cylinder alike: the mask comes from depth.
    scene = cylaov.Scene.load(SCENE)
    want = cylaov.render(scene, aovs="depth")["mask"]
    out = cylaov.render(scene, aovs="label")
    assert set(out) == {"label", "mask"}
    np.testing.assert_array_equal(out["mask"], want)
    assert not out["label"].any()  # the scene gives no labels


def test_threads_are_bounded_and_pools_do_not_pile_up():
    scene = cylaov.Scene.load(SCENE)
    for bad in (0, 1025, 10**9):
        with pytest.raises(ValueError, match=r"threads: must be in 1\.\.=1024"):
            cylaov.render(scene, threads=bad)
    for n in range(2, 13):
        cylaov.render(scene, aovs="depth", threads=n)
    time.sleep(0.5)
    # 77 threads if every pool were kept; at most the four largest (42) and this thread.
    assert len(os.listdir("/proc/self/task")) < 60


def test_a_string_is_one_aov_everywhere():
    scene = cylaov.Scene.load(SCENE)
    assert set(cylaov.render(scene, aovs="depth")) == {"depth", "mask"}


def test_a_dataset_of_2_63_views_counts_them():
    ds = cylaov.Dataset(None, 0, 2**63, aovs="depth")
    assert "depth" in ds[2**63 - 1]


def test_read_of_a_foreign_exr_says_what_it_expected(tmp_path):
    import OpenEXR

    path = tmp_path / "f.exr"
    px = np.zeros((4, 4), np.float32)
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"A": px, "Q": px}).write(str(path))
    with pytest.raises(ValueError, match=r"not one of cylaov's EXRs: its channels are \[A, Q\]; expected"):
        cylaov.read(path)
