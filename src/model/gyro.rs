//! A gyroscope as a heading reference.
//!
//! A gyroscope axis about the turn's axis, integrated over time, says how far
//! the sensor turned between any two samples, independently of the field
//! sensor. A calibration that is right turns the calibrated heading
//! `atan2(s_y, s_x)` by the same angle; what differs is heading error the
//! magnitude `|s|` cannot show (a model can make `|s|` rounder by distorting
//! where each sample points).
//!
//! The gyro is not trusted blindly: its sign depends on how it is mounted,
//! its sensitivity has a tolerance, an axis tilted by φ from the turn's axis
//! reads cos φ of the rate, and its zero-rate output drifts. So the check fits
//! `heading ≈ h0 + scale·angle + bias·(t − mean t)` over the recording and
//! reports what remains; a `scale` far from ±1 means the column is not the
//! axis about which the sensor turned.

use serde::Serialize;

use super::residuals::{CentredSums, centred_sums};

/// Units of the gyro's rate column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
pub enum GyroUnits {
    #[value(name = "deg/s")]
    DegPerSecond,
    #[value(name = "rad/s")]
    RadPerSecond,
}

impl GyroUnits {
    /// Degrees per second in one unit of the column.
    pub fn to_deg_per_second(self) -> f64 {
        match self {
            GyroUnits::DegPerSecond => 1.0,
            GyroUnits::RadPerSecond => 180.0 / std::f64::consts::PI,
        }
    }
}

/// Smallest |scale| the fit may find for a gyro about the turn's axis. An
/// axis tilted by φ from the turn's axis reads cos φ of the rate; 0.7 is
/// cos 45.6°: beyond that tilt another axis of a 3-axis gyro sees at least as
/// much of the turn, so this column is the wrong choice. The MPU-6050's
/// sensitivity tolerance (±3 %, datasheet PS-MPU-6000A-00 §6.1, "Sensitivity
/// Scale Factor Tolerance") is far inside the bound.
pub const MIN_GYRO_SCALE: f64 = 0.7;

/// Largest |scale|: the reciprocal of [`MIN_GYRO_SCALE`]. A gyro does not
/// read more than the rate (±3 % sensitivity); a heading that turns this much
/// faster than the gyro says is not the gyro's turn.
pub const MAX_GYRO_SCALE: f64 = 1.0 / MIN_GYRO_SCALE;

/// The gyro's angle must span at least half a turn over the checked samples:
/// over less, its scale and bias are not pinned down against a heading error
/// that varies with heading (a second harmonic has a period of half a turn).
pub const MIN_GYRO_SPAN_DEG: f64 = 180.0;

/// The gyro's bias is fitted beside its scale only where the recording pins
/// the scale to this standard error in that fit: 1 %. The gyro's own
/// tolerance is ±3 % (MPU-6050 datasheet, "Sensitivity Scale Factor
/// Tolerance"); a fit that cannot pin the scale within a third of that
/// cannot tell a bias from a scale (a turn at a constant rate: the gyro's
/// angle is then a line in time, bent only by its noise), and the bias is
/// left in the scale instead.
pub const MAX_SCALE_SE: f64 = 0.01;

/// Contiguous time batches for the standard error of a comparison: heading
/// errors are strongly autocorrelated (they follow heading, which follows
/// time), so samples are not independent; ~20 batch means are (nearly)
/// independent and still give the standard error to about ±16 % (1/√(2·19)).
pub const COMPARISON_BATCHES: usize = 20;

/// Fewest samples a check accepts: two per comparison batch, and far more
/// than the three parameters fitted.
pub const MIN_CHECK_SAMPLES: usize = 2 * COMPARISON_BATCHES;

/// Why a gyro cannot serve as a heading reference. Messages say what was
/// found and what to do; the caller adds the file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GyroError {
    #[error(
        "the gyro column '{column}' has {found} values and its time column {times}: each gyro reading needs its time"
    )]
    LengthMismatch {
        column: String,
        found: usize,
        times: usize,
    },
    #[error(
        "the gyro column '{column}' has {found} readings; integrating it needs at least 2, over the time of the recording"
    )]
    TooFewGyroSamples { column: String, found: usize },
    #[error("the {what} at row {index} is {value}, not a finite number: remove or repair that row")]
    NotFinite {
        what: String,
        index: usize,
        value: f64,
    },
    #[error(
        "the {what} go backwards at row {index} ({previous} then {value}): the times must be in increasing order, on one clock"
    )]
    NotMonotonic {
        what: String,
        index: usize,
        previous: f64,
        value: f64,
    },
    #[error(
        "only {} within the gyro's time span ({gyro_start} s to {gyro_end} s), and the check needs {needed}; the recording runs from {sample_start} s to {sample_end} s: the two must be on the same clock and overlap",
        crate::sample::count(*overlapping as u64, "sample")
    )]
    NoOverlap {
        overlapping: usize,
        needed: usize,
        gyro_start: f64,
        gyro_end: f64,
        sample_start: f64,
        sample_end: f64,
    },
    #[error(
        "{found} headings were given for {expected} samples: give one heading per sample of the recording"
    )]
    HeadingCount { found: usize, expected: usize },
    #[error(
        "only {} can be checked against the gyro (with a gyro reading and a finite heading, not flagged), and the check needs {needed}",
        crate::sample::count(*found as u64, "sample")
    )]
    TooFewChecked { found: usize, needed: usize },
    #[error(
        "the gyro '{column}' turns through only {span_deg:.0}° over the checked samples, and a heading check needs at least {needed_deg:.0}°: the sensor did not turn about this gyro's axis; choose the gyro axis perpendicular to the two chosen axes (e.g. gyro_z for x and y), or check the units (--gyro-units)"
    )]
    NoTurnSeen {
        column: String,
        span_deg: f64,
        needed_deg: f64,
    },
    #[error(
        "the heading turns {scale:.2} times as fast as the gyro '{column}' says (a gyro about the turn's axis gives ±1 within its ±3 % tolerance; the check accepts {min:.2} to {max:.2} in size): this column is not the axis about which the sensor turned; choose the gyro axis perpendicular to the two chosen axes (e.g. gyro_z for x and y), or check the units (--gyro-units)"
    )]
    WrongAxis {
        column: String,
        scale: f64,
        min: f64,
        max: f64,
    },
}

/// A gyro's integrated angle at each sample of a recording.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadingReference {
    column: String,
    /// The gyro's angle in degrees (trapezoid on the gyro's own clock),
    /// interpolated at each sample time; NaN outside the gyro's time span.
    angle_deg: Vec<f64>,
    /// The recording's sample times, in seconds.
    sample_t: Vec<f64>,
}

/// Checks a time column: finite and never going backwards.
fn check_times(what: &str, t: &[f64]) -> Result<(), GyroError> {
    for (i, &v) in t.iter().enumerate() {
        if !v.is_finite() {
            return Err(GyroError::NotFinite {
                what: what.to_string(),
                index: i + 1,
                value: v,
            });
        }
        if i > 0 && v < t[i - 1] {
            return Err(GyroError::NotMonotonic {
                what: what.to_string(),
                index: i + 1,
                previous: t[i - 1],
                value: v,
            });
        }
    }
    Ok(())
}

/// Linear interpolation of `y(x)` at `at`, `x` non-decreasing; NaN outside.
fn interpolate(x: &[f64], y: &[f64], at: f64) -> f64 {
    let (Some(&first), Some(&last)) = (x.first(), x.last()) else {
        return f64::NAN;
    };
    if !(at >= first && at <= last) {
        return f64::NAN;
    }
    // First index with x > at (1..=len); the segment is [k-1, k].
    let k = x.partition_point(|&v| v <= at);
    if k >= x.len() {
        return y[x.len() - 1];
    }
    let (x0, x1, y0, y1) = (x[k - 1], x[k], y[k - 1], y[k]);
    let dx = x1 - x0;
    if dx > 0.0 {
        y0 + (y1 - y0) * (at - x0) / dx
    } else {
        y0
    }
}

/// Wraps degrees to (-180, 180].
fn wrap_deg(d: f64) -> f64 {
    let w = (d + 180.0).rem_euclid(360.0) - 180.0;
    if w == -180.0 { 180.0 } else { w }
}

impl HeadingReference {
    /// Integrates a gyro's rate (trapezoid, on the gyro's own clock `gyro_t`)
    /// and interpolates its angle at each sample time `sample_t`.
    pub fn from_rates(
        column: &str,
        sample_t: &[f64],
        gyro_t: &[f64],
        rate: &[f64],
        units: GyroUnits,
    ) -> Result<Self, GyroError> {
        if gyro_t.len() != rate.len() {
            return Err(GyroError::LengthMismatch {
                column: column.to_string(),
                found: rate.len(),
                times: gyro_t.len(),
            });
        }
        if rate.len() < 2 {
            return Err(GyroError::TooFewGyroSamples {
                column: column.to_string(),
                found: rate.len(),
            });
        }
        check_times("sample times", sample_t)?;
        check_times(&format!("times of the gyro '{column}'"), gyro_t)?;
        if let Some(i) = rate.iter().position(|r| !r.is_finite()) {
            return Err(GyroError::NotFinite {
                what: format!("gyro rate '{column}'"),
                index: i + 1,
                value: rate[i],
            });
        }
        let k = units.to_deg_per_second();
        let mut angle = Vec::with_capacity(rate.len());
        let mut acc = 0.0;
        angle.push(acc);
        for i in 1..rate.len() {
            acc += 0.5 * (rate[i - 1] + rate[i]) * k * (gyro_t[i] - gyro_t[i - 1]);
            angle.push(acc);
        }
        let angle_deg: Vec<f64> = sample_t
            .iter()
            .map(|&t| interpolate(gyro_t, &angle, t))
            .collect();
        let overlapping = angle_deg.iter().filter(|a| a.is_finite()).count();
        if overlapping < MIN_CHECK_SAMPLES {
            return Err(GyroError::NoOverlap {
                overlapping,
                needed: MIN_CHECK_SAMPLES,
                gyro_start: gyro_t[0],
                gyro_end: gyro_t[gyro_t.len() - 1],
                sample_start: sample_t.first().copied().unwrap_or(f64::NAN),
                sample_end: sample_t.last().copied().unwrap_or(f64::NAN),
            });
        }
        Ok(HeadingReference {
            column: column.to_string(),
            angle_deg,
            sample_t: sample_t.to_vec(),
        })
    }

    /// The gyro's integrated angle at each sample time, degrees (NaN
    /// outside its time span): no scale or bias applied.
    pub fn angles_deg(&self) -> &[f64] {
        &self.angle_deg
    }

    /// The gyro column's name.
    pub fn column(&self) -> &str {
        &self.column
    }

    /// Heading error of a model against the gyro: `headings_rad` are the
    /// model's calibrated headings atan2(s_y, s_x), one per dataset sample in
    /// dataset order; samples whose index is in `skip` (ascending; a robust
    /// fit's flagged samples) are left out. Fits heading_deg ≈ h0 +
    /// scale·gyro_angle + bias·(t - mean t) by least squares on the unwrapped
    /// model heading (time order), so the gyro's scale and sign (scale ≈ ±1)
    /// and its bias are fitted over the recording; errors are what remains,
    /// wrapped to (-180, 180].
    pub fn check(&self, headings_rad: &[f64], skip: &[usize]) -> Result<HeadingCheck, GyroError> {
        let n_all = self.sample_t.len();
        if headings_rad.len() != n_all {
            return Err(GyroError::HeadingCount {
                found: headings_rad.len(),
                expected: n_all,
            });
        }
        let mut skip_iter = skip.iter().copied().peekable();
        let mut idx = Vec::with_capacity(n_all);
        for (i, (angle, heading)) in self.angle_deg.iter().zip(headings_rad).enumerate() {
            while skip_iter.peek().is_some_and(|&s| s < i) {
                skip_iter.next();
            }
            if skip_iter.peek() == Some(&i) {
                continue;
            }
            if angle.is_finite() && heading.is_finite() {
                idx.push(i);
            }
        }
        let n = idx.len();
        if n < MIN_CHECK_SAMPLES {
            return Err(GyroError::TooFewChecked {
                found: n,
                needed: MIN_CHECK_SAMPLES,
            });
        }
        let g: Vec<f64> = idx.iter().map(|&i| self.angle_deg[i]).collect();
        let t: Vec<f64> = idx.iter().map(|&i| self.sample_t[i]).collect();
        let (gmin, gmax) = g
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                (lo.min(v), hi.max(v))
            });
        let span = gmax - gmin;
        if !(span >= MIN_GYRO_SPAN_DEG) {
            return Err(GyroError::NoTurnSeen {
                column: self.column.clone(),
                span_deg: span,
                needed_deg: MIN_GYRO_SPAN_DEG,
            });
        }
        // The model's heading, unwrapped in time order.
        let mut h = Vec::with_capacity(n);
        let mut prev = headings_rad[idx[0]].to_degrees();
        let mut acc = prev;
        h.push(acc);
        for &i in &idx[1..] {
            let d = headings_rad[i].to_degrees();
            acc += wrap_deg(d - prev);
            prev = d;
            h.push(acc);
        }
        // Least squares on centred columns: h - mh = s (g - mg) + b (t - mt).
        let CentredSums {
            means: [mg, mt, mh],
            aa: sgg,
            bb: stt,
            ab: sgt,
            ac: sgh,
            bc: sth,
            cc: shh,
        } = centred_sums(&g, &t, &h);
        let det = sgg * stt - sgt * sgt;
        // The scale and the bias together, where the turn's rate varied
        // enough to tell them apart: the scale's standard error from that
        // fit at most [`MAX_SCALE_SE`]. When the turn ran at a constant
        // rate, the gyro's angle is a line in time (bent only by its own
        // noise) and its bias cannot be told from its scale: fitted on that
        // bend, the bias would chase the heading's noise and throw the
        // scale anywhere. The heading error is the same either way, so the
        // bias is then left in the scale (reported as 0).
        // A system that is singular to rounding (an exact constant rate)
        // has no standard error to trust either: it keeps the scale alone.
        let both = (stt > 0.0 && det > 1e-9 * sgg * stt).then(|| {
            let scale = (sgh * stt - sth * sgt) / det;
            let bias = (sth * sgg - sgh * sgt) / det;
            let rss = (shh - scale * sgh - bias * sth).max(0.0);
            let sigma_sq = rss / n.saturating_sub(3).max(1) as f64;
            (scale, bias, (sigma_sq * stt / det).sqrt())
        });
        let (scale, bias) = match both {
            Some((scale, bias, se)) if se <= MAX_SCALE_SE => (scale, bias),
            _ => (sgh / sgg, 0.0),
        };
        if !(scale.abs() >= MIN_GYRO_SCALE && scale.abs() <= MAX_GYRO_SCALE) {
            return Err(GyroError::WrongAxis {
                column: self.column.clone(),
                scale,
                min: MIN_GYRO_SCALE,
                max: MAX_GYRO_SCALE,
            });
        }
        let mut errors_deg = vec![f64::NAN; n_all];
        let mut reference_deg = vec![f64::NAN; n_all];
        let (mut ss, mut lo, mut hi) = (0.0, f64::INFINITY, f64::NEG_INFINITY);
        for k in 0..n {
            let fitted = mh + scale * (g[k] - mg) + bias * (t[k] - mt);
            let e = wrap_deg(h[k] - fitted);
            errors_deg[idx[k]] = e;
            reference_deg[idx[k]] = fitted;
            ss += e * e;
            lo = lo.min(e);
            hi = hi.max(e);
        }
        Ok(HeadingCheck {
            gyro_column: self.column.clone(),
            rms_deg: (ss / n as f64).sqrt(),
            peak_to_peak_deg: hi - lo,
            n,
            gyro_scale: scale,
            // heading rate = scale·(gyro rate) + bias, so the gyro reads
            // −bias/scale when the heading stands still.
            gyro_bias_deg_s: if bias == 0.0 { 0.0 } else { -bias / scale },
            errors_deg,
            reference_deg,
        })
    }
}

/// Harmonics of heading taken out of a comparison's differences before its
/// standard error: the calibration effects of the catalogue distort heading
/// by harmonics up to the 4th, and a difference of squared errors doubles
/// the orders.
pub const COMPARISON_HARMONICS: usize = 8;

/// `values` less their least-squares fit on a constant and harmonics 1 to
/// [`COMPARISON_HARMONICS`] of `headings_deg`; the values unchanged when the
/// headings are unknown or too few samples pin the fit (three per column).
fn without_heading_pattern(values: &[f64], headings_deg: &[f64]) -> Vec<f64> {
    let columns = 1 + 2 * COMPARISON_HARMONICS;
    let n = values.len();
    if n < 3 * columns || headings_deg.len() != n || !headings_deg.iter().all(|h| h.is_finite()) {
        return values.to_vec();
    }
    let row = |h: f64| -> Vec<f64> {
        let h = h.to_radians();
        (0..columns)
            .map(|j| match j {
                0 => 1.0,
                j if j % 2 == 1 => (j.div_ceil(2) as f64 * h).cos(),
                j => ((j / 2) as f64 * h).sin(),
            })
            .collect()
    };
    // Normal equations: a 17 × 17 system however long the recording.
    let mut ata = nalgebra::DMatrix::<f64>::zeros(columns, columns);
    let mut atb = nalgebra::DVector::<f64>::zeros(columns);
    for (&h, &v) in headings_deg.iter().zip(values) {
        let r = row(h);
        for (u, ru) in r.iter().enumerate() {
            atb[u] += ru * v;
            for (w, rw) in r.iter().enumerate() {
                ata[(u, w)] += ru * rw;
            }
        }
    }
    let Some(coefficients) = ata.cholesky().map(|c| c.solve(&atb)) else {
        return values.to_vec();
    };
    let fitted: Vec<f64> = headings_deg
        .iter()
        .map(|&h| {
            row(h)
                .iter()
                .zip(coefficients.iter())
                .map(|(r, c)| r * c)
                .sum()
        })
        .collect();
    // The constant stays: it is the mean difference being measured.
    values
        .iter()
        .zip(fitted.iter())
        .map(|(v, f)| v - f + coefficients[0])
        .collect()
}

/// A model's heading error against a gyro.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HeadingCheck {
    /// The gyro column the heading was checked against.
    pub gyro_column: String,
    /// Root mean square of the heading error, degrees.
    pub rms_deg: f64,
    /// Largest less smallest heading error, degrees.
    pub peak_to_peak_deg: f64,
    /// Samples checked.
    pub n: usize,
    /// Heading turned per degree of gyro angle (±1 for a gyro about the turn's
    /// axis; the sign says how it is mounted).
    pub gyro_scale: f64,
    /// What the gyro reads at rest, deg/s (0 when a constant-rate turn leaves
    /// it undetermined).
    pub gyro_bias_deg_s: f64,
    /// Per dataset sample, degrees; NaN where not checked.
    #[serde(skip)]
    pub errors_deg: Vec<f64>,
    /// The heading the gyro gives each sample (its fitted angle), degrees;
    /// NaN where not checked. Empty when unknown.
    #[serde(skip)]
    pub reference_deg: Vec<f64>,
}

/// How much worse one model's heading is than another's.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct HeadingDelta {
    /// rms(other) − rms(self) over the samples both checked, degrees.
    pub delta_rms_deg: f64,
    /// Its standard error, degrees (NaN with too few samples).
    pub se_deg: f64,
}

impl HeadingCheck {
    /// How much worse `other` (another model on the same samples) is than
    /// `self`, in rms heading error, with a standard error that respects the
    /// strong autocorrelation of heading errors (batch means over ~20
    /// contiguous time batches, propagated to rms).
    ///
    /// The batches see `e_other² − e_self²` less its pattern in heading
    /// (harmonics 1 to [`COMPARISON_HARMONICS`] of the gyro's heading, when
    /// the checks carry it): two models' headings differ by a pattern locked
    /// to heading, which is the very difference being measured and repeats
    /// on every turn, not noise; what varies from turn to turn (sensor and
    /// gyro noise, a hand's wobble) is what makes the mean uncertain. Left
    /// in, the pattern would swell the standard error of any systematic
    /// difference until no distortion could ever be told from chance.
    pub fn worse_by(&self, other: &HeadingCheck) -> HeadingDelta {
        let heading = |i: usize| self.reference_deg.get(i).copied().unwrap_or(f64::NAN);
        let d: Vec<(f64, f64, f64)> = self
            .errors_deg
            .iter()
            .zip(&other.errors_deg)
            .enumerate()
            .filter(|(_, (a, b))| a.is_finite() && b.is_finite())
            .map(|(i, (&a, &b))| (a, b, heading(i)))
            .collect();
        let n = d.len();
        if n == 0 {
            return HeadingDelta {
                delta_rms_deg: f64::NAN,
                se_deg: f64::NAN,
            };
        }
        let ms_self = d.iter().map(|(a, _, _)| a * a).sum::<f64>() / n as f64;
        let ms_other = d.iter().map(|(_, b, _)| b * b).sum::<f64>() / n as f64;
        let (rs, ro) = (ms_self.sqrt(), ms_other.sqrt());
        let sum = rs + ro;
        // rms_o − rms_s = (ms_o − ms_s) / (rms_o + rms_s): exact, and linear
        // in the mean difference of squares, whose SE the batches give.
        if !(sum > 0.0) {
            return HeadingDelta {
                delta_rms_deg: 0.0,
                se_deg: 0.0,
            };
        }
        let diff: Vec<f64> = d.iter().map(|(a, o, _)| o * o - a * a).collect();
        let headings: Vec<f64> = d.iter().map(|(_, _, h)| *h).collect();
        let noise = without_heading_pattern(&diff, &headings);
        let batches = COMPARISON_BATCHES.min(n / 2);
        let se_mean = if batches >= 2 {
            let means: Vec<f64> = (0..batches)
                .map(|b| {
                    let (start, end) = (b * n / batches, (b + 1) * n / batches);
                    noise[start..end].iter().sum::<f64>() / (end - start) as f64
                })
                .collect();
            let m = means.iter().sum::<f64>() / batches as f64;
            let var = means.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (batches - 1) as f64;
            (var / batches as f64).sqrt()
        } else {
            f64::NAN
        };
        HeadingDelta {
            delta_rms_deg: (ms_other - ms_self) / sum,
            se_deg: se_mean / sum,
        }
    }
}

#[cfg(test)]
mod wrap_tests {
    use super::*;

    #[test]
    fn wrap_is_in_the_half_open_interval() {
        assert_eq!(wrap_deg(180.0), 180.0);
        assert_eq!(wrap_deg(-180.0), 180.0);
        assert!((wrap_deg(190.0) + 170.0).abs() < 1e-12);
        assert!((wrap_deg(-721.0) + 1.0).abs() < 1e-12);
    }
}
