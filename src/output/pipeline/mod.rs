//! What a command writes: one view's files as a plan executed into a sink ([`view`]: the
//! EXR, PNGs, PLY and camera files of `render` and `batch`, or a tar shard's members), and a
//! scan's points as LAS, PLY or NPZ ([`scan_files`]); the memory a view holds while it is
//! rendered and written ([`memory`]); a format's bytes staged and committed as a file
//! ([`files`]). The one layer that calls both `render` and the formats, and the formats
//! and the store.

pub mod files;
pub mod memory;
pub mod scan_files;
pub mod view;
