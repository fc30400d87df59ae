//! The daemon's sources, one start function per kind of `[[source]]`,
//! listed once in [`spawn`]: each owns its port or file in a task or
//! thread of its own and sends [`SourceEvent`]s, which one forwarding task
//! per source tags with the source's index for the loop.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use super::DaemonError;
use super::sensors::Sensors;
use crate::capture::read_capture;
use crate::daemon::config::{Config, SourceConfig, SourceKind};
use crate::daemon::messages::SourceStatus;
use crate::io::csv::CsvLayout;
use crate::source::bridge::{BridgeConfig, spawn_bridge_source};
use crate::source::csv::{CsvSource, check_csv_files, spawn_csv_source};
use crate::source::replay::{Speed, replay_counted};
use crate::source::serial::{SerialConfig, run_serial_source, unix_now};
use crate::source::{SourceCounters, SourceEvent};

/// A running source, as the loop sees it.
pub(super) struct SourceHandle {
    pub(super) name: String,
    pub(super) counters: Arc<SourceCounters>,
    pub(super) connected: bool,
    task: SourceTask,
    /// A csv source's files and their headers, for sensors a reload binds
    /// to them.
    pub(super) csv_layout: Option<(Vec<PathBuf>, Vec<Arc<CsvLayout>>)>,
}

enum SourceTask {
    Async(tokio::task::JoinHandle<()>),
    Thread(std::thread::JoinHandle<()>),
}

/// Every configured source, started, and what stops them.
pub(super) struct Sources {
    pub(super) handles: Vec<SourceHandle>,
    /// Tells the async sources (the Falcon-GX's serial task) to stop.
    stop_tx: watch::Sender<bool>,
    /// Tells the sources that run on threads to stop.
    stop_flag: Arc<AtomicBool>,
}

/// What a source's start function is given beside its configuration.
struct Start<'a> {
    index: usize,
    sensors: &'a mut Sensors,
    tx: mpsc::Sender<SourceEvent>,
    counters: &'a Arc<SourceCounters>,
    stop_rx: &'a watch::Receiver<bool>,
    stop_flag: &'a Arc<AtomicBool>,
}

/// A source as its start function leaves it.
struct Started {
    task: SourceTask,
    csv_layout: Option<(Vec<PathBuf>, Vec<Arc<CsvLayout>>)>,
}

impl From<SourceTask> for Started {
    fn from(task: SourceTask) -> Self {
        Started {
            task,
            csv_layout: None,
        }
    }
}

impl Sources {
    /// Starts every source of `config`, in order; its events reach
    /// `events` tagged with the source's index.
    pub(super) fn start(
        config: &Config,
        sensors: &mut Sensors,
        events: mpsc::Sender<(usize, SourceEvent)>,
    ) -> Result<Sources, DaemonError> {
        let (stop_tx, stop_rx) = watch::channel(false);
        let stop_flag = Arc::new(AtomicBool::new(false));
        let mut handles = Vec::new();
        for (index, source) in config.sources.iter().enumerate() {
            let counters = Arc::new(SourceCounters::default());
            let (tx, mut rx) = mpsc::channel::<SourceEvent>(4096);
            let start = Start {
                index,
                sensors: &mut *sensors,
                tx,
                counters: &counters,
                stop_rx: &stop_rx,
                stop_flag: &stop_flag,
            };
            let Started { task, csv_layout } = spawn(source, start)?;
            // One channel for the loop, each event tagged with its source.
            let forward = events.clone();
            tokio::spawn(async move {
                while let Some(event) = rx.recv().await {
                    if forward.send((index, event)).await.is_err() {
                        break;
                    }
                }
            });
            handles.push(SourceHandle {
                name: source.name.clone(),
                counters,
                connected: false,
                task,
                csv_layout,
            });
        }
        Ok(Sources {
            handles,
            stop_tx,
            stop_flag,
        })
    }

    /// Asks every source to stop (the Falcon source sends its stop
    /// command) and waits up to 2 s for each.
    pub(super) async fn stop(&mut self) {
        let _ = self.stop_tx.send(true);
        self.stop_flag.store(true, Ordering::Relaxed);
        for source in &mut self.handles {
            let task =
                std::mem::replace(&mut source.task, SourceTask::Async(tokio::spawn(async {})));
            match task {
                SourceTask::Async(handle) => {
                    let _ = tokio::time::timeout(Duration::from_secs(2), handle).await;
                }
                SourceTask::Thread(handle) => {
                    let _ = tokio::time::timeout(
                        Duration::from_secs(2),
                        tokio::task::spawn_blocking(move || handle.join()),
                    )
                    .await;
                }
            }
        }
    }

    /// Each source's name, connection and counters, for STATUS.
    pub(super) fn statuses(&self) -> Vec<SourceStatus<'_>> {
        self.handles
            .iter()
            .map(|s| SourceStatus {
                source: &s.name,
                connected: s.connected,
                counters: s.counters.snapshot(),
            })
            .collect()
    }
}

/// The table of source kinds: each kind's start function.
fn spawn(source: &SourceConfig, start: Start<'_>) -> Result<Started, DaemonError> {
    match &source.kind {
        SourceKind::Falcon { port, baud } => Ok(spawn_falcon(source, port, *baud, start)),
        SourceKind::UsbIss {
            port,
            chips,
            poll,
            i2c_khz,
        } => {
            let bridge = BridgeConfig {
                period: *poll,
                retry_interval: source.retry,
                speed: if *i2c_khz >= 400 {
                    crate::i2c::I2cSpeed::Khz400
                } else {
                    crate::i2c::I2cSpeed::Khz100
                },
                ..BridgeConfig::new(port, chips.clone())
            };
            spawn_bridge(source, bridge, start)
        }
        SourceKind::Replay { file, speed } => spawn_replay(file, *speed, start),
        SourceKind::Csv {
            files,
            speed,
            time_column,
            period_s,
        } => spawn_csv(
            source,
            files,
            *speed,
            (time_column.as_deref(), *period_s),
            start,
        ),
    }
}

/// A Falcon-GX-style IMU on a serial port: an async task.
fn spawn_falcon(
    source: &SourceConfig,
    port: &std::path::Path,
    baud: u32,
    start: Start<'_>,
) -> Started {
    let serial = SerialConfig {
        baud,
        retry_interval: source.retry,
        ..SerialConfig::new(port)
    };
    SourceTask::Async(tokio::spawn(run_serial_source(
        serial,
        start.tx,
        start.counters.clone(),
        start.stop_rx.clone(),
    )))
    .into()
}

/// Chips behind a USB-ISS I2C bridge, polled on a thread.
fn spawn_bridge(
    source: &SourceConfig,
    bridge: BridgeConfig,
    start: Start<'_>,
) -> Result<Started, DaemonError> {
    let thread = spawn_bridge_source(
        bridge,
        start.tx,
        start.counters.clone(),
        start.stop_flag.clone(),
    )
    .map_err(|e| cannot_start(source, e))?;
    Ok(SourceTask::Thread(thread).into())
}

/// A capture played on a thread, re-stamped on the host's clock.
fn spawn_replay(
    file: &std::path::Path,
    speed: Speed,
    start: Start<'_>,
) -> Result<Started, DaemonError> {
    let capture = read_capture(file)?;
    let (name, stop) = (file.display().to_string(), start.stop_flag.clone());
    let (tx, counters) = (start.tx, start.counters.clone());
    Ok(SourceTask::Thread(std::thread::spawn(move || {
        let _ = tx.blocking_send(SourceEvent::Connected {
            device: name.clone(),
        });
        // Capture times count from the capture's start: on the
        // host's clock, from this source's start.
        let start = unix_now();
        let result = replay_counted(&capture, &name, speed, &stop, &counters, &mut |reading| {
            let reading = crate::sample::Reading {
                time: start + reading.time,
                ..reading
            };
            if tx.blocking_send(SourceEvent::Reading(reading)).is_err() {
                stop.store(true, Ordering::Relaxed);
            }
        });
        match result {
            Ok(summary) => {
                tracing::info!(readings = summary.readings, "replay of {name} finished")
            }
            Err(e) => tracing::warn!("{e}"),
        }
    }))
    .into())
}

/// CSV files on one clock, played on a thread; its sensors are bound to
/// the files' headers first.
/// `clock` is the time column, or else the period.
fn spawn_csv(
    source: &SourceConfig,
    files: &[PathBuf],
    speed: Speed,
    clock: (Option<&str>, Option<f64>),
    start: Start<'_>,
) -> Result<Started, DaemonError> {
    let (time_column, period_s) = clock;
    // Checked whole before READY: each header, times that
    // increase, and clocks that overlap.
    let (checked, warning) = check_csv_files(files, time_column, period_s)?;
    if let Some(warning) = warning {
        tracing::warn!("source '{}': {warning}", source.name);
    }
    let layouts: Vec<Arc<CsvLayout>> = checked.iter().map(|(l, _)| Arc::new(l.clone())).collect();
    let csv_layout = Some((files.to_vec(), layouts.clone()));
    let required = start.sensors.bind_csv(start.index, &layouts, files)?;
    for (file, (layout, scan)) in files.iter().zip(&checked) {
        tracing::info!(
            rows = scan.rows,
            bad_rows = scan.bad,
            "{}: {} columns ({})",
            file.display(),
            layout.names.len(),
            layout.available()
        );
    }
    let thread = spawn_csv_source(
        CsvSource {
            name: source.name.clone(),
            files: files.to_vec(),
            layouts: checked.into_iter().map(|(l, _)| l).collect(),
            required,
            speed,
        },
        start.tx,
        start.counters.clone(),
        start.stop_flag.clone(),
    )
    .map_err(|e| cannot_start(source, e))?;
    Ok(Started {
        task: SourceTask::Thread(thread),
        csv_layout,
    })
}

/// A source whose thread could not be started.
fn cannot_start(source: &SourceConfig, e: std::io::Error) -> DaemonError {
    DaemonError::Source {
        name: source.name.clone(),
        source: e,
    }
}
