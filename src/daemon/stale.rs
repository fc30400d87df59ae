//! What a later fit that shows a calibration stale does, for both
//! geometries: a `STALE` line on the control lane (logged as a warning)
//! and, unless the new fit replaces the calibration at once, the reason
//! every reading is distrusted ([`Lifecycle::stale`]).

use super::lifecycle::Lifecycle;
use super::messages::{StaleMessage, to_line};
use super::publish::Lane;
use super::sensor::Emitter;
use crate::model::watch::{CLEAN_RMS_FACTOR, Comparison};

/// The words of a geometry's later fit.
#[derive(Debug, Clone, Copy)]
pub struct Later {
    /// "rotation" or "sphere".
    pub what: &'static str,
    /// What the move turns: "the heading", "a reading's direction".
    pub turning: &'static str,
    /// Its noise: "a reading's heading noise", "a reading's noise".
    pub noise: &'static str,
    /// What the distrust says it turns: "the heading", "a reading".
    pub turns: &'static str,
}

pub const ROTATION: Later = Later {
    what: "rotation",
    turning: "the heading",
    noise: "a reading's heading noise",
    turns: "the heading",
};

pub const SPHERE: Later = Later {
    what: "sphere",
    turning: "a reading's direction",
    noise: "a reading's noise",
    turns: "a reading",
};

/// A later fit of `sensor` that showed calibration `id` stale.
pub struct Stale<'a> {
    pub sensor: &'a str,
    pub later: Later,
    pub id: u64,
    pub comparison: &'a Comparison,
    /// The later fit's rms, against the stale calibration's.
    pub refit_rms: f64,
    pub stored_rms: f64,
    /// `on_stale = "replace"`.
    pub replace: bool,
    pub time: f64,
}

impl Stale<'_> {
    /// Whether the later fit is clean: the same sensor's noise, not a fit
    /// that straddled the change (which calibrates nothing).
    pub fn clean(&self) -> bool {
        self.refit_rms <= CLEAN_RMS_FACTOR * self.stored_rms
    }

    /// Publishes the `STALE` line and, unless the later fit replaces the
    /// calibration now (returns true), sets why every reading is distrusted.
    pub fn announce(&self, life: &mut Lifecycle, emit: &mut Emitter<'_>) -> bool {
        let (id, c, what) = (self.id, self.comparison, self.later.what);
        let replaces = self.replace && self.clean();
        let what_now = match (self.replace, replaces) {
            (true, true) => format!("the new fit replaces it as calibration #{}", life.next_id),
            (true, false) => format!(
                "the {what} straddled the change (rms {:.2} % against the calibration's {:.2} %): readings are distrusted while a new {what} is collected to replace it",
                self.refit_rms * 100.0,
                self.stored_rms * 100.0
            ),
            (false, _) => "readings are distrusted until the sensor is recalibrated: find what changed near it (a magnet, a battery, a motor), then send {\"command\":\"recalibrate\"}, or {\"command\":\"rollback\"} if it was a mistake".to_string(),
        };
        let moved = c.moved_text();
        let text = format!(
            "calibration #{id} no longer holds: a later {what} moved {moved} (beyond {:.1} SE), turning {} by up to {:.1}° (limit {:.2}°: 3 σ of {}); {what_now}",
            c.z_threshold,
            self.later.turning,
            c.heading_error_deg,
            c.heading_limit_deg,
            self.later.noise,
        );
        let line = to_line(&StaleMessage {
            class: "STALE",
            sensor: self.sensor,
            time: self.time,
            calibration: id,
            parameters: &c.parameters,
            z_threshold: c.z_threshold,
            heading_error_deg: c.heading_error_deg,
            heading_noise_deg: c.heading_noise_deg,
            heading_limit_deg: c.heading_limit_deg,
            action: if self.replace { "replace" } else { "warn" },
            message: &text,
        });
        tracing::warn!(sensor = %self.sensor, "{text}");
        emit.line(Lane::Control, line);
        if !replaces {
            life.stale = Some(format!(
                "calibration #{id} is stale: a later {what} moved {moved}, turning {} by up to {:.1}°; {}",
                self.later.turns,
                c.heading_error_deg,
                if self.replace {
                    format!("a new {what} is being collected to replace it")
                } else {
                    "recalibrate".to_string()
                }
            ));
        }
        replaces
    }
}
