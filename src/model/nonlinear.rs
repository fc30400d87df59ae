//! The general model: the paper's model plus any effects of the catalogue,
//! fitted by Levenberg-Marquardt from the paper's closed form.
//!
//! Per sample i (raw x, y; time t; covariates c_k):
//! - moving offsets: `x1 = x - drift_x*(t - mean t) - Σ g_xk*(c_k - mean c_k)`,
//!   the same for y, centred so that b and d stay the mean offsets;
//! - odd non-linearity: `x2 = x1 + k_x*x1^3/S^2`, with `S` = [`cubic_scale`]
//!   (a fixed scale of the data, so k_x is a fraction at full scale);
//! - the paper's linear part plus cross-axis: `s_x = a*x2 + b + c*(y2 + d)`,
//!   `s_y = y2 + d`;
//! - residual `e = |s|/r - 1`, the magnitude error as a fraction of the field.
//!
//! `outliers` adds no unknowns: it turns the fit robust (IRLS with Huber
//! weights) and flags samples far outside the robust spread.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::FitError;
use super::effects::Effect;
use super::fit::DEFAULT_MIN_COVERAGE_DEG;
use super::heading::{circle_centre, coverage};
use super::paper::{PaperCalibration, closed_form};
use crate::sample::Dataset;

/// Huber's tuning constant: 95 % efficiency on Gaussian noise.
pub const HUBER_TUNING: f64 = 1.345;
/// Scales a median absolute deviation to a Gaussian standard deviation.
pub const MAD_TO_SD: f64 = 1.4826;
/// Samples whose |e| exceeds this many robust standard deviations are flagged.
pub const FLAG_THRESHOLD_SD: f64 = 4.0;
/// Levenberg-Marquardt stops when an accepted step lowers the cost by less
/// than this fraction.
pub const RELATIVE_COST_TOLERANCE: f64 = 1e-12;
/// Levenberg-Marquardt iterations (over all IRLS rounds) before giving up.
pub const MAX_ITERATIONS: usize = 500;
/// Levenberg-Marquardt's stop rule within IRLS rounds whose weights still move.
const LOOSE_COST_TOLERANCE: f64 = 1e-8;
/// IRLS rounds before giving up on the weights settling.
const MAX_IRLS_ROUNDS: usize = 60;

/// One fitted parameter with its standard error.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Param {
    pub name: String,
    pub value: f64,
    pub se: f64,
}

/// A fitted model.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelFit {
    pub effects: Vec<Effect>,
    pub params: Vec<Param>,
    /// Root mean square of e over the samples used (not flagged).
    pub rms: f64,
    pub n: usize,
    pub unknowns: usize,
    /// e_i for every sample, input order (flagged ones included).
    pub residuals: Vec<f64>,
    /// atan2(s_y, s_x) in radians, every sample.
    pub headings: Vec<f64>,
    /// (s_x, s_y) for every sample.
    pub calibrated: Vec<(f64, f64)>,
    /// Outlier indices (outliers effect only), ascending.
    pub flagged: Vec<usize>,
    /// Final IRLS weights (all 1.0 without outliers).
    pub weights: Vec<f64>,
    /// Levenberg-Marquardt iterations, over all IRLS rounds.
    pub iterations: usize,
    /// Σ e² over the samples used (for BIC).
    pub rss: f64,
}

impl ModelFit {
    /// The parameter of that name, if the model has it.
    pub fn param(&self, name: &str) -> Option<&Param> {
        self.params.iter().find(|p| p.name == name)
    }

    /// The value of a parameter, 0 when the model lacks it.
    pub fn value(&self, name: &str) -> f64 {
        self.param(name).map_or(0.0, |p| p.value)
    }

    /// The paper's constants a, b, d, r of this fit.
    pub fn paper(&self) -> PaperCalibration {
        PaperCalibration {
            a: self.value("a"),
            b: self.value("b"),
            d: self.value("d"),
            r: self.value("r"),
        }
    }

    /// The calibrated reading of sample i ((0, 0) past the end).
    pub fn apply(&self, i: usize) -> (f64, f64) {
        self.calibrated.get(i).copied().unwrap_or((0.0, 0.0))
    }
}

/// The fixed scale S of the cubic term: the largest |x| or |y| of the data,
/// so `k` reads as the fraction of non-linearity at full scale and the
/// column `x^3/S^2` stays the size of x (conditioning).
pub fn cubic_scale(data: &Dataset) -> f64 {
    data.x
        .iter()
        .chain(&data.y)
        .fold(0.0f64, |m, v| m.max(v.abs()))
}

/// Where each unknown sits in the parameter vector, and the centred
/// columns the moving offsets use.
struct Layout<'a> {
    x: &'a [f64],
    y: &'a [f64],
    /// Index of c, when cross-axis is in the model.
    cross: Option<usize>,
    /// Index of drift_x (drift_y follows), with centred time.
    drift: Option<(usize, Vec<f64>)>,
    /// Index of g_x (g_y follows) and centred values, per covariate.
    covariates: Vec<(usize, Vec<f64>)>,
    /// Index of k_x (k_y follows).
    cubic: Option<usize>,
    /// 1/S^2 of the cubic term.
    inv_scale_sq: f64,
    names: Vec<String>,
}

fn centred(values: &[f64]) -> Vec<f64> {
    let mean = values.iter().sum::<f64>() / values.len().max(1) as f64;
    values.iter().map(|v| v - mean).collect()
}

impl<'a> Layout<'a> {
    fn new(data: &'a Dataset, effects: &[Effect]) -> Result<Self, FitError> {
        let mut names: Vec<String> = ["a", "b", "d", "r"].map(String::from).to_vec();
        let mut push = |name: String| {
            names.push(name);
            names.len() - 1
        };
        let cross = effects
            .contains(&Effect::CrossAxis)
            .then(|| push("c".into()));
        let drift = if effects.contains(&Effect::Drift) {
            let t = data.t.as_deref().ok_or(FitError::MissingTime)?;
            let index = push("drift_x".into());
            push("drift_y".into());
            Some((index, centred(t)))
        } else {
            None
        };
        let mut covariates = Vec::new();
        for effect in effects {
            if let Effect::Covariate(column) = effect {
                let found = data
                    .covariate(column)
                    .ok_or_else(|| FitError::MissingCovariate {
                        column: column.clone(),
                        available: data
                            .covariates
                            .iter()
                            .map(|c| c.name.clone())
                            .collect::<Vec<_>>()
                            .join(", "),
                    })?;
                let index = push(format!("{column}_x"));
                push(format!("{column}_y"));
                covariates.push((index, centred(&found.values)));
            }
        }
        let cubic = if effects.contains(&Effect::Cubic) {
            let index = push("k_x".into());
            push("k_y".into());
            Some(index)
        } else {
            None
        };
        let scale = cubic_scale(data);
        Ok(Layout {
            x: &data.x,
            y: &data.y,
            cross,
            drift,
            covariates,
            cubic,
            inv_scale_sq: if scale > 0.0 {
                1.0 / (scale * scale)
            } else {
                0.0
            },
            names,
        })
    }

    fn unknowns(&self) -> usize {
        self.names.len()
    }

    /// The calibrated reading of sample i; with `row`, also de/dp into it
    /// (row must have `unknowns()` entries). Returns (s_x, s_y, e).
    #[inline]
    fn evaluate(&self, p: &[f64], i: usize, row: Option<&mut [f64]>) -> (f64, f64, f64) {
        let (a, b, d, r) = (p[0], p[1], p[2], p[3]);
        let mut x1 = self.x[i];
        let mut y1 = self.y[i];
        if let Some((k, tc)) = &self.drift {
            x1 -= p[*k] * tc[i];
            y1 -= p[k + 1] * tc[i];
        }
        for (k, values) in &self.covariates {
            x1 -= p[*k] * values[i];
            y1 -= p[k + 1] * values[i];
        }
        let (mut x2, mut y2, mut dx2, mut dy2) = (x1, y1, 1.0, 1.0);
        if let Some(k) = self.cubic {
            x2 += p[k] * x1 * x1 * x1 * self.inv_scale_sq;
            y2 += p[k + 1] * y1 * y1 * y1 * self.inv_scale_sq;
            dx2 += 3.0 * p[k] * x1 * x1 * self.inv_scale_sq;
            dy2 += 3.0 * p[k + 1] * y1 * y1 * self.inv_scale_sq;
        }
        let c = self.cross.map_or(0.0, |k| p[k]);
        let sy = y2 + d;
        let sx = a * x2 + b + c * sy;
        // sqrt rather than hypot: no overflow is possible at sensor
        // magnitudes, and this is the hot loop.
        let m = (sx * sx + sy * sy).sqrt();
        let e = m / r - 1.0;
        if let Some(row) = row {
            // de/ds_x and de/ds_y; a zero reading has no direction.
            let (ux, uy) = if m > 0.0 {
                (sx / (m * r), sy / (m * r))
            } else {
                (0.0, 0.0)
            };
            // de/dy2 through both s_x (via c) and s_y.
            let uy2 = ux * c + uy;
            let ux2 = ux * a;
            row[0] = ux * x2;
            row[1] = ux;
            row[2] = uy2;
            row[3] = -m / (r * r);
            if let Some(k) = self.cross {
                row[k] = ux * sy;
            }
            if let Some((k, tc)) = &self.drift {
                row[*k] = -ux2 * dx2 * tc[i];
                row[k + 1] = -uy2 * dy2 * tc[i];
            }
            for (k, values) in &self.covariates {
                row[*k] = -ux2 * dx2 * values[i];
                row[k + 1] = -uy2 * dy2 * values[i];
            }
            if let Some(k) = self.cubic {
                row[k] = ux2 * x1 * x1 * x1 * self.inv_scale_sq;
                row[k + 1] = uy2 * y1 * y1 * y1 * self.inv_scale_sq;
            }
        }
        (sx, sy, e)
    }

    /// Σ w e², or None when a residual is not finite (a step too far).
    fn cost(&self, p: &[f64], weights: &[f64]) -> Option<f64> {
        let mut sum = 0.0;
        for (i, w) in weights.iter().enumerate() {
            let (_, _, e) = self.evaluate(p, i, None);
            sum += w * e * e;
        }
        sum.is_finite().then_some(sum)
    }

    /// JᵀWJ, JᵀWe and Σ w e² at p, in one pass.
    fn normal_equations(
        &self,
        p: &[f64],
        weights: &[f64],
        row: &mut [f64],
    ) -> (DMatrix<f64>, DVector<f64>, f64) {
        let k = self.unknowns();
        // Flat row-major accumulators: the hot loop of the fit, kept free of
        // matrix indexing and allocation.
        let mut upper = vec![0.0; k * k];
        let mut gradient = vec![0.0; k];
        let mut cost = 0.0;
        for (i, &w) in weights.iter().enumerate() {
            let (_, _, e) = self.evaluate(p, i, Some(row));
            cost += w * e * e;
            for (u, &ru) in row.iter().enumerate() {
                let wu = w * ru;
                gradient[u] += wu * e;
                let target = &mut upper[u * k + u..(u + 1) * k];
                for (acc, &rv) in target.iter_mut().zip(&row[u..]) {
                    *acc += wu * rv;
                }
            }
        }
        let jtj = DMatrix::from_fn(k, k, |u, v| {
            let (lo, hi) = if u <= v { (u, v) } else { (v, u) };
            upper[lo * k + hi]
        });
        let jte = DVector::from_vec(gradient);
        (jtj, jte, cost)
    }
}

/// Applies the stored parameters of the model `effects` to a recording:
/// `(s_x, s_y, e)` for every sample. Drift and covariate terms are taken
/// about the recording's own mean time and mean covariate value (as the fit
/// takes them), so the stored `b` and `d` are the offsets at those means.
/// `cubic_scale`: the full scale S the stored `k` refers to (the fitted
/// recording's); `None` takes this recording's.
pub fn apply_model(
    data: &Dataset,
    effects: &[Effect],
    params: &[Param],
    cubic_scale: Option<f64>,
) -> Result<Vec<(f64, f64, f64)>, FitError> {
    let mut layout = Layout::new(data, effects)?;
    if let Some(scale) = cubic_scale.filter(|s| *s > 0.0 && s.is_finite()) {
        layout.inv_scale_sq = 1.0 / (scale * scale);
    }
    let p: Vec<f64> = layout
        .names
        .iter()
        .map(|name| {
            params
                .iter()
                .find(|q| &q.name == name)
                .map(|q| q.value)
                .filter(|v| v.is_finite())
                .ok_or_else(|| FitError::MissingParameter {
                    parameter: name.clone(),
                })
        })
        .collect::<Result<_, _>>()?;
    Ok((0..data.len())
        .map(|i| layout.evaluate(&p, i, None))
        .collect())
}

/// Fits the model made of `effects` (the paper's plus any others) to the
/// recording, by Levenberg-Marquardt started from the paper's closed form.
pub fn fit_model(data: &Dataset, effects: &[Effect]) -> Result<ModelFit, FitError> {
    let layout = Layout::new(data, effects)?;
    let unknowns = layout.unknowns();
    let n = data.len();
    if n < unknowns + 1 {
        return Err(FitError::TooFewSamples {
            found: n,
            unknowns,
            needed: unknowns + 1,
        });
    }
    let start = starting_point(data)?;
    let mut p = vec![0.0; unknowns];
    p[..4].copy_from_slice(&[start.a, start.b, start.d, start.r]);

    let robust = effects.contains(&Effect::Outliers);
    let mut weights = vec![1.0; n];
    let mut row = vec![0.0; unknowns];
    let mut residuals = vec![0.0; n];
    let mut iterations = 0;
    let mut scale = 0.0;
    // The damping carries over between IRLS rounds: each round starts near
    // the last minimum, where small damping is right.
    let mut lambda = 1e-3;
    // While the weights still move, each round need not reach the last
    // digit: a loose tolerance, then one tight run once they have settled.
    let mut settled = !robust;
    for round in 0.. {
        let tolerance = if settled {
            RELATIVE_COST_TOLERANCE
        } else {
            LOOSE_COST_TOLERANCE
        };
        iterations += levenberg_marquardt(
            &layout,
            &mut p,
            &weights,
            &mut row,
            &mut lambda,
            tolerance,
            iterations,
        )
        .map_err(|e| explain_failure(e, data, &start))?;
        if settled {
            break;
        }
        for (i, e) in residuals.iter_mut().enumerate() {
            *e = layout.evaluate(&p, i, None).2;
        }
        scale = robust_sd(&residuals);
        let mut largest_change = 0.0f64;
        for (w, e) in weights.iter_mut().zip(&residuals) {
            let new = huber_weight(*e, scale);
            largest_change = largest_change.max((new - *w).abs());
            *w = new;
        }
        // Weights settled to 1e-5 move the parameters by far less than
        // their standard errors.
        if largest_change < 1e-5 {
            settled = true;
        }
        if !settled && round + 1 >= MAX_IRLS_ROUNDS {
            return Err(FitError::NoConvergence {
                iterations,
                what: "the robust weights did not settle",
            });
        }
    }

    // Everything the caller sees, at the final parameters.
    let mut calibrated = Vec::with_capacity(n);
    let mut headings = Vec::with_capacity(n);
    for (i, e) in residuals.iter_mut().enumerate() {
        let (sx, sy, err) = layout.evaluate(&p, i, None);
        *e = err;
        calibrated.push((sx, sy));
        headings.push(sy.atan2(sx));
    }
    let flagged: Vec<usize> = if robust && scale > 0.0 {
        residuals
            .iter()
            .enumerate()
            .filter(|(_, e)| e.abs() > FLAG_THRESHOLD_SD * scale)
            .map(|(i, _)| i)
            .collect()
    } else {
        Vec::new()
    };
    let mut rss = 0.0;
    let mut next_flagged = flagged.iter().peekable();
    for (i, e) in residuals.iter().enumerate() {
        if next_flagged.peek() == Some(&&i) {
            next_flagged.next();
            continue;
        }
        rss += e * e;
    }
    let used = n - flagged.len();
    let rms = (rss / used.max(1) as f64).sqrt();

    // Standard errors from the curvature at the minimum.
    let (jtj, _, weighted_cost) = layout.normal_equations(&p, &weights, &mut row);
    let covariance = jtj
        .clone()
        .cholesky()
        .map(|c| c.inverse())
        .ok_or_else(|| undetermined(&layout, &jtj))?;
    let sigma_sq = weighted_cost / (n - unknowns) as f64;
    let params: Vec<Param> = layout
        .names
        .iter()
        .enumerate()
        .map(|(j, name)| Param {
            name: name.clone(),
            value: p[j] + 0.0,
            se: (covariance[(j, j)] * sigma_sq).max(0.0).sqrt(),
        })
        .collect();

    if let Some(bad) = params
        .iter()
        .find(|q| !q.value.is_finite() || !q.se.is_finite())
    {
        return Err(FitError::NotFinite {
            parameter: bad.name.clone(),
        });
    }
    for (name, value) in [("a", p[0]), ("r", p[3])] {
        if !(value > 0.0) {
            return Err(FitError::NonPositive {
                parameter: name,
                value,
            });
        }
    }
    if !rms.is_finite() || residuals.iter().any(|e| !e.is_finite()) {
        return Err(FitError::NotFinite {
            parameter: "rms".into(),
        });
    }

    Ok(ModelFit {
        effects: effects.to_vec(),
        params,
        rms,
        n,
        unknowns,
        residuals,
        headings,
        calibrated,
        flagged,
        weights,
        iterations,
        rss,
    })
}

/// Where Levenberg-Marquardt starts: the paper's closed form, or, when
/// the readings fit no ellipse of the paper's family (strong coupling,
/// spikes), the best circle, from which the general model may still get
/// there. A failure of both reports the closed form's reason.
/// A fit that fails on readings that never went round is a problem of the
/// turn or of the columns chosen, not of the model: say so.
fn explain_failure(error: FitError, data: &Dataset, start: &PaperCalibration) -> FitError {
    if !matches!(
        error,
        FitError::NoConvergence { .. } | FitError::NotFinite { .. } | FitError::NonPositive { .. }
    ) {
        return error;
    }
    let turn = coverage(
        data.x
            .iter()
            .zip(&data.y)
            .map(|(&x, &y)| start.heading(x, y)),
    );
    if turn.covered_deg < DEFAULT_MIN_COVERAGE_DEG {
        FitError::NoTurn {
            covered_deg: turn.covered_deg,
            gap_deg: turn.largest_gap_deg,
            gap_start_deg: turn.gap_start_deg,
        }
    } else {
        error
    }
}

fn starting_point(data: &Dataset) -> Result<PaperCalibration, FitError> {
    let closed = closed_form(&data.x, &data.y).and_then(|theta| theta.to_calibration());
    let error = match closed {
        Ok(start) => return Ok(start),
        Err(e @ (FitError::NotAnEllipse { .. } | FitError::NoRadius { .. })) => e,
        Err(e) => return Err(e),
    };
    let (cx, cy) = circle_centre(&data.x, &data.y).map_err(|_| error.clone())?;
    let r = data
        .x
        .iter()
        .zip(&data.y)
        .map(|(x, y)| (x - cx).hypot(y - cy))
        .sum::<f64>()
        / data.len().max(1) as f64;
    if r > 0.0 && r.is_finite() {
        Ok(PaperCalibration {
            a: 1.0,
            b: -cx,
            d: -cy,
            r,
        })
    } else {
        Err(error)
    }
}

/// The parameter whose column carries no information (zero or dependent).
fn undetermined(layout: &Layout<'_>, jtj: &DMatrix<f64>) -> FitError {
    let largest = (0..jtj.nrows()).map(|j| jtj[(j, j)]).fold(0.0, f64::max);
    let index = (0..jtj.nrows())
        .find(|&j| !(jtj[(j, j)] > largest * 1e-300))
        .unwrap_or(jtj.nrows().saturating_sub(1));
    FitError::Undetermined {
        parameter: layout.names.get(index).cloned().unwrap_or_default(),
    }
}

/// Runs Levenberg-Marquardt with fixed weights from `p`, in place; returns
/// the iterations it took. `done` counts iterations already spent (cap).
fn levenberg_marquardt(
    layout: &Layout<'_>,
    p: &mut [f64],
    weights: &[f64],
    row: &mut [f64],
    lambda: &mut f64,
    tolerance: f64,
    done: usize,
) -> Result<usize, FitError> {
    let k = p.len();
    *lambda = lambda.max(1e-6);
    let mut trial = vec![0.0; k];
    let (mut jtj, mut jte, mut cost) = layout.normal_equations(p, weights, row);
    for j in 0..k {
        if !(jtj[(j, j)] > 0.0) {
            return Err(undetermined(layout, &jtj));
        }
    }
    let mut iterations = 0;
    loop {
        if done + iterations >= MAX_ITERATIONS {
            return Err(FitError::NoConvergence {
                iterations: done + iterations,
                what: "Levenberg-Marquardt did not converge",
            });
        }
        iterations += 1;
        if cost == 0.0 {
            return Ok(iterations);
        }
        // Marquardt's scaling: damping proportional to each curvature, so
        // parameters of very different units step alike.
        let mut damped = jtj.clone();
        for j in 0..k {
            damped[(j, j)] += *lambda * jtj[(j, j)];
        }
        let step = damped.cholesky().map(|c| c.solve(&(-&jte)));
        let accepted = match step {
            Some(step) => {
                for j in 0..k {
                    trial[j] = p[j] + step[j];
                }
                match layout.cost(&trial, weights) {
                    Some(new_cost) if trial[3] > 0.0 && new_cost <= cost => {
                        let relative = (cost - new_cost) / cost;
                        p.copy_from_slice(&trial);
                        let small_step =
                            (0..k).all(|j| step[j].abs() <= 1e-12 * p[j].abs().max(1e-300));
                        if relative < tolerance || small_step {
                            return Ok(iterations);
                        }
                        Some(())
                    }
                    _ => None,
                }
            }
            None => None,
        };
        if accepted.is_some() {
            *lambda = (*lambda / 10.0).max(1e-15);
            (jtj, jte, cost) = layout.normal_equations(p, weights, row);
        } else {
            *lambda *= 10.0;
            // No step, however short, lowers the cost: p is the minimum to
            // the precision of the arithmetic.
            if *lambda > 1e12 {
                return Ok(iterations);
            }
        }
    }
}

/// Median absolute deviation about the median, as a Gaussian SD.
fn robust_sd(residuals: &[f64]) -> f64 {
    let mut work: Vec<f64> = residuals.to_vec();
    let median = median_in_place(&mut work);
    for (w, e) in work.iter_mut().zip(residuals) {
        *w = (e - median).abs();
    }
    MAD_TO_SD * median_in_place(&mut work)
}

fn median_in_place(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    let mid = values.len() / 2;
    let (_, m, _) = values.select_nth_unstable_by(mid, f64::total_cmp);
    *m
}

/// Huber's weight for a residual at a robust scale.
fn huber_weight(e: f64, scale: f64) -> f64 {
    if !(scale > 0.0) {
        return 1.0;
    }
    let z = (e / scale).abs();
    if z <= HUBER_TUNING {
        1.0
    } else {
        HUBER_TUNING / z
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn apply_model_reproduces_the_fit() {
        let sensor = crate::sim::SimSensor {
            gain_x: 1.1,
            offset_x: 50.0,
            noise: 3.0,
            effects: crate::sim::SimEffects {
                cross_axis_deg: 2.0,
                cubic: [0.02, 0.0],
                drift_per_s: [0.5, -0.3],
                ..Default::default()
            },
            ..Default::default()
        };
        let data = sensor.simulate().unwrap();
        let effects = crate::model::effects::parse_list("cross-axis,cubic,drift").unwrap();
        let fit = fit_model(&data, &effects).unwrap();
        let applied = apply_model(&data, &effects, &fit.params, None).unwrap();
        for (i, (sx, sy, e)) in applied.iter().enumerate() {
            let (fx, fy) = fit.calibrated[i];
            assert!((sx - fx).abs() < 1e-9 && (sy - fy).abs() < 1e-9);
            assert!((e - fit.residuals[i]).abs() < 1e-12);
        }
        let missing: Vec<Param> = fit
            .params
            .iter()
            .filter(|p| p.name != "c")
            .cloned()
            .collect();
        assert_eq!(
            apply_model(&data, &effects, &missing, None),
            Err(FitError::MissingParameter {
                parameter: "c".into()
            })
        );
    }
    use crate::model::effects::PAPER;
    use crate::sim::SimSensor;

    #[test]
    fn paper_effects_agree_with_the_closed_form() {
        let sensor = SimSensor {
            gain_x: 1.2,
            offset_x: 150.0,
            offset_y: -80.0,
            noise: 2.0,
            turns: 2.0,
            ..Default::default()
        };
        let data = sensor.simulate().unwrap();
        let closed = closed_form(&data.x, &data.y)
            .unwrap()
            .to_calibration()
            .unwrap();
        let fit = fit_model(&data, &PAPER).unwrap();
        let paper = fit.paper();
        for (name, got, want) in [
            ("a", paper.a, closed.a),
            ("b", paper.b, closed.b),
            ("d", paper.d, closed.d),
            ("r", paper.r, closed.r),
        ] {
            let se = fit.param(name).unwrap().se;
            assert!(
                (got - want).abs() < 3.0 * se,
                "{name}: {got} vs {want} ± {se}"
            );
        }
        assert!(fit.rms <= closed.rms(&data.x, &data.y) * 1.0001);
    }

    #[test]
    fn noiseless_circle_fits_exactly() {
        let data = SimSensor {
            offset_x: 10.0,
            ..Default::default()
        }
        .simulate()
        .unwrap();
        let fit = fit_model(&data, &[Effect::Offset, Effect::Scale, Effect::CrossAxis]).unwrap();
        assert!(fit.rms < 1e-9, "{}", fit.rms);
        assert!((fit.value("b") + 10.0).abs() < 1e-6);
    }
}
