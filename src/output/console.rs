//! Console output that survives a closed pipe and never panics.

use std::io::{self, Write};

static STDOUT_CLOSED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Print `text` and a newline on stdout. A closed pipe (the reader left, as `| head` does)
/// is not an error: this and every later line are dropped quietly, and the command finishes
/// with its own exit status, like other Unix tools. Any other failure (`> /dev/full`) is
/// returned, to be reported as an error. `println!` would panic in both cases.
pub fn say(text: &str) -> io::Result<()> {
    use std::sync::atomic::Ordering;
    if STDOUT_CLOSED.load(Ordering::Relaxed) {
        return Ok(());
    }
    let mut out = io::stdout().lock();
    match writeln!(out, "{text}").and_then(|()| out.flush()) {
        Err(e) if e.kind() == io::ErrorKind::BrokenPipe => {
            STDOUT_CLOSED.store(true, Ordering::Relaxed);
            Ok(())
        }
        Err(e) => Err(io::Error::new(e.kind(), format!("writing to stdout: {e}"))),
        Ok(()) => Ok(()),
    }
}

/// Print `text` and a newline on stderr; a failure is ignored (there is nowhere left to
/// report it), where `eprintln!` would panic.
pub fn warn(text: &str) {
    let _ = writeln!(io::stderr().lock(), "{text}");
}

/// `count word` with the English plural `-s` unless `count` is one: "1 cylinder",
/// "2 cylinders", "8..32 cylinders".
pub fn count(n: impl std::fmt::Display, word: &str) -> String {
    let n = n.to_string();
    if n == "1" {
        format!("{n} {word}")
    } else {
        format!("{n} {word}s")
    }
}

/// A size as every message prints it: GiB with one decimal, MiB below 1 GiB (one line never
/// mixes "1.9 GiB" with "1995.1 MiB").
pub fn bytes(n: u64) -> String {
    let b = n as f64;
    if n >= 1 << 30 {
        format!("{:.1} GiB", b / (1u64 << 30) as f64)
    } else {
        format!("{:.1} MiB", b / (1u64 << 20) as f64)
    }
}
