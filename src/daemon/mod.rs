//! The daemon: one rotation buffered per sensor, a live fit, corrected
//! readings published to subscribers, and the calibration kept on disk.
//!
//! A sample passes, in order: a source ([`crate::source`]) -> the sensor's
//! [`rotation`] buffer -> the fit and its [`acceptance`] check -> the
//! corrector -> [`publish`] (stdout, TCP, Unix socket, the [`http`] live
//! page) and [`state`] (written by the [`state_writer`] thread, off the
//! readings' path).

pub mod acceptance;
mod beside;
pub mod config;
pub mod lifecycle;
pub mod messages;
pub mod north;
pub mod notify;
pub mod output_kinds;
pub mod plane;
pub mod progress;
pub mod publish;
pub mod reload;
pub mod rotation;
pub mod run;
pub mod sensor;
pub mod sensor3;
pub mod source_kinds;
pub mod sphere_limits;
pub mod stale;
pub mod state;
pub mod state_writer;

// The publisher's transports, also at the paths they had before they moved
// under [`publish`].
pub use publish::http;

// The calibration values live in the model ([`crate::model::calibration`]),
// which the state file, `check` and the corrector share; also here, at the
// paths the daemon's users have always named.
pub use crate::model::calibration::{Calibration, Ellipsoid3Params, Terms, apply};
