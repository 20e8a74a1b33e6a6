//! How output reaches the disk, whatever its format: files staged under temporary names
//! and committed together, never half-written ([`atomic`]); staged files removed on a
//! signal ([`signals`]); files opened in place without following links ([`files`]); every
//! output target checked before any work starts ([`targets`]).

pub mod atomic;
pub mod files;
pub mod signals;
pub mod targets;
