//! The daemon: one rotation buffered per sensor, a live fit, corrected
//! readings published to subscribers, and the calibration kept on disk.
//!
//! A sample passes, in order: a source ([`crate::source`]) -> the sensor's
//! [`rotation`] buffer -> the fit and its [`acceptance`] check -> the
//! corrector -> [`publish`] (stdout, TCP, Unix socket) and [`state`].

pub mod acceptance;
pub mod config;
pub mod messages;
pub mod notify;
pub mod publish;
pub mod rotation;
pub mod run;
pub mod sensor;
pub mod state;

use serde::{Deserialize, Serialize};

use crate::model::paper::PaperCalibration;

/// An accepted calibration of one sensor: what is published in a
/// `CALIBRATION` message, what is stored, and what corrects readings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// The sensor's name, from the configuration.
    pub sensor: String,
    /// Increases by one with every accepted calibration of the sensor,
    /// across restarts; readings name the id that corrected them.
    pub id: u64,
    /// The model as effect names joined by `+` (the paper's: `offset+scale`).
    pub model: String,
    /// The model's parameters.
    pub params: PaperCalibration,
    /// Root mean square of |calibrated|/r - 1 over the fitted samples.
    pub rms: f64,
    /// Heading coverage of the rotation that was fitted, in degrees.
    pub coverage_deg: f64,
    /// Samples fitted.
    pub n: usize,
    /// When it was accepted, in seconds since the Unix epoch.
    pub time: f64,
}
