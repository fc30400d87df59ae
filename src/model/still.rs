//! Still segments of a 3-axis recording: where the sensor was at rest.
//!
//! An accelerometer reads gravity alone only at rest; held still in a few
//! poses (the six-position calibration of ArduPilot's AccelCalibrator, or
//! the pauses of a hand-held tumble) its readings are points on the
//! ellipsoid, while in motion the hand's own acceleration moves them off
//! it. [`find_still`] finds the poses automatically:
//!
//! 1. a window of [`STILL_WINDOW_S`] (ArduPilot's sample time per pose)
//!    slides over the samples; its spread is the rms distance of its
//!    readings from their mean (all three axes);
//! 2. the sensor's noise is the spread of the quietest windows (the
//!    [`FLOOR_QUANTILE`] of all windows): the data's own noise, whatever
//!    the units;
//! 3. a window is still when its spread is within what that noise and a
//!    hand holding still give ([`NOISE_FACTOR`], [`HAND_STILL_DEG_S`]),
//!    and, when a gyroscope is given, when its rate about its bias stays
//!    under [`HAND_STILL_DEG_S`] at every sample;
//! 4. samples of still windows that follow one another form a segment: a
//!    pose, with its mean and count.
//!
//! A recording in which the sensor never rests (a continuous tumble) has
//! quietest windows far above any sensor's noise ([`MAX_NOISE_FRACTION`]
//! of the field) and gives no poses.

use serde::Serialize;

/// Length of the window over which a pose must stay still, seconds.
/// ArduPilot's AccelCalibrator averages each of its poses over
/// `sample_time = 0.5f` (AccelCalibrator.h, `start(...)`).
pub const STILL_WINDOW_S: f64 = 0.5;

/// The window in samples when the recording has no time column: 0.5 s at
/// 50 Hz, the Falcon-GX's frame rate (sample period 0.05 s).
pub const STILL_WINDOW_SAMPLES_NO_TIME: usize = 25;

/// Fewest samples a window may hold: with 8 samples the spread has
/// 3·7 = 21 degrees of freedom, so its sampling error is 1/√42 ≈ 15 %,
/// well inside [`NOISE_FACTOR`].
pub const MIN_WINDOW_SAMPLES: usize = 8;

/// Most samples a window may hold (a cap on the work per window; 0.5 s at
/// 2 kHz, faster than any chip fieldcal reads).
pub const MAX_WINDOW_SAMPLES: usize = 1000;

/// The sensor's noise is the spread of the quietest windows: this
/// quantile of all windows' spreads. A recording of poses is at rest far
/// more than 5 % of its time (ArduPilot holds each pose for its sample
/// time, and a hand pauses between turns); a noise estimate from the
/// quietest 5 % is then the noise at rest.
pub const FLOOR_QUANTILE: f64 = 0.05;

/// A still window's spread is at most this multiple of the noise. The
/// spread of a window of w samples has 3(w − 1) degrees of freedom; at
/// the minimum window ([`MIN_WINDOW_SAMPLES`]) its relative sampling
/// error is 15 %, so a window at rest exceeds 2× the noise with
/// negligible probability (> 6 standard errors), while a motion that adds
/// √3× the noise in quadrature fails.
pub const NOISE_FACTOR: f64 = 2.0;

/// A hand holding a board still turns it by at most a few degrees per
/// second (physiological tremor, 8–12 Hz, moves the hand by a fraction of
/// a degree); a gyro rate above this, about its bias, is motion. Over one
/// window the direction moves by up to 5 °/s × 0.5 s = 2.5°, an rms
/// spread of r · 2.5° (in radians) / √12 = 1.3 % of the field, which the
/// spread threshold allows beside the noise.
pub const HAND_STILL_DEG_S: f64 = 5.0;

/// The noise of a sensor at rest is far below this fraction of its field:
/// the noisiest chip fieldcal reads, the MPU-6050 accelerometer
/// (400 µg/√Hz, datasheet PS-MPU-6000A-00 rev. 3.4 table 6.2) at its
/// widest bandwidth (260 Hz) gives 6.5 mg per axis, 11 mg = 1.1 % of g
/// over three axes; the HMC5883L's 2 mG noise floor is 0.4 % of a 0.5 G
/// field. Quietest windows spreading more than 5 % of the field (4.5× the
/// MPU-6050's noise) are a sensor in motion: there is no still pose.
pub const MAX_NOISE_FRACTION: f64 = 0.05;

/// A pose: samples `start..end` (indices into the recording) at rest.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StillSegment {
    pub start: usize,
    pub end: usize,
    /// Mean reading over the segment, raw units.
    pub mean: [f64; 3],
    /// Rms distance of the segment's readings from their mean.
    pub spread: f64,
}

impl StillSegment {
    pub fn len(&self) -> usize {
        self.end - self.start
    }

    pub fn is_empty(&self) -> bool {
        self.end == self.start
    }
}

/// The still poses of a recording and how they were found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StillPoses {
    pub segments: Vec<StillSegment>,
    /// Window length in samples.
    pub window: usize,
    /// The noise: spread of the quietest windows, raw units.
    pub noise: f64,
    /// Largest spread of a still window, raw units.
    pub threshold: f64,
    /// Scale of the field: rms distance of all readings from their mean.
    pub field_scale: f64,
    /// The gyro's bias (deg/s) estimated over the windows the readings
    /// alone find still, when a gyro was given.
    pub gyro_bias_deg_s: Option<[f64; 3]>,
}

impl StillPoses {
    /// Indices of every still sample, in order.
    pub fn indices(&self) -> impl Iterator<Item = usize> + '_ {
        self.segments.iter().flat_map(|s| s.start..s.end)
    }

    /// Samples at rest.
    pub fn samples(&self) -> usize {
        self.segments.iter().map(StillSegment::len).sum()
    }
}

/// Why no still poses were found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StillError {
    #[error(
        "{found} samples are too few to find still poses: one window of {window} samples ({STILL_WINDOW_S} s) is needed at least"
    )]
    TooFew { found: usize, window: usize },
    #[error(
        "the gyro has {gyro} samples and the readings {readings}: they must be the rows of one recording"
    )]
    GyroLength { gyro: usize, readings: usize },
    #[error(
        "the sensor never held still: its quietest {STILL_WINDOW_S} s windows spread {:.1} % of the field, and a sensor at rest spreads less than {:.0} %; hold it still in each pose for at least {STILL_WINDOW_S} s",
        100.0 * quietest / field_scale,
        100.0 * MAX_NOISE_FRACTION
    )]
    NeverStill { quietest: f64, field_scale: f64 },
    #[error(
        "no window is still by the gyro (rate about its bias under {HAND_STILL_DEG_S} °/s for {STILL_WINDOW_S} s); hold the sensor still in each pose"
    )]
    GyroNeverStill,
}

/// The window in samples for the recording's times (or none).
pub fn window_samples(t: Option<&[f64]>) -> usize {
    let w = match t {
        Some(t) if t.len() >= 2 => {
            // The mean period: I2C polling delivers samples in bursts (the
            // sunsided MPU-6050 recording: median step 2.2 ms, mean 10 ms),
            // and the window must span 0.5 s of the recording's clock.
            let period = (t[t.len() - 1] - t[0]) / (t.len() - 1) as f64;
            let w = (STILL_WINDOW_S / period).round();
            if period > 0.0 && w.is_finite() {
                (w as usize).min(MAX_WINDOW_SAMPLES)
            } else {
                STILL_WINDOW_SAMPLES_NO_TIME
            }
        }
        _ => STILL_WINDOW_SAMPLES_NO_TIME,
    };
    w.clamp(MIN_WINDOW_SAMPLES, MAX_WINDOW_SAMPLES)
}

/// Spread of each window of `w` samples (window i covers i..i+w), by
/// prefix sums on readings centred on their mean.
fn window_spreads(points: &[[f64; 3]], mean: [f64; 3], w: usize) -> Vec<f64> {
    let n = points.len();
    let mut sum = vec![[0.0f64; 3]; n + 1];
    let mut sq = vec![0.0f64; n + 1];
    for (i, p) in points.iter().enumerate() {
        let d = [p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]];
        sum[i + 1] = [sum[i][0] + d[0], sum[i][1] + d[1], sum[i][2] + d[2]];
        sq[i + 1] = sq[i] + d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    }
    let wf = w as f64;
    (0..=n - w)
        .map(|i| {
            let s = [0, 1, 2].map(|k| sum[i + w][k] - sum[i][k]);
            let m2 = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]) / (wf * wf);
            ((sq[i + w] - sq[i]) / wf - m2).max(0.0).sqrt()
        })
        .collect()
}

fn quantile(values: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = values.to_vec();
    v.sort_by(f64::total_cmp);
    let k = ((v.len() as f64 - 1.0) * q).round() as usize;
    v[k.min(v.len() - 1)]
}

/// The upper median of a non-empty `v` (found by selection).
fn median(mut v: Vec<f64>) -> f64 {
    let middle = v.len() / 2;
    *v.select_nth_unstable_by(middle, f64::total_cmp).1
}

/// Samples covered by a still window, as segments.
fn segments_of(points: &[[f64; 3]], still_window: &[bool], w: usize) -> Vec<StillSegment> {
    let n = points.len();
    let mut still = vec![false; n];
    for (i, _) in still_window.iter().enumerate().filter(|(_, s)| **s) {
        for s in &mut still[i..i + w] {
            *s = true;
        }
    }
    let mut out = Vec::new();
    let mut i = 0;
    while i < n {
        if !still[i] {
            i += 1;
            continue;
        }
        let start = i;
        while i < n && still[i] {
            i += 1;
        }
        let seg = &points[start..i];
        let k = seg.len() as f64;
        let mut mean = [0.0; 3];
        for p in seg {
            for j in 0..3 {
                mean[j] += p[j] / k;
            }
        }
        let spread = (seg
            .iter()
            .map(|p| (0..3).map(|j| (p[j] - mean[j]).powi(2)).sum::<f64>())
            .sum::<f64>()
            / k)
            .sqrt();
        out.push(StillSegment {
            start,
            end: i,
            mean,
            spread,
        });
    }
    out
}

/// Finds the still poses of a 3-axis recording. `t`: sample times in
/// seconds (the window is [`STILL_WINDOW_S`] long; without times,
/// [`STILL_WINDOW_SAMPLES_NO_TIME`] samples). `gyro_deg_s`: the three
/// rates of a gyroscope on the same board, one per sample, in deg/s.
pub fn find_still(
    points: &[[f64; 3]],
    t: Option<&[f64]>,
    gyro_deg_s: Option<&[[f64; 3]]>,
) -> Result<StillPoses, StillError> {
    let n = points.len();
    let w = window_samples(t);
    if n < w {
        return Err(StillError::TooFew {
            found: n,
            window: w,
        });
    }
    if let Some(g) = gyro_deg_s
        && g.len() != n
    {
        return Err(StillError::GyroLength {
            gyro: g.len(),
            readings: n,
        });
    }
    let nf = n as f64;
    let mut mean = [0.0; 3];
    for p in points {
        for j in 0..3 {
            mean[j] += p[j] / nf;
        }
    }
    let field_scale = (points
        .iter()
        .map(|p| (0..3).map(|j| (p[j] - mean[j]).powi(2)).sum::<f64>())
        .sum::<f64>()
        / nf)
        .sqrt();
    let spreads = window_spreads(points, mean, w);
    let noise = quantile(&spreads, FLOOR_QUANTILE);
    if !(noise <= MAX_NOISE_FRACTION * field_scale) {
        return Err(StillError::NeverStill {
            quietest: noise,
            field_scale,
        });
    }
    // A hand turning at HAND_STILL_DEG_S sweeps the field's direction
    // through this many radians in one window; a sweep of angle a has an
    // rms spread of r·a/√12 about its middle.
    let sweep = HAND_STILL_DEG_S.to_radians() * STILL_WINDOW_S;
    let motion = field_scale * sweep / 12f64.sqrt();
    let threshold = ((NOISE_FACTOR * noise).powi(2) + motion.powi(2)).sqrt();
    let mut still: Vec<bool> = spreads.iter().map(|&s| s <= threshold).collect();
    let mut gyro_bias = None;
    if let Some(g) = gyro_deg_s {
        // The gyro's bias (up to ±20 °/s for the MPU-6050, its datasheet's
        // zero-rate output tolerance): its median over the samples the
        // readings alone find still.
        let at_rest: Vec<usize> = segments_of(points, &still, w)
            .iter()
            .flat_map(|s| s.start..s.end)
            .collect();
        if at_rest.is_empty() {
            return Err(StillError::GyroNeverStill);
        }
        let bias = [0, 1, 2].map(|k| median(at_rest.iter().map(|&i| g[i][k]).collect()));
        let calm: Vec<bool> = g
            .iter()
            .map(|r| {
                let d = [r[0] - bias[0], r[1] - bias[1], r[2] - bias[2]];
                (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() <= HAND_STILL_DEG_S
            })
            .collect();
        // A window is still when every one of its samples is calm: count
        // the calm samples per window by prefix sums.
        let mut calm_sum = vec![0usize; n + 1];
        for (i, c) in calm.iter().enumerate() {
            calm_sum[i + 1] = calm_sum[i] + usize::from(*c);
        }
        for (i, s) in still.iter_mut().enumerate() {
            *s = *s && calm_sum[i + w] - calm_sum[i] == w;
        }
        if !still.iter().any(|s| *s) {
            return Err(StillError::GyroNeverStill);
        }
        gyro_bias = Some(bias);
    }
    Ok(StillPoses {
        segments: segments_of(points, &still, w),
        window: w,
        noise,
        threshold,
        field_scale,
        gyro_bias_deg_s: gyro_bias,
    })
}
