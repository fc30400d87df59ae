//! Calibration models and their fits: pure functions on plain data.
//!
//! - [`paper`]: the paper's model `s_x = a*x + b, s_y = y + d, |s| = r`, its
//!   closed-form least squares (eq. 6) and its gradient descent (eqs. 7-21).
//! - [`heading`]: where on the circle the samples lie (coverage of the turn).
//! - [`gyro`]: a gyroscope as a heading reference, and a model's heading
//!   error against it.
//! - [`fit`]: fitting a recording end to end, with the checks a user needs.
//! - [`effects`]: the catalogue of physical effects a model can add.
//! - [`nonlinear`]: the paper's model plus any effects, fitted by
//!   Levenberg-Marquardt.
//! - [`lm`]: the one Levenberg–Marquardt solver the 2-D and 3-D fits share.
//! - [`residuals`]: what a fit's residual still holds, and its noise floor.
//! - [`rotation`]: the rotation buffer of a 2-axis sensor: samples kept
//!   until they make one full turn.
//! - [`diagnose`]: which effect the data supports, step by step.
//! - [`ladder`]: the diagnosis ladder both geometries share.
//! - [`check`]: whether a stored calibration holds on another recording.
//! - [`check3`]: the same for a 3-D calibration.
//! - [`turn`]: whether the readings show a turn at all, before any fit.
//! - [`ellipsoid`]: the 3-D model (offset, gains, soft iron) and its fit.
//! - [`sphere`]: coverage of the sphere of directions, for 3-axis sensors.
//! - [`sphere_buffer`]: the samples a 3-axis sensor collects until their
//!   directions cover the sphere.
//! - [`spike`]: the per-sample gate that keeps spikes out of the
//!   rotation and the fit.
//! - [`still`]: still segments (poses at rest) of a 3-axis recording.
//! - [`tilt`]: the tilt-compensated heading from a magnetometer and an
//!   accelerometer on one board.
//! - [`heading_analysis`]: what `fieldcal heading` makes of those headings:
//!   their summary, the field against the model, the check against a gyro.

pub mod calibration;
pub mod calibration3;
pub mod centred_split;
pub mod check;
pub mod check3;
pub mod diagnose;
pub mod diagnose3;
pub mod effects;
pub mod ellipsoid;
pub mod ellipsoid_effects;
pub mod fit;
#[cfg(test)]
mod fixtures;
pub mod gyro;
pub mod gyro3;
pub mod heading;
pub mod heading_analysis;
pub mod ladder;
pub mod level;
pub mod lm;
pub mod nonlinear;
pub mod paper;
pub mod residuals;
pub mod rotation;
pub mod sphere;
pub mod sphere_buffer;
pub mod spike;
pub mod still;
pub mod still_stream;
pub mod tilt;
pub mod trust;
pub(crate) mod tsqr;
pub mod turn;
pub mod validity;
pub mod vertical;
pub mod watch;

use crate::numfmt::significant;

/// Why a fit could not produce a calibration. Messages say what was found
/// and what to do; the caller adds which file or sensor it was.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    #[error(
        "{} too few to show a turn: fieldcal needs at least {needed} to tell a turn from a sensor that stood still; record a full rotation",
        crate::sample::count_is(*found as u64, "sample")
    )]
    TooFewToTurn { found: usize, needed: usize },
    #[error(
        "reading {index} is not a finite number (x = {x}, y = {y}); remove it from the recording"
    )]
    NonFiniteReading { index: usize, x: f64, y: f64 },
    #[error(
        "reading {index} of '{column}' is {value:e}: too large to square in f64 (the fit squares readings, and they must stay within ±{max:e}); these are not a sensor's readings: give counts or physical units",
        max = crate::sample::MAX_MAGNITUDE
    )]
    TooLarge {
        column: String,
        index: usize,
        value: f64,
    },
    #[error(
        "the readings form a cloud {} across around ({}, {}): their spread is only {}× the noise ({}), and a turn needs {needed}×: the sensor did not turn; turn it a full rotation in a constant field",
        significant(*.across, 2), significant(*.centre_x, 4), significant(*.centre_y, 4), significant(*.ratio, 2), significant(*.noise, 2)
    )]
    NotTurning {
        across: f64,
        centre_x: f64,
        centre_y: f64,
        ratio: f64,
        noise: f64,
        needed: f64,
    },
    #[error(
        "{percent:.1} % of the readings lie within half the radius of the centre: the two axes fill a disc rather than trace a ring, so the sensor did not turn in the plane of {x} and {y} (a tumble, or the wrong columns: choose the two axes that turned with --x and --y)"
    )]
    DiscNotRing { percent: f64, x: String, y: String },
    #[error(
        "the readings go only {covered_deg:.0}° round their centre (the largest gap runs {gap_deg:.0}° from {gap_start_deg:.0}°), and a fit needs {needed_deg:.0}°: the sensor did not turn a full rotation in the plane of {x} and {y}; turn it a full rotation in a constant field, choose the two axes that turned with --x and --y, or lower the required coverage"
    )]
    NoFullTurn {
        covered_deg: f64,
        gap_deg: f64,
        gap_start_deg: f64,
        needed_deg: f64,
        x: String,
        y: String,
    },
    #[error(
        "{} too few: the model has {unknowns} unknowns and needs at least {needed} samples",
        crate::sample::count_is(*found as u64, "sample")
    )]
    TooFewSamples {
        found: usize,
        unknowns: usize,
        needed: usize,
    },
    #[error(
        "the {axis} readings are all the same ({value}); the sensor must turn so that both axes change"
    )]
    ConstantAxis { axis: &'static str, value: f64 },
    #[error(
        "the readings are degenerate (they lie on a line or a single conic arc the model cannot pin down); turn the sensor a full rotation in a constant field"
    )]
    Degenerate,
    #[error(
        "the readings cover only {found_deg:.1}° of heading (the largest gap runs {gap_deg:.1}° from {gap_start_deg:.1}°); a fit needs at least {needed_deg:.1}°: turn the sensor a full rotation, or lower the required coverage"
    )]
    InsufficientCoverage {
        found_deg: f64,
        needed_deg: f64,
        gap_deg: f64,
        gap_start_deg: f64,
    },
    #[error(
        "the points fit no ellipse of the paper's family (theta1 = {theta1:.6e} >= 0, so a = sqrt(-theta1) does not exist): the readings are not a sensor turning in a constant field, or the chosen x and y are not the turning axes"
    )]
    NotAnEllipse { theta1: f64 },
    #[error(
        "the fitted ellipse has no real radius (r^2 = {r_squared:.6e} <= 0): the readings are not a sensor turning in a constant field"
    )]
    NoRadius { r_squared: f64 },
    #[error(
        "gradient descent diverged at iteration {iteration} (theta grew without bound): the learning rate {learning_rate} is too large for these features, which happens when the offsets are large compared with the field; use the closed-form solver (--solver lsq) or a smaller --learning-rate"
    )]
    Diverged { iteration: u64, learning_rate: f64 },
    #[error(
        "gradient descent did not converge within {cap} iterations (the last step changed theta by {last_step:.3e}, the stop rule needs every change below {tolerance:.1e}); raise --max-iterations or use the closed-form solver (--solver lsq)"
    )]
    IterationCap {
        cap: u64,
        last_step: f64,
        tolerance: f64,
    },
    #[error(
        "the fit did not converge, and the readings go only {covered_deg:.0}° round the closed-form ellipse (the largest gap runs {gap_deg:.0}° from {gap_start_deg:.0}°): the columns chosen as x and y may not be the axes that turned (choose them with --x and --y), or the turn was not complete"
    )]
    NoTurn {
        covered_deg: f64,
        gap_deg: f64,
        gap_start_deg: f64,
    },
    #[error(
        "the fit did not converge after {iterations} iterations ({what}); the model may not suit these readings: try fewer effects"
    )]
    NoConvergence {
        iterations: usize,
        what: &'static str,
    },
    #[error(
        "the recording has no column '{column}' for the effect covariate:{column}; its covariate columns are: {available}"
    )]
    MissingCovariate { column: String, available: String },
    #[error(
        "the drift effect needs sample times, and the recording has no time column (t, t_s, time or time_s, or choose one with --t)"
    )]
    MissingTime,
    #[error(
        "the readings do not determine the parameter '{parameter}' (its column is constant or a combination of others); drop the effect that adds it"
    )]
    Undetermined { parameter: String },
    #[error(
        "the stored calibration has no finite value of '{parameter}', which its model needs: the file is incomplete; store it again with `fieldcal fit --json`"
    )]
    MissingParameter { parameter: String },
    #[error(
        "the fit reached a non-finite value of '{parameter}': the model does not suit these readings"
    )]
    NotFinite { parameter: String },
    #[error(
        "the fit reached {parameter} = {value}, which must be positive: the model does not suit these readings"
    )]
    NonPositive { parameter: &'static str, value: f64 },
}
