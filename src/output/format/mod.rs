//! The bytes of each output file: the AOV EXR ([`exr`]), the 16-bit depth PNG and the hit
//! mask ([`depth_png`]), PNG previews ([`preview`]) drawn with the figures' pixel font and
//! axis panels ([`plot`]), hit points as PLY ([`ply`]), the stored zip of `.npy` members
//! ([`npz`]), deterministic ustar members of tar shards ([`tar`]), the camera and Open3D
//! JSON with the record encoding ([`camera_files`]) and the scene as Mitsuba 3 XML
//! ([`mitsuba`]). A format knows bytes, not files: it writes into a writer it is given
//! (the streaming EXR writer into an open file, at offsets) and never imports
//! [`super::store`]; staging its bytes as a file ([`super::pipeline::files`]) and deciding
//! which files a command writes are [`super::pipeline`]'s.

pub mod camera_files;
pub mod depth_png;
pub mod exr;
pub mod mitsuba;
pub mod npz;
pub mod plot;
pub mod ply;
pub mod preview;
pub mod tar;
