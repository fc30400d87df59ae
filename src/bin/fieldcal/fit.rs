//! `fieldcal fit`: read a CSV, fit, report.

use std::io::IsTerminal;

use std::time::Instant;

use anyhow::{Context, Result};

use fieldcal::io::csv::write_calibrated;
use fieldcal::model::effects::Effect;
use fieldcal::model::fit::{FitOptions, fit_paper};
use fieldcal::model::gyro::{HeadingCheck, HeadingReference};
use fieldcal::model::heading::coverage;
use fieldcal::model::nonlinear::fit_model;
use fieldcal::model::paper::{GradientDescentOptions, GradientDescentProgress, closed_form_se};
use fieldcal::report::fit::{FitJson, FitSource, ModelFitJson, render_model_text, render_text};

use crate::FitArgs;
use crate::output::write_stdout;

pub fn fit(args: FitArgs) -> Result<()> {
    let (data, reference) = args.input.read_with_reference()?;
    let options = FitOptions {
        solver: args.solver,
        gradient_descent: GradientDescentOptions {
            learning_rate: args.learning_rate,
            max_iterations: args.max_iterations,
            ..Default::default()
        },
        min_coverage_deg: args.min_coverage,
    };
    let file = args.input.file.display().to_string();
    if let Some(effects) = &args.effects {
        if args.solver != fieldcal::model::fit::Solver::Lsq {
            anyhow::bail!(
                "--solver {} fits the paper's model only; --effects fits by Levenberg-Marquardt: drop one of them",
                args.solver.name()
            );
        }
        return fit_effects(&args, &data, reference.as_ref(), &effects.0, &file);
    }
    let mut progress = progress_printer();
    let report = fit_paper(&data.x, &data.y, &options, &mut progress);
    finish_progress();
    let report = report.with_context(|| format!("{file}: no calibration"))?;

    if let Some(output) = &args.output {
        let (cx, cy): (Vec<f64>, Vec<f64>) = data
            .x
            .iter()
            .zip(&data.y)
            .map(|(&x, &y)| report.calibration.apply(x, y))
            .unzip();
        write_output(output, data.t.as_deref(), &cx, &cy)?;
    }

    let se = closed_form_se(&data.x, &data.y, &report.theta);
    let heading = match &reference {
        Some(reference) => {
            let headings: Vec<f64> = data
                .x
                .iter()
                .zip(&data.y)
                .map(|(&x, &y)| report.calibration.heading(x, y))
                .collect();
            Some(heading_check(reference, &headings, &[], &file)?)
        }
        None => None,
    };
    let source = FitSource {
        file: &file,
        x_column: &data.x_name,
        y_column: &data.y_name,
    };
    let text = if args.json {
        serde_json::to_string(&FitJson::new(
            &report,
            se.as_ref(),
            heading.as_ref(),
            source,
        ))? + "\n"
    } else {
        render_text(&report, se.as_ref(), heading.as_ref(), source)
    };
    write_stdout(text.as_bytes())
}

/// `fit --effects`: the general model by Levenberg-Marquardt.
fn fit_effects(
    args: &FitArgs,
    data: &fieldcal::sample::Dataset,
    reference: Option<&HeadingReference>,
    effects: &[Effect],
    file: &str,
) -> Result<()> {
    let started = Instant::now();
    let fit = fit_model(data, effects).with_context(|| format!("{file}: no calibration"))?;
    let elapsed = started.elapsed();
    let coverage = coverage(fit.headings.iter().copied());
    coverage
        .require(args.min_coverage)
        .with_context(|| format!("{file}: no calibration"))?;

    if let Some(output) = &args.output {
        let (cx, cy): (Vec<f64>, Vec<f64>) = fit.calibrated.iter().copied().unzip();
        write_output(output, data.t.as_deref(), &cx, &cy)?;
    }
    let heading = match reference {
        Some(reference) => Some(heading_check(reference, &fit.headings, &fit.flagged, file)?),
        None => None,
    };
    let source = FitSource {
        file,
        x_column: &data.x_name,
        y_column: &data.y_name,
    };
    let text = if args.json {
        let mut json = ModelFitJson::new(&fit, &coverage, elapsed, heading.as_ref(), source);
        json.cubic_scale = effects
            .contains(&Effect::Cubic)
            .then(|| fieldcal::model::nonlinear::cubic_scale(data));
        serde_json::to_string(&json)? + "\n"
    } else {
        render_model_text(&fit, &coverage, elapsed, heading.as_ref(), source)
    };
    write_stdout(text.as_bytes())
}

/// The model's heading against the gyro; a gyro that cannot serve is an
/// error naming the file and the column.
pub(crate) fn heading_check(
    reference: &HeadingReference,
    headings: &[f64],
    skip: &[usize],
    file: &str,
) -> Result<HeadingCheck> {
    reference.check(headings, skip).with_context(|| {
        format!(
            "{file}: cannot check the heading against the gyro '{}'",
            reference.column()
        )
    })
}

/// Reports gradient-descent progress on a terminal; silent otherwise.
fn progress_printer() -> impl FnMut(GradientDescentProgress) {
    let terminal = std::io::stderr().is_terminal();
    move |p: GradientDescentProgress| {
        if terminal {
            eprint!(
                "\rgradient descent: iteration {:>9}, step {:.2e}   ",
                p.iteration, p.step
            );
        }
    }
}

fn finish_progress() {
    if std::io::stderr().is_terminal() {
        eprint!("\r{:60}\r", "");
    }
}

/// `--output FILE`: every sample's calibrated x, y (and t).
fn write_output(output: &std::path::Path, t: Option<&[f64]>, x: &[f64], y: &[f64]) -> Result<()> {
    write_calibrated(output, t, x, y).with_context(|| {
        format!(
            "cannot write the calibrated samples to {}",
            output.display()
        )
    })
}
