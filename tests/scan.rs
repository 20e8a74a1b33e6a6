//! `cylaov scan`: presets, sensor errors, poses, multiple returns, noise, trajectories,
//! and every return against the double-double oracle's k-th intersection along its beam.

// Points are parallel columns (`d["x"][i]`, `d["range"][i]`, ...) read at one index.
#![allow(clippy::needless_range_loop)]

mod common;

use common::{cylaov, fresh_dir, ok};
use cylaov::scan::{Motion, Noise, Pose, ScanOptions, Sensor, Trajectory, beam_dir, scan};
use cylaov::scene;
use cylaov::verify::oracle::{self, DD, Problem};
use glam::DVec3;
use std::collections::BTreeMap;
use std::path::Path;

/// The arrays of an `.npz` as cylaov writes it (stored members, `.npy` 1.0), as f64.
fn read_npz(path: &Path) -> BTreeMap<String, Vec<f64>> {
    let b = std::fs::read(path).unwrap();
    let u16_at = |i: usize| u16::from_le_bytes([b[i], b[i + 1]]) as usize;
    let u32_at = |i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap()) as usize;
    let mut out = BTreeMap::new();
    let mut at = 0;
    while b[at..at + 4] == *b"PK\x03\x04" {
        let (size, name_len) = (u32_at(at + 18), u16_at(at + 26));
        let name = String::from_utf8(b[at + 30..at + 30 + name_len].to_vec()).unwrap();
        let data = &b[at + 30 + name_len..at + 30 + name_len + size];
        let head = 10 + u16::from_le_bytes([data[8], data[9]]) as usize;
        let dict = String::from_utf8_lossy(&data[10..head]).into_owned();
        let body = &data[head..];
        let values: Vec<f64> = if dict.contains("<f8") {
            body.chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
                .collect()
        } else if dict.contains("<f4") {
            body.chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()) as f64)
                .collect()
        } else {
            body.chunks_exact(4)
                .map(|c| u32::from_le_bytes(c.try_into().unwrap()) as f64)
                .collect()
        };
        out.insert(name.trim_end_matches(".npy").to_string(), values);
        at += 30 + name_len + size;
    }
    out
}

fn write(dir: &Path, name: &str, text: &str) -> String {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p.to_str().unwrap().to_string()
}

/// Open tubes (no caps) along z, centred on the origin, of the given radii, heights
/// `-half..half`; ids 1, 2, ... in order.
fn tubes(radii: &[f64], half: f64) -> String {
    let cyl: Vec<String> = radii
        .iter()
        .enumerate()
        .map(|(i, r)| {
            format!(
                r#"{{"p0": [0, 0, {}], "p1": [0, 0, {half}], "radius": {r}, "caps": false, "id": {}, "label": {}}}"#,
                -half,
                i + 1,
                10 + i
            )
        })
        .collect();
    format!(
        r#"{{"camera": {{"origin": [0, -50, 0], "target": [0, 0, 0], "up": [0, 0, 1], "fov_deg": 40, "width": 8, "height": 8}},
"cylinders": [{}]}}"#,
        cyl.join(",\n")
    )
}

/// A sensor of one flat beam (or the given elevations) and `steps` azimuth steps.
fn flat_sensor(elevations: &str, steps: u32) -> String {
    format!(
        r#"{{"name": "flat", "elevations_deg": [{elevations}], "points_per_rotation": {steps},
"rotation_hz": 10, "min_range": 0.1, "max_range": 200}}"#
    )
}

/// Inside a tall open tube of radius 20, every beam of every preset hits its inside wall
/// once, at range 20 / cos(elevation); rings, azimuths and times follow the datasheet.
#[test]
fn presets_inside_a_tube() {
    let dir = fresh_dir("scan", "presets");
    let scene = write(dir.path(), "tube.json", &tubes(&[20.0], 50.0));
    for (name, beams, steps, lo, hi) in [
        ("vlp16", 16, 1800, -15.0, 15.0),
        ("hdl32", 32, 2250, -30.67, 10.67),
        ("os1-64", 64, 1024, -16.6, 16.6),
    ] {
        let out = dir.path().join(format!("{name}.npz"));
        ok(&[
            "scan",
            &scene,
            "--sensor",
            name,
            "-o",
            out.to_str().unwrap(),
        ]);
        let d = read_npz(&out);
        assert_eq!(d["x"].len(), beams * steps, "{name}");
        let ring_max = d["ring"].iter().cloned().fold(0.0, f64::max);
        assert_eq!(ring_max, (beams - 1) as f64);
        let el = &d["elevation"];
        assert_eq!(el.iter().cloned().fold(f64::INFINITY, f64::min), lo);
        assert!((el.iter().cloned().fold(f64::NEG_INFINITY, f64::max) - hi).abs() < 1e-12);
        // Times: step s at s / steps / 10 Hz; the last step just under a tenth of a second.
        let tmax = d["time"].iter().cloned().fold(0.0, f64::max);
        assert!((tmax - (steps - 1) as f64 / steps as f64 / 10.0).abs() < 1e-15);
        for i in 0..d["x"].len() {
            let want = 20.0 / el[i].to_radians().cos();
            // The kernel's range: a few ulp of 20 over the rounding of cos (1e-15 relative).
            assert!(
                (d["range"][i] - want).abs() < 1e-12 * want,
                "{name} point {i}"
            );
            assert_eq!(d["part"][i], 2.0, "inside wall");
            assert_eq!(d["label"][i], 10.0);
        }
        // Ring r of step s: azimuth s * 360 / steps (no offsets in the presets).
        let k = 5 * beams + 3;
        assert!((d["azimuth"][k] - 5.0 * 360.0 / steps as f64).abs() < 1e-12);
        assert_eq!(d["ring"][k], 3.0);
    }
}

/// A bad sensor file is refused naming the field and value, exit 1, nothing written.
#[test]
fn bad_sensor_files_name_the_field() {
    let dir = fresh_dir("scan", "bad");
    let scene = write(dir.path(), "tube.json", &tubes(&[20.0], 50.0));
    let out = dir.path().join("x.npz");
    let base = r#""points_per_rotation": 10, "rotation_hz": 10, "min_range": 0, "max_range": 9"#;
    let cases = [
        (
            format!(r#"{{"elevations_deg": [0, 1, 2, 95], {base}}}"#),
            "sensor.elevations_deg[3]: 95 is outside -90..90",
        ),
        (
            format!(r#"{{"elevations_deg": [0], "azimuth_offsets_deg": [1, 2], {base}}}"#),
            "sensor.azimuth_offsets_deg: must have one value per beam (1, as elevations_deg), got 2",
        ),
        (
            r#"{"elevations_deg": [0], "azimuth_resolution_deg": 0.7, "rotation_hz": 10, "min_range": 0, "max_range": 9}"#.to_string(),
            "sensor.azimuth_resolution_deg: 0.7 does not divide 360",
        ),
        (
            format!(r#"{{"elevations_deg": [0], "azimuth_resolution_deg": 1, {base}}}"#),
            "sensor.azimuth_resolution_deg: give exactly one of",
        ),
        (
            r#"{"elevations_deg": [0], "points_per_rotation": 10, "rotation_hz": 0, "min_range": 0, "max_range": 9}"#.to_string(),
            "sensor.rotation_hz: 0 must be finite and > 0",
        ),
        // A subnormal rate's period is infinite; a huge one's step time rounds to 0.
        (
            r#"{"elevations_deg": [0], "points_per_rotation": 10, "rotation_hz": 1e-320, "min_range": 0, "max_range": 9}"#.to_string(),
            "sensor.rotation_hz: 1e-320 gives a step time of inf s (10 steps a rotation)",
        ),
        (
            r#"{"elevations_deg": [0], "points_per_rotation": 10, "rotation_hz": 1e308, "min_range": 0, "max_range": 9}"#.to_string(),
            "sensor.rotation_hz: 1e308 gives a step time of 0e0 s",
        ),
        (
            r#"{"elevations_deg": [0], "points_per_rotation": 10, "rotation_hz": 1, "min_range": 5, "max_range": 2}"#.to_string(),
            "sensor.max_range: 2 must be finite and > min_range (5)",
        ),
        (
            format!(r#"{{"elevations_deg": [0], "beams": 3, {base}}}"#),
            "sensor.beams: unknown field",
        ),
        ("[1, 2]".to_string(), "sensor: invalid type"),
    ];
    for (json, want) in cases {
        let sensor = write(dir.path(), "s.json", &json);
        let o = cylaov(&[
            "scan",
            &scene,
            "--sensor",
            &sensor,
            "-o",
            out.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{json}: {err}");
        assert!(err.contains(want), "{json}: {err}");
        assert!(!out.exists());
    }
    // Options: each refused naming itself, never a panic; a sensor that is neither a preset
    // nor a file is an input refused (1), a flag's bad value a usage error (2).
    for (args, want) in [
        (
            vec!["--sensor", "vlp17"],
            "--sensor \"vlp17\": neither a preset",
        ),
        (
            vec!["--sensor", "vlp16", "--returns", "16"],
            "--returns: must be in 1..=15, got 16",
        ),
        (
            vec!["--sensor", "vlp16", "--dropout", "1.5"],
            "--dropout: must be in [0, 1], got 1.5",
        ),
        (
            vec!["--sensor", "vlp16", "--range-noise", "-1"],
            "--range-noise: must be finite",
        ),
        (
            vec!["--sensor", "vlp16", "--pose", "1,2,x"],
            "--pose: value 3 (\"x\") is not a finite number",
        ),
    ] {
        let code = if args.len() == 2 { 1 } else { 2 };
        let mut a = vec!["scan", scene.as_str(), "-o", out.to_str().unwrap()];
        a.extend(args);
        let o = cylaov(&a);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(code), "{a:?}: {err}");
        assert!(err.contains(want), "{a:?}: {err}");
    }
    // A scan that cannot fit is refused before it starts, naming its most points: 1024
    // beams of 2^20 steps are 2^30 points: three copies of 100 bytes each (307 200 MiB)
    // and 840 bytes a step (840 MiB).
    let elevations: Vec<String> = (0..1024)
        .map(|i| format!("{}", -45.0 + 0.08 * i as f64))
        .collect();
    let huge = write(
        dir.path(),
        "huge.json",
        &format!(
            r#"{{"elevations_deg": [{}], "points_per_rotation": 1048576, "rotation_hz": 10, "min_range": 0, "max_range": 9}}"#,
            elevations.join(",")
        ),
    );
    let o = cylaov(&[
        "scan",
        &scene,
        "--sensor",
        &huge,
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("a scan of up to 1073741824 points needs about 308040 MiB of memory"),
        "{err}"
    );
    assert!(!out.exists());
    let o = cylaov(&["scan", &scene, "--sensor", "vlp16", "-o", "x.xyz"]);
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("x.xyz: unknown point-file extension"));
}

/// The pose moves and turns the sensor: yaw 90 sends azimuth 0 along world +y.
#[test]
fn pose_places_the_beams() {
    let dir = fresh_dir("scan", "pose");
    let scene = write(dir.path(), "tube.json", &tubes(&[20.0], 50.0));
    let sensor = write(dir.path(), "s.json", &flat_sensor("0", 4));
    let out = dir.path().join("p.npz");
    ok(&[
        "scan",
        &scene,
        "--sensor",
        &sensor,
        "--pose",
        "1,2,3,90,0,0",
        "-o",
        out.to_str().unwrap(),
    ]);
    let d = read_npz(&out);
    assert_eq!(d["x"].len(), 4);
    // Step 0 along +y from (1, 2, 3): x² + (2 + t)² = 400.
    let t = 399f64.sqrt() - 2.0;
    let got = DVec3::new(d["x"][0], d["y"][0], d["z"][0]);
    assert!(
        (got - DVec3::new(1.0, 2.0 + t, 3.0)).length() < 1e-12,
        "{got}"
    );
    assert!((d["range"][0] - t).abs() < 1e-12);
    // Step 1 (azimuth 90) along world -x: (1 - t)² + 4 = 400.
    let t1 = 396f64.sqrt() + 1.0;
    assert!((d["x"][1] - (1.0 - t1)).abs() < 1e-12);
}

/// Multiple returns: a closed cylinder crossed gives 2 (in, out) and nothing more; two
/// coaxial tubes crossed give 4 (outer, inner, inner's far wall, outer's far wall).
#[test]
fn returns_through_cylinders_and_coaxial_tubes() {
    let dir = fresh_dir("scan", "returns");
    let closed = r#"{"camera": {"origin": [0, -50, 0], "target": [0, 0, 0], "up": [0, 0, 1], "fov_deg": 40, "width": 8, "height": 8},
"cylinders": [{"p0": [0, 0, -1], "p1": [0, 0, 1], "radius": 1, "id": 4}]}"#;
    let scene = write(dir.path(), "closed.json", closed);
    let out = dir.path().join("c.npz");
    ok(&[
        "scan",
        &scene,
        "--sensor",
        "vlp16",
        "--pose",
        "-10,0,0",
        "--returns",
        "3",
        "-o",
        out.to_str().unwrap(),
    ]);
    let d = read_npz(&out);
    assert!(d["x"].len() > 100);
    for i in 0..d["x"].len() {
        assert_eq!(d["num_returns"][i], 2.0, "point {i}");
        let first = d["return_index"][i] == 1.0;
        // In through the side (1) or a cap (3, 4); out through the side from inside (2)
        // or a cap.
        if first {
            assert!([1.0, 3.0, 4.0].contains(&d["part"][i]));
            assert!(d["range"][i + 1] > d["range"][i]);
        } else {
            assert!([2.0, 3.0, 4.0].contains(&d["part"][i]));
        }
    }
    let scene = write(dir.path(), "coax.json", &tubes(&[2.0, 1.0], 5.0));
    let sensor = write(dir.path(), "s.json", &flat_sensor("0", 8));
    let out = dir.path().join("t.npz");
    ok(&[
        "scan",
        &scene,
        "--sensor",
        &sensor,
        "--pose",
        "-10,0,0",
        "--returns",
        "5",
        "-o",
        out.to_str().unwrap(),
    ]);
    let d = read_npz(&out);
    // Step 0 (azimuth 0, along +x through the axis): walls at x = -2, -1, 1, 2.
    assert_eq!(&d["num_returns"][..4], &[4.0; 4]);
    assert_eq!(&d["range_exact"][..4], &[8.0, 9.0, 11.0, 12.0]);
    assert_eq!(&d["shape_id"][..4], &[1.0, 2.0, 2.0, 1.0]);
    assert_eq!(&d["part"][..4], &[1.0, 1.0, 2.0, 2.0]);
    assert_eq!(&d["return_index"][..4], &[1.0, 2.0, 3.0, 4.0]);
}

/// Noise and dropout: the same seed gives the same bytes on 1 and 2 threads; the noise
/// is N(0, sigma) along the beam and the dropout fraction binomial.
#[test]
fn noise_is_reproducible_and_distributed() {
    let dir = fresh_dir("scan", "noise");
    let scene = write(dir.path(), "tube.json", &tubes(&[20.0], 50.0));
    let run = |name: &str, threads: &str, seed: &str| {
        let out = dir.path().join(name);
        ok(&[
            "scan",
            &scene,
            "--sensor",
            "vlp16",
            "--pose",
            "0.5,0.3,0",
            "--range-noise",
            "0.05",
            "--dropout",
            "0.3",
            "--seed",
            seed,
            "--threads",
            threads,
            "-o",
            out.to_str().unwrap(),
        ]);
        out
    };
    let (a, b, c) = (
        run("a.npz", "1", "7"),
        run("b.npz", "2", "7"),
        run("c.npz", "2", "8"),
    );
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert_ne!(std::fs::read(&a).unwrap(), std::fs::read(&c).unwrap());
    let d = read_npz(&a);
    let n = 16.0 * 1800.0;
    let kept = d["x"].len() as f64 / n;
    // Binomial: sd sqrt(0.3 * 0.7 / 28800) = 0.0027; 5 sd.
    assert!((kept - 0.7).abs() < 5.0 * (0.21f64 / n).sqrt(), "{kept}");
    let e: Vec<f64> = (0..d["x"].len())
        .map(|i| (d["range"][i] - d["range_exact"][i]) / 0.05)
        .collect();
    let m = e.len() as f64;
    let mean = e.iter().sum::<f64>() / m;
    let var = e.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / m;
    // Standard errors of the mean and variance of N(0, 1): 1/sqrt(m), sqrt(2/m); 5 of each.
    assert!(mean.abs() < 5.0 / m.sqrt(), "{mean}");
    assert!((var - 1.0).abs() < 5.0 * (2.0 / m).sqrt(), "{var}");
    // x, y, z follow the noisy range.
    for i in 0..d["x"].len() {
        let p = DVec3::new(d["x"][i] - 0.5, d["y"][i] - 0.3, d["z"][i]);
        assert!((p.length() - d["range"][i]).abs() < 1e-12 * d["range"][i].max(1.0));
    }
}

/// A moving sensor: each point lies on its beam from the pose at its own time (motion
/// skew), and on the tube's wall.
#[test]
fn trajectory_skews_the_scan() {
    let dir = fresh_dir("scan", "traj");
    let scene = write(dir.path(), "tube.json", &tubes(&[20.0], 50.0));
    let traj = write(
        dir.path(),
        "path.csv",
        "time,x,y,z,yaw,pitch,roll\n0,0,-1,0,0,0,0\n0.1,0,1,0,36,0,0\n",
    );
    let out = dir.path().join("m.npz");
    ok(&[
        "scan",
        &scene,
        "--sensor",
        "vlp16",
        "--trajectory",
        &traj,
        "-o",
        out.to_str().unwrap(),
    ]);
    let d = read_npz(&out);
    let tr = Trajectory::from_csv(&std::fs::read_to_string(&traj).unwrap()).unwrap();
    let mut moved = 0.0f64;
    for i in 0..d["x"].len() {
        let pose = tr.at(d["time"][i]);
        let dir = (pose.rotation * beam_dir(d["elevation"][i], d["azimuth"][i])).normalize();
        let p = DVec3::new(d["x"][i], d["y"][i], d["z"][i]);
        let want = pose.position + dir * d["range"][i];
        assert!((p - want).length() < 1e-9, "point {i}: {p} vs {want}");
        assert!(((p.x * p.x + p.y * p.y).sqrt() - 20.0).abs() < 1e-9);
        moved = moved.max(pose.position.y + 1.0);
    }
    // The last step fires at 0.1 * 1799/1800 s: the sensor has moved 2 * 1799/1800.
    assert!((moved - 2.0 * 1799.0 / 1800.0).abs() < 1e-9, "{moved}");
}

/// Every return of a 3-return scan of 300 random cylinders (70% closed) equals the
/// double-double oracle's k-th intersection along the beam, and each beam reports
/// min(3, intersections) returns; near the world origin and with the scene and the
/// sensor moved 1e6 away (georeferenced coordinates).
#[test]
fn returns_are_the_oracles_kth_intersections() {
    let near = oracle_errors(DVec3::ZERO);
    // Near the origin: relative to the range.
    assert!(near.relative < 1e-14, "{near:?}");
    // Far from it, a point's coordinates carry ulps of 1e6 (1.2e-10): its range can be
    // no better than a few of them, whichever return it is.
    let far = oracle_errors(DVec3::new(1e6, -2e6, 300.0));
    assert!(far.absolute < 8.0 * 2e6 * f64::EPSILON, "{far:?}");
}

/// The worst errors of [`oracle_errors`].
#[derive(Debug)]
#[allow(dead_code)] // read through Debug
struct RangeErrors {
    relative: f64,
    absolute: f64,
    beams: usize,
    skipped: usize,
}

/// The scan of [`returns_are_the_oracles_kth_intersections`] with everything moved by
/// `offset`, checked beam by beam against the oracle: the return counts exactly, each
/// range's worst errors returned. Beams whose oracle intersections include two closer
/// than 1e-9 relative (a graze or a rim: the count is then a matter of rounding) are
/// skipped, and counted (under 1%).
fn oracle_errors(offset: DVec3) -> RangeErrors {
    let mut sc = cylaov::bench::dense_scene(300, 5, 8, 8);
    for (i, c) in sc.cylinders.iter_mut().enumerate() {
        c.label = i as u32 % 7;
        c.base += offset;
    }
    let sensor = Sensor::from_json(&flat_sensor("-15, -7, -1, 1, 7, 15", 720)).unwrap();
    let pose = Pose::new(DVec3::new(0.3, -0.2, 0.4) + offset, 20.0, 5.0, -3.0);
    let opts = ScanOptions {
        returns: 3,
        ..ScanOptions::new(sensor.clone(), pose)
    };
    let s = scan(&sc, &opts).unwrap();
    assert!(s.len() > 1000, "{}", s.len());
    let mut e = RangeErrors {
        relative: 0.0,
        absolute: 0.0,
        beams: 0,
        skipped: 0,
    };
    // Points are ordered by step, then ring: each beam's points are consecutive, and
    // a beam that hit nothing has none (which the oracle must agree with).
    let mut i = 0;
    for step in 0..sensor.steps_per_rotation {
        for ring in 0..sensor.beams() {
            let azimuth = step as f64 * 360.0 / sensor.steps_per_rotation as f64;
            let elevation = sensor.elevations_deg[ring];
            let dir = (pose.rotation * beam_dir(elevation, azimuth)).normalize();
            let mut all: Vec<f64> = Vec::new();
            for c in &sc.cylinders {
                let p = Problem::new(c, pose.position, dir);
                let mut tmin = DD::new(sensor.min_range);
                while let Some(h) = oracle::intersect(&p, tmin, DD::new(sensor.max_range)) {
                    all.push(h.t.to_f64());
                    // Past this hit (1e-13 relative: far below any gap compared here).
                    tmin = DD::new(h.t.to_f64() * (1.0 + 1e-13) + 1e-300);
                }
            }
            all.sort_by(f64::total_cmp);
            let here = i < s.len() && s.ring[i] as usize == ring && s.azimuth[i] == azimuth;
            let n = if here { s.num_returns[i] as usize } else { 0 };
            e.beams += 1;
            if all.windows(2).any(|w| w[1] - w[0] < 1e-9 * w[1]) {
                e.skipped += 1;
                i += n;
                continue;
            }
            assert_eq!(n, all.len().min(3), "step {step} ring {ring}: {all:?}");
            for k in 0..n {
                let want = all[k];
                let abs = (s.range_exact[i + k] - want).abs();
                e.absolute = e.absolute.max(abs);
                e.relative = e.relative.max(abs / want);
                assert_eq!(s.return_index[i + k] as usize, k + 1);
            }
            i += n;
        }
    }
    assert_eq!(i, s.len());
    eprintln!("offset {offset}: {e:?}");
    assert!(e.skipped * 100 < e.beams, "{e:?}");
    e
}

/// Beams that hit nothing report nothing; the scan of a moving sensor equals the fixed
/// one when the trajectory stands still.
#[test]
fn a_still_trajectory_is_the_fixed_pose() {
    let sc = scene::parse(&tubes(&[3.0, 6.0], 2.0)).unwrap();
    let sensor = Sensor::preset("vlp16").unwrap();
    let pose = Pose::new(DVec3::new(0.5, 0.0, 0.2), 10.0, 0.0, 0.0);
    let fixed = scan(&sc, &ScanOptions::new(sensor.clone(), pose)).unwrap();
    let still = ScanOptions {
        motion: Motion::Path(Trajectory {
            poses: vec![(0.0, pose), (1.0, pose)],
        }),
        noise: Noise::NONE,
        ..ScanOptions::new(sensor, pose)
    };
    // Slerp between equal rotations renormalises: equal to a few ulp, not bit for bit.
    let moving = scan(&sc, &still).unwrap();
    assert_eq!(fixed.len(), moving.len());
    assert_eq!(fixed.shape_id, moving.shape_id);
    for i in 0..fixed.len() {
        assert!(
            (fixed.range[i] - moving.range[i]).abs() < 1e-12,
            "point {i}"
        );
    }
    // Beams steeper than atan(1.8 / 2.5) = 35.8 deg would leave through the open ends;
    // the VLP-16's 15 degrees all hit the inner tube.
    assert_eq!(fixed.len(), 16 * 1800);
}

/// With noise, a beam's returns are numbered in the order of their measured (noisy)
/// ranges, and a noisy range outside the sensor's `[min_range, max_range]` is not
/// reported: a thin pole's two walls 0.1 apart under noise of 0.05, and noise of 3 on
/// the vlp16 (0.5 to 100) at 3 from the pole.
#[test]
fn noisy_returns_are_ordered_and_in_the_window() {
    let dir = fresh_dir("scan", "noisy-order");
    let scene = write(
        dir.path(),
        "pole.json",
        r#"{"camera": {"origin": [10, 10, 10], "target": [0, 0, 0], "up": [0, 0, 1], "fov_deg": 40, "width": 8, "height": 8},
"cylinders": [{"p0": [3, 0, -10], "p1": [3, 0, 10], "radius": 0.05}]}"#,
    );
    let run = |name: &str, extra: &[&str]| {
        let out = dir.path().join(name);
        let mut a = vec!["scan", scene.as_str(), "--sensor", "vlp16", "--seed", "1"];
        a.extend(extra);
        a.extend(["-o", out.to_str().unwrap()]);
        ok(&a);
        read_npz(&out)
    };
    let d = run("two.npz", &["--returns", "2", "--range-noise", "0.05"]);
    let (r, k, n) = (&d["range"], &d["return_index"], &d["num_returns"]);
    let mut pairs = 0;
    let mut swapped = 0;
    for i in 0..r.len() {
        if k[i] == 1.0 && n[i] == 2.0 {
            pairs += 1;
            assert_eq!(k[i + 1], 2.0);
            assert!(r[i] <= r[i + 1], "point {i}: {} then {}", r[i], r[i + 1]);
            swapped += usize::from(d["range_exact"][i] > d["range_exact"][i + 1]);
        }
    }
    // The walls' exact ranges differ by under 0.1, noise sd 0.05: about a tenth of the
    // pairs swap (16 of 144 when numbered by exact range); the test sees some.
    assert!(
        pairs > 100 && swapped > 0,
        "{pairs} pairs, {swapped} swapped"
    );
    let d = run("wide.npz", &["--range-noise", "3"]);
    let r = &d["range"];
    assert!(r.len() > 50, "{}", r.len());
    assert!(r.iter().all(|&x| (0.5..=100.0).contains(&x)), "{r:?}");
}
