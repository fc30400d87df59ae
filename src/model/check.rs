//! Does a stored calibration hold on the next run?
//!
//! A calibration stored by `fieldcal fit --json` (the paper's model or
//! `--effects`) or by the daemon (its state file) is applied to another
//! recording of the same sensor: its magnitude rms there, its heading error
//! against a gyro when one is given, and each parameter refitted on the new
//! recording (same model) next to the stored value, in standard errors.
//!
//! A parameter "moved" when |z| = |Δ| / sqrt(se_stored² + se_new²) exceeds
//! the Bonferroni threshold that keeps the family-wise false-alarm rate at
//! [`FAMILY_FALSE_ALARM`] over the parameters compared: two-sided, each at
//! `FAMILY_FALSE_ALARM / m`, so z = Φ⁻¹(1 − FAMILY_FALSE_ALARM / (2m))
//! (3.02 for the paper's four parameters). The standard errors are the fits'
//! own (least squares' covariance), which assume independent residuals.

use serde::Serialize;
use serde_json::Value;

use super::FitError;
use super::calibration::Terms;
use super::centred_split::{as_one_kc, fit_with_gyro};
use super::effects::{Effect, model_name, parse_list};
use super::fit::{FitOptions, fit_paper_turned};
use super::gyro::{GyroError, HeadingCheck, HeadingReference};
use super::heading::coverage;
use super::nonlinear::{KC_AXES, Param, TurnFrame, apply_model};
use super::paper::{PaperCalibration, closed_form_se};
use crate::sample::Dataset;

/// Probability that `check` calls any parameter moved when none did (two
/// runs of the same sensor), over all the parameters compared: 1 %.
pub const FAMILY_FALSE_ALARM: f64 = 0.01;

/// Where a stored calibration came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum StoredSource {
    /// `fieldcal fit --json` of the paper's model.
    FitPaper,
    /// `fieldcal fit --effects ... --json`.
    FitEffects,
    /// A daemon state file (`{"format":1,"calibration":{...}}`).
    DaemonState,
}

/// A calibration read back from a file.
#[derive(Debug, Clone, PartialEq)]
pub struct StoredCalibration {
    pub source: StoredSource,
    pub effects: Vec<Effect>,
    /// The model's parameters; `se` is NaN where the file holds none.
    pub params: Vec<Param>,
    /// The full scale the cubic `k` refers to, when the file says.
    pub cubic_scale: Option<f64>,
    /// The turn's frame the centred cubic `kc` refers to, when the file
    /// says (otherwise it is taken from the stored a, b, d, r).
    pub turn_frame: Option<TurnFrame>,
    /// The rms the file reports on its own recording.
    pub rms: Option<f64>,
}

impl StoredCalibration {
    /// The stored calibration applied to `data` ([`apply_model`]): `(s_x,
    /// s_y, e)` for every sample, in the frame and scale it was fitted in.
    pub fn apply(&self, data: &Dataset) -> Result<Vec<(f64, f64, f64)>, FitError> {
        apply_model(
            data,
            &self.effects,
            &self.params,
            self.cubic_scale,
            self.turn_frame.as_ref(),
        )
    }

    /// Whether the file gave standard errors for all its parameters.
    pub fn has_se(&self) -> bool {
        self.params.iter().all(|p| p.se.is_finite())
    }
}

/// Why a calibration could not be checked. The caller adds the file names.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CheckError {
    #[error(
        "not a calibration fieldcal knows ({problem}); expected the JSON of `fieldcal fit --json` (the paper's model or --effects) or a daemon state file ({{\"format\":1,\"calibration\":{{...}}}})"
    )]
    UnknownFormat { problem: String },
    #[error(
        "the stored calibration is not usable: {problem}; store it again with `fieldcal fit --json`"
    )]
    Invalid { problem: String },
    #[error("the new recording gives no calibration of the stored model: {0}")]
    Refit(FitError),
    #[error("the stored calibration cannot be applied to the new recording: {0}")]
    Apply(FitError),
    #[error(transparent)]
    Gyro(#[from] GyroError),
}

fn unknown(problem: impl Into<String>) -> CheckError {
    CheckError::UnknownFormat {
        problem: problem.into(),
    }
}

fn number(v: &Value, key: &str) -> Result<f64, CheckError> {
    v.get(key)
        .and_then(Value::as_f64)
        .ok_or_else(|| unknown(format!("no number '{key}'")))
}

fn paper_params(params: &Value) -> Result<Vec<Param>, CheckError> {
    ["a", "b", "d", "r"]
        .iter()
        .map(|name| {
            Ok(Param {
                name: (*name).into(),
                value: number(params, name)
                    .map_err(|_| unknown(format!("no number params.{name}")))?,
                se: f64::NAN,
            })
        })
        .collect()
}

/// The `calibration` of a daemon state file (one with a `format`), refused
/// when this fieldcal does not read its format; None for other JSON.
pub(super) fn state_calibration(root: &Value) -> Result<Option<&Value>, CheckError> {
    let Some(cal) = root
        .get("calibration")
        .filter(|_| root.get("format").is_some())
    else {
        return Ok(None);
    };
    let format = root.get("format").and_then(Value::as_u64);
    if format != Some(u64::from(super::calibration::FORMAT_VERSION)) {
        return Err(unknown(format!(
            "a state file of format {}, this fieldcal reads format {}",
            root["format"],
            super::calibration::FORMAT_VERSION
        )));
    }
    Ok(Some(cal))
}

/// A daemon state file's calibration as a stored calibration.
fn from_state(cal: &Value) -> Result<StoredCalibration, CheckError> {
    let calibration: super::calibration::Calibration = serde_json::from_value(cal.clone())
        .map_err(|e| unknown(format!("a state file whose calibration does not read: {e}")))?;
    let effects = parse_list(&calibration.model).map_err(unknown)?;
    let p = calibration.params;
    let mut params: Vec<Param> = [("a", p.a), ("b", p.b), ("d", p.d), ("r", p.r)]
        .into_iter()
        .map(|(name, value)| Param {
            name: name.into(),
            value,
            se: f64::NAN,
        })
        .collect();
    let t = calibration.terms;
    let mut push = |name: &str, value: f64| {
        params.push(Param {
            name: name.into(),
            value,
            se: f64::NAN,
        })
    };
    for effect in &effects {
        match effect {
            Effect::Offset | Effect::Scale | Effect::Outliers => {}
            Effect::CrossAxis => push("c", t.c),
            Effect::Cubic => {
                push("k_x", t.k[0]);
                push("k_y", t.k[1]);
            }
            Effect::CubicCentred if t.kc[0] == t.kc[1] => push("kc", t.kc[0]),
            Effect::CubicCentred => {
                push(KC_AXES[0], t.kc[0]);
                push(KC_AXES[1], t.kc[1]);
            }
            other => {
                return Err(CheckError::Invalid {
                    problem: format!(
                        "the state file's model '{}' has the effect '{other}', whose terms a state file does not store",
                        calibration.model
                    ),
                });
            }
        }
    }
    let centred = effects.contains(&Effect::CubicCentred);
    if centred && !t.turn_radius.iter().all(|r| r.is_finite() && *r > 0.0) {
        return Err(CheckError::Invalid {
            problem: format!(
                "the state file's cubic-centred term has turn_radius = {:?}: each must be a positive number (the turn's radius its kc refers to)",
                t.turn_radius
            ),
        });
    }
    Ok(StoredCalibration {
        source: StoredSource::DaemonState,
        effects,
        params,
        cubic_scale: (t.cubic_scale > 0.0).then_some(t.cubic_scale),
        turn_frame: centred.then_some(TurnFrame {
            centre: t.centre,
            radius: t.turn_radius,
        }),
        rms: Some(calibration.rms),
    })
}

/// Reads a stored calibration: `fit --json` of the paper's model or of
/// `--effects`, or a daemon state file.
pub fn parse_stored(bytes: &[u8]) -> Result<StoredCalibration, CheckError> {
    let root: Value =
        serde_json::from_slice(bytes).map_err(|e| unknown(format!("not JSON: {e}")))?;
    if !root.is_object() {
        return Err(unknown("the JSON is not an object"));
    }
    let stored = if let Some(cal) = state_calibration(&root)? {
        from_state(cal)?
    } else {
        let solver = root
            .get("solver")
            .and_then(Value::as_str)
            .ok_or_else(|| unknown("no 'solver', and no daemon 'format' and 'calibration'"))?;
        let params_value = root.get("params").ok_or_else(|| unknown("no 'params'"))?;
        match solver {
            "lsq" | "paper-gd" => {
                let mut params = paper_params(params_value)?;
                if let Some(list) = root.get("parameters").and_then(Value::as_array) {
                    for item in list {
                        let name = item.get("name").and_then(Value::as_str);
                        let se = item.get("se").and_then(Value::as_f64);
                        if let (Some(name), Some(se)) = (name, se)
                            && let Some(p) = params.iter_mut().find(|p| p.name == name)
                        {
                            p.se = se;
                        }
                    }
                }
                StoredCalibration {
                    source: StoredSource::FitPaper,
                    effects: crate::model::effects::PAPER.to_vec(),
                    params,
                    cubic_scale: None,
                    turn_frame: None,
                    rms: root.get("rms").and_then(Value::as_f64),
                }
            }
            "levenberg-marquardt" => {
                let model = root
                    .get("model")
                    .and_then(Value::as_str)
                    .ok_or_else(|| unknown("no 'model'"))?;
                let effects = parse_list(model).map_err(unknown)?;
                let map = params_value
                    .as_object()
                    .ok_or_else(|| unknown("'params' is not an object"))?;
                let se = root.get("se");
                let params = map
                    .iter()
                    .map(|(name, v)| {
                        Ok(Param {
                            name: name.clone(),
                            value: v
                                .as_f64()
                                .ok_or_else(|| unknown(format!("params.{name} is not a number")))?,
                            se: se
                                .and_then(|s| s.get(name))
                                .and_then(Value::as_f64)
                                .unwrap_or(f64::NAN),
                        })
                    })
                    .collect::<Result<Vec<_>, CheckError>>()?;
                StoredCalibration {
                    source: StoredSource::FitEffects,
                    effects,
                    params,
                    cubic_scale: root.get("cubic_scale").and_then(Value::as_f64),
                    turn_frame: root
                        .get("turn_frame")
                        .map(|v| serde_json::from_value(v.clone()))
                        .transpose()
                        .map_err(|e| unknown(format!("turn_frame does not read: {e}")))?,
                    rms: root.get("rms").and_then(Value::as_f64),
                }
            }
            other => return Err(unknown(format!("solver '{other}'"))),
        }
    };
    for p in &stored.params {
        if !p.value.is_finite() {
            return Err(CheckError::Invalid {
                problem: format!("{} = {} is not a finite number", p.name, p.value),
            });
        }
    }
    for name in ["a", "r"] {
        let v = stored
            .params
            .iter()
            .find(|p| p.name == name)
            .map_or(f64::NAN, |p| p.value);
        if !(v > 0.0) {
            return Err(CheckError::Invalid {
                problem: format!("{name} = {v} must be positive"),
            });
        }
    }
    // The same rules as a daemon's stored calibration, at the bounds of a
    // possible one (`fit` holds no acceptance limits, and a daemon's may be
    // wider than the defaults): a gain ratio of 1e308 or an offset of
    // 1.7e308 would only print null and inf.
    let (paper, terms) = paper_and_terms(&stored);
    if let Some(problem) = crate::model::validity::plane_problem(
        &paper,
        &terms,
        crate::model::validity::POSSIBLE_SCALE_RATIO,
        crate::model::validity::POSSIBLE_OFFSET_RATIO,
    ) {
        return Err(CheckError::Invalid { problem });
    }
    Ok(stored)
}

/// A stored calibration's paper constants and live terms, as a daemon
/// would hold them (0 where the model lacks a term).
fn paper_and_terms(stored: &StoredCalibration) -> (PaperCalibration, Terms) {
    let value = |name: &str| {
        stored
            .params
            .iter()
            .find(|p| p.name == name)
            .map_or(0.0, |p| p.value)
    };
    let kc = if stored.params.iter().any(|p| p.name == KC_AXES[0]) {
        [value(KC_AXES[0]), value(KC_AXES[1])]
    } else {
        [value("kc"); 2]
    };
    let frame = stored.turn_frame.unwrap_or(TurnFrame {
        centre: [0.0; 2],
        radius: [1.0; 2],
    });
    let terms = Terms {
        c: value("c"),
        k: [value("k_x"), value("k_y")],
        cubic_scale: stored.cubic_scale.unwrap_or(1.0),
        kc,
        centre: frame.centre,
        turn_radius: frame.radius,
    };
    let paper = PaperCalibration {
        a: value("a"),
        b: value("b"),
        d: value("d"),
        r: value("r"),
    };
    (paper, terms)
}

/// The inverse of the standard normal distribution function, by Acklam's
/// rational approximation (relative error below 1.2e-9), for p in (0, 1).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.38357751867269e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] = [
        -5.447609879822406e1,
        1.615858368580409e2,
        -1.556989798598866e2,
        6.680131188771972e1,
        -1.328068155288572e1,
    ];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [
        7.784695709041462e-3,
        3.224671290700398e-1,
        2.445134137142996,
        3.754408661907416,
    ];
    if !(p > 0.0 && p < 1.0) {
        return f64::NAN;
    }
    let tail = |q: f64| {
        ((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5]
    } / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0);
    if p < 0.02425 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// The |z| beyond which one of `m` parameters is called moved, keeping the
/// family-wise false alarm at [`FAMILY_FALSE_ALARM`] (Bonferroni, two-sided).
pub fn moved_threshold(m: usize) -> f64 {
    normal_quantile(1.0 - FAMILY_FALSE_ALARM / (2.0 * m.max(1) as f64))
}

/// One parameter: stored, refitted on the new recording, and how far apart.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamShift {
    pub name: String,
    pub stored: f64,
    /// Null when the stored file has no standard errors.
    pub stored_se: Option<f64>,
    pub refitted: f64,
    pub refitted_se: f64,
    /// (refitted − stored) / sqrt(stored_se² + refitted_se²), or over
    /// refitted_se alone without a stored one.
    pub z: f64,
    pub moved: bool,
}

impl ParamShift {
    /// One parameter compared: z = (refitted − stored) / sqrt(stored_se² +
    /// refitted_se²), or over refitted_se alone when `stored_has_se` is
    /// false; moved beyond `z_threshold`. A z that cannot be computed is
    /// not evidence of a move.
    pub fn compare(
        name: String,
        (stored, stored_se): (f64, f64),
        (refitted, refitted_se): (f64, f64),
        stored_has_se: bool,
        z_threshold: f64,
    ) -> ParamShift {
        let var = refitted_se * refitted_se
            + if stored_has_se {
                stored_se * stored_se
            } else {
                0.0
            };
        let delta = refitted - stored;
        let z = if var > 0.0 {
            delta / var.sqrt()
        } else if delta == 0.0 {
            0.0
        } else {
            f64::NAN
        };
        ParamShift {
            name,
            stored,
            stored_se: stored_has_se.then_some(stored_se),
            refitted,
            refitted_se,
            z,
            moved: z.abs() > z_threshold,
        }
    }
}

/// "o_x moved by 12.3 SE (100.0 → 130.1 ± 0.079): <meaning>; ..." for
/// every moved parameter, `meaning` saying what each move means.
pub fn moved_text(parameters: &[ParamShift], meaning: impl Fn(&str) -> String) -> String {
    let parts: Vec<String> = parameters
        .iter()
        .filter(|p| p.moved)
        .map(|p| {
            let by = if p.z.is_finite() {
                format!("by {:.1} SE", p.z.abs())
            } else {
                // A stored value so far off that the SE count overflows.
                "far beyond its standard errors".to_string()
            };
            format!(
                "{} moved {by} ({} → {} ± {}): {}",
                p.name,
                sig(p.stored),
                sig(p.refitted),
                crate::numfmt::significant(p.refitted_se, 2),
                meaning(&p.name)
            )
        })
        .collect();
    parts.join("; ")
}

/// The verdict's note when the stored file gave no standard errors.
pub fn se_note(stored_has_se: bool) -> &'static str {
    if stored_has_se {
        ""
    } else {
        " (the stored file has no standard errors: z uses the new fit's alone)"
    }
}

/// Most the SEs are inflated: ρ is clamped to 0.9998 (10 000 samples
/// counting as one), so a constant residual cannot divide by zero.
const MAX_RHO: f64 = 0.9998;

/// Lag-1 autocorrelation of `e` (0 when it is too short or constant),
/// clamped to [0, MAX_RHO]: a negative one would deflate the SEs, which
/// the fits' white-noise SEs do not warrant.
pub fn lag1_autocorrelation(e: &[f64]) -> f64 {
    if e.len() < 3 {
        return 0.0;
    }
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    let var: f64 = e.iter().map(|x| (x - mean) * (x - mean)).sum();
    if !(var > 0.0) {
        return 0.0;
    }
    let cov: f64 = e.windows(2).map(|w| (w[0] - mean) * (w[1] - mean)).sum();
    (cov / var).clamp(0.0, MAX_RHO)
}

/// sqrt((1 + ρ)/(1 − ρ)): the factor the fits' white-noise standard errors
/// are multiplied by before z when the residuals have lag-1
/// autocorrelation ρ (the variance inflation of a mean of AR(1) errors; a
/// smooth turn or tumble makes the parameters' sensitivities slow too, so
/// correlated residuals count as fewer independent ones). 1 for white
/// noise.
pub fn se_inflation(rho: f64) -> f64 {
    ((1.0 + rho) / (1.0 - rho)).sqrt()
}

/// The verdict's first words when nothing moved: plain "holds", or, when
/// correlated residuals left the recording able to see only large moves,
/// "holds within what this recording can tell".
pub fn holds_word(inflation: f64) -> &'static str {
    if inflation > 3.0 {
        "holds within what this recording can tell"
    } else {
        "holds"
    }
}

/// The verdict's note when the SEs were widened for correlated residuals:
/// the factor, and when it is large (the recording tells little), the
/// smallest move of each parameter the check could see (`z_threshold` ×
/// the widened combined SE), so that "holds" is not read as more than it is.
pub fn inflation_note(
    inflation: f64,
    rho: f64,
    parameters: &[ParamShift],
    z_threshold: f64,
) -> String {
    if inflation <= 1.05 {
        return String::new();
    }
    let mut note = format!(
        "; z uses the SEs × {inflation:.1}, as the residuals are correlated in time (lag-1 {rho:.2}: fewer independent samples than points)"
    );
    if inflation > 3.0 {
        let sizes: Vec<String> = parameters
            .iter()
            .map(|p| {
                let se = (p.refitted_se.powi(2) + p.stored_se.unwrap_or(0.0).powi(2)).sqrt();
                format!(
                    "{} {}",
                    p.name,
                    crate::numfmt::significant(z_threshold * inflation * se, 2)
                )
            })
            .collect();
        note.push_str(&format!(
            ": a smaller move than {} would not show",
            sizes.join(", ")
        ));
    }
    note
}

/// What `fieldcal check` found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CheckReport {
    pub model: String,
    pub stored_source: StoredSource,
    /// The rms the stored file reports on its own recording.
    pub stored_rms: Option<f64>,
    /// Magnitude rms (|s|/r − 1) of the stored calibration on the new recording.
    pub rms: f64,
    /// Magnitude rms of the model refitted on the new recording.
    pub refitted_rms: f64,
    /// Heading error of the stored calibration against the gyro.
    pub heading_vs_gyro: Option<HeadingCheck>,
    /// Heading error of the refitted model against the gyro.
    pub refitted_heading_vs_gyro: Option<HeadingCheck>,
    pub parameters: Vec<ParamShift>,
    /// |z| beyond which a parameter is called moved.
    pub z_threshold: f64,
    /// The family-wise false-alarm rate the threshold keeps.
    pub family_false_alarm: f64,
    /// Whether z used the stored file's standard errors too.
    pub stored_has_se: bool,
    /// Lag-1 autocorrelation of the refit's residuals in time order.
    pub residual_autocorrelation: f64,
    /// The factor both SEs were multiplied by before z ([`se_inflation`]).
    pub se_inflation: f64,
    /// True when no parameter moved.
    pub holds: bool,
    pub verdict: String,
}

/// What a parameter's move means, for the verdict.
fn meaning(name: &str) -> String {
    match name {
        "a" => "the gain ratio of the axes changed".into(),
        "b" | "d" => "the offset (hard iron, zero-g bias) changed between runs".into(),
        "r" => "the field magnitude changed (another place, or both gains changed)".into(),
        "c" => "the cross-axis coupling (soft iron, mounting) changed".into(),
        "k_x" | "k_y" | "kc" | "kc_x" | "kc_y" => "the non-linearity changed".into(),
        "drift_x" | "drift_y" => "the drift during the run differs".into(),
        other => format!("the term '{other}' changed"),
    }
}

/// Formats a number with 4 significant digits.
fn sig(v: f64) -> String {
    crate::numfmt::significant(v, 4)
}

/// The stored model refitted on the new recording.
struct Refit {
    /// Its parameters, with their standard errors.
    params: Vec<Param>,
    rms: f64,
    /// Every sample's heading.
    headings: Vec<f64>,
    /// The samples it set aside (the `outliers` effect).
    flagged: Vec<usize>,
    /// Its residuals over the samples it used, in input order.
    residuals: Vec<f64>,
}

/// Refits the stored model on `data`: the paper's closed form for a paper
/// calibration, the model's own fit otherwise (its centred cubic split per
/// axis where the gyro pins that down, as `fit` and `diagnose` do).
fn refit(
    data: &Dataset,
    stored: &StoredCalibration,
    reference: Option<&HeadingReference>,
    min_coverage_deg: f64,
) -> Result<Refit, CheckError> {
    let paper =
        stored.source == StoredSource::FitPaper || stored.effects.iter().all(Effect::is_paper);
    let (params, rms, headings, flagged, residuals) = if paper {
        let options = FitOptions {
            min_coverage_deg,
            ..FitOptions::default()
        };
        // `check` ran the turn gate on these samples before the refit.
        let report =
            fit_paper_turned(&data.x, &data.y, &options, &mut |_| {}).map_err(CheckError::Refit)?;
        let se = closed_form_se(&data.x, &data.y, &report.theta).unwrap_or(PaperCalibration {
            a: f64::NAN,
            b: f64::NAN,
            d: f64::NAN,
            r: f64::NAN,
        });
        let c = report.calibration;
        let params = super::calibration::paper_parameters(&c, Some(&se));
        let headings = data
            .x
            .iter()
            .zip(&data.y)
            .map(|(&x, &y)| c.heading(x, y))
            .collect::<Vec<_>>();
        let residuals: Vec<f64> = data
            .x
            .iter()
            .zip(&data.y)
            .map(|(&x, &y)| c.magnitude_error(x, y))
            .collect();
        (params, report.rms, headings, Vec::new(), residuals)
    } else {
        let fit = fit_with_gyro(data, &stored.effects, reference).map_err(CheckError::Refit)?;
        coverage(fit.headings.iter().copied())
            .require(min_coverage_deg)
            .map_err(CheckError::Refit)?;
        // The samples the refit set aside are not its residuals' series.
        let residuals = fit.used_residuals();
        (fit.params, fit.rms, fit.headings, fit.flagged, residuals)
    };
    Ok(Refit {
        params,
        rms,
        headings,
        flagged,
        residuals,
    })
}

/// Applies `stored` to `data`, refits its model there, and compares.
/// `min_coverage_deg`: the turn the refit needs, as for `fit`.
pub fn check(
    data: &Dataset,
    stored: &StoredCalibration,
    reference: Option<&HeadingReference>,
    min_coverage_deg: f64,
) -> Result<CheckReport, CheckError> {
    // A turn, or no check: the same gate as `fit` and `diagnose`.
    crate::model::turn::check_turn_of(data, min_coverage_deg).map_err(CheckError::Refit)?;
    let Refit {
        params: refitted,
        rms: refitted_rms,
        headings: refitted_headings,
        flagged,
        residuals: refit_residuals,
    } = refit(data, stored, reference, min_coverage_deg)?;
    let residual_autocorrelation = lag1_autocorrelation(&refit_residuals);
    let inflation = se_inflation(residual_autocorrelation);
    // The stored calibration on the new recording.
    let applied = stored.apply(data).map_err(CheckError::Apply)?;
    let mut skip = flagged.iter().copied().peekable();
    let (mut ss, mut n) = (0.0, 0usize);
    for (i, (_, _, e)) in applied.iter().enumerate() {
        while skip.peek().is_some_and(|&s| s < i) {
            skip.next();
        }
        if skip.peek() != Some(&i) {
            ss += e * e;
            n += 1;
        }
    }
    let rms = if n > 0 {
        (ss / n as f64).sqrt()
    } else {
        f64::NAN
    };
    let headings: Vec<f64> = applied.iter().map(|(sx, sy, _)| sy.atan2(*sx)).collect();
    let (heading, refitted_heading) = match reference {
        Some(r) => (
            Some(r.check(&headings, &flagged)?),
            Some(r.check(&refitted_headings, &flagged)?),
        ),
        None => (None, None),
    };

    let stored_has_se = stored.has_se();
    // A centred cubic split per axis on one side only (the gyro pinned the
    // split on one run and not the other, or one was checked without a
    // gyro) is compared as the one kc both have.
    let split = |params: &[Param]| params.iter().any(|p| p.name == KC_AXES[0]);
    let (stored_params, refitted) = if split(&stored.params) == split(&refitted) {
        (stored.params.clone(), refitted)
    } else {
        (as_one_kc(&stored.params), as_one_kc(&refitted))
    };
    let z_threshold = moved_threshold(stored_params.len());
    let parameters: Vec<ParamShift> = stored_params
        .iter()
        .filter_map(|s| {
            let new = refitted.iter().find(|p| p.name == s.name)?;
            let mut shift = ParamShift::compare(
                s.name.clone(),
                (s.value, s.se * inflation),
                (new.value, new.se * inflation),
                stored_has_se,
                z_threshold,
            );
            // Report the SEs as the fits gave them; z carries the inflation.
            shift.stored_se = shift.stored_se.map(|_| s.se);
            shift.refitted_se = new.se;
            Some(shift)
        })
        .collect();
    let moved: Vec<&ParamShift> = parameters.iter().filter(|p| p.moved).collect();
    let holds = moved.is_empty();
    let heading_text = heading
        .as_ref()
        .map(|h| format!(", heading {:.1}° rms against {}", h.rms_deg, h.gyro_column))
        .unwrap_or_default();
    let se_note = format!(
        "{}{}",
        se_note(stored_has_se),
        inflation_note(
            inflation,
            residual_autocorrelation,
            &parameters,
            z_threshold
        )
    );
    let verdict = if holds {
        format!(
            "{}: rms {} (fitted here {}){heading_text}; no parameter moved beyond {z_threshold:.1} SE{se_note}",
            holds_word(inflation),
            crate::numfmt::percent(rms),
            crate::numfmt::percent(refitted_rms)
        )
    } else {
        format!(
            "{}; recalibrate (rms {} with the stored calibration, {} fitted here{heading_text}){se_note}",
            moved_text(&parameters, meaning),
            crate::numfmt::percent(rms),
            crate::numfmt::percent(refitted_rms)
        )
    };
    Ok(CheckReport {
        model: model_name(&stored.effects),
        stored_source: stored.source,
        stored_rms: stored.rms,
        rms,
        refitted_rms,
        heading_vs_gyro: heading,
        refitted_heading_vs_gyro: refitted_heading,
        parameters,
        z_threshold,
        family_false_alarm: FAMILY_FALSE_ALARM,
        stored_has_se,
        residual_autocorrelation,
        se_inflation: inflation,
        holds,
        verdict,
    })
}
