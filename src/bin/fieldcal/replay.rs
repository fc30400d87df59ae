//! `fieldcal replay FILE`: decode a capture and print its samples.

use std::io::{BufWriter, Write};
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result};
use serde::Serialize;

use fieldcal::capture::open_capture;
use fieldcal::daemon::config::{Config, SourceKind};
use fieldcal::daemon::run::DaemonError;
use fieldcal::io::csv::looks_like_csv;
use fieldcal::sample::Reading;
use fieldcal::source::replay::{Speed, replay_playable};

use crate::ReplayArgs;

/// One decoded sample on stdout.
#[derive(Serialize)]
struct SampleLine<'a> {
    class: &'static str,
    #[serde(flatten)]
    reading: &'a Reading,
}

pub fn replay(args: ReplayArgs) -> Result<()> {
    let name = args.file.display().to_string();
    if let Some(config) = &args.config {
        let config = fieldcal::daemon::config::load(config)?;
        return replay_with_config(&args, &config, &name);
    }
    if looks_like_csv(&args.file) {
        anyhow::bail!(
            "{name} is a CSV recording: replaying one needs --config FILE, a configuration with a \
             [[source]] of kind = \"csv\" whose [[sensor]] names its columns (axes = [\"COL_X\", \
             \"COL_Y\"]); `fieldcal fit {name} --x COL_X --y COL_Y` fits it without one"
        );
    }
    let mut file = open_capture(&args.file)?;
    let speed = args.speed.unwrap_or(Speed::Times(1.0));
    let stop = AtomicBool::new(false);
    let stdout = std::io::stdout();
    let mut out = BufWriter::with_capacity(1 << 16, stdout.lock());
    let mut write_error: Option<std::io::Error> = None;
    let realtime = !matches!(speed, Speed::Max);
    let counters = fieldcal::source::SourceCounters::default();
    let summary = replay_playable(&mut file, &name, speed, &stop, &counters, &mut |reading| {
        if write_error.is_some() {
            return;
        }
        let line = SampleLine {
            class: "SAMPLE",
            reading: &reading,
        };
        let result = serde_json::to_writer(&mut out, &line)
            .map_err(std::io::Error::from)
            .and_then(|()| out.write_all(b"\n"))
            // In real time, a reader downstream wants each sample as it comes.
            .and_then(|()| if realtime { out.flush() } else { Ok(()) });
        if let Err(e) = result {
            write_error = Some(e);
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    })?;
    match write_error.map_or_else(|| out.flush(), Err) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(()),
        other => other.context("cannot write to stdout")?,
    }
    if let Some(truncated) = &summary.truncated {
        tracing::warn!("{truncated}");
    }
    tracing::info!(
        readings = summary.readings,
        frames_good = summary.falcon.frames_good,
        frames_bad = summary.falcon.frames_bad,
        bytes_skipped = summary.falcon.bytes_skipped,
        frames_lost = summary.falcon.frames_lost,
        "replayed {name}"
    );
    if args.json {
        let line = serde_json::json!({ "class": "SUMMARY", "file": name, "summary": summary });
        crate::output::write_stdout(format!("{line}\n").as_bytes())?;
    }
    Ok(())
}

/// `replay --config`: the file stands in for the configured source (the
/// one named by --source, else the first) and goes through the daemon's
/// pipeline, at --speed, else at the source's configured speed.
fn replay_with_config(args: &ReplayArgs, config: &Config, name: &str) -> Result<()> {
    let source = match &args.source {
        Some(wanted) => config.source(wanted),
        None => config.sources.first(),
    };
    let speed = args
        .speed
        .or_else(|| source.and_then(|s| s.kind.speed()))
        .unwrap_or(Speed::Times(1.0));
    let is_csv_source = source.is_some_and(|s| matches!(s.kind, SourceKind::Csv(_)));
    // Stdout itself (not its lock, which stays on this thread): a replay
    // at full speed writes its lines on a thread of its own.
    let mut out = BufWriter::with_capacity(1 << 16, std::io::stdout());
    let result = if is_csv_source {
        fieldcal::daemon::run::replay_csv_through_pipeline(
            config,
            &args.file,
            args.source.as_deref(),
            speed,
            &mut out,
        )
        .map(|summary| {
            tracing::info!(
                rows = summary.rows,
                bad_rows = summary.bad_rows,
                bytes = summary.bytes_read,
                "replayed {name}"
            );
        })
    } else {
        if let Some(source) = source.filter(|_| looks_like_csv(&args.file)) {
            return Err(DaemonError::NotCsv(source.name.clone()).into());
        }
        let mut file = open_capture(&args.file)?;
        fieldcal::daemon::run::replay_through_pipeline(
            config,
            &mut file,
            name,
            args.source.as_deref(),
            speed,
            &mut out,
        )
        .map(|summary| {
            if let Some(truncated) = &summary.truncated {
                tracing::warn!("{truncated}");
            }
        })
    };
    match result {
        Err(DaemonError::Output(e)) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        Err(e) => Err(e.into()),
        Ok(()) => Ok(()),
    }
}
