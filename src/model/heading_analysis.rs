//! The analysis of `fieldcal heading` on plain data: a calibrated 3-axis
//! magnetometer and accelerometer on one board give every sample's
//! tilt-compensated heading; this module sums those headings up, measures
//! the field against the World Magnetic Model, checks the headings against
//! a gyro, and says in words what the check means.
//!
//! Reading the files and choosing the columns is the caller's; everything
//! here works on readings already on the magnetometer's times. The report
//! it builds, [`HeadingReport`], is rendered by [`crate::report::heading`].

use std::path::PathBuf;

use crate::geomag::{FieldComparison, MagUnits, ModelField, compare_field};
use crate::model::gyro::{GyroError, GyroUnits, HeadingCheck, HeadingDelta, HeadingReference};
use crate::model::tilt::{
    AxisChoice, AxisMap, BoardAxesError, Calibration3, HeadingSeries, Resampled, RobustSpread,
    heading_series, robust_spread,
};
use crate::model::vertical::{VerticalError, fuse_vertical, rate_about_vertical};

/// Why the headings cannot be analysed. The caller adds which file or
/// option it was.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum HeadingAnalysisError {
    #[error("--declination {0}: give degrees east of true north, -180 to 180")]
    Declination(f64),
    #[error(
        "no sample has a heading: each needs a field with a horizontal part and an accelerometer reading at its time (check --accel, the clocks, and --mag-axes)"
    )]
    NoHeading,
}

/// One sensor's readings, calibrated (or not), on the magnetometer's times.
#[derive(Debug, Clone, PartialEq)]
pub struct Sensor {
    /// The file its readings came from.
    pub file: PathBuf,
    /// Its three columns, as named by the user.
    pub columns: [String; 3],
    /// The calibration applied to its readings, if any.
    pub calibration: Option<PathBuf>,
    /// Its readings (calibrated when a calibration was given).
    pub points: Vec<[f64; 3]>,
}

/// The readings `raw` through the calibration `cal`, or as they are.
pub fn calibrated(cal: Option<&Calibration3>, raw: Vec<[f64; 3]>) -> Vec<[f64; 3]> {
    match cal {
        Some(c) => raw.iter().map(|p| c.apply(*p)).collect(),
        None => raw,
    }
}

/// Where the declination added to the headings came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeclinationSource {
    /// The World Magnetic Model at the recording's place and date.
    Wmm,
    /// The user's `--declination`.
    Given,
    /// None: the headings are from magnetic north.
    None,
}

impl DeclinationSource {
    /// The name the JSON report gives it.
    pub fn name(self) -> &'static str {
        match self {
            DeclinationSource::Wmm => "wmm",
            DeclinationSource::Given => "given",
            DeclinationSource::None => "none",
        }
    }
}

/// The declination added to every heading, degrees east of true north.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Declination {
    pub deg: f64,
    pub source: DeclinationSource,
}

impl Declination {
    /// The model's declination when there is a model, else the one `given`
    /// (which must be degrees within ±180), else none (0°).
    pub fn choose(
        model: Option<&ModelField>,
        given: Option<f64>,
    ) -> Result<Declination, HeadingAnalysisError> {
        let (deg, source) = match (model, given) {
            (Some(m), _) => (m.declination_deg, DeclinationSource::Wmm),
            (None, Some(d)) if d.is_finite() && d.abs() <= 180.0 => (d, DeclinationSource::Given),
            (None, Some(d)) => return Err(HeadingAnalysisError::Declination(d)),
            (None, None) => (0.0, DeclinationSource::None),
        };
        Ok(Declination { deg, source })
    }

    /// Which north the headings are from: `true` with a declination,
    /// `magnetic` without.
    pub fn north(&self) -> &'static str {
        if self.source == DeclinationSource::None {
            "magnetic"
        } else {
            "true"
        }
    }
}

/// The board: the axis whose heading is reported, the axis that points up
/// when it lies level (both in the accelerometer's frame), and the
/// declination added to give true north.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Board {
    pub forward: [f64; 3],
    pub up: [f64; 3],
    pub declination_deg: f64,
}

impl Board {
    /// Every sample's heading from the field `body` (in the board's frame)
    /// and the board's vertical `vertical`, paired sample by sample.
    pub fn headings(
        &self,
        body: &[[f64; 3]],
        vertical: &[[f64; 3]],
    ) -> Result<HeadingSeries, BoardAxesError> {
        heading_series(body, vertical, self.forward, self.up, self.declination_deg)
    }
}

/// `--rates`: the gyro that steadies the vertical.
#[derive(Debug, Clone, PartialEq)]
pub struct Fusion {
    /// The file the rates came from.
    pub file: PathBuf,
    /// The rates' columns as named (a leading `-` for an axis read negated).
    pub columns: [String; 3],
    /// The filter's time constant, seconds.
    pub tau_s: f64,
    /// The fused vertical at each magnetometer time.
    pub up: Vec<[f64; 3]>,
    /// The rates at each magnetometer time, in --gyro-units.
    pub rates: Vec<[f64; 3]>,
}

impl Fusion {
    /// The accelerometer's vertical `accel` steadied by the gyro's `rates`
    /// (in `units`, the gyro's axes in the accelerometer's frame), all at
    /// the times `t`, with the time constant `tau_s`.
    pub fn fuse(
        file: PathBuf,
        columns: [String; 3],
        tau_s: f64,
        t: &[f64],
        accel: &[[f64; 3]],
        rates: Vec<[f64; 3]>,
        units: GyroUnits,
    ) -> Result<Fusion, VerticalError> {
        let to_rad = units.to_deg_per_second().to_radians();
        let rad: Vec<[f64; 3]> = rates.iter().map(|w| w.map(|v| v * to_rad)).collect();
        let up = fuse_vertical(t, accel, &rad, tau_s)?;
        Ok(Fusion {
            file,
            columns,
            tau_s,
            up,
            rates,
        })
    }
}

/// What the headings of a recording add up to.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadingStats {
    /// Samples with a heading.
    pub n_heading: usize,
    /// The measured inclination (dip), degrees.
    pub inclination: Option<RobustSpread>,
    /// The board's tilt, degrees.
    pub tilt: Option<RobustSpread>,
    /// The largest tilt, degrees (0 when none is known).
    pub max_tilt: f64,
}

impl HeadingStats {
    /// The summary of `series`; an error when no sample has a heading.
    pub fn of(series: &HeadingSeries) -> Result<HeadingStats, HeadingAnalysisError> {
        let n_heading = series.heading_deg.iter().filter(|h| h.is_finite()).count();
        if n_heading == 0 {
            return Err(HeadingAnalysisError::NoHeading);
        }
        let inclination = robust_spread(&series.inclination_deg);
        let tilt = robust_spread(&series.tilt_deg);
        let max_tilt = series
            .tilt_deg
            .iter()
            .copied()
            .filter(|t| t.is_finite())
            .fold(0.0, f64::max);
        Ok(HeadingStats {
            n_heading,
            inclination,
            tilt,
            max_tilt,
        })
    }
}

/// The field's magnitude, in the magnetometer's units.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldMagnitude {
    /// In the readings' units; NaN when unknown.
    pub magnitude: f64,
    /// The readings' units, when known.
    pub units: Option<MagUnits>,
    /// The magnitude in nanotesla, when the units are known.
    pub magnitude_nt: Option<f64>,
    /// Where the magnitude came from: the calibration's r or the readings.
    pub source: &'static str,
}

impl FieldMagnitude {
    /// The field's magnitude: the calibration's r, or the median length of
    /// the readings `mag` without one; in the `given` units, else the
    /// calibration's.
    pub fn measure(
        mag_cal: Option<&Calibration3>,
        given: Option<MagUnits>,
        mag: &[[f64; 3]],
    ) -> FieldMagnitude {
        let units = given.or_else(|| {
            mag_cal
                .and_then(|c| c.units.as_deref())
                .and_then(MagUnits::from_name)
        });
        let magnitude = match mag_cal {
            Some(c) => c.calibration.r,
            None => {
                let norms: Vec<f64> = mag
                    .iter()
                    .map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt())
                    .collect();
                robust_spread(&norms).map_or(f64::NAN, |s| s.median)
            }
        };
        FieldMagnitude {
            magnitude,
            units,
            magnitude_nt: units.map(|u| magnitude * u.nanotesla()),
            source: if mag_cal.is_some() {
                "calibration r"
            } else {
                "median |reading|"
            },
        }
    }

    /// The measured field beside the model's, when there is a model and a
    /// measured inclination.
    pub fn compare(
        &self,
        model: Option<&ModelField>,
        inclination: Option<&RobustSpread>,
    ) -> Option<FieldComparison> {
        match (model, inclination) {
            (Some(m), Some(i)) => Some(compare_field(i, self.magnitude_nt, m)),
            _ => None,
        }
    }
}

/// The name of the heading reference integrated from the three rates.
pub const RATE_ABOUT_VERTICAL: &str = "rate about the vertical";

/// The heading reference of the gyro's rate about the fused vertical, at
/// the times `t` (the fused vertical's), in `units`.
pub fn rate_reference(
    t: &[f64],
    fusion: &Fusion,
    units: GyroUnits,
) -> Result<HeadingReference, GyroError> {
    // Integrated over the samples that have a rate and a vertical
    // (outside the gyro's or the accelerometer's span they have not).
    let (rate_t, rate): (Vec<f64>, Vec<f64>) = t
        .iter()
        .copied()
        .zip(rate_about_vertical(&fusion.rates, &fusion.up))
        .filter(|(_, r)| r.is_finite())
        .unzip();
    HeadingReference::from_rates(RATE_ABOUT_VERTICAL, t, &rate_t, &rate, units)
}

/// The tilt-compensated and the level heading against the gyro; an error
/// says why one could not be checked.
#[derive(Debug, Clone, PartialEq)]
pub struct GyroChecks {
    pub column: String,
    /// The tilt-compensated heading (on the fused vertical with --rates).
    pub tilt: Result<HeadingCheck, String>,
    /// With --rates: the heading on the accelerometer's vertical alone.
    pub accel_only: Option<Result<HeadingCheck, String>>,
    pub level: Result<HeadingCheck, String>,
}

impl GyroChecks {
    /// The headings of `series` against the gyro's `reference`; with a
    /// `fusion`, also the heading on the accelerometer's vertical `accel`
    /// alone (the field `body` on the `board`).
    pub fn check(
        reference: &HeadingReference,
        series: &HeadingSeries,
        fusion: Option<&Fusion>,
        board: &Board,
        body: &[[f64; 3]],
        accel: &[[f64; 3]],
    ) -> Result<GyroChecks, BoardAxesError> {
        // The heading turns clockwise, a gyro about up reads a
        // counter-clockwise turn as positive, so it is checked against the
        // counter-clockwise angle (−heading): scale +1 for a gyro about up.
        let ccw = |h: &[f64]| -> Vec<f64> { h.iter().map(|d| -d.to_radians()).collect() };
        // A heading that does not follow the gyro (a level compass
        // tilted in a steep field) is a finding, not a failure.
        let check = |h: &[f64]| reference.check(&ccw(h), &[]).map_err(|e| e.to_string());
        let accel_only = match fusion {
            Some(_) => Some(check(&board.headings(body, accel)?.heading_deg)),
            None => None,
        };
        Ok(GyroChecks {
            column: reference.column().to_string(),
            tilt: check(&series.heading_deg),
            accel_only,
            level: check(&series.level_deg),
        })
    }
}

/// Everything `fieldcal heading` reports: where the readings came from,
/// how they were put on the board, and what the headings say.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadingReport {
    pub mag: Sensor,
    pub accel: Sensor,
    /// How the accelerometer's second file was put on the magnetometer's
    /// times, if it had one.
    pub interpolation: Option<Resampled>,
    /// The magnetometer's axes on the board.
    pub map: AxisMap,
    /// How `--mag-axes auto` chose them, if it did.
    pub choice: Option<AxisChoice>,
    /// The board's forward and up axes as the user named them.
    pub forward: String,
    pub up: String,
    pub declination: Declination,
    /// Samples in the recording.
    pub n: usize,
    pub stats: HeadingStats,
    pub field: FieldMagnitude,
    pub model: Option<ModelField>,
    pub comparison: Option<FieldComparison>,
    pub gyro: Option<GyroChecks>,
    pub fusion: Option<Fusion>,
}

impl HeadingReport {
    /// What the gyro says of tilt compensation: how much worse the level
    /// heading is, and its verdict; `None` unless both were checked.
    pub fn compensation(&self, g: &GyroChecks) -> Option<(HeadingDelta, String)> {
        match (&g.tilt, &g.level) {
            (Ok(t), Ok(l)) => {
                let d = t.worse_by(l);
                Some((
                    d,
                    compensation_verdict(
                        d,
                        self.accel.calibration.is_some(),
                        self.fusion.is_some(),
                    ),
                ))
            }
            _ => None,
        }
    }
}

/// The largest heading error of a check, degrees (0 when none is finite).
pub fn max_abs(check: &HeadingCheck) -> f64 {
    check
        .errors_deg
        .iter()
        .copied()
        .filter(|e| e.is_finite())
        .fold(0.0, |m, e| m.max(e.abs()))
}

/// Standard errors a difference of rms heading errors must exceed to be
/// called a difference (as `diagnose` calls a model's heading worse).
pub const VERDICT_SES: f64 = 3.0;

/// What the comparison with the gyro says about tilt compensation, in
/// words a person acts on: it helped, it made no difference, or it made the
/// heading worse, and then the physical reason to look at first.
pub fn compensation_verdict(d: HeadingDelta, accel_calibrated: bool, fused: bool) -> String {
    let (delta, se) = (d.delta_rms_deg, d.se_deg);
    if !(delta.is_finite() && se.is_finite()) {
        return "too few samples to compare the two headings".to_string();
    }
    if delta > VERDICT_SES * se {
        format!("tilt compensation removed {delta:.2}° rms of heading error")
    } else if delta < -VERDICT_SES * se {
        let cause = if fused {
            "the fused vertical is less accurate than the board was level: check that --rates names \
             the gyro's axes in the accelerometer's frame and its units (--gyro-units), and the gyro's \
             bias (a bias of b tilts the vertical by about b times --fusion-tau: shorten it)"
        } else if accel_calibrated {
            "the accelerometer's vertical is less accurate than the board was level: the board \
             accelerated during the turn (give the gyro's three axes with --rates to steady the \
             vertical), or the accelerometer's calibration holds the hand's accelerations \
             (calibrate it from still poses: fit --still)"
        } else {
            "the raw accelerometer's vertical is less accurate than the board was level: calibrate \
             it (fit --z on a tumble, or --still on still poses), steady it with the gyro (--rates), \
             and check --mag-axes"
        };
        format!(
            "tilt compensation made the heading WORSE by {:.2}° rms: {cause}",
            -delta
        )
    } else {
        format!(
            "tilt compensation made no difference beyond the noise ({delta:+.2}° ± {se:.2}°): the board stayed near level"
        )
    }
}

/// What steadying the vertical with the gyro did, against the
/// accelerometer alone.
pub fn fusion_verdict(d: HeadingDelta) -> String {
    let (delta, se) = (d.delta_rms_deg, d.se_deg);
    if !(delta.is_finite() && se.is_finite()) {
        "too few samples to compare".to_string()
    } else if delta > VERDICT_SES * se {
        "the gyro removed the board's accelerations from the vertical".to_string()
    } else if delta < -VERDICT_SES * se {
        "the gyro made the vertical worse: check the --rates columns and units, and the gyro's bias \
         (shorten --fusion-tau)"
            .to_string()
    } else {
        "no difference beyond the noise: the board's accelerations were small".to_string()
    }
}
