//! cylaov: cylinder scenes to per-pixel AOVs, verified against Mitsuba 3.
//!
//! # Bird's-eye view
//!
//! A scene (cylinders and cameras) goes in; for each camera, every pixel's ray is traced
//! exactly against the cylinders and the requested AOVs (depth, normal, ids, uv, …) come
//! out as one image, written as EXR, PNG, `.npy` members of tar shards or numpy arrays. The
//! same scene exported as Mitsuba 3 XML, rendered by Mitsuba and judged pixel by pixel with
//! the exact answer as arbiter, is the proof.
//!
//! # Data flow
//!
//! One way, one stage per folder:
//!
//! ```text
//! scene JSON ─parse, validate─▶ scene::Scene ─accelerate─▶ accel::{Tiles, Bvh, WideBvh}
//!            ─trace (geometry kernels)─▶ image::AovImage ─write (output)─▶ EXR, PNG, JSON, tar
//! ```
//!
//! A render ([`render::render`]) is a pure function of scene + options: no global state, no
//! IO. Everything that reads or writes files sits at the two ends (`scene` reads, `output`
//! writes) or in [`commands`].
//!
//! # Entry points
//!
//! - The command line: `src/main.rs` (the command list, exit codes) and `src/cli/<command>.rs`
//!   (each command's arguments), which call [`commands`]`::<command>::run`.
//! - The Python package: the crate in `python/` (`python/src/lib.rs` registers the module),
//!   on this library's public API: [`scene::load`], [`render::render`], [`render::cast`],
//!   [`dataset::batch::shards::write_shards`], [`scan::scan`], [`verify::compare`].
//! - A render: [`render::render`] (the whole image) and [`render::render_bands`] (bands
//!   handed to the caller as they are traced).
//!
//! # Seams
//!
//! - **An AOV** is one variant and one row of [`scene::aov::AOV_TABLE`] (channels, per-AOV
//!   channel names by count, sample type, miss value, meaning, Mitsuba's source, the compare
//!   metric) and its value in `render/planes.rs`'s `fill`, the one place a hit becomes
//!   every AOV; the EXR writers, the per-AOV files, the Python arrays, the tar members and
//!   the README's table follow the row (`uv` was added that way).
//! - **A camera model** is a [`scene::camera::Projection`] variant: a pixel's ray
//!   ([`scene::camera::Camera::pixel_ray`]) and a point's pixel (`project`), its scene-file
//!   fields in `scene/camera/model.rs`.
//! - **A front end** spells options its own way: the library names them through
//!   [`spelling::opt`] and lists each choice's values through [`choice::Choice`].
//!
//! # Code map
//!
//! Product, in pipeline order:
//! - [`scene`]: the scene file schema (serde), defaults, validation with field-naming errors,
//!   one camera or several; [`scene::strict`]: strict JSON reading (objects only, exact
//!   3-vectors, long values cut in messages); [`scene::camera`]: Mitsuba's look-at pinhole
//!   camera, pixel rays in f64, K in both pixel conventions, pose matrices; [`scene::aov`]:
//!   the one AOV table (channels, sample type, miss value, meaning, Mitsuba's source, the
//!   comparison metric) every other layer reads; [`scene::table`]: cylinder tables (tree
//!   QSMs from TreeQSM, SimpleForest, aRchi, plain CSV) read into cylinders, and
//!   [`scene::table::npz`] (the same from NumPy's `.npz`); `scene::parallel`: a big scene
//!   file's cylinder list read on every core (a fast path that falls back to the one-thread
//!   read for every message);
//!   [`scene::framing`]: the camera distance at which a bounding sphere fills the view
//!   (`generate`'s cameras and `import`'s); [`scene::rig`]: orbits and spheres of cameras
//!   around any scene, drawn as `generate` draws them.
//! - [`geometry`]: the f32/f64 abstraction ([`geometry::real`]), the literal and stable
//!   ray–cylinder kernels ([`geometry::cylinder`]), scalar and in packets of eight lanes, and
//!   [`geometry::kernel`], the one type that names a kernel (formulation × precision).
//! - [`accel`]: [`accel::tiles`], screen tiles of projected cylinder bounds (the primary-ray
//!   fast path), [`accel::bvh`], a binned-SAH hierarchy of bounded depth (the tile-by-tile
//!   cone walks with occlusion culling walk it), and [`accel::wide_bvh`], that tree collapsed
//!   to eight-wide nodes for one traversal per ray: a ray tests eight boxes at once (AVX2 or
//!   lane by lane, the same lanes), lanes far to near, four rays in turn, on a bounded stack.
//! - [`render`]: parallel bands of tiles, nearest hit, only the requested AOVs; the whole
//!   image ([`render::render`]) or each band handed on as soon as it is traced
//!   ([`render::render_bands`]: `cylaov render` and `batch` write an uncompressed EXR that
//!   way, during the trace, without holding the image); [`render::strategy`] picks the
//!   acceleration; the tracer, the tile walk and the planes (the AOV buffers being filled)
//!   are its files `tracer.rs`, `walk.rs`, `planes.rs`; [`render::cast`], rays from any origin,
//!   hits reprojected onto their surface with an error bound, and rays continued from them;
//!   [`render::cast::AnyOrigin`], one BVH for rays from any origin (a scan's beams and returns).
//! - [`scan`]: simulated rotating LiDAR: [`scan::sensor`] (beam tables, the `vlp16`,
//!   `hdl32`, `os1-64` presets, sensor JSON with field-naming errors), [`scan::pose`]
//!   (poses, trajectories interpolated by lerp and slerp), and [`scan::scan`], every beam
//!   of one rotation with up to N returns, each continued past the last hit through
//!   [`render::cast::AnyOrigin`] (one BVH walked from any origin), with seeded noise and
//!   dropout.
//! - [`image`]: the AOV image a render fills, one buffer per AOV in numpy's `(H, W)` /
//!   `(H, W, C)` layout, read channel by channel; no file format.
//! - [`output`], three layers, arrows down:
//!   - [`output::pipeline`]: [`output::pipeline::view`] (one view's files as a plan executed
//!     into a sink: `render`, `batch` and the tar shards write through it),
//!     [`output::pipeline::files`] (an EXR or PNG staged and committed as a file, an EXR
//!     read from a path),
//!     [`output::pipeline::memory`] (the memory a view holds at its peak, checked before it
//!     allocates), [`output::pipeline::scan_files`] (a scan's points as LAS, PLY or NPZ);
//!   - [`output::format`]: [`output::format::exr`] (the image's EXR reading and writing,
//!     band by band too ([`output::format::exr::ExrBands`]), self-describing headers, the
//!     per-AOV layout), [`output::format::depth_png`] (the 16-bit depth PNG that fails
//!     rather than drop far pixels, and the hit mask), [`output::format::preview`] (PNG
//!     previews with legends), [`output::format::plot`] (the pixel font and axis panels of
//!     every figure), [`output::format::ply`], [`output::format::npz`] (the stored zip of
//!     `.npy` members), [`output::format::tar`] (deterministic ustar members, and read
//!     back), [`output::format::camera_files`] (the camera and Open3D JSON, record
//!     encoding), [`output::format::mitsuba`] (the scene as Mitsuba 3 XML);
//!   - [`output::store`]: [`output::store::atomic`] (files staged under temporary names and
//!     committed together), [`output::store::signals`] (the clean-up on a signal),
//!     [`output::store::files`] (opening in place without following links),
//!     [`output::store::targets`] (output-target checks before any work);
//!   - and [`output::console`] (console output that survives a closed pipe).
//!
//! Checking tools:
//! - [`verify`]: [`verify::compare`] (the per-pixel rule: identity by cylinder and part,
//!   silhouette and seam mismatches, float32 conditioning bounds; its report and wording;
//!   the heatmap), [`verify::arbiter`] (the exact answer judging each pixel on the camera's
//!   own pixel ray: reference error, candidate error, tie; and the exact answer's image,
//!   the reference of the lens models Mitsuba has no camera for), [`verify::report`] (the
//!   HTML page of `--report`), [`verify::reference`](mod@verify::reference) (the one check
//!   against Mitsuba 3, perspective and orthographic, or against the exact answer alone for
//!   the lens models, behind `cylaov verify`, `batch --verify-fraction` and the reference
//!   tests; the script is compiled in), [`verify::repro`] (for each proven reference error,
//!   a standalone Mitsuba script that casts the one ray at the shapes involved, written by
//!   `--report`), [`verify::oracle`] (double-double reference answer, κ and tangency band),
//!   [`verify::stress`] (the hard ray families of `cylaov stress`).
//! - [`bench`](mod@bench): run time against error per kernel, AOV set, cylinder count and
//!   scene family, with Mitsuba's and Open3D's times on the same scenes ([`bench::Anchors`]),
//!   the two dataset formats side by side (`--batch-formats`), every way of making views
//!   at 1, 2, 4, … threads (`--scaling`), a LiDAR scan's beams a second (`--scan`), and
//!   whole-process load of a dense 100 000-cylinder scene against 1 000 ([`bench::load`]).
//!
//! Datasets:
//! - [`dataset`]: [`dataset::generate`] (seeded procedural scenes, several cameras each if
//!   asked), [`dataset::batch`] (views of (scene, camera), shards and their locks, one
//!   driver both formats run on (locks, resume, memory-bounded windows, verification,
//!   progress), resumable kill-safe rendering, `index.json` and per-scene
//!   `transforms.json`, and
//!   [`dataset::batch::shards`], `--format webdataset`: tar shards, sidecars and
//!   `shards.json`, resumable per tar; [`dataset::batch::samples`], the tars read back a
//!   sample at a time for `cylaov verify`), [`dataset::names`]
//!   (every file name cylaov writes).
//! - [`npy`]: NumPy's `.npy` arrays as bytes, written (tar shards, a scan's NPZ) and read
//!   (tar samples for `verify`, cylinder tables from NPZ), below every layer that uses it.
//! - [`rng`]: SplitMix64, written out so generated data never changes under us.
//! - [`mem`]: the memory check before a command allocates, the fallible reservation of
//!   our large buffers, the process's allocator (a refused allocation is one error line
//!   and exit 1, never an abort), the 2 MiB-page hint for the large buffers of every stage,
//!   and the allocator policy `main.rs` sets so freed memory is reused.
//!
//! Python: the package `cylaov` is the separate crate in `python/`, using this library's public API.
//!
//! Front-end neutral: [`choice`] (each option's named values, with `FromStr`, `Display` and
//! the list both front ends show and check against), [`spelling`] (library messages name an
//! option neutrally, `shard_size`; the binary has it spelled `--shard-size`).
//!
//! Around them: [`commands`], the IO of each subcommand (`render`, `generate`, `batch`,
//! `import`, `scan`, `cameras`, `export-mitsuba`, `compare`, `verify`, `stress`, `bench`,
//! `aovs`), taking plain option structs. The binary is `main.rs` (the command list, exit
//! codes, error reporting) and `src/cli/`, one file a command: its parsed arguments, checked
//! and turned into those structs; no parser type reaches the library.
//!
//! # Invariants
//!
//! Held by `tests/layers.rs` where it says so:
//! - **Arrows between modules point down**: the top-level modules import each other
//!   without a cycle, and so do the files inside each (a file's own submodules excepted)
//!   (layers).
//! - **`output` is `pipeline` over `format` over `store`**, **only `pipeline` calls
//!   `render`**, and **a format knows bytes, not files** (it never imports the store)
//!   (layers).
//! - **One batch driver**: both dataset formats are containers of
//!   `dataset::batch::driver`, the one place that loads, renders, checks and walks a
//!   batch's views (layers).
//! - **The trace knows no file**: `scene`, `geometry`, `accel`, `image`, `render` and `scan`
//!   never import `output` (`render_bands` hands its bands to the caller's sink) (layers).
//! - **A render is a pure function of scene + options**: the same inputs give the same bits
//!   on any thread count and acceleration (`tests/core.rs` compares every channel).
//! - **The library never names a flag**: messages name options through [`spelling::opt`]
//!   (layers); **only the binary names the argument parser** and **only `python/` names
//!   PyO3** (layers).
//! - **`output` never reaches into `accel`**, and **`verify` never calls up into
//!   `commands`** (layers).
//! - `output::format::mitsuba` knows Mitsuba's XML, not how to run it (`verify::reference` does).

#![warn(missing_docs)]

pub mod accel;
pub mod bench;
pub mod choice;
pub mod commands;
pub mod dataset;
pub mod geometry;
pub mod image;
pub mod mem;
pub mod npy;
pub mod output;
pub mod render;
pub mod rng;
pub mod scan;
pub mod scene;
pub mod spelling;
pub mod verify;
