//! Output files: the AOV EXR, PNG previews and figures, the Mitsuba 3 XML export, and one
//! view's files written as one plan (`view`); `.npy` arrays (`npy`) and ustar archives
//! (`tar`) for tar shards; hit points as PLY point clouds (`ply`); a scan's points as LAS, PLY or `.npz` (`scan_files`, `npz`); files never half-written (`atomic`), output targets checked
//! before any work (`targets`), camera metadata and record encoding (`camera_files`),
//! console output (`console`), files opened in place without following links (`files`) and
//! the clean-up of staged files on a signal (`signals`). The last stage of the pipeline;
//! nothing here traces rays.

pub mod aov;
pub mod atomic;
pub mod camera_files;
pub mod console;
pub mod depth_png;
pub mod files;
pub mod mitsuba;
pub mod npz;
pub mod plot;
pub mod ply;
pub mod preview;
pub mod scan_files;
pub mod signals;
pub mod tar;
pub mod targets;
pub mod view;
