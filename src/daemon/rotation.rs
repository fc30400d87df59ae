//! The rotation buffer, at the path it had before it moved to
//! [`crate::model::rotation`] (it is pure: no I/O, no daemon messages).

pub use crate::model::rotation::*;
