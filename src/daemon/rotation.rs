//! The rotation buffer: one per sensor, it collects samples until the
//! sensor has turned one full rotation in a constant field, the way
//! ArduPilot's compass calibration collects until its completion mask is
//! full. Pure: no I/O, no clock; time comes in with each sample.
//!
//! # How a full rotation is judged
//! The circle of headings is cut into `sectors` equal sectors; the rotation
//! is complete when every sector holds at least `min_per_sector` samples
//! that lie near the circle, at least [`MIN_RING_FRACTION`] of all samples
//! lie near it, and the readings spread well beyond their noise.
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
//!   into hyperbolas), and needs the gain ratio only to make sector
//!   densities even, which the default `min_per_sector` already tolerates up
//!   to a gain ratio of about 1.8 at the slowest expected sample rate.
//!
//! Samples are counted into sectors around a reference centre. When the
//! running centre (or radius) moves by more than [`RECOUNT_MOVE`] of the
//! radius, every held sample is recounted around it, at most once per
//! max(16, n/8) samples so the cost stays O(1) amortised; before the
//! rotation is declared complete the counts are always redone around a
//! centre within [`EXACT_MOVE`] of the current one. So a sector filled
//! around a wrong early centre never counts.

use serde::{Deserialize, Serialize};

/// Samples whose distance from the centre is within this band of the
/// circle's rms radius count as "on the circle". Wide enough for an
/// ellipse of gain ratio 2 (its radii span 0.63 to 1.26 of the rms), narrow
/// enough that most of a noise cloud falls outside.
const RING_BAND: (f64, f64) = (0.5, 1.5);
/// At least this fraction of the samples must lie on the circle: a noise
/// cloud puts about 2/3 there, a real turn all of them.
pub const MIN_RING_FRACTION: f64 = 0.8;
/// Recount when the centre or radius moved by this fraction of the radius
/// (a centre off by 5 % of the radius shifts headings by at most ~3°, a
/// third of a default sector).
pub const RECOUNT_MOVE: f64 = 0.05;
/// A rotation is only declared complete with counts made around a centre
/// within this fraction of the radius of the current one (< 0.6° of heading).
pub const EXACT_MOVE: f64 = 0.01;
/// A heading that retreats this far from its furthest point is a reversal;
/// large enough that noise on the circle never makes one.
pub const REVERSAL_DEG: f64 = 30.0;
/// E|d2| / sigma for white noise: the second difference of white noise of
/// standard deviation sigma is N(0, 6 sigma^2), whose mean absolute value is
/// sqrt(6) * sqrt(2/pi) * sigma.
const D2_PER_SIGMA: f64 = 1.954_410_047_611_31;

/// How the rotation buffer decides a rotation is complete or rejected.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct RotationConfig {
    /// Sectors the circle of headings is cut into.
    pub sectors: usize,
    /// Samples each sector must hold for the rotation to be complete.
    pub min_per_sector: usize,
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
}

impl Default for RotationConfig {
    /// - 36 sectors of 10° and 3 samples each: the Falcon's 50 ms frames at
    ///   one turn in 10 s put ~5.5 samples in a sector, a 30 ms poll ~9, so 3
    ///   leaves margin for an uneven hand-held turn and for a gain ratio up
    ///   to ~1.8 (which squeezes some sectors), while a 10° hole would
    ///   already be visible in the fit's coverage check (300° needed).
    /// - 20000 samples: a 60 s turn at 3 ms, 320 kB per axis.
    /// - 60 s: a person turning a robot by hand needs 10-20 s; 60 s gives a
    ///   second try without restarting.
    /// - 10 s still: the time someone needs to pick the robot up; after it,
    ///   a still buffer restarts so the turn gets its full timeout.
    /// - 20 noise deviations: n white-noise readings spread over about
    ///   2*sqrt(2 ln n) deviations, ~9 for 20000; and a field below 10
    ///   deviations (radius) could not meet the acceptance's 5 % rms anyway.
    fn default() -> Self {
        RotationConfig {
            sectors: 36,
            min_per_sector: 3,
            max_samples: 20_000,
            timeout_s: 60.0,
            still_timeout_s: 10.0,
            still_ratio: 20.0,
        }
    }
}

impl RotationConfig {
    /// Checks the configuration; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if !(8..=360).contains(&self.sectors) {
            return Err(format!(
                "sectors must be between 8 and 360, got {}",
                self.sectors
            ));
        }
        if !(1..=1000).contains(&self.min_per_sector) {
            return Err(format!(
                "min_per_sector must be between 1 and 1000, got {}",
                self.min_per_sector
            ));
        }
        let needed = self.sectors * self.min_per_sector;
        if !(needed..=10_000_000).contains(&self.max_samples) {
            return Err(format!(
                "max_samples must be between sectors * min_per_sector ({needed}) and 10000000, got {}",
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
    /// Sectors holding enough samples, as a percentage of all sectors.
    pub coverage_pct: f64,
    /// Headings still missing, as [start, end] in degrees counter-clockwise
    /// from the raw +x axis around the running centre; a range whose end is
    /// smaller than its start wraps through 0° (e.g. [350, 20]).
    pub missing_sectors: Vec<[f64; 2]>,
    /// Samples held.
    pub samples: usize,
    /// Seconds from the first sample held to the last.
    pub elapsed_s: f64,
    pub state: RotationState,
    /// Samples ignored since the buffer was made: non-finite values, or a
    /// time earlier than the previous sample's.
    pub ignored: u64,
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

/// The running centre and radius samples are counted around.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Frame {
    cx: f64,
    cy: f64,
    /// Root mean square distance of the samples from the centre.
    radius: f64,
}

impl Frame {
    /// How far `other` is from `self`, as a fraction of the radius.
    fn distance(&self, other: &Frame) -> f64 {
        let shift = (self.cx - other.cx).hypot(self.cy - other.cy) / self.radius;
        let scale = (other.radius / self.radius - 1.0).abs();
        let d = shift.max(scale);
        if d.is_nan() { f64::INFINITY } else { d }
    }

    /// Heading in degrees [0, 360) of a sample on the circle, or None when
    /// it lies too far inside or outside it to have a meaningful heading.
    fn heading_deg(&self, x: f64, y: f64) -> Option<f64> {
        let (du, dv) = (x - self.cx, y - self.cy);
        let rho = du.hypot(dv) / self.radius;
        if !(RING_BAND.0..=RING_BAND.1).contains(&rho) {
            return None;
        }
        let h = dv.atan2(du).to_degrees().rem_euclid(360.0);
        h.is_finite().then_some(h)
    }
}

/// Running sums for Kåsa's circle fit, in coordinates relative to the
/// first sample (so the sums of cubes do not lose their digits to large
/// offsets).
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    n: f64,
    su: f64,
    sv: f64,
    suu: f64,
    svv: f64,
    suv: f64,
    suuu: f64,
    suvv: f64,
    suuv: f64,
    svvv: f64,
}

impl Moments {
    fn add(&mut self, u: f64, v: f64) {
        self.n += 1.0;
        self.su += u;
        self.sv += v;
        self.suu += u * u;
        self.svv += v * v;
        self.suv += u * v;
        self.suuu += u * u * u;
        self.suvv += u * v * v;
        self.suuv += u * u * v;
        self.svvv += v * v * v;
    }

    /// The circle minimising sum (u^2 + v^2 - A u - B v - C)^2, relative to
    /// the anchor; None for fewer than 3 samples or points on a line.
    fn circle(&self) -> Option<(f64, f64, f64)> {
        let n = self.n;
        if n < 3.0 {
            return None;
        }
        let (mu, mv) = (self.su / n, self.sv / n);
        let mz = (self.suu + self.svv) / n;
        let s_uu = self.suu - n * mu * mu;
        let s_vv = self.svv - n * mv * mv;
        let s_uv = self.suv - n * mu * mv;
        let s_uz = self.suuu + self.suvv - n * mu * mz;
        let s_vz = self.suuv + self.svvv - n * mv * mz;
        let det = s_uu * s_vv - s_uv * s_uv;
        if !(s_uu > 0.0 && s_vv > 0.0 && det > 1e-9 * s_uu * s_vv) {
            return None;
        }
        let a = (s_uz * s_vv - s_vz * s_uv) / det;
        let b = (s_vz * s_uu - s_uz * s_uv) / det;
        let (cu, cv) = (a / 2.0, b / 2.0);
        let r2 = (s_uu + s_vv) / n + (mu - cu).powi(2) + (mv - cv).powi(2);
        let radius = r2.sqrt();
        (cu.is_finite() && cv.is_finite() && radius.is_finite() && radius > 0.0)
            .then_some((cu, cv, radius))
    }
}

/// Which limit ended a rotation that did not complete.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Limit {
    Timeout,
    Samples,
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
    /// Samples per sector, counted around `reference`.
    counts: Vec<usize>,
    /// Samples on the circle around `reference`.
    on_ring: usize,
    reference: Option<Frame>,
    since_recount: usize,
    complete: bool,
    ignored: u64,
}

impl RotationBuffer {
    /// A buffer for `config`. An invalid configuration (see
    /// [`RotationConfig::validate`]) is clamped into range rather than
    /// panicking; callers validate first to tell the user.
    pub fn new(config: RotationConfig) -> Self {
        let mut config = config;
        config.sectors = config.sectors.clamp(8, 360);
        config.min_per_sector = config.min_per_sector.clamp(1, 1000);
        config.max_samples = config
            .max_samples
            .clamp(config.sectors * config.min_per_sector, 10_000_000);
        let defaults = RotationConfig::default();
        if !(config.timeout_s.is_finite() && config.timeout_s > 0.0) {
            config.timeout_s = defaults.timeout_s;
        }
        if !(config.still_timeout_s.is_finite() && config.still_timeout_s > 0.0) {
            config.still_timeout_s = defaults.still_timeout_s;
        }
        if !(config.still_ratio.is_finite() && config.still_ratio >= 1.0) {
            config.still_ratio = defaults.still_ratio;
        }
        let counts = vec![0; config.sectors];
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
            counts,
            on_ring: 0,
            reference: None,
            since_recount: 0,
            complete: false,
            ignored: 0,
        }
    }

    /// The configuration in use (after clamping).
    pub fn config(&self) -> &RotationConfig {
        &self.config
    }

    /// Adds a sample (time in seconds, raw x and y counts). O(1) amortised.
    ///
    /// Non-finite values and times earlier than the previous sample's are
    /// ignored (counted in [`Progress::ignored`]). Once `Complete` is
    /// returned the buffer holds that rotation and ignores further samples,
    /// still answering `Complete`, until [`take`](Self::take) or
    /// [`reset`](Self::reset).
    pub fn push(&mut self, time: f64, x: f64, y: f64) -> RotationEvent {
        if self.complete {
            return RotationEvent::Complete;
        }
        if !(time.is_finite() && x.is_finite() && y.is_finite()) {
            self.ignored += 1;
            return RotationEvent::Collecting;
        }
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
                self.restart_with(time, x, y);
                return RotationEvent::Rejected { reason };
            }
            if elapsed >= self.config.still_timeout_s && !self.turning() {
                let reason = self.not_turning();
                self.restart_with(time, x, y);
                return RotationEvent::Rejected { reason };
            }
        }
        self.ingest(time, x, y);
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

    /// How far the rotation has got.
    pub fn progress(&self) -> Progress {
        let min = self.config.min_per_sector;
        let sectors = self.config.sectors;
        let filled = if self.reference.is_some() {
            self.counts.iter().filter(|&&c| c >= min).count()
        } else {
            0
        };
        let width = 360.0 / sectors as f64;
        let missing: Vec<bool> = (0..sectors)
            .map(|i| self.reference.is_none() || self.counts[i] < min)
            .collect();
        let mut ranges: Vec<[f64; 2]> = Vec::new();
        let mut i = 0;
        while i < sectors {
            if missing[i] {
                let start = i;
                while i < sectors && missing[i] {
                    i += 1;
                }
                ranges.push([start as f64 * width, i as f64 * width]);
            } else {
                i += 1;
            }
        }
        // A gap through 0° is one gap: [340, 360] and [0, 20] read [340, 20].
        if ranges.len() > 1
            && let (Some(first), Some(last)) = (ranges.first().copied(), ranges.last().copied())
            && first[0] == 0.0
            && last[1] >= 360.0
        {
            ranges.remove(0);
            if let Some(last) = ranges.last_mut() {
                last[1] = first[1];
            }
        }
        Progress {
            coverage_pct: filled as f64 / sectors as f64 * 100.0,
            missing_sectors: ranges,
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
        }
    }

    /// The samples held (t, x, y) — on `Complete`, those of the rotation —
    /// and the buffer restarts empty.
    pub fn take(&mut self) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let taken = (
            std::mem::take(&mut self.t),
            std::mem::take(&mut self.x),
            std::mem::take(&mut self.y),
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
        self.counts.iter_mut().for_each(|c| *c = 0);
        self.on_ring = 0;
        self.reference = None;
        self.since_recount = 0;
        self.complete = false;
    }

    fn restart_with(&mut self, time: f64, x: f64, y: f64) {
        self.clear();
        self.ingest(time, x, y);
    }

    fn elapsed(&self) -> f64 {
        match (self.t.first(), self.t.last()) {
            (Some(first), Some(last)) => last - first,
            _ => 0.0,
        }
    }

    fn ingest(&mut self, time: f64, x: f64, y: f64) {
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
        self.t.push(time);
        self.x.push(x);
        self.y.push(y);
        self.moments.add(x - self.anchor.0, y - self.anchor.1);
        self.since_recount += 1;

        let Some(frame) = self.frame() else {
            return;
        };
        match self.reference {
            Some(reference)
                if reference.distance(&frame) <= RECOUNT_MOVE
                    || self.since_recount < (self.t.len() / 8).max(16) =>
            {
                self.place(&reference, x, y);
            }
            _ => self.recount(frame),
        }
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
            let sectors = self.config.sectors;
            let i = ((h / 360.0 * sectors as f64) as usize).min(sectors - 1);
            self.counts[i] += 1;
            self.on_ring += 1;
        }
    }

    /// Recounts every held sample around `frame`: O(n), rare (see the
    /// module documentation).
    fn recount(&mut self, frame: Frame) {
        self.counts.iter_mut().for_each(|c| *c = 0);
        self.on_ring = 0;
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
        let exact = self
            .reference
            .is_some_and(|r| r.distance(&frame) <= EXACT_MOVE);
        if exact {
            return true;
        }
        if !force && self.since_recount < (self.t.len() / 32).max(1) {
            return false;
        }
        self.recount(frame);
        self.complete_around_reference()
    }

    fn complete_around_reference(&self) -> bool {
        self.reference.is_some()
            && self.counts.iter().all(|&c| c >= self.config.min_per_sector)
            && self.on_ring as f64 >= MIN_RING_FRACTION * self.t.len() as f64
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
        let ended = match limit {
            Limit::Timeout => format!("within {} s", self.config.timeout_s),
            Limit::Samples => format!(
                "within {} samples ({elapsed:.1} s; raise max_samples for a sensor this fast)",
                self.config.max_samples
            ),
        };
        if reversals > 0 && progress.coverage_pct < 100.0 {
            return format!(
                "the sensor turned back and forth over {span:.0}° and never completed a rotation {ended} ({:.0} % of headings covered); turn it once all the way round in one direction",
                progress.coverage_pct
            );
        }
        if progress.coverage_pct >= 100.0 {
            let on_ring = self.on_ring as f64 / self.t.len().max(1) as f64 * 100.0;
            return format!(
                "no full rotation {ended}: every heading was seen but only {on_ring:.0} % of the readings lie near one circle (at least {:.0} % must); the field changed during the turn, or the sensor moved rather than turned: turn it in place, away from motors and metal",
                MIN_RING_FRACTION * 100.0
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
    use crate::sim::SimSensor;

    /// Deterministic Gaussian noise (xorshift + Box-Muller), so tests need
    /// no generator state from elsewhere.
    struct Noise(u64);
    impl Noise {
        fn uniform(&mut self) -> f64 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            ((self.0 >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        }
        fn gauss(&mut self, sigma: f64) -> f64 {
            let (u1, u2) = (self.uniform(), self.uniform());
            sigma * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        }
    }

    /// Samples every `period` s for `seconds` of a circle of radius 1000
    /// around (cx, cy), heading(t) in degrees.
    fn track(
        seconds: f64,
        period: f64,
        centre: (f64, f64),
        noise: f64,
        heading: impl Fn(f64) -> f64,
    ) -> Vec<(f64, f64, f64)> {
        let mut rng = Noise(0x9E37_79B9_7F4A_7C15);
        let n = (seconds / period).round() as usize;
        (0..n)
            .map(|i| {
                let t = i as f64 * period;
                let h = heading(t).to_radians();
                (
                    t,
                    centre.0 + 1000.0 * h.cos() + rng.gauss(noise),
                    centre.1 + 1000.0 * h.sin() + rng.gauss(noise),
                )
            })
            .collect()
    }

    /// Pushes until something other than Collecting; returns its index.
    fn run(
        buffer: &mut RotationBuffer,
        samples: &[(f64, f64, f64)],
    ) -> Option<(usize, RotationEvent)> {
        for (i, &(t, x, y)) in samples.iter().enumerate() {
            match buffer.push(t, x, y) {
                RotationEvent::Collecting => {}
                event => return Some((i, event)),
            }
        }
        None
    }

    fn sim_samples(sim: &SimSensor) -> Vec<(f64, f64, f64)> {
        let d = sim.simulate().unwrap();
        let t = d.t.clone().unwrap();
        (0..d.len()).map(|i| (t[i], d.x[i], d.y[i])).collect()
    }

    /// Fraction of a turn at which the buffer completed.
    fn completes_at(sim: &SimSensor) -> f64 {
        let samples = sim_samples(sim);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, &samples).expect("no event");
        assert_eq!(event, RotationEvent::Complete, "{sim:?}");
        i as f64 * sim.period / sim.turn_seconds
    }

    #[test]
    fn a_clean_turn_completes_at_its_end_and_not_before() {
        let sim = SimSensor {
            turns: 1.5,
            noise: 2.0,
            ..Default::default()
        };
        let at = completes_at(&sim);
        assert!((0.9..=1.0).contains(&at), "completed at {at} turns");
    }

    #[test]
    fn a_turn_from_any_heading_completes() {
        for start in [0.0, 4.0, 37.0, 90.0, 123.4, 181.0, 269.0, 333.3, 359.0] {
            let sim = SimSensor {
                turns: 1.5,
                noise: 2.0,
                start_heading_deg: start,
                seed: start as u64 + 7,
                ..Default::default()
            };
            let at = completes_at(&sim);
            // At worst the last sector needs its samples from the second pass.
            assert!(
                (0.9..=1.03).contains(&at),
                "start {start}: completed at {at} turns"
            );
        }
    }

    #[test]
    fn a_turn_far_from_the_origin_and_with_unequal_gains_completes() {
        for (gain_x, period) in [(1.0, 0.05), (1.4, 0.05), (0.6, 0.03)] {
            let sim = SimSensor {
                turns: 1.5,
                noise: 3.0,
                offset_x: 5000.0,
                offset_y: -5000.0,
                gain_x,
                period,
                start_heading_deg: 200.0,
                ..Default::default()
            };
            let at = completes_at(&sim);
            assert!(
                (0.9..=1.05).contains(&at),
                "gain {gain_x}: completed at {at} turns"
            );
        }
    }

    #[test]
    fn clockwise_turn_completes() {
        let samples = track(15.0, 0.05, (-300.0, 800.0), 2.0, |t| 50.0 - 36.0 * t);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, &samples).unwrap();
        assert_eq!(event, RotationEvent::Complete);
        let at = i as f64 * 0.05 / 10.0;
        assert!((0.9..=1.03).contains(&at), "{at}");
    }

    #[test]
    fn waiting_before_turning_then_turning_completes() {
        // 8 s still, then one turn in 10 s: the wait must not spoil it.
        let samples = track(25.0, 0.05, (2000.0, 0.0), 2.0, |t| {
            if t < 8.0 {
                120.0
            } else {
                120.0 + 36.0 * (t - 8.0)
            }
        });
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, &samples).unwrap();
        assert_eq!(event, RotationEvent::Complete);
        let turned = (i as f64 * 0.05 - 8.0) / 10.0;
        assert!((0.9..=1.03).contains(&turned), "{turned}");
        let (t, x, y) = buffer.take();
        assert_eq!((t.len(), x.len(), y.len()), (i + 1, i + 1, i + 1));
        assert_eq!(buffer.progress().state, RotationState::Empty);
    }

    #[test]
    fn half_a_turn_times_out_with_the_missing_headings() {
        // From 5° to 185° in 5 s, then held still at 185°.
        let samples = track(61.0, 0.05, (100.0, 100.0), 2.0, |t| 5.0 + 36.0 * t.min(5.0));
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let mut last = None;
        for &(t, x, y) in &samples {
            match buffer.push(t, x, y) {
                RotationEvent::Collecting => last = Some(buffer.progress()),
                RotationEvent::Complete => panic!("half a turn completed at {t}"),
                RotationEvent::Rejected { reason } => {
                    // The first sample past 60 s.
                    assert!((t - 60.05).abs() < 1e-9, "{t}");
                    assert_eq!(
                        reason,
                        "no full rotation within 60 s: 53 % of headings covered, missing 190° to 360°; turn the sensor once all the way round, steadily"
                    );
                    let p = last.take().unwrap();
                    // Sectors 0..=18 (0° to 190°) are full, the rest empty.
                    assert!((p.coverage_pct - 19.0 / 36.0 * 100.0).abs() < 1e-9, "{p:?}");
                    assert_eq!(p.missing_sectors, vec![[190.0, 360.0]]);
                    // Restarted with the rejected sample as its first.
                    assert_eq!(buffer.progress().samples, 1);
                    return;
                }
            }
        }
        panic!("no rejection");
    }

    #[test]
    fn a_gap_through_zero_is_one_range() {
        // From 20° to 340° in about 9 s; stop before the timeout.
        let samples = track(9.0, 0.05, (0.0, 0.0), 1.0, |t| {
            20.0 + 36.0 * t.min(320.0 / 36.0)
        });
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        assert_eq!(run(&mut buffer, &samples), None);
        let p = buffer.progress();
        assert_eq!(p.missing_sectors, vec![[340.0, 20.0]], "{p:?}");
        assert!((p.coverage_pct - 32.0 / 36.0 * 100.0).abs() < 1e-9, "{p:?}");
        assert_eq!(p.samples, samples.len());
        assert!((p.elapsed_s - samples[samples.len() - 1].0).abs() < 1e-12);
        assert_eq!(p.state, RotationState::Collecting);
    }

    #[test]
    fn back_and_forth_is_rejected_as_such() {
        // Swings between 0° and 170°, 6 s per sweep, for over a minute.
        let samples = track(62.0, 0.05, (-4000.0, 2500.0), 2.0, |t| {
            let phase = (t / 6.0).rem_euclid(2.0);
            170.0 * if phase < 1.0 { phase } else { 2.0 - phase }
        });
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, &samples).unwrap();
        assert!((i as f64 * 0.05 - 60.05).abs() < 1e-9, "{i}");
        let RotationEvent::Rejected { reason } = event else {
            panic!("{event:?}");
        };
        assert!(
            reason.starts_with("the sensor turned back and forth over 170° and never completed a rotation within 60 s"),
            "{reason}"
        );
        assert!(
            reason.ends_with("turn it once all the way round in one direction"),
            "{reason}"
        );
    }

    #[test]
    fn a_still_sensor_is_rejected_as_not_turning() {
        let samples = track(12.0, 0.05, (700.0, -300.0), 3.0, |_| 40.0);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let (i, event) = run(&mut buffer, &samples).unwrap();
        // The first sample 10 s after the first.
        assert_eq!(i, 200);
        let RotationEvent::Rejected { reason } = event else {
            panic!("{event:?}");
        };
        assert!(
            reason.starts_with("the sensor is not turning: readings spread over only "),
            "{reason}"
        );
        assert!(
            reason.contains("counts in 10.0 s (noise about "),
            "{reason}"
        );
        assert!(reason.ends_with("; turn it a full rotation"), "{reason}");
        // And it never completes on noise, however long it sits.
        let samples = track(300.0, 0.01, (0.0, 0.0), 5.0, |_| 0.0);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        for &(t, x, y) in &samples {
            assert_ne!(buffer.push(t, x, y), RotationEvent::Complete, "at {t}");
        }
    }

    #[test]
    fn memory_stays_bounded() {
        let config = RotationConfig {
            max_samples: 150,
            ..Default::default()
        };
        // A slow turn (a tenth of a turn in 10 s) that is clearly turning.
        let samples = track(20.0, 0.05, (0.0, 0.0), 1.0, |t| 3.6 * t);
        let mut buffer = RotationBuffer::new(config);
        let mut rejected = 0;
        for &(t, x, y) in &samples {
            if let RotationEvent::Rejected { reason } = buffer.push(t, x, y) {
                assert!(reason.contains("within 150 samples"), "{reason}");
                rejected += 1;
            }
            assert!(buffer.progress().samples < 150);
        }
        assert_eq!(rejected, samples.len() / 150);
    }

    #[test]
    fn bad_samples_are_ignored_without_harm() {
        let sim = SimSensor {
            turns: 1.5,
            noise: 2.0,
            ..Default::default()
        };
        let clean = sim_samples(&sim);
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        let mut done = None;
        for (i, &(t, x, y)) in clean.iter().enumerate() {
            for (bt, bx, by) in [
                (t, f64::NAN, y),
                (t, x, f64::INFINITY),
                (f64::NAN, x, y),
                (t, f64::NEG_INFINITY, f64::NAN),
            ] {
                assert_eq!(buffer.push(bt, bx, by), RotationEvent::Collecting);
            }
            if i > 0 {
                // Out of order: earlier than the last sample.
                assert_eq!(buffer.push(t - 1.0, x, y), RotationEvent::Collecting);
            }
            if buffer.push(t, x, y) == RotationEvent::Complete {
                done = Some(i);
                break;
            }
        }
        let i = done.unwrap();
        let at = i as f64 * sim.period / sim.turn_seconds;
        assert!((0.9..=1.0).contains(&at), "{at}");
        let p = buffer.progress();
        assert_eq!(p.samples, i + 1);
        assert_eq!(p.ignored, 5 * i as u64 + 4);
        assert_eq!(p.state, RotationState::Complete);
        assert_eq!(p.coverage_pct, 100.0);
        assert!(p.missing_sectors.is_empty());
        // Frozen until taken.
        assert_eq!(buffer.push(1e6, 0.0, 0.0), RotationEvent::Complete);
        let (t, _, _) = buffer.take();
        assert_eq!(t.len(), i + 1);
        assert_eq!(buffer.progress().samples, 0);
    }

    #[test]
    fn the_samples_of_a_turn_fit() {
        let sim = SimSensor {
            turns: 1.5,
            noise: 2.0,
            gain_x: 1.2,
            offset_x: 3000.0,
            ..Default::default()
        };
        let mut buffer = RotationBuffer::new(RotationConfig::default());
        assert_eq!(
            run(&mut buffer, &sim_samples(&sim)).unwrap().1,
            RotationEvent::Complete
        );
        let (_, x, y) = buffer.take();
        let fit = crate::model::fit::fit_paper(
            &x,
            &y,
            &crate::model::fit::FitOptions::default(),
            &mut |_| {},
        )
        .unwrap();
        assert!(
            crate::daemon::acceptance::check(&fit, &Default::default()).is_ok(),
            "{fit:?}"
        );
        assert!((fit.calibration.a - sim.truth().a).abs() < 0.01, "{fit:?}");
    }

    #[test]
    fn config_validation_names_the_key() {
        assert_eq!(RotationConfig::default().validate(), Ok(()));
        let bad = RotationConfig {
            sectors: 2,
            ..Default::default()
        };
        assert_eq!(
            bad.validate().unwrap_err(),
            "sectors must be between 8 and 360, got 2"
        );
        let cases = [
            (
                RotationConfig {
                    min_per_sector: 0,
                    ..Default::default()
                },
                "min_per_sector",
            ),
            (
                RotationConfig {
                    max_samples: 100,
                    ..Default::default()
                },
                "max_samples",
            ),
            (
                RotationConfig {
                    timeout_s: f64::NAN,
                    ..Default::default()
                },
                "timeout_s",
            ),
            (
                RotationConfig {
                    still_timeout_s: -1.0,
                    ..Default::default()
                },
                "still_timeout_s",
            ),
            (
                RotationConfig {
                    still_ratio: 0.5,
                    ..Default::default()
                },
                "still_ratio",
            ),
        ];
        for (config, key) in cases {
            let err = config.validate().unwrap_err();
            assert!(err.starts_with(key), "{err}");
            // An invalid configuration still makes a working buffer.
            let mut buffer = RotationBuffer::new(config);
            buffer.push(0.0, 1.0, 2.0);
            assert_eq!(buffer.progress().samples, 1);
        }
        let c: RotationConfig = toml::from_str("sectors = 24\ntimeout_s = 30.0").unwrap();
        assert_eq!((c.sectors, c.timeout_s, c.min_per_sector), (24, 30.0, 3));
        assert!(toml::from_str::<RotationConfig>("sector = 24").is_err());
    }
}
