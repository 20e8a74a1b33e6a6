//! The work behind each CLI subcommand: IO orchestration around the pure library.
//! `main.rs` only parses arguments and calls these.

pub mod batch;
pub mod bench;
pub mod cameras;
pub mod compare;
pub mod export_mitsuba;
pub mod generate;
pub mod import;
pub mod render;
pub mod stress;
pub mod verify;
