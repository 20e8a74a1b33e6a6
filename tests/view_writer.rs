//! One view writer: `render` and a one-view `batch` write the same bytes for the same
//! view, files and memory hold the same members, and a failure while committing leaves
//! none of a view's files.

mod common;
use common::{cylaov, ok, tree};

use cylaov::output::format::exr::{Compression, ExrLayout};
use cylaov::output::pipeline::view::{FileSink, Member, MemorySink, ViewPlan};
use cylaov::render::RenderOptions;
use cylaov::scene::camera::Camera;
use std::path::Path;

/// A small scene with every kind of pixel: caps, an open tube seen inside, a miss.
const SCENE: &str = r#"{
  "camera": {"origin": [3, -5, 2.5], "target": [0, 0, 0.6], "up": [0, 0, 1],
             "fov_deg": 40, "fov_axis": "x", "width": 48, "height": 36},
  "cylinders": [
    {"p0": [0, 0, 0], "p1": [0, 0, 1.5], "radius": 0.5, "caps": true},
    {"p0": [1, 0.5, 0], "p1": [1.2, 0.5, 1], "radius": 0.3, "caps": false}
  ],
  "aovs": ["depth", "normal", "shape_id", "part"]
}"#;

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// The same view through `render -o R/v.exr` and `batch IN --out B` (scene `IN/v.json`):
/// the EXR (both layouts), camera JSON and Open3D JSON are byte for byte the same.
#[test]
fn render_and_a_one_view_batch_write_the_same_bytes() {
    let tmp = common::fresh_dir("view_writer", "same");
    let d = tmp.path();
    std::fs::create_dir_all(d.join("in")).unwrap();
    std::fs::write(d.join("in/v.json"), SCENE).unwrap();
    for (layout, members) in [
        ("layers", vec!["v.exr"]),
        (
            "per-aov",
            vec![
                "v.depth.exr",
                "v.normal.exr",
                "v.shape_id.exr",
                "v.part.exr",
            ],
        ),
    ] {
        let (r, b) = (d.join(format!("r-{layout}")), d.join(format!("b-{layout}")));
        let scene = d.join("in/v.json");
        ok(&[
            "render",
            s(&scene),
            "-o",
            s(&r.join("v.exr")),
            "--exr-layout",
            layout,
        ]);
        ok(&[
            "batch",
            s(&d.join("in")),
            "--out",
            s(&b),
            "--no-png",
            "--exr-layout",
            layout,
        ]);
        let (rt, bt) = (tree(&r), tree(&b));
        for name in members
            .iter()
            .copied()
            .chain(["v.camera.json", "v.open3d.json"])
        {
            let (x, y) = (&rt[name], bt.get(name).expect(name));
            assert!(x.len() > 100, "{layout} {name}: {} bytes", x.len());
            assert!(x == y, "{layout} {name}: render and batch differ");
        }
    }
}

/// The plan executed into memory holds the bytes it writes as files, EXRs last.
#[test]
fn memory_and_files_hold_the_same_members() {
    let tmp = common::fresh_dir("view_writer", "memory");
    let d = tmp.path().to_path_buf();
    let path = d.join("v.json");
    std::fs::write(&path, SCENE).unwrap();
    let scene = cylaov::scene::load(&path).unwrap();
    let plan = ViewPlan {
        camera: Camera::new(scene.camera),
        exr_aovs: scene.aovs.clone(),
        layout: ExrLayout::PerAov,
        compression: Compression::None,
        depth_png: None,
        mask: false,
        normal_picture: false,
        previews: true,
        stamp: Some("stamp\n".into()),
        ply: true,
    };
    let opts = RenderOptions::new(plan.traced_aovs());
    let mut memory = MemorySink::new("v");
    plan.execute(&scene, &opts, &mut memory).unwrap();
    let out = d.join("out");
    let dir = out.clone();
    let mut files = FileSink::beside(move |m: Member| dir.join(format!("v.{}", m.suffix())));
    plan.execute(&scene, &opts, &mut files).unwrap();
    let on_disk = tree(&out);
    let names: Vec<&str> = memory.members.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "v.camera.json",
            "v.open3d.json",
            "v.render.json",
            "v.ply",
            "v.normal.preview.png",
            "v.depth.preview.png",
            "v.depth.exr",
            "v.normal.exr",
            "v.shape_id.exr",
            "v.part.exr"
        ]
    );
    assert_eq!(on_disk.len(), memory.members.len());
    for (name, bytes) in &memory.members {
        assert!(on_disk[name] == *bytes, "{name} differs");
    }
}

/// Every file of `dir` whose name ends in `.tmp`, recursively, and the `.partial` folder.
fn leftovers(dir: &Path) -> Vec<String> {
    let mut left: Vec<String> = tree(dir)
        .into_keys()
        .filter(|k| k.ends_with(".tmp"))
        .collect();
    if dir.join(".partial").exists() {
        left.push(".partial".into());
    }
    left
}

/// The last rename of a commit fails (`CYLAOV_FAIL_WRITES=COMMIT`) after the others
/// happened: `render` and `batch` put back nothing of the view, and leave no temporary
/// file.
#[test]
fn a_failure_while_committing_leaves_nothing_half_written() {
    let tmp = common::fresh_dir("view_writer", "commit");
    let d = tmp.path();
    std::fs::create_dir_all(d.join("in")).unwrap();
    let scene = d.join("in/v.json");
    std::fs::write(&scene, SCENE).unwrap();
    let fail = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_cylaov"))
            .args(args)
            .env("CYLAOV_FAIL_WRITES", "COMMIT")
            .env_remove("SLURM_ARRAY_TASK_ID")
            .output()
            .unwrap()
    };
    let r = d.join("r");
    let r_exr = r.join("v.exr");
    std::fs::create_dir_all(&r).unwrap();
    for extra in [&[][..], &["--depth-png", "--preview", s(&r)][..]] {
        let mut args = vec!["render", s(&scene), "-o", s(&r_exr)];
        args.extend_from_slice(extra);
        let o = fail(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
        assert!(err.contains("putting the outputs in place"), "{err}");
        let left = tree(&r);
        assert!(left.is_empty(), "{args:?} left {:?}", left.keys());
    }
    // A batch: its view fails, and an older complete view is not half replaced.
    let b = d.join("b");
    ok(&["batch", s(&d.join("in")), "--out", s(&b)]);
    let before = tree(&b);
    assert!(before.contains_key("v.exr") && before.contains_key("v.mask.png"));
    let o = fail(&["batch", s(&d.join("in")), "--out", s(&b), "--no-png"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "batch with a failing commit: {err}");
    let after = tree(&b);
    let view: Vec<&String> = after.keys().filter(|k| k.starts_with("v.")).collect();
    assert!(view.is_empty(), "view files left: {view:?}");
    assert!(leftovers(&b).is_empty(), "{:?}", leftovers(&b));
    // Without the failure the view renders again.
    assert!(
        cylaov(&["batch", s(&d.join("in")), "--out", s(&b), "--no-png"])
            .status
            .success()
    );
    assert!(b.join("v.exr").exists());
}

/// A compressed EXR is a pure function of its view and options: two processes write the same
/// bytes for every compression (the EXR encoder's header attributes would otherwise come out
/// in a different order in each process), and the header lists its attributes by name.
#[test]
fn compressed_exrs_are_the_same_bytes_in_every_process() {
    let tmp = common::fresh_dir("view_writer", "compressed");
    let d = tmp.path();
    std::fs::write(d.join("v.json"), SCENE).unwrap();
    let aovs = "distance,depth,normal,position,shape_id,part,normal_camera";
    for c in ["zip", "zips", "piz", "rle"] {
        let mut files = Vec::new();
        for run in 0..3 {
            let out = d.join(format!("{c}-{run}.exr"));
            let v = d.join("v.json");
            ok(&[
                "render",
                s(&v),
                "-o",
                s(&out),
                "--compression",
                c,
                "--aov",
                aovs,
            ]);
            files.push(std::fs::read(&out).unwrap());
        }
        assert!(
            files.iter().all(|f| f == &files[0]),
            "{c}: bytes differ between runs"
        );
        // The attribute names in file order, read from the header (magic, version, records).
        let bytes = &files[0];
        let (mut at, mut names) = (8, Vec::new());
        while bytes[at] != 0 {
            let name_end = at + bytes[at..].iter().position(|&b| b == 0).unwrap();
            let type_end =
                name_end + 1 + bytes[name_end + 1..].iter().position(|&b| b == 0).unwrap();
            let size = i32::from_le_bytes(bytes[type_end + 1..type_end + 5].try_into().unwrap());
            names.push(String::from_utf8_lossy(&bytes[at..name_end]).into_owned());
            at = type_end + 5 + size as usize;
        }
        let mut sorted = names.clone();
        sorted.sort();
        assert_eq!(names, sorted, "{c}");
        assert!(names.len() > 20, "{c}: {names:?}");
    }
}
