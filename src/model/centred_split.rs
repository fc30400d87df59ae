//! The centred cubic per axis, where a gyro pins it down.
//!
//! One axis that saturates softly and another that does not need a cubic of
//! its own each, `kc_x` and `kc_y`. Over a turn an axis's deviation
//! `u = S cos θ` has `u³ = S³ (3 cos θ + cos 3θ)/4`, so in |s| their
//! difference `δ = kc_x − kc_y` shows only as a 2nd harmonic, the one a
//! change of the gain ratio `a` makes too: a magnitude fit cannot tell the
//! two apart, and [`super::nonlinear`] keeps one `kc` for both axes. The
//! heading can: what `δ` does to it (−δ/4·sin 2θ − δ/8·sin 4θ, about) is
//! not what the gain does (−δ/2·sin 2θ for the same |s|).
//!
//! So with a gyro, `δ` is found on the heading's errors against it
//! ([`HeadingReference::check`], which fits the gyro's scale and bias
//! itself) by Gauss-Newton, the magnitude fit taking every other parameter
//! at each `δ` (variable projection: the derivative is taken through the
//! refit, by a finite difference). Its standard error comes from the same
//! sums, widened by batch means for errors that are correlated in time, as
//! [`super::gyro::HeadingCheck::worse_by`] widens its own.
//!
//! The split is offered only where the data pin it down: `δ` beyond
//! [`SPLIT_SES`] of its standard error, and the heading better than with
//! one `kc` by more than the diagnosis asks of any effect
//! ([`HEADING_WORSE_SES`] standard errors and [`HEADING_MATTERS_DEG`]),
//! and each axis's cubic within the physical limit with a gyro
//! ([`MAX_CUBIC`], by more than 2 standard errors, as the diagnosis holds
//! `kc`); otherwise the model keeps one `kc`.
//!
//! The split adds no unknown to the magnitude fit's count (its BIC): it is
//! measured on the heading against the gyro, not on the magnitude residual
//! the BIC scores, which it leaves as it was.
//!
//! Its standard error has two parts: the heading errors' own (white, or
//! from batch means where neighbours move together), and the gain ratio
//! `a`'s: the magnitude fit's error in `a` turns the heading by a 2nd
//! harmonic that `δ` takes in, so `(∂δ/∂a)² SE(a)²` is added.

use super::FitError;
use super::diagnose::{HEADING_MATTERS_DEG, HEADING_WORSE_SES, beyond_limit};
use super::effects::{Effect, MAX_CUBIC};
use super::gyro::{COMPARISON_BATCHES, HeadingCheck, HeadingReference};
use super::nonlinear::{KC_AXES, ModelFit, Param, fit_model, fit_model_split};
use crate::sample::Dataset;

/// `δ` beyond this many of its standard errors is pinned down: two, the
/// rule the diagnosis holds a parameter's limit to.
pub const SPLIT_SES: f64 = 2.0;
/// The finite-difference step in `δ`: 1 % at the turn's radius, a bend
/// that moves the heading by a few hundredths of a degree, well above the
/// refit's own precision and small enough for the heading to be linear.
const STEP: f64 = 0.01;
/// Gauss-Newton steps at most: the heading is nearly linear in `δ`, so the
/// first step lands within a few percent and the second confirms it.
const MAX_ITERATIONS: usize = 5;
/// Halvings of a step that does not lower the heading error.
const MAX_HALVINGS: usize = 2;
/// A step below this changes no heading measurably: the search stops.
const SMALLEST_STEP: f64 = 1e-5;
/// The search stays within twice the difference two cubics at the
/// physical limit can make; beyond it the fit is chasing something else.
const MAX_SPLIT: f64 = 4.0 * MAX_CUBIC;

/// A model whose centred cubic is split per axis by the gyro.
#[derive(Debug, Clone, PartialEq)]
pub struct SplitFit {
    /// The fit, with `kc_x` and `kc_y` in place of `kc`.
    pub fit: ModelFit,
    /// kc_x − kc_y and its standard error.
    pub split: f64,
    pub se: f64,
    /// The heading against the gyro with the split, and with one kc.
    pub heading: HeadingCheck,
    pub unsplit: HeadingCheck,
}

/// Fits `effects` by [`fit_model`], and with a gyro and `cubic-centred`
/// splits the centred cubic per axis where the gyro pins it down
/// ([`pin`]).
pub fn fit_with_gyro(
    data: &Dataset,
    effects: &[Effect],
    reference: Option<&HeadingReference>,
) -> Result<ModelFit, FitError> {
    let fit = fit_model(data, effects)?;
    let Some(reference) = reference.filter(|_| effects.contains(&Effect::CubicCentred)) else {
        return Ok(fit);
    };
    Ok(pin(data, effects, reference, &fit).map_or(fit, |split| split.fit))
}

/// The wrapped difference of two heading errors, degrees.
fn wrapped(d: f64) -> f64 {
    (d + 180.0).rem_euclid(360.0) - 180.0
}

/// The heading check of the fit with `δ = split`, or None when it fails.
fn trial(
    data: &Dataset,
    effects: &[Effect],
    reference: &HeadingReference,
    split: f64,
) -> Option<(ModelFit, HeadingCheck)> {
    let fit = fit_model_split(data, effects, split).ok()?;
    let check = reference.check(&fit.headings, &fit.flagged).ok()?;
    Some((fit, check))
}

/// Σ j·e over the samples both have.
fn dot(jacobian: &[f64], errors: &[f64]) -> f64 {
    jacobian
        .iter()
        .zip(errors)
        .filter(|(j, e)| j.is_finite() && e.is_finite())
        .map(|(j, e)| j * e)
        .sum()
}

/// The standard error of the Gauss-Newton estimate `−Σje/Σj²` at the
/// errors `e`: the larger of the white-noise figure and the batch means'
/// (the errors of neighbouring samples move together: a hand's wobble, the
/// gyro's noise integrated).
fn standard_error(jacobian: &[f64], errors: &[f64], jj: f64) -> f64 {
    let terms: Vec<(f64, f64)> = jacobian
        .iter()
        .zip(errors)
        .filter(|(j, e)| j.is_finite() && e.is_finite())
        .map(|(&j, &e)| (j, e))
        .collect();
    let n = terms.len();
    if n < 3 || !(jj > 0.0) {
        return f64::INFINITY;
    }
    let sigma_sq = terms.iter().map(|(_, e)| e * e).sum::<f64>() / (n - 1) as f64;
    let white = sigma_sq * jj;
    let batches = COMPARISON_BATCHES.min(n / 2);
    let batched = if batches >= 2 {
        let sums: Vec<f64> = (0..batches)
            .map(|b| {
                terms[b * n / batches..(b + 1) * n / batches]
                    .iter()
                    .map(|(j, e)| j * e)
                    .sum()
            })
            .collect();
        let mean = sums.iter().sum::<f64>() / batches as f64;
        sums.iter().map(|s| (s - mean) * (s - mean)).sum::<f64>() * batches as f64
            / (batches - 1) as f64
    } else {
        0.0
    };
    white.max(batched).sqrt() / jj
}

/// What the magnitude fit's error in the gain ratio `a` puts into `δ`:
/// `|∂δ/∂a| SE(a)`, with `∂δ/∂a = −Σ j k / Σ j²` and `k` the heading's
/// change per unit of `a` at each sample, `−s_y x₂ / |s|²` (radians, in
/// degrees here), `x₂ = (s_x − b − c s_y)/a`.
fn gain_part(fit: &ModelFit, jacobian: &[f64], jj: f64) -> f64 {
    let (a, b, c) = (fit.value("a"), fit.value("b"), fit.value("c"));
    let se_a = fit.param("a").map_or(f64::NAN, |p| p.se);
    if !(a > 0.0 && jj > 0.0 && se_a.is_finite()) {
        return 0.0;
    }
    let k: Vec<f64> = fit
        .calibrated
        .iter()
        .map(|&(sx, sy)| {
            let m2 = sx * sx + sy * sy;
            let x2 = (sx - b - c * sy) / a;
            if m2 > 0.0 {
                (-sy * x2 / m2).to_degrees()
            } else {
                f64::NAN
            }
        })
        .collect();
    (dot(jacobian, &k) / jj * se_a).abs()
}

/// Parameters with a split centred cubic (`kc_x`, `kc_y`) seen as one `kc`,
/// their mean, to compare with a fit that kept one: the standard error is
/// an axis's, which holds the mean's and half the split's.
pub fn as_one_kc(params: &[Param]) -> Vec<Param> {
    let (Some(x), Some(y)) = (
        params.iter().find(|p| p.name == KC_AXES[0]),
        params.iter().find(|p| p.name == KC_AXES[1]),
    ) else {
        return params.to_vec();
    };
    let one = Param {
        name: "kc".into(),
        value: 0.5 * (x.value + y.value),
        se: x.se.max(y.se),
    };
    params
        .iter()
        .filter(|p| p.name != KC_AXES[1])
        .map(|p| {
            if p.name == KC_AXES[0] {
                one.clone()
            } else {
                p.clone()
            }
        })
        .collect()
}

/// The centred cubic of `fit` (a fit of `effects` with one `kc`) split per
/// axis against the gyro, when the gyro pins the split down and the
/// heading is better for it; None otherwise (or when a check fails).
pub fn pin(
    data: &Dataset,
    effects: &[Effect],
    reference: &HeadingReference,
    fit: &ModelFit,
) -> Option<SplitFit> {
    let kc = fit.param("kc")?.clone();
    let unsplit = reference.check(&fit.headings, &fit.flagged).ok()?;
    let (_, probed) = trial(data, effects, reference, STEP)?;
    let jacobian: Vec<f64> = unsplit
        .errors_deg
        .iter()
        .zip(&probed.errors_deg)
        .map(|(a, b)| wrapped(b - a) / STEP)
        .collect();
    let jj = dot(&jacobian, &jacobian);
    if !(jj > 0.0) {
        return None;
    }
    let (mut split, mut best) = (0.0, (fit.clone(), unsplit.clone()));
    for _ in 0..MAX_ITERATIONS {
        let mut step = -dot(&jacobian, &best.1.errors_deg) / jj;
        if !(step.abs() >= SMALLEST_STEP) {
            break;
        }
        let mut moved = false;
        for _ in 0..=MAX_HALVINGS {
            let next = split + step;
            if next.abs() <= MAX_SPLIT
                && let Some(found) = trial(data, effects, reference, next)
                && found.1.rms_deg < best.1.rms_deg
            {
                (split, best, moved) = (next, found, true);
                break;
            }
            step *= 0.5;
        }
        if !moved {
            break;
        }
    }
    let se =
        standard_error(&jacobian, &best.1.errors_deg, jj).hypot(gain_part(&best.0, &jacobian, jj));
    if !(split.abs() > SPLIT_SES * se) {
        return None;
    }
    let better = best.1.worse_by(&unsplit);
    if !(better.delta_rms_deg > HEADING_WORSE_SES * better.se_deg
        && better.delta_rms_deg > HEADING_MATTERS_DEG)
    {
        return None;
    }
    let (mut fit, heading) = best;
    let mean = fit.param("kc").map_or(kc.value, |p| p.value);
    let mean_se = fit.param("kc").map_or(kc.se, |p| p.se);
    let axis_se = mean_se.hypot(0.5 * se);
    let at = fit.params.iter().position(|p| p.name == "kc")?;
    fit.params.splice(
        at..=at,
        [(KC_AXES[0], 0.5), (KC_AXES[1], -0.5)].map(|(name, sign)| Param {
            name: name.to_string(),
            value: mean + sign * split,
            se: axis_se,
        }),
    );
    if fit
        .params
        .iter()
        .any(|p| beyond_limit(p, MAX_CUBIC) && p.name.starts_with("kc"))
    {
        return None;
    }
    Some(SplitFit {
        fit,
        split,
        se,
        heading,
        unsplit,
    })
}
