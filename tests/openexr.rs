//! Our direct EXR writer read back by OpenEXR itself (through Mitsuba's `Bitmap` in the
//! reference venv), not only by the `exr` crate. Skipped, saying so, without the venv,
//! unless `CYLAOV_REQUIRE_VENV=1` (then a missing venv fails the test).

mod common;
use common::venv_python;

use cylaov::render::{RenderOptions, render};
use cylaov::scene::{self, Aov};
use std::path::Path;
use std::process::Command;

#[test]
fn openexr_reads_every_channel_of_our_uncompressed_files() {
    let Some(py) = venv_python() else { return };
    let sc =
        scene::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/single.json")).unwrap();
    let img = render(&sc, &RenderOptions::new(Aov::ALL.to_vec())).image;
    let tmp = tempfile::Builder::new()
        .prefix("cylaov-openexr-")
        .tempdir()
        .unwrap();
    let dir = tmp.path();
    let path = dir.join("all.exr");
    img.write_exr(&path, cylaov::output::format::exr::Compression::None)
        .unwrap();
    let script = r#"
import sys, numpy as np, mitsuba as mi
mi.set_variant('scalar_rgb')
b = mi.Bitmap(sys.argv[1])
names = [b.struct_()[i].name for i in range(b.channel_count())]
a = np.array(b).reshape(-1, len(names))
k = np.arange(a.shape[0], dtype=np.float64)
for i, n in enumerate(names):
    print(n, repr(float((a[:, i].astype(np.float64) * (1 + k)).sum())))
"#;
    let out = Command::new(&py)
        .args(["-c", script, path.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    let mut seen = 0;
    for line in text.lines() {
        let (name, sum) = line.split_once(' ').unwrap();
        let sum: f64 = sum.parse().unwrap();
        let ours: f64 = match img
            .channel(name)
            .unwrap_or_else(|| panic!("extra channel {name}"))
        {
            // Weighted by 1 + pixel index, so a misplaced row or column shows.
            cylaov::image::ChannelRef::F32(v) => v
                .iter()
                .enumerate()
                .map(|(k, &x)| x as f64 * (1 + k) as f64)
                .sum(),
            cylaov::image::ChannelRef::U32(v) => v
                .iter()
                .enumerate()
                .map(|(k, &x)| x as f64 * (1 + k) as f64)
                .sum(),
        };
        assert!(
            (sum - ours).abs() <= 1e-9 * ours.abs().max(1.0),
            "{name}: OpenEXR {sum}, ours {ours}"
        );
        seen += 1;
    }
    assert_eq!(seen, img.names().len(), "OpenEXR saw {text}");
}

/// `cylaov render` writes one uncompressed EXR band by band during the trace, and the
/// whole image at the end when it also makes pictures (`--preview`): both give the same
/// bytes, every AOV included, at a height that is no multiple of the 16-row band.
#[test]
fn streamed_and_whole_image_renders_write_the_same_file() {
    let tmp = common::fresh_dir("openexr", "streamed");
    let dir = tmp.path();
    let committed = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/cluster.json");
    let mut json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(committed).unwrap()).unwrap();
    json["camera"]["height"] = 101.into();
    let scene = dir.join("cluster-101.json");
    std::fs::write(&scene, json.to_string()).unwrap();
    let aovs: Vec<&str> = Aov::ALL.iter().map(|a| a.name()).collect();
    let aovs = aovs.join(",");
    let (a, b) = (dir.join("a.exr"), dir.join("b.exr"));
    let pics = dir.join("pics");
    for (out, extra) in [
        (&a, vec![]),
        (&b, vec!["--preview", pics.to_str().unwrap()]),
    ] {
        let mut args = vec![
            "render",
            scene.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ];
        args.extend(["--aov", &aovs]);
        args.extend(extra);
        common::ok(&args);
    }
    assert!(
        pics.join("b.normal.preview.png").exists(),
        "the whole-image path ran"
    );
    let (x, y) = (std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    assert!(
        x.len() > 100_000 && x == y,
        "{} and {} bytes",
        x.len(),
        y.len()
    );
}
