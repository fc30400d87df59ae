//! The simulator: a sensor turned through whole rotations in a constant
//! field, read through the paper's model (per-axis gain and offset) with
//! Gaussian noise, so fieldcal can be tried and tested with no sensor.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use crate::model::paper::PaperCalibration;
use crate::sample::Dataset;

/// A simulated sensor and the way it is turned.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimSensor {
    /// Magnitude of the field, in true units (for example counts at unit gain).
    pub field: f64,
    /// Gains: raw = gain * true + offset, per axis.
    pub gain_x: f64,
    pub gain_y: f64,
    /// Offsets (hard iron, zero-g bias) in raw counts.
    pub offset_x: f64,
    pub offset_y: f64,
    /// Standard deviation of the Gaussian noise on each axis, in raw counts.
    pub noise: f64,
    /// Sample period in seconds.
    pub period: f64,
    /// Number of rotations (may be fractional).
    pub turns: f64,
    /// Seconds one rotation takes.
    pub turn_seconds: f64,
    /// Heading of the first sample, in degrees.
    pub start_heading_deg: f64,
    /// Seed of the noise: the same seed gives the same file.
    pub seed: u64,
}

impl Default for SimSensor {
    fn default() -> Self {
        SimSensor {
            field: 1000.0,
            gain_x: 1.0,
            gain_y: 1.0,
            offset_x: 0.0,
            offset_y: 0.0,
            noise: 0.0,
            period: 0.05,
            turns: 1.0,
            turn_seconds: 10.0,
            start_heading_deg: 0.0,
            seed: 1,
        }
    }
}

/// Why a simulation cannot run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    #[error("--{name} must be {rule}, got {value}")]
    Invalid {
        name: &'static str,
        rule: &'static str,
        value: f64,
    },
    #[error(
        "{samples} samples are too many to simulate (at most {max}); lower --turns or raise --period"
    )]
    TooMany { samples: f64, max: usize },
}

/// Most samples one simulation writes (about 1 GB of CSV).
pub const MAX_SAMPLES: usize = 20_000_000;

impl SimSensor {
    fn validate(&self) -> Result<usize, SimError> {
        let checks: [(&'static str, f64, &'static str, bool); 8] = [
            ("field", self.field, "a positive number", self.field > 0.0),
            (
                "gain-x",
                self.gain_x,
                "a positive number",
                self.gain_x > 0.0,
            ),
            (
                "gain-y",
                self.gain_y,
                "a positive number",
                self.gain_y > 0.0,
            ),
            ("noise", self.noise, "zero or more", self.noise >= 0.0),
            (
                "period",
                self.period,
                "a positive number of seconds",
                self.period > 0.0,
            ),
            ("turns", self.turns, "a positive number", self.turns > 0.0),
            (
                "turn-seconds",
                self.turn_seconds,
                "a positive number of seconds",
                self.turn_seconds > 0.0,
            ),
            (
                "offset-x",
                self.offset_x,
                "a finite number",
                self.offset_x.is_finite(),
            ),
        ];
        for (name, value, rule, ok) in checks {
            if !ok || !value.is_finite() {
                return Err(SimError::Invalid { name, rule, value });
            }
        }
        for (name, value) in [
            ("offset-y", self.offset_y),
            ("start-heading", self.start_heading_deg),
        ] {
            if !value.is_finite() {
                return Err(SimError::Invalid {
                    name,
                    rule: "a finite number",
                    value,
                });
            }
        }
        let samples = (self.turns * self.turn_seconds / self.period).round();
        if !(samples <= MAX_SAMPLES as f64) {
            return Err(SimError::TooMany {
                samples,
                max: MAX_SAMPLES,
            });
        }
        Ok(samples.max(1.0) as usize)
    }

    /// The calibration that undoes this sensor, in the paper's terms.
    pub fn truth(&self) -> PaperCalibration {
        let a = self.gain_y / self.gain_x;
        PaperCalibration {
            a,
            // `+ 0.0` so a zero offset reads 0, not -0.
            b: -a * self.offset_x + 0.0,
            d: -self.offset_y + 0.0,
            r: self.gain_y * self.field,
        }
    }

    /// Simulates the recording: columns `t`, `x`, `y`.
    pub fn simulate(&self) -> Result<Dataset, SimError> {
        let n = self.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let noise = Normal::new(0.0, self.noise).map_err(|_| SimError::Invalid {
            name: "noise",
            rule: "zero or more",
            value: self.noise,
        })?;
        let rate = std::f64::consts::TAU / self.turn_seconds;
        let start = self.start_heading_deg.to_radians();
        let mut t = Vec::with_capacity(n);
        let mut x = Vec::with_capacity(n);
        let mut y = Vec::with_capacity(n);
        for i in 0..n {
            // Rounded to the nanosecond so 0.15 is written 0.15, not 0.15000000000000002.
            let time = (i as f64 * self.period * 1e9).round() / 1e9;
            let heading = start + rate * time;
            t.push(time);
            x.push(
                self.gain_x * self.field * heading.cos() + self.offset_x + noise.sample(&mut rng),
            );
            y.push(
                self.gain_y * self.field * heading.sin() + self.offset_y + noise.sample(&mut rng),
            );
        }
        // Every value is finite: the inputs were checked above.
        Dataset::new("x", "y", Some(t), x, y, Vec::new()).map_err(|_| SimError::Invalid {
            name: "field",
            rule: "small enough to keep readings finite",
            value: self.field,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_seed_same_data_other_seed_other_noise() {
        let s = SimSensor {
            noise: 2.0,
            ..Default::default()
        };
        let a = s.simulate().unwrap();
        assert_eq!(a, s.simulate().unwrap());
        let b = SimSensor { seed: 2, ..s }.simulate().unwrap();
        assert_ne!(a.x, b.x);
        assert_eq!(a.len(), 200);
    }

    #[test]
    fn truth_calibrates_noiseless_samples_onto_the_circle() {
        let s = SimSensor {
            gain_x: 1.4,
            gain_y: 0.9,
            offset_x: 300.0,
            offset_y: -120.0,
            ..Default::default()
        };
        let d = s.simulate().unwrap();
        let truth = s.truth();
        assert!(truth.rms(&d.x, &d.y) < 1e-12);
    }

    #[test]
    fn refuses_nonsense() {
        let s = SimSensor {
            period: 0.0,
            ..Default::default()
        };
        assert_eq!(
            s.simulate().unwrap_err().to_string(),
            "--period must be a positive number of seconds, got 0"
        );
    }
}

/// How a simulated Falcon-GX-style IMU puts the simulated sensor on the wire.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FalconWire {
    /// Fraction of extra garbage bytes spliced between frames (0.01 = 1 %).
    pub garbage: f64,
    /// Timer ticks per frame (the device's clock; 50 for a 1 ms tick).
    pub ticks_per_frame: u16,
    /// Counts the accelerometer reads for gravity, on its z axis.
    pub gravity_counts: i16,
}

impl Default for FalconWire {
    fn default() -> Self {
        FalconWire {
            garbage: 0.0,
            ticks_per_frame: 50,
            gravity_counts: 4096,
        }
    }
}

/// Why a simulated recording cannot be put in Falcon-GX frames.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error(
        "sample {index} reads {value:.0} counts, outside the i16 range of a Falcon-GX frame; lower --field, the gains or the offsets"
    )]
    OutOfRange { index: usize, value: f64 },
    #[error("--garbage must be a fraction from 0 up to (not including) 1, got {0}")]
    Garbage(f64),
}

impl SimSensor {
    /// Simulates a Falcon-GX-style IMU whose magnetometer x, y are this
    /// sensor (turning about z, so mag z and gravity stay constant), one
    /// frame per `period`, as a capture: header and chunks.
    pub fn falcon_capture(
        &self,
        wire: &FalconWire,
    ) -> Result<(crate::capture::CaptureHeader, Vec<crate::capture::Chunk>), WireError> {
        use crate::capture::{CaptureHeader, Chunk, StreamInfo, StreamKind};
        use crate::protocol::falcon::{BAUD, FalconFrame};
        use rand::RngExt as _;

        if !(0.0..1.0).contains(&wire.garbage) {
            return Err(WireError::Garbage(wire.garbage));
        }
        let data = self.simulate()?;
        let to_counts = |index: usize, value: f64| -> Result<i16, WireError> {
            let rounded = value.round();
            if rounded >= i16::MIN as f64 && rounded <= i16::MAX as f64 {
                Ok(rounded as i16)
            } else {
                Err(WireError::OutOfRange { index, value })
            }
        };
        // A separate stream of randomness, so adding garbage does not change
        // the sensor's noise.
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x0067_6172_6261_6765);
        let rate_counts = (360.0 / self.turn_seconds * 10.0).round() as i16;
        let t = data.t.as_deref().unwrap_or(&[]);
        let mut chunks = Vec::with_capacity(data.len());
        let mut debt = 0.0f64;
        for i in 0..data.len() {
            let frame = FalconFrame {
                mag: [to_counts(i, data.x[i])?, to_counts(i, data.y[i])?, 200],
                accel: [0, 0, wire.gravity_counts],
                rate: [0, 0, rate_counts],
                timer: (i as u64 * wire.ticks_per_frame as u64 % 65_536) as u16,
            };
            let mut bytes = frame.encode().to_vec();
            if wire.garbage > 0.0 {
                // Garbage bytes make up `garbage` of the stream on average;
                // the fractional remainder carries over so small rates still
                // produce some garbage.
                debt += wire.garbage / (1.0 - wire.garbage).max(1e-9)
                    * 23.0
                    * 2.0
                    * rng.random::<f64>();
                let burst = debt.floor() as usize;
                debt -= burst as f64;
                let mut junk: Vec<u8> = (0..burst).map(|_| rng.random::<u8>()).collect();
                junk.extend_from_slice(&bytes);
                bytes = junk;
            }
            chunks.push(Chunk {
                time: t.get(i).copied().unwrap_or(i as f64 * self.period),
                stream: 0,
                bytes,
            });
        }
        let header = CaptureHeader {
            version: crate::capture::VERSION,
            streams: vec![StreamInfo {
                id: 0,
                kind: StreamKind::Falcon,
            }],
            port: None,
            baud: Some(BAUD),
            started_unix: 0.0,
            nominal_period_s: self.period,
            note: Some(format!(
                "simulated: field {} gains {} {} offsets {} {} noise {} seed {}",
                self.field,
                self.gain_x,
                self.gain_y,
                self.offset_x,
                self.offset_y,
                self.noise,
                self.seed
            )),
        };
        Ok((header, chunks))
    }
}
