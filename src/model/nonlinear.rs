//! The general model: the paper's model plus any effects of the catalogue,
//! fitted by Levenberg-Marquardt ([`super::lm`]) from the paper's closed
//! form.
//!
//! Per sample i (raw x, y; time t; covariates c_k):
//! - moving offsets: `x1 = x - drift_x*(t - mean t) - Σ g_xk*(c_k - mean c_k)`,
//!   the same for y, centred so that b and d stay the mean offsets;
//! - odd non-linearity about the sensor's zero: `x2 = x1 + k_x*x1^3/S^2`,
//!   with `S` = [`cubic_scale`] (a fixed scale of the data, so k_x is a
//!   fraction at full scale); and about the turn's centre (`cubic-centred`):
//!   `+ kc*(x1 - c_x)^3/S_x^2` (and `kc*(y1 - c_y)^3/S_y^2`), with the
//!   centre `c_x` and radius `S_x` of the turn in raw units ([`TurnFrame`])
//!   fixed at the paper's closed form, so kc is a fraction at the turn's
//!   amplitude. One kc for both axes: over a turn, `u^3` of an axis's
//!   deviation `u = S cos θ` is `S^3 (3 cos θ + cos 3θ)/4`, so a cubic of
//!   its own per axis adds to |s| a 2nd harmonic in `kc_x - kc_y` that a
//!   change of the gain ratio `a` makes too, and only the 4th harmonic in
//!   `kc_x + kc_y` is the cubic's own: a magnitude fit cannot pin the
//!   difference (it wanders to tens of percent on noisy turns), so the model
//!   keeps the part the data determine;
//! - the paper's linear part plus cross-axis: `s_x = a*x2 + b + c*(y2 + d)`,
//!   `s_y = y2 + d`;
//! - residual `e = |s|/r - 1`, the magnitude error as a fraction of the field.
//!
//! `outliers` adds no unknowns: it turns the fit robust (IRLS with Huber
//! weights) and flags samples far outside the robust spread.

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use super::FitError;
use super::effects::Effect;
use super::fit::DEFAULT_MIN_COVERAGE_DEG;
use super::heading::{circle_centre, coverage};
use super::lm::{self, LeastSquares, Weighting};
use super::paper::{PaperCalibration, closed_form};
use crate::sample::{Covariate, Dataset};

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
/// `cubic` and `cubic-centred` in one model are the same term when the
/// turn is centred on the sensor's zero: their columns then differ only by
/// the even term `3 c x^2 / S^2` of the centre c. When an axis's centre is
/// within this many of its standard errors of zero on both axes (the usual
/// 3-sigma test of "different from zero"), the data cannot tell the two
/// apart, and the fit says so instead of returning two huge opposite values.
pub const SAME_CENTRE_SES: f64 = 3.0;

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
    /// The residuals of the samples the fit used (those it set aside left
    /// out), in input order: the series whose correlation in time widens
    /// its standard errors.
    pub fn used_residuals(&self) -> Vec<f64> {
        self.residuals
            .iter()
            .enumerate()
            .filter(|(i, _)| self.flagged.binary_search(i).is_err())
            .map(|(_, &e)| e)
            .collect()
    }

    /// The parameter of that name, if the model has it.
    pub fn param(&self, name: &str) -> Option<&Param> {
        self.params.iter().find(|p| p.name == name)
    }

    /// The value of a parameter, 0 when the model lacks it.
    pub fn value(&self, name: &str) -> f64 {
        self.param(name).map_or(0.0, |p| p.value)
    }

    /// The centred cubic per axis, [kc_x, kc_y]: the same `kc` on both
    /// unless a gyro split it ([`super::centred_split`]); 0 without it.
    pub fn kc(&self) -> [f64; 2] {
        match (self.param(KC_AXES[0]), self.param(KC_AXES[1])) {
            (Some(x), Some(y)) => [x.value, y.value],
            _ => [self.value("kc"); 2],
        }
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

/// The fixed frame of the `cubic-centred` term: the turn's centre and its
/// radius per axis, in raw units, from the paper's closed form (the model's
/// starting point): `centre = (-b/a, -d)`, `radius = (r/a, r)`.
///
/// Held fixed during the fit, as [`cubic_scale`] is for `cubic`. A free
/// centre would add two unknowns whose columns, `-3 kc (x - c)^2 / S^2`,
/// vanish when kc does: on a sensor without the effect they would be
/// undetermined. Fixing it biases nothing measurable: an odd cubic about
/// the centre keeps the turn symmetric about that centre, so the closed
/// form finds it to within its noise, and a centre off by `dc` leaves only
/// an even term `3 kc dc / S` of the field, far below the noise for `dc`
/// of the order of noise / sqrt(n) (the linear and constant parts of the
/// expansion of `(x - c - dc)^3` go into the gain and offset).
/// tests/nonlinear.rs checks that kc is recovered within its standard error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct TurnFrame {
    /// The turn's centre (x, y), raw units.
    pub centre: [f64; 2],
    /// The turn's radius along x and along y, raw units.
    pub radius: [f64; 2],
}

impl TurnFrame {
    /// The frame of the paper's calibration `s_x = a x + b, s_y = y + d, |s| = r`.
    pub fn of(paper: &PaperCalibration) -> Self {
        TurnFrame {
            centre: [-paper.b / paper.a, -paper.d],
            radius: [paper.r / paper.a, paper.r],
        }
    }
}

/// The frame the `cubic-centred` term of a fit of `data` uses (the fit's
/// starting point): what the daemon stores to correct live readings.
pub fn turn_frame(data: &Dataset) -> Result<TurnFrame, FitError> {
    starting_point(data).map(|start| TurnFrame::of(&start))
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
    /// Index of kc (one for both axes, or their mean with a split).
    centred: Option<usize>,
    /// kc_x − kc_y, held fixed: x's cubic is kc + split/2, y's kc − split/2
    /// (0 unless a gyro pins it, [`super::centred_split`]).
    split: f64,
    /// The turn's centre, and 1/S_x^2, 1/S_y^2, of the centred cubic (set
    /// from the starting point by [`Layout::set_frame`]).
    centre: [f64; 2],
    inv_radius_sq: [f64; 2],
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
                        available: covariate_names(&data.covariates),
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
        let centred = if effects.contains(&Effect::CubicCentred) {
            Some(push("kc".into()))
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
            centred,
            split: 0.0,
            centre: [0.0; 2],
            inv_radius_sq: [0.0; 2],
            names,
        })
    }

    /// Fixes the centred cubic's frame.
    fn set_frame(&mut self, frame: &TurnFrame) {
        self.centre = frame.centre;
        self.inv_radius_sq = frame
            .radius
            .map(|s| if s > 0.0 { 1.0 / (s * s) } else { 0.0 });
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
        // Deviations from the turn's centre, scaled by its radius.
        let (mut vx, mut vy) = (0.0, 0.0);
        if let Some(k) = self.centred {
            vx = x1 - self.centre[0];
            vy = y1 - self.centre[1];
            let (kx, ky) = (p[k] + 0.5 * self.split, p[k] - 0.5 * self.split);
            x2 += kx * vx * vx * vx * self.inv_radius_sq[0];
            y2 += ky * vy * vy * vy * self.inv_radius_sq[1];
            dx2 += 3.0 * kx * vx * vx * self.inv_radius_sq[0];
            dy2 += 3.0 * ky * vy * vy * self.inv_radius_sq[1];
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
            if let Some(k) = self.centred {
                row[k] = ux2 * vx * vx * vx * self.inv_radius_sq[0]
                    + uy2 * vy * vy * vy * self.inv_radius_sq[1];
            }
        }
        (sx, sy, e)
    }
}

/// Applies the stored parameters of the model `effects` to a recording:
/// `(s_x, s_y, e)` for every sample. Drift and covariate terms are taken
/// about the recording's own mean time and mean covariate value (as the fit
/// takes them), so the stored `b` and `d` are the offsets at those means.
/// `cubic_scale`: the full scale S the stored `k` refers to (the fitted
/// recording's); `None` takes this recording's. `frame`: the turn's frame
/// the stored `kc` refers to; `None` takes this recording's, as the fit
/// does ([`turn_frame`]).
pub fn apply_model(
    data: &Dataset,
    effects: &[Effect],
    params: &[Param],
    cubic_scale: Option<f64>,
    frame: Option<&TurnFrame>,
) -> Result<Vec<(f64, f64, f64)>, FitError> {
    let mut layout = Layout::new(data, effects)?;
    if let Some(scale) = cubic_scale.filter(|s| *s > 0.0 && s.is_finite()) {
        layout.inv_scale_sq = 1.0 / (scale * scale);
    }
    let value = |name: &str| {
        params
            .iter()
            .find(|q| q.name == name)
            .map(|q| q.value)
            .filter(|v| v.is_finite())
    };
    // A centred cubic pinned per axis by a gyro is stored as kc_x and kc_y.
    let per_axis = value(KC_AXES[0]).zip(value(KC_AXES[1]));
    if layout.centred.is_some() {
        if let Some((kx, ky)) = per_axis {
            layout.split = kx - ky;
        }
        // Without the stored frame, this recording's own: the closed form of
        // the same sensor's turn finds the same frame within its noise,
        // where the fitted a and r have taken in the cubic's linear part
        // (3 kc / 4 of the radius).
        let own = || {
            turn_frame(data).unwrap_or_else(|_| {
                let [a, b, d, r] = ["a", "b", "d", "r"].map(|name| value(name).unwrap_or(f64::NAN));
                TurnFrame::of(&PaperCalibration { a, b, d, r })
            })
        };
        layout.set_frame(&frame.copied().unwrap_or_else(own));
    }
    let p: Vec<f64> = layout
        .names
        .iter()
        .map(|name| {
            let per_axis = per_axis.filter(|_| name == "kc");
            per_axis
                .map(|(kx, ky)| 0.5 * (kx + ky))
                .or_else(|| value(name))
                .ok_or_else(|| FitError::MissingParameter {
                    parameter: name.clone(),
                })
        })
        .collect::<Result<_, _>>()?;
    Ok((0..data.len())
        .map(|i| layout.evaluate(&p, i, None))
        .collect())
}

/// The 2-D model as a least-squares problem: e of every sample.
impl LeastSquares for Layout<'_> {
    type Shared = ();

    fn shared(&self, _: &[f64]) {}

    #[inline]
    fn residual(&self, _: &(), p: &[f64], i: usize, row: Option<&mut [f64]>) -> f64 {
        self.evaluate(p, i, row).2
    }
}

/// Levenberg–Marquardt as the 2-D fit runs it: every sample weighted, r
/// kept positive, a stop on a negligible step as well as on a negligible
/// gain, and the step that stops leaves the damping where it was.
fn lm_options(tolerance: f64) -> lm::Options {
    lm::Options {
        max_iterations: MAX_ITERATIONS,
        tolerance,
        weighting: Weighting::EverySample,
        require_curvature: true,
        damping_floor: None,
        step_tolerance: Some(1e-12),
        positive: Some(3),
        lower_damping_on_stop: false,
        trials_by_equations: false,
    }
}

/// The names of a centred cubic pinned per axis ([`super::centred_split`]).
pub const KC_AXES: [&str; 2] = ["kc_x", "kc_y"];

/// Fits the model made of `effects` (the paper's plus any others) to the
/// recording, by Levenberg-Marquardt started from the paper's closed form.
pub fn fit_model(data: &Dataset, effects: &[Effect]) -> Result<ModelFit, FitError> {
    fit_model_split(data, effects, 0.0)
}

/// [`fit_model`] with the centred cubic's per-axis difference kc_x − kc_y
/// held at `split` (ignored without `cubic-centred`); the fit's `kc` is
/// then the mean of the two.
pub(crate) fn fit_model_split(
    data: &Dataset,
    effects: &[Effect],
    split: f64,
) -> Result<ModelFit, FitError> {
    let mut layout = Layout::new(data, effects)?;
    layout.split = split;
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
    layout.set_frame(&TurnFrame::of(&start));
    let mut p = vec![0.0; unknowns];
    p[..4].copy_from_slice(&[start.a, start.b, start.d, start.r]);

    let robust = effects.contains(&Effect::Outliers);
    let Weighted {
        weights,
        iterations,
        scale,
    } = fit_weighted(&layout, &mut p, robust, data, &start)?;

    // Everything the caller sees, at the final parameters.
    let mut residuals = Vec::with_capacity(n);
    let mut calibrated = Vec::with_capacity(n);
    let mut headings = Vec::with_capacity(n);
    for i in 0..n {
        let (sx, sy, err) = layout.evaluate(&p, i, None);
        residuals.push(err);
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
    let rss = rss_without(&residuals, &flagged);
    let used = n - flagged.len();
    let rms = (rss / used.max(1) as f64).sqrt();

    let params = standard_errors(&layout, &p, &weights)?;
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

/// Where the (robust) Levenberg-Marquardt ended, besides the parameters.
struct Weighted {
    /// Final IRLS weights (all 1.0 without outliers).
    weights: Vec<f64>,
    /// Levenberg-Marquardt iterations, over all IRLS rounds.
    iterations: usize,
    /// The robust SD of the last round's residuals (0 without outliers).
    scale: f64,
}

/// Levenberg-Marquardt from `p`, in place: once, or with `robust` in IRLS
/// rounds with Huber weights until the weights settle, then once more to
/// the last digit. A failure of Levenberg-Marquardt itself is explained
/// ([`explain_failure`]) against the turn of the start.
fn fit_weighted(
    layout: &Layout<'_>,
    p: &mut [f64],
    robust: bool,
    data: &Dataset,
    start: &PaperCalibration,
) -> Result<Weighted, FitError> {
    let n = data.len();
    let mut weights = vec![1.0; n];
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
        iterations += lm::solve(
            layout,
            p,
            &weights,
            &mut lambda,
            iterations,
            &lm_options(tolerance),
        )
        .map(|solved| solved.iterations)
        .map_err(|failure| match failure {
            lm::Failure::Undetermined { jtj } => undetermined(layout, &jtj),
            lm::Failure::NoConvergence { iterations } => FitError::NoConvergence {
                iterations,
                what: "Levenberg-Marquardt did not converge",
            },
        })
        .map_err(|e| explain_failure(e, data, start))?;
        if settled {
            break;
        }
        for (i, e) in residuals.iter_mut().enumerate() {
            *e = layout.evaluate(p, i, None).2;
        }
        scale = robust_sd(&residuals);
        let largest_change = lm::reweight(&mut weights, &residuals, |e| huber_weight(e, scale));
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
    Ok(Weighted {
        weights,
        iterations,
        scale,
    })
}

/// Σ e² over the samples not flagged (`flagged` ascending).
fn rss_without(residuals: &[f64], flagged: &[usize]) -> f64 {
    let mut rss = 0.0;
    let mut next_flagged = flagged.iter().peekable();
    for (i, e) in residuals.iter().enumerate() {
        if next_flagged.peek() == Some(&&i) {
            next_flagged.next();
            continue;
        }
        rss += e * e;
    }
    rss
}

/// The parameters at `p` with their standard errors, from the curvature at
/// the minimum; refused when a parameter is undetermined or not finite.
fn standard_errors(
    layout: &Layout<'_>,
    p: &[f64],
    weights: &[f64],
) -> Result<Vec<Param>, FitError> {
    let n = weights.len();
    let unknowns = layout.unknowns();
    let lm::NormalEquations {
        jtj,
        cost: weighted_cost,
        ..
    } = lm::normal_equations(layout, p, weights, Weighting::EverySample);
    let covariance = jtj
        .clone()
        .cholesky()
        .map(|c| c.inverse())
        .ok_or_else(|| undetermined(layout, &jtj))?;
    let sigma_sq = weighted_cost / (n - unknowns) as f64;
    if let Some(kc) = layout.centred.filter(|_| layout.cubic.is_some()) {
        // The centre's standard errors: x's is b's over a, y's is d's.
        let se = |j: usize| (covariance[(j, j)] * sigma_sq).max(0.0).sqrt();
        let centre_se = [se(1) / p[0].abs(), se(2)];
        // One kc against a k per axis: kc stands apart when the centre is
        // off zero on either axis.
        let apart = layout
            .centre
            .iter()
            .zip(centre_se)
            .any(|(centre, se)| centre.abs() > SAME_CENTRE_SES * se);
        if !apart {
            return Err(FitError::Undetermined {
                parameter: layout.names[kc].clone(),
            });
        }
    }
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

    if let Some(parameter) = first_not_finite(&params) {
        return Err(FitError::NotFinite { parameter });
    }
    Ok(params)
}

/// The names of a recording's covariate columns, for the message of a
/// missing one.
pub(super) fn covariate_names(covariates: &[Covariate]) -> String {
    covariates
        .iter()
        .map(|c| c.name.clone())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The name of the first parameter whose value or standard error is not
/// finite.
pub(super) fn first_not_finite(params: &[Param]) -> Option<String> {
    params
        .iter()
        .find(|q| !q.value.is_finite() || !q.se.is_finite())
        .map(|q| q.name.clone())
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
        let applied = apply_model(&data, &effects, &fit.params, None, None).unwrap();
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
            apply_model(&data, &effects, &missing, None, None),
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

    /// The Jacobian row `evaluate` returns is the derivative of e, checked
    /// against central differences for every unknown of a model with every
    /// term that shapes the reading (both cubics, cross-axis, drift and a
    /// covariate, all non-zero, so each term's chain rule through the others
    /// is exercised), at samples all round the turn.
    #[test]
    fn jacobian_rows_match_central_differences() {
        let data = SimSensor {
            gain_x: 1.3,
            offset_x: 900.0,
            offset_y: -600.0,
            noise: 3.0,
            turns: 2.0,
            effects: crate::sim::SimEffects {
                temp_per_c: Some([2.0, -1.0]),
                ..Default::default()
            },
            ..Default::default()
        }
        .simulate()
        .unwrap();
        let effects = crate::model::effects::parse_list(
            "cross-axis,drift,covariate:temp,cubic,cubic-centred",
        )
        .unwrap();
        let mut layout = Layout::new(&data, &effects).unwrap();
        let start = starting_point(&data).unwrap();
        layout.set_frame(&TurnFrame::of(&start));
        let k = layout.unknowns();
        assert_eq!(k, 4 + 1 + 2 + 2 + 2 + 1);
        let mut p = vec![start.a, start.b, start.d, start.r];
        // c, drift, temp, k, kc: each a few percent, with both signs.
        p.extend([0.03, 0.4, -0.3, 1.5, -2.0, 0.04, -0.02, 0.05]);
        let mut row = vec![0.0; k];
        for i in (0..data.len()).step_by(23) {
            layout.evaluate(&p, i, Some(&mut row));
            for j in 0..k {
                let h = 1e-6 * p[j].abs().max(1e-2);
                let mut up = p.clone();
                up[j] += h;
                let mut down = p.clone();
                down[j] -= h;
                let numeric = (layout.evaluate(&up, i, None).2 - layout.evaluate(&down, i, None).2)
                    / (2.0 * h);
                assert!(
                    (row[j] - numeric).abs() <= 1e-5 * numeric.abs() + 1e-8,
                    "sample {i}, {}: analytic {} vs numeric {numeric}",
                    layout.names[j],
                    row[j]
                );
            }
        }
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
