//! The rotation buffer: one per sensor, it collects samples until the
//! sensor has turned one full rotation in a constant field, the way
//! ArduPilot's compass calibration collects until its completion mask is
//! full. Pure: no I/O, no clock; time (and, optionally, a gyro's integrated
//! angle) comes in with each sample.
//!
//! # How a full rotation is judged
//! A rotation is complete when, around the running centre (below), all of
//! these hold:
//! - **every heading is covered**: a heading counts as covered by any one
//!   sample on the circle (within [`RING_BAND`] of its radius), as
//!   ArduPilot's completion mask counts a section with one sample; the
//!   largest gap between covered headings is at most `max_gap_deg`
//!   (default [`DEFAULT_MAX_GAP_DEG`], 30°);
//! - **the sensor turned once round in one direction**: the net heading
//!   swept, the sum of the increments between consecutive samples on the
//!   circle (each wrapped to [-180°, 180°)), reaches 360° less the allowed
//!   gap (330° by default) in absolute value, both since the first sample
//!   and since the last reversal (a retreat of more than [`REVERSAL_DEG`]).
//!   Going back and forth adds and takes away: a swing about where the
//!   buffer started never gets there, however many headings it covers; a
//!   half turn gets to 180°; a wandering reading that happens to circle
//!   turns back on its way;
//! - **around a plausible offset**: the circle's centre lies within
//!   [`MAX_CENTRE_OVER_RADIUS`] radii of the zero reading (a sensor that
//!   slides without turning sees its readings wander by a small part of
//!   their value, so any loop they make is far from zero);
//! - **enough samples**: at least [`MIN_TURN_SAMPLES`] on the circle (the
//!   turn gate's own minimum), and at least [`MIN_RING_FRACTION`] of all
//!   samples on the circle;
//! - **the readings moved**: their spread exceeds `still_ratio` times their
//!   noise (a still sensor's noise cloud has "headings" too);
//! - **the gyro agrees**, only when `use_gyro` is on (it is off by default)
//!   and the sensor passes a gyro angle (see
//!   [`RotationBuffer::push_turned`]): its integrated angle since the first
//!   sample has also reached the net turn needed. The gyro alone never
//!   completes a rotation (an uncalibrated MEMS gyro drifts by up to ±20°/s,
//!   MPU-6050 datasheet, so a swing plus drift could integrate to a turn):
//!   it can only hold one back, e.g. when a magnet is carried round a still
//!   sensor. Off by default because a gyro whose axis or scale is
//!   configured wrong would then hold back every rotation, while the heading
//!   check of each CALIBRATION (information only) already tells the user;
//!   the readings' own net turn completes the recorded turns at one turn
//!   with or without it.
//!
//! None of this counts samples per sector, so it does not depend on the
//! sample rate: a 10 Hz robot turn with a few samples per 10° completes as
//! a 100 Hz hand turn does, on one turn.
//!
//! Headings are measured around a running centre: the circle that fits the
//! samples best in Kåsa's algebraic sense (the same fit as
//! [`crate::model::heading::circle_centre`]), kept as running sums so each
//! sample updates it in O(1). Why this centre and not the others:
//! - the min/max box is exact only once the turn is complete: on a partial
//!   arc it puts the centre near the chord and inflates the coverage (a
//!   quarter turn reads as half), so the progress a person watches would lie;
//! - Kåsa's centre of a circular arc is exact on any arc, so progress is
//!   right during the turn; on a full turn of an ellipse of the paper's
//!   family it is exact by symmetry, and on a partial ellipse arc it is off
//!   by a fraction of (gain ratio - 1) of the radius, which the recount fixes
//!   once the turn closes;
//! - the paper's ellipse fit itself is unstable on short arcs (it turns
//!   into hyperbolas).
//!
//! Samples are placed (into 1° heading bins and the net turn) around a
//! reference centre. When the running centre (or radius) moves by more than
//! [`RECOUNT_MOVE`] of the radius, every held sample is recounted around it,
//! at most once per max(16, n/8) samples so the cost stays O(1) amortised;
//! before the rotation is declared complete the counts are always redone
//! around a centre within [`EXACT_MOVE`] of the current one. So headings
//! covered, or a turn swept, around a wrong early centre never count.

use serde::{Deserialize, Serialize};

mod circle;

use circle::{Frame, Moments, wrap_deg};

pub use crate::model::turn::MIN_TURN_SAMPLES;

/// Samples whose distance from the centre is within this band of the
/// circle's rms radius count as "on the circle". Wide enough for an
/// ellipse of gain ratio 2 (its radii span 0.63 to 1.26 of the rms), narrow
/// enough that most of a noise cloud falls outside.
pub const RING_BAND: (f64, f64) = (0.5, 1.5);
/// At least this fraction of the samples must lie on the circle: a noise
/// cloud puts about 2/3 there, a real turn all of them.
pub const MIN_RING_FRACTION: f64 = 0.8;
/// Recount when the centre or radius moved by this fraction of the radius
/// (a centre off by 5 % of the radius shifts headings by at most ~3°, a
/// tenth of the default gap).
pub const RECOUNT_MOVE: f64 = 0.05;
/// A rotation is only declared complete with counts made around a centre
/// within this fraction of the radius of the current one (< 0.6° of heading).
pub const EXACT_MOVE: f64 = 0.01;
/// A heading that retreats this far from its furthest point is a reversal;
/// large enough that noise on the circle never makes one.
pub const REVERSAL_DEG: f64 = 30.0;
/// Headings are counted only once the arc held bends beyond its noise: its
/// sagitta (the largest distance of a sample from the chord through the
/// first and the latest sample) must be at least this many noise
/// deviations. On a shorter, flatter arc the circle's centre is set by the
/// noise rather than by the curvature (Kåsa's centre of a 10° arc with
/// noise of a few counts lands anywhere along its axis), and headings
/// counted around it would show more of the turn done than is, then fall
/// back once the centre settles. Ten deviations put the centre's error on
/// the arc's axis at a few percent of the radius for the dozen samples such
/// an arc holds, within [`RECOUNT_MOVE`].
pub const ARC_SAGITTA_NOISE: f64 = 10.0;
/// Default largest gap between covered headings, in degrees. The fit needs
/// its samples all round: its coverage check (and the acceptance's
/// `min_coverage_deg`) asks for 300° of the fitted headings, a largest gap
/// of 60° ([`crate::model::fit::DEFAULT_MIN_COVERAGE_DEG`]). The buffer sees
/// raw headings around a circle's centre; the fitted model maps them onto
/// its own with a local stretch of at most the gain ratio, which the
/// acceptance bounds by 2 (`max_scale_ratio`). So a raw gap of 60° / 2 =
/// 30° still leaves the fit its 300°. It is also 360° / 12, the spacing of
/// the turn gate's fewest samples ([`MIN_TURN_SAMPLES`]) spread evenly.
pub const DEFAULT_MAX_GAP_DEG: f64 = 30.0;
/// Farthest the circle's centre may lie from the zero reading, in radii.
/// A sensor turned in a field traces a circle around its offset; the offset
/// of a real sensor is bounded: ArduPilot accepts compass offsets up to
/// 1800 mGauss (COMPASS_OFFS_MAX) and fields down to 150 mGauss
/// (FIELD_RADIUS_MIN), a ratio of 12. A loop of readings much farther out
/// than that is a sensor that slid through a field that changes (readings
/// wandering by a fraction of their value), not one that turned.
pub const MAX_CENTRE_OVER_RADIUS: f64 = 12.0;
/// Bounds of `max_gap_deg`: 2° is twice the resolution of the heading bins;
/// beyond 60° the fit's default coverage check could never pass.
const MAX_GAP_BOUNDS: (f64, f64) = (2.0, 60.0);
/// Headings are kept as 1° bins: enough to measure gaps of a few degrees.
const HEADING_BINS: usize = 360;
/// E|d2| / sigma for white noise: the second difference of white noise of
/// standard deviation sigma is N(0, 6 sigma^2), whose mean absolute value is
/// sqrt(6) * sqrt(2/pi) * sigma.
const D2_PER_SIGMA: f64 = 1.954_410_047_611_31;

/// How the rotation buffer decides a rotation is complete or rejected.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RotationConfig {
    /// Largest gap between covered headings, in degrees; the net turn needed
    /// is 360° less this.
    pub max_gap_deg: f64,
    /// Most samples held; a rotation not complete by then is rejected.
    pub max_samples: usize,
    /// Seconds from the first sample within which the rotation must complete.
    pub timeout_s: f64,
    /// Seconds after which readings that have not moved beyond their noise
    /// are rejected as "not turning" and the buffer restarts, so a sensor
    /// that waits before it turns does not spend the whole timeout waiting.
    pub still_timeout_s: f64,
    /// The readings "move" when their spread on some axis exceeds this many
    /// standard deviations of their noise.
    pub still_ratio: f64,
    /// When the sensor has a heading-check gyro, a rotation also needs the
    /// gyro's integrated angle to reach the net turn.
    pub use_gyro: bool,
}

impl Default for RotationConfig {
    /// - 30° gap: see [`DEFAULT_MAX_GAP_DEG`]; so 330° of net turn.
    /// - 20000 samples: a 60 s turn at 3 ms, 320 kB per axis.
    /// - 60 s: a person turning a robot by hand needs 10-20 s, a robot
    ///   turning slowly with stops 30 s; 60 s gives a second try without
    ///   restarting.
    /// - 10 s still: the time someone needs to pick the robot up; after it,
    ///   a still buffer restarts so the turn gets its full timeout.
    /// - 20 noise deviations: n white-noise readings spread over about
    ///   2*sqrt(2 ln n) deviations, ~9 for 20000; and a field below 10
    ///   deviations (radius) could not meet the acceptance's 5 % rms anyway.
    /// - use_gyro: off; see the module documentation.
    fn default() -> Self {
        RotationConfig {
            max_gap_deg: DEFAULT_MAX_GAP_DEG,
            max_samples: 20_000,
            timeout_s: 60.0,
            still_timeout_s: 10.0,
            still_ratio: 20.0,
            use_gyro: false,
        }
    }
}

impl RotationConfig {
    /// Checks the configuration; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        let (lo, hi) = MAX_GAP_BOUNDS;
        if !(self.max_gap_deg.is_finite() && (lo..=hi).contains(&self.max_gap_deg)) {
            return Err(format!(
                "max_gap_deg must be between {lo} and {hi} degrees, got {}",
                self.max_gap_deg
            ));
        }
        if !(MIN_TURN_SAMPLES..=10_000_000).contains(&self.max_samples) {
            return Err(format!(
                "max_samples must be between {MIN_TURN_SAMPLES} and 10000000, got {}",
                self.max_samples
            ));
        }
        if !(self.timeout_s.is_finite() && self.timeout_s > 0.0) {
            return Err(format!(
                "timeout_s must be a positive number of seconds, got {}",
                self.timeout_s
            ));
        }
        if !(self.still_timeout_s.is_finite() && self.still_timeout_s > 0.0) {
            return Err(format!(
                "still_timeout_s must be a positive number of seconds, got {}",
                self.still_timeout_s
            ));
        }
        if !(self.still_ratio.is_finite() && self.still_ratio >= 1.0) {
            return Err(format!(
                "still_ratio must be at least 1 (noise standard deviations), got {}",
                self.still_ratio
            ));
        }
        Ok(())
    }

    /// The net heading a rotation must sweep, in degrees: 360° less the
    /// largest gap allowed (a turn that stops that short of its start has
    /// left exactly that gap).
    pub fn turn_needed_deg(&self) -> f64 {
        360.0 - self.max_gap_deg
    }
}

/// Where the buffer is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum RotationState {
    /// No samples yet.
    Empty,
    /// Collecting a rotation.
    Collecting,
    /// A full rotation is held, waiting for [`RotationBuffer::take`].
    Complete,
}

/// How far the rotation has got, as ArduPilot reports its completion mask.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Progress {
    /// Headings covered, as a percentage of the circle: 100 less the gaps
    /// between covered headings wider than `max_gap_deg`.
    pub coverage_pct: f64,
    /// Headings still missing (the gaps wider than `max_gap_deg`), as
    /// [start, end] in degrees counter-clockwise from the raw +x axis around
    /// the running centre; a range whose end is smaller than its start wraps
    /// through 0° (e.g. [350, 20]).
    pub missing_sectors: Vec<[f64; 2]>,
    /// Samples held.
    pub samples: usize,
    /// Seconds from the first sample held to the last.
    pub elapsed_s: f64,
    pub state: RotationState,
    /// Samples ignored since the buffer was made: non-finite values, or a
    /// time earlier than the previous sample's.
    pub ignored: u64,
    /// Heading swept by the readings in one direction, in degrees,
    /// counter-clockwise from raw x to raw y positive: since the first
    /// sample, or since the last reversal of more than [`REVERSAL_DEG`].
    pub turned_deg: f64,
    /// The net turn a rotation needs, in degrees (either direction).
    pub turn_needed_deg: f64,
    /// The largest gap between covered headings, in degrees (360 when none
    /// or one is covered).
    pub largest_gap_deg: f64,
    /// The gyro's integrated angle since the first sample, in degrees, when
    /// the sensor passes one.
    pub gyro_turned_deg: Option<f64>,
}

/// What a sample did to the buffer.
#[derive(Debug, Clone, PartialEq)]
pub enum RotationEvent {
    Collecting,
    /// A full rotation is held: call [`RotationBuffer::take`].
    Complete,
    /// The rotation failed for the reason given, in words for a person;
    /// the buffer has already restarted.
    Rejected {
        reason: String,
    },
}

/// Which limit ended a rotation that did not complete.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Limit {
    Timeout,
    Samples,
}

/// The gaps between neighbouring covered 1° bins: (the covered bin a gap
/// starts after, its width in degrees from bin to bin). A single covered
/// bin has one gap of 360°; none, no gaps.
fn bin_gaps(bins: &[u32]) -> Vec<(usize, usize)> {
    let covered: Vec<usize> = (0..bins.len()).filter(|&i| bins[i] > 0).collect();
    let (Some(&first), Some(&last)) = (covered.first(), covered.last()) else {
        return Vec::new();
    };
    let mut gaps: Vec<(usize, usize)> = covered.windows(2).map(|w| (w[0], w[1] - w[0])).collect();
    gaps.push((last, first + bins.len() - last));
    gaps
}

/// Whether every gap of [`bin_gaps`] is at most `max_gap` degrees, the
/// same answer without building them: one pass over the bins that stops
/// at the first gap too wide (the rotation's completion asks it often).
fn gaps_within(bins: &[u32], max_gap: f64) -> bool {
    let mut covered = (0..bins.len()).filter(|&i| bins[i] > 0);
    let Some(first) = covered.next() else {
        return true;
    };
    let mut last = first;
    for i in covered {
        if (i - last) as f64 > max_gap {
            return false;
        }
        last = i;
    }
    (first + bins.len() - last) as f64 <= max_gap
}

/// Collects one sensor's samples until they make a full rotation.
#[derive(Debug, Clone)]
pub struct RotationBuffer {
    config: RotationConfig,
    t: Vec<f64>,
    x: Vec<f64>,
    y: Vec<f64>,
    anchor: (f64, f64),
    moments: Moments,
    /// xmin, xmax, ymin, ymax.
    bounds: [f64; 4],
    /// Sums of |second difference| per axis, and how many.
    d2_sum: [f64; 2],
    d2_n: usize,
    /// Samples on the circle per 1° of heading, around `reference`.
    bins: Vec<u32>,
    /// Samples on the circle around `reference`.
    on_ring: usize,
    /// Net heading swept around `reference` (the unwrapped heading, 0 at
    /// the first sample on the circle), and the last heading on the circle
    /// it was summed to.
    net_deg: f64,
    last_heading: Option<f64>,
    /// The current sweep: its direction (0 until the heading first moved
    /// [`REVERSAL_DEG`] from where it started), where it started (the last
    /// reversal, or the lowest/highest point before the first), and its
    /// furthest point.
    direction: i8,
    sweep_from: f64,
    extreme: f64,
    reference: Option<Frame>,
    since_recount: usize,
    /// The sample count at which [`RotationBuffer::arc_determined`] looks
    /// again (every n/16 samples: O(1) amortised).
    next_arc_check: usize,
    /// The gyro's integrated angle at the first and the last sample that
    /// carried one.
    gyro: Option<(f64, f64)>,
    complete: bool,
    ignored: u64,
}

impl RotationBuffer {
    /// A buffer for `config`. An invalid configuration (see
    /// [`RotationConfig::validate`]) is clamped into range rather than
    /// panicking; callers validate first to tell the user.
    pub fn new(config: RotationConfig) -> Self {
        let mut config = config;
        let defaults = RotationConfig::default();
        config.max_gap_deg = if config.max_gap_deg.is_finite() {
            config.max_gap_deg.clamp(MAX_GAP_BOUNDS.0, MAX_GAP_BOUNDS.1)
        } else {
            defaults.max_gap_deg
        };
        config.max_samples = config.max_samples.clamp(MIN_TURN_SAMPLES, 10_000_000);
        if !(config.timeout_s.is_finite() && config.timeout_s > 0.0) {
            config.timeout_s = defaults.timeout_s;
        }
        if !(config.still_timeout_s.is_finite() && config.still_timeout_s > 0.0) {
            config.still_timeout_s = defaults.still_timeout_s;
        }
        if !(config.still_ratio.is_finite() && config.still_ratio >= 1.0) {
            config.still_ratio = defaults.still_ratio;
        }
        RotationBuffer {
            config,
            t: Vec::new(),
            x: Vec::new(),
            y: Vec::new(),
            anchor: (0.0, 0.0),
            moments: Moments::default(),
            bounds: [0.0; 4],
            d2_sum: [0.0; 2],
            d2_n: 0,
            bins: vec![0; HEADING_BINS],
            on_ring: 0,
            net_deg: 0.0,
            last_heading: None,
            direction: 0,
            sweep_from: 0.0,
            extreme: 0.0,
            reference: None,
            since_recount: 0,
            next_arc_check: 0,
            gyro: None,
            complete: false,
            ignored: 0,
        }
    }

    /// The configuration in use (after clamping).
    pub fn config(&self) -> &RotationConfig {
        &self.config
    }

    /// Adds a sample (time in seconds, raw x and y counts) without a gyro.
    /// O(1) amortised. See [`push_turned`](Self::push_turned).
    pub fn push(&mut self, time: f64, x: f64, y: f64) -> RotationEvent {
        self.push_turned(time, x, y, None)
    }

    /// Adds a sample with, when the sensor has a gyro about the turn's
    /// axis, the gyro's integrated angle at the sample's time in degrees
    /// (from any origin, either sign: only its change since the buffer's
    /// first sample counts). O(1) amortised.
    ///
    /// Non-finite values and times earlier than the previous sample's are
    /// ignored (counted in [`Progress::ignored`]); a non-finite angle is
    /// taken as none. Once `Complete` is returned the buffer holds that
    /// rotation and ignores further samples, still answering `Complete`,
    /// until [`take`](Self::take) or [`reset`](Self::reset).
    pub fn push_turned(
        &mut self,
        time: f64,
        x: f64,
        y: f64,
        gyro_deg: Option<f64>,
    ) -> RotationEvent {
        if self.complete {
            return RotationEvent::Complete;
        }
        if !(time.is_finite() && x.is_finite() && y.is_finite()) {
            self.ignored += 1;
            return RotationEvent::Collecting;
        }
        let gyro_deg = gyro_deg.filter(|g| g.is_finite());
        if let (Some(&first), Some(&last)) = (self.t.first(), self.t.last()) {
            if time < last {
                self.ignored += 1;
                return RotationEvent::Collecting;
            }
            let elapsed = time - first;
            if elapsed > self.config.timeout_s {
                // A rotation that completes on its last samples but was not
                // yet recounted exactly still counts.
                if self.try_complete(true) {
                    self.complete = true;
                    return RotationEvent::Complete;
                }
                let reason = self.failure(Limit::Timeout);
                self.restart_with(time, x, y, gyro_deg);
                return RotationEvent::Rejected { reason };
            }
            if elapsed >= self.config.still_timeout_s && !self.turning() {
                let reason = self.not_turning();
                self.restart_with(time, x, y, gyro_deg);
                return RotationEvent::Rejected { reason };
            }
        }
        self.ingest(time, x, y, gyro_deg);
        if self.try_complete(false) {
            self.complete = true;
            return RotationEvent::Complete;
        }
        if self.t.len() >= self.config.max_samples {
            let reason = self.failure(Limit::Samples);
            self.clear();
            return RotationEvent::Rejected { reason };
        }
        RotationEvent::Collecting
    }

    /// How far the rotation has got. O(360).
    pub fn progress(&self) -> Progress {
        let max_gap = self.config.max_gap_deg;
        let gaps = if self.reference.is_some() {
            bin_gaps(&self.bins)
        } else {
            Vec::new()
        };
        let largest = gaps.iter().map(|g| g.1).max().unwrap_or(HEADING_BINS) as f64;
        let (missing, missing_deg) = if gaps.is_empty() {
            (vec![[0.0, 360.0]], 360.0)
        } else {
            let mut ranges = Vec::new();
            let mut width = 0.0;
            for &(after, gap) in &gaps {
                if gap as f64 > max_gap {
                    let start = ((after + 1) % HEADING_BINS) as f64;
                    let end = match (after + gap) % HEADING_BINS {
                        0 => 360.0,
                        e => e as f64,
                    };
                    ranges.push([start, end]);
                    width += (gap - 1) as f64;
                }
            }
            // Ranges in order of their start, so a gap through 0° comes last.
            ranges.sort_by(|a, b| a[0].total_cmp(&b[0]));
            (ranges, width)
        };
        Progress {
            coverage_pct: 100.0 * (1.0 - missing_deg / 360.0),
            missing_sectors: missing,
            samples: self.t.len(),
            elapsed_s: self.elapsed(),
            state: if self.complete {
                RotationState::Complete
            } else if self.t.is_empty() {
                RotationState::Empty
            } else {
                RotationState::Collecting
            },
            ignored: self.ignored,
            turned_deg: self.swept(),
            turn_needed_deg: self.config.turn_needed_deg(),
            largest_gap_deg: largest,
            gyro_turned_deg: self.gyro_turned(),
        }
    }

    /// The samples held (t, x, y) — on `Complete`, those of the rotation —
    /// and the buffer restarts empty.
    pub fn take(&mut self) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        // Room for a rotation like this one (up to ROOM samples: a buffer
        // that may never collect again keeps little), so the next grows
        // without copying itself over and over.
        const ROOM: usize = 4096;
        let room = self.t.len().min(ROOM);
        let taken = (
            std::mem::replace(&mut self.t, Vec::with_capacity(room)),
            std::mem::replace(&mut self.x, Vec::with_capacity(room)),
            std::mem::replace(&mut self.y, Vec::with_capacity(room)),
        );
        self.clear();
        taken
    }

    /// Drops every sample and starts collecting anew (keeps the count of
    /// ignored samples, which describes the stream, not the rotation).
    pub fn reset(&mut self) {
        self.clear();
    }

    fn clear(&mut self) {
        self.t.clear();
        self.x.clear();
        self.y.clear();
        self.anchor = (0.0, 0.0);
        self.moments = Moments::default();
        self.bounds = [0.0; 4];
        self.d2_sum = [0.0; 2];
        self.d2_n = 0;
        self.bins.iter_mut().for_each(|c| *c = 0);
        self.on_ring = 0;
        self.net_deg = 0.0;
        self.last_heading = None;
        self.direction = 0;
        self.sweep_from = 0.0;
        self.extreme = 0.0;
        self.reference = None;
        self.since_recount = 0;
        self.next_arc_check = 0;
        self.gyro = None;
        self.complete = false;
    }

    fn restart_with(&mut self, time: f64, x: f64, y: f64, gyro_deg: Option<f64>) {
        self.clear();
        self.ingest(time, x, y, gyro_deg);
    }

    fn elapsed(&self) -> f64 {
        match (self.t.first(), self.t.last()) {
            (Some(first), Some(last)) => last - first,
            _ => 0.0,
        }
    }

    fn gyro_turned(&self) -> Option<f64> {
        self.gyro.map(|(first, last)| last - first)
    }

    fn ingest(&mut self, time: f64, x: f64, y: f64, gyro_deg: Option<f64>) {
        let n = self.t.len();
        if n == 0 {
            self.anchor = (x, y);
            self.bounds = [x, x, y, y];
        } else {
            self.bounds[0] = self.bounds[0].min(x);
            self.bounds[1] = self.bounds[1].max(x);
            self.bounds[2] = self.bounds[2].min(y);
            self.bounds[3] = self.bounds[3].max(y);
        }
        if n >= 2 {
            self.d2_sum[0] += (x - 2.0 * self.x[n - 1] + self.x[n - 2]).abs();
            self.d2_sum[1] += (y - 2.0 * self.y[n - 1] + self.y[n - 2]).abs();
            self.d2_n += 1;
        }
        if let Some(g) = gyro_deg {
            self.gyro = Some(match self.gyro {
                Some((first, _)) => (first, g),
                None => (g, g),
            });
        }
        self.t.push(time);
        self.x.push(x);
        self.y.push(y);
        self.moments.add(x - self.anchor.0, y - self.anchor.1);
        self.since_recount += 1;

        let Some(frame) = self.frame() else {
            return;
        };
        if self.reference.is_none() && !self.arc_determined() {
            return;
        }
        match self.reference {
            // (The count first: it is cheaper, and nearly always decides.)
            Some(reference)
                if self.since_recount < (self.t.len() / 8).max(16)
                    || reference.within(&frame, RECOUNT_MOVE) =>
            {
                self.place(&reference, x, y);
            }
            _ => self.recount(frame),
        }
    }

    /// Whether the arc held bends enough beyond its noise for its centre
    /// to mean something (see [`ARC_SAGITTA_NOISE`]). Looked at every n/16
    /// samples, so O(1) amortised; false until then.
    fn arc_determined(&mut self) -> bool {
        let n = self.t.len();
        if n < self.next_arc_check || self.d2_n == 0 {
            return false;
        }
        self.next_arc_check = n + (n / 16).max(1);
        let (Some(&x0), Some(&y0), Some(&x1), Some(&y1)) =
            (self.x.first(), self.y.first(), self.x.last(), self.y.last())
        else {
            return false;
        };
        let [sx, sy] = self.noise();
        let sigma = sx.max(sy);
        let (dx, dy) = (x1 - x0, y1 - y0);
        let chord = dx.hypot(dy);
        // Distance from the chord's line; from the first sample when the
        // latest has come back to it (a closed turn).
        let sagitta = self
            .x
            .iter()
            .zip(&self.y)
            .map(|(&x, &y)| {
                let (u, v) = (x - x0, y - y0);
                if chord > sigma {
                    (u * dy - v * dx).abs() / chord
                } else {
                    u.hypot(v)
                }
            })
            .fold(0.0, f64::max);
        sagitta.is_finite() && sagitta > ARC_SAGITTA_NOISE * sigma
    }

    /// The running centre, in absolute coordinates.
    fn frame(&self) -> Option<Frame> {
        let (cu, cv, radius) = self.moments.circle()?;
        Some(Frame {
            cx: self.anchor.0 + cu,
            cy: self.anchor.1 + cv,
            radius,
        })
    }

    fn place(&mut self, frame: &Frame, x: f64, y: f64) {
        if let Some(h) = frame.heading_deg(x, y) {
            let i = (h as usize).min(HEADING_BINS - 1);
            self.bins[i] = self.bins[i].saturating_add(1);
            self.on_ring += 1;
            if let Some(last) = self.last_heading {
                self.net_deg += wrap_deg(h - last);
                self.follow_sweep();
            }
            self.last_heading = Some(h);
        }
    }

    /// Moves the current sweep on to `net_deg`: a retreat of
    /// [`REVERSAL_DEG`] from the furthest point starts a new sweep there.
    fn follow_sweep(&mut self) {
        let u = self.net_deg;
        match self.direction {
            0 => {
                // Before the first sweep: it starts from the furthest point
                // on the side it then leaves.
                if u - self.sweep_from.min(self.extreme) >= REVERSAL_DEG {
                    self.sweep_from = self.sweep_from.min(self.extreme);
                    self.direction = 1;
                    self.extreme = u;
                } else if self.sweep_from.max(self.extreme) - u >= REVERSAL_DEG {
                    self.sweep_from = self.sweep_from.max(self.extreme);
                    self.direction = -1;
                    self.extreme = u;
                } else {
                    // Keep the lowest in sweep_from, the highest in extreme.
                    self.sweep_from = self.sweep_from.min(u);
                    self.extreme = self.extreme.max(u);
                }
            }
            1 if u > self.extreme => self.extreme = u,
            1 if self.extreme - u >= REVERSAL_DEG => {
                self.sweep_from = self.extreme;
                self.direction = -1;
                self.extreme = u;
            }
            -1 if u < self.extreme => self.extreme = u,
            -1 if u - self.extreme >= REVERSAL_DEG => {
                self.sweep_from = self.extreme;
                self.direction = 1;
                self.extreme = u;
            }
            _ => {}
        }
    }

    /// The heading swept in one direction since the last reversal (or the
    /// start), signed.
    fn swept(&self) -> f64 {
        if self.direction == 0 {
            // Either way from the start; the larger is the sweep so far.
            let (down, up) = (self.net_deg - self.sweep_from, self.net_deg - self.extreme);
            if down.abs() >= up.abs() { down } else { up }
        } else {
            self.net_deg - self.sweep_from
        }
    }

    /// Recounts every held sample around `frame`: O(n), rare (see the
    /// module documentation).
    fn recount(&mut self, frame: Frame) {
        self.bins.iter_mut().for_each(|c| *c = 0);
        self.on_ring = 0;
        self.net_deg = 0.0;
        self.last_heading = None;
        self.direction = 0;
        self.sweep_from = 0.0;
        self.extreme = 0.0;
        for i in 0..self.t.len() {
            let (x, y) = (self.x[i], self.y[i]);
            self.place(&frame, x, y);
        }
        self.reference = Some(frame);
        self.since_recount = 0;
    }

    /// Noise standard deviation per axis, from second differences (which a
    /// smooth turn barely moves, unlike first differences).
    fn noise(&self) -> [f64; 2] {
        if self.d2_n == 0 {
            return [0.0; 2];
        }
        let n = self.d2_n as f64;
        [
            self.d2_sum[0] / n / D2_PER_SIGMA,
            self.d2_sum[1] / n / D2_PER_SIGMA,
        ]
    }

    fn spread(&self) -> [f64; 2] {
        if self.t.is_empty() {
            return [0.0; 2];
        }
        [
            self.bounds[1] - self.bounds[0],
            self.bounds[3] - self.bounds[2],
        ]
    }

    /// Whether the readings moved well beyond their noise on some axis.
    fn turning(&self) -> bool {
        let noise = self.noise();
        let spread = self.spread();
        (0..2).any(|k| spread[k] > 0.0 && spread[k] > self.config.still_ratio * noise[k])
    }

    /// Whether the held samples make a full rotation; recounts around the
    /// current centre first if the counts were made around an older one
    /// (always when `force`, else at most once per max(1, n/32) samples).
    fn try_complete(&mut self, force: bool) -> bool {
        if !self.complete_around_reference() || !self.turning() {
            return false;
        }
        let Some(frame) = self.frame() else {
            return false;
        };
        let exact = self.reference.is_some_and(|r| r.within(&frame, EXACT_MOVE));
        if exact {
            return true;
        }
        if !force && self.since_recount < (self.t.len() / 32).max(1) {
            return false;
        }
        self.recount(frame);
        self.complete_around_reference()
    }

    /// Whether the gyro, if it is used and the sensor passed one, turned as
    /// far as the readings must.
    fn gyro_agrees(&self) -> bool {
        !self.config.use_gyro
            || self
                .gyro_turned()
                .is_none_or(|g| g.abs() >= self.config.turn_needed_deg())
    }

    /// The rule of the module documentation, on the counts around the
    /// reference; the O(360) gap last, once the O(1) parts hold.
    fn complete_around_reference(&self) -> bool {
        // The counts first: they are cheaper, and until the turn is done
        // they decide.
        self.on_ring >= MIN_TURN_SAMPLES
            && self.on_ring as f64 >= MIN_RING_FRACTION * self.t.len() as f64
            && self.net_deg.abs() >= self.config.turn_needed_deg()
            && self.swept().abs() >= self.config.turn_needed_deg()
            && self
                .reference
                .is_some_and(|r| r.offset_ratio() <= MAX_CENTRE_OVER_RADIUS)
            && self.gyro_agrees()
            && gaps_within(&self.bins, self.config.max_gap_deg)
    }

    fn not_turning(&self) -> String {
        let spread = self.spread();
        let noise = self.noise();
        format!(
            "the sensor is not turning: readings spread over only {:.1} counts in {:.1} s (noise about {:.1} counts); turn it a full rotation",
            spread[0].max(spread[1]),
            self.elapsed(),
            noise[0].max(noise[1]),
        )
    }

    /// Why the held samples are not a rotation, once a limit ended them.
    fn failure(&mut self, limit: Limit) -> String {
        if !self.turning() {
            return self.not_turning();
        }
        if let Some(frame) = self.frame() {
            self.recount(frame);
        }
        let progress = self.progress();
        let elapsed = self.elapsed();
        let (span, reversals) = self.sweep();
        let needed = self.config.turn_needed_deg();
        let turned = self.swept().abs();
        let ended = match limit {
            Limit::Timeout => format!("within {} s", self.config.timeout_s),
            Limit::Samples => format!(
                "within {} samples ({elapsed:.1} s; raise max_samples for a sensor this fast)",
                self.config.max_samples
            ),
        };
        let covered = progress.missing_sectors.is_empty();
        if reversals > 0 && turned < needed {
            return format!(
                "the sensor turned back and forth over {span:.0}° and never completed a rotation {ended} ({:.0} % of headings covered, net turn {turned:.0}° of {needed:.0}°); turn it once all the way round in one direction",
                progress.coverage_pct
            );
        }
        let on_ring = self.on_ring as f64 / self.t.len().max(1) as f64;
        if let Some(far) = self
            .reference
            .map(|r| r.offset_ratio())
            .filter(|&r| r > MAX_CENTRE_OVER_RADIUS)
        {
            return format!(
                "no full rotation {ended}: the readings circle a point {far:.0} times their radius away from zero (at most {MAX_CENTRE_OVER_RADIUS:.0}): they wandered by a small part of their value, as when the sensor slides through a field that changes, rather than turned; turn it in place"
            );
        }
        if covered && on_ring < MIN_RING_FRACTION {
            return format!(
                "no full rotation {ended}: every heading was seen but only {:.0} % of the readings lie near one circle (at least {:.0} % must); the field changed during the turn, or the sensor moved rather than turned: turn it in place, away from motors and metal",
                on_ring * 100.0,
                MIN_RING_FRACTION * 100.0
            );
        }
        if covered
            && turned >= needed
            && let Some(gyro) = self.gyro_turned().filter(|_| !self.gyro_agrees())
        {
            return format!(
                "no full rotation {ended}: the readings turned {turned:.0}° but the gyro only {:.0}° (at least {needed:.0}° needed); the field moved rather than the sensor, or the gyro's axis or scale is wrong: check gyro and gyro_lsb_per_deg_s, or set use_gyro = false in [sensor.rotation]",
                gyro.abs()
            );
        }
        if covered {
            return format!(
                "no full rotation {ended}: every heading was seen but the sensor turned only {turned:.0}° in one direction ({needed:.0}° needed); turn it once all the way round in one direction"
            );
        }
        let missing: Vec<String> = progress
            .missing_sectors
            .iter()
            .map(|[a, b]| format!("{a:.0}° to {b:.0}°"))
            .collect();
        format!(
            "no full rotation {ended}: {:.0} % of headings covered, missing {}; turn the sensor once all the way round, steadily",
            progress.coverage_pct,
            missing.join(", ")
        )
    }

    /// The heading swept, unwrapped, around the current centre: its span in
    /// degrees and how many times it reversed by more than
    /// [`REVERSAL_DEG`]. O(n); only used to explain a failure.
    fn sweep(&self) -> (f64, usize) {
        let Some(frame) = self.frame() else {
            return (0.0, 0);
        };
        let mut previous: Option<f64> = None;
        let (mut unwrapped, mut lo, mut hi) = (0.0f64, 0.0f64, 0.0f64);
        let (mut direction, mut extreme, mut reversals) = (0i8, 0.0f64, 0usize);
        for i in 0..self.t.len() {
            let Some(h) = frame.heading_deg(self.x[i], self.y[i]) else {
                continue;
            };
            if let Some(p) = previous {
                unwrapped += (h - p + 540.0).rem_euclid(360.0) - 180.0;
                lo = lo.min(unwrapped);
                hi = hi.max(unwrapped);
                match direction {
                    0 if unwrapped.abs() >= REVERSAL_DEG => {
                        direction = if unwrapped > 0.0 { 1 } else { -1 };
                        extreme = unwrapped;
                    }
                    1 if unwrapped > extreme => extreme = unwrapped,
                    1 if extreme - unwrapped >= REVERSAL_DEG => {
                        reversals += 1;
                        direction = -1;
                        extreme = unwrapped;
                    }
                    -1 if unwrapped < extreme => extreme = unwrapped,
                    -1 if unwrapped - extreme >= REVERSAL_DEG => {
                        reversals += 1;
                        direction = 1;
                        extreme = unwrapped;
                    }
                    _ => {}
                }
            }
            previous = Some(h);
        }
        (hi - lo, reversals)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `gaps_within` answers as the gaps `bin_gaps` lists do, on bins
    /// covered at random (from 1 % of them to all, the covered runs
    /// touching 0° and 359°), none, and one: at each gap's own width
    /// (where `<` and `<=` differ), at the ends of the limits a
    /// configuration may set (2° and 60°) and between them, and beyond
    /// them.
    #[test]
    fn the_gaps_are_within_their_limit_exactly_when_every_listed_gap_is() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x9e37_79b9);
        let mut cases = vec![vec![0u32; HEADING_BINS], {
            let mut one = vec![0u32; HEADING_BINS];
            one[0] = 1;
            one
        }];
        for k in 0..4000 {
            // Coverage from 1 % of the bins to all of them.
            let keep = 1 + (k % 100);
            cases.push(
                (0..HEADING_BINS)
                    .map(|_| u32::from(rng.random_range(0..100) < keep) * rng.random_range(1..6))
                    .collect(),
            );
        }
        let (mut within, mut beyond) = (0, 0);
        for bins in &cases {
            let gaps = bin_gaps(bins);
            let mut limits: Vec<f64> = gaps.iter().map(|&(_, g)| g as f64).collect();
            limits.extend([2.0, 2.5, 10.0, 45.0, 60.0, 90.0, 359.0, 360.0]);
            for limit in limits {
                let expected = gaps.iter().all(|&(_, g)| g as f64 <= limit);
                assert_eq!(gaps_within(bins, limit), expected, "{limit}: {gaps:?}");
                if expected { within += 1 } else { beyond += 1 }
            }
        }
        assert!(within > 10_000 && beyond > 10_000, "{within} {beyond}");
    }
}
