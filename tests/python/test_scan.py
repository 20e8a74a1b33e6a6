"""`cylaov scan`'s files read by their real consumers: laspy (LAS), Open3D (PLY), numpy (NPZ);
and `cylaov.scan`'s dict equal to the NPZ. (PDAL is not tested: the test machines' Debian has
no package of it and PyPI's `pdal` needs the C++ library.)"""

import json

import numpy as np
import pytest

import cylaov

# Two closed cylinders and an open tube around a sensor at 1.5 m: every return kind.
SCENE = {
    "camera": {"origin": [0, -30, 5], "target": [0, 0, 0], "up": [0, 0, 1],
               "fov_deg": 50, "width": 16, "height": 16},
    "cylinders": [
        {"p0": [4, 0, 0], "p1": [4, 0, 3], "radius": 0.5, "id": 1, "label": 5},
        {"p0": [-3, 2, 0], "p1": [-3, 2, 4], "radius": 0.8, "id": 2, "label": 300},
        {"p0": [0, -5, 0], "p1": [0, -5, 2], "radius": 1.0, "caps": False, "id": 3, "label": 12},
    ],
}
ARGS = ("--sensor", "vlp16", "--pose", "0.2,0.1,1.5,30,0,0", "--returns", "3",
        "--range-noise", "0.01", "--dropout", "0.1", "--seed", "4")


@pytest.fixture(scope="module")
def scanned(tmp_path_factory, cli):
    d = tmp_path_factory.mktemp("scan")
    scene = d / "scene.json"
    scene.write_text(json.dumps(SCENE))
    for ext in ("las", "ply", "npz"):
        cli("scan", scene, *ARGS, "-o", d / f"scan.{ext}")
    return d, np.load(d / "scan.npz")


def test_npz_columns(scanned):
    _, z = scanned
    n = len(z["x"])
    assert n > 1000
    assert z["x"].dtype == np.float64 and z["ring"].dtype == np.uint32
    assert z["normal"].shape == (n, 3) and z["normal"].dtype == np.float32
    # Closed cylinders crossed give two returns; nothing gives more than two here.
    assert set(np.unique(z["num_returns"])) <= {1, 2}
    assert np.all(z["return_index"] <= z["num_returns"])
    # xyz lie on the beam at the noisy range from the pose.
    p = np.stack([z["x"] - 0.2, z["y"] - 0.1, z["z"] - 1.5], axis=1)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), z["range"], rtol=1e-12)
    # Noise sigma 0.01: |noise| < 6 sigma everywhere (n ~ 1e4 draws: P(> 6 sigma) ~ 2e-9 each).
    assert np.max(np.abs(z["range"] - z["range_exact"])) < 0.06
    assert set(np.unique(z["label"])) == {5, 300, 12}


def test_las_read_by_laspy(scanned):
    laspy = pytest.importorskip("laspy")
    d, z = scanned
    las = laspy.read(d / "scan.las")
    assert las.header.version.major == 1 and las.header.version.minor == 4
    assert las.header.point_format.id == 6
    assert len(las.points) == len(z["x"])
    # 0.1 mm steps: half a step of rounding.
    for k in "xyz":
        np.testing.assert_allclose(np.asarray(getattr(las, k)), z[k], atol=0.5e-4 + 1e-9)
    np.testing.assert_array_equal(np.asarray(las.return_number), z["return_index"])
    np.testing.assert_array_equal(np.asarray(las.number_of_returns), z["num_returns"])
    np.testing.assert_array_equal(np.asarray(las.gps_time), z["time"])
    # Classification: the label clipped to 255; label 12 (LAS's overlap code) as class 1
    # with the overlap flag.
    want = np.minimum(z["label"], 255)
    overlap = want == 12
    cls = np.asarray(las.classification)
    np.testing.assert_array_equal(cls[~overlap], want[~overlap])
    assert np.all(cls[overlap] == 1) and np.all(np.asarray(las.overlap)[overlap] == 1)
    # Extra bytes carry the rest at full precision.
    np.testing.assert_array_equal(np.asarray(las.ring), z["ring"])
    np.testing.assert_array_equal(np.asarray(las.shape_id), z["shape_id"])
    np.testing.assert_array_equal(np.asarray(las.label), z["label"])
    np.testing.assert_array_equal(np.asarray(las.range_exact), z["range_exact"])
    np.testing.assert_array_equal(np.asarray(las.point_source_id), z["ring"])
    # Scan angle: the beam's elevation, in 0.006 degree steps.
    np.testing.assert_allclose(np.asarray(las.scan_angle) * 0.006, z["elevation"], atol=0.003)


def test_a_scan_with_no_points_is_an_empty_las_with_a_finite_box(tmp_path, cli):
    # Every return dropped: the header's box was +inf..-inf on every axis.
    laspy = pytest.importorskip("laspy")
    scene = tmp_path / "scene.json"
    scene.write_text(json.dumps(SCENE))
    cli("scan", scene, "--sensor", "vlp16", "--dropout", "1", "-o", tmp_path / "e.las")
    las = laspy.read(tmp_path / "e.las")
    assert len(las.points) == 0 and las.header.point_count == 0
    assert list(las.header.mins) == [0, 0, 0] and list(las.header.maxs) == [0, 0, 0]


def test_ply_read_by_open3d(scanned):
    o3d = pytest.importorskip("open3d")
    d, z = scanned
    pc = o3d.io.read_point_cloud(str(d / "scan.ply"))
    pts = np.asarray(pc.points)
    assert pts.shape == (len(z["x"]), 3)
    np.testing.assert_array_equal(pts, np.stack([z["x"], z["y"], z["z"]], axis=1))
    assert pc.has_normals()
    np.testing.assert_array_equal(np.asarray(pc.normals), z["normal"].astype(np.float64))


def test_python_scan_equals_the_npz(scanned):
    d, z = scanned
    scene = cylaov.Scene.from_dict(SCENE)
    got = cylaov.scan(scene, "vlp16", pose=(0.2, 0.1, 1.5, 30, 0, 0), returns=3,
                      range_noise=0.01, dropout=0.1, seed=4, threads=2)
    assert sorted(got) == sorted(z.files)
    for k in z.files:
        assert got[k].dtype == z[k].dtype, k
        np.testing.assert_array_equal(got[k], z[k], err_msg=k)


def test_python_scan_sensor_dict_and_errors():
    scene = cylaov.Scene.from_dict(SCENE)
    sensor = {"elevations_deg": [0.0], "points_per_rotation": 4, "rotation_hz": 10,
              "min_range": 0.1, "max_range": 50}
    got = cylaov.scan(scene, sensor, pose=(0, 0, 1.5))
    # Azimuth 0 along +x hits the first cylinder's side at x = 3.5.
    assert got["x"][0] == pytest.approx(3.5, abs=1e-12) and got["shape_id"][0] == 1
    with pytest.raises(ValueError, match=r"sensor.elevations_deg\[0\]: 95 is outside -90..90"):
        cylaov.scan(scene, dict(sensor, elevations_deg=[95]))
    with pytest.raises(ValueError, match="returns: must be in 1..=15, got 0"):
        cylaov.scan(scene, "vlp16", returns=0)
    with pytest.raises(ValueError, match="not a preset"):
        cylaov.scan(scene, "vlp17")
    # A trajectory as rows: the same as a fixed pose when it stands still.
    rows = np.array([[0, 0, 0, 1.5, 0, 0, 0], [1, 0, 0, 1.5, 0, 0, 0]], dtype=float)
    still = cylaov.scan(scene, sensor, trajectory=rows)
    np.testing.assert_allclose(still["x"], got["x"], rtol=1e-12)


def test_python_scan_trajectory_rows_are_named_by_row():
    scene = cylaov.Scene.from_dict(SCENE)
    rows = np.array([[0, 0, 0, 1.5, 0, 0, 0], [1, 0, 0, 1.5, 0, 0, 0]], dtype=float)
    # Rows were named as the CSV made of them: row 0 as "line 2".
    bad = rows.copy()
    bad[0, 2] = np.nan
    with pytest.raises(ValueError, match=r"^trajectory\[0, 2\]: must be a finite number, got nan$"):
        cylaov.scan(scene, "vlp16", trajectory=bad)
    late = rows.copy()
    late[1, 0] = 0
    with pytest.raises(ValueError, match=r"^trajectory\[1\]: time 0 must be after the previous row's 0$"):
        cylaov.scan(scene, "vlp16", trajectory=late)
    # A text cell: numpy's own message, named.
    with pytest.raises(ValueError, match=r"^trajectory: not an array of real numbers"):
        cylaov.scan(scene, "vlp16", trajectory=[["t", 0, 0, 0, 0, 0, 0]])
    # A pose beside a trajectory was ignored; the command line refuses the two together.
    with pytest.raises(ValueError, match="pose: give pose or trajectory, not both"):
        cylaov.scan(scene, "vlp16", pose=(3, 3, 3), trajectory=rows)
