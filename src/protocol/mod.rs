//! Wire protocols, sans-IO: bytes in, frames and counters out. Nothing here
//! opens a port, reads a clock or sleeps.

pub mod chips;
pub mod falcon;
pub mod usb_iss;
