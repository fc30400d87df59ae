//! The field across a 2-axis sensor's turn (`out_of_plane`): its readings
//! kept beside the rotation being collected, so that an accepted
//! calibration measures its median and spread over the same samples, for
//! the trust monitor's check of each later reading.

use std::collections::VecDeque;

use crate::model::calibration::AcrossFit;
use crate::model::tilt::robust_spread;

/// The readings across the turn kept beside a rotation: (time, value), at
/// most the rotation's own `max_samples`, oldest dropped first.
#[derive(Debug, Clone)]
pub struct AcrossTrack {
    samples: VecDeque<(f64, f64)>,
    cap: usize,
}

impl AcrossTrack {
    pub fn new(cap: usize) -> Self {
        AcrossTrack {
            samples: VecDeque::new(),
            cap: cap.max(1),
        }
    }

    /// Keeps one reading; one that is not finite is not kept.
    pub fn push(&mut self, time: f64, value: f64) {
        if !(time.is_finite() && value.is_finite()) {
            return;
        }
        if self.samples.len() >= self.cap {
            self.samples.pop_front();
        }
        self.samples.push_back((time, value));
    }

    /// Median and robust spread of the readings from `from` to `to`
    /// (seconds, inclusive): the span of a rotation just fitted.
    pub fn fit_over(&self, from: f64, to: f64) -> Option<AcrossFit> {
        let values: Vec<f64> = self
            .samples
            .iter()
            .filter(|(t, _)| (from..=to).contains(t))
            .map(|(_, v)| *v)
            .collect();
        robust_spread(&values).map(|s| AcrossFit {
            median: s.median,
            spread: s.spread,
            n: s.n,
        })
    }

    pub fn clear(&mut self) {
        self.samples.clear();
    }
}
