//! The daemon: one rotation buffered per sensor, a live fit, corrected
//! readings published to subscribers, and the calibration kept on disk.
//!
//! A sample passes, in order: a source ([`crate::source`]) -> the sensor's
//! [`rotation`] buffer -> the fit and its [`acceptance`] check -> the
//! corrector -> [`publish`] (stdout, TCP, Unix socket) and [`state`]
//! (written by the [`state_writer`] thread, off the readings' path).

pub mod acceptance;
pub mod config;
pub mod messages;
pub mod notify;
pub mod publish;
pub mod rotation;
pub mod run;
pub mod sensor;
pub mod state;
pub mod state_writer;

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
    /// Terms of the effects beyond the paper's (zero when absent, and then
    /// left out of the JSON, so files of the paper's model stay as they were).
    #[serde(default, skip_serializing_if = "Terms::is_none")]
    pub terms: Terms,
}

/// The live-correctable effects' terms: cross-axis coupling `c`, the odd
/// cubic per axis `k` relative to the full scale `cubic_scale`, and the odd
/// cubic about the turn's centre `kc` relative to the turn's radius per
/// axis `turn_radius` (raw units, as `centre`). The centred terms are left
/// out of the JSON when absent, and default to absent, so state files
/// written before them still load and read the same.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Terms {
    #[serde(default)]
    pub c: f64,
    #[serde(default)]
    pub k: [f64; 2],
    #[serde(default)]
    pub cubic_scale: f64,
    #[serde(default, skip_serializing_if = "is_zero_pair")]
    pub kc: [f64; 2],
    #[serde(default, skip_serializing_if = "is_zero_pair")]
    pub centre: [f64; 2],
    #[serde(default, skip_serializing_if = "is_zero_pair")]
    pub turn_radius: [f64; 2],
}

fn is_zero_pair(pair: &[f64; 2]) -> bool {
    *pair == [0.0; 2]
}

impl Terms {
    pub fn is_none(&self) -> bool {
        *self == Terms::default()
    }
}

impl Calibration {
    /// The corrected reading of a raw sample: the cubic terms removed (about
    /// the sensor's zero and about the turn's centre), then the paper's
    /// gains and offsets with the cross-axis coupling.
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        let t = &self.terms;
        let (mut x2, mut y2) = if t.cubic_scale > 0.0 {
            let s2 = t.cubic_scale * t.cubic_scale;
            (x + t.k[0] * x * x * x / s2, y + t.k[1] * y * y * y / s2)
        } else {
            (x, y)
        };
        if t.turn_radius.iter().all(|s| *s > 0.0) {
            let (vx, vy) = (x - t.centre[0], y - t.centre[1]);
            x2 += t.kc[0] * vx * vx * vx / (t.turn_radius[0] * t.turn_radius[0]);
            y2 += t.kc[1] * vy * vy * vy / (t.turn_radius[1] * t.turn_radius[1]);
        }
        let p = &self.params;
        (p.a * x2 + p.b + t.c * (y2 + p.d), y2 + p.d)
    }
}
