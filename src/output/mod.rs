//! Output, the last stage of the pipeline: nothing here traces rays. Three layers, arrows
//! pointing down:
//!
//! - [`pipeline`]: one view's files as a plan executed into a sink (`render` and `batch`
//!   write through it), a scan's points as files, and a format's bytes staged as a file
//!   (`files`): the one layer that calls both `render` and the formats, and the formats
//!   and the store.
//! - [`format`](mod@format): what the bytes of each file are: the AOV EXR and its streaming writer,
//!   PNG depth and previews with the figures' pixel font, PLY, `.npz`, ustar members, the
//!   camera and Open3D JSON, Mitsuba 3 XML.
//! - [`store`]: how files reach the disk: staged under temporary names and committed
//!   together (`atomic`), cleaned up on a signal (`signals`), opened without following
//!   links (`files`), and output targets checked before any work (`targets`).
//!
//! [`console`] prints what every layer says, surviving a closed pipe.

pub mod console;
pub mod format;
pub mod pipeline;
pub mod store;
