//! Still poses found as samples arrive: the daemon's form of
//! [`crate::model::still::find_still`], for an accelerometer calibrated
//! from poses held still (ArduPilot's six-position calibration) rather
//! than from a tumble, where the hand's own acceleration spoils the fit.
//!
//! The rules are those of [`find_still`](crate::model::still::find_still),
//! with the same constants:
//! - a window holds the last [`STILL_WINDOW_S`] of samples; its spread is
//!   the rms distance of its readings from their mean;
//! - the noise is the [`FLOOR_QUANTILE`] of every window's spread seen so
//!   far (a log histogram: bounded memory), once [`MIN_WINDOWS`] windows
//!   were seen;
//! - a window is still when its spread is within `NOISE_FACTOR` × the
//!   noise and the motion of a hand held still, and the noise itself is
//!   below [`MAX_NOISE_FRACTION`] of the field's scale (else the sensor has
//!   never been still);
//! - consecutive still windows form a pose; it ends when a window is not
//!   still (or a gap in time). Its samples are kept (every other one
//!   dropped when it grows beyond [`POSE_SAMPLES`] × 2: a long pose stays
//!   evenly sampled in bounded memory).
//!
//! Early judgements rest on a noise estimate from few windows, so a pose
//! is judged again whenever the poses are asked for
//! ([`StillStream::poses`]): one whose largest window spread exceeds the
//! current threshold is left out.
//!
//! Pure: samples in, poses out; no clock, no I/O.

use std::collections::VecDeque;

use serde::Serialize;

use super::still::{
    FLOOR_QUANTILE, HAND_STILL_DEG_S, MAX_NOISE_FRACTION, MAX_WINDOW_SAMPLES, MIN_WINDOW_SAMPLES,
    NOISE_FACTOR, STILL_WINDOW_S,
};

/// Samples a pose keeps, about: a pose held longer is thinned evenly to
/// between this and twice this. A pose's mean is known to noise/√100 =
/// a tenth of the noise; more samples add nothing a fit needs.
pub const POSE_SAMPLES: usize = 100;

/// Most poses kept; the oldest goes first. ArduPilot's calibration takes
/// six; a person placing the board on its faces and edges, 26.
pub const MAX_POSES: usize = 64;

/// Windows seen before the noise is estimated: the [`FLOOR_QUANTILE`] of
/// 20 windows is their quietest. Fewer would leave the quantile
/// undefined; more would lose the first pose of a person who places the
/// board at once (20 windows end 0.9 s into a pose at 50 Hz). An estimate
/// from few windows is corrected as more come: a pose begun under a
/// higher threshold restarts when its spread exceeds the current one,
/// and [`StillStream::poses`] judges every pose again.
pub const MIN_WINDOWS: u64 = 20;

/// Windows between two estimates of the noise: 0.16 s at 50 Hz, a small
/// share of a 0.5 s window, while a scan of the histogram's 4096 bins is
/// not paid at every sample.
pub const NOISE_EVERY: u64 = 8;

/// The spread histogram: bins of a 32nd of an octave (2 %) from 2^-64
/// to 2^64 (any unit a sensor reports in), a spread of exactly 0 in the
/// first.
const BINS_PER_OCTAVE: f64 = 32.0;
const MIN_LOG2: f64 = -64.0;
const BINS: usize = 128 * 32;

/// A pose: samples at rest.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StillPose {
    /// Time of its first and last sample.
    pub start: f64,
    pub end: f64,
    /// Samples it held, in all.
    pub count: usize,
    /// Mean reading.
    pub mean: [f64; 3],
    /// Rms distance of its samples from their mean.
    pub spread: f64,
    /// The samples kept (evenly spaced, at most 2 × [`POSE_SAMPLES`]).
    #[serde(skip)]
    pub samples: Vec<[f64; 3]>,
}

/// What the detector knows now, for STATUS.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StillState {
    /// The noise (the quiet windows' spread), raw units; none before
    /// [`MIN_WINDOWS`] windows.
    pub noise: Option<f64>,
    /// The largest spread of a still window, raw units.
    pub threshold: Option<f64>,
    /// The field's scale, raw units: the configured units (counts per g),
    /// else the larger of the rms distance of every sample from their
    /// mean and the magnitude of the current window's mean. (Before a
    /// second pose the first is the only one, and its samples spread by
    /// the noise alone; an accelerometer's reading at rest is g plus its
    /// zero-g offset, far below g on any chip.)
    pub field_scale: f64,
    /// Whether the sensor is at rest now (in a pose).
    pub still_now: bool,
    /// Whether the quiet windows spread more than [`MAX_NOISE_FRACTION`]
    /// of the field: the sensor was never at rest.
    pub never_still: bool,
}

/// The streaming detector of still poses.
#[derive(Debug, Clone)]
pub struct StillStream {
    /// The field's magnitude in raw units, when configured.
    unit: Option<f64>,
    window: VecDeque<(f64, [f64; 3])>,
    // Welford's running mean and sum of squares over every sample.
    n: u64,
    mean: [f64; 3],
    m2: f64,
    hist: Vec<u32>,
    windows: u64,
    /// The noise, from `hist`: renewed every [`NOISE_EVERY`] windows (a
    /// scan of the histogram's bins is not done at every sample).
    noise: Option<f64>,
    current: Option<PoseBuilder>,
    poses: VecDeque<StillPose>,
    last_time: Option<f64>,
}

#[derive(Debug, Clone)]
struct PoseBuilder {
    start: f64,
    end: f64,
    count: usize,
    /// The first sample: sums are of the samples less it, so raw counts in
    /// the tens of thousands lose no precision to the squares.
    origin: [f64; 3],
    sum: [f64; 3],
    sum_sq: f64,
    samples: Vec<[f64; 3]>,
    stride: usize,
    skipped: usize,
}

impl PoseBuilder {
    fn new(window: &VecDeque<(f64, [f64; 3])>) -> Self {
        let mut b = PoseBuilder {
            start: window.front().map_or(0.0, |s| s.0),
            end: 0.0,
            count: 0,
            origin: window.front().map_or([0.0; 3], |s| s.1),
            sum: [0.0; 3],
            sum_sq: 0.0,
            samples: Vec::new(),
            stride: 1,
            skipped: 0,
        };
        for &(t, p) in window {
            b.add(t, p);
        }
        b
    }

    fn add(&mut self, t: f64, p: [f64; 3]) {
        self.end = t;
        self.count += 1;
        for ((sum, v), o) in self.sum.iter_mut().zip(p).zip(self.origin) {
            let d = v - o;
            *sum += d;
            self.sum_sq += d * d;
        }
        self.skipped += 1;
        if self.skipped >= self.stride {
            self.skipped = 0;
            self.samples.push(p);
            if self.samples.len() >= 2 * POSE_SAMPLES {
                // Every other one: still evenly spaced, at twice the stride.
                let mut i = 0;
                self.samples.retain(|_| {
                    i += 1;
                    i % 2 == 1
                });
                self.stride *= 2;
            }
        }
    }

    /// Rms distance of the samples from their mean.
    fn spread(&self) -> f64 {
        let c = self.count.max(1) as f64;
        let m2: f64 = self.sum.iter().map(|s| (s / c).powi(2)).sum();
        (self.sum_sq / c - m2).max(0.0).sqrt()
    }

    /// (mean, spread) without copying the samples.
    fn summary(&self) -> ([f64; 3], f64) {
        let c = self.count.max(1) as f64;
        (
            [0, 1, 2].map(|k| self.origin[k] + self.sum[k] / c),
            self.spread(),
        )
    }

    fn pose(&self) -> StillPose {
        let c = self.count.max(1) as f64;
        StillPose {
            start: self.start,
            end: self.end,
            count: self.count,
            mean: [0, 1, 2].map(|k| self.origin[k] + self.sum[k] / c),
            spread: self.spread(),
            samples: self.samples.clone(),
        }
    }
}

impl Default for StillStream {
    fn default() -> Self {
        Self::new(None)
    }
}

impl StillStream {
    /// A detector for a field of magnitude `unit` raw units (counts per g,
    /// `lsb_per_g`), when known.
    pub fn new(unit: Option<f64>) -> Self {
        StillStream {
            unit: unit.filter(|u| u.is_finite() && *u > 0.0),
            window: VecDeque::new(),
            n: 0,
            mean: [0.0; 3],
            m2: 0.0,
            hist: vec![0; BINS],
            windows: 0,
            noise: None,
            current: None,
            poses: VecDeque::new(),
            last_time: None,
        }
    }

    /// Forgets the poses (a recalibration); the noise learnt is kept.
    pub fn clear_poses(&mut self) {
        self.poses.clear();
        self.current = None;
    }

    /// Takes one sample at `time` (seconds). Returns the pose it ended, if
    /// any. Non-finite samples and times are ignored; a time that goes
    /// back or jumps by more than a window ends the pose and restarts the
    /// window.
    pub fn push(&mut self, time: f64, raw: [f64; 3]) -> Option<StillPose> {
        if !time.is_finite() || raw.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let mut ended = None;
        if let Some(last) = self.last_time
            && !(time >= last && time - last <= STILL_WINDOW_S)
        {
            ended = self.end_pose();
            self.window.clear();
        }
        self.last_time = Some(time);
        self.welford(raw);
        self.window.push_back((time, raw));
        while self.window.len() > MAX_WINDOW_SAMPLES
            || self
                .window
                .front()
                .is_some_and(|(t0, _)| time - t0 > STILL_WINDOW_S)
        {
            self.window.pop_front();
        }
        let Some((spread, mean)) = self.full_window() else {
            return ended;
        };
        self.windows += 1;
        self.hist[bin(spread)] += 1;
        if self.windows >= MIN_WINDOWS && (self.windows - MIN_WINDOWS).is_multiple_of(NOISE_EVERY) {
            self.noise = Some(self.quantile(FLOOR_QUANTILE));
        }
        if !self.judged_at_rest(mean, spread) {
            return ended.or_else(|| self.end_pose());
        }
        // Begun under a higher threshold (an early noise estimate from a
        // sensor in motion), a pose is no longer at rest: its quiet part
        // starts here.
        let restart = self.current.as_ref().is_some_and(|b| {
            let (mean, spread) = b.summary();
            !self.judged_at_rest(mean, spread)
        });
        match &mut self.current {
            Some(b) if !restart => b.add(time, raw),
            _ => self.current = Some(PoseBuilder::new(&self.window)),
        }
        ended
    }

    fn end_pose(&mut self) -> Option<StillPose> {
        let pose = self.current.take()?.pose();
        if self.poses.len() >= MAX_POSES {
            self.poses.pop_front();
        }
        self.poses.push_back(pose.clone());
        Some(pose)
    }

    fn welford(&mut self, p: [f64; 3]) {
        self.n += 1;
        let n = self.n as f64;
        let mut d2 = 0.0;
        for (mean, v) in self.mean.iter_mut().zip(p) {
            let d = v - *mean;
            *mean += d / n;
            d2 += d * (v - *mean);
        }
        self.m2 += d2;
    }

    /// The window's spread and mean, when it spans a whole window: at
    /// least [`MIN_WINDOW_SAMPLES`], over (len − 1)/len of
    /// [`STILL_WINDOW_S`] (what `len` evenly spaced samples of a 0.5 s
    /// window span).
    fn full_window(&self) -> Option<(f64, [f64; 3])> {
        let len = self.window.len();
        if len < MIN_WINDOW_SAMPLES {
            return None;
        }
        let span = self.window.back()?.0 - self.window.front()?.0;
        // A sensor faster than 2 kHz fills the window's cap first: then the
        // window is its cap, as find_still's is.
        if len < MAX_WINDOW_SAMPLES && span * len as f64 / (len - 1) as f64 + 1e-9 < STILL_WINDOW_S
        {
            return None;
        }
        let mean = self.window_mean();
        let ss: f64 = self
            .window
            .iter()
            .map(|(_, p)| (0..3).map(|j| (p[j] - mean[j]).powi(2)).sum::<f64>())
            .sum();
        Some(((ss / len as f64).sqrt(), mean))
    }

    fn window_mean(&self) -> [f64; 3] {
        let k = self.window.len().max(1) as f64;
        let mut mean = [0.0; 3];
        for (_, p) in &self.window {
            for j in 0..3 {
                mean[j] += p[j] / k;
            }
        }
        mean
    }

    /// Whether a pose is being held now.
    pub fn still_now(&self) -> bool {
        self.current.is_some()
    }

    /// The noise, the threshold and whether the sensor is at rest now.
    pub fn state(&self) -> StillState {
        let field_scale = self.scale_at(self.window_mean());
        let threshold = self.noise.map(|n| threshold(n, field_scale));
        StillState {
            noise: self.noise,
            threshold,
            field_scale,
            still_now: self.still_now(),
            never_still: self
                .noise
                .is_some_and(|n| !(n <= MAX_NOISE_FRACTION * field_scale)),
        }
    }

    /// The field's scale about readings whose mean is `mean` (see
    /// [`StillState::field_scale`]).
    fn scale_at(&self, mean: [f64; 3]) -> f64 {
        self.unit.unwrap_or_else(|| {
            let spread = if self.n > 0 {
                (self.m2.max(0.0) / self.n as f64).sqrt()
            } else {
                0.0
            };
            spread.max((mean[0] * mean[0] + mean[1] * mean[1] + mean[2] * mean[2]).sqrt())
        })
    }

    /// The upper edge of the bin holding the `q` quantile of the spreads.
    fn quantile(&self, q: f64) -> f64 {
        let target = ((self.windows as f64) * q).ceil().max(1.0) as u64;
        let mut seen = 0u64;
        for (k, &c) in self.hist.iter().enumerate() {
            seen += u64::from(c);
            if seen >= target {
                return bin_upper(k);
            }
        }
        bin_upper(BINS - 1)
    }

    /// The poses ended so far that the current threshold still finds at
    /// rest, and the one being held now when it spans a window.
    pub fn poses(&self) -> Vec<StillPose> {
        self.poses
            .iter()
            .cloned()
            .chain(self.current.as_ref().map(PoseBuilder::pose))
            .filter(|p| self.at_rest(p))
            .collect()
    }

    /// How many poses [`StillStream::poses`] gives, without copying them.
    pub fn pose_count(&self) -> usize {
        let current = self.current.as_ref().map(PoseBuilder::summary);
        self.poses
            .iter()
            .map(|p| (p.mean, p.spread))
            .chain(current)
            .filter(|&(mean, spread)| self.judged_at_rest(mean, spread))
            .count()
    }

    fn at_rest(&self, p: &StillPose) -> bool {
        self.judged_at_rest(p.mean, p.spread)
    }

    /// Whether a pose of this mean and spread is at rest by the current
    /// noise: the noise is a sensor's at rest, and the spread within the
    /// threshold about the pose's own scale.
    fn judged_at_rest(&self, mean: [f64; 3], spread: f64) -> bool {
        self.noise.is_some_and(|noise| {
            let scale = self.scale_at(mean);
            noise <= MAX_NOISE_FRACTION * scale && spread <= threshold(noise, scale)
        })
    }
}

/// The largest spread of a still window, as find_still's: the noise
/// `NOISE_FACTOR` times over, beside a hand turning at HAND_STILL_DEG_S,
/// which sweeps the field through this angle in one window (an rms
/// spread of r·a/√12).
fn threshold(noise: f64, scale: f64) -> f64 {
    let sweep = HAND_STILL_DEG_S.to_radians() * STILL_WINDOW_S;
    let motion = scale * sweep / 12f64.sqrt();
    ((NOISE_FACTOR * noise).powi(2) + motion.powi(2)).sqrt()
}

fn bin(spread: f64) -> usize {
    if !(spread > 0.0) {
        return 0;
    }
    let k = ((spread.log2() - MIN_LOG2) * BINS_PER_OCTAVE).floor();
    if k < 1.0 {
        1
    } else {
        (k as usize).min(BINS - 1)
    }
}

fn bin_upper(k: usize) -> f64 {
    if k == 0 {
        return 0.0;
    }
    (MIN_LOG2 + (k as f64 + 1.0) / BINS_PER_OCTAVE).exp2()
}
