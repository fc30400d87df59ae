//! Does a stored 3-D calibration hold on another recording?
//!
//! The 3-D counterpart of [`super::check`]: a calibration stored by
//! `fieldcal fit --json` on three axes, or by the daemon for a 3-axis
//! sensor (its state file's `calibration.ellipsoid`), is applied to another
//! recording of the same sensor. Reported: the magnitude rms of the stored
//! calibration there (|W(raw − o)|/r − 1), the sphere coverage of the new
//! recording, and, when that coverage determines the stored model, the
//! model refitted on the new recording with every free parameter next to
//! its stored value in standard errors, judged by the same Bonferroni rule
//! as in 2-D ([`super::check::moved_threshold`], 1 % family-wise).
//!
//! A recording that does not cover enough of the sphere to refit the
//! model (a turn on the floor, a few poses) still shows what the stored
//! calibration gives on it, but no parameter is compared and the verdict
//! says "not decided" with what is missing: a magnitude rms alone cannot
//! tell a moved offset along an axis the recording never pointed from a
//! good calibration.

use serde::Serialize;
use serde_json::Value;

use super::calibration3::{self, Calibration3D, Calibration3JsonError};
use super::check::{
    CheckError, FAMILY_FALSE_ALARM, ParamShift, StoredSource, lag1_autocorrelation, moved_text,
    moved_threshold, se_inflation, se_note,
};
use super::ellipsoid::{self, Ellipsoid3Error, Ellipsoid3Model, Ellipsoid3Se};
use super::sphere::{self, SphereCoverage};

/// The axis names of the parameters, as `diagnose` in 3-D names them.
const AXES: [&str; 3] = ["x", "y", "z"];

/// A stored 3-D calibration: calibrated = W·(raw − o), |calibrated| = r.
#[derive(Debug, Clone, PartialEq)]
pub struct Stored3 {
    pub source: StoredSource,
    pub model: Ellipsoid3Model,
    /// o, W (row-major, symmetric) and r.
    pub calibration: Calibration3D,
    /// The fit's standard errors, when the file holds them.
    pub se: Option<Ellipsoid3Se>,
    /// The rms the file reports on its own recording.
    pub rms: Option<f64>,
    /// The columns it was fitted to (`fit --json`), x, y, z.
    pub columns: Option<[String; 3]>,
    /// The raw readings' units, when the file says.
    pub units: Option<String>,
}

impl Stored3 {
    /// W·(raw − o).
    pub fn apply(&self, raw: [f64; 3]) -> [f64; 3] {
        self.calibration.correct(raw)
    }
}

fn unknown(problem: impl Into<String>) -> CheckError {
    CheckError::UnknownFormat {
        problem: problem.into(),
    }
}

fn invalid(problem: impl Into<String>) -> CheckError {
    CheckError::Invalid {
        problem: problem.into(),
    }
}

/// A JSON shape error of the stored offset or matrix, in `check`'s words.
fn shape(e: Calibration3JsonError) -> CheckError {
    unknown(e.to_string())
}

/// Whether a parsed JSON document holds a 3-D calibration: `fit --json`
/// with `"axes": 3`, or a daemon state file whose calibration has an
/// `ellipsoid`.
pub fn is_three_axes(root: &Value) -> bool {
    root.get("axes").and_then(Value::as_u64) == Some(3)
        || root
            .get("calibration")
            .and_then(|c| c.get("ellipsoid"))
            .is_some_and(|e| !e.is_null())
}

/// Reads a stored 3-D calibration from the JSON of `fieldcal fit --json`
/// on three axes or a daemon state file of a 3-axis sensor.
pub fn parse_stored3(root: &Value) -> Result<Stored3, CheckError> {
    let stored = if let Some(cal) = super::check::state_calibration(root)? {
        let e = cal
            .get("ellipsoid")
            .filter(|e| !e.is_null())
            .ok_or_else(|| unknown("a state file without calibration.ellipsoid"))?;
        let model_name = cal
            .get("model")
            .and_then(Value::as_str)
            .ok_or_else(|| unknown("no calibration.model"))?;
        let model = model_name.parse().map_err(invalid)?;
        let calibration = Calibration3D::from_json(
            e,
            [
                "calibration.ellipsoid.offset",
                "calibration.ellipsoid.matrix",
            ],
        )
        .map_err(shape)?;
        Stored3 {
            source: StoredSource::DaemonState,
            model,
            calibration,
            se: None,
            rms: cal.get("rms").and_then(Value::as_f64),
            columns: None,
            units: None,
        }
    } else {
        let params = root.get("params").ok_or_else(|| unknown("no 'params'"))?;
        // `fit --effects full+drift` (covariate, cubic): the extras need the
        // new recording's times and covariates the same way; refused by
        // name rather than applied as offset and W alone.
        if let Some(extra) = params
            .get("extra")
            .and_then(Value::as_object)
            .filter(|e| !e.is_empty())
        {
            let text = |field: &str, default: &str| {
                root.get(field)
                    .and_then(Value::as_str)
                    .unwrap_or(default)
                    .to_string()
            };
            return Err(invalid(format!(
                "its model {} has terms `check` does not compare in 3-D ({}); store the calibration of the model without them (`fieldcal fit FILE --x X --y Y --z Z --effects {} --json`)",
                text("model", "with effects"),
                extra.keys().cloned().collect::<Vec<_>>().join(", "),
                text("base_model", "full"),
            )));
        }
        let model_name = root
            .get("base_model")
            .or_else(|| root.get("model"))
            .and_then(Value::as_str)
            .ok_or_else(|| unknown("no 'model'"))?;
        let se = match root.get("se").filter(|s| !s.is_null()) {
            Some(s) => Some(Ellipsoid3Se {
                offset: calibration3::triple(s.get("offset"), "se.offset").map_err(shape)?,
                matrix: calibration3::matrix(s.get("matrix"), "se.matrix").map_err(shape)?,
                r: s.get("r")
                    .and_then(Value::as_f64)
                    .ok_or_else(|| unknown("se.r is not a number"))?,
            }),
            None => None,
        };
        let column = |name: &str| root.get(name).and_then(Value::as_str).map(str::to_string);
        let columns = match (column("x_column"), column("y_column"), column("z_column")) {
            (Some(x), Some(y), Some(z)) => Some([x, y, z]),
            _ => None,
        };
        let model = model_name.parse().map_err(invalid)?;
        let calibration =
            Calibration3D::from_json(params, ["params.offset", "params.matrix"]).map_err(shape)?;
        Stored3 {
            source: StoredSource::FitEffects,
            model,
            calibration,
            se,
            rms: root.get("rms").and_then(Value::as_f64),
            columns,
            units: root
                .get("units")
                .and_then(Value::as_str)
                .map(str::to_string),
        }
    };
    validate(&stored)?;
    Ok(stored)
}

/// A calibration that cannot be what a fit stored: non-finite numbers, a
/// radius not above zero, W not symmetric positive definite
/// ([`Calibration3D::validate`]).
fn validate(s: &Stored3) -> Result<(), CheckError> {
    s.calibration.validate().map_err(|e| invalid(e.to_string()))
}

/// The stored model refitted on the new recording.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Refit3 {
    pub rms: f64,
    pub n: usize,
    /// Each free parameter of the model: stored → refitted, z.
    pub parameters: Vec<ParamShift>,
    /// |z| beyond which a parameter is called moved.
    pub z_threshold: f64,
    /// Lag-1 autocorrelation of the refit's residuals in time order (0
    /// for white noise; near 1 when a slow error the model does not
    /// explain, or the hand's motion, runs through them).
    pub residual_autocorrelation: f64,
    /// The factor both standard errors are multiplied by before z:
    /// sqrt((1 + ρ)/(1 − ρ)), the variance inflation of a mean of AR(1)
    /// errors (1 for white noise). The fits' own SEs assume independent
    /// residuals; a tumble's smooth motion makes the parameters' sensitivities
    /// slow too, so correlated residuals count as fewer independent ones.
    pub se_inflation: f64,
}

/// What `fieldcal check` found for a 3-D calibration.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Check3Report {
    pub axes: u8,
    pub model: String,
    pub stored_source: StoredSource,
    pub stored_rms: Option<f64>,
    pub units: Option<String>,
    /// Samples of the new recording.
    pub n: usize,
    /// Magnitude rms of the stored calibration on the new recording.
    pub rms: f64,
    /// Mean |calibrated| / r on the new recording (1 when the field's
    /// magnitude and the gains are unchanged).
    pub magnitude_ratio: f64,
    /// Directions of the new recording, through the stored calibration.
    pub coverage: SphereCoverage,
    /// The refit, when the new recording determines the stored model.
    pub refit: Option<Refit3>,
    /// Why there is no refit.
    pub refit_refused: Option<String>,
    /// The richest model the new recording's directions support.
    pub supported_model: Option<String>,
    pub family_false_alarm: f64,
    /// Whether z used the stored file's standard errors too.
    pub stored_has_se: bool,
    /// True when no parameter moved; null when nothing could be compared.
    pub holds: Option<bool>,
    pub verdict: String,
}

/// The free parameters of `model`: (name, stored, stored SE, refitted,
/// refitted SE).
fn parameters(
    model: Ellipsoid3Model,
    stored: &Stored3,
    fit: &ellipsoid::Ellipsoid3Fit,
) -> Vec<(String, f64, f64, f64, f64)> {
    let stored_se = stored.se.unwrap_or(Ellipsoid3Se {
        offset: [f64::NAN; 3],
        matrix: [[f64::NAN; 3]; 3],
        r: f64::NAN,
    });
    let mut out = Vec::with_capacity(10);
    for (i, axis) in AXES.iter().enumerate() {
        out.push((
            format!("o_{axis}"),
            stored.calibration.offset[i],
            stored_se.offset[i],
            fit.offset[i],
            fit.se.offset[i],
        ));
    }
    let mut entry = |i: usize, j: usize| {
        out.push((
            format!("W_{}{}", AXES[i], AXES[j]),
            stored.calibration.matrix[i][j],
            stored_se.matrix[i][j],
            fit.matrix[i][j],
            fit.se.matrix[i][j],
        ));
    };
    if model != Ellipsoid3Model::Offset {
        for i in 0..3 {
            entry(i, i);
        }
    }
    if model == Ellipsoid3Model::Full {
        for (i, j) in [(0, 1), (0, 2), (1, 2)] {
            entry(i, j);
        }
    }
    out.push((
        "r".into(),
        stored.calibration.r,
        stored_se.r,
        fit.r,
        fit.se.r,
    ));
    out
}

/// What a parameter's move means, for the verdict.
fn meaning(name: &str) -> &'static str {
    match name.as_bytes().first() {
        Some(b'o') => "the offset (hard iron, zero-g bias) changed between runs",
        Some(b'W') if name.as_bytes().get(2) == name.as_bytes().get(3) => {
            "the relative gain of the axes changed"
        }
        Some(b'W') => "the cross-axis coupling (soft iron, mounting) changed",
        _ => "the field magnitude changed (another place, or every gain changed)",
    }
}

/// Applies `stored` to the raw readings `points` of another recording,
/// refits its model there when the directions determine it, and compares.
pub fn check3(points: &[[f64; 3]], stored: &Stored3) -> Result<Check3Report, CheckError> {
    if points.is_empty() {
        return Err(CheckError::Apply(crate::model::FitError::TooFewSamples {
            found: 0,
            unknowns: stored.model.unknowns(),
            needed: stored.model.unknowns() + 1,
        }));
    }
    let mut ss = 0.0;
    let mut sum = 0.0;
    let calibrated: Vec<[f64; 3]> = points.iter().map(|&p| stored.apply(p)).collect();
    for c in &calibrated {
        let m = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt() / stored.calibration.r;
        ss += (m - 1.0) * (m - 1.0);
        sum += m;
    }
    let n = points.len();
    let rms = (ss / n as f64).sqrt();
    let magnitude_ratio = sum / n as f64;
    let coverage = sphere::coverage(calibrated.iter().copied());
    let supported_model = ellipsoid::best_supported(&calibrated).map(|m| m.name().to_string());
    let stored_has_se = stored.se.is_some();
    let rms_text = format!(
        "rms {} with the stored calibration{}",
        crate::numfmt::percent(rms),
        stored
            .rms
            .map(|r| format!(" ({} on its own recording)", crate::numfmt::percent(r)))
            .unwrap_or_default()
    );
    let (refit, refit_refused) = match ellipsoid::fit(points, stored.model) {
        Ok(fit) => {
            let list = parameters(stored.model, stored, &fit);
            let z_threshold = moved_threshold(list.len());
            let residuals: Vec<f64> = points.iter().map(|&p| fit.magnitude_error(p)).collect();
            let rho = lag1_autocorrelation(&residuals);
            let f = se_inflation(rho);
            let parameters = list
                .into_iter()
                .map(|(name, s, s_se, new, new_se)| {
                    let mut shift = ParamShift::compare(
                        name,
                        (s, s_se * f),
                        (new, new_se * f),
                        stored_has_se,
                        z_threshold,
                    );
                    // Report the SEs as the fits gave them; z carries f.
                    shift.stored_se = shift.stored_se.map(|_| s_se);
                    shift.refitted_se = new_se;
                    shift
                })
                .collect();
            (
                Some(Refit3 {
                    rms: fit.rms,
                    n: fit.n,
                    parameters,
                    z_threshold,
                    residual_autocorrelation: rho,
                    se_inflation: f,
                }),
                None,
            )
        }
        Err(e) => (None, Some(e)),
    };
    let se_note = se_note(stored_has_se);
    let (holds, verdict) = match &refit {
        Some(refit) => {
            let se_note = format!(
                "{se_note}{}",
                super::check::inflation_note(
                    refit.se_inflation,
                    refit.residual_autocorrelation,
                    &refit.parameters,
                    refit.z_threshold
                )
            );
            if refit.parameters.iter().all(|p| !p.moved) {
                (
                    Some(true),
                    format!(
                        "{}: {rms_text}, {} fitted here; no parameter moved beyond {:.1} SE{se_note}",
                        super::check::holds_word(refit.se_inflation),
                        crate::numfmt::percent(refit.rms),
                        refit.z_threshold
                    ),
                )
            } else {
                (
                    Some(false),
                    format!(
                        "{}; recalibrate ({rms_text}, {} fitted here){se_note}",
                        moved_text(&refit.parameters, |name| meaning(name).to_string()),
                        crate::numfmt::percent(refit.rms)
                    ),
                )
            }
        }
        None => (
            None,
            undecided(
                &rms_text,
                refit_refused.as_ref(),
                coverage.fraction,
                stored.model,
            ),
        ),
    };
    Ok(Check3Report {
        axes: 3,
        model: stored.model.name().to_string(),
        stored_source: stored.source,
        stored_rms: stored.rms,
        units: stored.units.clone(),
        n,
        rms,
        magnitude_ratio,
        coverage,
        refit,
        refit_refused: refit_refused.map(|e| e.to_string()),
        supported_model,
        family_false_alarm: FAMILY_FALSE_ALARM,
        stored_has_se,
        holds,
        verdict,
    })
}

/// The verdict when the stored model could not be refitted to the new
/// recording: why (its coverage, or the refit's own error).
fn undecided(
    rms_text: &str,
    refused: Option<&Ellipsoid3Error>,
    coverage: f64,
    model: Ellipsoid3Model,
) -> String {
    match refused {
        Some(e) if !matches!(e, Ellipsoid3Error::NotCovered { .. }) => format!(
            "not decided: {rms_text}, but the {model} model could not be refitted to the new recording to compare its parameters: {e}"
        ),
        _ => format!(
            "not decided: {rms_text}, but the new recording covers {:.0} % of the sphere, too little to refit the {model} model and compare its parameters (a magnitude rms alone cannot show an offset moved along a direction the recording never pointed); tumble the sensor through the missing directions to check it",
            coverage * 100.0,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim3::{Motion3, SimSensor3};

    const SOFT_IRON: [[f64; 3]; 3] = [[1.2, 0.15, -0.1], [0.15, 0.85, 0.2], [-0.1, 0.2, 1.05]];
    const OFFSET_X: f64 = 0.3;

    fn tumble(seed: u64, offset_x: f64) -> Vec<[f64; 3]> {
        SimSensor3 {
            matrix: SOFT_IRON,
            offset: [offset_x, -0.2, 0.45],
            r: 0.5,
            noise: 0.002,
            n: 1500,
            motion: Motion3::Tumble {
                turns: 20.0,
                axis_path_rad: 10.0,
            },
            seed,
        }
        .simulate()
        .unwrap()
    }

    fn stored_of(points: &[[f64; 3]]) -> Stored3 {
        let fit = ellipsoid::fit(points, Ellipsoid3Model::Full).unwrap();
        Stored3 {
            source: StoredSource::FitEffects,
            model: fit.model,
            calibration: fit.calibration(),
            se: Some(fit.se),
            rms: Some(fit.rms),
            columns: None,
            units: None,
        }
    }

    #[test]
    fn the_same_sensor_holds_and_a_moved_offset_is_named() {
        let base = OFFSET_X;
        let stored = stored_of(&tumble(1, base));
        let same = check3(&tumble(2, base), &stored).unwrap();
        assert_eq!(same.holds, Some(true), "{}", same.verdict);
        assert_eq!(same.refit.as_ref().unwrap().parameters.len(), 10);
        let moved = check3(&tumble(2, base + 0.03 * stored.calibration.r), &stored).unwrap();
        assert_eq!(moved.holds, Some(false), "{}", moved.verdict);
        let names: Vec<&str> = moved
            .refit
            .as_ref()
            .unwrap()
            .parameters
            .iter()
            .filter(|p| p.moved)
            .map(|p| p.name.as_str())
            .collect();
        assert_eq!(names, ["o_x"], "{}", moved.verdict);
        assert!(
            moved.verdict.starts_with("o_x moved by"),
            "{}",
            moved.verdict
        );
    }

    #[test]
    fn a_half_sphere_is_not_decided_and_names_what_is_missing() {
        let stored = stored_of(&tumble(1, OFFSET_X));
        let upper: Vec<[f64; 3]> = tumble(3, OFFSET_X)
            .into_iter()
            .filter(|p| stored.apply(*p)[2] > 0.2 * stored.calibration.r)
            .collect();
        let report = check3(&upper, &stored).unwrap();
        assert_eq!(report.holds, None, "{}", report.verdict);
        assert!(report.refit.is_none());
        assert!(
            report.verdict.starts_with("not decided"),
            "{}",
            report.verdict
        );
        assert!(
            report.coverage.missing_text().contains("-z"),
            "{:?}",
            report.coverage
        );
        assert!(
            report.refit_refused.as_deref().unwrap().contains("-z"),
            "{report:?}"
        );
        // The stored calibration still applies: the rms is the noise's.
        assert!(report.rms < 3.0 * stored.rms.unwrap(), "{}", report.rms);
    }

    /// The same sensor in a field whose magnitude wanders slowly by 2 %
    /// (a hand carrying the board past iron): residuals correlated in time.
    fn wandering(seed: u64, phase: f64) -> Vec<[f64; 3]> {
        let points = tumble(seed, OFFSET_X);
        let o = [OFFSET_X, -0.2, 0.45];
        let n = points.len() as f64;
        points
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let k = 1.0 + 0.02 * (std::f64::consts::TAU * 3.0 * i as f64 / n + phase).sin();
                [0, 1, 2].map(|a| o[a] + (p[a] - o[a]) * k)
            })
            .collect()
    }

    #[test]
    fn residuals_correlated_in_time_widen_the_standard_errors() {
        let stored = stored_of(&wandering(1, 0.0));
        let report = check3(&wandering(2, 2.0), &stored).unwrap();
        let refit = report.refit.as_ref().unwrap();
        assert!(refit.residual_autocorrelation > 0.8, "{refit:?}");
        assert!(refit.se_inflation > 4.0, "{refit:?}");
        // With the fits' white-noise SEs some parameter would be called
        // moved; the sensor did not change, and the check says it holds.
        let white_max = refit
            .parameters
            .iter()
            .map(|p| p.z.abs() * refit.se_inflation)
            .fold(0.0, f64::max);
        assert!(white_max > refit.z_threshold, "{white_max}");
        assert_eq!(report.holds, Some(true), "{}", report.verdict);
        assert!(
            report.verdict.contains("correlated in time"),
            "{}",
            report.verdict
        );
        // White noise is left alone.
        let white = check3(&tumble(2, OFFSET_X), &stored_of(&tumble(1, OFFSET_X))).unwrap();
        let refit = white.refit.unwrap();
        assert!(refit.se_inflation < 1.1, "{refit:?}");
        assert_eq!(lag1_autocorrelation(&[1.0, 1.0, 1.0]), 0.0);
        assert_eq!(lag1_autocorrelation(&[1.0, -1.0, 1.0, -1.0]), 0.0);
    }

    #[test]
    fn a_matrix_that_is_no_calibration_is_refused() {
        let mut stored = stored_of(&tumble(1, 0.0));
        stored.calibration.matrix[0][1] += 0.5;
        assert!(matches!(validate(&stored), Err(CheckError::Invalid { .. })));
        let mut stored = stored_of(&tumble(1, 0.0));
        stored.calibration.matrix[2][2] = -1.0;
        assert!(validate(&stored).is_err());
        let mut stored = stored_of(&tumble(1, 0.0));
        stored.calibration.r = 0.0;
        assert!(validate(&stored).is_err());
    }
}
