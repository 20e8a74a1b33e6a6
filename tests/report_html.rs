//! `verify --report DIR`: the page is self-contained (no network address, every image it
//! names beside it), has one table row per view, and, in headless Chromium (when installed;
//! skipped saying so otherwise), loads without console errors and renders a picture that is
//! not blank. Skipped without the reference venv, as the other Mitsuba tests.

mod common;
use common::venv_python;

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn chromium() -> Option<PathBuf> {
    ["chromium", "chromium-browser"].iter().find_map(|name| {
        std::env::var_os("PATH").and_then(|paths| {
            std::env::split_paths(&paths)
                .map(|d| d.join(name))
                .find(|p| p.is_file())
        })
    })
}

#[test]
fn the_report_page_is_self_contained_and_loads() {
    let Some(py) = venv_python() else { return };
    let venv = py.parent().and_then(Path::parent).expect("venv dir");
    let tmp = common::fresh_dir("report", "page");
    let scenes = tmp.path().join("scenes");
    std::fs::create_dir_all(&scenes).expect("dir");
    for stem in ["single", "mixed_caps"] {
        std::fs::copy(
            root().join(format!("scenes/{stem}.json")),
            scenes.join(format!("{stem}.json")),
        )
        .expect("copy");
    }
    std::fs::copy(
        root().join("scenes/stress/far_offset.json"),
        scenes.join("far_offset.json"),
    )
    .expect("copy");
    let out = tmp.path().join("report");
    let o = Command::new(env!("CARGO_BIN_EXE_cylaov"))
        .args(["verify", s(&scenes), "--report", s(&out)])
        .env("CYLAOV_VENV", venv)
        .output()
        .expect("running cylaov");
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let page = std::fs::read_to_string(out.join("index.html")).expect("index.html");
    assert_eq!(page.matches("<tr class=\"view\">").count(), 3, "{page}");
    assert!(
        !page.contains("http:") && !page.contains("https:"),
        "no network"
    );
    // Every image the page names is beside it; three per checked view.
    let images: Vec<&str> = page
        .split("src=\"")
        .skip(1)
        .filter_map(|rest| rest.split('"').next())
        .collect();
    assert_eq!(images.len(), 9, "{images:?}");
    for img in &images {
        assert!(out.join(img).is_file(), "{img}");
    }
    // far_offset's worst pixels with their three answers and class, and the note.
    assert!(page.contains("Mitsuba cannot discriminate here"), "note");
    assert!(
        page.contains("<td>reference error</td>"),
        "a classified pixel"
    );

    let Some(chrome) = chromium() else {
        // scripts/test installs it under CI: there the browser half must run.
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "CI=true and no chromium on PATH (scripts/test installs it)"
        );
        eprintln!("SKIPPED: no chromium on PATH (apt-get install -y chromium)");
        return;
    };
    let profile = common::fresh_dir("report", "chromium-profile");
    let shot = tmp.path().join("shot.png");
    let url = format!("file://{}", out.join("index.html").display());
    let o = Command::new(&chrome)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-dev-shm-usage",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--enable-logging=stderr",
            "--window-size=1200,900",
            &format!("--user-data-dir={}", profile.path().display()),
            &format!("--screenshot={}", shot.display()),
            &url,
        ])
        .output()
        .expect("running chromium");
    let log = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{log}");
    let console: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("CONSOLE") && l.to_lowercase().contains("error"))
        .collect();
    assert!(console.is_empty(), "{console:?}");
    let img = image::open(&shot).expect("screenshot").to_rgb8();
    let first = *img.get_pixel(0, 0);
    let differing = img.pixels().filter(|p| **p != first).count();
    assert!(
        differing > (img.width() * img.height()) as usize / 50,
        "the screenshot is nearly blank: {differing} pixels differ"
    );
}

/// `batch --verify-fraction 1 --report DIR` writes the page of `verify --report` for the
/// views it checked (one row and three pictures beside the page per view, the classified
/// pixels), and so does `verify OUT --report DIR` of its written files; `--report` without
/// `--verify-fraction` is refused naming both flags, before anything is rendered.
#[test]
fn batch_and_written_files_write_the_same_page() {
    let tmp = common::fresh_dir("report", "batch");
    let scenes = tmp.path().join("scenes");
    std::fs::create_dir_all(&scenes).expect("dir");
    for stem in ["single", "mixed_caps"] {
        std::fs::copy(
            root().join(format!("scenes/{stem}.json")),
            scenes.join(format!("{stem}.json")),
        )
        .expect("copy");
    }
    let out = tmp.path().join("render");
    let page_dir = tmp.path().join("page");
    let cylaov = |args: &[&str], venv: Option<&Path>| {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_cylaov"));
        cmd.args(args);
        if let Some(v) = venv {
            cmd.env("CYLAOV_VENV", v);
        }
        cmd.output().expect("running cylaov")
    };
    let o = cylaov(
        &[
            "batch",
            s(&scenes),
            "--out",
            s(&out),
            "--report",
            s(&page_dir),
        ],
        None,
    );
    assert_ne!(o.status.code(), Some(0));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--report") && err.contains("goes with --verify-fraction"),
        "{err}"
    );
    assert!(!out.exists() && !page_dir.exists(), "nothing written");

    let Some(py) = venv_python() else { return };
    let venv = py.parent().and_then(Path::parent).expect("venv dir");
    let check_page = |dir: &Path| {
        let page = std::fs::read_to_string(dir.join("index.html")).expect("index.html");
        assert_eq!(page.matches("<tr class=\"view\">").count(), 2, "{page}");
        for name in ["single", "mixed_caps"] {
            assert!(page.contains(&format!(">{name}</a>")), "{name}: {page}");
        }
        let images: Vec<&str> = page
            .split("src=\"")
            .skip(1)
            .filter_map(|rest| rest.split('"').next())
            .collect();
        assert_eq!(images.len(), 6, "{images:?}");
        for img in &images {
            assert!(dir.join(img).is_file(), "{img}");
        }
        page
    };
    let o = cylaov(
        &[
            "batch",
            s(&scenes),
            "--out",
            s(&out),
            "--no-png",
            "--verify-fraction",
            "1",
            "--report",
            s(&page_dir),
        ],
        Some(venv),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let from_batch = check_page(&page_dir);
    let written_dir = tmp.path().join("page-written");
    let o = cylaov(
        &["verify", s(&out), "--report", s(&written_dir)],
        Some(venv),
    );
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stdout)
    );
    let from_verify = check_page(&written_dir);
    // The same rows: the table is the same check's.
    let rows = |page: &str| -> Vec<String> {
        page.split("<tr class=\"view\">")
            .skip(1)
            .map(|r| r.split("</tr>").next().unwrap_or("").to_string())
            .collect()
    };
    assert_eq!(rows(&from_batch), rows(&from_verify));
}
