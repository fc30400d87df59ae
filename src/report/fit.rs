//! The report of `fieldcal fit`.

use serde::Serialize;

use super::significant;
use std::collections::BTreeMap;
use std::time::Duration;

use crate::model::effects::{Effect, model_name};
use crate::model::fit::{FitReport, PAPER_EFFECTS, Solver};
use crate::model::gyro::HeadingCheck;
use crate::model::heading::Coverage;
use crate::model::nonlinear::{ModelFit, Param, TurnFrame};
use crate::model::paper::PaperCalibration;

// The paper's parameters by name are the calibration's; also here, at
// the path the reports have always used.
pub use crate::model::calibration::paper_parameters;

/// Where the fitted samples came from, for the report.
#[derive(Debug, Clone, Copy)]
pub struct FitSource<'a> {
    pub file: &'a str,
    pub x_column: &'a str,
    pub y_column: &'a str,
}

/// The machine-readable report (`fieldcal fit --json`).
#[derive(Debug, Serialize)]
pub struct FitJson<'a> {
    pub file: &'a str,
    pub x_column: &'a str,
    pub y_column: &'a str,
    pub model: String,
    pub effects: Vec<&'static str>,
    pub solver: Solver,
    pub params: PaperCalibration,
    /// Every fitted parameter with its standard error (NaN, printed null,
    /// where the rows do not give one).
    pub parameters: Vec<Param>,
    pub theta: [f64; 4],
    pub rms: f64,
    pub n: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub iterations: Option<u64>,
    pub coverage_deg: f64,
    pub largest_gap_deg: f64,
    pub fit_seconds: f64,
    /// The heading error against a gyro (null without --gyro).
    pub heading_vs_gyro: Option<&'a HeadingCheck>,
}

impl<'a> FitJson<'a> {
    /// `se`: the standard errors of a, b, d, r ([`crate::model::paper::closed_form_se`]).
    pub fn new(
        report: &FitReport,
        se: Option<&PaperCalibration>,
        heading: Option<&'a HeadingCheck>,
        source: FitSource<'a>,
    ) -> Self {
        FitJson {
            file: source.file,
            x_column: source.x_column,
            y_column: source.y_column,
            model: PAPER_EFFECTS.join("+"),
            effects: PAPER_EFFECTS.to_vec(),
            solver: report.solver,
            params: report.calibration,
            parameters: paper_parameters(&report.calibration, se),
            theta: report.theta.0,
            rms: report.rms,
            n: report.n,
            iterations: report.iterations,
            coverage_deg: report.coverage.covered_deg,
            largest_gap_deg: report.coverage.largest_gap_deg,
            fit_seconds: report.elapsed.as_secs_f64(),
            heading_vs_gyro: heading,
        }
    }
}

/// Width of the value column of the text reports.
const VALUE_WIDTH: usize = 22;

/// One `label  value  note` line of a text report, trailing blanks trimmed.
fn push_line(out: &mut String, value_width: usize, label: &str, value: &str, note: &str) {
    // A value too long for its column keeps two blanks before the note.
    let value = if value.chars().count() + 2 > value_width {
        format!("{value}  ")
    } else {
        value.to_string()
    };
    out.push_str(format!("{label:<10}{value:<value_width$}{note}").trim_end());
    out.push('\n');
}

impl FitSource<'_> {
    /// The first lines of every text report: the file and its axes.
    fn header(&self, value_width: usize) -> String {
        let mut out = String::new();
        push_line(&mut out, value_width, "file", self.file, "");
        let axes = format!("x = {}, y = {}", self.x_column, self.y_column);
        push_line(&mut out, value_width, "axes", &axes, "");
        out
    }
}

/// The text line of a heading check: rms and peak-to-peak against the gyro,
/// and the gyro's fitted scale and bias.
pub fn heading_line(check: &HeadingCheck) -> (String, String) {
    (
        format!(
            "{:.2}° rms, {:.2}° p-p",
            check.rms_deg, check.peak_to_peak_deg
        ),
        format!(
            "heading error against the integrated gyro '{}' ({} samples; its fitted scale {:+.3}, bias {:+.3} deg/s)",
            check.gyro_column, check.n, check.gyro_scale, check.gyro_bias_deg_s
        ),
    )
}

/// The report for a person; `se` gives each parameter its standard error.
pub fn render_text(
    report: &FitReport,
    se: Option<&PaperCalibration>,
    heading: Option<&HeadingCheck>,
    source: FitSource<'_>,
) -> String {
    let c = &report.calibration;
    let solver = match (report.solver, report.iterations) {
        (Solver::PaperGd, Some(n)) => {
            format!("paper-gd (the paper's gradient descent, {n} iterations)")
        }
        (Solver::PaperGd, None) => "paper-gd (the paper's gradient descent)".into(),
        (Solver::Lsq, _) => "lsq (closed-form least squares, eq. 6)".into(),
    };
    let cov = &report.coverage;
    let mut out = source.header(VALUE_WIDTH);
    let mut line = |label: &str, value: String, note: &str| {
        push_line(&mut out, VALUE_WIDTH, label, &value, note)
    };
    line(
        "model",
        format!("paper ({})", PAPER_EFFECTS.join("+")),
        "s_x = a*x + b, s_y = y + d, |s| = r",
    );
    line("solver", solver, "");
    line("samples", report.n.to_string(), "");
    line(
        "coverage",
        format!("{:.1}°", cov.covered_deg),
        &format!("of heading (largest gap {:.1}°)", cov.largest_gap_deg),
    );
    let with_se = |value: f64, se: Option<f64>| match se {
        Some(se) if se.is_finite() => format!("{} ± {}", significant(value, 7), significant(se, 2)),
        _ => significant(value, 7),
    };
    line(
        "a",
        with_se(c.a, se.map(|s| s.a)),
        "gain of x relative to y",
    );
    line(
        "b",
        with_se(c.b, se.map(|s| s.b)),
        "offset of x, after the gain (y units)",
    );
    line("d", with_se(c.d, se.map(|s| s.d)), "offset of y");
    line(
        "r",
        with_se(c.r, se.map(|s| s.r)),
        "field magnitude (y units)",
    );
    line(
        "rms",
        significant(report.rms, 4),
        &format!(
            "{:.3} % of the field (|calibrated|/r - 1)",
            report.rms * 100.0
        ),
    );
    if let Some(check) = heading {
        let (value, note) = heading_line(check);
        line("heading", value, &note);
    }
    line(
        "fit time",
        format!("{:.3} ms", report.elapsed.as_secs_f64() * 1e3),
        "",
    );
    out
}

/// Which samples the robust fit set aside.
#[derive(Debug, Serialize)]
pub struct FlaggedJson<'a> {
    pub count: usize,
    pub indices: &'a [usize],
}

/// The machine-readable report of a fit with effects (`fit --effects --json`).
#[derive(Debug, Serialize)]
pub struct ModelFitJson<'a> {
    pub file: &'a str,
    pub x_column: &'a str,
    pub y_column: &'a str,
    pub model: String,
    pub effects: &'a [Effect],
    pub solver: &'static str,
    /// Parameter name -> value (a, b, d, r always).
    pub params: BTreeMap<&'a str, f64>,
    /// Parameter name -> standard error.
    pub se: BTreeMap<&'a str, f64>,
    /// Root mean square of |calibrated|/r - 1 over the samples used.
    pub rms: f64,
    pub rss: f64,
    pub n: usize,
    pub unknowns: usize,
    pub flagged: FlaggedJson<'a>,
    pub iterations: usize,
    pub coverage_deg: f64,
    pub largest_gap_deg: f64,
    pub fit_seconds: f64,
    /// The heading error against a gyro (null without --gyro).
    pub heading_vs_gyro: Option<&'a HeadingCheck>,
    /// With the cubic effect: the full scale S its `k` refers to (the
    /// largest |x| or |y| of the recording), so `check` applies it to
    /// another recording unchanged.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cubic_scale: Option<f64>,
    /// With the cubic-centred effect: the turn's centre and radius per axis
    /// its `kc` refers to, so `check` applies it to another recording
    /// unchanged.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub turn_frame: Option<TurnFrame>,
}

impl<'a> ModelFitJson<'a> {
    pub fn new(
        fit: &'a ModelFit,
        coverage: &Coverage,
        elapsed: Duration,
        heading: Option<&'a HeadingCheck>,
        source: FitSource<'a>,
    ) -> Self {
        ModelFitJson {
            file: source.file,
            x_column: source.x_column,
            y_column: source.y_column,
            model: model_name(&fit.effects),
            effects: &fit.effects,
            solver: "levenberg-marquardt",
            params: fit
                .params
                .iter()
                .map(|p| (p.name.as_str(), p.value))
                .collect(),
            se: fit.params.iter().map(|p| (p.name.as_str(), p.se)).collect(),
            rms: fit.rms,
            rss: fit.rss,
            n: fit.n,
            unknowns: fit.unknowns,
            flagged: FlaggedJson {
                count: fit.flagged.len(),
                indices: &fit.flagged,
            },
            iterations: fit.iterations,
            coverage_deg: coverage.covered_deg,
            largest_gap_deg: coverage.largest_gap_deg,
            fit_seconds: elapsed.as_secs_f64(),
            heading_vs_gyro: heading,
            cubic_scale: None,
            turn_frame: None,
        }
    }
}

/// What a parameter of the general model means, for the text report.
fn describe(name: &str) -> String {
    match name {
        "a" => "gain of x relative to y".into(),
        "b" => "mean offset of x, after the gain (y units)".into(),
        "d" => "mean offset of y".into(),
        "r" => "field magnitude (y units)".into(),
        "c" => "cross-axis coupling of y into x".into(),
        "drift_x" | "drift_y" => "offset drift, counts per second".into(),
        "k_x" | "k_y" => "cubic non-linearity, fraction at full scale".into(),
        "kc" => "cubic non-linearity about the turn's centre, fraction at the turn's radius".into(),
        "kc_x" | "kc_y" => format!(
            "cubic non-linearity of {} about the turn's centre, fraction at the turn's radius (per axis: the gyro pins the difference)",
            if name == "kc_x" { "x" } else { "y" }
        ),
        other => match other.rsplit_once('_') {
            Some((column, _)) => format!("offset per unit of '{column}'"),
            None => String::new(),
        },
    }
}

/// The report of a fit with effects, for a person.
pub fn render_model_text(
    fit: &ModelFit,
    coverage: &Coverage,
    elapsed: Duration,
    heading: Option<&HeadingCheck>,
    source: FitSource<'_>,
) -> String {
    // Values carry their standard errors: a wider column.
    let mut out = source.header(VALUE_WIDTH + 8);
    let mut line = |label: &str, value: String, note: &str| {
        push_line(&mut out, VALUE_WIDTH + 8, label, &value, note)
    };
    line("model", model_name(&fit.effects), "");
    line(
        "solver",
        format!("levenberg-marquardt, {} iterations", fit.iterations),
        "",
    );
    line(
        "samples",
        fit.n.to_string(),
        &format!("{} unknowns", fit.unknowns),
    );
    line(
        "coverage",
        format!("{:.1}°", coverage.covered_deg),
        &format!("of heading (largest gap {:.1}°)", coverage.largest_gap_deg),
    );
    for p in &fit.params {
        line(
            &p.name,
            format!("{} ± {}", significant(p.value, 7), significant(p.se, 2)),
            &describe(&p.name),
        );
    }
    if fit.effects.contains(&Effect::Outliers) {
        line(
            "flagged",
            fit.flagged.len().to_string(),
            "samples set aside as outliers",
        );
    }
    line(
        "rms",
        significant(fit.rms, 4),
        &format!(
            "{:.3} % of the field (|calibrated|/r - 1, over the samples used)",
            fit.rms * 100.0
        ),
    );
    if let Some(check) = heading {
        let (value, note) = heading_line(check);
        line("heading", value, &note);
    }
    line(
        "fit time",
        format!("{:.3} ms", elapsed.as_secs_f64() * 1e3),
        "",
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_wider_than_its_column_keeps_two_blanks_before_the_note() {
        let mut out = String::new();
        push_line(
            &mut out,
            VALUE_WIDTH,
            "b",
            "2.090700e-17 ± 8.1e-18",
            "offset of x",
        );
        assert_eq!(out, "b         2.090700e-17 ± 8.1e-18  offset of x\n");
        let mut out = String::new();
        push_line(&mut out, VALUE_WIDTH, "a", "1.000000 ± 1.6e-17", "gain");
        assert_eq!(out, "a         1.000000 ± 1.6e-17    gain\n");
    }
}
