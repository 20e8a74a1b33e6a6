//! Output files: the AOV EXR, PNG previews and figures, atomic writes, camera metadata and
//! the Mitsuba 3 XML export; `.npy` arrays and ustar archives for tar shards; files opened in place without following links (`files`) and
//! the clean-up of staged files on a signal (`signals`). The last stage of the pipeline; nothing here traces rays.

pub mod aov;
pub mod depth_png;
pub mod files;
pub mod io;
pub mod mitsuba;
pub mod npy;
pub mod plot;
pub mod preview;
pub mod signals;
pub mod tar;
