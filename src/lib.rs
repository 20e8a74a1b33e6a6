//! cylaov: cylinder scenes to per-pixel AOVs, verified against Mitsuba 3.
//!
//! Data flows one way: scene JSON → [`scene::Scene`] (validated) → [`camera::Camera`] rays →
//! [`bvh::Bvh`] → [`geometry::cylinder`] kernel → AOV buffers ([`aov::AovImage`]) → EXR/PNG.
//!
//! Code map:
//! - [`scene`]: the file schema (serde), defaults, validation with field-naming errors.
//! - [`camera`]: Mitsuba's look-at pinhole camera, pixel rays in f64, K and pose matrices.
//! - [`geometry`]: the f32/f64 abstraction and the literal and stable cylinder kernels.
//! - [`bvh`]: binned-SAH hierarchy over cylinder boxes, f32 boxes relative to the camera.
//! - [`render`]: parallel bands of rows, nearest hit, only the requested AOVs.
//! - [`aov`]: the in-memory AOV image and its EXR reading and writing.
//! - [`preview`]: PNG previews and 16-bit depth PNGs.
//! - [`plot`]: the 3×5 pixel font, clipped primitives and log/lin axis panels of the figures.
//! - [`io`]: atomic file writes and the camera metadata JSON.
//! - [`mitsuba`]: the Mitsuba 3 XML of a scene (the reference renderer's input).
//! - [`compare`]: per-pixel comparison of two AOV images (SPEC §7), heatmaps.
//! - [`oracle`]: double-double ray–cylinder reference answer, κ and tangency band (tests/stress).
//! - [`stress`]: the stress families and the kernel-vs-oracle measurements of `cylaov stress`.
//!
//! **Architecture invariants**: geometry and render never do IO; serde types live in
//! `scene`, `io` and `compare` (its report) only; a render is a pure function of
//! scene + options (no global state); `mitsuba` knows Mitsuba's XML, not how to run it.

pub mod aov;
pub mod bench;
pub mod bvh;
pub mod camera;
pub mod commands;
pub mod compare;
pub mod geometry;
pub mod io;
pub mod mitsuba;
pub mod oracle;
pub mod plot;
pub mod preview;
pub mod render;
pub mod rng;
pub mod scene;
pub mod stress;
pub mod tiles;
