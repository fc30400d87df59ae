//! `fieldcal fit`: read a CSV, fit, report. Two columns: the paper's model
//! (or --effects) on a turn; three (--z, or a `z` column): the ellipsoid.

use std::io::IsTerminal;

use std::time::Instant;

use anyhow::{Context, Result};

use fieldcal::io::csv::{write_calibrated, write_calibrated3};
use fieldcal::model::FitError;
use fieldcal::model::effects::Effect;
use fieldcal::model::ellipsoid::{self, Ellipsoid3Error, Ellipsoid3Fit, Ellipsoid3Model};
use fieldcal::model::fit::DEFAULT_MIN_COVERAGE_DEG;
use fieldcal::model::fit::{FitOptions, fit_paper};
use fieldcal::model::gyro::GyroUnits;
use fieldcal::model::gyro::{HeadingCheck, HeadingReference};
use fieldcal::model::heading::coverage;
use fieldcal::model::nonlinear::fit_model;
use fieldcal::model::paper::{GradientDescentOptions, GradientDescentProgress, closed_form_se};
use fieldcal::model::still::find_still;
use fieldcal::model::turn::check_turn_of;
use fieldcal::report::fit::{FitJson, FitSource, ModelFitJson, render_model_text, render_text};
use fieldcal::report::fit3::{
    Fit3Json, Fit3Source, ModelRms, StillSummary, infer_units, render_text3,
};
use fieldcal::sample::Dataset3;

use crate::FitArgs;
use crate::output::write_stdout;

pub fn fit(args: FitArgs) -> Result<()> {
    if let Some(z) = args.input.z_column()? {
        return fit3(&args, &z);
    }
    if args.still || args.units.is_some() {
        anyhow::bail!("--still and --units are for a 3-axis fit: name the third axis with --z COL");
    }
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
    // A turn, or no calibration: the same gate for both models, naming the
    // recording's columns.
    if let Err(err) = check_turn_of(&data, args.min_coverage) {
        if let FitError::DiscNotRing { .. } = err
            && let Some(hint) = third_axis_hint(&data)
        {
            anyhow::bail!("{file}: no calibration: {err}; {hint}");
        }
        return Err(err).with_context(|| format!("{file}: no calibration"));
    }
    if let Some(effects) = &args.effects {
        let effects = match &effects.effects {
            Ok(effects) => effects,
            Err(e) => anyhow::bail!("--effects: {e}"),
        };
        if args.solver != fieldcal::model::fit::Solver::Lsq {
            anyhow::bail!(
                "--solver {} fits the paper's model only; --effects fits by Levenberg-Marquardt: drop one of them",
                args.solver.name()
            );
        }
        return fit_effects(&args, &data, reference.as_ref(), effects, &file);
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

/// After a disc, not a ring: when the recording has more numeric columns,
/// the sensor may have been tumbled; the 3-D fit is the one to run.
fn third_axis_hint(data: &fieldcal::sample::Dataset) -> Option<String> {
    let names: Vec<&str> = data.covariates.iter().map(|c| c.name.as_str()).collect();
    // The column that shares the axes' prefix (mag_x, mag_y → mag_z) first.
    let prefix = |s: &str| {
        s.trim_end_matches(|c: char| "xyzXYZ".contains(c))
            .to_string()
    };
    let same = prefix(&data.x_name);
    let z = names
        .iter()
        .find(|n| !same.is_empty() && prefix(n) == same && n.len() == data.x_name.len())
        .or(names.first())?;
    Some(format!(
        "if the sensor was tumbled through every direction, fit its three axes in 3-D: --x {} --y {} --z {z}",
        data.x_name, data.y_name
    ))
}

/// `--effects` on three axes: the base model (the richest of `offset`,
/// `scale`/`paper` → offset+scale, `cross-axis`/`full` → the full model;
/// the full model when the list names none of them) and the catalogue's
/// other effects (drift, covariate:<col>, cubic, cubic-centred, outliers).
pub(crate) fn parse_effects3(text: &str) -> Result<(Ellipsoid3Model, Vec<Effect>), String> {
    let mut base: Option<Ellipsoid3Model> = None;
    let mut extra: Vec<Effect> = Vec::new();
    let richer = |m: Ellipsoid3Model, base: &mut Option<Ellipsoid3Model>| {
        if base.is_none_or(|b| b.unknowns() < m.unknowns()) {
            *base = Some(m);
        }
    };
    let mut any = false;
    for part in text
        .split([',', '+'])
        .map(str::trim)
        .filter(|p| !p.is_empty())
    {
        any = true;
        match part {
            "offset" => richer(Ellipsoid3Model::Offset, &mut base),
            "scale" | "paper" => richer(Ellipsoid3Model::OffsetScale, &mut base),
            "cross-axis" | "full" => richer(Ellipsoid3Model::Full, &mut base),
            other => {
                let effect: Effect = other.parse()?;
                if !extra.contains(&effect) {
                    extra.push(effect);
                }
            }
        }
    }
    if !any {
        return Err("the list is empty: name a model (offset, offset+scale, full)".into());
    }
    Ok((base.unwrap_or(Ellipsoid3Model::Full), extra))
}

/// The 3-D fit of `base` plus the catalogue's other effects on `points`
/// (the recording's, or its still poses'). The extra effects (drift,
/// covariates, the cubic, outliers) are not fitted in 3-D yet: the arm
/// `extra => ...` is where `fieldcal::model::ellipsoid_effects` plugs in.
fn fit_model3(
    data: &Dataset3,
    points: &[[f64; 3]],
    base: Ellipsoid3Model,
    extra: &[Effect],
) -> Result<Ellipsoid3Fit> {
    let _ = data;
    match extra {
        [] => Ok(ellipsoid::fit(points, base)?),
        extra => {
            let names: Vec<String> = extra.iter().map(Effect::to_string).collect();
            anyhow::bail!(
                "--effects: {} not available in `fit` in 3-D yet; `fieldcal diagnose` fits them in 3-D and shows what each removes, or fit the {base} model alone (--effects {base})",
                match names.len() {
                    1 => format!("the effect {} is", names[0]),
                    _ => format!("the effects {} are", names.join(", ")),
                }
            )
        }
    }
}

/// The gyro's three column names and its rates (deg/s), one per sample.
type GyroColumns = ([String; 3], Vec<[f64; 3]>);

/// The gyro's three columns for `--still`: `--still-gyro X,Y,Z`, or
/// gyro_x, gyro_y, gyro_z when the recording has them; `none`: no gyro.
fn still_gyro(args: &FitArgs, data: &Dataset3, file: &str) -> Result<Option<GyroColumns>> {
    let names: [String; 3] = match args.still_gyro.as_deref() {
        Some("none") => return Ok(None),
        Some(text) => {
            let parts: Vec<&str> = text.split(',').map(str::trim).collect();
            let [x, y, z] = parts[..] else {
                anyhow::bail!(
                    "--still-gyro '{text}': give the gyro's three rate columns as X,Y,Z (or none)"
                );
            };
            [x.to_string(), y.to_string(), z.to_string()]
        }
        None => {
            let default = ["gyro_x", "gyro_y", "gyro_z"].map(String::from);
            if default.iter().all(|n| data.covariate(n).is_some()) {
                default
            } else {
                return Ok(None);
            }
        }
    };
    let scale = match args.input.gyro_units {
        GyroUnits::DegPerSecond => 1.0,
        GyroUnits::RadPerSecond => 180.0 / std::f64::consts::PI,
    };
    let mut columns = Vec::new();
    for name in &names {
        let Some(c) = data.covariate(name) else {
            let have: Vec<&str> = data.covariates.iter().map(|c| c.name.as_str()).collect();
            anyhow::bail!(
                "{file}: no gyro column '{name}' for --still-gyro (the numeric columns other than the axes and time are: {})",
                if have.is_empty() {
                    "none".to_string()
                } else {
                    have.join(", ")
                }
            );
        };
        columns.push(&c.values);
    }
    let rates = (0..data.len())
        .map(|i| [0, 1, 2].map(|k| columns[k][i] * scale))
        .collect();
    Ok(Some((names, rates)))
}

/// `fit` on three axes.
fn fit3(args: &FitArgs, z: &str) -> Result<()> {
    if args.solver != fieldcal::model::fit::Solver::Lsq {
        anyhow::bail!(
            "--solver {} fits the paper's 2-axis model; the 3-axis fit is the ellipsoid's (drop --solver, or fit two axes without --z)",
            args.solver.name()
        );
    }
    if args.input.gyro.is_some() {
        anyhow::bail!(
            "--gyro checks a 2-axis heading against the gyro; with three axes the heading needs an accelerometer (for still poses, the gyro's columns go to --still-gyro)"
        );
    }
    if args.min_coverage != DEFAULT_MIN_COVERAGE_DEG {
        anyhow::bail!(
            "--min-coverage is the heading coverage of a 2-axis turn; a 3-axis fit follows the sphere's coverage rule (docs/three-axes.md)"
        );
    }
    let data = args.input.read3(z)?;
    let file = args.input.file.display().to_string();
    let (base, extra) = match &args.effects {
        Some(list) => parse_effects3(&list.text).map_err(|e| anyhow::anyhow!("--effects: {e}"))?,
        None => (Ellipsoid3Model::Full, Vec::new()),
    };
    let units: Option<String> = args
        .units
        .clone()
        .or_else(|| infer_units([&data.x_name, &data.y_name, &data.z_name]).map(String::from));

    let (points, still) = if args.still {
        let gyro = still_gyro(args, &data, &file)?;
        let poses = find_still(
            &data.points,
            data.t.as_deref(),
            gyro.as_ref().map(|(_, r)| r.as_slice()),
        )
        .with_context(|| format!("{file}: no still poses"))?;
        let points: Vec<[f64; 3]> = poses.indices().map(|i| data.points[i]).collect();
        let summary = StillSummary::new(&poses, data.len(), gyro.map(|(names, _)| names));
        (points, Some(summary))
    } else {
        (data.points.clone(), None)
    };

    let started = Instant::now();
    let fit =
        fit_model3(&data, &points, base, &extra).map_err(|e| refusal(e, &file, still.as_ref()))?;
    let elapsed = started.elapsed().as_secs_f64();

    let models: Vec<ModelRms> = Ellipsoid3Model::ALL
        .into_iter()
        .map(|m| {
            let result = if m == fit.model {
                Ok(fit.clone())
            } else {
                ellipsoid::fit(&points, m)
            };
            match result {
                Ok(f) => ModelRms {
                    model: m.name(),
                    rms: Some(f.rms),
                    r: Some(f.r),
                    refused: None,
                },
                Err(e) => ModelRms {
                    model: m.name(),
                    rms: None,
                    r: None,
                    refused: Some(e.to_string()),
                },
            }
        })
        .collect();
    let directions: Vec<[f64; 3]> = points.iter().map(|&p| fit.apply(p)).collect();
    let supported: Vec<Ellipsoid3Model> = Ellipsoid3Model::ALL
        .into_iter()
        .filter(|&m| ellipsoid::supports(m, &directions))
        .collect();

    if let Some(output) = &args.output {
        let calibrated: Vec<[f64; 3]> = data.points.iter().map(|&p| fit.apply(p)).collect();
        write_calibrated3(output, data.t.as_deref(), &calibrated).with_context(|| {
            format!(
                "cannot write the calibrated samples to {}",
                output.display()
            )
        })?;
    }
    let source = Fit3Source {
        file: &file,
        x_column: &data.x_name,
        y_column: &data.y_name,
        z_column: &data.z_name,
    };
    let text = if args.json {
        serde_json::to_string(&Fit3Json::new(
            &fit,
            source,
            units.as_deref(),
            elapsed,
            &supported,
            &models,
            still.as_ref(),
        ))? + "\n"
    } else {
        render_text3(
            &fit,
            source,
            units.as_deref(),
            &supported,
            &models,
            still.as_ref(),
        )
    };
    write_stdout(text.as_bytes())
}

/// A 3-D fit's refusal, naming the file and, when the coverage supports a
/// restricted model, how to ask for it.
fn refusal(err: anyhow::Error, file: &str, still: Option<&StillSummary>) -> anyhow::Error {
    let poses = match still {
        Some(s) => format!(" (on {} still poses, {} samples)", s.poses, s.samples),
        None => String::new(),
    };
    match err.downcast_ref::<Ellipsoid3Error>() {
        Some(Ellipsoid3Error::NotCovered {
            supported: Some(m), ..
        }) => anyhow::anyhow!("{file}: no 3-D calibration{poses}: {err}; to fit it: --effects {m}"),
        Some(_) => anyhow::anyhow!("{file}: no 3-D calibration{poses}: {err}"),
        None => err.context(format!("{file}: no 3-D calibration")),
    }
}
