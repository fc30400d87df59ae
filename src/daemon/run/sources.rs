//! The daemon's running sources. Each kind's start function is in
//! [`crate::daemon::source_kinds`]: each owns its port or file in a task or
//! thread of its own and sends [`SourceEvent`]s, which one forwarding task
//! per source tags with the source's index for the loop.

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use super::DaemonError;
use super::sensors::Sensors;
use crate::daemon::config::{Config, SourceConfig};
use crate::daemon::messages::SourceStatus;
use crate::io::csv::CsvLayout;
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

pub(crate) enum SourceTask {
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
pub(crate) struct Start<'a> {
    /// The source's index in the configuration.
    pub(crate) index: usize,
    /// The sensors, for a csv source to bind to its files' headers.
    pub(crate) sensors: &'a mut Sensors,
    /// Where its events go.
    pub(crate) tx: mpsc::Sender<SourceEvent>,
    pub(crate) counters: &'a Arc<SourceCounters>,
    /// Tells an async source to stop.
    pub(crate) stop_rx: &'a watch::Receiver<bool>,
    /// Tells a source on a thread to stop.
    pub(crate) stop_flag: &'a Arc<AtomicBool>,
}

/// A source as its start function leaves it.
pub(crate) struct Started {
    pub(crate) task: SourceTask,
    /// A csv source's files and their headers.
    pub(crate) csv_layout: Option<(Vec<PathBuf>, Vec<Arc<CsvLayout>>)>,
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
            let Started { task, csv_layout } = source.kind.spawn(source, start)?;
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

/// A source whose thread could not be started.
pub(crate) fn cannot_start(source: &SourceConfig, e: std::io::Error) -> DaemonError {
    DaemonError::Source {
        name: source.name.clone(),
        source: e,
    }
}
