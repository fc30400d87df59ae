//! Simulated devices that answer like the real ones: for tests (over real
//! pseudo-terminal pairs) and for trying fieldcal with no hardware. Each is
//! sans-IO (bytes in, bytes out); a test harness owns the pty.

pub mod falcon;
pub mod usb_iss;
