//! Files in and out: CSV recordings, atomic replacement, and the check that
//! an input is a regular file.

pub mod atomic;
pub mod csv;
pub mod regular;
