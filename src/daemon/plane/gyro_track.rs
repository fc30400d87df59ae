//! The gyro rate kept beside a plane's rotation, for its heading check and
//! the trust monitor.

use super::*;

/// The angular rate about the turn's axis, in degrees/second, with its
/// times, kept while the sensor collects a rotation: one push per reading;
/// integrated and compared once per rotation.
#[derive(Debug, Clone)]
pub(in crate::daemon) struct GyroTrack {
    pub(in crate::daemon) stream: u8,
    /// Index of the axis in the reading's gyro triad.
    pub(in crate::daemon) axis: usize,
    pub(in crate::daemon) lsb_per_deg_s: f64,
    /// `gyro_x`, `gyro_y` or `gyro_z`, as the messages name it.
    pub(in crate::daemon) column: String,
    pub(in crate::daemon) t: Vec<f64>,
    pub(in crate::daemon) rate: Vec<f64>,
    /// Most entries held: the older half is dropped when full, so memory
    /// stays bounded however long the sensor collects.
    pub(in crate::daemon) cap: usize,
    /// The rate integrated (trapezoids) over every reading kept, in
    /// degrees from an arbitrary origin: the rotation buffer takes its
    /// change since a rotation's first sample.
    pub(in crate::daemon) angle_deg: f64,
    /// The latest rate seen, deg/s, for the trust monitor.
    pub(in crate::daemon) latest: Option<f64>,
}

impl GyroTrack {
    pub(super) fn new(choice: &GyroChoice, max_samples: usize) -> Option<Self> {
        let (stream, axis, lsb_per_deg_s, column) = match choice {
            GyroChoice::Rate {
                stream,
                axis,
                lsb_per_deg_s,
            } => (
                *stream,
                axis.index(),
                *lsb_per_deg_s,
                format!("gyro_{}", axis.name()),
            ),
            // A column's value in its units: one deg/s is 1 deg/s, or
            // pi/180 rad/s.
            GyroChoice::Column { name, units } => (
                0,
                0,
                match units {
                    GyroUnits::DegPerSecond => 1.0,
                    GyroUnits::RadPerSecond => std::f64::consts::PI / 180.0,
                },
                name.clone(),
            ),
            GyroChoice::Off(_) => return None,
        };
        Some(GyroTrack {
            stream,
            axis,
            lsb_per_deg_s,
            column,
            t: Vec::new(),
            rate: Vec::new(),
            // A rotation holds at most max_samples readings of the sensor;
            // a gyro polled beside it adds as many.
            cap: 2 * max_samples.max(1),
            angle_deg: 0.0,
            latest: None,
        })
    }

    /// The latest rate seen, deg/s, kept or not.
    pub(super) fn latest_deg_s(&self) -> Option<f64> {
        self.latest
    }

    /// Notes the rate of a reading that carries this gyro, for the trust
    /// monitor, collecting or not.
    pub(super) fn observe(&mut self, reading: &Reading) {
        if let Some(triad) = reading.gyro.filter(|_| reading.stream == self.stream) {
            self.observe_value(f64::from(triad[self.axis]));
        }
    }

    /// Notes a rate in the gyro's units (counts, or a column's deg/s or
    /// rad/s).
    pub(super) fn observe_value(&mut self, value: f64) {
        let rate = value / self.lsb_per_deg_s;
        self.latest = rate.is_finite().then_some(rate);
    }

    /// Keeps the rate of a reading that carries this gyro. O(1) amortised.
    pub(super) fn keep(&mut self, reading: &Reading) {
        let Some(triad) = reading.gyro.filter(|_| reading.stream == self.stream) else {
            return;
        };
        self.keep_value(reading.time, f64::from(triad[self.axis]));
    }

    /// Keeps a rate at `time` in the gyro's units (counts, or a column's
    /// deg/s or rad/s). O(1) amortised.
    pub(super) fn keep_value(&mut self, time: f64, value: f64) {
        if !value.is_finite() {
            return;
        }
        // The integration needs increasing times; a repeated or earlier
        // time (as the rotation buffer also ignores) is left out.
        if !time.is_finite() || self.t.last().is_some_and(|&last| time <= last) {
            return;
        }
        if self.t.len() >= self.cap {
            let half = self.cap / 2;
            self.t.drain(..half);
            self.rate.drain(..half);
        }
        let rate = value / self.lsb_per_deg_s;
        if let (Some(&t0), Some(&r0)) = (self.t.last(), self.rate.last()) {
            self.angle_deg += (time - t0) * (rate + r0) / 2.0;
        }
        self.t.push(time);
        self.rate.push(rate);
    }

    /// The integrated angle, once a rate has been kept.
    pub(super) fn angle(&self) -> Option<f64> {
        (!self.t.is_empty()).then_some(self.angle_deg)
    }

    pub(super) fn clear(&mut self) {
        self.t.clear();
        self.rate.clear();
    }

    /// Drops the rates of a rotation that was given up, keeping the last
    /// one at or before `time` (where the new rotation starts) and after.
    pub(super) fn forget_before(&mut self, time: f64) {
        let keep_from = self.t.partition_point(|&g| g < time).saturating_sub(1);
        self.t.drain(..keep_from);
        self.rate.drain(..keep_from);
    }

    /// The heading check of a rotation: samples at times `t` whose model
    /// headings are `headings_rad` ([`GyroTrack::reference`]).
    pub(super) fn check(&self, t: &[f64], headings_rad: &[f64]) -> Result<HeadingCheck, String> {
        self.reference(t)?
            .check(headings_rad, &[])
            .map_err(|e| e.to_string())
    }

    /// The gyro's angle at each of a rotation's sample times `t`, from the
    /// rates from the last one at or before its first sample to the first
    /// at or after its last.
    pub(super) fn reference(&self, t: &[f64]) -> Result<HeadingReference, String> {
        let (Some(&first), Some(&last)) = (t.first(), t.last()) else {
            return Err("no samples to check".into());
        };
        let lo = self.t.partition_point(|&g| g <= first).saturating_sub(1);
        let hi = (self.t.partition_point(|&g| g < last) + 1).min(self.t.len());
        let (gyro_t, rate) = match (self.t.get(lo..hi), self.rate.get(lo..hi)) {
            (Some(gt), Some(r)) if !gt.is_empty() => (gt, r),
            _ => {
                return Err(format!("no {} readings during the rotation", self.column));
            }
        };
        HeadingReference::from_rates(&self.column, t, gyro_t, rate, GyroUnits::DegPerSecond)
            .map_err(|e| e.to_string())
    }
}
