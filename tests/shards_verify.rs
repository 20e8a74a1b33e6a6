//! `batch --format webdataset` with `--verify-fraction`, `--report` and the memory check:
//! the views chosen as in the files format are checked (a stand-in reference, then
//! Mitsuba), a disagreement fails the view as a render failure does, the report page is
//! written, the tars are those of a run without verification, and a view too large for the
//! memory left fails alone.

mod common;
use common::{cylaov, ok};

use cylaov::dataset::batch::shards::{
    ShardOptions, ShardSummary, TarOutcome, TarSelection, write_shards,
};
use cylaov::dataset::batch::{BatchOptions, ProgressMode, Shard, Verdict, Verifier, ViewSource};
use cylaov::image::AovImage;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Mutex;

/// `generate --count 4 --seed 1 --cylinders 10 --width 64 --height 48` into `tmp/data`.
fn generated(tmp: &Path) -> PathBuf {
    let data = tmp.join("data");
    ok(&[
        "generate",
        "--count",
        "4",
        "--seed",
        "1",
        "--cylinders",
        "10",
        "--width",
        "64",
        "--height",
        "48",
        "--out",
        data.to_str().unwrap(),
    ]);
    data
}

/// The tars of `out`, by name.
fn tars(out: &Path) -> Vec<(String, Vec<u8>)> {
    let mut v: Vec<(String, Vec<u8>)> = std::fs::read_dir(out)
        .unwrap()
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "tar"))
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    v.sort();
    assert!(!v.is_empty(), "no tars in {}", out.display());
    v
}

/// A stand-in reference: reads the EXR it is given back, and disagrees on view `bad`.
struct ReadsBack {
    checked: Mutex<Vec<String>>,
    bad: &'static str,
}

impl Verifier for ReadsBack {
    fn check(
        &self,
        view: &ViewSource,
        scene: &cylaov::scene::Scene,
        exr: &Path,
        work: &Path,
    ) -> anyhow::Result<Verdict> {
        assert!(work.is_dir() && exr.starts_with(work), "{}", exr.display());
        let img = AovImage::read_exr(exr)?;
        self.checked.lock().unwrap().push(view.id());
        let ok = img.width == scene.camera.width as usize && view.name != self.bad;
        Ok(Verdict {
            passes: ok,
            report: format!("stand-in verdict for {}", view.name),
        })
    }
}

/// All the tars of `data`'s views into `out`, two views a tar.
fn two_a_tar(
    data: &Path,
    out: &Path,
    opts: &BatchOptions,
    verifier: Option<&dyn Verifier>,
) -> anyhow::Result<ShardSummary> {
    let sopts = ShardOptions {
        shard_size: 2,
        ..ShardOptions::default()
    };
    let all = TarSelection::Shard(Shard::ALL);
    write_shards(data, out, &all, opts, &sopts, ProgressMode::Off, verifier)
}

/// A stand-in whose check of view `000001` finds the disk full, as writing its EXR would.
struct DiskFull;

impl Verifier for DiskFull {
    fn check(
        &self,
        view: &ViewSource,
        _scene: &cylaov::scene::Scene,
        _exr: &Path,
        _work: &Path,
    ) -> anyhow::Result<Verdict> {
        if view.name == "000001" {
            return Err(std::io::Error::from_raw_os_error(28).into());
        }
        Ok(Verdict {
            passes: true,
            report: String::new(),
        })
    }
}

/// A view that runs out of the disk stops the run, and its tar is not committed: no tar
/// and no sidecar vouch for a tar missing that view, so a rerun writes it whole.
#[test]
fn a_tar_whose_view_ran_out_of_disk_is_not_committed() {
    let tmp = common::fresh_dir("shards-verify", "disk-full");
    let data = generated(tmp.path());
    let opts = BatchOptions {
        verify_fraction: 1.0,
        ..BatchOptions::default()
    };
    let out = tmp.path().join("out");
    let e = two_a_tar(&data, &out, &opts, Some(&DiskFull)).unwrap_err();
    assert!(format!("{e:#}").contains("the disk is full"), "{e:#}");
    assert!(!out.join("shard-000000.tar").exists());
    assert!(!out.join("shard-000000.json").exists());
    assert!(!out.join(".partial").exists());
    let s = two_a_tar(&data, &out, &BatchOptions::default(), None).unwrap();
    assert!(s.failures.is_empty() && s.index_written, "{s}");
    assert_eq!(
        s.rendered
            + 2 * s
                .outcomes
                .iter()
                .filter(|o| o.1 == TarOutcome::Skipped)
                .count(),
        4,
        "{s}"
    );
}

/// The library's `write_shards` with a verifier: the chosen views are checked from their
/// EXR, the one that disagrees is absent from its tar and in the failures, and the tar is
/// otherwise the bytes of an unverified run (with that view failing alone); no temporary
/// file stays.
#[test]
fn shards_check_selected_views_and_fail_disagreements() {
    let tmp = common::fresh_dir("shards-verify", "stand-in");
    let data = generated(tmp.path());
    let opts = |fraction| BatchOptions {
        verify_fraction: fraction,
        verify_seed: 1,
        ..BatchOptions::default()
    };
    let verifier = ReadsBack {
        checked: Mutex::new(Vec::new()),
        bad: "000001",
    };
    let out = tmp.path().join("verified");
    let s = two_a_tar(&data, &out, &opts(1.0), Some(&verifier)).unwrap();
    let mut checked = verifier.checked.lock().unwrap().clone();
    checked.sort();
    assert_eq!(checked, ["000000", "000001", "000002", "000003"]);
    assert_eq!((s.verified, s.failures.len()), (4, 1), "{s}");
    assert!(s.to_string().contains("4 views verified"), "{s}");
    assert_eq!(s.failures[0].key, "000001");
    assert!(
        s.failures[0]
            .error
            .contains("disagrees with the reference: stand-in verdict for 000001"),
        "{}",
        s.failures[0].error
    );
    let failures = std::fs::read_to_string(&s.failures_path).unwrap();
    assert!(failures.contains("000001"), "{failures}");
    assert!(!out.join(".partial").exists());
    let verified = tars(&out);
    let tar0 = String::from_utf8_lossy(&verified[0].1);
    assert!(tar0.contains("000000.json") && !tar0.contains("000001.json"));

    // A rerun keeps both tars and checks their views again, as the files format checks
    // the views it keeps: a reference that now disagrees on 000002 fails that view too
    // (the tars stay as they are), and 000001 is listed once.
    let recheck = ReadsBack {
        checked: Mutex::new(Vec::new()),
        bad: "000002",
    };
    let s = two_a_tar(&data, &out, &opts(1.0), Some(&recheck)).unwrap();
    assert!(s.outcomes.iter().all(|o| o.1 == TarOutcome::Skipped), "{s}");
    let mut checked = recheck.checked.lock().unwrap().clone();
    checked.sort();
    assert_eq!(checked, ["000000", "000001", "000002", "000003"]);
    let failed: Vec<&str> = s.failures.iter().map(|f| f.key.as_str()).collect();
    assert_eq!((s.verified, failed), (4, vec!["000001", "000002"]), "{s}");
    assert_eq!(tars(&out), verified);
    assert!(!out.join(".partial").exists());

    // Half the views, the same choice as the files format's.
    let picked: Vec<String> = (0..4)
        .map(|i| format!("{i:06}"))
        .filter(|n| cylaov::dataset::batch::selected_for_verify(1, n, 0.5))
        .collect();
    let verifier = ReadsBack {
        checked: Mutex::new(Vec::new()),
        bad: "000001",
    };
    let half = tmp.path().join("half");
    two_a_tar(&data, &half, &opts(0.5), Some(&verifier)).unwrap();
    let mut checked = verifier.checked.lock().unwrap().clone();
    checked.sort();
    assert_eq!(checked, picked);

    // Without a verifier the tar of the passing views is the same bytes.
    let plain = tmp.path().join("plain");
    let s = two_a_tar(&data, &plain, &opts(0.0), None).unwrap();
    assert!(s.failures.is_empty(), "{s}");
    let plain = tars(&plain);
    assert_eq!(verified[1], plain[1], "the tar of passing views");
}

/// `batch --format webdataset --verify-fraction 1 --report DIR` against real Mitsuba
/// renders: every view agrees, the page names each, and the tars are byte for byte those
/// of the same batch without verification. `--report` alone is refused first.
#[test]
fn webdataset_verify_fraction_and_report_with_mitsuba() {
    let tmp = common::fresh_dir("shards-verify", "mitsuba");
    let data = generated(tmp.path());
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (out, page) = (tmp.path().join("out"), tmp.path().join("page"));
    let base = ["batch", &s(&data), "--format", "webdataset", "--out"];

    let mut args: Vec<&str> = base.to_vec();
    let refused_out = s(&tmp.path().join("refused"));
    let page_s = s(&page);
    args.extend([refused_out.as_str(), "--report", &page_s]);
    let o = cylaov(&args);
    assert_eq!(o.status.code(), Some(1));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("--report") && err.contains("goes with --verify-fraction"),
        "{err}"
    );
    assert!(!page.exists() && !tmp.path().join("refused").exists());

    if common::venv_python().is_none() {
        return;
    }
    let plain = s(&tmp.path().join("plain"));
    let mut args: Vec<&str> = base.to_vec();
    args.extend([plain.as_str(), "--shard-size", "2"]);
    ok(&args);
    let out_s = s(&out);
    let mut args: Vec<&str> = base.to_vec();
    args.extend([
        out_s.as_str(),
        "--shard-size",
        "2",
        "--verify-fraction",
        "1",
        "--report",
        &page_s,
    ]);
    let o = cylaov(&args);
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(o.status.success(), "{text}");
    assert!(
        text.contains("4 views verified against the reference"),
        "{text}"
    );
    let html = std::fs::read_to_string(page.join("index.html")).expect("index.html");
    assert_eq!(html.matches("<tr class=\"view\">").count(), 4, "{html}");
    for name in ["000000", "000001", "000002", "000003"] {
        assert!(html.contains(&format!(">{name}</a>")), "{name}: {html}");
    }
    let (verified, plain) = (tars(&out), tars(Path::new(&plain)));
    assert_eq!(verified.len(), 2);
    for ((a, x), (b, y)) in verified.iter().zip(&plain) {
        assert_eq!(a, b);
        assert!(x == y, "{a}: the tars differ");
    }
    assert!(!out.join(".partial").exists());
}

/// A view too large for the memory `ulimit -v` leaves fails alone before it renders, with
/// the memory line in the failures file, as in the files format; the small one is written.
#[test]
fn webdataset_view_over_the_memory_left_fails_alone() {
    let tmp = common::fresh_dir("shards-verify", "memory");
    let input = tmp.path().join("in");
    std::fs::create_dir(&input).unwrap();
    let scene = |name: &str, w: u32, h: u32| {
        std::fs::write(
            input.join(format!("{name}.json")),
            format!(
                r#"{{ "camera": {{ "origin": [0, -4, 0], "target": [0, 0, 0], "up": [0, 0, 1],
                     "fov_deg": 40, "width": {w}, "height": {h} }},
                   "cylinders": [ {{ "p0": [0, 3, -50], "p1": [0, 3, 50], "radius": 20, "id": 1 }} ] }}"#
            ),
        )
        .unwrap();
    };
    scene("big", 8192, 8192);
    scene("small", 64, 48);
    let out = tmp.path().join("out");
    let o = Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 1000000; exec \"$0\" \"$@\"")
        .arg(env!("CARGO_BIN_EXE_cylaov"))
        .args(["batch", input.to_str().unwrap(), "--out"])
        .arg(&out)
        .args(["--format", "webdataset"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    let failures = std::fs::read_to_string(out.join("failures.0-of-1.jsonl")).unwrap();
    assert_eq!(failures.lines().count(), 1, "{failures}");
    assert!(
        failures.contains("big") && failures.contains("rendering big needs about"),
        "{failures}"
    );
    let tar = String::from_utf8_lossy(&tars(&out)[0].1).into_owned();
    assert!(tar.contains("small.json") && !tar.contains("big.json"));
}
