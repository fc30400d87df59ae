//! `fieldcal fit`: read a CSV, fit, report. Two columns: the paper's model
//! (or --effects) on a turn; three (--z, or a `z` column): the ellipsoid.

use fieldcal::io::csv::Covariates;
use std::io::IsTerminal;

use std::time::Instant;

use anyhow::{Context, Result};

use fieldcal::io::csv::{write_calibrated, write_calibrated3};
use fieldcal::model::FitError;
use fieldcal::model::centred_split::fit_with_gyro;
use fieldcal::model::effects::Effect;
use fieldcal::model::ellipsoid::{self, Ellipsoid3Error, Ellipsoid3Fit, Ellipsoid3Model};
use fieldcal::model::ellipsoid_effects::{self, Effects3Error, Ellipsoid3EffectsFit};
use fieldcal::model::fit::DEFAULT_MIN_COVERAGE_DEG;
use fieldcal::model::fit::{FitOptions, Solver, fit_paper_turned};
use fieldcal::model::gyro::GyroUnits;
use fieldcal::model::gyro::{HeadingCheck, HeadingReference};
use fieldcal::model::heading::coverage;
use fieldcal::model::paper::{GradientDescentOptions, GradientDescentProgress, closed_form_se};
use fieldcal::model::still::find_still;
use fieldcal::model::turn::{check_turn_of, check_turn_of_with, second_difference_noise};
use fieldcal::report::fit::{FitJson, FitSource, ModelFitJson, render_model_text, render_text};
use fieldcal::report::fit3::{
    Extras3, Fit3Json, Fit3Source, ModelRms, StillSummary, infer_units, render_text3,
};
use fieldcal::sample::{Covariate, Dataset3};

use crate::FitArgs;
use crate::output::write_stdout;

pub fn fit(mut args: FitArgs) -> Result<()> {
    // The times are written with --output, integrate the --gyro, find
    // the still poses and may drive an effect; the model's fit alone has
    // no use for them, and does not parse them.
    args.input.times_unused =
        args.output.is_none() && args.input.gyro.is_none() && args.effects.is_none() && !args.still;
    if let Some(z) = args.input.z_column()? {
        return fit3(&args, &z);
    }
    if args.still || args.units.is_some() {
        anyhow::bail!("--still and --units are for a 3-axis fit: name the third axis with --z COL");
    }
    // The paper's model reads the axes, time and a gyro column; the
    // effects may name any column.
    let covariates = match args.effects {
        Some(_) => Covariates::All,
        None => Covariates::Only(Vec::new()),
    };
    let (data, reference) = args.input.read_with_reference(&covariates)?;
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
    let beside = args.effects.is_none() && args.solver == Solver::Lsq;
    let (turn, early) = turn_and_fit(&data, &options, args.min_coverage, beside);
    // A turn, or no calibration: the same gate for both models, naming the
    // recording's columns.
    if let Err(err) = turn {
        // The hint names the recording's other numeric columns (all
        // but the gyro's own, which is no covariate).
        let every_column = || -> Result<fieldcal::sample::Dataset> {
            let mut all = args.input.read(&Covariates::All)?;
            if let Some(gyro) = args.input.own_gyro_column() {
                all.covariates.retain(|c| c.name != gyro);
            }
            Ok(all)
        };
        if let FitError::DiscNotRing { .. } = err
            && let Some(hint) = every_column().ok().and_then(|all| third_axis_hint(&all))
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
    // The gate above judged the turn: the fit does not judge it again.
    let (report, se) = match early {
        Some(done) => {
            // As after a fit that showed its progress (a terminal's line).
            finish_progress();
            done
        }
        None => {
            let mut progress = progress_printer();
            let report = fit_paper_turned(&data.x, &data.y, &options, &mut progress);
            finish_progress();
            let se = report
                .as_ref()
                .ok()
                .and_then(|r| closed_form_se(&data.x, &data.y, &r.theta));
            (report, se)
        }
    };
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

/// The paper's fit that the turn gate said may be told: its report and
/// standard errors.
type EarlyFit = (
    Result<fieldcal::model::fit::FitReport, FitError>,
    Option<fieldcal::model::paper::PaperCalibration>,
);

/// The turn gate of `data`, and (`beside`) the paper's closed form and its
/// standard errors, run beside it on the other core: the gate decides
/// whether they are told. Then the gate's noise of the second
/// differences, which it needs last (the gate's own work is the longer).
fn turn_and_fit(
    data: &fieldcal::sample::Dataset,
    options: &FitOptions,
    min_coverage: f64,
    beside: bool,
) -> (
    Result<fieldcal::model::turn::TurnCheck, FitError>,
    Option<EarlyFit>,
) {
    std::thread::scope(|s| {
        let Some(fit) = beside.then(|| {
            s.spawn(|| {
                let report = fit_paper_turned(&data.x, &data.y, options, &mut |_| {});
                let se = report
                    .as_ref()
                    .ok()
                    .and_then(|r| closed_form_se(&data.x, &data.y, &r.theta));
                let noise = second_difference_noise(&data.x, &data.y);
                (report, se, noise)
            })
        }) else {
            return (check_turn_of(data, min_coverage), None);
        };
        let join = |fit: std::thread::ScopedJoinHandle<'_, _>| {
            fit.join().unwrap_or_else(|e| std::panic::resume_unwind(e))
        };
        let (mut fit, mut early) = (Some(fit), None);
        let turn = check_turn_of_with(data, min_coverage, || match fit.take() {
            Some(fit) => {
                let (report, se, noise) = join(fit);
                early = Some((report, se));
                noise
            }
            None => second_difference_noise(&data.x, &data.y),
        });
        // Readings the gate refused before it needed the noise: the fit
        // is joined all the same (a panic there is its own).
        if let Some(fit) = fit {
            let _ = join(fit);
        }
        (turn, early)
    })
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
    let fit = fit_with_gyro(data, effects, reference)
        .with_context(|| format!("{file}: no calibration"))?;
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
        json.turn_frame = effects
            .contains(&Effect::CubicCentred)
            .then(|| fieldcal::model::nonlinear::turn_frame(data).ok())
            .flatten();
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

/// The 3-D fit of `base` plus the catalogue's other effects (drift,
/// covariate:<col>, cubic, outliers) on `data` (the recording, or its still
/// samples), by [`fieldcal::model::ellipsoid_effects::fit_effects`], with
/// its view as a base fit. Refusals keep their types: a coverage refusal
/// downcasts to [`Ellipsoid3Error`].
fn fit_effects3(
    data: &Dataset3,
    base: Ellipsoid3Model,
    extra: &[Effect],
) -> Result<(Ellipsoid3Fit, Ellipsoid3EffectsFit)> {
    let fit = match ellipsoid_effects::fit_effects(data, base, extra) {
        Ok(fit) => fit,
        // The base fit's refusal as itself, so `refusal` finds the coverage
        // rule's hint in it.
        Err(Effects3Error::Fit(e)) => return Err(anyhow::Error::new(e)),
        Err(e) => return Err(anyhow::Error::new(e)),
    };
    let view = Ellipsoid3Fit {
        model: fit.model,
        offset: fit.offset,
        matrix: fit.matrix,
        r: fit.r,
        rms: fit.rms,
        n: fit.n,
        se: fit.se,
        coverage: fit.coverage.clone(),
        iterations: fit.iterations,
    };
    Ok((view, fit))
}

/// The samples `indices` of a recording, with their times and covariates.
fn select3(data: &Dataset3, indices: &[usize]) -> Dataset3 {
    let pick = |values: &[f64]| indices.iter().map(|&i| values[i]).collect::<Vec<f64>>();
    Dataset3 {
        x_name: data.x_name.clone(),
        y_name: data.y_name.clone(),
        z_name: data.z_name.clone(),
        t: data.t.as_deref().map(pick),
        points: indices.iter().map(|&i| data.points[i]).collect(),
        covariates: data
            .covariates
            .iter()
            .map(|c| Covariate {
                name: c.name.clone(),
                values: pick(&c.values),
            })
            .collect(),
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
    refuse_2d_options(args)?;
    // The model's fit reads the axes alone; --still reads the gyro, and
    // the effects may name any column.
    let covariates = if args.effects.is_none() && !args.still {
        Covariates::Only(Vec::new())
    } else {
        Covariates::All
    };
    let data = args.input.read3_gated(z, &covariates)?;
    let file = args.input.file.display().to_string();
    let (base, extra) = match &args.effects {
        Some(list) => parse_effects3(&list.text).map_err(|e| anyhow::anyhow!("--effects: {e}"))?,
        None => (Ellipsoid3Model::Full, Vec::new()),
    };
    let units: Option<String> = args
        .units
        .clone()
        .or_else(|| infer_units([&data.x_name, &data.y_name, &data.z_name]).map(String::from));

    let (still_data, still) = still_selection(args, &data, &file)?;
    // The samples fitted: the still ones with --still, else every one.
    let fitted: &Dataset3 = still_data.as_ref().unwrap_or(&data);
    let points = &fitted.points;

    // `covered`: the calibrated samples' coverage of the sphere.
    let (fit, effects_fit, elapsed, models, covered) = if extra.is_empty() {
        let (fit, elapsed, models) = fit_base_models3(points, base);
        let (fit, covered) =
            fit.map_err(|e| refusal(anyhow::Error::new(e), &file, still.as_ref(), &extra))?;
        (fit, None, elapsed, models, covered)
    } else {
        let started = Instant::now();
        let (fit, effects_fit) = fit_effects3(fitted, base, &extra)
            .map_err(|e| refusal(e, &file, still.as_ref(), &extra))?;
        let elapsed = started.elapsed().as_secs_f64();
        // The samples used (not the flagged ones), with the extras removed.
        let covered = fieldcal::model::sphere::coverage(
            effects_fit
                .calibrated
                .iter()
                .enumerate()
                .filter(|(i, _)| effects_fit.flagged.binary_search(i).is_err())
                .map(|(_, &c)| c),
        );
        (
            fit,
            Some(effects_fit),
            elapsed,
            model_table(points),
            covered,
        )
    };
    let supported: Vec<Ellipsoid3Model> = Ellipsoid3Model::ALL
        .into_iter()
        .filter(|&m| ellipsoid::supports_covered(m, &covered))
        .collect();
    let extras = extras3(effects_fit.as_ref(), &extra, &models, fitted);

    if let Some(output) = &args.output {
        write_output3(output, &data, &fit, effects_fit.as_ref(), &file)?;
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
            extras.as_ref(),
        ))? + "\n"
    } else {
        render_text3(
            &fit,
            source,
            units.as_deref(),
            &supported,
            &models,
            still.as_ref(),
            extras.as_ref(),
        )
    };
    write_stdout(text.as_bytes())
}

/// The options of a 2-axis fit, refused with three axes.
fn refuse_2d_options(args: &FitArgs) -> Result<()> {
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
    Ok(())
}

/// With --still: the still poses' samples (the ones fitted) and their
/// summary; without it, none.
fn still_selection(
    args: &FitArgs,
    data: &Dataset3,
    file: &str,
) -> Result<(Option<Dataset3>, Option<StillSummary>)> {
    if args.still {
        let gyro = still_gyro(args, data, file)?;
        let poses = find_still(
            &data.points,
            data.t.as_deref(),
            gyro.as_ref().map(|(_, r)| r.as_slice()),
        )
        .with_context(|| format!("{file}: no still poses"))?;
        let indices: Vec<usize> = poses.indices().collect();
        let summary = StillSummary::new(&poses, data.len(), gyro.map(|(names, _)| names));
        Ok((Some(select3(data, &indices)), Some(summary)))
    } else {
        Ok((None, None))
    }
}

/// The fit of `base` to `points` with the coverage of the points it
/// calibrates (and the seconds the fit took, beside the other fits), and
/// every base model's row of the table: the three fits at once, on every
/// core, the others' rms and r alone. A refusal of `base` comes once the
/// others are done too.
fn fit_base_models3(
    points: &[[f64; 3]],
    base: Ellipsoid3Model,
) -> (FitAndCoverage, f64, Vec<ModelRms>) {
    enum Outcome {
        // Boxed: the base fit is several hundred bytes, the others' two numbers.
        Base(Box<FitAndCoverage>, f64),
        Other(Result<ellipsoid::FitSummary, Ellipsoid3Error>),
    }
    let outcomes = fieldcal::parallel::map_in_order(&Ellipsoid3Model::ALL, |&m| {
        if m == base {
            let started = Instant::now();
            let fit = ellipsoid::fit(points, m);
            let seconds = started.elapsed().as_secs_f64();
            // Here, while the other core still fits the other models.
            let fit = fit.map(|f| {
                let covered = fieldcal::model::sphere::coverage(points.iter().map(|&p| f.apply(p)));
                (f, covered)
            });
            Outcome::Base(Box::new(fit), seconds)
        } else {
            Outcome::Other(ellipsoid::fit_summary(points, m))
        }
    });
    let mut base_fit = None;
    let mut rows = Vec::with_capacity(outcomes.len());
    for (outcome, m) in outcomes.into_iter().zip(Ellipsoid3Model::ALL) {
        rows.push(match outcome {
            Outcome::Base(result, seconds) => {
                let result = *result;
                let row = model_row(
                    m,
                    result
                        .as_ref()
                        .map(|(f, _)| ellipsoid::FitSummary { rms: f.rms, r: f.r })
                        .map_err(Clone::clone),
                );
                base_fit = Some((result, seconds));
                row
            }
            Outcome::Other(result) => model_row(m, result),
        });
    }
    let (fit, elapsed) = base_fit.expect("the base model is one of Ellipsoid3Model::ALL");
    (fit, elapsed, rows)
}

/// A base model's fit and its calibrated samples' coverage of the sphere.
type FitAndCoverage =
    Result<(Ellipsoid3Fit, fieldcal::model::sphere::SphereCoverage), Ellipsoid3Error>;

/// Every base model's rms and r on the fitted samples `points`, or why it
/// was refused: the three fits at once, on every core.
fn model_table(points: &[[f64; 3]]) -> Vec<ModelRms> {
    fieldcal::parallel::map_in_order(&Ellipsoid3Model::ALL, |&m| {
        model_row(m, ellipsoid::fit_summary(points, m))
    })
}

/// A model's row of the table: its rms and r, or why it was refused.
fn model_row(
    model: Ellipsoid3Model,
    fitted: Result<ellipsoid::FitSummary, Ellipsoid3Error>,
) -> ModelRms {
    match fitted {
        Ok(s) => ModelRms {
            model: model.name(),
            rms: Some(s.rms),
            r: Some(s.r),
            refused: None,
        },
        Err(e) => ModelRms {
            model: model.name(),
            rms: None,
            r: None,
            refused: Some(e.to_string()),
        },
    }
}

/// What a fit with extra effects adds to the report: the extras' own
/// parameters, the flagged samples, and the base model's rms beside it.
fn extras3(
    effects_fit: Option<&Ellipsoid3EffectsFit>,
    extra: &[Effect],
    models: &[ModelRms],
    fitted: &Dataset3,
) -> Option<Extras3> {
    effects_fit.map(|e| Extras3 {
        effects: e.effects.clone(),
        // o, W's entries and r (listed first, r last) are the base report's;
        // the parameters after r are the extras' own.
        params: e
            .params
            .iter()
            .skip_while(|p| p.name != "r")
            .skip(1)
            .cloned()
            .collect(),
        flagged: extra.contains(&Effect::Outliers).then(|| e.flagged.clone()),
        cubic_scale: e.reference.cubic_scale,
        unknowns: e.unknowns,
        base_rms: models
            .iter()
            .find(|m| m.model == e.model.name())
            .and_then(|m| m.rms),
        t_span: match (e.reference.t_mean, fitted.t.as_deref()) {
            (Some(_), Some(t)) => {
                let (lo, hi) = t
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                        (lo.min(v), hi.max(v))
                    });
                (hi > lo).then_some(hi - lo)
            }
            _ => None,
        },
    })
}

/// `--output`: every sample of `data` calibrated.
fn write_output3(
    output: &std::path::Path,
    data: &Dataset3,
    fit: &Ellipsoid3Fit,
    effects_fit: Option<&Ellipsoid3EffectsFit>,
    file: &str,
) -> Result<()> {
    let calibrated: Vec<[f64; 3]> = match effects_fit {
        Some(e) => e
            .calibrate(data)
            .with_context(|| format!("{file}: cannot calibrate every sample"))?,
        None => data.points.iter().map(|&p| fit.apply(p)).collect(),
    };
    write_calibrated3(output, data.t.as_deref(), &calibrated).with_context(|| {
        format!(
            "cannot write the calibrated samples to {}",
            output.display()
        )
    })
}

/// A 3-D fit's refusal, naming the file and, when the coverage supports a
/// restricted model, how to ask for it.
/// The hint keeps the extra effects asked for (`--effects offset+scale+drift`).
fn refusal(
    err: anyhow::Error,
    file: &str,
    still: Option<&StillSummary>,
    extra: &[Effect],
) -> anyhow::Error {
    let poses = match still {
        Some(s) => format!(" (on {} still poses, {} samples)", s.poses, s.samples),
        None => String::new(),
    };
    match err.downcast_ref::<Ellipsoid3Error>() {
        Some(Ellipsoid3Error::NotCovered {
            supported: Some(m), ..
        }) => {
            let with: String = extra.iter().map(|e| format!("+{e}")).collect();
            anyhow::anyhow!(
                "{file}: no 3-D calibration{poses}: {err}; to fit it: --effects {m}{with}"
            )
        }
        Some(_) => anyhow::anyhow!("{file}: no 3-D calibration{poses}: {err}"),
        None => err.context(format!("{file}: no 3-D calibration")),
    }
}
