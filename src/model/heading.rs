//! Where on the circle the samples lie: the coverage of a turn.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::FitError;

/// How much of the circle of headings a set of samples covers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Coverage {
    /// 360° less the largest gap between neighbouring headings.
    pub covered_deg: f64,
    /// The largest gap between neighbouring headings, in degrees.
    pub largest_gap_deg: f64,
    /// Where that gap starts (heading in [0, 360), counter-clockwise).
    pub gap_start_deg: f64,
}

impl Coverage {
    /// Checks the coverage against what a fit needs.
    pub fn require(&self, needed_deg: f64) -> Result<(), FitError> {
        if self.covered_deg + 1e-9 >= needed_deg {
            Ok(())
        } else {
            Err(FitError::InsufficientCoverage {
                found_deg: self.covered_deg,
                needed_deg,
                gap_deg: self.largest_gap_deg,
                gap_start_deg: self.gap_start_deg,
            })
        }
    }
}

/// Coverage of a set of headings given in radians (any range).
pub fn coverage(headings: impl IntoIterator<Item = f64>) -> Coverage {
    let mut deg: Vec<f64> = headings
        .into_iter()
        .map(|h| h.to_degrees().rem_euclid(360.0))
        .filter(|h| h.is_finite())
        .collect();
    if deg.is_empty() {
        return Coverage {
            covered_deg: 0.0,
            largest_gap_deg: 360.0,
            gap_start_deg: 0.0,
        };
    }
    deg.sort_unstable_by(f64::total_cmp);
    // The wrap-around gap from the last heading back to the first.
    let mut largest = (deg[0] + 360.0 - deg[deg.len() - 1], deg[deg.len() - 1]);
    for pair in deg.windows(2) {
        let gap = pair[1] - pair[0];
        if gap > largest.0 {
            largest = (gap, pair[0]);
        }
    }
    Coverage {
        covered_deg: 360.0 - largest.0,
        largest_gap_deg: largest.0,
        gap_start_deg: largest.1,
    }
}

/// Most sweeps of the SVD in [`circle_centre`]. Golub-Kahan SVD converges
/// in a few sweeps per singular value on finite input (a 3-column design
/// takes well under 100); 1000 only ends a run that will never converge
/// (non-finite or pathological input) with an error instead of a hang.
/// Same cap as the residual fit's SVD in `residuals.rs`.
pub const SVD_MAX_ITERATIONS: usize = 1000;

/// Centre of the circle that best fits the points (Kåsa's algebraic fit).
/// Used to judge the coverage of points that no ellipse of the paper's family
/// fits: a partial arc still has a well-defined centre of curvature.
pub fn circle_centre(x: &[f64], y: &[f64]) -> Result<(f64, f64), FitError> {
    let n = x.len();
    if n < 3 {
        return Err(FitError::TooFewSamples {
            found: n,
            unknowns: 3,
            needed: 3,
        });
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / n as f64;
    let (mx, my) = (mean(x), mean(y));
    let spread = x
        .iter()
        .zip(y)
        .map(|(x, y)| (x - mx).hypot(y - my))
        .fold(0.0, f64::max);
    if !(spread > 0.0) {
        return Err(FitError::Degenerate);
    }
    // u^2 + v^2 = 2*cu*u + 2*cv*v + c, in centred, scaled coordinates.
    let scaled = |i: usize| ((x[i] - mx) / spread, (y[i] - my) / spread);
    let design = DMatrix::from_fn(n, 3, |i, j| {
        let (u, v) = scaled(i);
        [2.0 * u, 2.0 * v, 1.0][j]
    });
    let target = DVector::from_fn(n, |i, _| {
        let (u, v) = scaled(i);
        u * u + v * v
    });
    if !(design.iter().all(|v| v.is_finite()) && target.iter().all(|v| v.is_finite())) {
        // Readings whose mean or spread overflows: refused before the SVD,
        // which would iterate on non-finite entries.
        return Err(FitError::Degenerate);
    }
    let p = design
        .try_svd(true, true, f64::EPSILON, SVD_MAX_ITERATIONS)
        .ok_or(FitError::NoConvergence {
            iterations: SVD_MAX_ITERATIONS,
            what: "the SVD of the circle fit did not converge",
        })?
        .solve(&target, 1e-12)
        .map_err(|_| FitError::Degenerate)?;
    if !p.iter().all(|v| v.is_finite()) {
        return Err(FitError::Degenerate);
    }
    Ok((mx + p[0] * spread, my + p[1] * spread))
}
