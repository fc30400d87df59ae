//! Which effect the data supports: fit every candidate effect the model
//! lacks, rank them by BIC, add the best supported one, and repeat until no
//! effect is supported; then say whether what is left is noise.
//!
//! The criterion is BIC, `n·ln(RSS/n) + p·ln(n)`, because it charges each
//! added unknown `ln(n)`: on Gaussian noise an effect of two unknowns must
//! lower `n·ln(RSS)` by more than `2·ln(n) + margin` (a χ²₂ beyond ~21 for
//! n = 200, p ≈ 3e-5), so the suggestion almost never fires on a clean
//! recording, while a real effect of a few noise SD lowers it by hundreds.
//!
//! `outliers` changes the sample set, so it is judged as the mean-shift
//! outlier model: each flagged sample costs one unknown (an indicator that
//! absorbs it), and the robust fit's RSS over the used samples is its RSS on
//! all n. On top, it must pass a tail gate: more samples beyond 4 robust SD
//! than Gaussian noise could plausibly give (Poisson tail below 1e-3, at
//! least [`MIN_TAILS`]), or one sample beyond [`EXTREME_SDS`]. Clean
//! Gaussian data gives ~0.01 samples beyond 4 SD per 200, so the gate holds
//! it shut.
//!
//! Detectable is not enough: at large n, BIC finds the bias that noise puts
//! into |s|/r − 1 (σ²/2r², and its heading dependence when the calibrated
//! noise differs per axis) and would call it an effect. A candidate must
//! also matter ([`MIN_RMS_DROP`], [`MIN_EXPLAINED_NOISE`]), and its fitted
//! size must be one that a physical cause of that name produces
//! ([`PARAM_LIMITS`], [`MAX_GAIN_CHANGE`], parameters resolved above their
//! standard errors). Every candidate's evidence is built from the numbers
//! that decided it.

use serde::Serialize;

use super::FitError;
use super::centred_split::fit_with_gyro;
use super::effects::{self, Effect, model_name};
/// The physical limits stand with their effects in the catalogue.
pub use super::effects::{
    MAX_CROSS_AXIS_DEG, MAX_CROSS_AXIS_SHEAR, MAX_CUBIC, MAX_CUBIC_UNCHECKED, ParamLimit,
    limit_for, limit_of,
};
use super::gyro::{HeadingCheck, HeadingReference};
use super::heading::coverage;
use super::ladder::{
    self, Gates, Geometry, Judgement, NotDetermined, Offer, STRUCTURE_SES, Scores, percent, range,
};
#[cfg(test)]
use super::ladder::{own_params, tails_heavy};
#[cfg(test)]
use super::nonlinear::fit_model;
use super::nonlinear::{ModelFit, Param};
use super::residuals::{self, NoiseFloor, Residuals, SetAside, analyse, is_time_like, set_aside};
use crate::sample::Dataset;

/// An effect is supported when it lowers BIC by more than this (Kass and
/// Raftery's "very strong" evidence).
pub const BIC_MARGIN: f64 = 10.0;
/// The ladder adds at most this many effects.
pub const MAX_STEPS: usize = 5;
/// The `outliers` tail gate needs at least this many samples beyond 4 SD.
pub const MIN_TAILS: usize = 2;
/// ... and a count this improbable for Gaussian noise (Poisson upper tail).
pub const TAIL_PROBABILITY: f64 = 1e-3;
/// Or one sample this many robust SD out: Gaussian noise puts one of n
/// there with probability n·2e-9 (plus the robust SD's own error), so a
/// single far spike is enough.
pub const EXTREME_SDS: f64 = 6.0;
/// The expected Gaussian tail count is inflated by this factor before the
/// Poisson test, for the uncertainty of the robust SD itself.
pub const TAIL_EXPECTED_SLACK: f64 = 2.0;
/// The verdict calls the remainder noise when the final rms is within this
/// fraction above the noise floor.
pub const NOISE_TOLERANCE: f64 = 0.2;
/// A candidate whose calibrated samples cover this many degrees of heading
/// less than the current model's did not find an effect: it folded the turn
/// onto an arc of a larger circle, where the relative residual |s|/r - 1
/// shrinks with r (drift or a covariate that rises through one turn can do
/// this, since time then follows heading). Real effects move headings by a
/// few degrees at most.
pub const FOLD_DEG: f64 = 30.0;
/// Materiality, part 1: a candidate must lower the model's rms by at least
/// this fraction. On a residual that is noise, an effect explaining an
/// amplitude A lowers the rms by about A²/2σ², so 3 % is an explained
/// amplitude of a quarter of the noise ([`MIN_EXPLAINED_NOISE`]); where
/// structure dominates the residual, a candidate must still move the rms
/// by more than the few percent its own estimate varies between two runs
/// of the same sensor (the rms of n samples has a relative SE of 1/√(2n),
/// 5 % at 200 samples), or nobody would act on it. The noise-induced bias
/// of |s|/r − 1 lowers the rms by (σ/2r)²/2 at most, 0.03 % of it at 5 %
/// noise, at any sample count.
pub const MIN_RMS_DROP: f64 = 0.03;
/// Materiality, part 2: the amplitude a candidate explains,
/// √(rms_before² − rms_after²), must be at least this fraction of the noise
/// floor. Below it the effect moves a calibrated reading (and its heading,
/// by amplitude/r radians) by less than a quarter of what each sample's
/// noise does: a calibration with or without it points the same within the
/// noise. The noise-induced bias explains about σ²/4r² · √2 (its heading
/// dependence with per-axis noise ratios up to 2.5:1), under 1 % of σ at
/// 5 % noise, far below this at any n.
pub const MIN_EXPLAINED_NOISE: f64 = 0.25;

/// The most an added effect may change the fitted gain ratio a, as a
/// factor: 1.25. The catalogue at its limits moves it less: a cubic of
/// [`MAX_CUBIC`] on one axis and its opposite on the other changes the
/// axes' mean gains by (1 + 0.1)/(1 − 0.1) = 1.22 at most; a coupling of
/// [`MAX_CROSS_AXIS_DEG`] by 1/cos 20° = 1.06; moving offsets not at all.
/// ArduPilot's newer CompassCalibrator bounds a scale factor to 1/1.5–1.5
/// (COMPASS_MAX_SCALE_FACTOR) for the gain itself; a change beyond 1.25 by
/// one added effect is the fit trading gain for a shape no cause has.
pub const MAX_GAIN_CHANGE: f64 = 1.25;

/// The most a moving offset (drift over the run, a covariate over its
/// logged range) may move the reading, as a fraction of the field: 0.6.
/// ArduPilot's CompassMot rates motor interference below 30 % of the
/// field as acceptable, 30–60 % as a grey zone and above 60 % as
/// unacceptable (ArduPilot docs, "Advanced Compass Setup", CompassMot);
/// a warm-up drift moves a magnetometer's offset by far less (HMC5883L:
/// offsets stable to a few mG with set/reset). Beyond it the "offset" is
/// the fit enlarging the circle (time and covariates that follow heading
/// through a turn can do that) rather than a cause.
pub const MAX_OFFSET_SWING: f64 = 0.6;

/// With a gyro, a candidate whose heading error against it is worse than
/// the model's without it by more than this many standard errors (of the
/// difference, from [`HeadingCheck::worse_by`]'s batch means, which respect
/// the errors' autocorrelation) is not supported: it makes |s| rounder by
/// moving where samples point. Two SE: a candidate that leaves the heading
/// as it was is refused by chance about one time in 40 (one-sided).
pub const HEADING_WORSE_SES: f64 = 2.0;
/// ... and by more than this, in degrees of rms heading error: a change
/// smaller than a tenth of a degree matters to no one who steers by the
/// heading (Honeywell gives the HMC5883L "1° to 2° compass heading
/// accuracy"; this is a twentieth of the better figure), however well a
/// long recording resolves it.
pub const HEADING_MATTERS_DEG: f64 = 0.1;

/// One effect the model could add, as judged on the current model, with
/// the heading error against the gyro when one was given.
pub type Candidate = ladder::Candidate<HeadingSlot>;

/// What a 2-D candidate adds to the ladder's: its heading against the gyro.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HeadingSlot {
    /// The heading error against the gyro, when one was given.
    pub heading_vs_gyro: Option<HeadingCheck>,
}

/// One model of the ladder.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Step {
    pub effects: Vec<Effect>,
    pub model: String,
    pub rms: f64,
    pub unknowns: usize,
    pub bic: f64,
    /// Every fitted parameter, with its standard error.
    pub params: Vec<Param>,
    /// The heading error against the gyro, when one was given.
    pub heading_vs_gyro: Option<HeadingCheck>,
}

/// The whole answer of `fieldcal diagnose`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Diagnosis {
    pub baseline: Step,
    /// Logged columns not offered as covariates, and why.
    pub set_aside: Vec<SetAside>,
    pub baseline_residuals: Residuals,
    /// Ranked best first: supported ones first, then by ΔBIC.
    pub candidates: Vec<Candidate>,
    /// None: the model is enough.
    pub suggested: Option<Effect>,
    /// A supported effect that explains the residual about as well as the
    /// suggested one (BIC within [`BIC_MARGIN`]): the data cannot tell them
    /// apart, and the person should know (a temperature that rises and falls
    /// through a single turn follows heading, as cross-axis coupling does).
    pub close_second: Option<Effect>,
    /// Baseline, then each added effect, in order.
    pub ladder: Vec<Step>,
    pub final_residuals: Residuals,
    pub noise_floor: NoiseFloor,
    pub verdict: String,
    pub criterion: String,
    /// Whether and how the heading was checked (against a gyro, or not).
    pub heading: String,
}

ladder::ladder_types!(ModelFit, Residuals);

/// The criterion, as the report states it.
pub fn criterion() -> String {
    format!(
        "BIC: n·ln(RSS/n) + p·ln(n), with n all samples and p the unknowns; an effect is supported when it lowers BIC by more than {BIC_MARGIN}. outliers counts one unknown per flagged sample (the mean-shift outlier model) and must also find at least {MIN_TAILS} samples beyond 4 robust SD, a count Gaussian noise gives with probability below {TAIL_PROBABILITY:e}, or one beyond {EXTREME_SDS} robust SD. It must also matter: lower the rms by {:.0} % or more and explain an amplitude of at least {MIN_EXPLAINED_NOISE} of the noise floor; and be physical: a cubic within {:.0} % at full scale with a gyro that checks the heading, {:.0} % without one (the datasheets' figure), a cross-axis within {MAX_CROSS_AXIS_DEG}°, a moving offset within {:.0} % of the field over the run, the gain ratio moved by less than ×{MAX_GAIN_CHANGE}, each effect's parameters resolved above their standard errors",
        MIN_RMS_DROP * 100.0,
        MAX_CUBIC * 100.0,
        MAX_CUBIC_UNCHECKED * 100.0,
        MAX_OFFSET_SWING * 100.0
    )
}

/// BIC of a fit over all `n` samples; flagged samples count as unknowns.
fn bic(fit: &ModelFit, n: usize) -> f64 {
    ladder::bic(n, fit.unknowns + fit.flagged.len(), fit.rss)
}

/// A fit's heading error against the gyro (None without one, or when the
/// check cannot be made, which is logged).
fn heading_check(fit: &ModelFit, reference: Option<&HeadingReference>) -> Option<HeadingCheck> {
    let reference = reference?;
    match reference.check(&fit.headings, &fit.flagged) {
        Ok(check) => Some(check),
        Err(err) => {
            tracing::debug!("heading against {}: {err}", reference.column());
            None
        }
    }
}

fn step_of(
    fit: &ModelFit,
    effects: &[Effect],
    n: usize,
    reference: Option<&HeadingReference>,
) -> Step {
    Step {
        heading_vs_gyro: heading_check(fit, reference),
        effects: effects.to_vec(),
        model: model_name(effects),
        rms: fit.rms,
        unknowns: fit.unknowns,
        bic: bic(fit, n),
        params: fit.params.clone(),
    }
}

/// Smallest count k with P(Poisson(λ) ≥ k) < [`TAIL_PROBABILITY`], at
/// least [`MIN_TAILS`].
pub fn tail_threshold(expected: f64) -> usize {
    let lambda = (expected * TAIL_EXPECTED_SLACK).max(0.0);
    let mut term = (-lambda).exp(); // P(X = 0)
    let mut below = 0.0; // P(X < k)
    let mut k = 0usize;
    while k < 100_000 {
        if 1.0 - below < TAIL_PROBABILITY {
            break;
        }
        below += term;
        k += 1;
        term *= lambda / k as f64;
    }
    k.max(MIN_TAILS)
}

/// A logged column that moves almost in step with time: drift and that
/// covariate are then hard to tell apart, and the user should know.
const TIME_LIKE_CORRELATION: f64 = 0.95;

/// The covariate columns that follow time closely, with their correlation.
fn time_twins(data: &Dataset) -> Vec<(String, f64)> {
    let Some(t) = data.t.as_deref() else {
        return Vec::new();
    };
    data.covariates
        .iter()
        .filter(|c| !is_time_like(&c.name))
        .filter_map(|c| {
            let (_, r) = residuals::line(t, &c.values)?;
            (r.abs() > TIME_LIKE_CORRELATION).then(|| (c.name.clone(), r))
        })
        .collect()
}

/// What a candidate says beyond its numbers: a drift and a covariate that
/// follows time cannot be told apart, and the person should know.
fn caveat(effect: &Effect, data: &Dataset) -> String {
    let twins = time_twins(data);
    match effect {
        Effect::Drift if !twins.is_empty() => {
            let names: Vec<String> = twins
                .iter()
                .map(|(name, r)| format!("{name} (correlation {r:.2})"))
                .collect();
            format!(
                " (but {} follows time closely, so a drift and that covariate are hard to tell apart)",
                names.join(", ")
            )
        }
        Effect::Covariate(column) => match twins.iter().find(|(name, _)| name == column) {
            Some((_, r)) => format!(
                " (but {column} follows time, correlation {r:.2}, so it is hard to tell apart from a drift)"
            ),
            None => String::new(),
        },
        _ => String::new(),
    }
}

/// A number to three significant digits, in plain or scientific notation.
fn sig(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || !a.is_finite() {
        return format!("{v}");
    }
    if !(1e-4..1e6).contains(&a) {
        return format!("{v:.2e}");
    }
    let decimals = (2 - a.log10().floor() as i32).clamp(0, 8) as usize;
    format!("{v:.decimals$}")
}

/// `name = value ± se`, joined.
pub fn params_text(params: &[Param]) -> String {
    params
        .iter()
        .map(|p| format!("{} = {} ± {}", p.name, sig(p.value), sig(p.se)))
        .collect::<Vec<_>>()
        .join(", ")
}

/// Everything a candidate is judged on.
struct Trial<'a> {
    data: &'a Dataset,
    /// Heading checks of the baseline, the current model and the candidate.
    heading: [Option<&'a HeadingCheck>; 3],
    effect: &'a Effect,
    fit: &'a ModelFit,
    current: &'a ModelFit,
    res: &'a Residuals,
    params: &'a [Param],
    delta_bic: f64,
    covered: f64,
    covered_now: f64,
}

/// At least this share of what a candidate explains, `rms₀² − rms₁²`, must
/// come out of the residual's structure, `rms² − floor²`, rather than out
/// of its noise floor.
///
/// An effect of the catalogue removes structure: a smooth function of
/// heading, time or a logged column, which cancels between neighbouring
/// samples and so leaves the noise floor (estimated from the differences
/// of neighbours) where it was. A term that changes the local gain can
/// also lower the rms with no effect present, by squeezing the noise where
/// the gain drops: on clean simulated data at 5 % noise `cubic-centred`
/// lowered the rms by 6 % (kc = −0.08), all of it out of the noise floor,
/// while adding a 4th harmonic of its own. A squeeze takes none of its
/// reduction out of the structure (all of it, or more, comes out of the
/// floor). A real effect takes most of it out of the structure; one that
/// changes fast between samples, as a temperature that jumps within a few
/// samples of a 50-sample recording, shows partly in the differences of
/// neighbours too, and such a case left 53 % in the floor. A quarter sits
/// apart from both.
pub const MIN_STRUCTURE_SHARE: f64 = 0.25;

/// The largest swing of a moving offset (drift, covariate) over the
/// recording, in calibrated units over the field.
struct Swing {
    param: String,
    value: f64,
    se: f64,
    fraction: f64,
    over: String,
}

fn offset_swing(t: &Trial<'_>) -> Option<Swing> {
    let (span, over) = match t.effect {
        Effect::Drift => {
            let span = range(t.data.t.as_deref()?);
            (span, format!("the run's {span:.1} s"))
        }
        Effect::Covariate(column) => {
            let span = range(&t.data.covariate(column)?.values);
            (span, format!("{column}'s range of {}", sig(span)))
        }
        _ => return None,
    };
    let (a, r) = (t.fit.value("a"), t.fit.value("r"));
    if !(r > 0.0) {
        return None;
    }
    t.params
        .iter()
        .map(|p| {
            // s_x = a·x + …: an x offset moves the calibrated reading a times.
            let gain = if p.name.ends_with("_x") { a } else { 1.0 };
            Swing {
                param: p.name.clone(),
                value: p.value,
                se: p.se,
                fraction: (p.value * span * gain).abs() / r,
                over: over.clone(),
            }
        })
        .max_by(|a, b| a.fraction.total_cmp(&b.fraction))
}

/// Judges a candidate on the ladder's gates, with the circle's own tests.
fn judge(t: &Trial<'_>) -> Judgement {
    let scores = Scores {
        effect: t.effect,
        rms_before: t.current.rms,
        rms_after: t.fit.rms,
        params: t.params,
        delta_bic: t.delta_bic,
        res: t.res,
        flagged: t.fit.flagged.len(),
    };
    ladder::judge(&scores, t)
}

impl Gates for Trial<'_> {
    fn fold(&self) -> Option<String> {
        (self.covered < self.covered_now - FOLD_DEG).then(|| format!(
            "not an effect: the fit folds the turn onto {:.0}° of heading (the model without it covers {:.0}°), a larger circle through an arc of the samples",
            self.covered, self.covered_now
        ))
    }

    fn physical(&self, numbers: &str, _with_params: &str) -> Option<String> {
        for p in self.params {
            // The candidate's heading checked against a gyro, or not.
            let checked = self.heading[2].is_some();
            if let Some(limit) = limit_for(&p.name, checked).filter(|l| beyond_limit(p, l.max_abs))
            {
                let beyond = if checked || limit.unchecked.is_none() {
                    "what any sensor does"
                } else {
                    "what the sensor's datasheet allows"
                };
                return Some(format!(
                    "not a physical {}: {} = {} ± {} {}, beyond {beyond} ({}); {numbers}",
                    self.effect,
                    p.name,
                    sig(p.value),
                    sig(p.se),
                    (limit.describe)(p.value),
                    limit.source
                ));
            }
        }
        let swing = offset_swing(self).filter(|s| s.fraction > MAX_OFFSET_SWING)?;
        Some(format!(
            "not a physical {}: {} = {} ± {} moves the offset by {:.0} % of the field over {}, more than the {:.0} % ArduPilot's CompassMot accepts for motor interference; {numbers}",
            self.effect,
            swing.param,
            sig(swing.value),
            sig(swing.se),
            swing.fraction * 100.0,
            swing.over,
            MAX_OFFSET_SWING * 100.0
        ))
    }

    fn gain(&self, with_params: &str) -> Option<String> {
        let (a0, a1) = (self.current.value("a"), self.fit.value("a"));
        if !(a0 > 0.0 && a1 > 0.0) {
            return None;
        }
        let factor = (a1 / a0).max(a0 / a1);
        (factor > MAX_GAIN_CHANGE).then(|| format!(
            "not a physical {}: it moves the gain ratio a from {} to {} (×{factor:.2}), more than any effect of the catalogue at its limit (×{MAX_GAIN_CHANGE}); {with_params}",
            self.effect,
            sig(a0),
            sig(a1)
        ))
    }

    fn candidate_floor(&self) -> f64 {
        residuals::noise_floor(self.data, self.fit).rms
    }

    fn squeeze_note(&self) -> &'static str {
        ", which a physical effect leaves alone"
    }

    fn heading(&self, rms0: f64, rms1: f64, with_params: &str) -> Option<String> {
        // Worse than the model it is added to, or than the baseline: steps
        // that each stay within their uncertainty must not add up to a worse
        // heading than the one the ladder started from.
        let [baseline, now, with] = self.heading;
        let with = with?;
        for (before, which) in [(now, "without it"), (baseline, "the baseline")] {
            let Some(before) = before else { continue };
            let delta = before.worse_by(with);
            if delta.delta_rms_deg > HEADING_WORSE_SES * delta.se_deg
                && delta.delta_rms_deg > HEADING_MATTERS_DEG
            {
                return Some(format!(
                    "distorts heading: makes |s| rounder (rms {} → {}) but moves the heading: {:.1}° ({which}) → {:.1}° rms against {} (+{:.1}° ± {:.1}°); {}",
                    percent(rms0),
                    percent(rms1),
                    before.rms_deg,
                    with.rms_deg,
                    with.gyro_column,
                    delta.delta_rms_deg,
                    delta.se_deg,
                    with_params
                ));
            }
        }
        None
    }
}

/// The candidate effects for a model: the optional catalogue, and one
/// covariate per logged column not set aside (time, constants, copies of
/// the axes).
fn candidate_effects(data: &Dataset, model: &[Effect], aside: &[SetAside]) -> Vec<Effect> {
    effects::OPTIONAL
        .iter()
        .cloned()
        .chain(
            data.covariates
                .iter()
                .filter(|c| !is_time_like(&c.name) && !aside.iter().any(|a| a.column == c.name))
                .map(|c| Effect::Covariate(c.name.clone())),
        )
        .filter(|e| !model.contains(e))
        .collect()
}

/// Heading coverage of a fit's calibrated samples, flagged ones left out.
fn covered_deg(fit: &ModelFit) -> f64 {
    let used = fit
        .headings
        .iter()
        .enumerate()
        .filter(|(i, _)| fit.flagged.binary_search(i).is_err())
        .map(|(_, h)| *h);
    coverage(used).covered_deg
}

/// Whether the data put a parameter beyond a physical limit: by more than
/// [`LIMIT_SES`] standard errors (a parameter the data barely determine is
/// not shown to be unphysical, only unresolved, which the judgement says
/// in its own words). A standard error that is not finite counts as none:
/// the value alone decides.
pub(crate) fn beyond_limit(p: &Param, max_abs: f64) -> bool {
    let se = if p.se.is_finite() { p.se } else { 0.0 };
    p.value.abs() - LIMIT_SES * se > max_abs
}

/// Standard errors by which a parameter must pass a physical limit to be
/// refused as unphysical: two, the 95 % one-sided bound and more.
pub const LIMIT_SES: f64 = 2.0;

/// The circle of a turn: the 2-D geometry of the diagnosis ladder.
struct Plane<'a> {
    data: &'a Dataset,
    aside: &'a [SetAside],
    reference: Option<&'a HeadingReference>,
}

impl Geometry for Plane<'_> {
    type Fit = ModelFit;
    type Residuals = Residuals;
    type Step = Step;
    type Candidate = Candidate;
    type Error = FitError;

    fn fit(&self, effects: &[Effect]) -> Result<ModelFit, FitError> {
        fit_with_gyro(self.data, effects, self.reference)
    }

    fn analyse(&self, fit: &ModelFit) -> Residuals {
        analyse(self.data, fit)
    }

    fn bic(&self, fit: &ModelFit) -> f64 {
        bic(fit, self.data.len())
    }

    fn step(&self, fit: &ModelFit, model: &[Effect]) -> Step {
        step_of(fit, model, self.data.len(), self.reference)
    }

    fn offered(&self, model: &[Effect], _current: &ModelFit) -> (Vec<Effect>, Vec<NotDetermined>) {
        (candidate_effects(self.data, model, self.aside), Vec::new())
    }

    fn no_fit(&self, effect: Effect, err: FitError) -> Option<NotDetermined> {
        tracing::debug!("candidate {effect}: no fit: {err}");
        None
    }

    fn candidate(&self, offer: Offer<'_, Self>) -> Candidate {
        let heading_vs_gyro = heading_check(offer.fit, self.reference);
        let judged = judge(&Trial {
            data: self.data,
            heading: [
                offer.baseline.heading_vs_gyro.as_ref(),
                offer.now.heading_vs_gyro.as_ref(),
                heading_vs_gyro.as_ref(),
            ],
            effect: &offer.effect,
            fit: offer.fit,
            current: offer.current,
            res: offer.res,
            params: &offer.params,
            delta_bic: offer.delta_bic,
            covered: covered_deg(offer.fit),
            covered_now: covered_deg(offer.current),
        });
        let evidence = judged.evidence + &caveat(&offer.effect, self.data);
        offer.candidate(judged.supported, evidence, HeadingSlot { heading_vs_gyro })
    }
}

/// What the diagnosis says about the heading: checked against a gyro, or
/// not, and what held the effects instead.
pub fn heading_note(reference: Option<&HeadingReference>, checked: bool) -> String {
    match reference {
        None => format!(
            "heading: not checked — no gyro given (--gyro); effects were held to physical limits instead, a cubic to {:.0} % at full scale (the datasheets' figure; {:.0} % with a gyro)",
            MAX_CUBIC_UNCHECKED * 100.0,
            MAX_CUBIC * 100.0
        ),
        Some(r) if checked => format!(
            "heading: checked against {}: an effect that makes the heading worse by more than {HEADING_WORSE_SES} standard errors (and {HEADING_MATTERS_DEG}°) is not supported; the physical limits hold too",
            r.column()
        ),
        Some(r) => format!(
            "heading: not checked — the gyro {} does not cover enough of the recording; effects were held to physical limits instead, a cubic to {:.0} % at full scale (the datasheets' figure)",
            r.column(),
            MAX_CUBIC_UNCHECKED * 100.0
        ),
    }
}

/// Diagnoses a recording, starting from the model `baseline` (the paper's
/// effects are always included). With a gyro `reference`, every step and
/// candidate carries its heading error against it, and a candidate that
/// makes the heading worse is not supported.
pub fn diagnose(
    data: &Dataset,
    baseline: &[Effect],
    reference: Option<&HeadingReference>,
) -> Result<Diagnosis, FitError> {
    super::turn::check_turn_of(data, super::fit::DEFAULT_MIN_COVERAGE_DEG)?;
    let model = ladder::starting_list(baseline);
    let aside = set_aside(data);
    let base_fit = fit_with_gyro(data, &model, reference)?;
    let baseline_residuals = analyse(data, &base_fit);
    let plane = Plane {
        data,
        aside: &aside,
        reference,
    };
    let climb = ladder::climb(&plane, model, base_fit, &baseline_residuals);

    // The noise floor comes from the final residual: differences of
    // neighbours cancel slow structure, but a large harmonic still moves a
    // little from one sample to the next (5 % at 200 samples a turn adds
    // ~13 % to the estimate), so the residual with the least structure left
    // gives the cleanest estimate.
    let noise_floor = climb.final_residuals.common.noise_floor.clone();
    let verdict = verdict(
        climb.last.rms,
        &climb.final_residuals,
        &noise_floor,
        climb.last.residuals.len(),
    );
    let heading = heading_note(reference, climb.baseline.heading_vs_gyro.is_some());
    Ok(Diagnosis {
        baseline: climb.baseline,
        set_aside: aside,
        baseline_residuals,
        candidates: climb.candidates,
        suggested: climb.suggested,
        close_second: climb.close_second,
        ladder: climb.ladder,
        final_residuals: climb.final_residuals,
        noise_floor,
        verdict,
        criterion: criterion(),
        heading,
    })
}

/// Noise, or where structure remains.
fn verdict(rms: f64, res: &Residuals, floor: &NoiseFloor, n: usize) -> String {
    let harmonics = || {
        // Standard error of one harmonic amplitude under noise σ: σ·√(2/n).
        let se = floor.rms * (2.0 / n.max(1) as f64).sqrt();
        res.harmonics
            .iter()
            .filter(|h| h.amplitude > STRUCTURE_SES * se)
            .map(|h| {
                format!(
                    "harmonic {} of heading ({} of the field)",
                    h.order,
                    percent(h.amplitude)
                )
            })
            .collect()
    };
    ladder::verdict(rms, res, floor, harmonics, |places, _| {
        if places.is_empty() {
            "no single harmonic, trend, covariate or tail to blame; the residual changes faster than a turn's structure but slower than white noise".to_string()
        } else {
            places.join(", ")
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tail_threshold_is_strict_for_small_runs() {
        assert_eq!(tail_threshold(0.0127), 2);
        // 100,000 samples: ~6 expected; the gate asks for far more.
        assert!(tail_threshold(6.3) > 20);
    }

    #[test]
    fn bic_counts_flagged_samples_as_unknowns() {
        let fit = ModelFit {
            effects: vec![],
            params: vec![],
            rms: 0.01,
            n: 100,
            unknowns: 4,
            residuals: vec![0.01; 100],
            headings: vec![0.0; 100],
            calibrated: vec![(1.0, 0.0); 100],
            flagged: vec![1, 2],
            weights: vec![1.0; 100],
            iterations: 1,
            rss: 0.01,
        };
        let expected = 100.0 * (0.01f64 / 100.0).ln() + 6.0 * 100f64.ln();
        assert!((bic(&fit, 100) - expected).abs() < 1e-9);
    }
}

#[cfg(test)]
mod tail_tests {
    use super::*;
    use crate::sim::SimSensor;

    fn clean(seed: u64) -> Dataset {
        SimSensor {
            offset_x: 30.0,
            offset_y: -20.0,
            gain_x: 1.05,
            noise: 3.0,
            seed,
            ..Default::default()
        }
        .simulate()
        .unwrap()
    }

    #[test]
    fn spikes_open_the_tail_gate_and_clean_data_does_not() {
        let data = clean(3);
        let fit = fit_model(&data, &effects::PAPER).unwrap();
        assert!(!tails_heavy(&analyse(&data, &fit)));
        let mut spiky = data.clone();
        for i in [17, 60, 111, 150] {
            spiky.x[i] += 80.0;
        }
        let fit = fit_model(&spiky, &effects::PAPER).unwrap();
        let res = analyse(&spiky, &fit);
        assert!(tails_heavy(&res), "{res:?}");
        let d = diagnose(&spiky, &[], None).unwrap();
        let outliers = d.candidates.iter().find(|c| c.effect == Effect::Outliers);
        let outliers = outliers.expect("outliers is a candidate");
        assert!(outliers.supported, "{outliers:?}");
        assert!(
            outliers.evidence.contains("beyond 4 robust SD"),
            "{outliers:?}"
        );

        // One far spike is enough.
        let mut one = data.clone();
        one.x[0] += 60.0;
        let fit = fit_model(&one, &effects::PAPER).unwrap();
        let res = analyse(&one, &fit);
        assert!(
            res.common.tail_max_sd > EXTREME_SDS && tails_heavy(&res),
            "{res:?}"
        );
    }

    /// Gains 2.2:1 apart make the radial residual twice as noisy at some
    /// headings as at others; one scale for all headings saw those
    /// headings' ordinary samples as 4-SD tails and suggested `outliers` in
    /// about one clean recording in six. Spikes must still be found.
    #[test]
    fn unequal_gains_are_not_outliers_and_spikes_still_are() {
        let sensor = |seed: u64, turns: f64| SimSensor {
            gain_x: 0.8,
            gain_y: 1.76,
            offset_x: 300.0,
            offset_y: -200.0,
            noise: 5.0,
            period: 0.02,
            turns,
            seed,
            ..Default::default()
        };
        let mut tails = 0;
        for seed in 1..=30 {
            let data = sensor(seed, if seed % 2 == 0 { 1.0 } else { 3.0 })
                .simulate()
                .unwrap();
            let fit = fit_model(&data, &effects::PAPER).unwrap();
            if tails_heavy(&analyse(&data, &fit)) {
                tails += 1;
            }
        }
        assert!(tails <= 1, "{tails} of 30 clean recordings had heavy tails");

        let mut spiky = sensor(7, 1.0).simulate().unwrap();
        for i in [40, 170, 333] {
            spiky.x[i] += 25.0 * 5.0;
        }
        let fit = fit_model(&spiky, &effects::PAPER).unwrap();
        assert!(tails_heavy(&analyse(&spiky, &fit)));
    }
}

#[cfg(test)]
mod evidence_tests {
    use super::*;
    use crate::sample::Covariate;

    #[test]
    fn a_covariate_that_follows_time_is_called_out() {
        let n = 50;
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.1).collect();
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.2).cos()).collect();
        let y: Vec<f64> = (0..n).map(|i| (i as f64 * 0.2).sin()).collect();
        let temp = Covariate {
            name: "temp_c".into(),
            values: t.iter().map(|t| 20.0 + t).collect(),
        };
        let data = Dataset::new("x", "y", Some(t), x, y, vec![temp]).unwrap();
        let drift = caveat(&Effect::Drift, &data);
        assert!(
            drift.contains("temp_c") && drift.contains("hard to tell apart"),
            "{drift}"
        );
        let cov = caveat(&Effect::Covariate("temp_c".into()), &data);
        assert!(cov.contains("hard to tell apart"), "{cov}");
    }
}

#[cfg(test)]
mod judge_tests {
    use super::*;
    use crate::sim::SimSensor;

    fn fit(params: &[(&str, f64, f64)], rms: f64) -> ModelFit {
        let n = 1000;
        ModelFit {
            effects: vec![],
            params: params
                .iter()
                .map(|&(name, value, se)| Param {
                    name: name.into(),
                    value,
                    se,
                })
                .collect(),
            rms,
            n,
            unknowns: params.len(),
            // White noise of SD 0.01, the noise floor `judged` gives the
            // current model: every synthetic fit has the same floor, as
            // fits that differ by a smooth effect do.
            residuals: {
                use rand::SeedableRng;
                use rand_distr::{Distribution, Normal};
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
                let noise = Normal::new(0.0, 0.01).expect("a valid SD");
                (0..n).map(|_| noise.sample(&mut rng)).collect()
            },
            headings: vec![0.0; n],
            calibrated: vec![(1.0, 0.0); n],
            flagged: vec![],
            weights: vec![1.0; n],
            iterations: 1,
            rss: rms * rms * n as f64,
        }
    }

    const PAPER_PARAMS: [(&str, f64, f64); 4] = [
        ("a", 1.0, 0.001),
        ("b", 10.0, 0.1),
        ("d", -5.0, 0.1),
        ("r", 1000.0, 1.0),
    ];

    /// Judges `effect` with `own` parameters (and `a` moved to `a1`) taking
    /// the rms from 2 % to `rms1` at ΔBIC -500, noise floor 1 %.
    fn judged(effect: Effect, own: &[(&str, f64, f64)], a1: f64, rms1: f64) -> Judgement {
        judged_checked(effect, own, a1, rms1, None)
    }

    /// A gyro's heading check that says nothing against the candidate: the
    /// same for the baseline, the model and the candidate.
    fn gyro_check() -> HeadingCheck {
        HeadingCheck {
            gyro_column: "gyro_z".into(),
            rms_deg: 1.0,
            peak_to_peak_deg: 4.0,
            n: 1000,
            gyro_scale: 1.0,
            gyro_bias_deg_s: 0.0,
            errors_deg: Vec::new(),
            reference_deg: Vec::new(),
        }
    }

    fn judged_checked(
        effect: Effect,
        own: &[(&str, f64, f64)],
        a1: f64,
        rms1: f64,
        heading: Option<&HeadingCheck>,
    ) -> Judgement {
        let data = SimSensor {
            noise: 10.0,
            ..Default::default()
        }
        .simulate()
        .unwrap();
        let current = fit(&PAPER_PARAMS, 0.02);
        let mut with: Vec<(&str, f64, f64)> = PAPER_PARAMS.to_vec();
        with[0].1 = a1;
        with.extend_from_slice(own);
        let candidate = fit(&with, rms1);
        let mut res = analyse(&data, &fit_model(&data, &effects::PAPER).unwrap());
        res.common.noise_floor.rms = 0.01;
        let params = own_params(&candidate, &current);
        judge(&Trial {
            data: &data,
            heading: [heading, heading, heading],
            effect: &effect,
            fit: &candidate,
            current: &current,
            res: &res,
            params: &params,
            delta_bic: -500.0,
            covered: 360.0,
            covered_now: 360.0,
        })
    }

    /// A candidate that lowers the rms only by shrinking the noise (its
    /// residual is the same white noise, 0.85 times as large) is refused as
    /// a squeeze; one with the same rms drop and the noise left alone is not.
    #[test]
    fn an_effect_that_only_squeezes_the_noise_is_not_supported() {
        let data = SimSensor {
            noise: 10.0,
            ..Default::default()
        }
        .simulate()
        .unwrap();
        let current = fit(&PAPER_PARAMS, 0.0105);
        let own = [("kc", -0.08, 0.004)];
        let mut with: Vec<(&str, f64, f64)> = PAPER_PARAMS.to_vec();
        with.extend_from_slice(&own);
        let mut squeezed = fit(&with, 0.0095);
        for e in &mut squeezed.residuals {
            *e *= 0.85;
        }
        let mut res = analyse(&data, &fit_model(&data, &effects::PAPER).unwrap());
        res.common.noise_floor.rms = residuals::noise_floor(&data, &current).rms;
        let effect = Effect::CubicCentred;
        // An 8 % cubic, with a gyro that checks the heading.
        let check = gyro_check();
        let judge_of = |candidate: &ModelFit| {
            let params = own_params(candidate, &current);
            judge(&Trial {
                data: &data,
                heading: [Some(&check); 3],
                effect: &effect,
                fit: candidate,
                current: &current,
                res: &res,
                params: &params,
                delta_bic: -200.0,
                covered: 360.0,
                covered_now: 360.0,
            })
        };
        let j = judge_of(&squeezed);
        assert!(!j.supported, "{}", j.evidence);
        assert!(j.evidence.contains("squeezing the noise"), "{}", j.evidence);
        let smooth = fit(&with, 0.0095);
        let j = judge_of(&smooth);
        assert!(j.supported, "{}", j.evidence);
    }

    #[test]
    fn a_physical_effect_that_matters_is_supported_with_its_numbers() {
        let check = gyro_check();
        let cubic = [("k_x", 0.03, 0.001), ("k_y", 0.0, 0.001)];
        let j = judged_checked(Effect::Cubic, &cubic, 1.0, 0.012, Some(&check));
        assert!(j.supported, "{}", j.evidence);
        assert!(
            j.evidence.contains("rms 2.00 % → 1.20 %")
                && j.evidence.contains("k_x = 0.0300 ± 0.00100"),
            "{}",
            j.evidence
        );
        // Within the datasheets' 1 %, no gyro is needed.
        let j = judged(
            Effect::Cubic,
            &[("k_x", 0.008, 0.0002), ("k_y", 0.0, 0.0002)],
            1.0,
            0.012,
        );
        assert!(j.supported, "{}", j.evidence);
    }

    /// Without a gyro to check what it does to the heading, a cubic is held
    /// to the datasheets' figure, and the evidence says which limit held.
    #[test]
    fn without_a_gyro_a_cubic_is_held_to_the_datasheet() {
        let cubic = [("k_x", 0.03, 0.001), ("k_y", 0.0, 0.001)];
        let j = judged(Effect::Cubic, &cubic, 1.0, 0.012);
        assert!(!j.supported);
        assert!(
            j.evidence.starts_with(
                "not a physical cubic: k_x = 0.0300 ± 0.00100 bends the reading by 3.0 % at full scale, beyond what the sensor's datasheet allows (limit 1 % at full scale with no gyro to check the heading"
            ),
            "{}",
            j.evidence
        );
        assert!(
            j.evidence
                .contains("with a gyro that checks the heading (--gyro) the limit is 10 %"),
            "{}",
            j.evidence
        );
        let j = judged(Effect::CubicCentred, &[("kc", -0.07, 0.002)], 1.0, 0.012);
        assert!(!j.supported);
        assert!(
            j.evidence
                .contains("by 7.0 % at full scale, beyond what the sensor's datasheet allows"),
            "{}",
            j.evidence
        );
        // The cross-axis limit is the same with or without a gyro.
        assert_eq!(
            limit_for("c", false).map(|l| l.max_abs),
            limit_for("c", true).map(|l| l.max_abs)
        );
        assert_eq!(
            limit_for("kc", false).map(|l| l.max_abs),
            Some(MAX_CUBIC_UNCHECKED)
        );
        assert_eq!(limit_for("kc", true).map(|l| l.max_abs), Some(MAX_CUBIC));
    }

    #[test]
    fn a_cubic_beyond_the_limit_is_not_physical() {
        let j = judged(
            Effect::Cubic,
            &[("k_x", -1.15, 0.02), ("k_y", 0.0, 0.01)],
            1.0,
            0.012,
        );
        assert!(!j.supported);
        assert!(
            j.evidence.starts_with("not a physical cubic: k_x = -1.15 ± 0.0200 bends the reading by 115.0 % at full scale"),
            "{}",
            j.evidence
        );
        // The centred cubic of the `cubic` branch is held to the same limit.
        assert_eq!(limit_of("kc").map(|l| l.max_abs), Some(MAX_CUBIC));
    }

    #[test]
    fn a_cross_axis_of_tens_of_degrees_is_not_physical() {
        assert!((MAX_CROSS_AXIS_SHEAR - MAX_CROSS_AXIS_DEG.to_radians().tan()).abs() < 1e-3);
        let j = judged(Effect::CrossAxis, &[("c", 0.5, 0.01)], 1.0, 0.012);
        assert!(!j.supported);
        assert!(
            j.evidence.contains("couples the axes by 26.6°"),
            "{}",
            j.evidence
        );
        let j = judged(Effect::CrossAxis, &[("c", 0.17, 0.01)], 1.0, 0.012);
        assert!(j.supported, "{}", j.evidence);
    }

    #[test]
    fn doubling_the_gain_ratio_is_not_physical() {
        let j = judged(Effect::Cubic, &[("k_x", 0.005, 0.0001)], 2.03, 0.012);
        assert!(!j.supported);
        assert!(
            j.evidence.contains("from 1.00 to 2.03 (×2.03)"),
            "{}",
            j.evidence
        );
    }

    #[test]
    fn a_covariate_within_its_standard_error_is_not_resolved() {
        let j = judged(
            Effect::Covariate("temp".into()),
            &[("temp_x", 0.3, 300.0), ("temp_y", -0.1, 250.0)],
            1.0,
            0.012,
        );
        assert!(!j.supported);
        assert!(j.evidence.starts_with("not resolved"), "{}", j.evidence);
    }

    #[test]
    fn a_detectable_effect_too_small_to_matter_is_not_suggested() {
        // ΔBIC -500 but the rms moves by 1 %.
        let j = judged(Effect::Cubic, &[("k_x", 0.01, 0.0001)], 1.0, 0.0198);
        assert!(!j.supported);
        assert!(
            j.evidence.starts_with("too small to matter"),
            "{}",
            j.evidence
        );
        // A 4 % drop explains 0.56 % of the field, over a quarter of the
        // 1 % noise floor.
        let j = judged(Effect::Cubic, &[("k_x", 0.01, 0.0001)], 1.0, 0.0192);
        assert!(j.supported, "{}", j.evidence);
    }
}
