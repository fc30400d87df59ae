//! The simulator: a sensor turned through whole rotations in a constant
//! field, read through the paper's model (per-axis gain and offset) with
//! Gaussian noise, so fieldcal can be tried and tested with no sensor.
//! Hidden effects ([`SimEffects`]) mirror the catalogue, so each effect's
//! fit can be checked against a known truth.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::Serialize;

use rand::RngExt as _;

use crate::model::paper::PaperCalibration;
use crate::sample::{Covariate, Dataset};

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
    /// Effects beyond the paper's model (none by default).
    pub effects: SimEffects,
}

/// Effects the paper's model lacks, hidden in the simulated readings with
/// known magnitudes. Each mirrors a term of [`crate::model::nonlinear`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimEffects {
    /// Non-orthogonality: the y sensing axis tilted toward x by this angle,
    /// in degrees (cross-axis coupling).
    pub cross_axis_deg: f64,
    /// Offsets moving during the run, in counts per second, [x, y].
    pub drift_per_s: [f64; 2],
    /// Offset per degree Celsius of a `temp` column, in counts, [x, y]. The
    /// temperature starts at 20 °C, rises by `temp_rise` toward a plateau and
    /// cools back after the half-way point (not monotonic, so it is told
    /// apart from drift).
    pub temp_per_c: Option<[f64; 2]>,
    /// How far the temperature rises, in °C.
    pub temp_rise: f64,
    /// Offset per ampere of a `current` column, in counts, [x, y]. The
    /// current is a motor switching between 0 A and 2 A at irregular times.
    pub current_per_a: Option<[f64; 2]>,
    /// Odd non-linearity per axis, [x, y]: the reading falls short of the
    /// linear one by this fraction at full scale (the largest static reading).
    pub cubic: [f64; 2],
    /// Odd non-linearity about the turn's centre per axis, [x, y]: each
    /// axis's reading falls short by that fraction at the turn's amplitude
    /// on that axis, about the turn's centre (a proof mass about its zero-g
    /// point; one axis's amplifier near saturation).
    pub cubic_centred: [f64; 2],
    /// Fraction of samples hit by a spike of 20 to 50 noise SDs.
    pub outliers: f64,
}

impl Default for SimEffects {
    fn default() -> Self {
        SimEffects {
            cross_axis_deg: 0.0,
            drift_per_s: [0.0; 2],
            temp_per_c: None,
            temp_rise: 10.0,
            current_per_a: None,
            cubic: [0.0; 2],
            cubic_centred: [0.0; 2],
            outliers: 0.0,
        }
    }
}

/// The true values behind a simulation, in the model's parameter names.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimTruth {
    /// Every parameter of the full model, by name (a, b, d, r, c, drift_x,
    /// drift_y, temp_x, temp_y, current_x, current_y, k_x, k_y, kc_x, kc_y),
    /// in the fit's units: k in terms of the data's own full scale, kc in
    /// terms of the turn's radius the fit takes from the closed form.
    pub params: std::collections::BTreeMap<String, f64>,
    /// Indices of the samples hit by spikes, ascending.
    pub outliers: Vec<usize>,
}

/// Temperature profile: 20 °C, rising with time constant `duration/6`,
/// cooling back from the half-way point.
fn temperature(time: f64, duration: f64, rise: f64) -> f64 {
    let tau = (duration / 6.0).max(1e-9);
    let half = duration / 2.0;
    if time <= half {
        20.0 + rise * (1.0 - (-time / tau).exp())
    } else {
        let peak = rise * (1.0 - (-half / tau).exp());
        20.0 + peak * (-(time - half) / tau).exp()
    }
}

/// An odd cubic `k*(raw - centre)^3/scale^2` of the model.
#[derive(Clone, Copy)]
struct CubicTerm {
    k: f64,
    centre: f64,
    scale: f64,
}

impl CubicTerm {
    /// k/scale², 0 when the term is absent.
    fn q(&self) -> f64 {
        if self.scale > 0.0 {
            self.k / (self.scale * self.scale)
        } else {
            0.0
        }
    }
}

/// Solves `raw + Σ k*(raw - centre)^3/scale^2 = linear` for raw by Newton's
/// method (the model's cubic corrections inverted, so the model can undo
/// them exactly).
fn compress(linear: f64, terms: [CubicTerm; 2]) -> f64 {
    let q = terms.map(|t| t.q());
    if q.iter().all(|q| *q == 0.0) {
        return linear;
    }
    let mut raw = linear;
    for _ in 0..50 {
        let mut f = raw - linear;
        let mut slope = 1.0;
        for (term, q) in terms.iter().zip(q) {
            let u = raw - term.centre;
            f += q * u * u * u;
            slope += 3.0 * q * u * u;
        }
        if slope <= 0.0 {
            break;
        }
        let step = f / slope;
        raw -= step;
        if step.abs() <= 1e-14 * raw.abs().max(1.0) {
            break;
        }
    }
    raw
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
            effects: SimEffects::default(),
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
        let e = &self.effects;
        let effect_checks: [(&'static str, f64, &'static str, bool); 6] = [
            (
                "effect cross-axis",
                e.cross_axis_deg,
                "an angle between -45 and 45 degrees",
                e.cross_axis_deg.abs() < 45.0,
            ),
            (
                "effect cubic",
                e.cubic[0].abs().max(e.cubic[1].abs()),
                "a fraction between -0.25 and 0.25",
                e.cubic.iter().all(|k| k.abs() <= 0.25),
            ),
            (
                "effect cubic-centred",
                e.cubic_centred[0].abs().max(e.cubic_centred[1].abs()),
                "a fraction between -0.25 and 0.25",
                e.cubic_centred.iter().all(|k| k.abs() <= 0.25),
            ),
            (
                "effect outliers",
                e.outliers,
                "a fraction from 0 to 0.5",
                (0.0..=0.5).contains(&e.outliers),
            ),
            ("temp-rise", e.temp_rise, "a finite number", true),
            (
                "effect drift",
                e.drift_per_s[0] + e.drift_per_s[1],
                "finite",
                true,
            ),
        ];
        for (name, value, rule, ok) in effect_checks {
            if !ok || !value.is_finite() {
                return Err(SimError::Invalid { name, rule, value });
            }
        }
        for value in e
            .temp_per_c
            .iter()
            .chain(&e.current_per_a)
            .flatten()
            .chain(&e.drift_per_s)
        {
            if !value.is_finite() {
                return Err(SimError::Invalid {
                    name: "effect",
                    rule: "a finite number",
                    value: *value,
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

    /// Simulates the recording: columns `t`, `x`, `y`, and `temp` or
    /// `current` when the sensor has those effects.
    pub fn simulate(&self) -> Result<Dataset, SimError> {
        self.simulate_with_truth().map(|(data, _)| data)
    }

    /// The sample times, rounded to the nanosecond so 0.15 is written 0.15,
    /// not 0.15000000000000002, and the covariates logged at each: the
    /// temperature and the switched current, where those effects are on.
    fn clock_and_covariates(
        &self,
        n: usize,
        duration: f64,
        switch_rng: &mut ChaCha8Rng,
    ) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let e = &self.effects;
        let mut t = Vec::with_capacity(n);
        let mut temp = Vec::new();
        let mut current = Vec::new();
        let mut current_on = false;
        let mut next_switch = 0.0;
        let switch_mean = self.turn_seconds / 5.0;
        for i in 0..n {
            let time = (i as f64 * self.period * 1e9).round() / 1e9;
            t.push(time);
            if e.temp_per_c.is_some() {
                temp.push(temperature(time, duration, e.temp_rise));
            }
            if e.current_per_a.is_some() {
                while time >= next_switch {
                    current_on = !current_on;
                    next_switch += switch_mean * (0.5 + switch_rng.random::<f64>());
                }
                current.push(if current_on { 2.0 } else { 0.0 });
            }
        }
        (t, temp, current)
    }

    /// Simulates the recording and reports the true value of every
    /// parameter of the full model, and which samples carry spikes.
    pub fn simulate_with_truth(&self) -> Result<(Dataset, SimTruth), SimError> {
        let n = self.validate()?;
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let noise = Normal::new(0.0, self.noise).map_err(|_| SimError::Invalid {
            name: "noise",
            rule: "zero or more",
            value: self.noise,
        })?;
        let rate = std::f64::consts::TAU / self.turn_seconds;
        let start = self.start_heading_deg.to_radians();
        let e = &self.effects;
        let tilt = e.cross_axis_deg.to_radians();
        // Full scale of the cubic: the largest static reading of the turn.
        let full_scale = (self.offset_x.abs() + self.gain_x * self.field)
            .max(self.offset_y.abs() + self.gain_y * self.field);
        let duration = n as f64 * self.period;
        // Effects draw from their own streams, so the noise of a seed stays
        // the same with or without them.
        let mut switch_rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x6375_7272_656e_7400);
        let mut spike_rng = ChaCha8Rng::seed_from_u64(self.seed ^ 0x7370_696b_6500_0000);
        let spike_sd = if self.noise > 0.0 {
            self.noise
        } else {
            1e-3 * self.field * self.gain_y
        };
        // First the clock and the covariates, so the moving offsets' means
        // are known: the model's cubic acts on the reading less the moving
        // offsets about their means, and the simulation mirrors it.
        let (t, temp, current) = self.clock_and_covariates(n, duration, &mut switch_rng);
        let moving = |i: usize| -> (f64, f64) {
            let mut moving_x = e.drift_per_s[0] * t[i];
            let mut moving_y = e.drift_per_s[1] * t[i];
            if let Some([kx, ky]) = e.temp_per_c {
                moving_x += kx * temp[i];
                moving_y += ky * temp[i];
            }
            if let Some([kx, ky]) = e.current_per_a {
                moving_x += kx * current[i];
                moving_y += ky * current[i];
            }
            (moving_x, moving_y)
        };
        let (mut mean_x, mut mean_y) = (0.0, 0.0);
        for i in 0..n {
            let (mx, my) = moving(i);
            mean_x += mx / n as f64;
            mean_y += my / n as f64;
        }
        let mut x = Vec::with_capacity(n);
        let mut y = Vec::with_capacity(n);
        let mut outliers = Vec::new();
        for (i, &time) in t.iter().enumerate() {
            let heading = start + rate * time;
            let (moving_x, moving_y) = moving(i);
            let centre_x = self.offset_x + mean_x;
            let centre_y = self.offset_y + mean_y;
            let static_x = compress(
                self.gain_x * self.field * heading.cos() + centre_x,
                [
                    CubicTerm {
                        k: e.cubic[0],
                        centre: 0.0,
                        scale: full_scale,
                    },
                    CubicTerm {
                        k: e.cubic_centred[0],
                        centre: centre_x,
                        scale: self.gain_x * self.field,
                    },
                ],
            );
            let static_y = compress(
                self.gain_y * self.field * (heading + tilt).sin() + centre_y,
                [
                    CubicTerm {
                        k: e.cubic[1],
                        centre: 0.0,
                        scale: full_scale,
                    },
                    CubicTerm {
                        k: e.cubic_centred[1],
                        centre: centre_y,
                        scale: self.gain_y * self.field,
                    },
                ],
            );
            let mut xi = static_x + (moving_x - mean_x) + noise.sample(&mut rng);
            let mut yi = static_y + (moving_y - mean_y) + noise.sample(&mut rng);
            if e.outliers > 0.0 && spike_rng.random::<f64>() < e.outliers {
                let size = spike_sd * (20.0 + 30.0 * spike_rng.random::<f64>());
                let sign = if spike_rng.random::<bool>() {
                    1.0
                } else {
                    -1.0
                };
                match spike_rng.random_range(0..3u8) {
                    0 => xi += sign * size,
                    1 => yi += sign * size,
                    _ => {
                        xi += sign * size;
                        yi -= sign * size;
                    }
                }
                outliers.push(i);
            }
            x.push(xi);
            y.push(yi);
        }
        let mut covariates = Vec::new();
        if !temp.is_empty() {
            covariates.push(Covariate {
                name: "temp".into(),
                values: temp,
            });
        }
        if !current.is_empty() {
            covariates.push(Covariate {
                name: "current".into(),
                values: current,
            });
        }
        // Every value is finite: the inputs were checked above.
        let data =
            Dataset::new("x", "y", Some(t), x, y, covariates).map_err(|_| SimError::Invalid {
                name: "field",
                rule: "small enough to keep readings finite",
                value: self.field,
            })?;
        let truth = self.model_truth(&data, full_scale, outliers);
        Ok((data, truth))
    }

    /// The full model's parameters that undo this sensor on `data`.
    fn model_truth(&self, data: &Dataset, full_scale: f64, outliers: Vec<usize>) -> SimTruth {
        let e = &self.effects;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let t_mean = data.t.as_deref().map_or(0.0, mean);
        let column_mean = |name: &str| data.covariate(name).map_or(0.0, |c| mean(&c.values));
        let [tx, ty] = e.temp_per_c.unwrap_or([0.0; 2]);
        let [cx, cy] = e.current_per_a.unwrap_or([0.0; 2]);
        // b and d are the mean offsets: the moving terms are centred.
        let offset_x = self.offset_x
            + e.drift_per_s[0] * t_mean
            + tx * column_mean("temp")
            + cx * column_mean("current");
        let offset_y = self.offset_y
            + e.drift_per_s[1] * t_mean
            + ty * column_mean("temp")
            + cy * column_mean("current");
        let tilt = e.cross_axis_deg.to_radians();
        let a = self.gain_y / (self.gain_x * tilt.cos());
        // The model's cubic is scaled by the data's own largest reading.
        let scale_ratio = (crate::model::nonlinear::cubic_scale(data) / full_scale).powi(2);
        // The centred cubic is scaled by the turn's radius per axis as the
        // fit finds it (the closed form's), against the true amplitudes.
        let radius_ratio = match crate::model::nonlinear::turn_frame(data) {
            Ok(frame) => [
                (frame.radius[0] / (self.gain_x * self.field)).powi(2),
                (frame.radius[1] / (self.gain_y * self.field)).powi(2),
            ],
            Err(_) => [1.0; 2],
        };
        let params = [
            ("a", a),
            ("b", -a * offset_x),
            ("d", -offset_y),
            ("r", self.gain_y * self.field),
            ("c", -tilt.tan()),
            ("drift_x", e.drift_per_s[0]),
            ("drift_y", e.drift_per_s[1]),
            ("temp_x", tx),
            ("temp_y", ty),
            ("current_x", cx),
            ("current_y", cy),
            ("k_x", e.cubic[0] * scale_ratio),
            ("k_y", e.cubic[1] * scale_ratio),
            (
                "kc",
                0.5 * (e.cubic_centred[0] * radius_ratio[0] + e.cubic_centred[1] * radius_ratio[1]),
            ),
            ("kc_x", e.cubic_centred[0] * radius_ratio[0]),
            ("kc_y", e.cubic_centred[1] * radius_ratio[1]),
        ]
        .into_iter()
        .map(|(name, value)| (name.to_string(), value + 0.0))
        .collect();
        SimTruth { params, outliers }
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

/// Largest `--garbage` fraction: nine garbage bytes for each frame byte,
/// far beyond any line a decoder must survive (a noisy RS-485 line loses a
/// few percent). The garbage per frame grows as f/(1 - f): 0.99999 took
/// 460 MB for a 10 s turn and 0.9999999 aborted on allocation.
pub const MAX_GARBAGE: f64 = 0.9;

/// Largest simulated capture, in bytes of frames and garbage: 1 GiB, the
/// size of the largest CSV [`MAX_SAMPLES`] allows. It is built in memory.
pub const MAX_CAPTURE_BYTES: f64 = (1u64 << 30) as f64;

/// Why a simulated recording cannot be put in Falcon-GX frames.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WireError {
    #[error(transparent)]
    Sim(#[from] SimError),
    #[error(
        "sample {index} reads {value:.0} counts, outside the i16 range of a Falcon-GX frame; lower --field, the gains or the offsets"
    )]
    OutOfRange { index: usize, value: f64 },
    #[error("--garbage must be a fraction from 0 to {max}, got {0}", max = MAX_GARBAGE)]
    Garbage(f64),
    #[error(
        "the capture would take about {bytes:.0} bytes, more than the {max:.0} a simulation writes; lower --turns or --garbage, or raise --period",
        max = MAX_CAPTURE_BYTES
    )]
    TooLarge { bytes: f64 },
}

impl SimSensor {
    /// Checks, before anything is simulated or allocated, that a capture of
    /// this sensor on `wire` can be made: the garbage fraction, the
    /// sensor's settings, and the size (frames of 23 bytes and on average
    /// f/(1 − f) garbage bytes for each frame byte) within
    /// [`MAX_CAPTURE_BYTES`].
    pub fn check_capture(&self, wire: &FalconWire) -> Result<(), WireError> {
        if !(0.0..=MAX_GARBAGE).contains(&wire.garbage) {
            return Err(WireError::Garbage(wire.garbage));
        }
        let samples = self.validate()? as f64;
        let bytes = samples * crate::protocol::falcon::FRAME_LEN as f64 / (1.0 - wire.garbage);
        if !(bytes <= MAX_CAPTURE_BYTES) {
            return Err(WireError::TooLarge { bytes });
        }
        Ok(())
    }

    /// Simulates a Falcon-GX-style IMU whose magnetometer x, y are this
    /// sensor (turning about z, so mag z and gravity stay constant), one
    /// frame per `period`, as a capture: header and chunks.
    pub fn falcon_capture(
        &self,
        wire: &FalconWire,
    ) -> Result<(crate::capture::CaptureHeader, Vec<crate::capture::Chunk>), WireError> {
        use crate::protocol::falcon::FalconFrame;

        self.check_capture(wire)?;
        let data = self.simulate()?;
        let to_counts = |index: usize, value: f64| -> Result<i16, WireError> {
            let rounded = value.round();
            if rounded >= i16::MIN as f64 && rounded <= i16::MAX as f64 {
                Ok(rounded as i16)
            } else {
                Err(WireError::OutOfRange { index, value })
            }
        };
        // The true turn rate, in the frame's gyro scale, about z.
        let rate_counts = (360.0 / self.turn_seconds * crate::protocol::falcon::RATE_LSB_PER_DEG_S)
            .round() as i16;
        let t = data.t.as_deref().unwrap_or(&[]);
        let frames = (0..data.len())
            .map(|i| {
                let frame = FalconFrame {
                    mag: [to_counts(i, data.x[i])?, to_counts(i, data.y[i])?, 200],
                    accel: [0, 0, wire.gravity_counts],
                    rate: [0, 0, rate_counts],
                    timer: (i as u64 * wire.ticks_per_frame as u64 % 65_536) as u16,
                };
                Ok((t.get(i).copied().unwrap_or(i as f64 * self.period), frame))
            })
            .collect::<Result<Vec<_>, WireError>>()?;
        let note = format!(
            "simulated: field {} gains {} {} offsets {} {} noise {} seed {}",
            self.field,
            self.gain_x,
            self.gain_y,
            self.offset_x,
            self.offset_y,
            self.noise,
            self.seed
        );
        Ok(pack_falcon(
            &frames,
            wire.garbage,
            self.seed,
            self.period,
            note,
        ))
    }
}

/// A one-stream Falcon capture of `frames` (time, frame), with random
/// bytes making up `garbage` of the stream on average before the frames.
/// The garbage draws on its own stream of randomness (from `seed`), so
/// adding it does not change a sensor's noise.
pub(crate) fn pack_falcon(
    frames: &[(f64, crate::protocol::falcon::FalconFrame)],
    garbage: f64,
    seed: u64,
    period: f64,
    note: String,
) -> (crate::capture::CaptureHeader, Vec<crate::capture::Chunk>) {
    use crate::capture::{CaptureHeader, Chunk, StreamInfo, StreamKind};
    use crate::protocol::falcon::{BAUD, FRAME_LEN};

    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x0067_6172_6261_6765);
    let mut chunks = Vec::with_capacity(frames.len());
    let mut debt = 0.0f64;
    for (time, frame) in frames {
        let mut bytes = frame.encode().to_vec();
        if garbage > 0.0 {
            // The fractional remainder carries over so small rates still
            // produce some garbage.
            debt +=
                garbage / (1.0 - garbage).max(1e-9) * FRAME_LEN as f64 * 2.0 * rng.random::<f64>();
            let burst = debt.floor() as usize;
            debt -= burst as f64;
            let mut junk: Vec<u8> = (0..burst).map(|_| rng.random::<u8>()).collect();
            junk.extend_from_slice(&bytes);
            bytes = junk;
        }
        chunks.push(Chunk {
            time: *time,
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
        nominal_period_s: period,
        note: Some(note),
    };
    (header, chunks)
}
