//! The report of `fieldcal fit` on three axes: the ellipsoid model
//! (docs/three-axes.md), as text and as the JSON every 3-D reader shares.

use serde::Serialize;

use super::significant;
use crate::model::ellipsoid::{Ellipsoid3Fit, Ellipsoid3Model, Ellipsoid3Se};
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

#[derive(Debug, Serialize)]
pub struct Params3 {
    pub offset: [f64; 3],
    pub matrix: [[f64; 3]; 3],
    pub r: f64,
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
    pub model: &'static str,
    pub effects: Vec<&'static str>,
    pub params: Params3,
    pub se: Ellipsoid3Se,
    pub rms: f64,
    pub n: usize,
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
    ) -> Self {
        Fit3Json {
            file: source.file,
            axes: 3,
            x_column: source.x_column,
            y_column: source.y_column,
            z_column: source.z_column,
            model: fit.model.name(),
            effects: model_effects(fit.model),
            params: Params3 {
                offset: fit.offset,
                matrix: fit.matrix,
                r: fit.r,
            },
            se: fit.se,
            rms: fit.rms,
            n: fit.n,
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
) -> String {
    let mut out = String::new();
    let mut line =
        |label: &str, value: String, note: &str| push_line(&mut out, label, &value, note);
    line("file", source.file.to_string(), "");
    line(
        "axes",
        format!(
            "x = {}, y = {}, z = {}",
            source.x_column, source.y_column, source.z_column
        ),
        "",
    );
    line(
        "model",
        fit.model.name().to_string(),
        "calibrated = W·(raw − o), |calibrated| = r, det W = 1",
    );
    line(
        "solver",
        format!("levenberg-marquardt, {} iterations", fit.iterations),
        "from the closed-form ellipsoid (Li & Griffiths)",
    );
    line("samples", fit.n.to_string(), "");
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
    line(
        "rms",
        significant(fit.rms, 4),
        &format!("{:.3} % of r (|calibrated|/r − 1)", fit.rms * 100.0),
    );
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
        "rms of each model on these samples",
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
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn accelerometer_columns_are_in_g() {
        assert_eq!(infer_units(["acc_x", "acc_y", "acc_z"]), Some("g"));
        assert_eq!(infer_units(["AccX", "accel_y", "acc_z"]), Some("g"));
        assert_eq!(infer_units(["acc_x", "acc_y", "mag_z"]), None);
        assert_eq!(infer_units(["mag_x", "mag_y", "mag_z"]), None);
    }
}
