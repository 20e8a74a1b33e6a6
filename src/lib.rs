//! cylaov: cylinder scenes to per-pixel AOVs, verified against Mitsuba 3.
//!
//! Data flows one way: scene JSON → [`scene::Scene`] (validated) → [`camera::Camera`] rays →
//! [`tiles::Tiles`] (or [`bvh::Bvh`]) → [`geometry::cylinder`] kernel → AOV buffers
//! ([`aov::AovImage`]) → EXR/PNG.
//!
//! Code map:
//! - [`scene`]: the file schema (serde), defaults, validation with field-naming errors.
//! - [`camera`]: Mitsuba's look-at pinhole camera, pixel rays in f64, K and pose matrices.
//! - [`geometry`]: the f32/f64 abstraction and the literal and stable cylinder kernels.
//! - [`tiles`]: screen tiles of projected cylinder bounds, the primary-ray fast path.
//! - [`bvh`]: binned-SAH hierarchy over cylinder boxes, for rays of any direction.
//! - [`render`]: parallel bands of tiles, nearest hit, only the requested AOVs.
//! - [`aov`]: the in-memory AOV image and its EXR reading and writing.
//! - [`preview`]: PNG previews and 16-bit depth PNGs.
//! - [`plot`]: the 3×5 pixel font, clipped primitives and log/lin axis panels of the figures.
//! - [`io`]: atomic file writes and the camera metadata JSON.
//! - [`mitsuba`]: the Mitsuba 3 XML of a scene (the reference renderer's input).
//! - [`compare`]: per-pixel comparison of two AOV images (SPEC §7), heatmaps.
//! - [`oracle`]: double-double ray–cylinder reference answer, κ and tangency band.
//! - [`stress`]: the stress families and the kernel-vs-oracle measurements of `cylaov stress`.
//! - [`bench`]: the time-vs-error benchmark (and Mitsuba's times on the same scenes).
//! - [`generate`]: seeded procedural scenes for datasets.
//! - [`batch`]: view lists, shards, resumable kill-safe batch rendering, `transforms.json`.
//! - [`verify`]: `batch --verify-fraction`, re-rendering views with Mitsuba.
//! - [`rng`]: SplitMix64, written out so generated data never changes under us.
//! - [`commands`]: the IO around each subcommand; `main.rs` only parses arguments.
//!
//! **Architecture invariants**: geometry, tiles, bvh and render never do IO; serde types live
//! in `scene`, `io`, `compare` (its report), `bench` and `batch` only; a render is a pure
//! function of scene + options (no global state); `mitsuba` knows Mitsuba's XML, not how to
//! run it.

pub mod aov;
pub mod batch;
pub mod bench;
pub mod bvh;
pub mod camera;
pub mod commands;
pub mod compare;
pub mod generate;
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
pub mod verify;
