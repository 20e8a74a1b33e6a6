//! `cylaov bench --scaling` as a user runs it: every workload at every thread count reaches
//! the table and the CSV, each having made every view, with the efficiency taken to its own
//! one-thread row. No timing is judged here: the figures live in docs/performance.md.

mod common;

use std::path::Path;

#[test]
fn scaling_rows_cover_every_workload_and_thread_count() {
    let py = common::venv_python();
    let tmp = common::fresh_dir("bench", "scaling");
    let csv = tmp.path().join("scaling.csv");
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_cylaov"));
    cmd.args([
        "bench",
        "--scaling",
        "--batch-views",
        "40",
        "--threads",
        "2",
        "--csv",
    ])
    .arg(&csv);
    if let Some(py) = &py {
        cmd.env(
            "CYLAOV_VENV",
            py.parent().and_then(Path::parent).expect("venv dir"),
        );
    }
    let o = cmd.output().expect("running cylaov");
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let text = std::fs::read_to_string(&csv).expect("the CSV");
    let mut reader = csv::Reader::from_reader(text.as_bytes());
    let header: Vec<String> = reader.headers().unwrap().iter().map(String::from).collect();
    assert_eq!(
        header,
        [
            "threads",
            "workload",
            "views",
            "seconds",
            "views_per_s",
            "efficiency"
        ]
    );
    let rows: Vec<csv::StringRecord> = reader.records().map(Result::unwrap).collect();
    // The DataLoader rows need the package and torch in the venv (scripts/test installs
    // both); without them the first lines say why they are left out.
    let dataloader = !stdout.contains("DataLoader rows left out");
    if std::env::var("CYLAOV_REQUIRE_VENV").as_deref() == Ok("1") {
        assert!(dataloader, "{stdout}");
    }
    let mut want = vec!["render", "batch files", "batch webdataset"];
    if dataloader {
        want.push("DataLoader");
    }
    for threads in ["1", "2"] {
        let got: Vec<&str> = rows
            .iter()
            .filter(|r| &r[0] == threads)
            .map(|r| &r[1])
            .collect();
        assert_eq!(got, want, "{text}");
    }
    for r in &rows {
        assert_eq!(&r[2], "40", "every view made: {text}");
        let seconds: f64 = r[3].parse().unwrap();
        let vps: f64 = r[4].parse().unwrap();
        assert!(
            seconds > 0.0 && (vps * seconds - 40.0).abs() < 1e-6,
            "{text}"
        );
        let eff: f64 = r[5].parse().unwrap();
        if &r[0] == "1" {
            assert_eq!(eff, 1.0, "{text}");
        } else {
            let one: f64 = rows
                .iter()
                .find(|o| &o[0] == "1" && o[1] == r[1])
                .map(|o| o[4].parse().unwrap())
                .unwrap();
            assert!((eff - vps / (2.0 * one)).abs() < 1e-9, "{text}");
        }
    }
    assert!(stdout.contains("webdataset/files"), "{stdout}");
}
