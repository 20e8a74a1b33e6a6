//! Acceleration: which cylinders a ray can hit. [`tiles`] serves primary rays (screen tiles
//! of projected bounds); [`bvh`] serves crowded primary rays a tile at a time
//! ([`bvh::ConeWalk`]: the tile's view cone, nearest first, with occlusion culling), and
//! [`wide_bvh`], its tree collapsed to eight-wide nodes, serves rays of any direction one at
//! a time. None does IO.

pub mod bvh;
pub mod tiles;
pub mod wide_bvh;
