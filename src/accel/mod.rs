//! Acceleration: which cylinders a ray can hit. [`tiles`] serves primary rays (screen tiles
//! of projected bounds); [`bvh`] serves rays of any direction, and crowded primary rays a
//! tile at a time ([`bvh::ConeWalk`]: the tile's view cone, nearest first, with occlusion
//! culling). Neither does IO.

pub mod bvh;
pub mod tiles;
