//! The repository stands alone: no tracked file points a reader at a document they do not
//! have (the team's specification, its sections, or an issue number). What a user or a
//! maintainer needs is stated in the README or in the rustdoc of the module that implements
//! it; `cargo doc` is the reference manual.

use std::path::Path;
use std::process::Command;

/// The three citation patterns, matched case-sensitively as `git grep -E` would: the
/// spec's name in capitals, a section sign with an optional space and a digit, and
/// `[Ii]ssues? #?` followed by a digit. Built from pieces so that this file does not match
/// itself.
fn citations(line: &str) -> Vec<&'static str> {
    let mut found = Vec::new();
    if line.contains(concat!("SP", "EC")) {
        found.push("the spec");
    }
    let chars: Vec<char> = line.chars().collect();
    let digit_at = |k: usize| chars.get(k).is_some_and(|c| c.is_ascii_digit());
    for (k, &c) in chars.iter().enumerate() {
        if c == '\u{a7}' && (digit_at(k + 1) || (chars.get(k + 1) == Some(&' ') && digit_at(k + 2)))
        {
            found.push("a section sign and number");
        }
    }
    for (k, _) in line.match_indices("ssue") {
        let before = line[..k].chars().last();
        if !matches!(before, Some('I' | 'i')) {
            continue;
        }
        let rest = &line[k + "ssue".len()..];
        let rest = rest.strip_prefix('s').unwrap_or(rest);
        let rest = rest.strip_prefix(' ').unwrap_or(rest);
        let rest = rest.strip_prefix('#').unwrap_or(rest);
        if rest.starts_with(|c: char| c.is_ascii_digit()) {
            found.push("an issue number");
        }
    }
    found
}

#[test]
fn the_citation_patterns_match_what_they_should() {
    let spec = concat!("SP", "EC");
    assert_eq!(citations(&format!("see {spec} for it")), ["the spec"]);
    assert_eq!(citations("as in \u{a7}7"), ["a section sign and number"]);
    assert_eq!(citations("as in \u{a7} 3"), ["a section sign and number"]);
    assert_eq!(
        citations(concat!("fixes iss", "ue 13")),
        ["an issue number"]
    );
    assert_eq!(citations(concat!("Iss", "ues #4")), ["an issue number"]);
    assert!(citations("a specification, issue tracker, \u{a7} alone, issues").is_empty());
}

#[test]
fn no_tracked_file_cites_the_spec_or_an_issue() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = Command::new("git")
        .args(["ls-files", "-z"])
        .current_dir(root)
        .output();
    let files = match out {
        Ok(o) if o.status.success() => o.stdout,
        // A source tarball without git: nothing is tracked, nothing to check. Under CI the
        // clone always has git, so the check cannot pass silently there.
        _ => {
            assert!(
                std::env::var("CI").as_deref() != Ok("true"),
                "git ls-files failed under CI"
            );
            eprintln!("SKIPPED: no git repository");
            return;
        }
    };
    let mut bad = Vec::new();
    let mut checked = 0;
    for name in files.split(|&b| b == 0).filter(|n| !n.is_empty()) {
        let name = String::from_utf8_lossy(name).into_owned();
        let Ok(bytes) = std::fs::read(root.join(&name)) else {
            continue; // deleted in the work tree, not yet committed
        };
        // Binary files (EXR, PNG) are not read by people.
        let Ok(text) = std::str::from_utf8(&bytes) else {
            continue;
        };
        if text.contains('\0') {
            continue;
        }
        checked += 1;
        for (k, line) in text.lines().enumerate() {
            for what in citations(line) {
                bad.push(format!("{name}:{}: cites {what}: {}", k + 1, line.trim()));
            }
        }
    }
    assert!(
        checked > 50,
        "only {checked} text files tracked: wrong folder?"
    );
    assert!(
        bad.is_empty(),
        "{} citation(s):\n{}",
        bad.len(),
        bad.join("\n")
    );
}
