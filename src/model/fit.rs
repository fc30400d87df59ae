//! Fitting a recording with the paper's model, with the checks a user needs:
//! a turn (see [`super::turn`]), a real ellipse, and a turn that covers the
//! circle.

use std::time::{Duration, Instant};

use serde::Serialize;

use super::FitError;
use super::heading::{Coverage, circle_centre, coverage};
use super::paper::{
    GradientDescentOptions, GradientDescentProgress, PaperCalibration, Theta, closed_form,
    gradient_descent,
};
use super::turn::check_turn;

/// The effects that make up the paper's model, by their catalogue names.
pub const PAPER_EFFECTS: [&str; 2] = ["offset", "scale"];

/// Default heading coverage a fit requires, in degrees. A full turn is the
/// paper's premise; 300° leaves room for a hand-held turn that stops short.
pub const DEFAULT_MIN_COVERAGE_DEG: f64 = 300.0;

/// Which solver finds theta.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Solver {
    /// Closed-form least squares, eq. (6): the default, and exact.
    Lsq,
    /// The paper's gradient descent, eqs. (7)-(21), for comparison.
    PaperGd,
}

impl Solver {
    pub fn name(self) -> &'static str {
        match self {
            Solver::Lsq => "lsq",
            Solver::PaperGd => "paper-gd",
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FitOptions {
    pub solver: Solver,
    pub gradient_descent: GradientDescentOptions,
    pub min_coverage_deg: f64,
}

impl Default for FitOptions {
    fn default() -> Self {
        FitOptions {
            solver: Solver::Lsq,
            gradient_descent: GradientDescentOptions::default(),
            min_coverage_deg: DEFAULT_MIN_COVERAGE_DEG,
        }
    }
}

/// The result of a fit.
#[derive(Debug, Clone, PartialEq)]
pub struct FitReport {
    pub solver: Solver,
    pub calibration: PaperCalibration,
    pub theta: Theta,
    /// Root mean square of |calibrated|/r - 1 over the samples.
    pub rms: f64,
    pub n: usize,
    /// Gradient-descent iterations (paper-gd only).
    pub iterations: Option<u64>,
    pub coverage: Coverage,
    /// Time the solver took.
    pub elapsed: Duration,
}

/// Fits the paper's model to the samples `(x[i], y[i])`.
pub fn fit_paper(
    x: &[f64],
    y: &[f64],
    options: &FitOptions,
    progress: &mut dyn FnMut(GradientDescentProgress),
) -> Result<FitReport, FitError> {
    // A turn, or no calibration: before any solver, so that no solver's
    // failure (or success on noise) speaks for readings that never turned.
    check_turn(x, y, options.min_coverage_deg)?;
    fit_paper_turned(x, y, options, progress)
}

/// [`fit_paper`] of samples already known to be a turn (the daemon's
/// rotation buffer judged it complete): without the turn gate, which is
/// most of the cost. The coverage the fitted model gives is still
/// required.
pub fn fit_paper_turned(
    x: &[f64],
    y: &[f64],
    options: &FitOptions,
    progress: &mut dyn FnMut(GradientDescentProgress),
) -> Result<FitReport, FitError> {
    let started = Instant::now();
    let (theta, iterations) = match options.solver {
        Solver::Lsq => (closed_form(x, y), None),
        Solver::PaperGd => match gradient_descent(x, y, &options.gradient_descent, progress) {
            Ok(outcome) => (Ok(outcome.theta), Some(outcome.iterations)),
            Err(e) => (Err(e), None),
        },
    };
    let elapsed = started.elapsed();

    let calibration = match theta.and_then(|t| t.to_calibration().map(|c| (t, c))) {
        Ok(found) => found,
        Err(
            e @ (FitError::NotAnEllipse { .. } | FitError::NoRadius { .. } | FitError::Degenerate),
        ) => {
            // A short arc is the usual reason no ellipse fits: say so when
            // it is, since turning further is what the user can do about it.
            if let Ok((cx, cy)) = circle_centre(x, y) {
                let arc = coverage(x.iter().zip(y).map(|(x, y)| (y - cy).atan2(x - cx)));
                arc.require(options.min_coverage_deg)?;
            }
            return Err(e);
        }
        Err(e) => return Err(e),
    };
    let (theta, calibration) = calibration;

    let coverage = coverage(x.iter().zip(y).map(|(&x, &y)| calibration.heading(x, y)));
    coverage.require(options.min_coverage_deg)?;

    Ok(FitReport {
        solver: options.solver,
        calibration,
        theta,
        rms: calibration.rms(x, y),
        n: x.len(),
        iterations,
        coverage,
        elapsed,
    })
}
