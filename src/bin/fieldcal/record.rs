//! `fieldcal record`: capture a device's bytes to a file until stopped.

use std::fs::OpenOptions;
use std::io::BufWriter;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use tokio::sync::{mpsc, watch};

use fieldcal::capture::{CaptureHeader, CaptureWriter, StreamInfo, StreamKind, VERSION};
use fieldcal::protocol::falcon::NOMINAL_PERIOD;
use fieldcal::record::{NothingRecorded, record as run_recorder};
use fieldcal::source::SourceCounters;
use fieldcal::source::bridge::{BridgeConfig, spawn_bridge_source};
use fieldcal::source::serial::{SerialConfig, run_serial_source, unix_now};

use crate::{DeviceKind, RecordArgs};

pub fn record(args: RecordArgs) -> Result<()> {
    if args.device == DeviceKind::UsbIss && args.chip.is_empty() {
        bail!("--device usb-iss needs at least one --chip to poll (for example --chip mpu6050)");
    }
    if args.device == DeviceKind::Falcon && !args.chip.is_empty() {
        bail!("--chip is for --device usb-iss; a Falcon-GX sends its own frames");
    }
    // Never overwrite a recording: it may be the only copy of a run.
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&args.output)
        .with_context(|| {
            format!(
                "cannot create {} (it must not exist yet)",
                args.output.display()
            )
        })?;

    let poll_period = Duration::from_millis(args.poll_ms);
    let (streams, nominal) = streams(&args, poll_period)?;
    let started_unix = unix_now();
    let started = std::time::Instant::now();
    let header = CaptureHeader {
        version: VERSION,
        streams,
        port: Some(args.port.display().to_string()),
        baud: (args.device == DeviceKind::Falcon).then_some(args.baud),
        started_unix,
        nominal_period_s: nominal.as_secs_f64(),
        note: None,
    };
    let mut writer = CaptureWriter::new(BufWriter::new(file), &header)
        .with_context(|| format!("cannot write {}", args.output.display()))?;

    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("cannot start the runtime")?;
    let summary = runtime.block_on(async {
        let (events_tx, events_rx) = mpsc::channel(1024);
        let counters = Arc::new(SourceCounters::default());
        let (stop_tx, stop_rx) = watch::channel(false);
        let stop_flag = Arc::new(AtomicBool::new(false));

        let source = match args.device {
            DeviceKind::Falcon => {
                let config = SerialConfig {
                    baud: args.baud,
                    raw: true,
                    ..SerialConfig::new(&args.port)
                };
                let task = tokio::spawn(run_serial_source(
                    config,
                    events_tx,
                    counters.clone(),
                    stop_rx.clone(),
                ));
                Source::Task(task)
            }
            DeviceKind::UsbIss => {
                let config = BridgeConfig {
                    period: poll_period,
                    ..BridgeConfig::new(&args.port, args.chip.clone())
                };
                let thread =
                    spawn_bridge_source(config, events_tx, counters.clone(), stop_flag.clone())
                        .context("cannot start the bridge thread")?;
                Source::Thread(thread)
            }
        };
        tokio::spawn(crate::signals::forward_signals(stop_tx.clone()));
        // --duration is checked to (0, a year] by its parser.
        let duration = args
            .duration
            .and_then(|s| Duration::try_from_secs_f64(s).ok());
        let result = run_recorder(events_rx, &mut writer, started, duration, stop_rx).await;
        // Stop the source whatever ended the recording; it sends the
        // device's stop command on its way out.
        let _ = stop_tx.send(true);
        stop_flag.store(true, Ordering::Relaxed);
        match source {
            Source::Task(task) => {
                let _ = task.await;
            }
            Source::Thread(thread) => {
                let _ = tokio::task::spawn_blocking(move || thread.join()).await;
            }
        }
        let summary =
            result.with_context(|| format!("recording to {} failed", args.output.display()))?;
        anyhow::Ok((summary, counters.snapshot()))
    })?;
    let (summary, counters) = summary;
    let port = args.port.display().to_string();
    if let Err(nothing) = summary.check_recorded(&port, args.port.exists(), started.elapsed()) {
        // The file holds only its header: nothing a replay could use. It
        // was created by this run (create_new above), so removing it loses
        // nothing.
        drop(writer);
        return Err(nothing_recorded(&args, nothing));
    }
    eprintln!(
        "recorded {} ({}, {}) to {}; frames good {}, bad {}, lost {}, reconnects {}",
        fieldcal::sample::count(summary.chunks, "chunk"),
        fieldcal::sample::count(summary.bytes, "byte"),
        fieldcal::sample::count(summary.readings, "reading"),
        args.output.display(),
        counters.frames_good,
        counters.frames_bad,
        counters.frames_lost,
        counters.reconnects
    );
    if args.json {
        let line = serde_json::json!({ "class": "SUMMARY", "file": args.output.display().to_string(), "record": summary, "counters": counters });
        crate::output::write_stdout(format!("{line}\n").as_bytes())?;
    }
    Ok(())
}

/// The capture's streams and their nominal period: the Falcon's one
/// stream, or one per `--chip` polled every `poll_period`.
fn streams(args: &RecordArgs, poll_period: Duration) -> Result<(Vec<StreamInfo>, Duration)> {
    let (streams, nominal) = match args.device {
        DeviceKind::Falcon => (
            vec![StreamInfo {
                id: 0,
                kind: StreamKind::Falcon,
            }],
            NOMINAL_PERIOD,
        ),
        DeviceKind::UsbIss => (
            args.chip
                .iter()
                .enumerate()
                .map(|(i, &(chip, address))| StreamInfo {
                    id: i as u8,
                    kind: StreamKind::Chip { chip, address },
                })
                .collect(),
            poll_period,
        ),
    };
    if streams.len() > u8::MAX as usize {
        bail!("at most 255 chips can be recorded at once");
    }
    Ok((streams, nominal))
}

/// The error of a run that recorded nothing, once its empty capture is
/// removed (or why it could not be).
fn nothing_recorded(args: &RecordArgs, nothing: NothingRecorded) -> anyhow::Error {
    let file = args.output.display();
    let left = match std::fs::remove_file(&args.output) {
        Ok(()) => format!("removed the empty capture {file}"),
        Err(e) => format!("left the empty capture {file} (cannot remove it: {e})"),
    };
    let this_run = match (&nothing, args.device) {
        (NothingRecorded::NoBytes { .. }, DeviceKind::Falcon) => {
            format!(" (this run: --device falcon --baud {})", args.baud)
        }
        (NothingRecorded::NoBytes { .. }, DeviceKind::UsbIss) => {
            " (this run: --device usb-iss)".to_string()
        }
        _ => String::new(),
    };
    anyhow::anyhow!("{nothing}{this_run}; {left}")
}

enum Source {
    Task(tokio::task::JoinHandle<()>),
    Thread(std::thread::JoinHandle<()>),
}
