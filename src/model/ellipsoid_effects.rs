//! The 3-D model with the effects of the catalogue that carry over to
//! three axes: calibrated = W·(q' − o), |calibrated| = r, where, per sample
//! (raw reading, time t, logged covariates c_k):
//!
//! - moving offsets: `q = raw − (t − t̄)·ȯ − Σ_k (c_k − c̄_k)·g_k` (`drift`:
//!   3 unknowns ȯ, raw units per second; `covariate:<column>`: 3 unknowns
//!   g_k, raw units per unit of the column), centred so that `o` stays the
//!   mean offset;
//! - odd non-linearity per axis about the sensor's zero (`cubic`, 3
//!   unknowns): `q'_j = q_j + k_j·q_j³/S²`, S the largest |reading| of any
//!   axis (as the 2-D [`super::nonlinear::cubic_scale`]), so k_j is the
//!   fraction of non-linearity at full scale;
//! - `outliers`: a robust fit (IRLS with Huber weights on the magnitude
//!   error, scaled by 1.4826·MAD), the samples beyond
//!   [`FLAG_THRESHOLD_SD`] robust SD flagged, then the model refitted on
//!   the inliers alone, so every parameter (the base ones too) and its
//!   standard error come from the inliers.
//!
//! The base W (`offset`, `offset+scale`, `offset+scale+cross-axis`) and its
//! det W = 1 normalisation are [`super::ellipsoid`]'s, and the fit starts
//! from [`super::ellipsoid::fit`]'s result for the base model (which also
//! applies the coverage rule: effects never make an uncovered sphere
//! acceptable). `cubic-centred` has no 3-D form here: the 2-D term is
//! defined about a turn's centre in its plane.
//!
//! Levenberg–Marquardt ([`super::lm`]) on the magnitude error
//! |A(p − o)| − 1 (A = W/r), on data centred on their mean and scaled by
//! their rms spread (so raw counts in the tens of thousands fit as gauss
//! do), with an iteration cap, and standard errors σ²(JᵀJ)⁻¹ propagated to
//! the reported parameters.

use nalgebra::{DMatrix, Matrix3, Vector3};
use serde::Serialize;

use super::calibration3::correct3;
use super::effects::Effect;
use super::ellipsoid::{
    self, Ellipsoid, Ellipsoid3Error, Ellipsoid3Fit, Ellipsoid3Model, Ellipsoid3Se,
};
use super::lm::{self, LeastSquares, Weighting};
use super::nonlinear::{FLAG_THRESHOLD_SD, HUBER_TUNING, Param, covariate_names, first_not_finite};
use super::residuals::robust_sd;
use super::sphere::{self, SphereCoverage};
use crate::sample::{Covariate, Dataset3};

/// Levenberg–Marquardt iterations over all IRLS rounds before giving up
/// (as the 2-D [`super::nonlinear::MAX_ITERATIONS`]).
pub const MAX_ITERATIONS: usize = 500;
/// IRLS rounds before giving up on the robust weights settling (as 2-D).
pub const MAX_IRLS_ROUNDS: usize = 60;
/// Stop when an accepted step lowers the cost by less than this fraction.
const RELATIVE_COST_TOLERANCE: f64 = 1e-12;
/// The looser stop rule within IRLS rounds whose weights still move.
const LOOSE_COST_TOLERANCE: f64 = 1e-8;

/// Why the 3-D model with effects gave no calibration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum Effects3Error {
    /// The base fit's reasons (coverage, too few samples, degenerate...).
    #[error(transparent)]
    Fit(#[from] Ellipsoid3Error),
    #[error(
        "the drift effect needs sample times, and the recording has no time column (t, t_s, time or time_s, or choose one with --t)"
    )]
    MissingTime,
    #[error(
        "the recording has no column '{column}' for the effect covariate:{column}; its covariate columns are: {available}"
    )]
    MissingCovariate { column: String, available: String },
    #[error(
        "the effect {effect} has no 3-D form (it is defined about a turn's centre in its plane); use cubic for a per-axis non-linearity"
    )]
    NotIn3D { effect: Effect },
    #[error(
        "the readings do not determine the parameter '{parameter}' (its column is constant or a combination of others); drop the effect that adds it"
    )]
    Undetermined { parameter: String },
    #[error(
        "the fit did not converge ({what}) within {iterations} iterations; the model may not suit these readings: try fewer effects"
    )]
    NoConvergence {
        iterations: usize,
        what: &'static str,
    },
}

/// A fitted 3-D model with effects.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Ellipsoid3EffectsFit {
    /// The base W.
    pub model: Ellipsoid3Model,
    /// The whole model by the catalogue's names, sorted: the base's
    /// (`offset`, `scale`, `cross-axis`) and the extras.
    pub effects: Vec<Effect>,
    /// o, raw units (at the mean time and the covariates' means).
    pub offset: [f64; 3],
    /// W, row-major, symmetric, det W = 1.
    pub matrix: [[f64; 3]; 3],
    /// The field's magnitude, raw units.
    pub r: f64,
    pub se: Ellipsoid3Se,
    /// Every estimated parameter with its standard error: `o_x`.., the free
    /// entries of W (`W_xx`.., `W_yz`..), `r`, then the extras' own:
    /// `drift_x`.. (raw units per second), `<column>_x`.. (raw units per
    /// unit of the column), `k_x`.. (fraction at full scale).
    pub params: Vec<Param>,
    /// Root mean square of |calibrated|/r − 1 over the samples used.
    pub rms: f64,
    /// Σ e² over the samples used (for BIC).
    pub rss: f64,
    pub n: usize,
    /// Unknowns of the model (flagged samples not counted).
    pub unknowns: usize,
    /// |calibrated|/r − 1 for every sample, input order (flagged included).
    #[serde(skip)]
    pub residuals: Vec<f64>,
    /// W·(q' − o), raw units, every sample.
    #[serde(skip)]
    pub calibrated: Vec<[f64; 3]>,
    /// Outlier indices (the `outliers` effect only), ascending.
    pub flagged: Vec<usize>,
    /// Levenberg–Marquardt iterations over all rounds.
    pub iterations: usize,
    /// Directions of the calibrated samples used, on the sphere.
    pub coverage: SphereCoverage,
    /// Where the moving offsets and the cubic are referred to, to apply the
    /// model to other samples ([`Ellipsoid3EffectsFit::calibrate`]).
    #[serde(skip)]
    pub reference: Effects3Reference,
}

/// The fitted samples' means the moving offsets are centred on, and the
/// full scale S of the cubic: with them the model applies to any sample.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Effects3Reference {
    /// The mean time of the fitted samples (s), with `drift`.
    pub t_mean: Option<f64>,
    /// Each `covariate:<column>`'s mean over the fitted samples, by column.
    pub covariate_means: Vec<(String, f64)>,
    /// S: the largest |reading| of any axis of the fitted samples, with
    /// `cubic` (its k is the fraction of non-linearity at S).
    pub cubic_scale: Option<f64>,
}

impl Ellipsoid3EffectsFit {
    /// The parameter of that name, if the model has it.
    pub fn param(&self, name: &str) -> Option<&Param> {
        self.params.iter().find(|p| p.name == name)
    }

    /// The value of a parameter, 0 when the model lacks it.
    pub fn value(&self, name: &str) -> f64 {
        self.param(name).map_or(0.0, |p| p.value)
    }

    /// W·(q' − o) for every sample of `data` (raw units, input order):
    /// the drift and covariate offsets removed about the fitted samples'
    /// means, the cubic undone about S, so samples the fit did not use (the
    /// moving ones of a `--still` fit) are calibrated as the fitted ones.
    pub fn calibrate(&self, data: &Dataset3) -> Result<Vec<[f64; 3]>, Effects3Error> {
        let mut moving: Vec<(&[f64], f64, [f64; 3])> = Vec::new();
        if let Some(t_mean) = self.reference.t_mean {
            let t = data.t.as_deref().ok_or(Effects3Error::MissingTime)?;
            let rate = AXES.map(|a| self.value(&format!("drift_{a}")));
            moving.push((t, t_mean, rate));
        }
        for (column, mean) in &self.reference.covariate_means {
            let found = covariate(data, column)?;
            let gain = AXES.map(|a| self.value(&format!("{column}_{a}")));
            moving.push((&found.values, *mean, gain));
        }
        let cubic = self.reference.cubic_scale.map(|s| {
            let k = AXES.map(|a| self.value(&format!("k_{a}")));
            (k, 1.0 / (s * s))
        });
        let w = &self.matrix;
        Ok(data
            .points
            .iter()
            .enumerate()
            .map(|(i, raw)| {
                let mut q = *raw;
                for (values, mean, per_unit) in &moving {
                    let delta = values.get(i).copied().unwrap_or(*mean) - mean;
                    for j in 0..3 {
                        q[j] -= per_unit[j] * delta;
                    }
                }
                if let Some((k, inv_s2)) = cubic {
                    q = [0, 1, 2].map(|j| q[j] + k[j] * q[j].powi(3) * inv_s2);
                }
                correct3(&self.offset, w, q)
            })
            .collect())
    }
}

const AXES: [&str; 3] = ["x", "y", "z"];

/// The recording's covariate `column`, or which columns it has.
fn covariate<'d>(data: &'d Dataset3, column: &str) -> Result<&'d Covariate, Effects3Error> {
    data.covariate(column)
        .ok_or_else(|| Effects3Error::MissingCovariate {
            column: column.to_string(),
            available: covariate_names(&data.covariates),
        })
}

/// The base model a list of effects asks for, at least `base`: `scale`
/// asks for `offset+scale`, `cross-axis` for the full W.
pub fn base_of(base: Ellipsoid3Model, effects: &[Effect]) -> Ellipsoid3Model {
    let wanted = if effects.contains(&Effect::CrossAxis) {
        Ellipsoid3Model::Full
    } else if effects.contains(&Effect::Scale) {
        Ellipsoid3Model::OffsetScale
    } else {
        Ellipsoid3Model::Offset
    };
    if wanted.unknowns() > base.unknowns() {
        wanted
    } else {
        base
    }
}

/// The catalogue names of a base model's W.
pub fn base_effects(model: Ellipsoid3Model) -> Vec<Effect> {
    match model {
        Ellipsoid3Model::Offset => vec![Effect::Offset],
        Ellipsoid3Model::OffsetScale => vec![Effect::Offset, Effect::Scale],
        Ellipsoid3Model::Full => vec![Effect::Offset, Effect::Scale, Effect::CrossAxis],
    }
}

/// What the model holds and how the packed parameters are laid out.
struct Layout<'a> {
    raw: &'a [[f64; 3]],
    model: Ellipsoid3Model,
    mean: Vector3<f64>,
    spread: f64,
    /// Moving offsets: (first packed index, the normalised regressor per
    /// sample, the regressor's unit in its own units: raw per unit = s/scale).
    moving: Vec<(usize, Vec<f64>, f64)>,
    /// First packed index of k, and 1/S².
    cubic: Option<(usize, f64)>,
    names: Vec<String>,
}

fn base_names(model: Ellipsoid3Model) -> Vec<String> {
    let mut names: Vec<String> = AXES.iter().map(|a| format!("o_{a}")).collect();
    match model {
        Ellipsoid3Model::Offset => names.push("a".into()),
        Ellipsoid3Model::OffsetScale => names.extend(["W_xx", "W_yy", "W_zz"].map(String::from)),
        Ellipsoid3Model::Full => {
            names.extend(["W_xx", "W_yy", "W_zz", "W_yz", "W_xz", "W_xy"].map(String::from))
        }
    }
    names
}

/// Values centred on their mean and divided by their SD, and that SD;
/// `None` when the values are constant.
fn standardised(values: &[f64]) -> Option<(Vec<f64>, f64)> {
    let n = values.len().max(1) as f64;
    let mean = values.iter().sum::<f64>() / n;
    let sd = (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n).sqrt();
    if !(sd > 0.0) || !sd.is_finite() {
        return None;
    }
    Some((values.iter().map(|v| (v - mean) / sd).collect(), sd))
}

impl<'a> Layout<'a> {
    fn new(
        data: &'a Dataset3,
        model: Ellipsoid3Model,
        extras: &[Effect],
        mean: Vector3<f64>,
        spread: f64,
    ) -> Result<Self, Effects3Error> {
        let mut names = base_names(model);
        let mut moving = Vec::new();
        let mut cubic = None;
        let mut sorted: Vec<&Effect> = extras.iter().collect();
        sorted.sort();
        sorted.dedup();
        for effect in sorted {
            if !effect.is_in_3d() {
                return Err(Effects3Error::NotIn3D {
                    effect: effect.clone(),
                });
            }
            match effect {
                // No columns of their own (the base model holds the first
                // three, outliers reweights); cubic-centred was refused above.
                Effect::Offset
                | Effect::Scale
                | Effect::CrossAxis
                | Effect::Outliers
                | Effect::CubicCentred => {}
                Effect::Drift => {
                    let t = data.t.as_deref().ok_or(Effects3Error::MissingTime)?;
                    let (tau, sd) = standardised(t).ok_or_else(|| Effects3Error::Undetermined {
                        parameter: "drift_x".into(),
                    })?;
                    moving.push((names.len(), tau, spread / sd));
                    names.extend(AXES.map(|a| format!("drift_{a}")));
                }
                Effect::Covariate(column) => {
                    let found = covariate(data, column)?;
                    let (gamma, sd) =
                        standardised(&found.values).ok_or_else(|| Effects3Error::Undetermined {
                            parameter: format!("{column}_x"),
                        })?;
                    moving.push((names.len(), gamma, spread / sd));
                    names.extend(AXES.map(|a| format!("{column}_{a}")));
                }
                Effect::Cubic => {
                    let s = data
                        .points
                        .iter()
                        .flat_map(|p| p.iter())
                        .fold(0.0f64, |m, v| m.max(v.abs()));
                    if !(s > 0.0) {
                        return Err(Effects3Error::Undetermined {
                            parameter: "k_x".into(),
                        });
                    }
                    cubic = Some((names.len(), 1.0 / (s * s)));
                    names.extend(AXES.map(|a| format!("k_{a}")));
                }
            }
        }
        Ok(Layout {
            raw: &data.points,
            model,
            mean,
            spread,
            moving,
            cubic,
            names,
        })
    }

    fn unknowns(&self) -> usize {
        self.names.len()
    }

    fn a_of(&self, v: &[f64]) -> Matrix3<f64> {
        ellipsoid::packed_matrix(self.model, v)
    }

    /// (q', p, d = p − o, v = A d) of sample i: raw units, then scaled.
    fn point(&self, v: &[f64], a: &Matrix3<f64>, i: usize) -> ([f64; 3], Vector3<f64>) {
        let mut q = self.raw[i];
        for (index, reg, _) in &self.moving {
            for j in 0..3 {
                q[j] -= self.spread * v[index + j] * reg[i];
            }
        }
        let mut qc = q;
        if let Some((index, inv_s2)) = self.cubic {
            for j in 0..3 {
                qc[j] += v[index + j] * q[j].powi(3) * inv_s2;
            }
        }
        let p = (Vector3::from(qc) - self.mean) / self.spread;
        let d = p - Vector3::new(v[0], v[1], v[2]);
        (q, a * d)
    }

    /// Residual of sample i and, when asked, its gradient.
    fn evaluate(&self, v: &[f64], a: &Matrix3<f64>, i: usize, row: Option<&mut [f64]>) -> f64 {
        let (q, av) = self.point(v, a, i);
        let norm = av.norm();
        if let Some(row) = row {
            let safe = norm.max(f64::MIN_POSITIVE);
            let g = (a * av) / safe;
            // d = A⁻¹·av is needed for the entries of A.
            let o = Vector3::new(v[0], v[1], v[2]);
            let mut qc = q;
            if let Some((index, inv_s2)) = self.cubic {
                for j in 0..3 {
                    qc[j] += v[index + j] * q[j].powi(3) * inv_s2;
                }
            }
            let d = (Vector3::from(qc) - self.mean) / self.spread - o;
            for j in 0..3 {
                row[j] = -g[j];
            }
            ellipsoid::gradient_in_matrix(self.model, &av, &d, safe, &mut row[3..]);
            // ∂p_j/∂q_j.
            let h: [f64; 3] = match self.cubic {
                Some((index, inv_s2)) => {
                    [0, 1, 2].map(|j| 1.0 + 3.0 * v[index + j] * q[j] * q[j] * inv_s2)
                }
                None => [1.0; 3],
            };
            for (index, reg, _) in &self.moving {
                for j in 0..3 {
                    row[index + j] = -g[j] * h[j] * reg[i];
                }
            }
            if let Some((index, inv_s2)) = self.cubic {
                for j in 0..3 {
                    row[index + j] = g[j] * q[j].powi(3) * inv_s2 / self.spread;
                }
            }
        }
        norm - 1.0
    }

    /// Reported values: o (3), W row-major (9), r, then every extra in its
    /// own units. `None` when A is not positive definite.
    fn report(&self, v: &[f64]) -> Option<Vec<f64>> {
        let mut out = ellipsoid::report(self.model, v, &self.mean, self.spread)?;
        let base = self.model.unknowns();
        for (j, value) in v.iter().enumerate().skip(base) {
            let unit = self
                .moving
                .iter()
                .find(|(index, _, _)| (*index..index + 3).contains(&j))
                .map_or(1.0, |(_, _, unit)| *unit);
            out.push(value * unit);
        }
        Some(out)
    }
}

/// The 3-D model with effects as a least-squares problem: the magnitude
/// error of every sample of positive weight.
impl LeastSquares for Layout<'_> {
    type Shared = Matrix3<f64>;

    fn shared(&self, v: &[f64]) -> Matrix3<f64> {
        self.a_of(v)
    }

    fn residual(&self, a: &Matrix3<f64>, v: &[f64], i: usize, row: Option<&mut [f64]>) -> f64 {
        self.evaluate(v, a, i, row)
    }
}

/// Levenberg–Marquardt with Marquardt's scaling and fixed weights, in
/// place; returns the iterations it took. `done` counts those already
/// spent; `lambda` carries over between runs.
fn levenberg_marquardt(
    layout: &Layout<'_>,
    v: &mut [f64],
    weights: &[f64],
    lambda: &mut f64,
    tolerance: f64,
    done: usize,
) -> Result<usize, Effects3Error> {
    let options = lm::Options {
        max_iterations: MAX_ITERATIONS,
        tolerance,
        weighting: Weighting::PositiveOnly,
        require_curvature: true,
        damping_floor: None,
        step_tolerance: None,
        positive: None,
        lower_damping_on_stop: true,
        trials_by_equations: false,
    };
    lm::solve(layout, v, weights, lambda, done, &options)
        .map(|solved| solved.iterations)
        .map_err(|failure| match failure {
            lm::Failure::Undetermined { jtj } => Effects3Error::Undetermined {
                parameter: (0..v.len())
                    .find(|&j| !(jtj[(j, j)] > 0.0))
                    .map(|j| layout.names[j].clone())
                    .unwrap_or_default(),
            },
            lm::Failure::NoConvergence { iterations } => Effects3Error::NoConvergence {
                iterations,
                what: "Levenberg–Marquardt",
            },
        })
}

fn huber_weight(e: f64, scale: f64) -> f64 {
    let limit = HUBER_TUNING * scale;
    if !(scale > 0.0) || e.abs() <= limit {
        1.0
    } else {
        limit / e.abs()
    }
}

/// Fits the 3-D model `base` plus the effects `extras` to a recording.
///
/// `extras` may hold the whole model's list (as `fit --effects` gives it):
/// `scale` and `cross-axis` raise the base to `offset+scale` or the full W
/// ([`base_of`]), `offset` is always in; `drift`, `covariate:<column>`,
/// `cubic` and `outliers` are the effects proper; `cubic-centred` is
/// refused ([`Effects3Error::NotIn3D`]).
pub fn fit_effects(
    data: &Dataset3,
    base: Ellipsoid3Model,
    extras: &[Effect],
) -> Result<Ellipsoid3EffectsFit, Effects3Error> {
    let model = base_of(base, extras);
    let start = ellipsoid::fit(&data.points, model)?;
    let n = data.len();
    // The same normalisation as the base fit: mean and rms spread.
    let (mean, spread) = ellipsoid::mean_and_spread(&data.points)?;
    let layout = Layout::new(data, model, extras, mean, spread)?;
    let unknowns = layout.unknowns();
    enough_samples(model, n, unknowns)?;
    let mut v = start_vector(&start, model, mean, spread, unknowns);

    let mut iterations = 0;
    let mut lambda = 1e-3;
    let flagged = if extras.contains(&Effect::Outliers) {
        robust_outliers(&layout, &mut v, &mut lambda, &mut iterations)?
    } else {
        Vec::new()
    };
    // The parameters from the inliers alone.
    let mut weights = vec![1.0; n];
    for &i in &flagged {
        weights[i] = 0.0;
    }
    iterations += levenberg_marquardt(
        &layout,
        &mut v,
        &weights,
        &mut lambda,
        RELATIVE_COST_TOLERANCE,
        iterations,
    )?;

    let used = n - flagged.len();
    enough_samples(model, used, unknowns)?;
    let (out, rss, cov_out) = reported(&layout, &v, &weights, used)?;
    let matrix = ellipsoid::reported_matrix(&out);
    let r = out[12];
    let params = named_params(&layout, &out, &cov_out)?;

    // Everything per sample, at the final parameters.
    let a = layout.a_of(&v);
    let mut residuals = Vec::with_capacity(n);
    let mut calibrated = Vec::with_capacity(n);
    let mut directions = Vec::with_capacity(used);
    for (i, weight) in weights.iter().enumerate() {
        let (_, av) = layout.point(&v, &a, i);
        residuals.push(av.norm() - 1.0);
        calibrated.push([av[0] * r, av[1] * r, av[2] * r]);
        if *weight > 0.0 {
            directions.push([av[0], av[1], av[2]]);
        }
    }
    let mut effects = base_effects(model);
    for e in extras {
        if !effects.contains(e) {
            effects.push(e.clone());
        }
    }
    effects.sort();
    let reference = reference(data, extras, &effects, &layout);
    Ok(Ellipsoid3EffectsFit {
        model,
        effects,
        offset: [out[0], out[1], out[2]],
        matrix,
        r,
        se: ellipsoid::base_se(&cov_out),
        params,
        rms: (rss / used as f64).sqrt(),
        rss,
        n,
        unknowns,
        residuals,
        calibrated,
        flagged,
        iterations,
        coverage: sphere::coverage(directions),
        reference,
    })
}

/// One sample more than unknowns, so the residual has a variance.
fn enough_samples(
    model: Ellipsoid3Model,
    found: usize,
    unknowns: usize,
) -> Result<(), Effects3Error> {
    if found < unknowns + 1 {
        return Err(Ellipsoid3Error::TooFewSamples {
            model,
            found,
            unknowns,
            needed: unknowns + 1,
        }
        .into());
    }
    Ok(())
}

/// The start: the base fit in the scaled frame, every effect at zero.
fn start_vector(
    start: &Ellipsoid3Fit,
    model: Ellipsoid3Model,
    mean: Vector3<f64>,
    spread: f64,
    unknowns: usize,
) -> Vec<f64> {
    let w = Matrix3::from_fn(|i, j| start.matrix[i][j]);
    let a = w / start.r * spread;
    let o = (Vector3::from(start.offset) - mean) / spread;
    let mut v = ellipsoid::pack(model, &Ellipsoid { o, a });
    v.resize(unknowns, 0.0);
    v
}

/// IRLS with Huber weights from `v`, in place, until the weights settle
/// (`iterations` and `lambda` carry over); returns the samples beyond
/// [`FLAG_THRESHOLD_SD`] robust SDs of the last round, ascending.
fn robust_outliers(
    layout: &Layout<'_>,
    v: &mut [f64],
    lambda: &mut f64,
    iterations: &mut usize,
) -> Result<Vec<usize>, Effects3Error> {
    let n = layout.raw.len();
    let mut weights = vec![1.0; n];
    let mut residuals = vec![0.0; n];
    let mut settled = false;
    let mut scale = 0.0;
    for round in 0.. {
        *iterations += levenberg_marquardt(
            layout,
            v,
            &weights,
            lambda,
            LOOSE_COST_TOLERANCE,
            *iterations,
        )?;
        let a = layout.a_of(v);
        for (i, e) in residuals.iter_mut().enumerate() {
            *e = layout.evaluate(v, &a, i, None);
        }
        scale = robust_sd(&residuals);
        let largest = lm::reweight(&mut weights, &residuals, |e| huber_weight(e, scale));
        if largest < 1e-5 {
            settled = true;
        }
        if settled {
            break;
        }
        if round + 1 >= MAX_IRLS_ROUNDS {
            return Err(Effects3Error::NoConvergence {
                iterations: *iterations,
                what: "the robust weights did not settle",
            });
        }
    }
    if !(scale > 0.0) {
        return Ok(Vec::new());
    }
    Ok(residuals
        .iter()
        .enumerate()
        .filter(|(_, e)| e.abs() > FLAG_THRESHOLD_SD * scale)
        .map(|(i, _)| i)
        .collect())
}

/// The reported parameters at `v` ([`Layout::report`]), Σ e² over the
/// samples used, and the covariance σ²(JᵀJ)⁻¹ propagated to the reported
/// parameters.
fn reported(
    layout: &Layout<'_>,
    v: &[f64],
    weights: &[f64],
    used: usize,
) -> Result<(Vec<f64>, f64, DMatrix<f64>), Effects3Error> {
    let unknowns = layout.unknowns();
    let lm::NormalEquations { jtj, cost: rss, .. } =
        lm::normal_equations(layout, v, weights, Weighting::PositiveOnly);
    let cov = jtj.clone().cholesky().map(|c| c.inverse()).ok_or_else(|| {
        let largest = (0..unknowns).map(|j| jtj[(j, j)]).fold(0.0, f64::max);
        let j = (0..unknowns)
            .min_by(|&p, &q| jtj[(p, p)].total_cmp(&jtj[(q, q)]))
            .filter(|&j| jtj[(j, j)] < largest)
            .unwrap_or(unknowns - 1);
        Effects3Error::Undetermined {
            parameter: layout.names[j].clone(),
        }
    })?;
    let sigma2 = rss / (used - unknowns) as f64;
    let cov = cov * sigma2;
    let out = layout.report(v).ok_or(Ellipsoid3Error::Degenerate)?;
    if out.iter().any(|x| !x.is_finite()) {
        return Err(Ellipsoid3Error::Degenerate.into());
    }
    // Propagate to the reported parameters by central differences.
    let cov_out = ellipsoid::propagate(v, cov, out.len(), |v| layout.report(v));
    Ok((out, rss, cov_out))
}

/// Parameters by name: o, W's free entries, r, the extras; refused when a
/// value or a standard error is not finite.
fn named_params(
    layout: &Layout<'_>,
    out: &[f64],
    cov_out: &DMatrix<f64>,
) -> Result<Vec<Param>, Effects3Error> {
    let se_of = |i: usize| ellipsoid::reported_se(cov_out, i);
    let mut params: Vec<Param> = (0..3)
        .map(|j| Param {
            name: format!("o_{}", AXES[j]),
            value: out[j],
            se: se_of(j),
        })
        .collect();
    let entries: &[(usize, usize)] = match layout.model {
        Ellipsoid3Model::Offset => &[],
        Ellipsoid3Model::OffsetScale => &[(0, 0), (1, 1), (2, 2)],
        Ellipsoid3Model::Full => &[(0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1)],
    };
    for &(i, j) in entries {
        params.push(Param {
            name: format!("W_{}{}", AXES[i], AXES[j]),
            value: out[3 + 3 * i + j],
            se: se_of(3 + 3 * i + j),
        });
    }
    params.push(Param {
        name: "r".into(),
        value: out[12],
        se: se_of(12),
    });
    let base_k = layout.model.unknowns();
    for j in base_k..layout.unknowns() {
        params.push(Param {
            name: layout.names[j].clone(),
            value: out[13 + j - base_k] + 0.0,
            se: se_of(13 + j - base_k),
        });
    }
    if let Some(parameter) = first_not_finite(&params) {
        return Err(Effects3Error::Undetermined { parameter });
    }
    Ok(params)
}

/// Where the fit's moving offsets and cubic are referred to: the fitted
/// samples' mean time and covariate means, and the cubic's full scale.
fn reference(
    data: &Dataset3,
    extras: &[Effect],
    effects: &[Effect],
    layout: &Layout<'_>,
) -> Effects3Reference {
    let mean_of = |values: &[f64]| values.iter().sum::<f64>() / values.len().max(1) as f64;
    Effects3Reference {
        t_mean: extras
            .contains(&Effect::Drift)
            .then(|| data.t.as_deref().map(mean_of))
            .flatten(),
        covariate_means: effects
            .iter()
            .filter_map(|e| match e {
                Effect::Covariate(column) => data
                    .covariate(column)
                    .map(|c| (column.clone(), mean_of(&c.values))),
                _ => None,
            })
            .collect(),
        cubic_scale: layout.cubic.map(|(_, inv_s2)| inv_s2.sqrt().recip()),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::needless_range_loop)] // indices pair fit, truth and se
    use super::*;
    use crate::model::fixtures::tumbling;
    use crate::sample::Covariate;
    use crate::sim3::SimSensor3;

    const SOFT_IRON: [[f64; 3]; 3] = [[1.2, 0.15, -0.1], [0.15, 0.85, 0.2], [-0.1, 0.2, 1.05]];
    const NOISE: f64 = 0.005;
    const R: f64 = 0.5;

    fn sensor(n: usize, seed: u64) -> SimSensor3 {
        tumbling(SOFT_IRON, [0.3, -0.2, 0.45], R, 0.0, n, seed)
    }

    /// What a test adds to a clean tumble.
    #[derive(Clone, Copy)]
    enum Added {
        Nothing,
        /// Offset moving by this much per second (raw units), 100 Hz.
        Drift([f64; 3]),
        /// Offset following a temperature by this much per degree.
        Covariate([f64; 3]),
        /// Per-axis cubic k (fraction at full scale).
        Cubic([f64; 3]),
        /// This many spikes of 0.3·r.
        Spikes(usize),
    }

    fn gaussian(n: usize, seed: u64) -> Vec<f64> {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n).map(|_| StandardNormal.sample(&mut rng)).collect()
    }

    /// A tumble with `added`, noise NOISE per axis, times at 100 Hz and a
    /// temperature that warms and cools twice (independent of direction).
    fn recording(added: Added, n: usize, seed: u64) -> Dataset3 {
        let linear = sensor(n, seed).simulate().unwrap();
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.01).collect();
        let span = t[n - 1];
        let temp: Vec<f64> = t
            .iter()
            .map(|&s| 25.0 + 8.0 * (std::f64::consts::TAU * 2.0 * s / span).sin() + 0.3 * s)
            .collect();
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let (t_mean, temp_mean) = (mean(&t), mean(&temp));
        let mut points: Vec<[f64; 3]> = linear.clone();
        match added {
            Added::Nothing | Added::Spikes(_) => {}
            Added::Drift(rate) => {
                for (p, &s) in points.iter_mut().zip(&t) {
                    for j in 0..3 {
                        p[j] += rate[j] * (s - t_mean);
                    }
                }
            }
            Added::Covariate(g) => {
                for (p, &c) in points.iter_mut().zip(&temp) {
                    for j in 0..3 {
                        p[j] += g[j] * (c - temp_mean);
                    }
                }
            }
            Added::Cubic(k) => {
                // The reading y with y + k·y³/S² = linear, S = max |y|
                // (a fixed point: S depends on y weakly).
                let mut s = linear.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
                for _ in 0..20 {
                    for (p, l) in points.iter_mut().zip(&linear) {
                        for j in 0..3 {
                            let mut y = l[j];
                            for _ in 0..50 {
                                let f = y + k[j] * y.powi(3) / (s * s) - l[j];
                                y -= f / (1.0 + 3.0 * k[j] * y * y / (s * s));
                            }
                            p[j] = y;
                        }
                    }
                    s = points.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
                }
            }
        }
        let noise = gaussian(3 * n, seed ^ 0x5eed);
        for (i, p) in points.iter_mut().enumerate() {
            for j in 0..3 {
                p[j] += NOISE * noise[3 * i + j];
            }
        }
        if let Added::Spikes(count) = added {
            // Along the field (a magnitude fit sees only that part): the
            // reading moved by 30 % of r out or in from the offset.
            let o = sensor(n, seed).offset;
            let u = gaussian(count, seed ^ 0xbad);
            for k in 0..count {
                let i = (k * 7919 + seed as usize * 31) % n;
                let factor = 1.0 + 0.3 * u[k].signum();
                for j in 0..3 {
                    points[i][j] = o[j] + (points[i][j] - o[j]) * factor;
                }
            }
        }
        Dataset3 {
            x_name: "x".into(),
            y_name: "y".into(),
            z_name: "z".into(),
            t: Some(t),
            points,
            covariates: vec![Covariate {
                name: "temp".into(),
                values: temp,
            }],
        }
    }

    /// Over `seeds` recordings, the share in which each named parameter
    /// lies within 3 reported SE of its truth; also the worst ratio of the
    /// rms with the effect to the noise's, and the best without it.
    /// `with`: the largest rms with the effect, `without`: the smallest rms
    /// without it, both over the noise's rms.
    fn check(
        added: Added,
        effect: Effect,
        truth: &[(&str, f64)],
        seeds: u64,
        with: f64,
        without: f64,
    ) {
        let mut hits = vec![0usize; truth.len()];
        let mut worst_with = 0.0f64;
        let mut best_without = f64::INFINITY;
        for seed in 0..seeds {
            let data = recording(added, 600, 500 + seed);
            // The noise's rms: the right model on the same tumble with
            // nothing added.
            let clean = recording(Added::Nothing, 600, 500 + seed);
            let noise_rms = ellipsoid::fit(&clean.points, Ellipsoid3Model::Full)
                .unwrap()
                .rms;
            let sim = sensor(600, 500 + seed);
            let (o, w, r) = sim.truth();
            let fit =
                fit_effects(&data, Ellipsoid3Model::Full, std::slice::from_ref(&effect)).unwrap();
            let base = ellipsoid::fit(&data.points, Ellipsoid3Model::Full).unwrap();
            worst_with = worst_with.max(fit.rms / noise_rms);
            best_without = best_without.min(base.rms / noise_rms);
            let mut all: Vec<(String, f64)> =
                truth.iter().map(|(n, v)| (n.to_string(), *v)).collect();
            for j in 0..3 {
                all.push((format!("o_{}", AXES[j]), o[j]));
            }
            for (i, j) in [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)] {
                all.push((format!("W_{}{}", AXES[i.min(j)], AXES[i.max(j)]), w[i][j]));
            }
            all.push(("r".into(), r));
            if seed == 0 {
                hits.resize(all.len(), 0);
            }
            for (k, (name, value)) in all.iter().enumerate() {
                let p = fit.param(name).unwrap_or_else(|| panic!("{name}: {fit:?}"));
                if (p.value - value).abs() <= 3.0 * p.se {
                    hits[k] += 1;
                }
            }
            if let Added::Spikes(count) = added {
                assert!(fit.flagged.len() >= count * 9 / 10, "{:?}", fit.flagged);
                assert!(fit.flagged.len() <= count + 3, "{:?}", fit.flagged);
            }
        }
        println!(
            "{effect}: hits {hits:?} of {seeds}; rms/noise with ≤ {worst_with:.3}, without ≥ {best_without:.3}"
        );
        for (k, h) in hits.iter().enumerate() {
            assert!(
                *h as f64 >= 0.95 * seeds as f64,
                "{effect}: parameter {k} within 3 SE in only {h} of {seeds}"
            );
        }
        // The radial noise is NOISE per axis: rms/noise ≈ 1 with the effect.
        assert!(
            worst_with < with,
            "{effect}: rms {worst_with}× the noise with it"
        );
        if !matches!(added, Added::Nothing) {
            assert!(
                best_without > without,
                "{effect}: rms only {best_without}× the noise without it"
            );
        }
    }

    #[test]
    fn drift_is_recovered_within_three_standard_errors() {
        let rate = [0.02, -0.015, 0.01];
        check(
            Added::Drift(rate),
            Effect::Drift,
            &[
                ("drift_x", rate[0]),
                ("drift_y", rate[1]),
                ("drift_z", rate[2]),
            ],
            100,
            1.02,
            3.0,
        );
    }

    #[test]
    fn a_covariate_is_recovered_within_three_standard_errors() {
        let g = [0.006, 0.004, -0.005];
        check(
            Added::Covariate(g),
            Effect::Covariate("temp".into()),
            &[("temp_x", g[0]), ("temp_y", g[1]), ("temp_z", g[2])],
            100,
            1.02,
            4.0,
        );
    }

    #[test]
    fn cubic_is_recovered_within_three_standard_errors() {
        let k = [0.08, -0.07, 0.09];
        check(
            Added::Cubic(k),
            Effect::Cubic,
            &[("k_x", k[0]), ("k_y", k[1]), ("k_z", k[2])],
            100,
            // The correction 1 + 3k·y²/S² scales the noise too (up to 1.27×
            // along an axis at full scale).
            1.10,
            1.5,
        );
    }

    #[test]
    fn spikes_are_flagged_and_the_base_comes_from_the_inliers() {
        check(Added::Spikes(12), Effect::Outliers, &[], 100, 1.02, 3.0);
    }

    #[test]
    fn no_effect_leaves_the_base_fit() {
        let data = recording(Added::Nothing, 600, 3);
        let base = ellipsoid::fit(&data.points, Ellipsoid3Model::Full).unwrap();
        let fit = fit_effects(&data, Ellipsoid3Model::Full, &[]).unwrap();
        assert!((fit.rms - base.rms).abs() < 1e-9 * base.rms);
        for j in 0..3 {
            assert!((fit.offset[j] - base.offset[j]).abs() < 1e-7);
        }
        assert!((fit.r - base.r).abs() < 1e-7);
    }

    #[test]
    fn raw_counts_fit_as_gauss_do() {
        let data = recording(Added::Drift([0.02, -0.015, 0.01]), 600, 9);
        let mut counts = data.clone();
        for p in &mut counts.points {
            *p = p.map(|v| v * 1e4 + 3e4);
        }
        // (cubic is about the sensor's zero, so it is not shift-invariant.)
        let effects = [Effect::Drift, Effect::Outliers];
        let a = fit_effects(&data, Ellipsoid3Model::Full, &effects).unwrap();
        let b = fit_effects(&counts, Ellipsoid3Model::Full, &effects).unwrap();
        assert!((a.rms - b.rms).abs() < 1e-6 * a.rms, "{} {}", a.rms, b.rms);
        for j in 0..3 {
            assert!((b.offset[j] - (a.offset[j] * 1e4 + 3e4)).abs() < 1e-5 * 1e4);
            let (da, db) = (
                a.value(&format!("drift_{}", AXES[j])),
                b.value(&format!("drift_{}", AXES[j])),
            );
            let se = a.param(&format!("drift_{}", AXES[j])).unwrap().se;
            assert!((db - da * 1e4).abs() < 1e-3 * se * 1e4, "{da} {db} ± {se}");
        }
        assert!((b.r - a.r * 1e4).abs() < 1e-6 * 1e4);
    }

    #[test]
    fn effects_that_cannot_be_fitted_say_why() {
        let mut data = recording(Added::Nothing, 300, 4);
        assert!(matches!(
            fit_effects(
                &data,
                Ellipsoid3Model::Full,
                &[Effect::Covariate("volts".into())]
            ),
            Err(Effects3Error::MissingCovariate { .. })
        ));
        assert!(matches!(
            fit_effects(&data, Ellipsoid3Model::Full, &[Effect::CubicCentred]),
            Err(Effects3Error::NotIn3D { .. })
        ));
        data.covariates[0].values = vec![20.0; 300];
        assert!(matches!(
            fit_effects(
                &data,
                Ellipsoid3Model::Full,
                &[Effect::Covariate("temp".into())]
            ),
            Err(Effects3Error::Undetermined { .. })
        ));
        data.t = None;
        let err = fit_effects(&data, Ellipsoid3Model::Full, &[Effect::Drift]).unwrap_err();
        assert_eq!(err, Effects3Error::MissingTime);
        assert!(err.to_string().contains("time column"));
    }

    #[test]
    fn scale_and_cross_axis_in_the_list_raise_the_base() {
        assert_eq!(
            base_of(Ellipsoid3Model::Offset, &[Effect::Offset, Effect::Scale]),
            Ellipsoid3Model::OffsetScale
        );
        assert_eq!(
            base_of(
                Ellipsoid3Model::OffsetScale,
                &[Effect::CrossAxis, Effect::Drift]
            ),
            Ellipsoid3Model::Full
        );
        assert_eq!(
            base_of(Ellipsoid3Model::Full, &[Effect::Offset]),
            Ellipsoid3Model::Full
        );
    }

    /// `calibrate` applies the fitted model to samples as the fit did: on
    /// the fitted recording it gives the fit's own calibrated samples, and
    /// on a part of it (as `fit --still` writes every sample of a recording
    /// fitted on its still ones) the same samples again.
    #[test]
    fn calibrate_reproduces_the_fitted_samples() {
        // Every effect that moves the samples in one model (the covariate
        // and cubic fitted near zero still enter each sample).
        let data = recording(Added::Drift([0.02, -0.015, 0.01]), 600, 5);
        let effects = [
            Effect::Drift,
            Effect::Covariate("temp".into()),
            Effect::Cubic,
        ];
        let fit = fit_effects(&data, Ellipsoid3Model::Full, &effects).unwrap();
        assert!(fit.reference.t_mean.is_some());
        assert_eq!(fit.reference.covariate_means.len(), 1);
        assert!(fit.reference.cubic_scale.is_some());
        let all = fit.calibrate(&data).unwrap();
        let worst = all
            .iter()
            .zip(&fit.calibrated)
            .flat_map(|(a, b)| (0..3).map(move |j| (a[j] - b[j]).abs()))
            .fold(0.0f64, f64::max);
        assert!(worst < 1e-9 * fit.r, "worst {worst}");
        // The last 100 samples alone: the same values.
        let tail = Dataset3 {
            t: data.t.as_ref().map(|t| t[500..].to_vec()),
            points: data.points[500..].to_vec(),
            covariates: data
                .covariates
                .iter()
                .map(|c| Covariate {
                    name: c.name.clone(),
                    values: c.values[500..].to_vec(),
                })
                .collect(),
            ..data.clone()
        };
        let part = fit.calibrate(&tail).unwrap();
        for (a, b) in part.iter().zip(&all[500..]) {
            for j in 0..3 {
                assert!((a[j] - b[j]).abs() < 1e-9 * fit.r);
            }
        }
        // Without its time column, the drift cannot be removed.
        let no_time = Dataset3 {
            t: None,
            ..tail.clone()
        };
        assert_eq!(fit.calibrate(&no_time), Err(Effects3Error::MissingTime));
    }
}
