//! `fieldcal diagnose`: read a CSV, find which effects the data supports,
//! add them one by one, and say whether what is left is noise.

use anyhow::{Context, Result};
use fieldcal::io::csv::Covariates;
use serde::Serialize;

use fieldcal::model::diagnose::params_text;
use fieldcal::model::diagnose::{Candidate, Diagnosis, Step, diagnose as run_diagnosis};
use fieldcal::model::diagnose3::{
    Candidate3, Diagnosis3, NotDetermined, Residuals3, Step3, diagnose3 as diagnose_3d,
};
use fieldcal::model::effects::{Effect, parse_list};
use fieldcal::model::nonlinear::Param;
use fieldcal::model::residuals::{NoiseFloor, Residuals, SetAside};
use std::path::{Path, PathBuf};

use crate::DiagnoseArgs;
use crate::output::write_stdout;

pub fn diagnose(args: DiagnoseArgs) -> Result<()> {
    if let Some(z) = args.input.z_column()? {
        return diagnose3(args, &z);
    }
    let (data, reference) = args.input.read_with_reference(&Covariates::All)?;
    let file = args.input.file.display().to_string();
    let baseline = baseline_effects(&args, &file, |column| data.covariate(column).is_some())?;
    let mut diagnosis = run_diagnosis(&data, &baseline, reference.as_ref())
        .with_context(|| format!("{file}: no diagnosis"))?;
    if let Some(gyro) = reference
        .as_ref()
        .filter(|_| args.input.gyro_in_recording())
    {
        diagnosis
            .set_aside
            .push(fieldcal::model::residuals::SetAside {
                column: gyro.column().to_string(),
                reason: "the heading reference (--gyro), not a covariate".into(),
            });
    }

    let summary = render_text(&diagnosis, &file);
    if let Some(dir) = &args.report {
        let title = format!("{file}: x = {}, y = {}", data.x_name, data.y_name);
        let report = fieldcal::report::diagnosis::report_data(
            &data,
            &diagnosis,
            reference.as_ref(),
            &title,
            &summary,
        )
        .with_context(|| format!("{file}: cannot refit the models for the report"))?;
        let written = fieldcal::report::plots::write_report(dir, &report)?;
        announce_report(dir, &written);
    }

    let text = if args.json {
        serde_json::to_string(&DiagnosisJson::new(&diagnosis, &file))? + "\n"
    } else {
        summary
    };
    write_stdout(text.as_bytes())
}

/// The model `--effects` asks to start from (`paper` by default), each
/// covariate of it checked against the recording's columns by `has_column`.
fn baseline_effects(
    args: &DiagnoseArgs,
    file: &str,
    has_column: impl Fn(&str) -> bool,
) -> Result<Vec<Effect>> {
    let baseline = parse_list(args.effects.as_deref().unwrap_or("paper"))
        .map_err(anyhow::Error::msg)
        .context("--effects")?;
    for effect in &baseline {
        if let Effect::Covariate(column) = effect
            && !has_column(column)
        {
            anyhow::bail!("--effects: {file}: the recording has no column '{column}'");
        }
    }
    Ok(baseline)
}

/// Tells the person (on stderr) where the report went and which page to
/// open.
fn announce_report(dir: &Path, written: &[PathBuf]) {
    eprintln!(
        "report: {} files in {}; open {}",
        written.len(),
        dir.display(),
        dir.join(fieldcal::report::plots::INDEX_FILE).display()
    );
}

/// The JSON surface: flat numbers where a program wants them (`noise_floor`
/// is the rms, `suggested` a name or null), the full diagnostics beside.
#[derive(Debug, Serialize)]
struct DiagnosisJson<'a> {
    file: &'a str,
    baseline: &'a Step,
    /// Logged columns not offered as covariates: `{column, reason}`.
    set_aside: &'a [SetAside],
    candidates: &'a [Candidate],
    /// The effect to add next, or null when the model is enough.
    suggested: Option<&'a Effect>,
    /// A supported effect within the BIC margin of the suggested one: the
    /// data cannot tell the two apart. Null otherwise.
    close_second: Option<&'a Effect>,
    ladder: &'a [Step],
    noise_floor: f64,
    noise_floor_method: &'a str,
    verdict: &'a str,
    criterion: &'a str,
    /// Whether the heading was checked against a gyro, and what held the
    /// effects when it was not.
    heading: &'a str,
    baseline_residuals: &'a Residuals,
    final_residuals: &'a Residuals,
}

impl<'a> DiagnosisJson<'a> {
    fn new(d: &'a Diagnosis, file: &'a str) -> Self {
        DiagnosisJson {
            file,
            baseline: &d.baseline,
            set_aside: &d.set_aside,
            candidates: &d.candidates,
            suggested: d.suggested.as_ref(),
            close_second: d.close_second.as_ref(),
            ladder: &d.ladder,
            noise_floor: d.noise_floor.rms,
            noise_floor_method: &d.noise_floor.method,
            verdict: &d.verdict,
            criterion: &d.criterion,
            heading: &d.heading,
            baseline_residuals: &d.baseline_residuals,
            final_residuals: &d.final_residuals,
        }
    }
}

fn pct(fraction: f64) -> String {
    format!("{:.3} %", fraction * 100.0)
}

/// One candidate's row: its effect, rms, what `heading` says (empty
/// without a gyro), ΔBIC, whether it is supported, and why.
fn candidate_row(
    effect: &Effect,
    rms: f64,
    heading: &str,
    delta_bic: f64,
    supported: bool,
    evidence: &str,
) -> String {
    format!(
        "  {:<22} rms {:>9}  {heading}ΔBIC {:>9.1}  {}  {}\n",
        effect.to_string(),
        pct(rms),
        delta_bic,
        if supported {
            "supported    "
        } else {
            "not supported"
        },
        evidence
    )
}

/// The candidates' rows, best first, and the suggestion (with a close
/// second, `undecided` is what follows "cannot tell them apart").
fn candidates_and_suggestion(
    out: &mut String,
    rows: Vec<String>,
    (suggested, close_second): (&Option<Effect>, &Option<Effect>),
    undecided: &str,
) {
    if rows.is_empty() {
        out.push_str("candidates: none could be fitted\n");
    } else {
        out.push_str("candidates, best first:\n");
        for row in rows {
            out.push_str(&row);
        }
    }
    match (suggested, close_second) {
        (Some(effect), Some(second)) => out.push_str(&format!(
            "suggested: {effect}, though {second} explains the residual about as well (BIC within {margin}): this recording cannot tell them apart{undecided}\n\n",
            margin = fieldcal::model::diagnose::BIC_MARGIN
        )),
        (Some(effect), None) => out.push_str(&format!("suggested: {effect}\n\n")),
        (None, _) => out.push_str("suggested: none (the model is enough)\n\n"),
    }
}

/// A step's rms against the noise floor, for the ladder.
fn noise_ratio(rms: f64, floor: f64) -> String {
    if floor > 0.0 {
        format!("{:.2}× the noise floor", rms / floor)
    } else {
        String::from("no noise floor")
    }
}

/// The baseline's line of the text report.
fn baseline_line(out: &mut String, model: &str, rms: f64, unknowns: usize) {
    out.push_str(&format!(
        "baseline  {model}: rms {} of the field ({unknowns} unknowns)\n",
        pct(rms),
    ));
}

/// The noise floor's line, and a line per column set aside.
fn floor_and_set_aside(out: &mut String, floor: &NoiseFloor, set_aside: &[SetAside]) {
    out.push_str(&format!(
        "noise floor  {} ({})\n\n",
        pct(floor.rms),
        floor.method
    ));
    for aside in set_aside {
        out.push_str(&format!("set aside  {}: {}\n", aside.column, aside.reason));
    }
}

/// The two lines of step `i` of the ladder: its model, rms and rms against
/// the noise floor (with `inside` added in the parentheses, `after` after
/// them), then its parameters.
fn ladder_step(
    out: &mut String,
    i: usize,
    (model, rms, params): (&str, f64, &[Param]),
    floor: f64,
    (inside, after): (&str, &str),
) {
    let ratio = noise_ratio(rms, floor);
    out.push_str(&format!(
        "  {i}. {:<40} rms {:>9}  ({ratio}{inside}){after}\n",
        model,
        pct(rms)
    ));
    out.push_str(&format!("     {}\n", params_text(params)));
}

fn render_text(d: &Diagnosis, file: &str) -> String {
    let mut out = String::new();
    out.push_str(&format!("{file}\n"));
    baseline_line(
        &mut out,
        &d.baseline.model,
        d.baseline.rms,
        d.baseline.unknowns,
    );
    floor_and_set_aside(&mut out, &d.noise_floor, &d.set_aside);
    if !d.set_aside.is_empty() {
        out.push('\n');
    }
    let rows = d.candidates.iter().map(|c| {
        let heading = c.extra.heading_vs_gyro.as_ref().map_or(String::new(), |h| {
            format!("heading {:.2}° rms  ", h.rms_deg)
        });
        candidate_row(
            &c.effect,
            c.rms,
            &heading,
            c.delta_bic,
            c.supported,
            &c.evidence,
        )
    });
    candidates_and_suggestion(
        &mut out,
        rows.collect(),
        (&d.suggested, &d.close_second),
        "; more turns, or the cause varying at other headings, would",
    );
    out.push_str("ladder:\n");
    for (i, step) in d.ladder.iter().enumerate() {
        let heading = step.heading_vs_gyro.as_ref().map_or(String::new(), |h| {
            format!(
                "  heading {:.2}° rms, {:.2}° peak to peak against {}",
                h.rms_deg, h.peak_to_peak_deg, h.gyro_column
            )
        });
        ladder_step(
            &mut out,
            i,
            (&step.model, step.rms, &step.params),
            d.noise_floor.rms,
            ("", &heading),
        );
    }
    out.push_str(&format!("  noise floor {}\n\n", pct(d.noise_floor.rms)));
    out.push_str(&format!("{}\n", d.heading));
    out.push_str(&format!("verdict: {}\n", d.verdict));
    out.push_str(&format!("criterion: {}\n", d.criterion));
    out
}

/// `diagnose` on three axes: the 3-D model's ladder (model::diagnose3).
fn diagnose3(args: DiagnoseArgs, z: &str) -> Result<()> {
    let file = args.input.file.display().to_string();
    if args.input.gyro.is_some() {
        anyhow::bail!(
            "{file}: --gyro checks the heading of a turn in one plane and has no 3-D form; drop --gyro, or choose two axes with --x and --y"
        );
    }
    let data = args.input.read3_gated(z, &Covariates::All)?;
    let baseline = baseline_effects(&args, &file, |column| data.covariate(column).is_some())?;
    let diagnosis =
        diagnose_3d(&data, &baseline).with_context(|| format!("{file}: no diagnosis"))?;
    let summary = render_text3(&diagnosis, &file, &data);
    if let Some(dir) = &args.report {
        let title = format!(
            "{file}: x = {}, y = {}, z = {}",
            data.x_name, data.y_name, data.z_name
        );
        let report =
            fieldcal::report::diagnosis3::report3_data(&data, &diagnosis, &title, &summary)
                .with_context(|| format!("{file}: cannot refit the models for the report"))?;
        let written = fieldcal::report::plots3::write_report3(dir, &report)?;
        announce_report(dir, &written);
    }
    let text = if args.json {
        serde_json::to_string(&Diagnosis3Json::new(&diagnosis, &file, &data))? + "\n"
    } else {
        summary
    };
    write_stdout(text.as_bytes())
}

/// The 3-D JSON surface: the 2-D keys (`baseline`, `candidates`,
/// `suggested`, `close_second`, `ladder`, `noise_floor`, `verdict`,
/// `criterion`), plus `axes`, the columns, `coverage` and `not_determined`.
#[derive(Debug, Serialize)]
struct Diagnosis3Json<'a> {
    file: &'a str,
    axes: u8,
    x_column: &'a str,
    y_column: &'a str,
    z_column: &'a str,
    baseline: &'a Step3,
    baseline_note: Option<&'a str>,
    set_aside: &'a [SetAside],
    candidates: &'a [Candidate3],
    not_determined: &'a [NotDetermined],
    suggested: Option<&'a Effect>,
    close_second: Option<&'a Effect>,
    ladder: &'a [Step3],
    noise_floor: f64,
    noise_floor_method: &'a str,
    coverage: CoverageJson<'a>,
    verdict: &'a str,
    criterion: &'a str,
    baseline_residuals: &'a Residuals3,
    final_residuals: &'a Residuals3,
}

#[derive(Debug, Serialize)]
struct CoverageJson<'a> {
    fraction: f64,
    regions: usize,
    covered: usize,
    missing: &'a [fieldcal::model::sphere::MissingDirections],
}

impl<'a> Diagnosis3Json<'a> {
    fn new(d: &'a Diagnosis3, file: &'a str, data: &'a fieldcal::sample::Dataset3) -> Self {
        Diagnosis3Json {
            file,
            axes: 3,
            x_column: &data.x_name,
            y_column: &data.y_name,
            z_column: &data.z_name,
            baseline: &d.baseline,
            baseline_note: d.baseline_note.as_deref(),
            set_aside: &d.set_aside,
            candidates: &d.candidates,
            not_determined: &d.not_determined,
            suggested: d.suggested.as_ref(),
            close_second: d.close_second.as_ref(),
            ladder: &d.ladder,
            noise_floor: d.noise_floor.rms,
            noise_floor_method: &d.noise_floor.method,
            coverage: CoverageJson {
                fraction: d.coverage.fraction,
                regions: d.coverage.regions,
                covered: d.coverage.covered,
                missing: &d.coverage.missing,
            },
            verdict: &d.verdict,
            criterion: &d.criterion,
            baseline_residuals: &d.baseline_residuals,
            final_residuals: &d.final_residuals,
        }
    }
}

fn render_text3(d: &Diagnosis3, file: &str, data: &fieldcal::sample::Dataset3) -> String {
    let mut out = format!(
        "{file}\naxes  x = {}, y = {}, z = {} (3-D)\n",
        data.x_name, data.y_name, data.z_name
    );
    baseline_line(
        &mut out,
        &d.baseline.model,
        d.baseline.rms,
        d.baseline.unknowns,
    );
    if let Some(note) = &d.baseline_note {
        out.push_str(&format!("           {note}\n"));
    }
    out.push_str(&format!(
        "coverage  {:.0} % of the sphere ({} of {} regions); {}\n",
        d.coverage.fraction * 100.0,
        d.coverage.covered,
        d.coverage.regions,
        d.coverage.missing_text()
    ));
    floor_and_set_aside(&mut out, &d.noise_floor, &d.set_aside);
    for n in &d.not_determined {
        out.push_str(&format!("not determined  {}: {}\n", n.effect, n.reason));
    }
    if !d.set_aside.is_empty() || !d.not_determined.is_empty() {
        out.push('\n');
    }
    let rows = d
        .candidates
        .iter()
        .map(|c| candidate_row(&c.effect, c.rms, "", c.delta_bic, c.supported, &c.evidence));
    candidates_and_suggestion(
        &mut out,
        rows.collect(),
        (&d.suggested, &d.close_second),
        "",
    );
    out.push_str("ladder:\n");
    for (i, step) in d.ladder.iter().enumerate() {
        let flagged = if step.flagged > 0 {
            format!(", {} flagged", step.flagged)
        } else {
            String::new()
        };
        ladder_step(
            &mut out,
            i,
            (&step.model, step.rms, &step.params),
            d.noise_floor.rms,
            (&flagged, ""),
        );
    }
    out.push_str(&format!("  noise floor {}\n\n", pct(d.noise_floor.rms)));
    out.push_str(&format!("verdict: {}\n", d.verdict));
    out.push_str(&format!("criterion: {}\n", d.criterion));
    out
}
