//! Checking a fit before it replaces the current calibration.
//!
//! A fit can succeed numerically and still be wrong: a turn disturbed by a
//! passing motor, a partial arc, swapped axes. ArduPilot's compass
//! calibrator judges its fits by fitness (residual), field radius, offsets
//! and scale factors before it accepts one; this module does the same for
//! the paper's model, so a bad rotation never replaces a good calibration.

use serde::{Deserialize, Serialize};

use crate::model::fit::FitReport;

/// What a fit must meet to be accepted. Every limit is relative to the
/// fitted field except the optional radius bounds, since raw counts have no
/// scale the daemon could know.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct Limits {
    /// Largest root mean square of |calibrated|/r - 1 (a fraction of the field).
    pub max_rms: f64,
    /// Smallest field radius r, in y's raw counts, when the user knows it.
    pub min_radius: Option<f64>,
    /// Largest field radius r, in y's raw counts, when the user knows it.
    pub max_radius: Option<f64>,
    /// Largest |offset| / r, the offset taken after the gain (|(b, d)|).
    pub max_offset_ratio: f64,
    /// Largest max(a, 1/a): how far the two axes' gains may differ.
    pub max_scale_ratio: f64,
    /// Smallest heading coverage of the fitted samples, in degrees.
    pub min_coverage_deg: f64,
}

impl Default for Limits {
    /// - `max_rms` 0.05: ArduPilot's default fitness tolerance is about 3 %
    ///   of the Earth's field; 5 % leaves room for a 2-axis sensor tilted a
    ///   little on a robot and for effects the paper's model lacks, while a
    ///   fit worse than that means heading errors of several degrees.
    /// - `max_offset_ratio` 5: ArduPilot accepts offsets up to 1000-1800 mG
    ///   (COMPASS_OFFS_MAX) beside fields of 250-850 mG, that is about 1.2 to
    ///   7 fields; 5 accepts a compass mounted near motors and batteries.
    /// - `max_scale_ratio` 2: the paper's `a` is the gain ratio of two axes
    ///   of one chip, which match within a few percent; soft iron adds tens of
    ///   percent. ArduPilot's per-axis bound (0.2 to 5) is a loose sanity
    ///   check of a 3-D soft-iron matrix; a ratio beyond 2 here is far more
    ///   likely a wrong axis or a degenerate fit than a real sensor.
    /// - `min_coverage_deg` 300: the fit's own default, see
    ///   [`crate::model::fit::DEFAULT_MIN_COVERAGE_DEG`].
    fn default() -> Self {
        Limits {
            max_rms: 0.05,
            min_radius: None,
            max_radius: None,
            max_offset_ratio: crate::model::validity::DEFAULT_MAX_OFFSET_RATIO,
            max_scale_ratio: crate::model::validity::DEFAULT_MAX_SCALE_RATIO,
            min_coverage_deg: crate::model::fit::DEFAULT_MIN_COVERAGE_DEG,
        }
    }
}

impl Limits {
    /// Checks the limits themselves; the message names the key.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.max_rms.is_finite() && self.max_rms > 0.0 && self.max_rms <= 1.0) {
            return Err(format!(
                "max_rms must be a fraction of the field above 0 and at most 1 (0.05 = 5 %), got {}",
                self.max_rms
            ));
        }
        for (key, value) in [
            ("min_radius", self.min_radius),
            ("max_radius", self.max_radius),
        ] {
            if let Some(v) = value
                && !(v.is_finite() && v > 0.0)
            {
                return Err(format!(
                    "{key} must be a positive number of counts, got {v}"
                ));
            }
        }
        if let (Some(lo), Some(hi)) = (self.min_radius, self.max_radius)
            && lo > hi
        {
            return Err(format!(
                "min_radius ({lo}) must not exceed max_radius ({hi})"
            ));
        }
        if !(self.max_offset_ratio.is_finite() && self.max_offset_ratio >= 0.0) {
            return Err(format!(
                "max_offset_ratio must be zero or more (offset over field radius), got {}",
                self.max_offset_ratio
            ));
        }
        if !(self.max_scale_ratio.is_finite() && self.max_scale_ratio >= 1.0) {
            return Err(format!(
                "max_scale_ratio must be at least 1 (it bounds max(a, 1/a)), got {}",
                self.max_scale_ratio
            ));
        }
        if !(self.min_coverage_deg.is_finite() && (0.0..=360.0).contains(&self.min_coverage_deg)) {
            return Err(format!(
                "min_coverage_deg must be between 0 and 360, got {}",
                self.min_coverage_deg
            ));
        }
        Ok(())
    }
}

/// Ok(()) or the reason, naming the quantity, its value and the limit, e.g.
/// "rms 7.3 % of the field exceeds the limit of 5.0 % (limits.max_rms)".
/// Every limit that fails is named, joined by "; ", so a person fixes all at
/// once rather than one per rotation.
pub fn check(report: &FitReport, limits: &Limits) -> Result<(), String> {
    let cal = &report.calibration;
    let values = [
        ("a", cal.a),
        ("b", cal.b),
        ("d", cal.d),
        ("r", cal.r),
        ("rms", report.rms),
        ("coverage", report.coverage.covered_deg),
    ];
    // A non-finite parameter would make every comparison below false, so
    // it must be refused first and explicitly.
    if let Some((name, value)) = values.iter().find(|(_, v)| !v.is_finite()) {
        return Err(format!(
            "the fit produced a non-finite {name} ({value}); the rotation cannot be used"
        ));
    }
    if !(cal.a > 0.0 && cal.r > 0.0) {
        return Err(format!(
            "the fit produced a non-positive gain a = {} or radius r = {}; the rotation cannot be used",
            cal.a, cal.r
        ));
    }

    let mut failures = Vec::new();
    let covered = report.coverage.covered_deg;
    if covered < limits.min_coverage_deg {
        failures.push(format!(
            "heading coverage {covered:.1}° is below the limit of {:.1}° (limits.min_coverage_deg)",
            limits.min_coverage_deg
        ));
    }
    if report.rms > limits.max_rms {
        failures.push(format!(
            "rms {:.1} % of the field exceeds the limit of {:.1} % (limits.max_rms)",
            report.rms * 100.0,
            limits.max_rms * 100.0
        ));
    }
    if let Some(lo) = limits.min_radius
        && cal.r < lo
    {
        failures.push(format!(
            "field radius {:.1} counts is below the limit of {lo} counts (limits.min_radius)",
            cal.r
        ));
    }
    if let Some(hi) = limits.max_radius
        && cal.r > hi
    {
        failures.push(format!(
            "field radius {:.1} counts exceeds the limit of {hi} counts (limits.max_radius)",
            cal.r
        ));
    }
    // In the paper's model the offsets after the gain are b (x) and d (y),
    // in the units of r; the raw offsets are -b/a and -d.
    let offset_ratio = cal.b.hypot(cal.d) / cal.r;
    if offset_ratio > limits.max_offset_ratio {
        failures.push(format!(
            "offset {offset_ratio:.2} times the field radius (raw x {:.1}, y {:.1} counts; radius {:.1}) exceeds the limit of {} (limits.max_offset_ratio)",
            // `+ 0.0` so a zero offset reads 0.0, not -0.0.
            -cal.b / cal.a + 0.0,
            -cal.d + 0.0,
            cal.r,
            limits.max_offset_ratio
        ));
    }
    let scale_ratio = cal.a.max(1.0 / cal.a);
    if scale_ratio > limits.max_scale_ratio {
        failures.push(format!(
            "axis gain ratio {scale_ratio:.3} (a = {:.4}) exceeds the limit of {} (limits.max_scale_ratio)",
            cal.a, limits.max_scale_ratio
        ));
    }
    if failures.is_empty() {
        Ok(())
    } else {
        Err(failures.join("; "))
    }
}
