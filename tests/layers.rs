//! The layers stay apart: nothing a render runs through imports `output` (files and
//! pictures), `output` never reaches into `accel` (how rays find cylinders), and `verify`
//! (the check against Mitsuba) never calls up into `commands` (the CLI). A lower layer that imports a higher one makes every change to the
//! higher one a change to the lower one's tests. The Python bindings (`python/src`, their
//! own crate) are held to the library's rules on clap and flags, and are the only place
//! that names PyO3.

use std::path::{Path, PathBuf};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");

/// Every `.rs` file under `dir`, recursively.
fn sources(dir: &Path) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut todo = vec![dir.to_path_buf()];
    while let Some(d) = todo.pop() {
        for e in std::fs::read_dir(&d).unwrap_or_else(|e| panic!("{}: {e}", d.display())) {
            let p = e.unwrap().path();
            if p.is_dir() {
                todo.push(p);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    out.sort();
    out
}

/// The sources the front-end rules read: the root crate's `src/` and the Python crate's
/// `python/src/`, each with its path from the repository root.
fn crate_sources() -> Vec<(PathBuf, String)> {
    let mut out = Vec::new();
    for dir in ["src", "python/src"] {
        let base = Path::new(ROOT).join(dir);
        for f in sources(&base) {
            let rel = Path::new(dir).join(f.strip_prefix(&base).unwrap());
            out.push((f, rel.display().to_string()));
        }
    }
    out
}

/// The lines of the sources under `src/<layer>` (and `src/<layer>.rs`) that name
/// `crate::<forbidden>`, as `path:line: text`.
fn uses(layer: &str, forbidden: &str) -> Vec<String> {
    let src = Path::new(ROOT).join("src");
    let dir = src.join(layer);
    let mut files = if dir.is_dir() {
        sources(&dir)
    } else {
        Vec::new()
    };
    let flat = src.join(format!("{layer}.rs"));
    if flat.is_file() {
        files.push(flat);
    }
    assert!(!files.is_empty(), "no sources under src/{layer}");
    let needle = format!("crate::{forbidden}");
    let mut hits = Vec::new();
    for f in files {
        let text = std::fs::read_to_string(&f).unwrap();
        for (k, l) in text.lines().enumerate() {
            if l.contains(&needle) {
                let rel = f.strip_prefix(ROOT).unwrap_or(&f).display().to_string();
                hits.push(format!("{rel}:{}: {}", k + 1, l.trim()));
            }
        }
    }
    hits
}

/// **The trace knows no file**: the layers a render runs through (`scene`, `geometry`,
/// `accel`, `image`, `render`, `scan`) never import `output`. `render` fills an
/// image (`src/image.rs`) and hands bands to its caller's sink; `output` writes them.
#[test]
fn the_trace_never_imports_output() {
    let mut hits = Vec::new();
    for layer in ["scene", "geometry", "accel", "image", "render", "scan"] {
        hits.extend(uses(layer, "output"));
    }
    assert!(
        hits.is_empty(),
        "a layer below output imports it:\n{}",
        hits.join("\n")
    );
    // The probe sees what it looks for: output itself names the image model.
    assert!(!uses("output", "image").is_empty());
}

#[test]
fn output_never_imports_accel() {
    let hits = uses("output", "accel");
    assert!(
        hits.is_empty(),
        "output reaches into accel:\n{}",
        hits.join("\n")
    );
}

#[test]
fn verify_never_imports_commands() {
    let hits = uses("verify", "commands");
    assert!(
        hits.is_empty(),
        "verify calls up into commands:\n{}",
        hits.join("\n")
    );
}

/// The scan finds what it looks for: the CLI's own sources name `crate::` paths of the
/// library (`main.rs` is outside `src/commands`, so `commands` itself is the probe).
#[test]
fn the_scan_sees_imports() {
    assert!(!uses("commands", "output").is_empty());
    assert!(!uses("render", "accel").is_empty());
}

/// The library knows no command line: `clap` is named only by the binary (`src/main.rs`
/// and the `src/cli/` tree it declares), not by the library nor the Python crate. The
/// library's option enums list their names through `cylaov::choice`, which both front
/// ends read.
#[test]
fn only_the_binary_names_clap() {
    let mut hits = Vec::new();
    for (f, rel) in crate_sources() {
        if rel == "src/main.rs" || Path::new(&rel).starts_with("src/cli") {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        for (k, l) in text.lines().enumerate() {
            if l.contains("clap::") || l.contains("use clap") || l.contains("#[value(") {
                hits.push(format!("{rel}:{}: {}", k + 1, l.trim()));
            }
        }
    }
    assert!(
        hits.is_empty(),
        "the library names clap:\n{}",
        hits.join("\n")
    );
    // The probe sees what it looks for.
    let main = std::fs::read_to_string(Path::new(ROOT).join("src/main.rs")).unwrap();
    assert!(main.contains("use clap"));
}

/// Only the Python crate names PyO3 and numpy's bindings: the library under `src/` has no
/// Python in it, so it builds and tests without one.
#[test]
fn only_the_python_crate_names_pyo3() {
    let mut hits = Vec::new();
    let mut seen = false;
    for (f, rel) in crate_sources() {
        let python = rel.starts_with("python/");
        let text = std::fs::read_to_string(&f).unwrap();
        for (k, l) in text.lines().enumerate() {
            let names = l.contains("pyo3") || l.contains("numpy::") || l.contains("#[py");
            seen |= python && names;
            if names && !python {
                hits.push(format!("{rel}:{}: {}", k + 1, l.trim()));
            }
        }
    }
    assert!(
        hits.is_empty(),
        "the library names PyO3:\n{}",
        hits.join("\n")
    );
    // The probe sees what it looks for.
    assert!(seen, "no python/src line names pyo3");
}

/// **The library never names a flag**: its messages name an option through
/// `cylaov::spelling::opt`, so each front end spells it its own way. Outside the command
/// line's front ends (`main.rs`, `cli/`, `commands/`, `bench/`), in the library and in the
/// Python crate, no line before a file's tests holds a `--word`, except the few that quote
/// another program's or a command's own invocation.
#[test]
fn the_library_never_names_a_flag() {
    // (file, text on the line): an invocation quoted as a whole, not an option named.
    let quoted = [
        ("dataset/names.rs", "out(\""),
        ("dataset/batch/transforms.rs", "ns-train ... --data"),
        ("verify/repro.rs", "`cylaov verify --report`"),
        ("verify/reference.rs", "cmd.arg(\"--aov\")"),
    ];
    let mut hits = Vec::new();
    for (f, path) in crate_sources() {
        // Under `src/`, as `quoted` names them; the Python crate's files have no quotes.
        let rel = Path::new(&path)
            .strip_prefix("src")
            .unwrap_or(Path::new(""));
        let front = rel == Path::new("main.rs")
            || rel.starts_with("cli")
            || rel.starts_with("commands")
            || rel.starts_with("bench");
        if front {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        for (k, l) in text.lines().enumerate() {
            if l.contains("#[cfg(test)]") {
                break;
            }
            let code = l.trim_start();
            if code.starts_with("//") {
                continue;
            }
            let flag = code
                .match_indices("--")
                .any(|(i, _)| code[i + 2..].starts_with(|c: char| c.is_ascii_lowercase()));
            let allowed = quoted
                .iter()
                .any(|(file, text)| rel == Path::new(file) && l.contains(text));
            if flag && !allowed {
                hits.push(format!("{path}:{}: {}", k + 1, code));
            }
        }
    }
    assert!(
        hits.is_empty(),
        "library lines name a flag (use crate::spelling::opt):\n{}",
        hits.join("\n")
    );
    // The probe sees what it looks for: the command line's own sources name flags.
    let batch = std::fs::read_to_string(Path::new(ROOT).join("src/cli/batch.rs")).unwrap();
    assert!(batch.contains("\"--shard-size: only with --format webdataset\""));
}

/// The library's modules as `crate::` paths (`["dataset", "batch", "run"]`), each with its
/// file: `src/x.rs` and `src/x/mod.rs` are `x`; `lib.rs`, `main.rs` and the binary's
/// `cli/` are left out.
fn modules() -> Vec<(Vec<String>, PathBuf)> {
    let src = Path::new(ROOT).join("src");
    let mut out = Vec::new();
    for f in sources(&src) {
        let rel = f.strip_prefix(&src).unwrap().with_extension("");
        let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into()).collect();
        if parts.last().is_some_and(|p| p == "mod") {
            parts.pop();
        }
        if parts == ["lib"] || parts == ["main"] || parts[0] == "cli" {
            continue;
        }
        out.push((parts, f));
    }
    out
}

/// The modules `file` (module `me`) imports through `crate::a::b` or `super::a` paths on
/// its code lines before its tests, each resolved to the longest module it names; its own
/// ancestors and descendants left out.
fn imports(me: &[String], file: &Path, known: &[Vec<String>]) -> Vec<Vec<String>> {
    let text = std::fs::read_to_string(file).unwrap();
    // `super` of `a/b.rs` (module a::b) and of `a/b/mod.rs` (module a::b) is `a`.
    let parent: Vec<String> = me[..me.len().saturating_sub(1)].to_vec();
    let mut out = Vec::new();
    for line in text.lines() {
        if line.contains("#[cfg(test)]") {
            break;
        }
        let code = line.trim_start();
        if code.starts_with("//") {
            continue;
        }
        for (root, base) in [("crate::", &[][..]), ("super::", &parent[..])] {
            for (i, _) in code.match_indices(root) {
                let before = code[..i].chars().next_back();
                if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
                    continue;
                }
                let mut path = base.to_vec();
                // Identifiers joined by `::`; the first segment that is more than one (`b;`,
                // `{x, y}`) ends the path.
                for seg in code[i + root.len()..].split("::") {
                    let id: String = seg
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    if id.is_empty() {
                        break;
                    }
                    let whole = id.len() == seg.len();
                    path.push(id);
                    if !whole {
                        break;
                    }
                }
                let target = (1..=path.len())
                    .rev()
                    .map(|n| path[..n].to_vec())
                    .find(|p| known.contains(p));
                if let Some(t) = target
                    && !me.starts_with(&t)
                    && !t.starts_with(me)
                {
                    out.push(t);
                }
            }
        }
    }
    out
}

/// Imports between modules, `a::b -> c::d`, as [`imports`] reads them.
type Edges = std::collections::BTreeMap<String, std::collections::BTreeSet<String>>;

/// A cycle of `edges`, named with its path (`a -> b -> a`), if there is one: a
/// depth-first search for a back edge.
fn cycle(edges: &Edges) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        edges: &Edges,
        path: &mut Vec<String>,
        done: &mut std::collections::BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(k) = path.iter().position(|p| p == n) {
            let mut cycle = path[k..].to_vec();
            cycle.push(n.to_string());
            return Some(cycle);
        }
        if done.contains(n) {
            return None;
        }
        path.push(n.to_string());
        for m in edges.get(n).into_iter().flatten() {
            if let Some(c) = visit(m, edges, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(n.to_string());
        None
    }
    let mut done = Default::default();
    edges
        .keys()
        .find_map(|n| visit(n, edges, &mut Vec::new(), &mut done))
}

/// Every module's imports, each module named by its `crate::` path (`output::store::atomic`),
/// cut to `depth` segments (1: the top-level modules); imports inside one cut module left out.
fn edges_at(depth: usize) -> Edges {
    let mods = modules();
    let known: Vec<Vec<String>> = mods.iter().map(|(m, _)| m.clone()).collect();
    let cut = |m: &[String]| m[..m.len().min(depth)].join("::");
    let mut edges = Edges::new();
    for (me, file) in &mods {
        for t in imports(me, file, &known) {
            let (a, b) = (cut(me), cut(&t));
            if a != b {
                edges.entry(a).or_default().insert(b);
            }
        }
    }
    edges
}

/// **Arrows between modules point down**: the top-level modules of the library
/// (`scene`, `render`, `output`, `dataset`, `verify`, `commands`, …) import each other
/// without a cycle, so each can be read, tested and changed knowing only those below it.
#[test]
fn top_level_modules_import_without_a_cycle() {
    let edges = edges_at(1);
    if let Some(c) = cycle(&edges) {
        panic!("an import cycle between modules: {}", c.join(" -> "));
    }
    // The probe sees what it looks for: render imports geometry and image, and verify
    // sits above render.
    assert!(edges["render"].contains("geometry") && edges["render"].contains("image"));
    assert!(edges["verify"].contains("render"));
    assert!(!edges.get("image").is_some_and(|e| e.contains("render")));
}

/// **No import cycle between files either**: inside a module, too, files import each other
/// one way (a file and its own submodules excepted: `scene::table::npz` reads the table's
/// types, and the table reads `.npz` through it).
#[test]
fn files_import_without_a_cycle() {
    let edges = edges_at(usize::MAX);
    if let Some(c) = cycle(&edges) {
        panic!("an import cycle between files: {}", c.join(" -> "));
    }
    assert!(edges["geometry::kernel"].contains("geometry::cylinder"));
    assert!(edges["dataset::batch::write"].contains("dataset::batch::resume"));
}

/// **`output` in three layers, arrows down**: `pipeline` (what a command writes) over
/// `format` (the bytes of each file) over `store` (how files reach the disk); **only
/// `pipeline` calls `render`**, and **a format knows bytes, not files**: it never
/// imports the store (`pipeline::files` stages its bytes as a file).
#[test]
fn output_is_pipeline_over_format_over_store() {
    let edges = edges_at(3);
    let from = |layer: &str| -> Vec<(String, String)> {
        edges
            .iter()
            .filter(|(a, _)| a.starts_with(&format!("output::{layer}::")))
            .flat_map(|(a, bs)| bs.iter().map(move |b| (a.clone(), b.clone())))
            .collect()
    };
    let up = |layer: &str, above: &[&str]| -> Vec<String> {
        from(layer)
            .into_iter()
            .filter(|(_, b)| above.iter().any(|x| b.starts_with(x)))
            .map(|(a, b)| format!("{a} -> {b}"))
            .collect()
    };
    assert_eq!(
        up("store", &["output::format", "output::pipeline", "render"]),
        Vec::<String>::new()
    );
    assert_eq!(
        up("format", &["output::pipeline", "output::store", "render"]),
        Vec::<String>::new()
    );
    // The probe sees the layers: the view plan calls render and the EXR format, and
    // `pipeline::files` stages a format's bytes in the store.
    let pipeline = from("pipeline");
    assert!(
        pipeline
            .iter()
            .any(|(a, b)| a == "output::pipeline::view" && b == "render")
    );
    assert!(pipeline.iter().any(|(_, b)| b == "output::format::exr"));
    assert!(
        pipeline
            .iter()
            .any(|(a, b)| a == "output::pipeline::files" && b == "output::store::atomic")
    );
}

/// **One batch driver**: in `dataset/batch`, only `driver.rs` reads a view's scene to
/// render it, checks a view against the reference and walks the views on the pool
/// (through `in_order.rs`, which is generic over what it makes and takes); the files
/// format (`run.rs`) and the tar shards (`shards.rs`) are its containers.
#[test]
fn both_batch_formats_run_on_one_driver() {
    let dir = Path::new(ROOT).join("src/dataset/batch");
    let mut found = Vec::new();
    for f in sources(&dir) {
        let rel = f.strip_prefix(&dir).unwrap().display().to_string();
        let text = std::fs::read_to_string(&f).unwrap();
        for (n, line) in text.lines().enumerate() {
            let code = line.trim_start();
            if code.starts_with("//")
                || code.starts_with("pub fn")
                || code.starts_with("pub(super) fn")
            {
                continue;
            }
            for call in ["view_scene(", "check_view(", "in_order(", "lock_shard("] {
                if code.contains(call) {
                    found.push(format!("{rel}:{}: {call}", n + 1));
                }
            }
        }
    }
    let outside: Vec<&String> = found
        .iter()
        .filter(|h| !h.starts_with("driver.rs:"))
        .filter(|h| !h.starts_with("in_order.rs:") || !h.ends_with("in_order("))
        .filter(|h| !h.starts_with("run.rs:") || !h.ends_with("lock_shard("))
        .collect();
    assert!(outside.is_empty(), "outside the driver:\n{outside:#?}");
    for call in ["view_scene(", "check_view(", "in_order(", "lock_shard("] {
        assert!(
            found
                .iter()
                .any(|h| h.starts_with("driver.rs:") && h.ends_with(call)),
            "the probe does not see {call} in driver.rs: {found:#?}"
        );
    }
    for container in ["run.rs", "shards.rs"] {
        let text = std::fs::read_to_string(dir.join(container)).unwrap();
        assert!(text.contains("impl Container for"), "{container}");
    }
}
