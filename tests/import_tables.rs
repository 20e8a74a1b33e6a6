//! `cylaov import`: a small tree written in each QSM layout (TreeQSM with and without a
//! header, SimpleForest, aRchi) and as plain CSV comes back as the same cylinders, every
//! number checked; the camera frames the whole tree; a bad row names its line and column,
//! exits non-zero and writes nothing.

mod common;

use common::{cylaov, fresh_dir, ok};
use cylaov::scene::camera::Camera;
use glam::DVec3;
use std::path::Path;

/// One cylinder of the test tree, as a QSM describes it.
struct Segment {
    start: [f64; 3],
    /// Not unit length: the reader must normalise it.
    axis: [f64; 3],
    length: f64,
    radius: f64,
    parent: u32,
    branch: u32,
    order: u32,
}

/// A stem of three segments and two branches (orders 0 and 1, one twig of order 2).
fn tree() -> Vec<Segment> {
    let s = |start, axis, length, radius, parent, branch, order| Segment {
        start,
        axis,
        length,
        radius,
        parent,
        branch,
        order,
    };
    vec![
        s([1.0, 2.0, 0.0], [0.0, 0.0, 2.0], 1.5, 0.2, 0, 1, 0),
        s([1.0, 2.0, 1.5], [0.0, 0.1, 1.0], 1.25, 0.15, 1, 1, 0),
        s([1.0, 2.124, 2.74], [0.0, 0.0, 1.0], 1.0, 0.1, 2, 1, 0),
        s([1.0, 2.0, 1.5], [1.0, 0.0, 1.0], 0.8, 0.06, 1, 2, 1),
        s([1.0, 2.124, 2.74], [-1.0, 0.5, 0.5], 0.6, 0.04, 2, 3, 1),
        s([1.5657, 2.0, 2.0657], [0.0, 1.0, 0.3], 0.3, 0.02, 4, 4, 2),
    ]
}

fn end(c: &Segment) -> [f64; 3] {
    let a = DVec3::from_array(c.axis);
    (DVec3::from_array(c.start) + a / a.length() * c.length).to_array()
}

fn v(x: [f64; 3]) -> String {
    format!("{} {} {}", x[0], x[1], x[2])
}

/// TreeQSM 2.3 `cyl_data` without a header: 15 whitespace-separated columns.
fn treeqsm15(t: &[Segment]) -> String {
    t.iter()
        .enumerate()
        .map(|(i, c)| {
            format!(
                "{} {} {} {} {} {} {} {} {} {} {}\n",
                c.radius,
                c.length,
                v(c.start),
                v(c.axis),
                c.parent,
                i as u32 + 2,
                c.branch,
                c.order,
                1,
                0,
                c.radius * 1.1
            )
        })
        .collect()
}

/// Older TreeQSM: 14 columns (no UnmodRadius), tab-separated.
fn treeqsm14(t: &[Segment]) -> String {
    treeqsm15(t)
        .lines()
        .map(|l| {
            let f: Vec<&str> = l.split(' ').collect();
            format!("{}\n", f[..14].join("\t"))
        })
        .collect()
}

/// A later TreeQSM text export with a header, `start_point` and `axis_direction` each
/// heading three columns.
fn treeqsm_header(t: &[Segment]) -> String {
    let mut s = String::from(
        "radius (m)\tlength (m)\tstart_point\taxis_direction\tparent\textension\tbranch\tbranch_order\tposition_in_branch\tmad\tSurfCov\tadded\tUnmodRadius (m)\n",
    );
    for (i, c) in t.iter().enumerate() {
        s += &format!(
            "{}\t{}\t{}\t{}\t{}\t{}\t{}\t{}\t1\t0.001\t0.9\t0\t{}\n",
            c.radius,
            c.length,
            v(c.start).replace(' ', "\t"),
            v(c.axis).replace(' ', "\t"),
            c.parent,
            i + 2,
            c.branch,
            c.order,
            c.radius
        );
    }
    s
}

const FIRST_ID: u32 = 101;

/// SimpleForest, columns in an order of their own, ids from [`FIRST_ID`], quoted names as
/// R's write.csv gives them.
fn simpleforest(t: &[Segment]) -> String {
    let mut s = String::from(
        "\"radius\",\"endX\",\"endY\",\"endZ\",\"ID\",\"parentID\",\"startX\",\"startY\",\"startZ\",\"length\",\"growthLength\",\"branchOrder\",\"branchID\"\n",
    );
    for (i, c) in t.iter().enumerate() {
        let e = end(c);
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{},7.5,{},{}\n",
            c.radius,
            e[0],
            e[1],
            e[2],
            FIRST_ID + i as u32,
            c.parent,
            c.start[0],
            c.start[1],
            c.start[2],
            c.length,
            c.order,
            c.branch
        );
    }
    s
}

/// aRchi: ids from 0 (moved up by one on import).
fn archi(t: &[Segment]) -> String {
    let mut s = String::from(
        "startX,startY,startZ,endX,endY,endZ,cyl_ID,parent_ID,extension_ID,radius_cyl,length,branch_ID,branching_order\n",
    );
    for (i, c) in t.iter().enumerate() {
        let e = end(c);
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{}\n",
            c.start[0],
            c.start[1],
            c.start[2],
            e[0],
            e[1],
            e[2],
            i,
            c.parent,
            i + 1,
            c.radius,
            c.length,
            c.branch,
            c.order
        );
    }
    s
}

/// Plain CSV with its own ids, labels and caps.
fn generic(t: &[Segment]) -> String {
    let mut s = String::from("# a comment line\nid,x0,y0,z0,x1,y1,z1,radius,label,caps\n");
    for (i, c) in t.iter().enumerate() {
        let e = end(c);
        s += &format!(
            "{},{},{},{},{},{},{},{},{},{}\n",
            50 + i,
            c.start[0],
            c.start[1],
            c.start[2],
            e[0],
            e[1],
            e[2],
            c.radius,
            7 * i,
            if i % 2 == 0 { "true" } else { "0" }
        );
    }
    s
}

/// Import `text` (written to `name`) with `flags`; the scene file's JSON.
fn import(dir: &Path, name: &str, text: &str, flags: &[&str]) -> serde_json::Value {
    let table = dir.join(name);
    std::fs::write(&table, text).unwrap();
    let out = dir.join(format!("{name}.json"));
    let mut args = vec![
        "import",
        table.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend(flags);
    let said = ok(&args);
    assert!(said.contains("6 cylinders"), "{said}");
    check_framing(&out);
    serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap()
}

/// Every cylinder's two end centres, and its rim points across the view, project inside
/// the image of the scene's camera.
fn check_framing(scene: &Path) {
    let s = cylaov::scene::load(scene).unwrap();
    let cam = Camera::new(s.camera);
    let (w, h) = (s.camera.width as f64, s.camera.height as f64);
    let mut margin = f64::INFINITY;
    for c in &s.cylinders {
        for p in [c.base, c.top()] {
            for off in [DVec3::ZERO, DVec3::X, -DVec3::X, DVec3::Z, -DVec3::Z] {
                let q = cam
                    .project(p + off * c.radius)
                    .expect("in front of the camera");
                margin = margin.min(q.x).min(q.y).min(w - q.x).min(h - q.y);
            }
        }
    }
    // The bounding sphere fills the smaller field of view: inside, with some room left.
    assert!(margin > 0.0 && margin < h / 2.0, "margin {margin} px");
}

/// Check every cylinder against the tree: p0, p1, radius to 1e-12, the ids and labels.
fn check(scene: &serde_json::Value, ids: &[u32], labels: &[u32], caps: &[bool]) {
    let t = tree();
    let cyl = scene["cylinders"].as_array().unwrap();
    assert_eq!(cyl.len(), t.len());
    for (k, (c, want)) in cyl.iter().zip(&t).enumerate() {
        let got = |key: &str| -> DVec3 {
            let a = c[key].as_array().unwrap();
            DVec3::new(
                a[0].as_f64().unwrap(),
                a[1].as_f64().unwrap(),
                a[2].as_f64().unwrap(),
            )
        };
        let e0 = (got("p0") - DVec3::from_array(want.start))
            .abs()
            .max_element();
        let e1 = (got("p1") - DVec3::from_array(end(want)))
            .abs()
            .max_element();
        assert!(
            e0 < 1e-12 && e1 < 1e-12,
            "cylinder {k}: p0 off by {e0}, p1 by {e1}"
        );
        assert_eq!(c["radius"].as_f64().unwrap(), want.radius, "cylinder {k}");
        assert_eq!(c["id"].as_u64().unwrap(), ids[k] as u64, "cylinder {k} id");
        assert_eq!(
            c.get("label").map_or(0, |l| l.as_u64().unwrap()),
            labels[k] as u64,
            "cylinder {k} label"
        );
        assert_eq!(c["caps"].as_bool().unwrap(), caps[k], "cylinder {k} caps");
    }
}

const ROWS: [u32; 6] = [1, 2, 3, 4, 5, 6];
const ORDER_PLUS_1: [u32; 6] = [1, 1, 1, 2, 2, 3];
const BRANCH_PLUS_1: [u32; 6] = [2, 2, 2, 3, 4, 5];

#[test]
fn treeqsm_without_header_15_and_14_columns() {
    let dir = fresh_dir("import-tables", "treeqsm");
    let s = import(
        dir.path(),
        "cyl15.txt",
        &treeqsm15(&tree()),
        &["--label", "branch_order"],
    );
    check(&s, &ROWS, &ORDER_PLUS_1, &[true; 6]);
    assert_eq!(s["aovs"][3], "label");
    let s = import(
        dir.path(),
        "cyl14.txt",
        &treeqsm14(&tree()),
        &["--label", "branch", "--caps", "off"],
    );
    check(&s, &ROWS, &BRANCH_PLUS_1, &[false; 6]);
    let s = import(
        dir.path(),
        "cylh.txt",
        &treeqsm_header(&tree()),
        &["--label", "segment"],
    );
    check(&s, &ROWS, &ROWS, &[true; 6]);
    // No label: none written, no label AOV.
    let s = import(dir.path(), "cyl.txt", &treeqsm15(&tree()), &[]);
    check(&s, &ROWS, &[0; 6], &[true; 6]);
    assert_eq!(s["aovs"].as_array().unwrap().len(), 3);
}

#[test]
fn simpleforest_and_archi_keep_their_ids() {
    let dir = fresh_dir("import-tables", "qsm-csv");
    let ids: Vec<u32> = (0..6).map(|i| FIRST_ID + i).collect();
    let s = import(
        dir.path(),
        "sf.csv",
        &simpleforest(&tree()),
        &["--label", "segment"],
    );
    check(&s, &ids, &ids, &[true; 6]);
    let s = import(
        dir.path(),
        "sf2.csv",
        &simpleforest(&tree()),
        &["--label", "branch_order", "--format", "simpleforest"],
    );
    check(&s, &ids, &ORDER_PLUS_1, &[true; 6]);
    // aRchi counts from 0: every id moves up by one.
    let s = import(
        dir.path(),
        "archi.csv",
        &archi(&tree()),
        &["--label", "branch"],
    );
    check(&s, &ROWS, &BRANCH_PLUS_1, &[true; 6]);
}

#[test]
fn generic_csv_with_ids_labels_and_caps() {
    let dir = fresh_dir("import-tables", "csv");
    let ids: Vec<u32> = (50..56).collect();
    let labels: Vec<u32> = (0..6).map(|i| 7 * i).collect();
    let caps = [true, false, true, false, true, false];
    let s = import(dir.path(), "t.csv", &generic(&tree()), &[]);
    check(&s, &ids, &labels, &caps);
    // An explicit rule replaces the label column.
    let s = import(
        dir.path(),
        "t2.csv",
        &generic(&tree()),
        &["--label", "none"],
    );
    check(&s, &ids, &[0; 6], &caps);
}

/// A bad table: exit 1, one error line naming the file, line and column, no output.
fn refused(dir: &Path, name: &str, text: &str, flags: &[&str], want: &str) {
    let table = dir.join(name);
    std::fs::write(&table, text).unwrap();
    let out = dir.join(format!("{name}.json"));
    let mut args = vec![
        "import",
        table.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend(flags);
    let o = cylaov(&args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{name}: {err}");
    assert!(err.contains(want), "{name}: wanted {want:?} in {err}");
    assert!(err.contains(name), "{name}: {err}");
    assert!(!out.exists(), "{name}: wrote {}", out.display());
    assert!(!err.contains("panic"), "{err}");
}

#[test]
fn bad_rows_name_line_and_column_and_write_nothing() {
    let dir = fresh_dir("import-tables", "bad");
    let d = dir.path();
    let t = tree();
    let with_line = |text: String, k: usize, f: &dyn Fn(&str) -> String| -> String {
        text.lines()
            .enumerate()
            .map(|(i, l)| if i == k { f(l) } else { l.to_string() } + "\n")
            .collect()
    };
    // TreeQSM row 3: radius -0.1 (column 1).
    let bad = with_line(treeqsm15(&t), 2, &|l: &str| l.replacen("0.1 ", "-0.1 ", 1));
    refused(
        d,
        "neg.txt",
        &bad,
        &[],
        "line 3, column 1 (radius): must be > 0, got -0.1",
    );
    // TreeQSM row 2: length 0 (column 2).
    let bad = with_line(treeqsm15(&t), 1, &|l: &str| l.replacen(" 1.25 ", " 0 ", 1));
    refused(
        d,
        "zero.txt",
        &bad,
        &[],
        "line 2, column 2 (length): must be > 0, got 0",
    );
    // SimpleForest row on line 5 (the header is line 1): endZ is NaN.
    let bad = with_line(simpleforest(&t), 4, &|l: &str| {
        let mut f: Vec<String> = l.split(',').map(String::from).collect();
        f[3] = "NaN".into();
        f.join(",")
    });
    refused(
        d,
        "nan.csv",
        &bad,
        &[],
        "line 5, column 4 (endZ): must be finite",
    );
    // aRchi: end equal to start on line 2.
    let bad = with_line(archi(&t), 1, &|l: &str| {
        let mut f: Vec<String> = l.split(',').map(String::from).collect();
        for k in 0..3 {
            f[k + 3] = f[k].clone();
        }
        f.join(",")
    });
    refused(
        d,
        "flat.csv",
        &bad,
        &[],
        "line 2, column 4 (endX): zero length",
    );
    // Generic CSV: a word where a number belongs, after the comment line.
    let bad = with_line(generic(&t), 4, &|l: &str| l.replacen(",0.1,", ",thin,", 1));
    refused(
        d,
        "word.csv",
        &bad,
        &[],
        "line 5, column 8 (radius): not a number, got \"thin\"",
    );
    // Neither a header nor TreeQSM's column count.
    refused(
        d,
        "seven.txt",
        "1 2 3 4 5 6 7\n",
        &[],
        "line 1: cannot tell the table format",
    );
    // A rule the table has no column for.
    refused(
        d,
        "nolabel.csv",
        &generic(&t),
        &["--label", "branch_order"],
        "no branch order column",
    );
}

/// A scene whose cylinders are `{"file": ...}`: read relative to the scene file, the
/// same cylinders as the imported scene, and a batch renders the view again once the
/// table changes (its content is part of the view's render stamp).
#[test]
fn scenes_reference_tables_and_batch_notices_a_changed_table() {
    let dir = fresh_dir("import-tables", "ref");
    let d = dir.path();
    let scenes = d.join("scenes");
    std::fs::create_dir_all(scenes.join("tables")).unwrap();
    let table = scenes.join("tables/tree.csv");
    std::fs::write(&table, generic(&tree())).unwrap();
    // The imported scene's camera, the cylinders by reference.
    let imported = d.join("imported.json");
    ok(&[
        "import",
        table.to_str().unwrap(),
        "-o",
        imported.to_str().unwrap(),
    ]);
    let full: serde_json::Value =
        serde_json::from_slice(&std::fs::read(&imported).unwrap()).unwrap();
    let scene = scenes.join("tree.json");
    let by_ref = serde_json::json!({
        "camera": full["camera"],
        "cylinders": {"file": "tables/tree.csv"},
        "aovs": ["depth", "shape_id", "label"],
    });
    std::fs::write(&scene, by_ref.to_string()).unwrap();
    let a = cylaov::scene::load(&imported).unwrap();
    let b = cylaov::scene::load(&scene).unwrap();
    assert_eq!(a.cylinders, b.cylinders);
    assert_eq!(b.cylinders.len(), 6);
    assert_eq!(b.cylinders[3].id, 53);
    assert_eq!(b.cylinders[3].label, 21);
    // Options of the reference: segment labels are the ids (the path from another folder).
    let seg = d.join("seg.json");
    let mut v = by_ref.clone();
    v["cylinders"] =
        serde_json::json!({"file": "scenes/tables/tree.csv", "label": "segment", "caps": false});
    std::fs::write(&seg, v.to_string()).unwrap();
    let s = cylaov::scene::load(&seg).unwrap();
    assert!(s.cylinders.iter().all(|c| c.label == c.id));
    // The table's caps column wins over the reference's caps.
    let caps: Vec<bool> = s.cylinders.iter().map(|c| c.caps).collect();
    assert_eq!(caps, [true, false, true, false, true, false]);

    let out = d.join("render");
    let batch = || {
        ok(&[
            "batch",
            scenes.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
        ])
    };
    batch();
    let stamp = out.join("tree.render.json");
    let first = std::fs::read_to_string(&stamp).unwrap();
    let said = batch();
    assert_eq!(std::fs::read_to_string(&stamp).unwrap(), first, "{said}");
    // A label changes in the table: the view renders again with a new stamp.
    let changed = generic(&tree()).replacen(",21,", ",22,", 1);
    assert_ne!(changed, generic(&tree()));
    std::fs::write(&table, changed).unwrap();
    batch();
    assert_ne!(std::fs::read_to_string(&stamp).unwrap(), first);

    // A bad row in the table names the scene field, the table, its line and column.
    std::fs::write(&table, generic(&tree()).replacen(",0.2,", ",0,", 1)).unwrap();
    let o = cylaov(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        d.join("x.exr").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("cylinders.file: ")
            && err.contains("tree.csv: line 3, column 8 (radius): must be > 0, got 0"),
        "{err}"
    );
    assert!(!d.join("x.exr").exists());
    // A misspelt key of the reference is named.
    std::fs::write(&scene, r#"{"camera": {"origin": [0, -5, 1], "target": [0, 0, 1], "up": [0, 0, 1], "fov_deg": 40, "width": 8, "height": 8}, "cylinders": {"fil": "x.csv"}}"#).unwrap();
    let o = cylaov(&[
        "render",
        scene.to_str().unwrap(),
        "-o",
        d.join("x.exr").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("unknown field `fil`"), "{err}");
}

/// `"cameras": {"orbit": ...}` and `{"sphere": ...}` around a table's tree, and `cylaov
/// cameras --orbit N`: N cameras, each framing every cylinder, the orbit's at one distance
/// and height stepped by 360°/N, the same bytes for the same seed.
#[test]
fn camera_rigs_frame_any_scene_deterministically() {
    let dir = fresh_dir("import-tables", "rig");
    let d = dir.path();
    let table = d.join("tree.txt");
    std::fs::write(&table, treeqsm15(&tree())).unwrap();
    let scene = d.join("tree.json");
    ok(&[
        "import",
        table.to_str().unwrap(),
        "-o",
        scene.to_str().unwrap(),
    ]);
    let out = d.join("orbit.json");
    let said = ok(&[
        "cameras",
        scene.to_str().unwrap(),
        "--orbit",
        "200",
        "--seed",
        "4",
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(said.contains("200 cameras and 6 cylinders"), "{said}");
    let again = d.join("orbit2.json");
    ok(&[
        "cameras",
        scene.to_str().unwrap(),
        "--orbit",
        "200",
        "--seed",
        "4",
        "-o",
        again.to_str().unwrap(),
    ]);
    assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(&again).unwrap());
    let s = cylaov::scene::load(&out).unwrap();
    assert_eq!(s.cameras.len(), 200);
    let t = s.cameras[0].target;
    let r0 = s.cameras[0].origin - t;
    for (k, c) in s.cameras.iter().enumerate() {
        assert_eq!(c.target, t);
        assert_eq!(
            (c.width, c.height),
            (640, 480),
            "the imported camera's size"
        );
        let r = c.origin - t;
        assert!(
            (r.length() - r0.length()).abs() < 1e-9 * r0.length(),
            "camera {k}"
        );
        assert!((r.z - r0.z).abs() < 1e-9, "camera {k}");
        let turn = r0
            .truncate()
            .angle_to(r.truncate())
            .to_degrees()
            .rem_euclid(360.0);
        let want = (k as f64 * 1.8).rem_euclid(360.0);
        let diff = (turn - want).abs().min(360.0 - (turn - want).abs());
        assert!(diff < 1e-6, "camera {k}: turned {turn}°, want {want}°");
    }
    // Every cylinder is in every view (every 20th camera checked).
    for k in (0..200).step_by(20) {
        let mut one = s.clone();
        one.select_camera(k).unwrap();
        let cam = Camera::new(one.camera);
        for c in &one.cylinders {
            for p in [c.base, c.top()] {
                let q = cam.project(p).unwrap();
                assert!(
                    q.x > 0.0 && q.y > 0.0 && q.x < 640.0 && q.y < 480.0,
                    "camera {k}: {q}"
                );
            }
        }
    }
    // A rig in the scene file resolves to the same cameras as the command's.
    let rig = d.join("rig.json");
    std::fs::write(
        &rig,
        r#"{"cameras": {"orbit": {"count": 200, "seed": 4, "elevation_deg": [-20, 60]}}, "cylinders": {"file": "tree.txt"}}"#,
    )
    .unwrap();
    let r = cylaov::scene::load(&rig).unwrap();
    assert_eq!(r.cameras, s.cameras);
    // Directions over the sphere: distinct elevations within the band, one distance.
    std::fs::write(
        &rig,
        r#"{"cameras": {"sphere": {"count": 50, "seed": 1, "elevation_deg": [10, 40], "width": 64, "height": 48, "distance": 1.5}}, "cylinders": {"file": "tree.txt"}}"#,
    )
    .unwrap();
    let r = cylaov::scene::load(&rig).unwrap();
    assert_eq!(r.cameras.len(), 50);
    let mut heights: Vec<f64> = Vec::new();
    for c in &r.cameras {
        let v = (c.origin - c.target).normalize();
        let e = v.z.asin().to_degrees();
        assert!((10.0 - 1e-9..=40.0 + 1e-9).contains(&e), "elevation {e}");
        heights.push(e);
    }
    heights.sort_by(f64::total_cmp);
    heights.dedup();
    assert_eq!(heights.len(), 50);
    ok(&[
        "render",
        rig.to_str().unwrap(),
        "-o",
        d.join("v.exr").to_str().unwrap(),
        "--camera",
        "49",
    ]);
    // Bad rigs name the field or the flag.
    std::fs::write(
        &rig,
        r#"{"cameras": {"orbit": {"count": 0}}, "cylinders": {"file": "tree.txt"}}"#,
    )
    .unwrap();
    let o = cylaov(&[
        "render",
        rig.to_str().unwrap(),
        "-o",
        d.join("w.exr").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(1)
            && err.contains("cameras.orbit.count: must be in 1..=100000, got 0"),
        "{err}"
    );
    let o = cylaov(&[
        "cameras",
        scene.to_str().unwrap(),
        "--sphere",
        "3",
        "--elevation",
        "0..90",
        "-o",
        d.join("x.json").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.code() == Some(2) && err.contains("--elevation: must lie in -85..85"),
        "{err}"
    );
    assert!(!d.join("x.json").exists());
}

/// Import `text` (written to `name`) with `flags`; the scene file's cylinders.
fn import_rows(dir: &Path, name: &str, text: &str, flags: &[&str]) -> Vec<serde_json::Value> {
    let table = dir.join(name);
    std::fs::write(&table, text).unwrap();
    let out = dir.join(format!("{name}.json"));
    let mut args = vec![
        "import",
        table.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend(flags);
    ok(&args);
    let scene: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    scene["cylinders"].as_array().unwrap().clone()
}

/// A cylinder's `key` (`p0`, `p1`) as numbers.
fn xyz(c: &serde_json::Value, key: &str) -> [f64; 3] {
    let a = c[key].as_array().unwrap();
    [0, 1, 2].map(|k| a[k].as_f64().unwrap())
}

/// Every row has the header's fields, counted by its separator: a quoted field holds
/// commas and doubled quotes, an empty field between tabs stays a field, and a row of more
/// or fewer fields is refused naming both counts, where it once shifted its values into
/// the next columns' roles.
#[test]
fn rows_have_the_headers_fields() {
    let dir = fresh_dir("import-tables", "fields");
    let d = dir.path();
    let cyl = import_rows(
        d,
        "quoted.csv",
        "name,x0,y0,z0,x1,y1,z1,radius\n\"1,5\",0,0,0,0,0,1,0.1\n \"say \"\"hi\"\", ok\" ,1,2,3,1,2,4.5,0.25\n",
        &[],
    );
    assert_eq!(cyl.len(), 2);
    assert_eq!(xyz(&cyl[0], "p0"), [0.0, 0.0, 0.0]);
    assert_eq!(xyz(&cyl[0], "p1"), [0.0, 0.0, 1.0]);
    assert_eq!(cyl[0]["radius"].as_f64(), Some(0.1));
    assert_eq!(xyz(&cyl[1], "p0"), [1.0, 2.0, 3.0]);
    assert_eq!(xyz(&cyl[1], "p1"), [1.0, 2.0, 4.5]);
    assert_eq!(cyl[1]["radius"].as_f64(), Some(0.25));
    // An empty note between tabs: the radius is still the eighth field.
    let cyl = import_rows(
        d,
        "note.tsv",
        "x0\ty0\tz0\tx1\ty1\tz1\tnote\tradius\n0\t0\t0\t0\t0\t1\t\t0.5\n1\t1\t1\t1\t1\t3\tfine\t0.75\n",
        &[],
    );
    assert_eq!(cyl[0]["radius"].as_f64(), Some(0.5));
    assert_eq!(xyz(&cyl[1], "p1"), [1.0, 1.0, 3.0]);
    assert_eq!(cyl[1]["radius"].as_f64(), Some(0.75));
    // TreeQSM's text: runs of spaces are one separator.
    let cyl = import_rows(
        d,
        "spaced.txt",
        "0.2   2  1 2 3   0 0 1  0 1 1 0 1 0 0.2\n",
        &[],
    );
    assert_eq!(xyz(&cyl[0], "p1"), [1.0, 2.0, 5.0]);
    assert_eq!(cyl[0]["radius"].as_f64(), Some(0.2));

    refused(
        d,
        "extra.csv",
        "x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,1,5,0,1\n",
        &[],
        "extra.csv: line 2: has 9 fields, the header (line 1) has 7 (a field holding a comma goes in double quotes)",
    );
    refused(
        d,
        "short.csv",
        "x0,y0,z0,x1,y1,z1,radius,note\n0,0,0,0,0,1,0.5,a\n0,0,0,0,0,1,0.5\n",
        &[],
        "short.csv: line 3: has 7 fields, the header (line 1) has 8",
    );
    refused(
        d,
        "emptytab.tsv",
        "x0\ty0\tz0\tx1\ty1\tz1\tradius\tnote\n0\t0\t0\t0\t0\t1\t\t5\n",
        &[],
        "emptytab.tsv: line 2, column 7 (radius): is empty; a number is needed",
    );
    refused(
        d,
        "open.csv",
        "x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,1,0.5\n0,0,0,\"0,0,1,0.5\n",
        &[],
        "open.csv: line 3: field 4 opens a quote that does not close on this line",
    );
    refused(
        d,
        "after.csv",
        "x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,1,\"0.5\"x\n",
        &[],
        "after.csv: line 2: field 7 has \"x\" after its closing quote",
    );
    let two = treeqsm15(&tree());
    let mut lines: Vec<&str> = two.lines().collect();
    let fourteen = lines[1].rsplit_once(' ').unwrap().0.to_string();
    lines[1] = &fourteen;
    refused(
        d,
        "mixed.txt",
        &(lines.join("\n") + "\n"),
        &[],
        "mixed.txt: line 2: has 14 fields, the first row (line 1) has 15",
    );
}

/// Two columns that read as one field (`radius` and `radius (mm)`, `x0` and `X0`) are
/// refused naming both: neither silently wins.
#[test]
fn ambiguous_columns_are_refused() {
    let dir = fresh_dir("import-tables", "ambiguous");
    let d = dir.path();
    refused(
        d,
        "dup.csv",
        "x0,y0,z0,x1,y1,z1,radius,radius (mm)\n0,0,0,0,0,1,0.1,100\n",
        &[],
        "dup.csv: line 1: columns 7 (radius) and 8 (radius (mm)) are both radius; keep one, or rename the other",
    );
    refused(
        d,
        "x0.csv",
        "x0,y0,z0,x1,y1,z1,radius,X0\n0,0,0,0,0,1,0.1,5\n",
        &[],
        "x0.csv: line 1: columns 1 (x0) and 8 (X0) are both x0",
    );
    // A header of thousands of unknown names is listed by its first 12.
    let wide = (0..5000)
        .map(|k| format!("c{k}"))
        .collect::<Vec<_>>()
        .join(",")
        + "\n1\n";
    refused(
        d,
        "wide.csv",
        &wide,
        &[],
        "(c0, c1, c2, c3, c4, c5, c6, c7, c8, c9, c10, c11, … 4988 more): expected",
    );
    let o = cylaov(&[
        "import",
        d.join("wide.csv").to_str().unwrap(),
        "-o",
        d.join("w.json").to_str().unwrap(),
    ]);
    assert!(o.stderr.len() < 600, "{} bytes", o.stderr.len());
    refused(
        d,
        "wider.csv",
        &(",".repeat(20_000) + "x\n"),
        &[],
        "wider.csv: line 1: has 20001 fields; a table may have at most 10000 columns",
    );
}

/// Axis and length: an axis of any finite non-zero size is a direction (1e-162 squares to
/// a subnormal, 1e-200 to 0), and a length too short to move the end off the start is
/// refused at its row and column.
#[test]
fn axes_of_any_size_and_lengths_that_vanish() {
    let dir = fresh_dir("import-tables", "axis");
    let d = dir.path();
    let cyl = import_rows(
        d,
        "tiny.txt",
        "0.1 1 0 0 0 2e-162 0 0 0 1 1 0 1 0 0.1\n\
         0.1 1 0 0 0 1e-200 0 0 0 1 1 0 1 0 0.1\n\
         0.1 5 0 0 0 3e-200 -4e-200 0 0 1 1 0 1 0 0.1\n\
         0.1 2 0 0 0 0 3e11 4e11 0 1 1 0 1 0 0.1\n",
        &[],
    );
    assert_eq!(xyz(&cyl[0], "p1"), [1.0, 0.0, 0.0]);
    assert_eq!(xyz(&cyl[1], "p1"), [1.0, 0.0, 0.0]);
    let p = xyz(&cyl[2], "p1");
    assert!(
        (p[0] - 3.0).abs() < 1e-15 && (p[1] + 4.0).abs() < 1e-15 && p[2] == 0.0,
        "{p:?}"
    );
    let p = xyz(&cyl[3], "p1");
    assert!(
        p[0] == 0.0 && (p[1] - 1.2).abs() < 1e-15 && (p[2] - 1.6).abs() < 1e-15,
        "{p:?}"
    );
    refused(
        d,
        "vanish.txt",
        "0.1 1e-12 1e6 0 0 1 0 0 0 1 1 0 1 0 0.1\n",
        &[],
        "vanish.txt: line 1, column 2 (length): 1e-12 is too short to move the end away from the start [1000000.0, 0.0, 0.0]",
    );
}

/// One `.npy` member: numpy's header for `descr` and `shape`, then `data`.
fn npy(descr: &str, fortran: bool, shape: &str, data: &[u8]) -> Vec<u8> {
    let mut dict = format!(
        "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape}, }}",
        if fortran { "True" } else { "False" }
    );
    while (10 + dict.len() + 1) % 64 != 0 {
        dict.push(' ');
    }
    dict.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend((dict.len() as u16).to_le_bytes());
    out.extend(dict.as_bytes());
    out.extend(data);
    out
}

/// An `.npz` of these members, deflated as `numpy.savez_compressed` writes them.
fn write_npz(path: &Path, members: &[(&str, Vec<u8>)]) {
    use std::io::Write;
    let mut zip = zip::ZipWriter::new(std::fs::File::create(path).unwrap());
    let opts = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated)
        .large_file(true);
    for (name, bytes) in members {
        zip.start_file(format!("{name}.npy"), opts).unwrap();
        zip.write_all(bytes).unwrap();
    }
    zip.finish().unwrap();
}

/// `cylaov args` and the most memory it held (peak resident set, bytes) and its stderr.
#[cfg(target_os = "linux")]
#[allow(
    clippy::zombie_processes,
    reason = "wait4 reaps the child, with its usage"
)]
fn peak_memory(args: &[&str]) -> (i32, u64, String) {
    use std::io::Read;
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut status = 0;
    // SAFETY: rusage is plain data, filled by wait4 for the child just spawned.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    let pid = unsafe { libc::wait4(child.id() as i32, &mut status, 0, &mut usage) };
    assert_eq!(pid, child.id() as i32);
    let mut err = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut err)
        .unwrap();
    (
        libc::WEXITSTATUS(status),
        usage.ru_maxrss as u64 * 1024,
        err,
    )
}

/// NumPy arrays are read element by element from their bytes, in any dtype and order: a
/// 56 MB table of uint8 (60 KB packed) takes about its own size in memory, where decoding
/// it to a list of values took 1.8 GB. Strings are refused by their dtype.
#[test]
fn npz_arrays_are_read_where_they_lie() {
    let dir = fresh_dir("import-tables", "npz");
    let d = dir.path();
    // Two rows: p0 Fortran-ordered uint8, p1 big-endian int16, radius float32, ids int64.
    let p0 = npy("|u1", true, "(2, 3)", &[1, 4, 2, 5, 3, 6]);
    let p1: Vec<u8> = [1i16, 2, 9, -4, 5, 6]
        .iter()
        .flat_map(|v| v.to_be_bytes())
        .collect();
    let p1 = npy(">i2", false, "(2, 3)", &p1);
    let r: Vec<u8> = [0.5f32, 0.25]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let id: Vec<u8> = [7i64, 9].iter().flat_map(|v| v.to_le_bytes()).collect();
    let path = d.join("mixed.npz");
    write_npz(
        &path,
        &[
            ("p0", p0),
            ("p1", p1),
            ("radius", npy("<f4", false, "(2,)", &r)),
            ("id", npy("<i8", false, "(2,)", &id)),
        ],
    );
    let out = d.join("mixed.json");
    ok(&[
        "import",
        path.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    let s: serde_json::Value = serde_json::from_slice(&std::fs::read(&out).unwrap()).unwrap();
    let cyl = s["cylinders"].as_array().unwrap();
    assert_eq!(xyz(&cyl[0], "p0"), [1.0, 2.0, 3.0]);
    assert_eq!(xyz(&cyl[1], "p0"), [4.0, 5.0, 6.0]);
    assert_eq!(xyz(&cyl[0], "p1"), [1.0, 2.0, 9.0]);
    assert_eq!(xyz(&cyl[1], "p1"), [-4.0, 5.0, 6.0]);
    assert_eq!(cyl[1]["radius"].as_f64(), Some(0.25));
    assert_eq!(cyl[1]["id"].as_u64(), Some(9));

    // Strings: named by their dtype.
    let text = npy("<U1", false, "(2,)", &[b'1', 0, 0, 0, b'2', 0, 0, 0]);
    let path = d.join("strings.npz");
    let p0 = npy("|u1", false, "(2, 3)", &[0; 6]);
    write_npz(&path, &[("p0", p0.clone()), ("p1", p0), ("radius", text)]);
    let o = cylaov(&[
        "import",
        path.to_str().unwrap(),
        "-o",
        d.join("s.json").to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!d.join("s.json").exists());
    assert!(
        err.contains("strings.npz: array radius: an array of dtype \"<U1\"; readable are float32, float64, (u)int8 to (u)int64 and bool"),
        "{err}"
    );

    #[cfg(target_os = "linux")]
    {
        let n = 8_000_000;
        let zeros = vec![0u8; n * 3];
        let path = d.join("big.npz");
        let shape = format!("({n}, 3)");
        write_npz(
            &path,
            &[
                ("p0", npy("|u1", false, &shape, &zeros)),
                ("p1", npy("|u1", false, &shape, &zeros)),
                (
                    "radius",
                    npy("|u1", false, &format!("({n},)"), &vec![1u8; n]),
                ),
            ],
        );
        assert!(std::fs::metadata(&path).unwrap().len() < 1 << 20);
        let out = d.join("big.json");
        let (code, peak, err) = peak_memory(&[
            "import",
            path.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        assert_eq!(code, 1, "{err}");
        assert!(err.contains("big.npz: p1[0]: zero length"), "{err}");
        // The unpacked arrays (56 MB) and little else.
        assert!(peak < 250 << 20, "peak memory {} MB", peak >> 20);
        assert!(!out.exists());
    }
}

/// A scene larger than the 512 MiB every reader accepts is refused before it is written,
/// with its size and how many cylinders fit: 2.5 million cylinders whose float32 ends
/// print as 17 digits take about 700 MB as JSON.
#[test]
fn a_scene_too_large_to_read_is_not_written() {
    let dir = fresh_dir("import-tables", "large");
    let d = dir.path();
    let n = 2_500_000;
    let f32s = |v: &[f32], rows: usize| -> Vec<u8> {
        (0..rows)
            .flat_map(|_| v.iter().flat_map(|x| x.to_le_bytes()))
            .collect()
    };
    let path = d.join("large.npz");
    write_npz(
        &path,
        &[
            (
                "p0",
                npy(
                    "<f4",
                    false,
                    &format!("({n}, 3)"),
                    &f32s(&[0.1, 0.1, 0.1], n),
                ),
            ),
            (
                "p1",
                npy(
                    "<f4",
                    false,
                    &format!("({n}, 3)"),
                    &f32s(&[0.1, 0.1, 1.1], n),
                ),
            ),
            (
                "radius",
                npy("<f4", false, &format!("({n},)"), &f32s(&[0.1], n)),
            ),
        ],
    );
    let out = d.join("large.json");
    let o = cylaov(&[
        "import",
        path.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(!out.exists());
    let bytes: u64 = err
        .split("would take ")
        .nth(1)
        .and_then(|t| t.split(' ').next())
        .and_then(|t| t.parse().ok())
        .unwrap_or_else(|| panic!("{err}"));
    // Each cylinder: two lines of three 19-digit numbers, a radius, caps and a 7-digit id.
    let each = bytes as f64 / n as f64;
    assert!(
        (240.0..270.0).contains(&each),
        "{each} bytes a cylinder: {err}"
    );
    let fit = (536870912.0 / each.round()).floor();
    assert!(
        err.contains(&format!(
            "large.npz: the scene of its {n} cylinders would take {bytes} bytes, more than the 536870912 (512 MiB) a scene file may have"
        )) && err.contains(&format!("import fewer cylinders: at {} bytes each, about {fit} fit", each.round())),
        "{err}"
    );
}

/// The camera `import` places is checked in the terms the user gave: `--width` × `--height`
/// beyond 64 megapixels, a `--fov` too small for a focal length, a table so large that the
/// camera framing it stands beyond 1e12, each named by its flag or the table's extent.
#[test]
fn the_framing_cameras_limits_name_the_flags() {
    let dir = fresh_dir("import-tables", "camera");
    let d = dir.path();
    let table = d.join("big.csv");
    std::fs::write(&table, "x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,1,0.1\n").unwrap();
    let out = d.join("big.json");
    let o = cylaov(&[
        "import",
        table.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
        "--width",
        "16384",
        "--height",
        "16384",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(!out.exists());
    assert_eq!(
        err,
        "error: --width/--height: width × height must be <= 67108864 pixels (64 megapixels, e.g. 8192 × 8192), got 16384 × 16384 = 268435456\n"
    );
    refused(
        d,
        "far.csv",
        "x0,y0,z0,x1,y1,z1,radius\n0,0,0,0,0,9e11,0.1\n",
        &[],
        "far.csv: the camera framing every cylinder cannot be placed: the cylinders fill a sphere of radius 450000000000.1 about [0.0, 0.0, 450000000000.0], which --fov 50 with --width 640 --height 480 sees whole from 1363124196675.",
    );
    let o = cylaov(&[
        "import",
        d.join("far.csv").to_str().unwrap(),
        "-o",
        d.join("far.json").to_str().unwrap(),
        "--fov",
        "120",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}
