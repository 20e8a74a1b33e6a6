"""Bad calls raise exceptions of the package, never a panic, an abort or a hang: arrays of
different sizes, huge headers, FIFOs, thread counts; the mask beside a lone position; one
string for `aovs`; Ctrl-C during a long call; the array-likes `Scene.from_arrays` takes."""

import json
import os
import re
import signal
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


def test_the_largest_dataset_counts_its_views():
    """2**63 - 1 views, the most `len()` can return."""
    ds = cylaov.Dataset(None, 0, 2**63 - 1, aovs="depth")
    assert len(ds) == 2**63 - 1
    assert "depth" in ds[2**63 - 2]


def test_read_of_a_foreign_exr_says_what_it_expected(tmp_path):
    import OpenEXR

    path = tmp_path / "f.exr"
    px = np.zeros((4, 4), np.float32)
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"A": px, "Q": px}).write(str(path))
    with pytest.raises(ValueError, match=r"not one of cylaov's EXRs: its channels are \[A, Q\]; expected"):
        cylaov.read(path)


# ---- Ctrl-C during a long call -------------------------------------------------------------

# How long after SIGINT the call may take to raise KeyboardInterrupt: the calling thread
# looks for signals every 20 ms, and the work stops at its next band (a render), chunk of
# rays (cast_rays) or view (a tar). Measured on an idle 2-core VM: 4-18 ms (render,
# cast_rays, Dataset[i]), 44-64 ms (8 million rays: their finished chunks are freed) and
# 9-36 ms (write_shards, which also removes its temporary tar); 3-75 ms at a load average of
# 3. 0.5 s leaves several times that for a busy machine, and still fails a call that runs on
# to its end (seconds), or whose stop waits on work proportional to the work done so far.
LATENCY = 0.5

PRELUDE = """
import time
import cylaov
# A view that takes about 5 s on one core of a 2-core VM.
BIG = {"cylinders": "20000..20000", "width": 5000, "height": 5000}
def report(call):
    print("started", flush=True)
    t0 = time.monotonic()
    try:
        call()
    except KeyboardInterrupt:
        print("interrupted", time.monotonic(), time.monotonic() - t0, flush=True)
    else:
        print("finished", time.monotonic() - t0, flush=True)
"""


def _interrupt(code, wait=0.5, until=None):
    """Run PRELUDE + `code` in a new Python; once it prints "started" and `wait` seconds
    have passed (and then `until()` holds), send SIGINT. Returns (seconds from SIGINT to
    KeyboardInterrupt, the call's seconds, stderr)."""
    p = subprocess.Popen([sys.executable, "-c", PRELUDE + code], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert p.stdout.readline().strip() == "started", p.stderr.read()
        time.sleep(wait)
        deadline = time.monotonic() + 60
        while until is not None and not until() and time.monotonic() < deadline:
            time.sleep(0.01)
        sent = time.monotonic()
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=120)
    finally:
        p.kill()
    assert p.returncode == 0, err
    words = out.split()
    assert words[0] == "interrupted", f"the call was not interrupted: {out}{err}"
    latency, took = float(words[1]) - sent, float(words[2])
    assert took > wait  # the signal came while the call ran
    return latency, took, err


def test_ctrl_c_stops_a_render():
    # The first call that returns arrays in this process: numpy's API is loaded at import,
    # so the signal is a KeyboardInterrupt, never a panic.
    latency, took, err = _interrupt("""
scene = cylaov.generate(BIG, 1, 0)
report(lambda: cylaov.render(scene, aovs="depth", threads=1))
""")
    assert latency < LATENCY, latency
    assert "Panic" not in err, err


def test_ctrl_c_stops_cast_rays():
    # One origin a ray: the scene is prepared for each (about 1 ms), 5000 times.
    latency, took, err = _interrupt("""
import numpy as np
scene = cylaov.generate(BIG, 1, 0)
origins = np.random.default_rng(0).uniform(-20, 20, (5000, 3))
report(lambda: cylaov.cast_rays(scene, origins, -origins, threads=1))
""")
    assert latency < LATENCY, latency


def test_ctrl_c_stops_a_dataset_item():
    latency, took, err = _interrupt("""
ds = cylaov.Dataset(BIG, 1, 4, aovs="depth", threads=1)
report(lambda: ds[0])
""")
    assert latency < LATENCY, latency


def test_ctrl_c_stops_cast_rays_of_millions_of_rays():
    # 8 million rays from one origin through 200 cylinders, about 10 s on one core, stopped
    # while they are traced: a stop waits for the rays in flight, not for every ray's hit
    # to be filled and gathered (most of a second here).
    latency, took, err = _interrupt("""
import numpy as np
scene = cylaov.generate({"cylinders": "200..200"}, 1, 0)
dirs = np.random.default_rng(0).normal(size=(8_000_000, 3))
report(lambda: cylaov.cast_rays(scene, [0.1, 0.2, 0.3], dirs, threads=1))
""", wait=1.5)
    assert latency < LATENCY, latency


def _shard_input(path, views):
    """A folder holding one scene of 20 000 cylinders seen by `views` cameras: a view takes
    about 60 ms on one core (loading the scene, then the trace), its tar members 1.3 MB."""
    path.mkdir()
    scene = json.loads(cylaov.generate({"cylinders": "20000..20000", "width": 320,
                                        "height": 240}, 7, 0).to_json())
    cam = scene.pop("camera")
    x, y, z = cam["origin"]
    scene["cameras"] = [dict(cam, origin=[x + 0.01 * k, y, z]) for k in range(views)]
    (path / "scene.json").write_text(json.dumps(scene))
    return path


def _files(out):
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file()}


def test_ctrl_c_stops_write_shards_leaving_a_resumable_output(tmp_path):
    # 12 tars of 8 views: about 6 s on one core; interrupted once the first tar is done.
    data = _shard_input(tmp_path / "data", 96)
    out = tmp_path / "out"
    latency, took, err = _interrupt(f"""
report(lambda: cylaov.write_shards({str(data)!r}, {str(out)!r}, shard_size=8, aovs="depth",
                                   threads=1))
""", until=lambda: any(out.glob("shard-*.json")))
    assert latency < LATENCY, latency
    left = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    # Nothing staged is left: no .partial folder, no temporary file, no lock.
    assert not [p for p in left if ".partial" in p or p.endswith((".tmp", ".lock"))], left
    # Beside the dataset's settings record: the finished tars and their sidecars.
    assert "shards.settings.json" in left, left
    done = sorted(p for p in left if p.startswith("shard-") and p.endswith(".json"))
    assert done and len(done) < 12, left  # some tars finished, others not
    assert left == sorted(done + [p.replace(".json", ".tar") for p in done]
                          + ["shards.settings.json"])
    # The rerun skips the finished tars and writes the rest: the bytes of one run.
    again = cylaov.write_shards(data, out, shard_size=8, aovs="depth")
    assert again["skipped"] == [int(p[6:12]) for p in done]
    assert len(again["written"]) == 12 - len(done) and again["index_written"]
    whole = cylaov.write_shards(data, tmp_path / "whole", shard_size=8, aovs="depth")
    assert len(whole["written"]) == 12
    assert _files(out) == _files(tmp_path / "whole")


# ---- arguments -------------------------------------------------------------------------------

CAM = {"origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1], "fov_deg": 40,
       "width": 32, "height": 24}


def test_from_arrays_takes_any_real_array_like():
    want = cylaov.Scene.from_arrays(np.zeros((2, 3)), np.array([[0, 0, 1.0], [1, 0, 2.0]]),
                                    np.array([0.5, 0.25]), ids=np.array([7, 9]), camera=CAM)
    same = [
        # lists, int arrays, float32 arrays, uint32 / int8 / float ids with whole values
        ([[0, 0, 0], [0, 0, 0]], [[0, 0, 1], [1, 0, 2]], [0.5, 0.25], [7, 9]),
        (np.zeros((2, 3), np.int64), np.array([[0, 0, 1], [1, 0, 2]]),
         np.array([0.5, 0.25], np.float32), np.array([7, 9], np.uint32)),
        (np.zeros((2, 3), np.float32), np.array([[0, 0, 1], [1, 0, 2]], np.int32),
         (0.5, 0.25), np.array([7, 9], np.int8)),
        (np.zeros((3, 2)).T, np.array([[0, 0, 1], [1, 0, 2]], np.uint64), [0.5, 0.25],
         np.array([7.0, 9.0])),
        (np.zeros((2, 3)), np.array([[0, 0, 1], [1, 0, 2]]), [0.5, 0.25],
         np.array([7, 9], np.uint64)),
    ]
    for p0, p1, r, ids in same:
        got = cylaov.Scene.from_arrays(p0, p1, r, ids=ids, camera=CAM)
        assert got == want
        np.testing.assert_array_equal(cylaov.render(got, aovs="shape_id")["shape_id"],
                                      cylaov.render(want, aovs="shape_id")["shape_id"])
    assert 9 in cylaov.render(want, aovs="shape_id")["shape_id"]


def test_from_arrays_refuses_ids_that_are_not_whole_u32_values():
    p0, p1, r = np.zeros((2, 3)), [[0, 0, 1], [1, 0, 2]], [0.5, 0.25]
    for ids, at, shown in (([1, 1.5], 1, "1.5"), ([-1, 2], 0, "-1"), ([1, 2**32], 1, "4294967296"),
                           (np.array([3, 2**40], np.int64), 1, "1099511627776"),
                           (np.array([1, 2**64 - 1], np.uint64), 1, "18446744073709551615"),
                           ([1, float("nan")], 1, "NaN"), ([float("inf"), 1], 0, "inf")):
        with pytest.raises(ValueError, match=rf"^ids\[{at}\]: must be a whole number in "
                                             rf"1\.\.=4294967295, got {shown}$"):
            cylaov.Scene.from_arrays(p0, p1, r, ids=ids, camera=CAM)
    for ids, msg in (([True, False], r"ids: whole numbers in 1\.\.=4294967295, got an array of bool"),
                     (["a", "b"], r"ids: whole numbers in 1\.\.=4294967295, got an array of <U1"),
                     ([1, 2, 3], r"ids: shape must be \(2,\) for 2 radii, got \[3\]")):
        with pytest.raises(ValueError, match=msg):
            cylaov.Scene.from_arrays(p0, p1, r, ids=ids, camera=CAM)
    with pytest.raises(cylaov.SceneError, match=r"cylinders\[0\]\.id"):
        cylaov.Scene.from_arrays(p0, p1, r, ids=[0, 2], camera=CAM)
    with pytest.raises(ValueError, match=r"^p1: complex values"):
        cylaov.Scene.from_arrays(p0, np.ones((2, 3), complex), r, camera=CAM)
    with pytest.raises(ValueError, match=r"^radius: not an array of real numbers"):
        cylaov.Scene.from_arrays(p0, p1, ["a", None], camera=CAM)
    with pytest.raises(ValueError, match=r"^radius: shape must be \(N,\), got \[1, 2\]"):
        cylaov.Scene.from_arrays(p0, p1, [r], camera=CAM)


def test_from_arrays_with_several_cameras():
    cams = [CAM, dict(CAM, origin=[-3, 5, 2.5], width=16, height=12)]
    s = cylaov.Scene.from_arrays([[0, 0, 0]], [[0, 0, 1]], [0.5], cameras=cams)
    assert [c["width"] for c in s.cameras] == [32, 16]
    assert cylaov.render(s, aovs="depth", camera=1)["depth"].shape == (12, 16)
    with pytest.raises(IndexError, match="camera"):
        cylaov.render(s, camera=2)


def test_every_aovs_parameter_takes_one_name(tmp_path):
    scene = cylaov.Scene.load(SCENE)
    assert set(cylaov.render(scene, aovs="depth")) == {"depth", "mask"}
    assert set(cylaov.render(scene, aovs=["depth"])) == {"depth", "mask"}
    assert set(cylaov.cast_rays(scene, [0, 0, 5], [[0, 0, -1]], aovs="t_hit")) == {"t_hit"}
    assert cylaov.Dataset(None, 0, 1, aovs="depth").aovs == ("depth",)
    data = _shard_input(tmp_path / "data", 2)  # one tar of two views
    one = cylaov.write_shards(data, tmp_path / "one", aovs="depth", members="depth.png")
    seq = cylaov.write_shards(data, tmp_path / "seq", aovs=["depth"], members=["depth.png"])
    assert one["written"] == seq["written"] == [0]
    assert _files(tmp_path / "one") == _files(tmp_path / "seq")
    assert b"depth.png" in (tmp_path / "one" / "shard-000000.tar").read_bytes()
    for bad in (3, [3], None.__class__):
        with pytest.raises(TypeError, match="aovs: an AOV name or a sequence of AOV names"):
            cylaov.render(scene, aovs=bad)
        with pytest.raises(TypeError, match="aovs: an AOV name or a sequence of AOV names"):
            cylaov.write_shards(data, tmp_path / "bad", aovs=bad)
        with pytest.raises(TypeError, match="aovs: an AOV name or a sequence of AOV names"):
            cylaov.Dataset(None, 0, 1, aovs=bad)
        with pytest.raises(TypeError, match="aovs: a ray output name or a sequence of them"):
            cylaov.cast_rays(scene, [0, 0, 5], [[0, 0, -1]], aovs=bad)


def test_integer_arguments_name_themselves_and_their_value():
    """Negative, huge and fractional numbers raise ValueError or TypeError naming the
    argument and the value, not pyo3's nameless OverflowError; a Dataset index of any size
    out of range is an IndexError. (pytest matches the notes too: no `$`.)"""
    scene = cylaov.Scene.load(SCENE)
    for call, exc, msg in (
        (lambda: cylaov.render(scene, camera=-1), ValueError, r"^camera: must be >= 0, got -1"),
        (lambda: cylaov.render(scene, camera=1.0), TypeError, r"^camera: must be an integer, got float 1\.0"),
        (lambda: cylaov.render(scene, threads=-1), ValueError, r"^threads: must be in 1\.\.=1024, got -1"),
        (lambda: cylaov.render(scene, threads=2**70), ValueError, r"^threads: must be in 1\.\.=1024, got 1180591620717411303424"),
        (lambda: cylaov.render(scene, threads="2"), TypeError, r"^threads: must be an integer, got str '2'"),
        (lambda: cylaov.camera_info(scene, camera=-2), ValueError, r"^camera: must be >= 0, got -2"),
        (lambda: cylaov.camera_rays(scene, camera=-1), ValueError, r"^camera: must be >= 0, got -1"),
        (lambda: cylaov.cast_rays(scene, [0, 0, 5], [[0, 0, -1]], threads=-1), ValueError, r"^threads: must be in 1\.\.=1024, got -1"),
        (lambda: cylaov.generate(None, -1, 0), ValueError, r"^seed: must be >= 0, got -1"),
        (lambda: cylaov.generate(None, 0, 2**64), ValueError, r"^index: must be <= 18446744073709551615, got 18446744073709551616"),
        (lambda: cylaov.scan(scene, "vlp16", returns=1.5), TypeError, r"^returns: must be an integer, got float 1\.5"),
        (lambda: cylaov.scan(scene, "vlp16", seed=-1), ValueError, r"^seed: must be >= 0, got -1"),
        (lambda: cylaov.Dataset(None, -1, 4), ValueError, r"^seed: must be >= 0, got -1"),
        (lambda: cylaov.Dataset(None, 0, 4, threads=-1), ValueError, r"^threads: must be in 1\.\.=1024, got -1"),
        (lambda: cylaov.Dataset(None, 0, 4, views_per_scene=-2), ValueError, r"^views_per_scene: must be in 1\.\.=1000, got -2"),
        (lambda: cylaov.Dataset(None, 0, 4, views_per_scene=0), ValueError, r"^views_per_scene: must be in 1\.\.=1000, got 0"),
        (lambda: cylaov.Dataset(None, 0, 1.5), TypeError, r"^length: must be an integer, got float 1\.5"),
        (lambda: cylaov.Dataset(None, 0, -1), ValueError, r"^length: must be >= 0, got -1"),
        (lambda: cylaov.Dataset(None, 0, 2**64), ValueError, r"^length: must be <= 9223372036854775807, got 18446744073709551616"),
    ):
        with pytest.raises(exc, match=msg):
            call()
    # numpy integers are integers; the attributes keep Python ints.
    ds = cylaov.Dataset(None, np.uint64(3), np.int64(4), aovs="depth", threads=np.int32(1))
    assert (ds.seed, ds.length, ds.threads) == (3, 4, 1) and type(ds.length) is int
    assert cylaov.render(scene, aovs="depth", camera=np.int64(0), threads=np.uint8(1))["depth"].size
    for i in (4, -5, 2**63, -(2**63) - 1, 2**70):
        with pytest.raises(IndexError, match=rf"^index {i} out of range for a dataset of 4 views$"):
            ds[i]
        with pytest.raises(IndexError, match=rf"^index {i} out of range"):
            ds.__getitems__([0, i])
    assert np.array_equal(ds[-4]["depth"], ds[0]["depth"])


# Run in a child whose address space is capped at 2 GiB (so pytest survives whatever it
# does): each call needs more than that, and must raise MemoryError naming its size before
# it allocates, not end the process; a small render works after.
OUT_OF_MEMORY = """
import json, resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30))
import numpy as np
import cylaov

ALL = ("depth", "distance", "normal", "normal_camera", "position", "shape_id", "part", "label", "uv")
scene = json.load(open(sys.argv[1]))
small = cylaov.Scene.from_dict(scene)
scene["camera"].update(width=8192, height=8192)
big = cylaov.Scene.from_dict(scene)
settings = {"width": 8192, "height": 8192, "cylinders": "5..5"}
sensor = {"elevations_deg": [0.01 * k for k in range(1024)], "points_per_rotation": 2**20,
          "rotation_hz": 10, "min_range": 0.1, "max_range": 100}
calls = {
    # The directions (916 MiB) fit; the hits beside them (1.5 GiB) do not.
    "cast_rays": lambda: cylaov.cast_rays(small, [0, 0, 1], np.zeros((40_000_000, 3)),
                                          threads=2),
    "render": lambda: cylaov.render(big, aovs=ALL, threads=2),
    "Dataset[0]": lambda: cylaov.Dataset(settings, 0, 2, aovs=ALL, threads=2)[0],
    # The batch's buffer (960 MiB) fits; its three views' planes beside it do not.
    "Dataset.__getitems__": lambda: cylaov.Dataset(settings, 0, 3, aovs="depth", threads=2)
        .__getitems__([0, 1, 2]),
    "camera_rays": lambda: cylaov.camera_rays(big),
    "scan": lambda: cylaov.scan(small, sensor, threads=2),
}
for name, call in calls.items():
    try:
        call()
    except MemoryError as e:
        print(name, "|", e, flush=True)
    else:
        print(name, "| no error", flush=True)
out = cylaov.render(small, aovs=ALL, threads=2)
print("small render |", sorted(out) == sorted(ALL + ("mask",)) and bool(out["mask"].any()))
"""


def test_out_of_memory_is_a_memory_error_naming_the_size():
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1")
    p = subprocess.run([sys.executable, "-c", OUT_OF_MEMORY, str(SCENE)], capture_output=True,
                       text=True, cwd=ROOT, env=env, timeout=300)
    assert p.returncode == 0, p.stdout + p.stderr
    got = dict(line.split(" | ", 1) for line in p.stdout.splitlines())
    assert got.pop("small render") == "True", p.stdout
    names = "depth,distance,normal,normal_camera,position,shape_id,part,label,uv"
    sizes = {
        "render": rf"rendering 8192x8192 with {names} needs about 4160 MiB",
        "Dataset[0]": rf"rendering 8192x8192 with {names} needs about 4160 MiB",
        "Dataset.__getitems__": r"rendering 3 views of 8192x8192 with depth needs about 960 MiB",
        "camera_rays": r"the camera rays of 8192x8192 needs about 3072 MiB",
        "cast_rays": r"casting 40000000 rays needs about",
        "scan": r"a scan of up to 1073741824 points needs about",
    }
    assert set(got) == set(sizes), p.stdout
    for name, size in sizes.items():
        assert re.search(size, got[name]), (name, got[name])
