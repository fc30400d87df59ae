//! Which effect a 3-axis recording supports: the 2-D diagnosis
//! ([`super::diagnose`]) on the 3-D model ([`super::ellipsoid_effects`]).
//!
//! The same rules, constants and wording: start from the paper's model
//! (`offset+scale`, W diagonal, the 3-D form of the 2-D default), fit every
//! candidate effect the model lacks, rank them by BIC (supported ones
//! first), add the best supported one, and repeat until none is supported
//! (at most [`MAX_STEPS`](super::diagnose::MAX_STEPS)); then compare the
//! rms with the noise floor and say whether what remains is noise or where
//! structure remains. The ladder itself is [`super::ladder`]'s, shared with
//! the 2-D diagnosis; this module brings the sphere's own tests.
//!
//! A candidate is supported only when it passes every test of the 2-D
//! judgement, in the same order: it must not fold the sphere (the
//! calibrated directions must not shrink onto a cap), its fitted size must
//! be physical ([`MAX_CUBIC_UNCHECKED`], [`MAX_CROSS_AXIS_SHEAR`],
//! [`MAX_OFFSET_SWING`], [`MAX_GAIN_CHANGE`]), its parameters resolved
//! above their standard errors, ΔBIC below −[`BIC_MARGIN`], the tail gate
//! for `outliers`, material ([`MIN_RMS_DROP`], [`MIN_EXPLAINED_NOISE`]) and
//! out of the structure rather than the noise floor
//! ([`MIN_STRUCTURE_SHARE`](super::diagnose::MIN_STRUCTURE_SHARE)).
//!
//! Physics before statistics: an effect the recording cannot determine is
//! not a candidate at all, and the diagnosis says why (`not_determined`):
//! `drift` needs sample times; `scale` and `cross-axis` need the sphere's
//! coverage to determine the richer W ([`ellipsoid::supports`]); a
//! covariate needs a logged column that varies and is not a copy of the
//! axes.
//!
//! What the 3-D residual is analysed for: in place of the harmonics of
//! heading, the residual's pattern over the sphere of directions (its
//! least-squares fit on the real spherical harmonics of degree 1 and 2, as
//! an rms over the samples); slow wander in time; links to logged columns;
//! heavy tails. The noise floor is the 2-D estimator: 1.4826·MAD of the
//! differences of consecutive residuals in time order, over √2.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::diagnose::EXTREME_SDS;
use super::diagnose::{
    BIC_MARGIN, FOLD_DEG, MAX_CROSS_AXIS_SHEAR, MAX_GAIN_CHANGE, MAX_OFFSET_SWING,
    MIN_EXPLAINED_NOISE, MIN_RMS_DROP,
};
use super::effects::{Effect, MAX_CUBIC_UNCHECKED, model_name};
use super::ellipsoid::{self, Ellipsoid3Error, Ellipsoid3Model};
use super::ellipsoid_effects::{Effects3Error, Ellipsoid3EffectsFit, base_effects, fit_effects};
use super::ladder::{self, Gates, Geometry, Offer, STRUCTURE_SES, percent, range, starting_list};
use super::nonlinear::{MAD_TO_SD, Param};
use super::residuals::{
    COPY_R2, NoiseFloor, ResidualCommon, SetAside, is_time_like, links, median, robust_sd,
};
use super::sphere::{self, SphereCoverage};
use crate::sample::Dataset3;

/// The 2-D fold rule ([`FOLD_DEG`] of a 360° turn) as a share of the
/// sphere: a candidate whose calibrated samples cover this share of the
/// sphere's regions less than the model without it folded the sphere onto
/// a cap of a larger one rather than found an effect.
pub const FOLD_SHARE: f64 = FOLD_DEG / 360.0;

/// The residual of a 3-D fit: what it still holds, and its noise.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Residuals3 {
    /// Rms over the samples of the residual's least-squares part on the
    /// real spherical harmonics of degree 1 (x, y, z: a leftover offset)
    /// and degree 2 (xy, yz, xz, x² − y², 3z² − 1: leftover gains and
    /// coupling), as a fraction of the field; fitted jointly.
    pub direction_degree1: f64,
    pub direction_degree2: f64,
    #[serde(flatten)]
    pub common: ResidualCommon,
}

/// One effect the model could add, as judged on the current model.
pub type Candidate3 = ladder::Candidate<ladder::Nothing>;

pub use super::ladder::NotDetermined;

/// One model of the ladder.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Step3 {
    pub effects: Vec<Effect>,
    pub model: String,
    pub rms: f64,
    pub unknowns: usize,
    pub bic: f64,
    /// Samples flagged as outliers (the `outliers` effect).
    pub flagged: usize,
    pub params: Vec<Param>,
}

/// The whole answer of `fieldcal diagnose` on three axes.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Diagnosis3 {
    pub baseline: Step3,
    /// Why the baseline is not the model asked for (the coverage supports
    /// only a simpler W), if so.
    pub baseline_note: Option<String>,
    pub set_aside: Vec<SetAside>,
    pub baseline_residuals: Residuals3,
    /// Ranked best first: supported ones first, then by ΔBIC.
    pub candidates: Vec<Candidate3>,
    /// Effects of the catalogue the recording cannot determine.
    pub not_determined: Vec<NotDetermined>,
    pub suggested: Option<Effect>,
    /// A supported effect within [`BIC_MARGIN`] of the suggested one.
    pub close_second: Option<Effect>,
    pub ladder: Vec<Step3>,
    pub final_residuals: Residuals3,
    pub noise_floor: NoiseFloor,
    /// The baseline fit's coverage of the sphere.
    pub coverage: SphereCoverage,
    pub verdict: String,
    pub criterion: String,
}

ladder::ladder_types!(Ellipsoid3EffectsFit, Residuals3);

/// The criterion, as the report states it.
pub fn criterion() -> String {
    format!(
        "BIC: n·ln(RSS/n) + p·ln(n), with n all samples and p the unknowns; an effect is supported when it lowers BIC by more than {BIC_MARGIN}. outliers counts one unknown per flagged sample and must also find more samples beyond 4 robust SD than Gaussian noise gives (Poisson tail), or one beyond {EXTREME_SDS} robust SD. It must also matter: lower the rms by {:.0} % or more and explain an amplitude of at least {MIN_EXPLAINED_NOISE} of the noise floor, mostly out of the residual's structure; and be physical: a cubic within {:.0} % at full scale (the datasheets' figure: nothing checks a 3-D fit's heading against a gyro), a cross-axis coupling within tan⁻¹ {MAX_CROSS_AXIS_SHEAR}, a moving offset within {:.0} % of the field over the run, gains moved by less than ×{MAX_GAIN_CHANGE}, the sphere not folded onto a cap, each effect's parameters resolved above their standard errors. An effect the recording cannot determine (drift without times, a richer W without the coverage) is not a candidate",
        MIN_RMS_DROP * 100.0,
        MAX_CUBIC_UNCHECKED * 100.0,
        MAX_OFFSET_SWING * 100.0
    )
}

fn bic(fit: &Ellipsoid3EffectsFit) -> f64 {
    ladder::bic(fit.n, fit.unknowns + fit.flagged.len(), fit.rss)
}

fn step_of(fit: &Ellipsoid3EffectsFit) -> Step3 {
    Step3 {
        effects: fit.effects.clone(),
        model: model_name(&fit.effects),
        rms: fit.rms,
        unknowns: fit.unknowns,
        bic: bic(fit),
        flagged: fit.flagged.len(),
        params: fit.params.clone(),
    }
}

/// R² of `u` on `[1, x, y, z]`; None when `u` is constant.
fn r2_on_axes(u: &[f64], points: &[[f64; 3]]) -> Option<f64> {
    let n = u.len().min(points.len());
    if n < 5 {
        return None;
    }
    let mean = u[..n].iter().sum::<f64>() / n as f64;
    let total: f64 = u[..n].iter().map(|v| (v - mean).powi(2)).sum();
    if !(total > 0.0) || !total.is_finite() {
        return None;
    }
    let design = DMatrix::from_fn(n, 4, |i, j| if j == 0 { 1.0 } else { points[i][j - 1] });
    let target = DVector::from_column_slice(&u[..n]);
    let svd = design.clone().try_svd(true, true, f64::EPSILON, 1000)?;
    let coef = svd.solve(&target, 1e-12).ok()?;
    let left = (&design * coef - target).norm_squared();
    Some((1.0 - left / total).clamp(0.0, 1.0))
}

/// Logged columns not offered as covariates: time-like names (drift's
/// business), constants, and copies of the axes (R² above [`COPY_R2`] on
/// x, y, z, as the 2-D rule).
pub fn set_aside(data: &Dataset3) -> Vec<SetAside> {
    data.covariates
        .iter()
        .filter_map(|c| {
            let reason = if is_time_like(&c.name) {
                "looks like time: the drift effect's business, not a covariate".to_string()
            } else {
                match r2_on_axes(&c.values, &data.points) {
                    None => "constant: nothing to follow".to_string(),
                    Some(r2) if r2 > COPY_R2 => format!(
                        "a linear copy of the axes (R² {r2:.4} on {}, {}, {}): scale and cross-axis's business",
                        data.x_name, data.y_name, data.z_name
                    ),
                    Some(_) => return None,
                }
            };
            Some(SetAside {
                column: c.name.clone(),
                reason,
            })
        })
        .collect()
}

/// Indices of the used (not flagged) samples, in time order.
fn used_in_time_order(data: &Dataset3, fit: &Ellipsoid3EffectsFit) -> Vec<usize> {
    let mut used: Vec<usize> = (0..fit.residuals.len())
        .filter(|i| fit.flagged.binary_search(i).is_err())
        .collect();
    if let Some(t) = data.t.as_deref().filter(|t| t.len() == fit.residuals.len()) {
        used.sort_by(|&a, &b| t[a].total_cmp(&t[b]));
    }
    used
}

/// The 2-D noise floor estimator on residuals in time order.
pub fn noise_floor_of(e: &[f64], timed: bool) -> NoiseFloor {
    let order = if timed { "time" } else { "input" };
    if e.len() < 3 {
        return NoiseFloor {
            rms: 0.0,
            method: "too few samples to estimate the noise".to_string(),
        };
    }
    let abs: Vec<f64> = e.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    let rms = MAD_TO_SD * median(&abs) / std::f64::consts::SQRT_2;
    NoiseFloor {
        rms: if rms.is_finite() { rms } else { 0.0 },
        method: format!(
            "1.4826·MAD of the differences of consecutive residuals in {order} order, divided by √2 ({} differences): slow structure cancels between neighbours, noise does not, and the MAD ignores spikes",
            abs.len()
        ),
    }
}

/// Rms over the samples of the residual's parts of degree 1 and 2 on the
/// sphere of directions `u` (unit vectors).
fn direction_structure(e: &[f64], u: &[[f64; 3]]) -> (f64, f64) {
    let n = e.len().min(u.len());
    let columns = 9;
    if n <= 2 * columns {
        return (0.0, 0.0);
    }
    let basis = |d: &[f64; 3]| -> [f64; 9] {
        let [x, y, z] = *d;
        [
            1.0,
            x,
            y,
            z,
            x * y,
            y * z,
            x * z,
            x * x - y * y,
            3.0 * z * z - 1.0,
        ]
    };
    let design = DMatrix::from_fn(n, columns, |i, j| basis(&u[i])[j]);
    let target = DVector::from_column_slice(&e[..n]);
    let Some(svd) = design.try_svd(true, true, f64::EPSILON, 1000) else {
        return (0.0, 0.0);
    };
    let Ok(coef) = svd.solve(&target, 1e-12) else {
        return (0.0, 0.0);
    };
    let part = |range: std::ops::Range<usize>| {
        let sum: f64 = u[..n]
            .iter()
            .map(|d| {
                let b = basis(d);
                range.clone().map(|j| coef[j] * b[j]).sum::<f64>().powi(2)
            })
            .sum();
        let v = (sum / n as f64).sqrt();
        if v.is_finite() { v } else { 0.0 }
    };
    (part(1..4), part(4..9))
}

/// Every residual statistic of a fit; flagged samples left out.
pub fn analyse(data: &Dataset3, fit: &Ellipsoid3EffectsFit, aside: &[SetAside]) -> Residuals3 {
    let order = used_in_time_order(data, fit);
    let e: Vec<f64> = order.iter().map(|&i| fit.residuals[i]).collect();
    let u: Vec<[f64; 3]> = order
        .iter()
        .map(|&i| {
            let c = fit.calibrated[i];
            let m = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
                .sqrt()
                .max(f64::MIN_POSITIVE);
            c.map(|v| v / m)
        })
        .collect();
    let n_all = fit.residuals.len();
    let column = |values: &[f64]| -> Option<Vec<f64>> {
        (values.len() == n_all).then(|| order.iter().map(|&i| values[i]).collect())
    };
    let links = links(data.t.as_deref(), &data.covariates, aside, column, &e);
    let m = median(&e);
    let sd = robust_sd(&e);
    let z: Vec<f64> = if sd > 0.0 {
        e.iter().map(|v| (v - m) / sd).collect()
    } else {
        vec![0.0; e.len()]
    };
    let (d1, d2) = direction_structure(&e, &u);
    Residuals3 {
        direction_degree1: d1,
        direction_degree2: d2,
        common: ResidualCommon::of(&e, &z, sd, links, noise_floor_of(&e, data.t.is_some())),
    }
}

fn fit_list(data: &Dataset3, effects: &[Effect]) -> Result<Ellipsoid3EffectsFit, Effects3Error> {
    fit_effects(data, Ellipsoid3Model::Offset, effects)
}

/// The candidates of the catalogue for a model, and those the recording
/// cannot determine (with why).
fn candidate_effects(
    data: &Dataset3,
    model: &[Effect],
    current: &Ellipsoid3EffectsFit,
    aside: &[SetAside],
) -> (Vec<Effect>, Vec<NotDetermined>) {
    let mut offered = Vec::new();
    let mut refused = Vec::new();
    let directions: Vec<[f64; 3]> = current
        .calibrated
        .iter()
        .enumerate()
        .filter(|(i, _)| current.flagged.binary_search(i).is_err())
        .map(|(_, c)| *c)
        .collect();
    let cov = sphere::coverage(directions.iter().copied());
    for (effect, needs) in [
        (Effect::Scale, Ellipsoid3Model::OffsetScale),
        (Effect::CrossAxis, Ellipsoid3Model::Full),
    ] {
        if model.contains(&effect) {
            continue;
        }
        if ellipsoid::supports(needs, &directions) {
            offered.push(effect);
        } else {
            refused.push(NotDetermined {
                effect,
                reason: format!(
                    "the samples cover {:.0} % of the sphere, too little to determine the {needs} model ({})",
                    cov.fraction * 100.0,
                    cov.missing_text()
                ),
            });
        }
    }
    if !model.contains(&Effect::Drift) {
        match data.t.as_deref() {
            Some(t) if range(t) > 0.0 => offered.push(Effect::Drift),
            Some(_) => refused.push(NotDetermined {
                effect: Effect::Drift,
                reason: "every sample has the same time".into(),
            }),
            None => refused.push(NotDetermined {
                effect: Effect::Drift,
                reason: "the recording has no time column (t, t_s, time or time_s, or --t)".into(),
            }),
        }
    }
    for c in &data.covariates {
        let effect = Effect::Covariate(c.name.clone());
        if model.contains(&effect) || aside.iter().any(|a| a.column == c.name) {
            continue;
        }
        offered.push(effect);
    }
    for effect in [Effect::Cubic, Effect::Outliers] {
        if !model.contains(&effect) {
            offered.push(effect);
        }
    }
    (offered, refused)
}

/// Everything a candidate is judged on.
struct Trial<'a> {
    data: &'a Dataset3,
    effect: &'a Effect,
    fit: &'a Ellipsoid3EffectsFit,
    current: &'a Ellipsoid3EffectsFit,
    /// The effect's own parameters.
    params: &'a [Param],
}

/// The largest swing of a moving offset over the recording, in calibrated
/// units over the field: |W·g|·span/r.
fn offset_swing(t: &Trial<'_>) -> Option<(f64, String)> {
    let (span, over, prefix) = match t.effect {
        Effect::Drift => {
            let span = range(t.data.t.as_deref()?);
            (span, format!("the run's {span:.1} s"), "drift".to_string())
        }
        Effect::Covariate(column) => {
            let span = range(&t.data.covariate(column)?.values);
            (
                span,
                format!(
                    "{column}'s range of {}",
                    crate::numfmt::significant(span, 3)
                ),
                column.clone(),
            )
        }
        _ => return None,
    };
    let g: Vec<f64> = ["x", "y", "z"]
        .iter()
        .map(|a| t.fit.value(&format!("{prefix}_{a}")))
        .collect();
    let w = &t.fit.matrix;
    let moved: f64 = (0..3)
        .map(|i| (0..3).map(|j| w[i][j] * g[j]).sum::<f64>().powi(2))
        .sum::<f64>()
        .sqrt();
    (t.fit.r > 0.0).then(|| (moved * span / t.fit.r, over))
}

impl Gates for Trial<'_> {
    fn fold(&self) -> Option<String> {
        let (before, after) = (self.current.coverage.covered, self.fit.coverage.covered);
        let fold = (FOLD_SHARE * sphere::REGIONS as f64).round() as usize;
        (after + fold < before).then(|| format!(
            "not an effect: the fit folds the sphere onto {after} of its {} regions (the model without it covers {before}), a larger sphere through a cap of the samples",
            sphere::REGIONS
        ))
    }

    fn physical(&self, numbers: &str, with_params: &str) -> Option<String> {
        // Nothing checks a 3-D fit's heading: a cubic is held to what the
        // sensor's datasheet allows.
        if *self.effect == Effect::Cubic
            && let Some(p) = self
                .params
                .iter()
                .find(|p| super::diagnose::beyond_limit(p, MAX_CUBIC_UNCHECKED))
        {
            return Some(format!(
                "not a physical cubic: {} = {} ± {} bends the reading by {:.1} % at full scale, beyond what the sensor's datasheet allows (limit {:.0} %: twice the worst datasheet figure, 0.1–0.5 %: HMC5883L, MPU-6050, ADXL345; nothing checks a 3-D fit's heading against a gyro); {numbers}",
                p.name,
                crate::numfmt::significant(p.value, 3),
                crate::numfmt::significant(p.se, 2),
                p.value.abs() * 100.0,
                MAX_CUBIC_UNCHECKED * 100.0
            ));
        }
        if *self.effect == Effect::CrossAxis {
            let w = &self.fit.matrix;
            for (i, j) in [(0, 1), (0, 2), (1, 2)] {
                let shear = w[i][j] / (w[i][i] * w[j][j]).sqrt();
                if shear.abs() > MAX_CROSS_AXIS_SHEAR {
                    return Some(format!(
                        "not a physical cross-axis: W couples axes {i} and {j} by {:.1}°, beyond the 20° limit (datasheets give ±2 % cross-axis sensitivity, ≈ 1°); {numbers}",
                        shear.atan().to_degrees().abs()
                    ));
                }
            }
        }
        let (fraction, over) = offset_swing(self).filter(|(f, _)| *f > MAX_OFFSET_SWING)?;
        Some(format!(
            "not a physical {}: it moves the offset by {:.0} % of the field over {over}, more than the {:.0} % ArduPilot's CompassMot accepts for motor interference; {with_params}",
            self.effect,
            fraction * 100.0,
            MAX_OFFSET_SWING * 100.0
        ))
    }

    fn gain(&self, with_params: &str) -> Option<String> {
        if *self.effect == Effect::Scale {
            return None;
        }
        let (w0, w1) = (&self.current.matrix, &self.fit.matrix);
        let factor = (0..3)
            .map(|i| {
                let (a, b) = (w0[i][i], w1[i][i]);
                if a > 0.0 && b > 0.0 {
                    (a / b).max(b / a)
                } else {
                    f64::INFINITY
                }
            })
            .fold(1.0, f64::max);
        (factor > MAX_GAIN_CHANGE).then(|| format!(
            "not a physical {}: it moves a gain of W by ×{factor:.2}, more than any effect of the catalogue at its limit (×{MAX_GAIN_CHANGE}); {with_params}",
            self.effect
        ))
    }

    fn candidate_floor(&self) -> f64 {
        let order = used_in_time_order(self.data, self.fit);
        let e: Vec<f64> = order.iter().map(|&i| self.fit.residuals[i]).collect();
        noise_floor_of(&e, self.data.t.is_some()).rms
    }

    fn squeeze_note(&self) -> &'static str {
        ""
    }

    fn heading(&self, _rms0: f64, _rms1: f64, _with_params: &str) -> Option<String> {
        None
    }
}

/// The sphere of a tumble: the 3-D geometry of the diagnosis ladder.
struct Sphere<'a> {
    data: &'a Dataset3,
    aside: &'a [SetAside],
}

impl Geometry for Sphere<'_> {
    type Fit = Ellipsoid3EffectsFit;
    type Residuals = Residuals3;
    type Step = Step3;
    type Candidate = Candidate3;
    type Error = Effects3Error;

    fn fit(&self, effects: &[Effect]) -> Result<Ellipsoid3EffectsFit, Effects3Error> {
        fit_list(self.data, effects)
    }

    fn analyse(&self, fit: &Ellipsoid3EffectsFit) -> Residuals3 {
        analyse(self.data, fit, self.aside)
    }

    fn bic(&self, fit: &Ellipsoid3EffectsFit) -> f64 {
        bic(fit)
    }

    /// The step of the fit's own list of effects (the model it was fitted
    /// to).
    fn step(&self, fit: &Ellipsoid3EffectsFit, _model: &[Effect]) -> Step3 {
        step_of(fit)
    }

    fn offered(
        &self,
        model: &[Effect],
        current: &Ellipsoid3EffectsFit,
    ) -> (Vec<Effect>, Vec<NotDetermined>) {
        candidate_effects(self.data, model, current, self.aside)
    }

    fn no_fit(&self, effect: Effect, err: Effects3Error) -> Option<NotDetermined> {
        Some(NotDetermined {
            effect,
            reason: format!("no fit: {err}"),
        })
    }

    fn candidate(&self, offer: Offer<'_, Self>) -> Candidate3 {
        let judged = ladder::judge(
            &offer.scores(),
            &Trial {
                data: self.data,
                effect: &offer.effect,
                fit: offer.fit,
                current: offer.current,
                params: &offer.params,
            },
        );
        offer.candidate(judged.supported, judged.evidence, ladder::Nothing {})
    }
}

/// Diagnoses a 3-axis recording, starting from `baseline` (the paper's
/// `offset+scale` is always in). When the coverage does not determine that
/// W, the diagnosis starts from the richest W it does determine and says so.
pub fn diagnose3(data: &Dataset3, baseline: &[Effect]) -> Result<Diagnosis3, Effects3Error> {
    let aside = set_aside(data);
    let mut model = starting_list(baseline);
    let mut baseline_note = None;
    let base_fit = match fit_list(data, &model) {
        Ok(fit) => fit,
        Err(Effects3Error::Fit(Ellipsoid3Error::NotCovered {
            model: asked,
            supported: Some(simpler),
            percent,
            missing,
            ..
        })) if simpler.unknowns() < asked.unknowns() => {
            model.retain(|e| !matches!(e, Effect::Offset | Effect::Scale | Effect::CrossAxis));
            model.extend(base_effects(simpler));
            model.sort();
            baseline_note = Some(format!(
                "the samples cover {percent:.0} % of the sphere, too little to determine the {asked} model ({missing}); the diagnosis starts from {simpler}, the richest W they determine"
            ));
            fit_list(data, &model)?
        }
        Err(err) => return Err(err),
    };
    let baseline_residuals = analyse(data, &base_fit, &aside);
    let coverage = base_fit.coverage.clone();
    let sphere = Sphere {
        data,
        aside: &aside,
    };
    let climb = ladder::climb(&sphere, model, base_fit, &baseline_residuals);
    let noise_floor = climb.final_residuals.common.noise_floor.clone();
    let used = climb.last.n - climb.last.flagged.len();
    let verdict = verdict(climb.last.rms, &climb.final_residuals, &noise_floor, used);
    Ok(Diagnosis3 {
        baseline: climb.baseline,
        baseline_note,
        set_aside: aside,
        baseline_residuals,
        candidates: climb.candidates,
        not_determined: climb.not_determined,
        suggested: climb.suggested,
        close_second: climb.close_second,
        ladder: climb.ladder,
        final_residuals: climb.final_residuals,
        noise_floor,
        coverage,
        verdict,
        criterion: criterion(),
    })
}

/// Noise, or where structure remains (the 2-D verdict's rule and words).
pub fn verdict(rms: f64, res: &Residuals3, floor: &NoiseFloor, n: usize) -> String {
    let patterns = || {
        // Under noise σ, the rms of a fitted part of k functions is about
        // σ·√(k/n). σ is the residual's own rms, not the floor: the residual
        // of a moving sensor is correlated from sample to sample, and a
        // pattern over direction must stand out of all of it, as the BIC of
        // the candidates that would remove it (offset, W) judges it. Degree 1
        // and 2 are what o and W absorb: the candidates above say whether a
        // richer W does; here the pattern is only named.
        let noise_part = |k: f64| rms * (k / n.max(1) as f64).sqrt();
        let mut places = Vec::new();
        for (amplitude, k, what) in [
            (
                res.direction_degree1,
                3.0,
                "a pattern of degree 1 over direction",
            ),
            (
                res.direction_degree2,
                5.0,
                "a pattern of degree 2 over direction",
            ),
        ] {
            if amplitude > STRUCTURE_SES * noise_part(k) {
                places.push(format!("{what}, {} of the field", percent(amplitude)));
            }
        }
        places
    };
    // The rest of what the floor does not explain: a residual correlated
    // from sample to sample (the noise floor comes from neighbours'
    // differences, so it leaves this out).
    let blame = |places: Vec<String>, excess: f64| {
        let smooth = "the residual moves smoothly from one sample to the next, slower than white noise, as the sensor's own motion does (the linear acceleration of a hand-held accelerometer, a magnetometer carried through a field that is not uniform), which no calibration removes";
        match (places.is_empty(), excess > 1.0) {
            (true, _) => {
                format!("no pattern over direction, trend, covariate or tail to blame: {smooth}")
            }
            (false, true) => format!("{}; beyond these, {smooth}", places.join(", ")),
            (false, false) => places.join(", "),
        }
    };
    ladder::verdict(rms, res, floor, patterns, blame)
}
