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
//! - [`io`]: atomic file writes and the camera metadata JSON.
//! - [`generate`]: seeded procedural scenes (SplitMix64 written out) for datasets.
//! - [`batch`]: view lists, shards, resumable kill-safe batch rendering, `transforms.json`.
//! - `verify` (feature `mitsuba-verify`): `batch --verify-fraction` against Mitsuba.
//!
//! **Architecture invariants**: geometry and render never do IO; serde types live in
//! `scene`, `io` and the dataset file formats of `generate` and `batch` only; a render is a pure function of scene + options (no global state).

pub mod aov;
pub mod batch;
pub mod bvh;
pub mod camera;
pub mod commands;
pub mod generate;
pub mod geometry;
pub mod io;
pub mod preview;
pub mod render;
pub mod scene;
#[cfg(feature = "mitsuba-verify")]
pub mod verify;
