//! What every sensor of the daemon keeps whatever its geometry (a 2-axis
//! sensor's plane or a 3-axis sensor's sphere): its state, the calibration
//! correcting its readings, the id the next one gets, and its counts.
//! Held once per sensor by [`super::sensor::Sensor`] and lent to its
//! geometry for each reading.

use super::Calibration;
use super::messages::SensorState;
use super::sensor::Sample;
use crate::model::spike::{Spike, SpikeGate};
use crate::model::watch::HISTORY;

/// Spikes are logged at most once per this many seconds of a sensor's
/// time (each is counted; the log says how many so far).
const SPIKE_LOG_INTERVAL_S: f64 = 10.0;

/// A sensor's state, current calibration, ids and counts.
#[derive(Debug, Clone)]
pub struct Lifecycle {
    /// Collecting, calibrated, or calibrated and collecting anew.
    pub state: SensorState,
    /// The calibration correcting the readings, if any.
    pub current: Option<Calibration>,
    /// The id the next accepted calibration gets.
    pub next_id: u64,
    /// Readings published.
    pub readings: u64,
    pub fits_accepted: u64,
    pub fits_rejected: u64,
    /// Why the last fit was refused.
    pub last_rejection: Option<String>,
    /// Why the current calibration no longer holds (a later rotation moved
    /// it, `on_stale = "warn"`): every reading is distrusted with it until
    /// a new calibration is accepted or an older one rolled back to.
    pub stale: Option<String>,
    /// The gate every published sample passes before it is collected
    /// ([`crate::model::spike`]).
    pub gate: SpikeGate<Sample>,
    /// Samples refused by the gate as spikes, and the last one's sentence.
    pub spikes: u64,
    pub last_spike: Option<String>,
    /// When a spike was last logged (the sensor's time), and a sentence
    /// to log now, taken by the sensor.
    spike_logged_at: Option<f64>,
    spike_log: Option<String>,
}

impl Lifecycle {
    /// A sensor starting from its stored calibration, if any: it corrects
    /// at once and collects nothing until asked to.
    pub fn new(stored: Option<Calibration>) -> Self {
        Lifecycle {
            state: if stored.is_some() {
                SensorState::Calibrated
            } else {
                SensorState::Collecting
            },
            next_id: stored
                .as_ref()
                .map_or(1, |c| c.id.saturating_add(1).min(super::state::MAX_ID)),
            current: stored,
            readings: 0,
            fits_accepted: 0,
            fits_rejected: 0,
            last_rejection: None,
            stale: None,
            gate: SpikeGate::default(),
            spikes: 0,
            last_spike: None,
            spike_logged_at: None,
            spike_log: None,
        }
    }

    /// A sample refused by the gate as `spike` (on the axis `axis_name`):
    /// counted, and logged unless one was within [`SPIKE_LOG_INTERVAL_S`]
    /// (either way: a clock that went back does not mute it).
    pub fn refuse_spike(&mut self, sample: &Sample, spike: &Spike, axis_name: &str) {
        self.spikes = self.spikes.saturating_add(1);
        let sentence = format!(
            "a spike at t = {:.3} s: {}; left out of the rotation and the fit",
            sample.time,
            spike.describe(axis_name)
        );
        let due = self
            .spike_logged_at
            .is_none_or(|t| !((sample.time - t).abs() < SPIKE_LOG_INTERVAL_S));
        if due {
            self.spike_logged_at = Some(sample.time);
            self.spike_log = Some(format!("{sentence} ({} so far)", self.spikes));
        }
        self.last_spike = Some(sentence);
    }

    /// The spike to log now, if one is due.
    pub fn take_spike_log(&mut self) -> Option<String> {
        self.spike_log.take()
    }

    /// Whether the sensor collects (it has no calibration, or was asked
    /// to recalibrate).
    pub fn collecting(&self) -> bool {
        self.state != SensorState::Calibrated
    }

    /// Collects anew; the current calibration keeps correcting until a
    /// new one is accepted.
    pub fn restart(&mut self) {
        // Samples held or decided but not yet collected belong to the
        // rotation before.
        self.gate.drop_held();
        self.state = if self.current.is_some() {
            SensorState::Recalibrating
        } else {
            SensorState::Collecting
        };
    }

    /// A fit was accepted as `calibration`: it corrects from now on, and
    /// the sensor stops collecting.
    /// The one it replaces goes to the new one's history (at most
    /// [`HISTORY`] kept), for `rollback`.
    pub fn accept(&mut self, mut calibration: Calibration) {
        self.next_id = self.next_id.saturating_add(1).min(super::state::MAX_ID);
        self.fits_accepted += 1;
        self.state = SensorState::Calibrated;
        self.stale = None;
        if let Some(mut old) = self.current.take() {
            let mut history = std::mem::take(&mut old.history);
            history.push(old);
            let excess = history.len().saturating_sub(HISTORY);
            history.drain(..excess);
            calibration.history = history;
        }
        self.current = Some(calibration);
    }

    /// Returns to the calibration before the current one (kept in its
    /// history): it corrects from now on, and the sensor stops collecting.
    /// Err says why there is none to return to.
    pub fn rollback(&mut self) -> Result<&Calibration, &'static str> {
        let Some(current) = self.current.as_mut() else {
            return Err("it has no calibration");
        };
        let Some(mut previous) = current.history.pop() else {
            return Err("no earlier calibration is kept");
        };
        previous.history = std::mem::take(&mut current.history);
        self.state = SensorState::Calibrated;
        self.stale = None;
        Ok(self.current.insert(previous))
    }

    /// A fit (or a rotation) was refused for `reason`: counted, and the
    /// previous calibration (if any) keeps correcting.
    pub fn reject(&mut self, reason: String) {
        self.fits_rejected += 1;
        self.last_rejection = Some(reason);
    }

    /// Takes over what `old` (the same sensor under the settings before a
    /// reload) had earned: its calibration (when it had one), the next id
    /// and its counts; then collects anew.
    pub fn carry_over(&mut self, old: Lifecycle) {
        self.carry_counts(&old);
        if old.current.is_some() {
            self.current = old.current;
        }
        self.last_rejection = old.last_rejection;
        self.stale = old.stale;
        self.restart();
    }

    /// Takes over `old`'s next id and counts alone (its axes went from two
    /// to three, or back, so its calibration cannot correct this one): ids
    /// go on from where they were, never back, and the counts keep
    /// counting.
    pub fn carry_counts(&mut self, old: &Lifecycle) {
        self.next_id = self.next_id.max(old.next_id);
        self.readings = old.readings;
        self.fits_accepted = old.fits_accepted;
        self.fits_rejected = old.fits_rejected;
        self.spikes = old.spikes;
        self.last_spike.clone_from(&old.last_spike);
    }
}
