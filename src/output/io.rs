//! One import path for the four concerns of writing output: [`super::atomic`] (files never
//! half-written), [`super::targets`] (output-target checks), [`super::camera_files`] (camera
//! and Open3D JSON, record encoding) and [`super::console`] (say/warn).

pub use super::atomic::*;
pub use super::camera_files::*;
pub use super::console::*;
pub use super::targets::*;
