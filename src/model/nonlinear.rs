// PLACEHOLDER: replaced by the real nonlinear.rs at merge
//! Placeholder for the nonlinear fit of the paper's model plus effects. It
//! implements the agreed API for the paper's effects only, through
//! [`paper::closed_form`], so that code written against the API compiles and
//! runs; every other effect gives [`FitError::Degenerate`].

use super::FitError;
use super::effects::Effect;
use super::paper::{self, PaperCalibration};
use crate::sample::Dataset;

/// One fitted parameter with its standard error.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Param {
    pub name: String,
    pub value: f64,
    pub se: f64,
}

/// A fit of the paper's model plus effects.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelFit {
    pub effects: Vec<Effect>,
    pub params: Vec<Param>,
    pub rms: f64,
    pub n: usize,
    pub unknowns: usize,
    /// e_i = |s_i|/r - 1 for every sample, input order.
    pub residuals: Vec<f64>,
    /// atan2(s_y, s_x) radians, every sample.
    pub headings: Vec<f64>,
    pub calibrated: Vec<(f64, f64)>,
    /// Outlier indices (outliers effect only).
    pub flagged: Vec<usize>,
    pub weights: Vec<f64>,
    pub iterations: usize,
    /// Σ e² over the samples used.
    pub rss: f64,
}

impl ModelFit {
    pub fn param(&self, name: &str) -> Option<&Param> {
        self.params.iter().find(|p| p.name == name)
    }

    pub fn paper(&self) -> PaperCalibration {
        let get = |name: &str, default: f64| self.param(name).map_or(default, |p| p.value);
        PaperCalibration {
            a: get("a", 1.0),
            b: get("b", 0.0),
            d: get("d", 0.0),
            r: get("r", 1.0),
        }
    }
}

/// Fits the model (placeholder: the paper's effects only).
pub fn fit_model(data: &Dataset, effects: &[Effect]) -> Result<ModelFit, FitError> {
    if effects.iter().any(|e| !e.is_paper()) {
        return Err(FitError::Degenerate);
    }
    let cal = paper::closed_form(&data.x, &data.y)?.to_calibration()?;
    let calibrated: Vec<(f64, f64)> = data
        .x
        .iter()
        .zip(&data.y)
        .map(|(&x, &y)| cal.apply(x, y))
        .collect();
    let residuals: Vec<f64> = calibrated
        .iter()
        .map(|&(sx, sy)| sx.hypot(sy) / cal.r - 1.0)
        .collect();
    let headings = calibrated.iter().map(|&(sx, sy)| sy.atan2(sx)).collect();
    let rss: f64 = residuals.iter().map(|e| e * e).sum();
    let n = residuals.len();
    let param = |name: &str, value: f64| Param {
        name: name.to_string(),
        value,
        se: 0.0,
    };
    Ok(ModelFit {
        effects: effects.to_vec(),
        params: vec![
            param("a", cal.a),
            param("b", cal.b),
            param("d", cal.d),
            param("r", cal.r),
        ],
        rms: if n > 0 { (rss / n as f64).sqrt() } else { 0.0 },
        n,
        unknowns: paper::UNKNOWNS,
        residuals,
        headings,
        calibrated,
        flagged: Vec::new(),
        weights: vec![1.0; n],
        iterations: 1,
        rss,
    })
}
