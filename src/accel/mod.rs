//! Acceleration: which cylinders a ray can hit. [`tiles`] serves primary rays (screen tiles
//! of projected bounds); [`bvh`] serves rays of any direction. Neither does IO.

pub mod bvh;
pub mod tiles;
