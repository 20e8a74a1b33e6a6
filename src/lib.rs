//! cylaov: cylinder scenes to per-pixel AOVs, verified against Mitsuba 3.
//!
//! # Data flow
//!
//! One way, one stage per folder:
//!
//! ```text
//! scene JSON ─parse, validate─▶ scene::Scene ─accelerate─▶ accel::{Tiles, Bvh}
//!            ─trace (geometry kernels)─▶ output::aov::AovImage ─write─▶ EXR, PNG, JSON
//! ```
//!
//! A render ([`render::render`]) is a pure function of scene + options: no global state, no
//! IO. Everything that reads or writes files sits at the two ends (`scene` reads, `output`
//! writes) or in [`commands`].
//!
//! # Code map
//!
//! Product, in pipeline order:
//! - [`scene`]: the scene file schema (serde), defaults, validation with field-naming errors;
//!   [`scene::camera`]: Mitsuba's look-at pinhole camera, pixel rays in f64, K and pose matrices.
//! - [`geometry`]: the f32/f64 abstraction and the literal and stable ray–cylinder kernels,
//!   scalar and in packets of eight lanes.
//! - [`accel`]: [`accel::tiles`], screen tiles of projected cylinder bounds (the primary-ray
//!   fast path), and [`accel::bvh`], a binned-SAH hierarchy for rays of any direction.
//! - [`render`]: parallel bands of tiles, nearest hit, only the requested AOVs.
//! - [`output`]: [`output::aov`] (the in-memory AOV image, its EXR reading and writing),
//!   [`output::preview`] (PNG previews, 16-bit depth PNGs), [`output::plot`] (the pixel font
//!   and axis panels of every figure), [`output::io`] (atomic writes, the camera metadata
//!   JSON), [`output::mitsuba`] (the scene as Mitsuba 3 XML).
//!
//! Checking tools:
//! - [`verify`]: [`verify::compare`] (the per-pixel comparison rule, heatmaps),
//!   [`verify::reference`](mod@verify::reference) (a view rendered by Mitsuba from the pinned venv and compared),
//!   [`verify::oracle`] (double-double reference answer, κ and tangency band),
//!   [`verify::stress`] (the hard ray families of `cylaov stress`).
//! - [`bench`](mod@bench): run time against error per kernel, AOV set and cylinder count, Mitsuba's
//!   times on the same scenes.
//!
//! Datasets:
//! - [`dataset`]: [`dataset::generate`] (seeded procedural scenes) and [`dataset::batch`]
//!   (view lists, shards, resumable kill-safe rendering, `transforms.json`).
//! - [`rng`]: SplitMix64, written out so generated data never changes under us.
//!
//! Around them: [`commands`], the IO of each subcommand; `main.rs` only parses arguments.
//!
//! **Invariants**: `geometry`, `accel` and `render` never do IO; a render is a pure function
//! of scene + options; `output::mitsuba` knows Mitsuba's XML, not how to run it
//! (`verify::reference` does).

pub mod accel;
pub mod bench;
pub mod commands;
pub mod dataset;
pub mod geometry;
pub mod output;
pub mod render;
pub mod rng;
pub mod scene;
pub mod verify;
