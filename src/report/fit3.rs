//! The report of `fieldcal fit` on three axes: the ellipsoid model
//! (docs/three-axes.md), as text and as the JSON every 3-D reader shares.

use std::collections::BTreeMap;

use serde::Serialize;

use super::fit::FlaggedJson;
use super::significant;
use crate::model::effects::{Effect, model_name};
use crate::model::ellipsoid::{Ellipsoid3Fit, Ellipsoid3Model, Ellipsoid3Se};
use crate::model::nonlinear::Param;
use crate::model::sphere::SphereCoverage;
use crate::model::still::{STILL_WINDOW_S, StillPoses};

/// Where the fitted samples came from.
#[derive(Debug, Clone, Copy)]
pub struct Fit3Source<'a> {
    pub file: &'a str,
    pub x_column: &'a str,
    pub y_column: &'a str,
    pub z_column: &'a str,
}

/// The unit of the readings when the user names none: `g` when the three
/// columns are an accelerometer's (their names start with `acc`, as the
/// MPU-6050's `acc_x`, `accel_y`, `AccZ`), else unknown: a magnetometer's
/// columns may hold gauss, microtesla or counts alike.
pub fn infer_units(columns: [&str; 3]) -> Option<&'static str> {
    columns
        .iter()
        .all(|c| c.to_ascii_lowercase().starts_with("acc"))
        .then_some("g")
}

/// The effects of the 2-D catalogue a 3-D model holds.
pub fn model_effects(model: Ellipsoid3Model) -> Vec<&'static str> {
    match model {
        Ellipsoid3Model::Offset => vec!["offset"],
        Ellipsoid3Model::OffsetScale => vec!["offset", "scale"],
        Ellipsoid3Model::Full => vec!["offset", "scale", "cross-axis"],
    }
}

/// One model fitted to the same samples, for comparison: its rms, or why
/// it gave none.
#[derive(Debug, Clone, Serialize)]
pub struct ModelRms {
    pub model: &'static str,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rms: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub r: Option<f64>,
    /// Why the model gave no fit (the coverage rule, too few samples).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub refused: Option<String>,
}

/// `--still`: the poses the fit used.
#[derive(Debug, Clone, Serialize)]
pub struct StillSummary {
    /// Still segments (poses) found.
    pub poses: usize,
    /// Samples at rest, fitted.
    pub samples: usize,
    /// Samples of the recording.
    pub of: usize,
    pub window_s: f64,
    pub window_samples: usize,
    /// The noise: spread of the quietest windows, raw units.
    pub noise: f64,
    /// Largest spread of a still window, raw units.
    pub threshold: f64,
    /// The gyro's columns, when the rate was checked.
    pub gyro_columns: Option<[String; 3]>,
    pub gyro_bias_deg_s: Option<[f64; 3]>,
    /// Each pose: first and last sample (0-based, end exclusive), count
    /// and mean reading.
    pub segments: Vec<PoseJson>,
}

#[derive(Debug, Clone, Serialize)]
pub struct PoseJson {
    pub start: usize,
    pub end: usize,
    pub n: usize,
    pub mean: [f64; 3],
}

impl StillSummary {
    pub fn new(poses: &StillPoses, of: usize, gyro_columns: Option<[String; 3]>) -> Self {
        StillSummary {
            poses: poses.segments.len(),
            samples: poses.samples(),
            of,
            window_s: STILL_WINDOW_S,
            window_samples: poses.window,
            noise: poses.noise,
            threshold: poses.threshold,
            gyro_columns,
            gyro_bias_deg_s: poses.gyro_bias_deg_s,
            segments: poses
                .segments
                .iter()
                .map(|s| PoseJson {
                    start: s.start,
                    end: s.end,
                    n: s.len(),
                    mean: s.mean,
                })
                .collect(),
        }
    }
}

/// The catalogue's other effects fitted with the 3-D model (`fit
/// --effects full+drift`, `+covariate:<col>`, `+cubic`, `+outliers`):
/// what the report adds to the base model's.
#[derive(Debug, Clone, Default)]
pub struct Extras3 {
    /// The whole model by the catalogue's names, sorted: the base's
    /// (`offset`, `scale`, `cross-axis`) and the extras.
    pub effects: Vec<Effect>,
    /// The extras' own parameters with their standard errors: `drift_x`..
    /// (raw units per second), `<column>_x`.. (raw units per unit of the
    /// column), `k_x`.. (fraction of non-linearity at full scale).
    pub params: Vec<Param>,
    /// With `outliers`: the samples set aside (indices into the fitted
    /// samples, ascending).
    pub flagged: Option<Vec<usize>>,
    /// With `cubic`: the full scale S its k refers to (largest |reading|
    /// of any axis of the fitted samples), raw units.
    pub cubic_scale: Option<f64>,
    /// Unknowns of the whole model.
    pub unknowns: usize,
    /// The rms of the base model alone (no extras) on the same samples.
    pub base_rms: Option<f64>,
    /// With `drift`: the time the fitted samples span, s.
    pub t_span: Option<f64>,
}

#[derive(Debug, Serialize)]
pub struct Params3 {
    pub offset: [f64; 3],
    pub matrix: [[f64; 3]; 3],
    pub r: f64,
    /// The extras' parameters by name (empty without extras).
    pub extra: BTreeMap<String, f64>,
}

/// The standard errors: the base model's, and the extras' by name.
#[derive(Debug, Serialize)]
pub struct Se3 {
    #[serde(flatten)]
    pub base: Ellipsoid3Se,
    /// The extras' standard errors by name (empty without extras).
    pub extra: BTreeMap<String, f64>,
}

/// The machine-readable report (`fieldcal fit --json` on three axes): the
/// shared contract of docs/three-axes.md plus the fit's details.
#[derive(Debug, Serialize)]
pub struct Fit3Json<'a> {
    pub file: &'a str,
    pub axes: u8,
    pub x_column: &'a str,
    pub y_column: &'a str,
    pub z_column: &'a str,
    /// The whole model's name: the effects joined by `+` (as 2-D), e.g.
    /// `offset+scale+cross-axis+drift`.
    pub model: String,
    /// The base W alone: `offset`, `offset+scale` or
    /// `offset+scale+cross-axis` (as in `supported_models` and `models`).
    pub base_model: &'static str,
    pub effects: Vec<String>,
    pub params: Params3,
    pub se: Se3,
    /// Root mean square of |calibrated|/r − 1 over the samples used (the
    /// inliers, with `outliers`).
    pub rms: f64,
    /// With extras: the rms of the base model alone on the same samples.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub base_rms: Option<f64>,
    pub n: usize,
    /// Unknowns of the whole model.
    pub unknowns: usize,
    /// The samples set aside by `outliers` (count 0 without it).
    pub flagged: FlaggedJson<'a>,
    /// With `cubic`: the full scale S its k refers to, raw units.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cubic_scale: Option<f64>,
    pub units: Option<&'a str>,
    pub coverage: &'a SphereCoverage,
    pub iterations: usize,
    pub fit_seconds: f64,
    /// The models the calibrated directions support, richest first.
    pub supported_models: Vec<&'static str>,
    /// Every model fitted to the same samples, richest first.
    pub models: &'a [ModelRms],
    /// `--still`: the poses fitted (null without it).
    pub still: Option<&'a StillSummary>,
}

impl<'a> Fit3Json<'a> {
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        fit: &'a Ellipsoid3Fit,
        source: Fit3Source<'a>,
        units: Option<&'a str>,
        fit_seconds: f64,
        supported: &[Ellipsoid3Model],
        models: &'a [ModelRms],
        still: Option<&'a StillSummary>,
        extras: Option<&'a Extras3>,
    ) -> Self {
        let effects: Vec<String> = match extras {
            Some(e) => e.effects.iter().map(Effect::to_string).collect(),
            None => model_effects(fit.model)
                .into_iter()
                .map(String::from)
                .collect(),
        };
        let by_name = |f: fn(&Param) -> f64| -> BTreeMap<String, f64> {
            extras
                .map(|e| e.params.iter().map(|p| (p.name.clone(), f(p))).collect())
                .unwrap_or_default()
        };
        Fit3Json {
            file: source.file,
            axes: 3,
            x_column: source.x_column,
            y_column: source.y_column,
            z_column: source.z_column,
            model: match extras {
                Some(e) => model_name(&e.effects),
                None => fit.model.name().to_string(),
            },
            base_model: fit.model.name(),
            effects,
            params: Params3 {
                offset: fit.offset,
                matrix: fit.matrix,
                r: fit.r,
                extra: by_name(|p| p.value),
            },
            se: Se3 {
                base: fit.se,
                extra: by_name(|p| p.se),
            },
            rms: fit.rms,
            base_rms: extras.and_then(|e| e.base_rms),
            n: fit.n,
            unknowns: extras.map_or(fit.model.unknowns(), |e| e.unknowns),
            flagged: FlaggedJson {
                count: extras.and_then(|e| e.flagged.as_ref()).map_or(0, Vec::len),
                indices: extras.and_then(|e| e.flagged.as_deref()).unwrap_or(&[]),
            },
            cubic_scale: extras.and_then(|e| e.cubic_scale),
            units,
            coverage: &fit.coverage,
            iterations: fit.iterations,
            fit_seconds,
            supported_models: supported.iter().map(|m| m.name()).collect(),
            models,
            still,
        }
    }
}

const WIDTH: usize = 34;

fn push_line(out: &mut String, label: &str, value: &str, note: &str) {
    // A value too long for its column keeps two blanks before the note.
    let value = if value.chars().count() + 2 > WIDTH {
        format!("{value}  ")
    } else {
        value.to_string()
    };
    out.push_str(format!("{label:<10}{value:<WIDTH$}{note}").trim_end());
    out.push('\n');
}

fn with_se(value: f64, se: f64) -> String {
    if se > 0.0 && se.is_finite() {
        format!("{} ± {}", significant(value, 6), significant(se, 2))
    } else {
        significant(value, 6)
    }
}

/// The text report.
pub fn render_text3(
    fit: &Ellipsoid3Fit,
    source: Fit3Source<'_>,
    units: Option<&str>,
    supported: &[Ellipsoid3Model],
    models: &[ModelRms],
    still: Option<&StillSummary>,
    extras: Option<&Extras3>,
) -> String {
    let mut out = String::new();
    push_fit_setup(&mut out, fit, source, still, extras);
    push_parameters(&mut out, fit, units, extras);
    push_quality(&mut out, fit, supported, models, extras);
    out
}

/// The report's first lines: the file and axes, the model and solver, the
/// samples (and the still poses), the sphere's coverage.
fn push_fit_setup(
    out: &mut String,
    fit: &Ellipsoid3Fit,
    source: Fit3Source<'_>,
    still: Option<&StillSummary>,
    extras: Option<&Extras3>,
) {
    let mut line = |label: &str, value: String, note: &str| push_line(out, label, &value, note);
    line("file", source.file.to_string(), "");
    line(
        "axes",
        format!(
            "x = {}, y = {}, z = {}",
            source.x_column, source.y_column, source.z_column
        ),
        "",
    );
    match extras {
        Some(e) => line("model", model_name(&e.effects), &model_note(e)),
        None => line(
            "model",
            fit.model.name().to_string(),
            "calibrated = W·(raw − o), |calibrated| = r, det W = 1",
        ),
    }
    line(
        "solver",
        format!("levenberg-marquardt, {} iterations", fit.iterations),
        match fit.model {
            Ellipsoid3Model::Offset => "from the closed-form sphere (linear least squares)",
            _ => "from the closed-form ellipsoid (Li & Griffiths)",
        },
    );
    match extras {
        Some(e) => line(
            "samples",
            fit.n.to_string(),
            &format!("{} unknowns", e.unknowns),
        ),
        None => line("samples", fit.n.to_string(), ""),
    }
    if let Some(s) = still {
        let gyro = match &s.gyro_columns {
            Some(c) => format!(", gyro {} under 5 °/s", c.join("/")),
            None => String::new(),
        };
        line(
            "still",
            format!("{} poses, {} of {} samples", s.poses, s.samples, s.of),
            &format!(
                "at rest for {} s or more (spread ≤ {}{gyro})",
                s.window_s,
                significant(s.threshold, 2)
            ),
        );
    }
    let cov = &fit.coverage;
    line(
        "coverage",
        format!(
            "{:.0} % of the sphere ({} of {} regions)",
            cov.fraction * 100.0,
            cov.covered,
            cov.regions
        ),
        &cov.missing_text(),
    );
}

/// The fitted parameters: r, the offset, W, and the extras' terms with
/// the samples they flagged.
fn push_parameters(
    out: &mut String,
    fit: &Ellipsoid3Fit,
    units: Option<&str>,
    extras: Option<&Extras3>,
) {
    let mut line = |label: &str, value: String, note: &str| push_line(out, label, &value, note);
    let unit = units.unwrap_or("");
    let unit_note = match units {
        Some(u) => format!("field magnitude ({u})"),
        None => "field magnitude (units unknown: name them with --units)".to_string(),
    };
    line(
        "r",
        format!("{} {unit}", with_se(fit.r, fit.se.r))
            .trim_end()
            .to_string(),
        &unit_note,
    );
    for (i, axis) in ["x", "y", "z"].iter().enumerate() {
        line(
            if i == 0 { "offset" } else { "" },
            format!("{axis} {} {unit}", with_se(fit.offset[i], fit.se.offset[i]))
                .trim_end()
                .to_string(),
            if i == 0 {
                "o: hard iron (magnetometer) or zero-g bias (accelerometer)"
            } else {
                ""
            },
        );
    }
    for (i, row) in fit.matrix.iter().enumerate() {
        let cells: Vec<String> = row
            .iter()
            .zip(&fit.se.matrix[i])
            .map(|(v, s)| {
                if *s > 0.0 {
                    format!("{:>9.5} ±{:.1e}", v, s)
                } else {
                    format!("{v:>9.5}        ")
                }
            })
            .collect();
        let note = match i {
            0 => "W, row-major: gains on the diagonal, cross-axis / soft iron off it",
            _ => "",
        };
        line(if i == 0 { "W" } else { "" }, cells.join(" "), note);
    }
    if let Some(e) = extras {
        for p in &e.params {
            let (value, note) = describe_extra(p, units, e);
            line(&p.name, value, &note);
        }
        if let Some(flagged) = &e.flagged {
            line("flagged", flagged.len().to_string(), &flagged_note(flagged));
        }
    }
}

/// How well it fits: the rms (and without the extras), every model's rms
/// on these samples, and the models the coverage determines.
fn push_quality(
    out: &mut String,
    fit: &Ellipsoid3Fit,
    supported: &[Ellipsoid3Model],
    models: &[ModelRms],
    extras: Option<&Extras3>,
) {
    let mut line = |label: &str, value: String, note: &str| push_line(out, label, &value, note);
    let used = match extras.and_then(|e| e.flagged.as_ref()) {
        Some(flagged) => format!(", over the {} samples used", fit.n - flagged.len()),
        None => String::new(),
    };
    line(
        "rms",
        significant(fit.rms, 4),
        &format!("{:.3} % of r (|calibrated|/r − 1{used})", fit.rms * 100.0),
    );
    if let Some(base_rms) = extras.and_then(|e| e.base_rms) {
        line(
            "without",
            significant(base_rms, 4),
            &format!(
                "{:.3} % of r: the {} model alone, no extras, on the same samples",
                base_rms * 100.0,
                fit.model.name()
            ),
        );
    }
    let compared: Vec<String> = models
        .iter()
        .map(|m| match m.rms {
            Some(rms) => format!("{} {:.2} %", m.model, rms * 100.0),
            None => format!("{} refused", m.model),
        })
        .collect();
    line(
        "models",
        compared.join(", "),
        if extras.is_some() {
            "rms of each model on these samples, without the extras"
        } else {
            "rms of each model on these samples"
        },
    );
    let supported: Vec<&str> = supported.iter().map(|m| m.name()).collect();
    line(
        "supported",
        if supported.is_empty() {
            "none".to_string()
        } else {
            supported.join(", ")
        },
        "models the coverage determines",
    );
}

/// The model line's note: what the extras take out of each reading.
fn model_note(e: &Extras3) -> String {
    let parts: Vec<String> = e
        .effects
        .iter()
        .filter_map(|effect| match effect {
            Effect::Drift => Some("the offset's drift in time".to_string()),
            Effect::Covariate(column) => Some(format!("the offset following '{column}'")),
            Effect::Cubic => Some("the cubic non-linearity".to_string()),
            _ => None,
        })
        .collect();
    let mut text = match parts.len() {
        0 => "calibrated = W·(raw − o), |calibrated| = r, det W = 1".to_string(),
        n => format!(
            "calibrated = W·(q − o), |calibrated| = r, det W = 1; q: the reading with {} removed",
            match n {
                1 => parts[0].clone(),
                _ => format!("{} and {}", parts[..n - 1].join(", "), parts[n - 1]),
            }
        ),
    };
    if e.flagged.is_some() {
        text.push_str("; outliers set aside");
    }
    text
}

/// An extra parameter's value with its SE and units, and what it means.
fn describe_extra(p: &Param, units: Option<&str>, e: &Extras3) -> (String, String) {
    let unit = units.unwrap_or("raw units");
    let value = with_se(p.value, p.se);
    let Some((stem, axis)) = p.name.rsplit_once('_') else {
        return (value, String::new());
    };
    match stem {
        "drift" => (
            format!("{value} {unit}/s"),
            format!(
                "offset drift of {axis}: {} ± {} {unit} per hour{}",
                significant(p.value * 3600.0, 4),
                significant(p.se * 3600.0, 2),
                match e.t_span {
                    Some(span) => format!(
                        ", {} {unit} over the {} s fitted",
                        significant(p.value * span, 2),
                        significant(span, 3)
                    ),
                    None => String::new(),
                }
            ),
        ),
        "k" => (
            value,
            format!(
                "cubic non-linearity of {axis}: fraction at full scale S = {} {}",
                e.cubic_scale.map_or("?".to_string(), |s| significant(s, 4)),
                units.unwrap_or("(raw units)")
            ),
        ),
        column => (
            format!("{value} {unit}/unit"),
            format!("offset of {axis} per unit of the column '{column}' ({unit} per unit)"),
        ),
    }
}

/// The flagged samples: how many, and the first of them.
fn flagged_note(flagged: &[usize]) -> String {
    const SHOWN: usize = 8;
    if flagged.is_empty() {
        return "samples set aside as outliers: none".to_string();
    }
    let first: Vec<String> = flagged.iter().take(SHOWN).map(|i| i.to_string()).collect();
    let more = if flagged.len() > SHOWN { ", ..." } else { "" };
    format!(
        "samples set aside as outliers (0-based: {}{more}; all in the JSON's flagged.indices)",
        first.join(", ")
    )
}
