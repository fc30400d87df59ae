//! `fieldcal diagnose`: read a CSV, find which effects the data supports,
//! add them one by one, and say whether what is left is noise.

use anyhow::{Context, Result};
use serde::Serialize;

use fieldcal::model::diagnose::params_text;
use fieldcal::model::diagnose::{Candidate, Diagnosis, Step, diagnose as run_diagnosis};
use fieldcal::model::diagnose3::{
    Candidate3, Diagnosis3, NotDetermined, Residuals3, Step3, diagnose3 as diagnose_3d,
};
use fieldcal::model::effects::{Effect, parse_list};
use fieldcal::model::residuals::{Residuals, SetAside};

use crate::DiagnoseArgs;
use crate::output::write_stdout;

pub fn diagnose(args: DiagnoseArgs) -> Result<()> {
    if let Some(z) = args.input.z_column()? {
        return diagnose3(args, &z);
    }
    let (data, reference) = args.input.read_with_reference()?;
    let baseline = parse_list(args.effects.as_deref().unwrap_or("paper"))
        .map_err(anyhow::Error::msg)
        .context("--effects")?;
    for effect in &baseline {
        if let Effect::Covariate(column) = effect
            && data.covariate(column).is_none()
        {
            anyhow::bail!(
                "--effects: {}: the recording has no column '{column}'",
                args.input.file.display()
            );
        }
    }
    let file = args.input.file.display().to_string();
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
        let report = fieldcal::report::diagnosis::report_data(&data, &diagnosis, &title, &summary)
            .with_context(|| format!("{file}: cannot refit the models for the report"))?;
        let written = fieldcal::report::plots::write_report(dir, &report)?;
        eprintln!(
            "report: {} files in {}; open {}",
            written.len(),
            dir.display(),
            dir.join(fieldcal::report::plots::INDEX_FILE).display()
        );
    }

    let text = if args.json {
        serde_json::to_string(&DiagnosisJson::new(&diagnosis, &file))? + "\n"
    } else {
        summary
    };
    write_stdout(text.as_bytes())
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

fn render_text(d: &Diagnosis, file: &str) -> String {
    let mut out = String::new();
    out.push_str(&format!("{file}\n"));
    out.push_str(&format!(
        "baseline  {}: rms {} of the field ({} unknowns)\n",
        d.baseline.model,
        pct(d.baseline.rms),
        d.baseline.unknowns
    ));
    out.push_str(&format!(
        "noise floor  {} ({})\n\n",
        pct(d.noise_floor.rms),
        d.noise_floor.method
    ));
    for aside in &d.set_aside {
        out.push_str(&format!("set aside  {}: {}\n", aside.column, aside.reason));
    }
    if !d.set_aside.is_empty() {
        out.push('\n');
    }
    let rows = d.candidates.iter().map(|c| {
        let heading = c.heading_vs_gyro.as_ref().map_or(String::new(), |h| {
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
        let ratio = noise_ratio(step.rms, d.noise_floor.rms);
        let heading = step.heading_vs_gyro.as_ref().map_or(String::new(), |h| {
            format!(
                "  heading {:.2}° rms, {:.2}° peak to peak against {}",
                h.rms_deg, h.peak_to_peak_deg, h.gyro_column
            )
        });
        out.push_str(&format!(
            "  {i}. {:<40} rms {:>9}  ({ratio}){heading}\n",
            step.model,
            pct(step.rms)
        ));
        out.push_str(&format!("     {}\n", params_text(&step.params)));
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
    let data = args.input.read3(z)?;
    let baseline = parse_list(args.effects.as_deref().unwrap_or("paper"))
        .map_err(anyhow::Error::msg)
        .context("--effects")?;
    for effect in &baseline {
        if let Effect::Covariate(column) = effect
            && data.covariate(column).is_none()
        {
            anyhow::bail!("--effects: {file}: the recording has no column '{column}'");
        }
    }
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
        eprintln!(
            "report: {} files in {}; open {}",
            written.len(),
            dir.display(),
            dir.join(fieldcal::report::plots::INDEX_FILE).display()
        );
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
    out.push_str(&format!(
        "baseline  {}: rms {} of the field ({} unknowns)\n",
        d.baseline.model,
        pct(d.baseline.rms),
        d.baseline.unknowns
    ));
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
    out.push_str(&format!(
        "noise floor  {} ({})\n\n",
        pct(d.noise_floor.rms),
        d.noise_floor.method
    ));
    for aside in &d.set_aside {
        out.push_str(&format!("set aside  {}: {}\n", aside.column, aside.reason));
    }
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
        let ratio = noise_ratio(step.rms, d.noise_floor.rms);
        let flagged = if step.flagged > 0 {
            format!(", {} flagged", step.flagged)
        } else {
            String::new()
        };
        out.push_str(&format!(
            "  {i}. {:<40} rms {:>9}  ({ratio}{flagged})\n",
            step.model,
            pct(step.rms)
        ));
        out.push_str(&format!("     {}\n", params_text(&step.params)));
    }
    out.push_str(&format!("  noise floor {}\n\n", pct(d.noise_floor.rms)));
    out.push_str(&format!("verdict: {}\n", d.verdict));
    out.push_str(&format!("criterion: {}\n", d.criterion));
    out
}
