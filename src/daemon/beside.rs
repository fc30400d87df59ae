//! What a sensor keeps beside the rotation (or sphere) being collected, so that
//! an accepted calibration measures it over the same samples for the trust
//! monitor's check of each later reading: a 2-axis sensor's field across
//! its turn (`out_of_plane`) and its tilt accelerometer's vertical
//! (`tilt`), a 3-axis compass's gyro beside its sphere.

use std::collections::VecDeque;

use crate::model::calibration::{AcrossFit, LevelFit};
use crate::model::level::level_of;
use crate::model::tilt::robust_spread;

/// Values kept beside a rotation or a sphere: (time, value), at most its
/// own `max_samples`, oldest dropped first.
#[derive(Debug, Clone)]
pub struct Beside<T> {
    samples: VecDeque<(f64, T)>,
    cap: usize,
}

impl<T: Copy> Beside<T> {
    pub fn new(cap: usize) -> Self {
        Beside {
            samples: VecDeque::new(),
            cap: cap.max(1),
        }
    }

    /// Keeps one value, at a finite time.
    pub fn push(&mut self, time: f64, value: T) {
        if !time.is_finite() {
            return;
        }
        if self.samples.len() >= self.cap {
            self.samples.pop_front();
        }
        self.samples.push_back((time, value));
    }

    /// The values from `from` to `to` (seconds, inclusive): the span of a
    /// rotation just fitted.
    pub fn over(&self, from: f64, to: f64) -> Vec<T> {
        self.samples
            .iter()
            .filter(|(t, _)| (from..=to).contains(t))
            .map(|(_, v)| *v)
            .collect()
    }

    /// Every (time, value) kept, oldest first.
    pub fn entries(&self) -> impl Iterator<Item = (f64, T)> + '_ {
        self.samples.iter().copied()
    }

    pub fn clear(&mut self) {
        self.samples.clear();
    }
}

impl Beside<f64> {
    /// Median and robust spread of the readings across the turn from
    /// `from` to `to`; those that are not finite are left out.
    pub fn across_over(&self, from: f64, to: f64) -> Option<AcrossFit> {
        robust_spread(&self.over(from, to)).map(|s| AcrossFit {
            median: s.median,
            spread: s.spread,
            n: s.n,
        })
    }
}

impl Beside<[f64; 3]> {
    /// The attitude the tilt accelerometer's readings from `from` to `to`
    /// give ([`level_of`]).
    pub fn level_over(&self, from: f64, to: f64) -> Option<LevelFit> {
        level_of(&self.over(from, to))
    }
}
