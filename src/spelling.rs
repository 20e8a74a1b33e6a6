//! How a message names an option. The library names each option by its neutral key
//! (`shard_size`, `depth_scale`) through [`opt`], and the front end in use says, once at
//! start-up ([`set`]), how its users write one: the command line as a flag
//! (`--shard-size`), Python as the keyword it is (`shard_size`, the default). So a Python
//! user who passed `shard_size=0` reads about `shard_size`, and the same check run from
//! the command line names `--shard-size`. **The library never names a flag**: a test in
//! `tests/layers.rs` fails on a `--flag` in a library message.

use std::sync::OnceLock;

static SPELLING: OnceLock<fn(&str) -> String> = OnceLock::new();

/// Spell options with `spell` from now on: called once by a front end before any work
/// (a second call is ignored: a process has one front end).
pub fn set(spell: fn(&str) -> String) {
    let _ = SPELLING.set(spell);
}

/// The option `key` (snake_case, as the library's option structs name their fields) as
/// the front end in use spells it.
pub fn opt(key: &str) -> String {
    match SPELLING.get() {
        Some(spell) => spell(key),
        None => key.to_string(),
    }
}

/// The command line's spelling: `shard_size` → `--shard-size`.
pub fn as_flag(key: &str) -> String {
    format!("--{}", key.replace('_', "-"))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Keys read as keywords until a front end says otherwise; flags are kebab-case.
    #[test]
    fn keys_and_flags() {
        assert_eq!(as_flag("views_per_scene"), "--views-per-scene");
        assert_eq!(as_flag("out"), "--out");
        // The unit-test process has no front end.
        assert_eq!(opt("shard_size"), "shard_size");
    }
}
