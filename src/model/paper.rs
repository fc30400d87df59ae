//! The paper's model and its two solvers.
//!
//! Model: `s_x = a*x + b`, `s_y = y + d`, `|s| = r`, in the linear form of
//! eq. (4): `y^2 = th1*x^2 + th2*x + th3*y + th4`, with
//! `th1 = -a^2, th2 = -2ab, th3 = -2d, th4 = r^2 - b^2 - d^2`.

use nalgebra::{DMatrix, DVector, Matrix4, Vector4};
use serde::{Deserialize, Serialize};

use super::FitError;

/// Unknowns of the paper's model (a, b, d, r).
pub const UNKNOWNS: usize = 4;
/// The paper's learning rate (section IV).
pub const PAPER_LEARNING_RATE: f64 = 0.73;
/// The paper's stop rule, eq. (21): every |theta_j^n - theta_j^(n-1)| below this.
pub const PAPER_TOLERANCE: f64 = 1e-7;

/// The coefficients of eq. (4), in raw sensor units.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Theta(pub [f64; 4]);

/// The paper's calibration constants.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PaperCalibration {
    /// Gain of x relative to y.
    pub a: f64,
    /// Offset of x, after the gain.
    pub b: f64,
    /// Offset of y.
    pub d: f64,
    /// Magnitude of the field, in y's units.
    pub r: f64,
}

impl Theta {
    /// Recovers a, b, d, r (section II, after eq. 6).
    pub fn to_calibration(&self) -> Result<PaperCalibration, FitError> {
        let [th1, th2, th3, th4] = self.0;
        if !(th1 < 0.0) {
            return Err(FitError::NotAnEllipse { theta1: th1 });
        }
        let d = -th3 / 2.0;
        let a = (-th1).sqrt();
        let b = -th2 / (2.0 * a);
        let r_squared = th4 + b * b + d * d;
        if !(r_squared > 0.0) || !r_squared.is_finite() {
            return Err(FitError::NoRadius { r_squared });
        }
        Ok(PaperCalibration {
            a,
            b,
            d,
            r: r_squared.sqrt(),
        })
    }
}

impl PaperCalibration {
    /// The inverse of [`Theta::to_calibration`].
    pub fn to_theta(&self) -> Theta {
        let PaperCalibration { a, b, d, r } = *self;
        Theta([-a * a, -2.0 * a * b, -2.0 * d, r * r - b * b - d * d])
    }

    /// The calibrated reading of a raw sample.
    #[inline]
    pub fn apply(&self, x: f64, y: f64) -> (f64, f64) {
        (self.a * x + self.b, y + self.d)
    }

    /// `|s|/r - 1`: the magnitude error as a fraction of the field.
    #[inline]
    pub fn magnitude_error(&self, x: f64, y: f64) -> f64 {
        let (sx, sy) = self.apply(x, y);
        sx.hypot(sy) / self.r - 1.0
    }

    /// Heading of the calibrated reading, in radians in (-pi, pi].
    #[inline]
    pub fn heading(&self, x: f64, y: f64) -> f64 {
        let (sx, sy) = self.apply(x, y);
        sy.atan2(sx)
    }

    /// Root mean square of the magnitude error over the samples.
    pub fn rms(&self, x: &[f64], y: &[f64]) -> f64 {
        if x.is_empty() {
            return 0.0;
        }
        let sum: f64 = x
            .iter()
            .zip(y)
            .map(|(&x, &y)| self.magnitude_error(x, y).powi(2))
            .sum();
        (sum / x.len() as f64).sqrt()
    }
}

/// Mean and spread of a column, for centring and scaling.
fn mean_and_spread(values: &[f64]) -> (f64, f64) {
    let n = values.len() as f64;
    let mean = values.iter().sum::<f64>() / n;
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
    (mean, var.sqrt())
}

fn check_inputs(x: &[f64], y: &[f64]) -> Result<(), FitError> {
    // Five points fix a conic; with four unknowns, four points fit exactly.
    if x.len() < UNKNOWNS || y.len() != x.len() {
        return Err(FitError::TooFewSamples {
            found: x.len().min(y.len()),
            unknowns: UNKNOWNS,
            needed: UNKNOWNS,
        });
    }
    for (axis, values) in [("x", x), ("y", y)] {
        let first = values[0];
        if values.iter().all(|&v| v == first) {
            return Err(FitError::ConstantAxis { axis, value: first });
        }
    }
    Ok(())
}

/// Closed-form least squares of eq. (6).
///
/// Raw counts in the tens of thousands make `x^2` columns of 1e9 beside a
/// column of ones: the normal equations would lose most of their digits.
/// So the columns are centred and scaled first (an affine change of the same
/// least-squares problem: its residual is the original one times a constant),
/// solved by Householder QR, and mapped back to raw units.
pub fn closed_form(x: &[f64], y: &[f64]) -> Result<Theta, FitError> {
    check_inputs(x, y)?;
    let (mx, sx) = mean_and_spread(x);
    let (my, sy) = mean_and_spread(y);
    let n = x.len();

    let phi = if n <= QR_BLOCK {
        let design = DMatrix::from_fn(n, UNKNOWNS, |i, j| {
            let u = (x[i] - mx) / sx;
            match j {
                0 => u * u,
                1 => u,
                2 => (y[i] - my) / sy,
                _ => 1.0,
            }
        });
        let mut target = DVector::from_fn(n, |i, _| ((y[i] - my) / sy).powi(2));
        solve_least_squares(design, &mut target)?
    } else {
        // A product by the reciprocal: a division per value would be most
        // of the time of the rows. The reciprocal of a finite, non-zero
        // spread is a normal number: the spread is the square root of a
        // variance of at least the least subnormal (so at least 2.2e-162)
        // and at most the largest f64 (so at most 1.3e154). A spread of 0,
        // of ∞ or NaN gives what dividing by it gives (NaN or ∞ for 0, 0
        // or NaN for ∞, NaN for NaN).
        let (to_u, to_v) = (1.0 / sx, 1.0 / sy);
        solve_by_blocks(n, |i| {
            let u = (x[i] - mx) * to_u;
            let v = (y[i] - my) * to_v;
            [u * u, u, v, 1.0, v * v]
        })?
    };

    // Back to raw units: substitute x = mx + sx*u, y = my + sy*v in
    // v^2 = phi1*u^2 + phi2*u + phi3*v + phi4 and multiply by sy^2.
    let [p1, p2, p3, p4] = [phi[0], phi[1], phi[2], phi[3]];
    let k = sy * sy / (sx * sx);
    Ok(Theta([
        k * p1,
        k * (p2 * sx - 2.0 * mx * p1),
        sy * p3 + 2.0 * my,
        k * (p1 * mx * mx - p2 * mx * sx) + sy * sy * (p4 - p3 * my / sy) - my * my,
    ]))
}

/// Standard errors of a, b, d, r from the algebraic least squares' own
/// covariance: `σ² (AᵀA)⁻¹` of eq. (4)'s rows `[x², x, y, 1]` (target `y²`),
/// `σ²` the residual variance of those rows at `theta` (n − 4 degrees of
/// freedom), propagated to a, b, d, r by the delta method through
/// `a = sqrt(−θ1), b = −θ2/(2a), d = −θ3/2, r = sqrt(θ4 + b² + d²)`.
/// `AᵀA` is formed on centred, scaled columns (as in [`closed_form`]) and
/// mapped back. `None` when the rows do not determine theta or `theta` is not
/// an ellipse of the family.
pub fn closed_form_se(x: &[f64], y: &[f64], theta: &Theta) -> Option<PaperCalibration> {
    check_inputs(x, y).ok()?;
    let n = x.len();
    if n <= UNKNOWNS {
        return None;
    }
    let cal = theta.to_calibration().ok()?;
    let [t1, t2, t3, t4] = theta.0;
    let (mx, sx) = mean_and_spread(x);
    let (my, sy) = mean_and_spread(y);
    // Residual variance of eq. (4)'s rows, raw units.
    let rss: f64 = x
        .iter()
        .zip(y)
        .map(|(&x, &y)| (y * y - (t1 * x * x + t2 * x + t3 * y + t4)).powi(2))
        .sum();
    let sigma2 = rss / (n - UNKNOWNS) as f64;
    // (UᵀU)⁻¹ of the scaled rows [u², u, v, 1].
    let mut utu = Matrix4::<f64>::zeros();
    for (&x, &y) in x.iter().zip(y) {
        let u = (x - mx) / sx;
        let row = Vector4::new(u * u, u, (y - my) / sy, 1.0);
        utu += row * row.transpose();
    }
    let inv = utu.try_inverse()?;
    // theta = J phi + const (the back-mapping of `closed_form`); a raw
    // residual is sy² times a scaled one, so cov(phi) = sigma2 / sy⁴ · inv.
    let k = sy * sy / (sx * sx);
    #[rustfmt::skip]
    let jac = Matrix4::new(
        k, 0.0, 0.0, 0.0,
        -2.0 * k * mx, k * sx, 0.0, 0.0,
        0.0, 0.0, sy, 0.0,
        k * mx * mx, -k * mx * sx, -sy * my, sy * sy,
    );
    let cov_theta = jac * inv * jac.transpose() * (sigma2 / sy.powi(4));
    // Delta method.
    let PaperCalibration { a, b, d, r } = cal;
    let da = [-1.0 / (2.0 * a), 0.0, 0.0, 0.0];
    let db = [-t2 / (4.0 * a * a * a), -1.0 / (2.0 * a), 0.0, 0.0];
    let dd = [0.0, 0.0, -0.5, 0.0];
    let dr: Vec<f64> = (0..4)
        .map(|j| (f64::from(j == 3) + 2.0 * b * db[j] + 2.0 * d * dd[j]) / (2.0 * r))
        .collect();
    let se = |g: &[f64]| {
        let g = Vector4::new(g[0], g[1], g[2], g[3]);
        (g.transpose() * cov_theta * g)[(0, 0)].max(0.0).sqrt()
    };
    let out = PaperCalibration {
        a: se(&da),
        b: se(&db),
        d: se(&dd),
        r: se(&dr),
    };
    [out.a, out.b, out.d, out.r]
        .iter()
        .all(|v| v.is_finite())
        .then_some(out)
}

/// Solves `min |A p - b|` for a tall `A` with four columns by Householder QR.
/// `b` is overwritten. Fails if `A` is rank-deficient.
pub(crate) fn solve_least_squares(
    design: DMatrix<f64>,
    target: &mut DVector<f64>,
) -> Result<Vector4<f64>, FitError> {
    let qr = design.qr();
    qr.q_tr_mul(target);
    let r4: Matrix4<f64> = qr.r().fixed_view::<4, 4>(0, 0).into_owned();
    let rhs = Vector4::new(target[0], target[1], target[2], target[3]);
    solve_triangle(&r4, &rhs)
}

/// Solves the triangle R of a QR of the scaled design for its right-hand
/// side (Qᵀ target). Columns are scaled to unit spread, so a tiny pivot
/// means a column is a combination of the others: the points do not
/// determine the conic.
fn solve_triangle(r4: &Matrix4<f64>, rhs: &Vector4<f64>) -> Result<Vector4<f64>, FitError> {
    let largest = (0..4).map(|i| r4[(i, i)].abs()).fold(0.0, f64::max);
    if (0..4).any(|i| !(r4[(i, i)].abs() > largest * 1e-10)) {
        return Err(FitError::Degenerate);
    }
    r4.solve_upper_triangular(rhs)
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .ok_or(FitError::Degenerate)
}

/// Rows factored at once by [`closed_form`]: up to this many, the whole
/// design in one Householder QR; beyond, a block at a time (the design of
/// one block, 4096 rows of five columns, is 160 KiB: it stays in the
/// cache, where the whole design of two million rows would be 80 MB
/// written, faulted in and read five times over).
pub(crate) const QR_BLOCK: usize = super::tsqr::BLOCK;

/// [`solve_least_squares`] of `n` rows `[x², x, y, 1 | target]` made by
/// `row`, a block of [`QR_BLOCK`] at a time ([`super::tsqr::StreamedR`]):
/// each block is stacked under the triangle R (of the design and the
/// target beside it) of the rows before and reduced again by Householder
/// reflections (a tall-skinny QR: as backward stable as one QR of all the
/// rows, and R the same up to the signs of its rows for a design of full
/// rank). The solution and the degeneracy test are those of
/// [`solve_least_squares`], on the last R.
fn solve_by_blocks(n: usize, row: impl Fn(usize) -> [f64; 5]) -> Result<Vector4<f64>, FitError> {
    let mut streamed = super::tsqr::StreamedR::<{ UNKNOWNS + 1 }>::default();
    for at in 0..n {
        streamed.push(row(at));
    }
    let r = streamed.finish();
    let r4 = Matrix4::from_fn(|i, j| r[i][j]);
    let rhs = Vector4::from_fn(|i, _| r[i][UNKNOWNS]);
    solve_triangle(&r4, &rhs)
}

/// Settings of the paper's gradient descent.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GradientDescentOptions {
    pub learning_rate: f64,
    pub tolerance: f64,
    /// The run ends with [`FitError::IterationCap`] after this many iterations.
    pub max_iterations: u64,
}

impl Default for GradientDescentOptions {
    fn default() -> Self {
        GradientDescentOptions {
            learning_rate: PAPER_LEARNING_RATE,
            tolerance: PAPER_TOLERANCE,
            max_iterations: 1_000_000,
        }
    }
}

/// What gradient descent reached.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GradientDescentOutcome {
    pub theta: Theta,
    pub iterations: u64,
}

/// Reported every [`PROGRESS_EVERY`] iterations while gradient descent runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GradientDescentProgress {
    pub iteration: u64,
    /// The largest |theta_j^n - theta_j^(n-1)| of this iteration (scaled theta).
    pub step: f64,
}

pub const PROGRESS_EVERY: u64 = 4096;

/// Scaled theta beyond this means the iteration is running away.
const DIVERGENCE_BOUND: f64 = 1e12;

/// The paper's standard gradient descent, eqs. (7)-(21), exactly: features
/// divided by their max-min ranges (12-19), theta from zero, the paper's
/// learning rate and stop rule, and theta unscaled with (20).
pub fn gradient_descent(
    x: &[f64],
    y: &[f64],
    options: &GradientDescentOptions,
    progress: &mut dyn FnMut(GradientDescentProgress),
) -> Result<GradientDescentOutcome, FitError> {
    check_inputs(x, y)?;
    let range = |values: &mut dyn Iterator<Item = f64>| {
        let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
        hi - lo
    };
    let rho1 = range(&mut x.iter().map(|v| v * v));
    let rho2 = range(&mut x.iter().copied());
    let rho3 = range(&mut y.iter().copied());
    let rho4 = range(&mut y.iter().map(|v| v * v));
    if !(rho1 > 0.0 && rho4 > 0.0) {
        // x or y symmetric about zero with a single magnitude: x^2 constant.
        return Err(FitError::Degenerate);
    }

    // Scaled features, laid out for one pass per iteration.
    let f1: Vec<f64> = x.iter().map(|v| v * v / rho1).collect();
    let f2: Vec<f64> = x.iter().map(|v| v / rho2).collect();
    let f3: Vec<f64> = y.iter().map(|v| v / rho3).collect();
    let target: Vec<f64> = y.iter().map(|v| v * v / rho4).collect();
    let inv_m = 1.0 / x.len() as f64;
    let alpha = options.learning_rate;

    let mut theta = [0.0f64; 4];
    let mut step = f64::INFINITY;
    for iteration in 1..=options.max_iterations {
        let mut grad = [0.0f64; 4];
        for i in 0..f1.len() {
            let eps = theta[3] + theta[2] * f3[i] + theta[1] * f2[i] + theta[0] * f1[i] - target[i];
            grad[0] += eps * f1[i];
            grad[1] += eps * f2[i];
            grad[2] += eps * f3[i];
            grad[3] += eps;
        }
        step = 0.0;
        for j in 0..4 {
            let delta = alpha * grad[j] * inv_m;
            theta[j] -= delta;
            step = step.max(delta.abs());
        }
        if !theta
            .iter()
            .all(|t| t.is_finite() && t.abs() < DIVERGENCE_BOUND)
        {
            return Err(FitError::Diverged {
                iteration,
                learning_rate: alpha,
            });
        }
        if step < options.tolerance {
            let unscaled = Theta([
                rho4 * theta[0] / rho1,
                rho4 * theta[1] / rho2,
                rho4 * theta[2] / rho3,
                rho4 * theta[3],
            ]);
            return Ok(GradientDescentOutcome {
                theta: unscaled,
                iterations: iteration,
            });
        }
        if iteration % PROGRESS_EVERY == 0 {
            progress(GradientDescentProgress { iteration, step });
        }
    }
    Err(FitError::IterationCap {
        cap: options.max_iterations,
        last_step: step,
        tolerance: options.tolerance,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Scaled rows `[u², u, v, 1 | v²]` of a noisy ellipse turned `n`
    /// samples, as `closed_form` makes them.
    fn rows(n: usize, seed: u64) -> Vec<[f64; 5]> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|i| {
                let angle = i as f64 * 0.0137;
                let u = 0.83 * angle.cos() - 0.2 + rng.random_range(-1e-3..1e-3);
                let v = angle.sin() + 0.1 + rng.random_range(-1e-3..1e-3);
                [u * u, u, v, 1.0, v * v]
            })
            .collect()
    }

    /// The same rows in one Householder QR.
    fn whole(rows: &[[f64; 5]]) -> Result<Vector4<f64>, FitError> {
        let design = DMatrix::from_fn(rows.len(), UNKNOWNS, |i, j| rows[i][j]);
        let mut target = DVector::from_fn(rows.len(), |i, _| rows[i][UNKNOWNS]);
        solve_least_squares(design, &mut target)
    }

    /// A block at a time is the least squares of all the rows: the same
    /// solution as one QR to 1e-12 (an R that lost the blocks before, or
    /// the last block, would be far off), at one block, a block and a
    /// row, and several blocks and a part.
    #[test]
    fn blocks_solve_the_whole_least_squares() {
        for (n, seed) in [(QR_BLOCK, 1), (QR_BLOCK + 1, 2), (3 * QR_BLOCK + 17, 3)] {
            let rows = rows(n, seed);
            let blocks = solve_by_blocks(n, |i| rows[i]).expect("an ellipse");
            let one = whole(&rows).expect("an ellipse");
            for k in 0..UNKNOWNS {
                assert!(
                    (blocks[k] - one[k]).abs() <= 1e-12 * one[k].abs().max(1.0),
                    "n = {n}: phi[{k}] {} by blocks, {} at once",
                    blocks[k],
                    one[k]
                );
            }
        }
    }

    /// Rows on a line (v = u) do not determine the conic, by blocks as at
    /// once.
    #[test]
    fn blocks_find_a_degenerate_design() {
        let n = 2 * QR_BLOCK + 5;
        let line: Vec<[f64; 5]> = (0..n)
            .map(|i| {
                let u = i as f64 / n as f64 - 0.5;
                [u * u, u, u, 1.0, u * u]
            })
            .collect();
        assert!(matches!(whole(&line), Err(FitError::Degenerate)));
        assert!(matches!(
            solve_by_blocks(n, |i| line[i]),
            Err(FitError::Degenerate)
        ));
    }
}
