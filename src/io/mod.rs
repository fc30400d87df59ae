//! Files in and out: CSV recordings and atomic replacement.

pub mod atomic;
pub mod csv;
