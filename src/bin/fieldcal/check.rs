//! `fieldcal check`: does a stored calibration hold on another recording?

use anyhow::{Context, Result};
use fieldcal::io::csv::Covariates;

use fieldcal::model::check::{
    CheckReport, ParamShift, StoredCalibration, check as check_calibration, parse_stored,
};
use fieldcal::model::check3::{Check3Report, check3, is_three_axes, parse_stored3};
use fieldcal::model::gyro::HeadingReference;
use fieldcal::model::trust::{GyroModel, RecordingTrust, TrustLimits, monitor_recording};
use fieldcal::report::significant;

use crate::CheckArgs;
use crate::output::write_stdout;

/// A calibration file is a few kilobytes; anything far larger is not one.
const MAX_CALIBRATION_BYTES: u64 = 1 << 20;

pub fn check(args: CheckArgs) -> Result<()> {
    let cal_path = &args.calibration;
    let cal_name = cal_path.display();
    // A regular file only (a FIFO or device is refused before it blocks).
    let bytes = fieldcal::io::regular::read_regular(cal_path, MAX_CALIBRATION_BYTES)
        .map_err(|e| match e.kind() {
            std::io::ErrorKind::InvalidData => anyhow::anyhow!(
                "{cal_name}: {e}: not a calibration file (the JSON of `fieldcal fit --json` or a daemon state file is a few kilobytes)"
            ),
            _ => anyhow::Error::new(e).context(format!("{cal_name}: cannot read the calibration file")),
        })?;
    if let Some(root) = serde_json::from_slice::<serde_json::Value>(&bytes)
        .ok()
        .filter(is_three_axes)
    {
        return check_three(&args, &root);
    }
    if args.input.z.is_some() {
        anyhow::bail!(
            "{cal_name}: a 2-axis calibration, checked on two columns: leave out --z (or give the calibration of a 3-axis fit, `fieldcal fit FILE --z COL --json`)"
        );
    }
    let stored = parse_stored(&bytes).with_context(|| format!("{cal_name}"))?;
    let (data, reference) = args.input.read_with_reference(&Covariates::All)?;
    let file = args.input.file.display().to_string();
    let checked = check_calibration(&data, &stored, reference.as_ref(), args.min_coverage)
        .with_context(|| format!("{file}: cannot check {cal_name} against it"));
    if !args.monitor {
        let report = checked?;
        let text = if args.json {
            serde_json::to_string(&report)? + "\n"
        } else {
            render(
                &report,
                &file,
                &cal_name.to_string(),
                &data.x_name,
                &data.y_name,
            )
        };
        return write_stdout(text.as_bytes());
    }
    // The monitor judges every reading even where the recording cannot be
    // refitted (a log that mostly stands still): the refit's reason is said.
    let (report, unchecked) = match checked {
        Ok(report) => (Some(report), None),
        Err(e) => (None, Some(format!("{e:#}"))),
    };
    let monitored = monitor(&data, &stored, reference.as_ref(), report.as_ref())
        .with_context(|| format!("{file}: cannot monitor {cal_name} over it"))?;
    let text = match &report {
        Some(report) => render(
            report,
            &file,
            &cal_name.to_string(),
            &data.x_name,
            &data.y_name,
        ),
        None => String::new(),
    };
    let json = serde_json::to_value(&report)?;
    publish_monitor(&args, &file, text, (json, unchecked), &monitored)
}

/// The monitor's result after the check's own `text`: why the parameters
/// were not compared (`unchecked`), the stretches, the report when asked
/// for; or all of it as JSON (`check`: the check's).
fn publish_monitor(
    args: &CheckArgs,
    file: &str,
    mut text: String,
    (check, unchecked): (serde_json::Value, Option<String>),
    monitored: &Monitored,
) -> Result<()> {
    if let Some(why) = &unchecked {
        text.push_str(&format!("parameters  not compared: {why}\n"));
    }
    if let Some(what) = monitored.only {
        text.push_str(&format!("checked     {what}\n"));
    }
    text.push_str(&render_monitor(&monitored.trust));
    if let Some(dir) = &args.report {
        let written = fieldcal::report::monitor::write_monitor_report(
            dir,
            &fieldcal::report::monitor::MonitorData {
                title: format!("{file} under {}", args.calibration.display()),
                summary: text.clone(),
                t: &monitored.t,
                field_ratio: &monitored.field_ratio,
                trust: &monitored.trust,
            },
        )
        .with_context(|| format!("{}: cannot write the report", dir.display()))?;
        if let Some(page) = written.last() {
            text.push_str(&format!("report      {}\n", page.display()));
        }
    }
    if args.json {
        let json = serde_json::json!({
            "check": check,
            "not_compared": unchecked,
            "checked": monitored.only,
            "monitor": monitored.trust,
        });
        return write_stdout((json.to_string() + "\n").as_bytes());
    }
    write_stdout(text.as_bytes())
}

/// The monitor's judgement of every reading, with what it was judged on.
struct Monitored {
    t: Vec<f64>,
    field_ratio: Vec<f64>,
    trust: RecordingTrust,
    /// What the monitor checked, when that is less than the daemon would.
    only: Option<&'static str>,
}

/// The times of a recording the monitor judges.
fn times_of(t: Option<&Vec<f64>>) -> Result<Vec<f64>> {
    t.cloned().ok_or_else(|| {
        anyhow::anyhow!(
            "--monitor judges readings over time, and the recording has no time column (t, t_s, time or time_s; choose one with --t)"
        )
    })
}

/// Runs the daemon's trust monitor over the recording under the stored
/// calibration: the field against the calibration's own noise (its rms;
/// the rms here when the file gives none), and with a gyro, the heading
/// against it (its scale and bias from the heading check).
fn monitor(
    data: &fieldcal::sample::Dataset,
    stored: &StoredCalibration,
    reference: Option<&HeadingReference>,
    report: Option<&CheckReport>,
) -> Result<Monitored> {
    let t = times_of(data.t.as_ref())?;
    let applied = stored.apply(data)?;
    let field_ratio: Vec<f64> = applied.iter().map(|&(_, _, e)| 1.0 + e).collect();
    let headings_rad: Vec<f64> = applied.iter().map(|&(sx, sy, _)| sy.atan2(sx)).collect();
    let heading = match (report.and_then(|r| r.heading_vs_gyro.clone()), reference) {
        (Some(h), _) => Some(h),
        (None, Some(r)) => r.check(&headings_rad, &[]).ok(),
        (None, None) => None,
    };
    let rms = stored.rms.or(report.map(|r| r.rms)).unwrap_or_else(|| {
        let ss: f64 = applied.iter().map(|&(_, _, e)| e * e).sum();
        (ss / applied.len().max(1) as f64).sqrt()
    });
    // The heading's noise from the middle of its errors (1.4826 × their
    // median absolute deviation): the stretches the monitor is to find
    // are in this recording, and must not widen its own limit.
    let limits = TrustLimits::from_rms(
        rms,
        heading.as_ref().map(robust_heading_sigma),
        heading.as_ref().map(|h| GyroModel {
            scale: h.gyro_scale,
            bias_deg_s: h.gyro_bias_deg_s,
        }),
    );
    let heading_deg: Vec<f64> = headings_rad
        .iter()
        .map(|h| h.to_degrees().rem_euclid(360.0))
        .collect();
    let trust = monitor_recording(
        limits,
        &t,
        &field_ratio,
        &heading_deg,
        reference.map(HeadingReference::angles_deg),
    );
    Ok(Monitored {
        t,
        field_ratio,
        trust,
        only: None,
    })
}

/// The trust monitor over a 3-axis recording under a 3-D calibration: the
/// field's magnitude against the calibration's own noise (its rms; the
/// rms here when the file gives none), as the daemon checks a 3-axis
/// sensor's. The dip and the heading against a gyro need the
/// accelerometer beside each reading, which `check` does not read.
fn monitor_three(
    data: &fieldcal::sample::Dataset3,
    stored: &fieldcal::model::check3::Stored3,
    report: Option<&Check3Report>,
) -> Result<Monitored> {
    let t = times_of(data.t.as_ref())?;
    let r = stored.calibration.r;
    let field_ratio: Vec<f64> = data
        .points
        .iter()
        .map(|&p| {
            let s = stored.apply(p);
            (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt() / r
        })
        .collect();
    let rms = stored.rms.or(report.map(|r| r.rms)).unwrap_or_else(|| {
        let ss: f64 = field_ratio.iter().map(|f| (f - 1.0).powi(2)).sum();
        (ss / field_ratio.len().max(1) as f64).sqrt()
    });
    let headings = vec![0.0; field_ratio.len()];
    let trust = monitor_recording(
        TrustLimits::from_rms(rms, None, None),
        &t,
        &field_ratio,
        &headings,
        None,
    );
    Ok(Monitored {
        t,
        field_ratio,
        trust,
        only: Some(
            "the field only: a 3-axis compass's dip and its heading against a gyro need the accelerometer beside each reading (the daemon checks them live with `tilt` and `gyro`)",
        ),
    })
}

/// The heading check's error scatter, robust to the stretches a
/// disturbance adds: 1.4826 × the median absolute deviation of its
/// errors (the rms when there are too few).
fn robust_heading_sigma(h: &fieldcal::model::gyro::HeadingCheck) -> f64 {
    let mut e: Vec<f64> = h
        .errors_deg
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .collect();
    if e.len() < 10 {
        return h.rms_deg;
    }
    let median = |v: &mut Vec<f64>| {
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    let m = median(&mut e);
    let mut dev: Vec<f64> = e.iter().map(|v| (v - m).abs()).collect();
    fieldcal::model::tilt::MAD_TO_SIGMA * median(&mut dev)
}

/// Most stretches the text lists (`--json` lists up to
/// [`fieldcal::model::trust::MAX_STRETCHES`]).
const TEXT_STRETCHES: usize = 50;

fn render_monitor(trust: &RecordingTrust) -> String {
    let c = trust.counts;
    let all = c.trusted + c.distrusted;
    let mut out = format!(
        "monitor     {} of {} readings trusted ({:.1} %); field limit ±{:.2} % (5 σ of the calibration's noise); {}; longest distrusted stretch {:.2} s\n",
        c.trusted,
        all,
        if all > 0 {
            100.0 * c.trusted as f64 / all as f64
        } else {
            0.0
        },
        trust.field_limit * 100.0,
        if trust.gyro_checked {
            "heading checked against the gyro"
        } else {
            "no gyro: the heading's change not checked"
        },
        c.longest_distrusted_s
    );
    for s in trust.stretches.iter().take(TEXT_STRETCHES) {
        out.push_str(&format!(
            "distrusted  {:.2}–{:.2} s ({} reading{}): {}\n",
            s.from_s,
            s.to_s,
            s.readings,
            if s.readings == 1 { "" } else { "s" },
            s.reason
        ));
    }
    let more = trust.stretches.len().saturating_sub(TEXT_STRETCHES) + trust.stretches_left_out;
    if more > 0 {
        out.push_str(&format!(
            "distrusted  and {more} more stretches (--json lists the first {})\n",
            fieldcal::model::trust::MAX_STRETCHES
        ));
    }
    out
}

fn render(report: &CheckReport, file: &str, cal: &str, x: &str, y: &str) -> String {
    let mut out = String::new();
    let mut line = |label: &str, value: String| {
        out.push_str(format!("{label:<12}{value}").trim_end());
        out.push('\n');
    };
    line("file", file.to_string());
    line("axes", format!("x = {x}, y = {y}"));
    line("calibration", format!("{cal} ({})", report.model));
    line(
        "rms",
        format!(
            "{:.3} % with the stored calibration, {:.3} % refitted here{}",
            report.rms * 100.0,
            report.refitted_rms * 100.0,
            report
                .stored_rms
                .map(|r| format!(" ({:.3} % on its own recording)", r * 100.0))
                .unwrap_or_default()
        ),
    );
    if let (Some(h), Some(r)) = (&report.heading_vs_gyro, &report.refitted_heading_vs_gyro) {
        line(
            "heading",
            format!(
                "{:.2}° rms, {:.2}° p-p against '{}' with the stored calibration; {:.2}° rms refitted here",
                h.rms_deg, h.peak_to_peak_deg, h.gyro_column, r.rms_deg
            ),
        );
    }
    for (label, value) in parameter_rows(
        &report.parameters,
        report.z_threshold,
        report.family_false_alarm,
    ) {
        line(&label, value);
    }
    line("verdict", report.verdict.clone());
    out
}

/// `check` of a 3-D calibration (`fit --json` on three axes, or a daemon
/// state file of a 3-axis sensor) on a 3-axis recording. The columns are
/// --x/--y/--z, else those the calibration was fitted to, else x, y, z.
fn check_three(args: &CheckArgs, root: &serde_json::Value) -> Result<()> {
    let cal_name = args.calibration.display().to_string();
    let stored = parse_stored3(root).with_context(|| cal_name.clone())?;
    if args.input.gyro.is_some() {
        anyhow::bail!(
            "--gyro checks a 2-axis heading; a 3-D calibration's heading needs the accelerometer: `fieldcal heading FILE --mag-cal {cal_name} --accel X,Y,Z --gyro COLUMN`"
        );
    }
    let stored_column = |k: usize, default: &str| {
        stored
            .columns
            .as_ref()
            .map_or_else(|| default.to_string(), |c| c[k].clone())
    };
    let spec = fieldcal::io::csv::ColumnSpec {
        x: args
            .input
            .x
            .clone()
            .unwrap_or_else(|| stored_column(0, "x")),
        y: args
            .input
            .y
            .clone()
            .unwrap_or_else(|| stored_column(1, "y")),
        t: args.input.t.clone(),
        read_time: true,
    };
    let z = args
        .input
        .z
        .clone()
        .unwrap_or_else(|| stored_column(2, "z"));
    let data = crate::without_spikes3(
        &args.input.file,
        fieldcal::io::csv::read_dataset3(&args.input.file, &spec, &z)?,
    );
    let file = args.input.file.display().to_string();
    let checked = check3(&data.points, &stored)
        .with_context(|| format!("{file}: cannot check {cal_name} against it"));
    let axes = [
        data.x_name.as_str(),
        data.y_name.as_str(),
        data.z_name.as_str(),
    ];
    if args.monitor {
        // As in 2-D: every reading is judged even where the recording
        // cannot be refitted, and the refit's reason is said.
        let (report, unchecked) = match checked {
            Ok(report) => (Some(report), None),
            Err(e) => (None, Some(format!("{e:#}"))),
        };
        let monitored = monitor_three(&data, &stored, report.as_ref())
            .with_context(|| format!("{file}: cannot monitor {cal_name} over it"))?;
        let text = report
            .as_ref()
            .map(|r| render3(r, &file, &cal_name, axes))
            .unwrap_or_default();
        let json = serde_json::to_value(&report)?;
        return publish_monitor(args, &file, text, (json, unchecked), &monitored);
    }
    let report = checked?;
    let text = if args.json {
        serde_json::to_string(&report)? + "\n"
    } else {
        render3(&report, &file, &cal_name, axes)
    };
    write_stdout(text.as_bytes())
}

fn render3(report: &Check3Report, file: &str, cal: &str, axes: [&str; 3]) -> String {
    let mut out = String::new();
    let mut line = |label: &str, value: String| {
        out.push_str(format!("{label:<12}{value}").trim_end());
        out.push('\n');
    };
    let units = report
        .units
        .as_deref()
        .map(|u| format!(", {u}"))
        .unwrap_or_default();
    line("file", file.to_string());
    line(
        "axes",
        format!(
            "x = {}, y = {}, z = {} ({} samples)",
            axes[0], axes[1], axes[2], report.n
        ),
    );
    line(
        "calibration",
        format!("{cal} ({}, 3-D{units})", report.model),
    );
    line(
        "rms",
        format!(
            "{:.3} % with the stored calibration{}; mean |calibrated|/r {:.4}",
            report.rms * 100.0,
            report
                .stored_rms
                .map(|r| format!(" ({:.3} % on its own recording)", r * 100.0))
                .unwrap_or_default(),
            report.magnitude_ratio
        ),
    );
    line(
        "coverage",
        format!(
            "{:.0} % of the sphere ({} of {} regions); {}",
            report.coverage.fraction * 100.0,
            report.coverage.covered,
            report.coverage.regions,
            report.coverage.missing_text()
        ),
    );
    match &report.refit {
        Some(refit) => {
            line(
                "refitted",
                format!("{:.3} % rms on {} samples", refit.rms * 100.0, refit.n),
            );
            for (label, value) in parameter_rows(
                &refit.parameters,
                refit.z_threshold,
                report.family_false_alarm,
            ) {
                line(&label, value);
            }
        }
        None => line(
            "refitted",
            format!(
                "no refit: {}",
                report.refit_refused.as_deref().unwrap_or("not determined")
            ),
        ),
    }
    line("verdict", report.verdict.clone());
    out
}

/// The report's rows of the parameters compared: a heading row, then each
/// parameter stored → refitted with its z.
fn parameter_rows(
    parameters: &[ParamShift],
    z_threshold: f64,
    family_false_alarm: f64,
) -> Vec<(String, String)> {
    let mut rows = vec![(
        "parameters".to_string(),
        format!(
            "stored → refitted here, z in standard errors (moved beyond |z| {z_threshold:.2}: {:.0} % false alarm over {} parameters)",
            family_false_alarm * 100.0,
            parameters.len()
        ),
    )];
    for p in parameters {
        let stored = match p.stored_se {
            Some(se) => format!("{} ± {}", significant(p.stored, 6), significant(se, 2)),
            None => significant(p.stored, 6),
        };
        rows.push((
            format!("  {}", p.name),
            format!(
                "{stored} → {} ± {}   z {:+.2}{}",
                significant(p.refitted, 6),
                significant(p.refitted_se, 2),
                p.z,
                if p.moved { "  moved" } else { "" }
            ),
        ));
    }
    rows
}
