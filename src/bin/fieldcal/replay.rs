//! `fieldcal replay FILE`: decode a capture and print its samples.

use std::io::{BufWriter, Write};
use std::sync::atomic::AtomicBool;

use anyhow::{Context, Result};
use serde::Serialize;

use fieldcal::capture::read_capture;
use fieldcal::sample::Reading;
use fieldcal::source::replay::replay as run_replay;

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
    let file = read_capture(&args.file)?;
    if let Some(config) = &args.config {
        let config = fieldcal::daemon::config::load(config)?;
        let stdout = std::io::stdout();
        let mut out = BufWriter::with_capacity(1 << 16, stdout.lock());
        let result = fieldcal::daemon::run::replay_through_pipeline(
            &config,
            &file,
            &name,
            args.source.as_deref(),
            args.speed,
            &mut out,
        );
        return match result {
            Err(fieldcal::daemon::run::DaemonError::Output(e))
                if e.kind() == std::io::ErrorKind::BrokenPipe =>
            {
                Ok(())
            }
            Err(e) => Err(e.into()),
            Ok(summary) => {
                if let Some(truncated) = &summary.truncated {
                    tracing::warn!("{truncated}");
                }
                Ok(())
            }
        };
    }
    let stop = AtomicBool::new(false);
    let stdout = std::io::stdout();
    let mut out = BufWriter::with_capacity(1 << 16, stdout.lock());
    let mut write_error: Option<std::io::Error> = None;
    let realtime = !matches!(args.speed, fieldcal::source::replay::Speed::Max);
    let summary = run_replay(&file, &name, args.speed, &stop, &mut |reading| {
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
