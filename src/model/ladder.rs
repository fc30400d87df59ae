//! The diagnosis ladder, written once for both geometries: which effects
//! are candidates, the gates a candidate must pass, how candidates are
//! ranked, the climb from the baseline one supported effect at a time, the
//! verdict on what remains, and the evidence sentences built from the
//! numbers that decided each.
//!
//! A geometry ([`super::diagnose`] on the circle of a turn,
//! [`super::diagnose3`] on the sphere of a tumble) brings only what is its
//! own, through [`Geometry`] and [`Gates`]: its fit and residual analysis,
//! which effects it can offer, and the tests that depend on its shape: the
//! fold of the calibrated samples, the physical limits of an effect's
//! parameters, how far an effect may move the gains, and the noise floor of
//! a candidate's residual. Everything else (the order of the gates, the
//! criterion's numbers, the wording) lives here, so the two diagnoses
//! cannot drift apart.

use serde::Serialize;

use super::diagnose::{
    BIC_MARGIN, EXTREME_SDS, MAX_STEPS, MIN_EXPLAINED_NOISE, MIN_RMS_DROP, MIN_STRUCTURE_SHARE,
    NOISE_TOLERANCE, params_text, tail_threshold,
};
use super::effects::Effect;
use super::nonlinear::Param;
use super::residuals::{GAUSSIAN_TAIL_4SD, NoiseFloor, ResidualCommon};

/// An rms below this is rounding, not noise or structure.
pub(crate) const NUMERICAL_RMS: f64 = 1e-12;
/// A harmonic of heading, a pattern over direction or a trend counts as
/// structure in the verdict when it exceeds this many standard errors of a
/// Gaussian-noise estimate.
pub(crate) const STRUCTURE_SES: f64 = 5.0;

/// An effect of the catalogue a recording cannot determine, and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NotDetermined {
    pub effect: Effect,
    pub reason: String,
}

/// What the ladder reads of a fit, in either geometry.
pub(crate) trait LadderFit {
    /// Rms over the used (not flagged) samples.
    fn rms(&self) -> f64;
    /// Residual sum of squares over the used samples.
    fn rss(&self) -> f64;
    /// Unknowns of the model, flagged samples not counted.
    fn unknowns(&self) -> usize;
    /// Samples flagged as outliers (the `outliers` effect).
    fn flagged(&self) -> usize;
    /// Every fitted parameter, with its standard error.
    fn params(&self) -> &[Param];
    /// Samples fitted.
    fn samples(&self) -> usize;
}

/// What the gates and the verdict read of a residual, in either geometry.
pub(crate) trait ResidualStats {
    fn common(&self) -> &ResidualCommon;
}

/// What the ladder reads of a ranked candidate.
pub(crate) trait Ranked {
    fn effect(&self) -> &Effect;
    fn supported(&self) -> bool;
    fn delta_bic(&self) -> f64;
}

/// Implements [`LadderFit`] and [`ResidualStats`] for a geometry's fit
/// and residual types, whose fields share the ladder's names (`rms`,
/// `rss`, `unknowns`, `flagged`, `params`; `common`).
macro_rules! ladder_types {
    ($fit:ty, $residuals:ty) => {
        impl $crate::model::ladder::LadderFit for $fit {
            fn rms(&self) -> f64 {
                self.rms
            }
            fn rss(&self) -> f64 {
                self.rss
            }
            fn unknowns(&self) -> usize {
                self.unknowns
            }
            fn flagged(&self) -> usize {
                self.flagged.len()
            }
            fn params(&self) -> &[$crate::model::nonlinear::Param] {
                &self.params
            }
            fn samples(&self) -> usize {
                self.n
            }
        }

        impl $crate::model::ladder::ResidualStats for $residuals {
            fn common(&self) -> &$crate::model::residuals::ResidualCommon {
                &self.common
            }
        }
    };
}
pub(crate) use ladder_types;

/// One geometry of the diagnosis: its fit, its residual, its steps and
/// candidates, and which effects it can offer a model.
pub(crate) trait Geometry: Sync {
    type Fit: LadderFit + Sync;
    type Residuals: ResidualStats + Clone + Sync;
    type Step: Clone + Sync;
    type Candidate: Ranked + Send;
    type Error;

    /// Fits the model of `effects` to the recording.
    fn fit(&self, effects: &[Effect]) -> Result<Self::Fit, Self::Error>;
    /// The residual statistics of a fit.
    fn analyse(&self, fit: &Self::Fit) -> Self::Residuals;
    /// BIC of a fit, flagged samples counted as unknowns ([`bic`]).
    fn bic(&self, fit: &Self::Fit) -> f64;
    /// The ladder's record of a fitted model.
    fn step(&self, fit: &Self::Fit, model: &[Effect]) -> Self::Step;
    /// The effects a model could add, and those the recording cannot
    /// determine (with why).
    fn offered(&self, model: &[Effect], current: &Self::Fit) -> (Vec<Effect>, Vec<NotDetermined>);
    /// What a candidate that could not be fitted becomes: a note of why it
    /// is not determined, or nothing.
    fn no_fit(&self, effect: Effect, err: Self::Error) -> Option<NotDetermined>;
    /// Judges one fitted candidate (through [`judge`] with the geometry's
    /// [`Gates`]) and records it.
    fn candidate(&self, offer: Offer<'_, Self>) -> Self::Candidate;
}

/// One fitted candidate, as [`Geometry::candidate`] receives it.
pub(crate) struct Offer<'a, G: Geometry + ?Sized> {
    pub effect: Effect,
    pub fit: &'a G::Fit,
    /// The model it is added to.
    pub current: &'a G::Fit,
    /// The current model's residual.
    pub res: &'a G::Residuals,
    /// The ladder's first step and the current model's.
    pub baseline: &'a G::Step,
    pub now: &'a G::Step,
    /// The effect's own parameters: those `fit` has that `current` lacks.
    pub params: Vec<Param>,
    pub delta_bic: f64,
}

/// One effect the model could add, as judged on the current model. `X`
/// is what the geometry adds: the 2-D heading against a gyro, nothing in
/// 3-D ([`Nothing`]); its keys stand before `evidence` in the JSON.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Candidate<X> {
    pub effect: Effect,
    /// Rms the model reaches with this effect added (over the used samples).
    pub rms: f64,
    /// Rms of the model it was added to.
    pub rms_before: f64,
    /// Share of the model's mean-square residual the effect explains,
    /// 1 − rms²/rms_before².
    pub explained: f64,
    /// The effect's own fitted parameters, with standard errors.
    pub params: Vec<Param>,
    /// Unknowns the effect adds; for `outliers`, the flagged samples (each
    /// costs one unknown in the mean-shift outlier model).
    pub unknowns_added: usize,
    /// BIC with the effect minus BIC without: negative is better.
    pub delta_bic: f64,
    /// Whether the data supports it: ΔBIC below -[`BIC_MARGIN`] (and the
    /// tail gate for `outliers`), material, within the physical limits,
    /// resolved above its standard errors, and not folding the data.
    pub supported: bool,
    #[serde(flatten)]
    pub extra: X,
    /// Why: built from the numbers that decided `supported`.
    pub evidence: String,
}

/// Nothing added to a candidate (a 3-D one).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Nothing {}

impl<X> Ranked for Candidate<X> {
    fn effect(&self) -> &Effect {
        &self.effect
    }
    fn supported(&self) -> bool {
        self.supported
    }
    fn delta_bic(&self) -> f64 {
        self.delta_bic
    }
}

impl<G: Geometry + ?Sized> Offer<'_, G> {
    /// The candidate this offer is, judged `supported` for `evidence`, with
    /// what the geometry adds.
    pub fn candidate<X>(self, supported: bool, evidence: String, extra: X) -> Candidate<X> {
        Candidate {
            rms: self.fit.rms(),
            rms_before: self.current.rms(),
            explained: self.explained(),
            unknowns_added: self.unknowns_added(),
            delta_bic: self.delta_bic,
            supported,
            extra,
            evidence,
            params: self.params,
            effect: self.effect,
        }
    }

    /// Share of the current model's mean-square residual the candidate
    /// explains.
    pub fn explained(&self) -> f64 {
        explained(self.current.rms(), self.fit.rms()).0
    }

    /// Unknowns the candidate adds; for `outliers`, the flagged samples.
    pub fn unknowns_added(&self) -> usize {
        (self.fit.unknowns() + self.fit.flagged())
            .saturating_sub(self.current.unknowns() + self.current.flagged())
    }

    /// The numbers [`judge`] reads.
    pub fn scores(&self) -> Scores<'_> {
        Scores {
            effect: &self.effect,
            rms_before: self.current.rms(),
            rms_after: self.fit.rms(),
            params: &self.params,
            delta_bic: self.delta_bic,
            res: self.res,
            flagged: self.fit.flagged(),
        }
    }
}

/// BIC, `n·ln(RSS/n) + p·ln(n)`, of a fit over all `n` samples with `p`
/// unknowns (flagged samples count as unknowns).
pub(crate) fn bic(n: usize, unknowns: usize, rss: f64) -> f64 {
    let n = n.max(1) as f64;
    let p = unknowns as f64;
    // A perfect fit would give ln(0): floor the RSS far below any noise.
    let rss = rss.max(n * 1e-30);
    n * (rss / n).ln() + p * n.ln()
}

/// `model` with `effect` added, sorted. An effect already in the model is
/// not added twice (no caller offers one: every candidate is an effect the
/// model lacks).
pub(crate) fn with_effect(model: &[Effect], effect: &Effect) -> Vec<Effect> {
    let mut effects = model.to_vec();
    if !effects.contains(effect) {
        effects.push(effect.clone());
    }
    effects.sort();
    effects
}

/// The model a list of effects asks for, always with the paper's
/// `offset+scale`.
pub(crate) fn starting_list(baseline: &[Effect]) -> Vec<Effect> {
    let mut model = super::effects::PAPER.to_vec();
    for e in baseline {
        if !model.contains(e) {
            model.push(e.clone());
        }
    }
    model.sort();
    model
}

/// The parameters `fit` has that `current` lacks: the added effect's own.
/// The centred cubic's `kc` and its split `kc_x`, `kc_y` are one term
/// (model/centred_split.rs: the gyro may split it in one model and not in
/// the next).
pub(crate) fn own_params<F: LadderFit>(fit: &F, current: &F) -> Vec<Param> {
    fn term(name: &str) -> &str {
        match name {
            "kc_x" | "kc_y" => "kc",
            other => other,
        }
    }
    fit.params()
        .iter()
        .filter(|p| {
            !current
                .params()
                .iter()
                .any(|q| term(&q.name) == term(&p.name))
        })
        .cloned()
        .collect()
}

/// Explained share of the mean-square residual, and explained amplitude.
pub(crate) fn explained(rms_before: f64, rms_after: f64) -> (f64, f64) {
    let (before, after) = (rms_before * rms_before, rms_after * rms_after);
    let share = if before > 0.0 {
        1.0 - after / before
    } else {
        0.0
    };
    (share, (before - after).max(0.0).sqrt())
}

/// The span of the values (0 for none).
pub(crate) fn range(values: &[f64]) -> f64 {
    let (lo, hi) = values
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(*v), hi.max(*v))
        });
    if hi >= lo { hi - lo } else { 0.0 }
}

pub(crate) fn percent(fraction: f64) -> String {
    format!("{:.2} %", fraction * 100.0)
}

/// Whether the tails of a residual are too heavy for Gaussian noise.
pub(crate) fn tails_heavy<R: ResidualStats + ?Sized>(res: &R) -> bool {
    let n = res.common().tail_expected / GAUSSIAN_TAIL_4SD;
    res.common().tail_count >= tail_threshold(res.common().tail_expected)
        || (res.common().tail_count >= 1 && res.common().tail_max_sd > EXTREME_SDS && n < 100_000.0)
}

/// What decided one candidate.
pub(crate) struct Judgement {
    pub supported: bool,
    pub evidence: String,
}

/// The numbers every geometry judges a candidate by.
pub(crate) struct Scores<'a> {
    pub effect: &'a Effect,
    /// Rms of the model the candidate is added to, and with it.
    pub rms_before: f64,
    pub rms_after: f64,
    /// The effect's own parameters.
    pub params: &'a [Param],
    pub delta_bic: f64,
    /// The current model's residual: its tails and noise floor.
    pub res: &'a dyn ResidualStats,
    /// Samples the candidate flags (the `outliers` effect).
    pub flagged: usize,
}

/// The tests of a candidate that depend on the geometry. Each returns the
/// evidence of a refusal, or None when the candidate passes.
pub(crate) trait Gates {
    /// Whether the fit folds the calibrated samples (a turn onto an arc,
    /// the sphere onto a cap) rather than finding an effect.
    fn fold(&self) -> Option<String>;
    /// Whether the effect's fitted size is one a physical cause produces:
    /// its parameters' limits and the swing of a moving offset. `numbers`
    /// is the rms and ΔBIC summary, `with_params` the same with the
    /// parameters.
    fn physical(&self, numbers: &str, with_params: &str) -> Option<String>;
    /// Whether the effect moves the gains more than any effect of the
    /// catalogue at its limit.
    fn gain(&self, with_params: &str) -> Option<String>;
    /// The noise floor of the candidate's own residual.
    fn candidate_floor(&self) -> f64;
    /// What the squeeze evidence says after the two floors.
    fn squeeze_note(&self) -> &'static str;
    /// Tests after the common ones (the heading against a gyro);
    /// `rms_before`, `rms_after` as in [`Scores`].
    fn heading(&self, rms_before: f64, rms_after: f64, with_params: &str) -> Option<String>;
}

/// Judges a candidate, first failing reason first; the evidence is made of
/// the numbers that decided it.
pub(crate) fn judge(t: &Scores<'_>, gates: &dyn Gates) -> Judgement {
    let (rms0, rms1) = (t.rms_before, t.rms_after);
    let (share, amplitude) = explained(rms0, rms1);
    let numbers = format!(
        "rms {} → {}, {:.1} % of the residual variance, ΔBIC {:.1}",
        percent(rms0),
        percent(rms1),
        share * 100.0,
        t.delta_bic
    );
    let with_params = if t.params.is_empty() {
        numbers.clone()
    } else {
        format!("{numbers}; {}", params_text(t.params))
    };
    let refuse = |evidence: String| Judgement {
        supported: false,
        evidence,
    };
    let shape = gates
        .fold()
        .or_else(|| gates.physical(&numbers, &with_params))
        .or_else(|| gates.gain(&with_params));
    if let Some(evidence) = shape {
        return refuse(evidence);
    }
    if !t.params.is_empty() && t.params.iter().all(|p| !(p.value.abs() > p.se)) {
        return refuse(format!(
            "not resolved: no parameter of {} stands above its standard error ({}); {numbers}",
            t.effect,
            params_text(t.params)
        ));
    }
    if !(t.delta_bic < -BIC_MARGIN) {
        return refuse(format!(
            "not detectable: ΔBIC {:.1} does not reach -{BIC_MARGIN}; {with_params}",
            t.delta_bic
        ));
    }
    if *t.effect == Effect::Outliers && !tails_heavy(t.res) {
        return refuse(format!(
            "no outliers: {} beyond 4 robust SD (the furthest at {:.1}) where Gaussian noise would give {:.2}; {numbers}",
            crate::sample::count(t.res.common().tail_count as u64, "sample"),
            t.res.common().tail_max_sd,
            t.res.common().tail_expected
        ));
    }
    let drop = if rms0 > 0.0 { 1.0 - rms1 / rms0 } else { 0.0 };
    if drop < MIN_RMS_DROP {
        return refuse(format!(
            "too small to matter: it lowers the rms by {:.2} % (under {:.0} %); {with_params}",
            drop * 100.0,
            MIN_RMS_DROP * 100.0
        ));
    }
    let floor = t.res.common().noise_floor.rms;
    if amplitude < MIN_EXPLAINED_NOISE * floor {
        return refuse(format!(
            "too small to matter: it explains {} of the field, under a quarter of the noise floor {}; {with_params}",
            percent(amplitude),
            percent(floor)
        ));
    }
    if *t.effect != Effect::Outliers {
        let (floor0, floor1) = (floor, gates.candidate_floor());
        let total = rms0 * rms0 - rms1 * rms1;
        let from_noise = floor0 * floor0 - floor1 * floor1;
        if total > 0.0 && total - from_noise < MIN_STRUCTURE_SHARE * total {
            return refuse(format!(
                "not an effect: it lowers the rms by squeezing the noise, not by removing structure ({:.0} % of what it explains comes out of the noise floor, {} → {}{}); {with_params}",
                (from_noise / total * 100.0).min(100.0),
                percent(floor0),
                percent(floor1),
                gates.squeeze_note()
            ));
        }
    }
    if let Some(evidence) = gates.heading(rms0, rms1, &with_params) {
        return refuse(evidence);
    }
    let extra = if *t.effect == Effect::Outliers {
        format!(
            "; {} flagged, {} beyond 4 robust SD (the furthest at {:.1}) where Gaussian noise would give {:.2}",
            crate::sample::count(t.flagged as u64, "sample"),
            t.res.common().tail_count,
            t.res.common().tail_max_sd,
            t.res.common().tail_expected
        )
    } else {
        String::new()
    };
    Judgement {
        supported: true,
        evidence: format!(
            "explains {} of the field: {with_params}{extra}",
            percent(amplitude)
        ),
    }
}

/// Samples from which [`rank`] fits the candidates on every core. A
/// candidate's fit costs about 0.4 µs a sample (2-D, `cargo bench --bench
/// fit`, "diagnosis of one rotation"), starting and joining a thread some
/// 50 µs: from 5,000 samples a fit takes 2 ms, forty times that.
const PARALLEL_FROM_SAMPLES: usize = 5_000;

/// Fits and ranks every candidate against `current` (already fitted):
/// supported ones first, then by ΔBIC. Also returns the effects the
/// recording cannot determine.
pub(crate) fn rank<G: Geometry>(
    g: &G,
    model: &[Effect],
    current: (&G::Fit, &G::Step),
    baseline: &G::Step,
    res: &G::Residuals,
) -> (Vec<G::Candidate>, Vec<NotDetermined>) {
    let (current, now) = current;
    let base_bic = g.bic(current);
    let (offered, mut refused) = g.offered(model, current);
    // What became of one offered effect.
    enum Tried<C> {
        Fitted(C),
        Refused(Option<NotDetermined>),
        NotFinite,
    }
    let try_one = |effect: &Effect| {
        let fit = match g.fit(&with_effect(model, effect)) {
            Ok(fit) if fit.rms().is_finite() && fit.rss().is_finite() => fit,
            Ok(_) => return Tried::NotFinite,
            Err(err) => return Tried::Refused(g.no_fit(effect.clone(), err)),
        };
        let delta_bic = g.bic(&fit) - base_bic;
        let params = own_params(&fit, current);
        Tried::Fitted(g.candidate(Offer {
            effect: effect.clone(),
            fit: &fit,
            current,
            res,
            baseline,
            now,
            params,
            delta_bic,
        }))
    };
    // The candidates are fitted on every core, one fit per core alive at
    // once, each judged where it was fitted so that only its judgement is
    // kept; a short recording's (one turn, as the daemon diagnoses in its
    // loop) on this thread, where starting threads would cost more than
    // they save.
    let tried: Vec<Tried<G::Candidate>> = if current.samples() >= PARALLEL_FROM_SAMPLES {
        crate::parallel::map_in_order(&offered, try_one)
    } else {
        offered.iter().map(try_one).collect()
    };
    let mut candidates: Vec<G::Candidate> = Vec::new();
    for tried in tried {
        match tried {
            Tried::Fitted(candidate) => candidates.push(candidate),
            Tried::Refused(note) => refused.extend(note),
            Tried::NotFinite => {}
        }
    }
    candidates.sort_by(|a, b| {
        b.supported()
            .cmp(&a.supported())
            .then(a.delta_bic().total_cmp(&b.delta_bic()))
    });
    (candidates, refused)
}

/// The ladder climbed: the candidates on the baseline, what was suggested,
/// and every model added until none was supported.
pub(crate) struct Climb<Step, Candidate, Fit, Residuals> {
    pub baseline: Step,
    /// Ranked on the baseline, best first.
    pub candidates: Vec<Candidate>,
    pub not_determined: Vec<NotDetermined>,
    pub suggested: Option<Effect>,
    /// A supported effect within [`BIC_MARGIN`] of the suggested one.
    pub close_second: Option<Effect>,
    /// Baseline, then each added effect, in order.
    pub ladder: Vec<Step>,
    /// The last model's fit and residual.
    pub last: Fit,
    pub final_residuals: Residuals,
}

/// Climbs the ladder from the baseline `model` (fitted as `base_fit`, with
/// residual `baseline_residuals`): ranks the candidates, adds the best
/// supported one, and repeats until none is supported (at most
/// [`MAX_STEPS`] effects).
pub(crate) fn climb<G: Geometry>(
    g: &G,
    mut model: Vec<Effect>,
    base_fit: G::Fit,
    baseline_residuals: &G::Residuals,
) -> Climb<G::Step, G::Candidate, G::Fit, G::Residuals> {
    let baseline = g.step(&base_fit, &model);
    let (candidates, not_determined) = rank(
        g,
        &model,
        (&base_fit, &baseline),
        &baseline,
        baseline_residuals,
    );
    let suggested = candidates
        .first()
        .filter(|c| c.supported())
        .map(|c| c.effect().clone());
    let close_second = match candidates.as_slice() {
        [first, second, ..] if first.supported() && second.supported() => {
            (second.delta_bic() - first.delta_bic() < BIC_MARGIN).then(|| second.effect().clone())
        }
        _ => None,
    };

    let mut ladder = vec![baseline.clone()];
    let mut current = base_fit;
    let mut current_res = baseline_residuals.clone();
    let mut next = suggested.clone();
    while let Some(effect) = next.take() {
        if ladder.len() > MAX_STEPS {
            break;
        }
        let effects = with_effect(&model, &effect);
        let Ok(fit) = g.fit(&effects) else {
            break;
        };
        model = effects;
        current_res = g.analyse(&fit);
        let step = g.step(&fit, &model);
        next = rank(g, &model, (&fit, &step), &baseline, &current_res)
            .0
            .into_iter()
            .find(|c| c.supported())
            .map(|c| c.effect().clone());
        ladder.push(step);
        current = fit;
    }
    Climb {
        baseline,
        candidates,
        not_determined,
        suggested,
        close_second,
        ladder,
        last: current,
        final_residuals: current_res,
    }
}

/// Noise, or where structure remains. `patterns` names the structure of
/// the geometry's own shape (harmonics of heading, patterns over
/// direction); `blame` joins every place found (given the rms's excess
/// over the floor) into what the verdict says remains.
pub(crate) fn verdict<R: ResidualStats + ?Sized>(
    rms: f64,
    res: &R,
    floor: &NoiseFloor,
    patterns: impl FnOnce() -> Vec<String>,
    blame: impl FnOnce(Vec<String>, f64) -> String,
) -> String {
    // Noiseless data fits to rounding: no floor to compare with, and
    // nothing left to explain.
    if rms < NUMERICAL_RMS {
        return format!(
            "what remains is noise: the rms {rms:.1e} is at the level of rounding; the data has no measurable noise"
        );
    }
    let excess = if floor.rms > 0.0 {
        rms / floor.rms - 1.0
    } else {
        f64::INFINITY
    };
    if excess <= NOISE_TOLERANCE {
        let relation = if excess <= 0.0 {
            "at or below".to_string()
        } else {
            format!("within {:.0} % of", excess * 100.0)
        };
        return format!(
            "what remains is noise: the rms {} is {relation} the noise floor {}",
            percent(rms),
            percent(floor.rms)
        );
    }
    let mut places = patterns();
    if let Some(s) = res.common().time_structure.filter(|s| *s > 0.3) {
        places.push(format!(
            "slow wander in time ({:.0} % of the variance)",
            s * 100.0
        ));
    }
    for c in res
        .common()
        .covariates
        .iter()
        .filter(|c| c.correlation.abs() > 0.5)
    {
        places.push(format!("{} (correlation {:.2})", c.column, c.correlation));
    }
    if tails_heavy(res) {
        places.push(format!(
            "{} beyond 4 robust SD",
            crate::sample::count(res.common().tail_count as u64, "sample")
        ));
    }
    let where_ = blame(places, excess);
    format!(
        "structure remains that no effect in the catalogue explains: {where_} (rms {} is {:.0} % above the noise floor {})",
        percent(rms),
        excess * 100.0,
        percent(floor.rms)
    )
}
