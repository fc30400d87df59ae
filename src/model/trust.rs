//! Trust at every reading: whether a calibrated reading can be believed,
//! from what can be checked at that moment, and why not.
//!
//! A calibration is a claim about the sensor; the world changes after it is
//! made (a magnet near the compass, a steel cabinet passing). The monitor
//! checks each calibrated reading against the calibration's own noise:
//!
//! - **The field.** |corrected|/r − 1 against the calibration's rms, with
//!   hysteresis: distrusted beyond [`ENTER_SIGMAS`] σ, trusted again within
//!   [`LEAVE_SIGMAS`] σ, so the flag does not flicker at the edge.
//! - **The dip.** A 3-axis compass with a tilt accelerometer: the field's
//!   angle below the accelerometer's horizontal against the dip measured
//!   over the calibration's sphere, beyond [`ENTER_SIGMAS`] of that
//!   sphere's spread (with the same hysteresis). A magnet can turn the
//!   field without changing its magnitude; it cannot keep the dip.
//! - **Across the turn.** A 2-axis sensor whose configuration names the
//!   axis across its turn: that axis's reading, as a fraction of r,
//!   against its median over the calibration's rotation, beyond
//!   [`ENTER_SIGMAS`] of its spread there (with the same hysteresis). A
//!   magnet moves it, and so does a tilt, which leaks the vertical field
//!   into the level pair: either way the heading is wrong.
//! - **Tilt.** A 2-axis compass with a tilt accelerometer: the angle
//!   between the accelerometer's vertical and the one it had over the
//!   calibration's rotation, beyond [`ENTER_SIGMAS`] of that rotation's
//!   own tilt spread (or, with the WMM's dip at a location, of the tilt at
//!   which the heading errs as much), with the same hysteresis. A level
//!   pair tilted by θ takes the vertical field's component sin θ · Z, and
//!   its heading errs by up to atan(tan(dip) · sin θ): 2° for 1° at a dip
//!   of 65°.
//! - **The gyro.** The heading's change over [`WINDOW_S`] against the
//!   integrated gyro (its scale and bias from the calibration's heading
//!   check). Once they disagree, the gyro carries the heading reference
//!   from the last trusted reading, and trust returns when the heading
//!   agrees with that reference again. A 2-axis compass's gyro is the one
//!   about its turn; a 3-axis compass's is a 3-axis gyro's rate about the
//!   vertical ([`crate::model::gyro3`]). A reading the gyro cannot check
//!   (none beside it, or a 3-axis compass pitched too far) starts the
//!   check afresh.
//!
//! Pure: no I/O, no clock but the readings' times. Memory is bounded: the
//! window holds at most [`MAX_WINDOW_READINGS`].

use std::collections::VecDeque;

/// Distrusted beyond this many σ: for Gaussian noise one reading in
/// 1.7 million, so a quiet sensor is not flagged in a day at 20 Hz.
pub const ENTER_SIGMAS: f64 = 5.0;
/// Trusted again within this many σ (hysteresis).
pub const LEAVE_SIGMAS: f64 = 3.0;
/// The span over which the heading's change is compared with the gyro's.
pub const WINDOW_S: f64 = 2.0;
/// Readings the window holds at most (2 s at 1 kHz, with room).
pub const MAX_WINDOW_READINGS: usize = 4096;
/// The gyro's scale known to within this fraction. The heading check fits
/// the scale over a whole turn: a hand-held turn's 2° rms heading error
/// over 360° leaves about 0.6 %; the MPU-6050's sensitivity moves ±2 % over
/// its 125 °C range, 0.016 % per °C. (Its ±3 % initial tolerance is what
/// the fit removes.)
pub const GYRO_SCALE_SD: f64 = 0.01;
/// The gyro's bias known to within this, deg/s, beyond what the monitor
/// follows ([`BIAS_TAU_S`]): the MPU-6050's zero-rate output moves about
/// 0.16 °/s per °C (±20 °/s over −40…85 °C), and within a disturbance of
/// a minute the temperature moves by well under 1 °C.
pub const GYRO_BIAS_SD_DEG_S: f64 = 0.1;
/// The time constant over which the monitor follows the gyro's bias while
/// the heading is trusted (the heading's rate less the gyro's), seconds: a
/// warming gyro drifts over minutes, a magnet swings the heading in one.
pub const BIAS_TAU_S: f64 = 60.0;
/// The smallest field noise the monitor assumes, as a fraction of r: a
/// noiseless fit's rms says nothing of the next reading.
pub const MIN_FIELD_SIGMA: f64 = 1e-3;
/// The smallest heading noise the monitor assumes, degrees.
pub const MIN_HEADING_SIGMA_DEG: f64 = 0.1;
/// The smallest tilt spread the monitor assumes along one axis, degrees:
/// an accelerometer's noise (the MPU-6050's 400 µg/√Hz over its 44 Hz
/// filter is 2.7 mg, 0.15°; the ADXL345's about 1 mg at 25 Hz, 0.06°).
/// A calibration turned on a level turntable measures no more.
pub const MIN_TILT_SIGMA_DEG: f64 = 0.1;

/// The gyro about the turn's axis, as the calibration's heading check
/// found it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GyroModel {
    /// Heading turned per degree of gyro angle (±1 and the sign of its
    /// mounting).
    pub scale: f64,
    /// What the gyro reads at rest, deg/s.
    pub bias_deg_s: f64,
}

/// What the monitor measures a reading against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrustLimits {
    /// The calibration's noise in |corrected|/r − 1 (its rms).
    pub field_sigma: f64,
    /// The heading's noise, degrees.
    pub heading_sigma_deg: f64,
    /// The gyro, when the sensor has one.
    pub gyro: Option<GyroModel>,
    /// The dip, when the calibration measured it (degrees).
    pub dip: Option<ReferenceLimit>,
    /// The field across a 2-axis sensor's turn, when the calibration
    /// measured it (a fraction of r).
    pub across: Option<ReferenceLimit>,
    /// The tilt a 2-axis compass tolerates from the attitude it was
    /// calibrated in, when it has a tilt accelerometer.
    pub tilt: Option<TiltLimit>,
}

/// The tilt a 2-axis compass tolerates: [`ENTER_SIGMAS`] of `sigma_deg`
/// from the attitude of its calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TiltLimit {
    /// Degrees, along one axis.
    pub sigma_deg: f64,
    /// The WMM's dip, degrees, when the tilt at which the heading errs
    /// [`ENTER_SIGMAS`] of its noise there is wider than the rotation's
    /// own spread and so set the limit.
    pub dip_deg: Option<f64>,
}

/// A quantity the calibration measured (its median over its samples: the
/// dip against the tilt accelerometer's vertical, degrees; the field
/// across a turn, a fraction of r) and one reading's spread about it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReferenceLimit {
    pub reference: f64,
    pub sigma: f64,
}

impl TrustLimits {
    /// The limits of a calibration of rms `rms` (in |corrected|/r − 1),
    /// with the heading check's rms in degrees when there was one.
    pub fn from_rms(rms: f64, heading_rms_deg: Option<f64>, gyro: Option<GyroModel>) -> Self {
        let field_sigma = if rms.is_finite() {
            rms.max(MIN_FIELD_SIGMA)
        } else {
            MIN_FIELD_SIGMA
        };
        // A field error of e is a heading error of up to e radians.
        let from_field = field_sigma.to_degrees();
        let heading_sigma_deg = heading_rms_deg
            .filter(|h| h.is_finite())
            .map_or(from_field, |h| h.max(from_field))
            .max(MIN_HEADING_SIGMA_DEG);
        TrustLimits {
            field_sigma,
            heading_sigma_deg,
            gyro,
            dip: None,
            across: None,
            tilt: None,
        }
    }

    /// These limits with the dip check: the calibration's measured dip
    /// (median, robust spread over the sphere, degrees). The spread is held
    /// at least to what the field's noise alone gives (its rms read as an
    /// angle) and [`MIN_HEADING_SIGMA_DEG`]; a dip that is not finite, or
    /// not within ±90°, or a spread that is not a finite, non-negative
    /// number, leaves the check out.
    pub fn with_dip(mut self, median_deg: f64, spread_deg: f64) -> Self {
        let usable = median_deg.is_finite()
            && median_deg.abs() <= 90.0
            && spread_deg.is_finite()
            && spread_deg >= 0.0;
        self.dip = usable.then(|| ReferenceLimit {
            reference: median_deg,
            sigma: spread_deg
                .max(self.field_sigma.to_degrees())
                .max(MIN_HEADING_SIGMA_DEG),
        });
        self
    }

    /// These limits with the tilt check of a 2-axis compass: the tilt's
    /// spread along one axis over the calibration's rotation (degrees,
    /// held at least to [`MIN_TILT_SIGMA_DEG`]) and the WMM's dip where
    /// the compass is, when a location gives it. A tilt θ errs the heading
    /// by up to atan(tan(dip) · sin θ), so the heading's [`ENTER_SIGMAS`]
    /// tolerate asin(tan(5 σ_h) / |tan(dip)|): with a dip, the limit is the
    /// wider of that and the rotation's own spread, over which the
    /// calibration's noise was measured. A spread that is not a finite,
    /// non-negative number leaves the check out.
    pub fn with_tilt(mut self, spread_deg: f64, dip_deg: Option<f64>) -> Self {
        if !(spread_deg.is_finite() && spread_deg >= 0.0) {
            self.tilt = None;
            return self;
        }
        let measured = spread_deg.max(MIN_TILT_SIGMA_DEG);
        let tolerated = dip_deg
            .filter(|d| d.is_finite() && d.abs() < 90.0)
            .map(|d| {
                let error = (ENTER_SIGMAS * self.heading_sigma_deg)
                    .min(89.0)
                    .to_radians();
                let sin = (error.tan() / d.to_radians().tan().abs()).min(1.0);
                (d, sin.asin().to_degrees() / ENTER_SIGMAS)
            });
        self.tilt = Some(match tolerated {
            Some((dip, sigma)) if sigma > measured => TiltLimit {
                sigma_deg: sigma,
                dip_deg: Some(dip),
            },
            _ => TiltLimit {
                sigma_deg: measured,
                dip_deg: None,
            },
        });
        self
    }

    /// These limits with the check across the turn: the reading of the
    /// axis across a 2-axis sensor's turn over the calibration's rotation
    /// (median, robust spread, as fractions of r). The spread is held at
    /// least to the field's noise σ; numbers that are not finite (or a
    /// negative spread) leave the check out.
    pub fn with_across(mut self, median: f64, spread: f64) -> Self {
        let usable = median.is_finite() && spread.is_finite() && spread >= 0.0;
        self.across = usable.then(|| ReferenceLimit {
            reference: median,
            sigma: spread.max(self.field_sigma),
        });
        self
    }
}

/// One calibrated reading, as the monitor sees it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Observation {
    /// Seconds, on the readings' clock.
    pub time: f64,
    /// |corrected| / r.
    pub field_ratio: f64,
    /// The corrected heading, degrees.
    pub heading_deg: f64,
    /// The gyro's rate about the turn's axis, deg/s, when there is one.
    pub gyro_deg_s: Option<f64>,
    /// The field's angle below the accelerometer's horizontal, degrees,
    /// when the sensor has a tilt accelerometer.
    pub dip_deg: Option<f64>,
    /// The reading of the axis across a 2-axis sensor's turn, a fraction
    /// of r, when the configuration names it.
    pub across: Option<f64>,
    /// A 2-axis compass's tilt from the attitude of its calibration,
    /// degrees, when it has a fresh tilt accelerometer reading.
    pub tilt_deg: Option<f64>,
}

/// The monitor's word on one reading.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Verdict {
    pub trusted: bool,
    /// Why not, with the deciding numbers; empty when trusted.
    pub reasons: Vec<String>,
}

/// Counts over the readings checked.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct TrustCounts {
    pub trusted: u64,
    pub distrusted: u64,
    /// The longest run of distrusted readings, seconds (first to last).
    pub longest_distrusted_s: f64,
}

/// A point of the heading's and the gyro's history.
#[derive(Debug, Clone, Copy)]
struct Point {
    time: f64,
    /// The heading, unwrapped (continuous across 0/360), degrees.
    heading: f64,
    /// The gyro's bias-corrected angle times its scale, degrees.
    gyro: f64,
}

/// The monitor of one sensor under one calibration.
#[derive(Debug, Clone)]
pub struct TrustMonitor {
    limits: TrustLimits,
    field_distrusted: bool,
    dip_distrusted: bool,
    across_distrusted: bool,
    tilt_distrusted: bool,
    window: VecDeque<Point>,
    /// The last trusted point while the gyro carries the reference.
    reference: Option<Point>,
    /// The last gyro rate and its time.
    last: Option<(f64, f64)>,
    /// The gyro angle so far (scaled, bias-corrected), degrees.
    gyro_angle: f64,
    /// The previous reading's time and heading (unwrapped).
    previous: Option<(f64, f64)>,
    /// The heading's rate less the gyro's, followed while trusted, deg/s.
    drift: f64,
    /// Set when the gyro lost the heading (a reading without a rate) while
    /// the heading was distrusted against it: the
    /// seconds the heading has agreed with the gyro since. Trust returns
    /// once they add up to a window ([`WINDOW_S`]).
    lost_agreed_s: Option<f64>,
    counts: TrustCounts,
    stretch_start: Option<f64>,
    /// The latest reading's first reason, while it is distrusted.
    now: Option<String>,
}

impl TrustMonitor {
    pub fn new(limits: TrustLimits) -> Self {
        TrustMonitor {
            limits,
            field_distrusted: false,
            dip_distrusted: false,
            across_distrusted: false,
            tilt_distrusted: false,
            window: VecDeque::new(),
            reference: None,
            last: None,
            gyro_angle: 0.0,
            previous: None,
            drift: 0.0,
            lost_agreed_s: None,
            counts: TrustCounts::default(),
            stretch_start: None,
            now: None,
        }
    }

    pub fn limits(&self) -> &TrustLimits {
        &self.limits
    }

    pub fn counts(&self) -> TrustCounts {
        self.counts
    }

    /// Why the latest reading was distrusted (its first reason), if it was.
    pub fn distrust_now(&self) -> Option<&str> {
        self.now.as_deref()
    }

    /// Checks one reading. Readings out of time order, or not finite, are
    /// distrusted and leave the history as it was.
    pub fn check(&mut self, obs: Observation) -> Verdict {
        self.check_under(obs, &[])
    }

    /// [`TrustMonitor::check`] under standing reasons to distrust every
    /// reading (a calibration known to be stale, a mounting known to be
    /// wrong: `standing`, why), which come first, the other checks going on
    /// beside them.
    pub fn check_under(&mut self, obs: Observation, standing: &[&str]) -> Verdict {
        let mut reasons: Vec<String> = standing.iter().map(|s| s.to_string()).collect();
        let ordered = self.previous.is_none_or(|(t, _)| obs.time >= t);
        if !(obs.time.is_finite()
            && obs.field_ratio.is_finite()
            && obs.heading_deg.is_finite()
            && ordered)
        {
            reasons.push("the reading is not a finite, time-ordered one".to_string());
            return self.record(obs.time, reasons);
        }
        self.check_field(obs.field_ratio, &mut reasons);
        if let (Some(limit), Some(dip)) = (self.limits.dip, obs.dip_deg)
            && let Some(b) = beyond(&mut self.dip_distrusted, limit, dip)
        {
            reasons.push(format!(
                "the dip is {dip:.1}° where the calibration measured {:.1}° ({:+.1}°, limit {:.1}°: {} σ of its spread{})",
                limit.reference, b.off, b.bound, b.sigmas, b.until,
            ));
        }
        if let (Some(limit), Some(across)) = (self.limits.across, obs.across)
            && let Some(b) = beyond(&mut self.across_distrusted, limit, across)
        {
            reasons.push(format!(
                "the field across the turn moved by {:+.1} % of r from the calibration's (limit {:.1} %: {} σ of its spread{})",
                b.off * 100.0,
                b.bound * 100.0,
                b.sigmas,
                b.until,
            ));
        }
        if let (Some(limit), Some(tilt)) = (self.limits.tilt, obs.tilt_deg) {
            let reference = ReferenceLimit {
                reference: 0.0,
                sigma: limit.sigma_deg,
            };
            if let Some(b) = beyond(&mut self.tilt_distrusted, reference, tilt) {
                let basis = match limit.dip_deg {
                    Some(dip) => format!(
                        "the tilt at which its heading errs {} σ of its noise at the WMM's dip of {dip:.1}°",
                        b.sigmas
                    ),
                    None => format!("{} σ of its tilt over the calibration's rotation", b.sigmas),
                };
                reasons.push(format!(
                    "the compass is tilted {tilt:.1}° from the attitude it was calibrated in (limit {:.1}°: {basis}{})",
                    b.bound, b.until,
                ));
            }
        }
        // A reading the gyro cannot check (a 3-axis compass pitched too
        // far, where its heading turns faster than any gyro error can be
        // bounded; a stale gyro): the turn since the last rate is not
        // known, and the check starts afresh from the next rate.
        if self.limits.gyro.is_some() && obs.gyro_deg_s.is_none() {
            self.restart_gyro();
        }
        let point = self.advance(obs);
        if self.limits.gyro.is_some() {
            if obs.gyro_deg_s.is_none() {
                // The window starts at the first reading with a rate.
                self.window.clear();
            }
            match obs.gyro_deg_s {
                Some(_) => self.check_gyro(point, &mut reasons),
                // A reading the gyro cannot check (a 3-axis compass pitched
                // too far, a stale gyro) is not trusted on its word while a
                // distrust it found holds.
                None if self.reference.is_some() || self.lost_agreed_s.is_some() => reasons.push(
                    "the heading cannot be checked against the gyro at this reading, and was off the gyro's before it"
                        .to_string(),
                ),
                None => {}
            }
        }
        self.record(obs.time, reasons)
    }

    /// The bound the next reading's |field ratio − 1| is held to: the
    /// entering one while the field is trusted, the leaving one while not.
    fn field_bound(&self) -> f64 {
        (if self.field_distrusted {
            LEAVE_SIGMAS
        } else {
            ENTER_SIGMAS
        }) * self.limits.field_sigma
    }

    /// |(x, y)| / r, a 2-axis reading's [`Observation::field_ratio`] for
    /// the next check: from the squares when they decide that check
    /// whatever the last bits of the distance (the ratio within its bound
    /// by 1e-12 of it or of 1, far beyond the few ulp between √(x² + y²) and
    /// `hypot`'s; the squares far from the ends of f64's range), else
    /// `hypot`'s ratio itself: every decision, and the message of a
    /// reading distrusted, are those of `hypot`'s ratio, at a tenth of its
    /// cost on nearly every reading.
    pub fn plane_field_ratio(&self, [x, y]: [f64; 2], r: f64) -> f64 {
        const MARGIN: f64 = 1e-12;
        let d2 = x * x + y * y;
        if (1e-200..1e200).contains(&d2) && (1e-100..1e100).contains(&r) {
            let ratio = d2.sqrt() / r;
            if (ratio - 1.0).abs() + MARGIN * ratio.max(1.0) < self.field_bound() {
                return ratio;
            }
        }
        x.hypot(y) / r
    }

    fn check_field(&mut self, ratio: f64, reasons: &mut Vec<String>) {
        let sigma = self.limits.field_sigma;
        let e = ratio - 1.0;
        let bound = self.field_bound();
        self.field_distrusted = e.abs() > bound;
        if self.field_distrusted {
            let (sigmas, until) = if bound == ENTER_SIGMAS * sigma {
                (ENTER_SIGMAS, "")
            } else {
                (LEAVE_SIGMAS, ", trusted again within it")
            };
            reasons.push(format!(
                "the field is {:.1} % {} the calibration's r (limit {:.1} %: {sigmas} σ of its noise{until})",
                e.abs() * 100.0,
                if e < 0.0 { "below" } else { "above" },
                bound * 100.0,
            ));
        }
    }

    /// Moves the heading and the gyro on to `obs`, and the window with them.
    fn advance(&mut self, obs: Observation) -> Point {
        let heading = match self.previous {
            Some((_, h)) => h + wrap180(obs.heading_deg - h),
            None => obs.heading_deg,
        };
        if let (Some(g), Some(rate)) = (self.limits.gyro, obs.gyro_deg_s)
            && rate.is_finite()
        {
            if let Some((t0, rate0)) = self.last {
                let dt = obs.time - t0;
                if dt > 0.0 {
                    let mean = 0.5 * (rate + rate0) - g.bias_deg_s;
                    self.gyro_angle += g.scale * mean * dt;
                }
            }
            self.last = Some((obs.time, rate));
        }
        self.previous = Some((obs.time, heading));
        let point = Point {
            time: obs.time,
            heading,
            gyro: self.gyro_angle,
        };
        self.window.push_back(point);
        // Keep one point at or before the window's start as its anchor.
        while self.window.len() > MAX_WINDOW_READINGS
            || (self.window.len() > 1 && self.window[1].time <= obs.time - WINDOW_S)
        {
            self.window.pop_front();
        }
        point
    }

    /// The gyro check afresh from the next reading with a rate: no
    /// window, no reference, no rate to integrate from. A heading that was
    /// distrusted against the gyro stays so, until a whole window agrees.
    fn restart_gyro(&mut self) {
        if self.reference.is_some() {
            self.lost_agreed_s = Some(0.0);
        }
        self.reference = None;
        self.last = None;
        self.window.clear();
    }

    /// The heading's change against the gyro's: over the window while
    /// trusted, from the last trusted point while not.
    fn check_gyro(&mut self, now: Point, reasons: &mut Vec<String>) {
        let anchor = match self.reference {
            Some(r) => r,
            None => match self.window.front() {
                Some(a) => *a,
                None => return,
            },
        };
        let dt = now.time - anchor.time;
        let turned = now.gyro - anchor.gyro + self.drift * dt;
        let moved = now.heading - anchor.heading;
        let mismatch = wrap180(moved - turned);
        let h = self.limits.heading_sigma_deg;
        let sigma =
            (2.0 * h * h + (GYRO_SCALE_SD * turned).powi(2) + (GYRO_BIAS_SD_DEG_S * dt).powi(2))
                .sqrt();
        match self.reference {
            None if mismatch.abs() > ENTER_SIGMAS * sigma => {
                self.reference = Some(anchor);
                if self.lost_agreed_s.is_some() {
                    self.lost_agreed_s = Some(0.0);
                }
                reasons.push(format!(
                    "the heading moved {:.1}° in {:.1} s while the gyro turned {:.1}° (limit {:.1}°: 5 σ)",
                    moved,
                    dt,
                    turned,
                    ENTER_SIGMAS * sigma
                ));
            }
            None if self.lost_agreed_s.is_some() => {
                // After the gyro lost the heading: agreement adding up to a
                // window (across the gaps a tumble makes) brings trust back.
                let step = self.window.iter().rev().nth(1).map_or(0.0, |p| now.time - p.time);
                let agreed = self.lost_agreed_s.unwrap_or(0.0) + step;
                if agreed >= WINDOW_S {
                    self.lost_agreed_s = None;
                } else {
                    self.lost_agreed_s = Some(agreed);
                    reasons.push(format!(
                        "the heading was off the gyro's when the gyro lost it, and has agreed with it again for {agreed:.1} s of the {WINDOW_S} s it must"
                    ));
                }
            }
            None => {
                // Trusted: follow the gyro's slow drift against the heading.
                let step = self.window.iter().rev().nth(1).map_or(0.0, |p| now.time - p.time);
                if dt >= 0.5 * WINDOW_S && step > 0.0 {
                    let weight = (step / BIAS_TAU_S).min(1.0);
                    self.drift += weight * mismatch / dt;
                }
            }
            Some(_) if mismatch.abs() <= LEAVE_SIGMAS * sigma => {
                // Back on the gyro's reference: the window starts afresh.
                self.reference = None;
                self.window.clear();
                self.window.push_back(now);
            }
            Some(_) => reasons.push(format!(
                "the heading is {:.1}° off the gyro's since the last trusted reading {:.1} s ago (trusted again within {:.1}°)",
                mismatch,
                dt,
                LEAVE_SIGMAS * sigma
            )),
        }
    }

    fn record(&mut self, time: f64, reasons: Vec<String>) -> Verdict {
        let trusted = reasons.is_empty();
        self.now = reasons.first().cloned();
        if trusted {
            self.counts.trusted += 1;
            self.stretch_start = None;
        } else {
            self.counts.distrusted += 1;
            let start = *self.stretch_start.get_or_insert(time);
            let span = time - start;
            if span.is_finite() && span > self.counts.longest_distrusted_s {
                self.counts.longest_distrusted_s = span;
            }
        }
        Verdict { trusted, reasons }
    }
}

/// How far a distrusted value is off its reference, and the bound it broke.
struct Beyond {
    off: f64,
    bound: f64,
    /// The bound in σ: [`ENTER_SIGMAS`], or [`LEAVE_SIGMAS`] while leaving.
    sigmas: f64,
    /// ", trusted again within it" while leaving, else "".
    until: &'static str,
}

/// A reading `value` against a measured `limit`, with hysteresis on
/// `distrusted`: beyond [`ENTER_SIGMAS`] σ it is distrusted, and stays so
/// until within [`LEAVE_SIGMAS`] σ. When distrusted: how far it is off,
/// and the bound it broke; a value that is not finite is not judged.
fn beyond(distrusted: &mut bool, limit: ReferenceLimit, value: f64) -> Option<Beyond> {
    if !value.is_finite() {
        return None;
    }
    let leaving = *distrusted;
    let sigmas = if leaving { LEAVE_SIGMAS } else { ENTER_SIGMAS };
    let off = value - limit.reference;
    *distrusted = off.abs() > sigmas * limit.sigma;
    distrusted.then_some(Beyond {
        off,
        bound: sigmas * limit.sigma,
        sigmas,
        until: if leaving {
            ", trusted again within it"
        } else {
            ""
        },
    })
}

/// The monitor of calibration `id` in `slot`, started afresh with
/// `limits()` when the slot holds none or another calibration's.
pub fn monitor_of(
    slot: &mut Option<(u64, TrustMonitor)>,
    id: u64,
    limits: impl FnOnce() -> TrustLimits,
) -> &mut TrustMonitor {
    if slot.as_ref().is_some_and(|(held, _)| *held != id) {
        *slot = None;
    }
    &mut slot
        .get_or_insert_with(|| (id, TrustMonitor::new(limits())))
        .1
}

/// An angle in (−180, 180].
fn wrap180(deg: f64) -> f64 {
    let w = crate::model::heading::wrap_degrees(deg);
    if w > 180.0 { w - 360.0 } else { w }
}

/// Most stretches a recording's report lists; more are counted.
pub const MAX_STRETCHES: usize = 1000;

/// A run of distrusted readings in a recording.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Stretch {
    /// Times of its first and last reading, seconds.
    pub from_s: f64,
    pub to_s: f64,
    pub readings: usize,
    /// Why its first reading was distrusted.
    pub reason: String,
}

/// The monitor run over a whole recording ([`monitor_recording`]).
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct RecordingTrust {
    #[serde(flatten)]
    pub counts: TrustCounts,
    /// The field's limit when it enters distrust (5 σ), fraction of r.
    pub field_limit: f64,
    /// Whether the heading was checked against a gyro.
    pub gyro_checked: bool,
    /// The distrusted stretches in time order, at most [`MAX_STRETCHES`].
    pub stretches: Vec<Stretch>,
    /// Stretches beyond [`MAX_STRETCHES`], counted only.
    pub stretches_left_out: usize,
    /// Per reading: trusted or not.
    #[serde(skip)]
    pub trusted: Vec<bool>,
}

/// Runs one monitor over a recording's calibrated readings in time order:
/// `t` (seconds), `field_ratio` (|corrected|/r), `heading_deg`, and the
/// gyro's integrated angle at each time (degrees, NaN where it has none)
/// when there is a gyro; its rate between readings is what the monitor
/// integrates. O(n).
pub fn monitor_recording(
    limits: TrustLimits,
    t: &[f64],
    field_ratio: &[f64],
    heading_deg: &[f64],
    gyro_angle_deg: Option<&[f64]>,
) -> RecordingTrust {
    let field_limit = ENTER_SIGMAS * limits.field_sigma;
    let gyro_checked = limits.gyro.is_some() && gyro_angle_deg.is_some();
    let mut monitor = TrustMonitor::new(limits);
    let n = t.len().min(field_ratio.len()).min(heading_deg.len());
    let rate = |i: usize| -> Option<f64> {
        let angles = gyro_angle_deg?;
        let (j, k) = if i == 0 { (0, 1) } else { (i - 1, i) };
        let dt = t.get(k)? - t.get(j)?;
        let r = (angles.get(k)? - angles.get(j)?) / dt;
        (dt > 0.0 && r.is_finite()).then_some(r)
    };
    let mut trusted = Vec::with_capacity(n);
    let (mut stretches, mut left_out) = (Vec::new(), 0usize);
    let mut open: Option<Stretch> = None;
    let mut last_rate = None;
    for i in 0..n {
        // A reading at the time of the one before (a repeated time stamp)
        // has no rate of its own: the one before's holds.
        let repeated = i > 0 && t[i] == t[i - 1];
        let gyro_deg_s = if repeated { last_rate } else { rate(i) };
        last_rate = gyro_deg_s;
        let verdict = monitor.check(Observation {
            time: t[i],
            field_ratio: field_ratio[i],
            heading_deg: heading_deg[i],
            gyro_deg_s,
            dip_deg: None,
            across: None,
            tilt_deg: None,
        });
        trusted.push(verdict.trusted);
        match (&mut open, verdict.trusted) {
            (Some(s), false) => {
                s.to_s = t[i];
                s.readings += 1;
            }
            (None, false) => {
                open = Some(Stretch {
                    from_s: t[i],
                    to_s: t[i],
                    readings: 1,
                    reason: verdict.reasons.into_iter().next().unwrap_or_default(),
                });
            }
            (_, true) => {
                if let Some(s) = open.take() {
                    push_capped(&mut stretches, &mut left_out, s);
                }
            }
        }
    }
    if let Some(s) = open.take() {
        push_capped(&mut stretches, &mut left_out, s);
    }
    RecordingTrust {
        counts: monitor.counts(),
        field_limit,
        gyro_checked,
        stretches,
        stretches_left_out: left_out,
        trusted,
    }
}

fn push_capped(stretches: &mut Vec<Stretch>, left_out: &mut usize, s: Stretch) {
    if stretches.len() < MAX_STRETCHES {
        stretches.push(s);
    } else {
        *left_out += 1;
    }
}
