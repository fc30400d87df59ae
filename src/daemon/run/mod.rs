//! The daemon's wiring: sources, sensors, publishers, state and systemd,
//! connected by channels. Each source task owns its port; this loop owns
//! the sensors; the hub owns the subscribers.
//!
//! [`replay_through_pipeline`] (and [`replay_csv_through_pipeline`]) run
//! the very same sensors on a capture (a CSV recording), synchronously and
//! losslessly, so its output is what `run` would have published.
//!
//! Clocks: under `run` every message is on the host's Unix clock; a replay
//! or csv source re-stamps each reading to the Unix time the source started
//! plus the reading's offset in the recording (not divided by the speed, so
//! the time between readings stays what the sensor saw: the rotation's
//! timeouts and the gyro's integration mean the same at any speed). Under
//! `fieldcal replay --config` every message is on the recording's clock, so
//! its output is the same on every run.

use std::path::PathBuf;
use std::sync::Arc;

use tokio::sync::{mpsc, watch};

use super::config::Config;
use super::notify::Notifier;
use super::progress::ProgressFeed;
use super::publish::{ClientCommand, Hub, Lane, ReplyTo};
use super::state::StateStore;
use super::state_writer::{SaveFailure, StateWriter};
use crate::io::csv::CsvError;
use crate::source::replay::ReplayError;

mod outputs;
mod pipeline;
mod sensors;
mod serve;
mod sources;

pub(crate) use sensors::Sensors;
pub(crate) use sources::{SourceTask, Start, Started, cannot_start};

pub use pipeline::{MAX_STATUS_CATCH_UP, replay_csv_through_pipeline, replay_through_pipeline};

use outputs::{Outputs, subscriber_policy};
use serve::Daemon;
use sources::Sources;

/// Why the daemon could not start. Once running, it reports and goes on.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error("state directory: {0}")]
    State(#[from] super::state::StateError),
    #[error(
        "cannot listen on TCP {address}: {source}; choose another address in [outputs] tcp, or stop what holds it"
    )]
    Tcp {
        address: String,
        #[source]
        source: std::io::Error,
    },
    #[error(
        "cannot listen on the Unix socket {path}: {source}; check that its directory exists and is writable"
    )]
    Unix {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error(transparent)]
    UnixSocket(#[from] super::publish::unix::UnixSocketError),
    #[error(
        "cannot listen for the live page on {address}: {source}; choose another address in [outputs] http (port 0 picks a free one), or stop what holds it"
    )]
    Http {
        address: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot start source '{name}': {source}")]
    Source {
        name: String,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot start the thread that stores calibrations: {0}")]
    StateWriter(#[source] std::io::Error),
    #[error(transparent)]
    Capture(#[from] crate::capture::CaptureError),
    #[error(transparent)]
    Replay(#[from] ReplayError),
    #[error(transparent)]
    Csv(#[from] CsvError),
    #[error(
        "source '{0}' is not of kind \"csv\": a CSV recording stands in for a csv source, whose \
         configuration names its columns; give --source NAME of one, or add a [[source]] with \
         kind = \"csv\""
    )]
    NotCsv(String),
    #[error(
        "source '{0}' plays {1} files on one clock: one CSV recording cannot stand in for it; run \
         the daemon on the configuration (`fieldcal run --config`), whose source names the files"
    )]
    SeveralCsvFiles(String, usize),
    #[error("no source named '{0}' in the configuration")]
    NoSuchSource(String),
    #[error("cannot write the output: {0}")]
    Output(#[source] std::io::Error),
    /// `[outputs] max_subscribers` does not fit the descriptor limit.
    #[error("{0}")]
    Limits(String),
}

/// Runs the daemon until `shutdown` turns true. Returns once sources are
/// stopped (the Falcon stop command sent) and subscribers flushed.
pub async fn run(config: Config, shutdown: watch::Receiver<bool>) -> Result<(), DaemonError> {
    run_with(config, shutdown, RunOptions::default()).await
}

/// What drives [`run_with`] beside its configuration and `shutdown`.
#[derive(Default)]
pub struct RunOptions {
    /// Fed a snapshot of the sensors every [`super::progress::REDRAW`] and
    /// every CALIBRATION line (the live lines or milestone log of
    /// [`super::progress`]).
    pub progress: Option<ProgressFeed>,
    /// Each message asks for the configuration to be read again from the
    /// file it came from ([`Config::path`]) and applied as far as it can be
    /// live ([`super::reload`]); `fieldcal run` sends one on SIGHUP.
    /// Requests that come while one is being checked make one more.
    pub reload: Option<mpsc::Receiver<()>>,
}

/// [`run`] with [`RunOptions`]: a progress feed and reload requests.
pub async fn run_with(
    config: Config,
    shutdown: watch::Receiver<bool>,
    options: RunOptions,
) -> Result<(), DaemonError> {
    let RunOptions { progress, reload } = options;
    let notifier = Notifier::from_env();
    let store = StateStore::open(&config.daemon.state_dir)?;
    // Loads the stored calibration of a sensor a reload adds.
    let reload_store = store.clone();
    // A read-only state directory: what is in it loads, readings go on,
    // new calibrations are held in memory only; said at start.
    let unwritable_state = store.unwritable().map(ToString::to_string);
    if let Some(message) = &unwritable_state {
        tracing::error!("{message}");
    }
    let (mut sensors, refused) = Sensors::build(&config, Some(&store));
    let (failures_tx, save_failures) = mpsc::unbounded_channel::<SaveFailure>();
    let writer = StateWriter::spawn(
        move |c: &super::Calibration| store.save_retrying(c).map_err(|e| e.to_string()),
        failures_tx,
    )
    .map_err(DaemonError::StateWriter)?;
    let hub = Hub::with_policy(
        config.outputs.queue,
        super::publish::CONTROL_QUEUE_LEN,
        subscriber_policy(&config)?,
    );
    let (commands_tx, commands) = mpsc::channel::<(ClientCommand, ReplyTo)>(64);
    // Sources stop first; outputs only once the last line is published.
    let outputs = Outputs::start(&config, &hub, commands_tx, progress.as_ref()).await?;

    // What went wrong at start, for subscribers as well as the log.
    for message in unwritable_state.into_iter().chain(refused) {
        let line = serde_json::json!({ "class": "ERROR", "message": message });
        hub.publish(Lane::Control, Arc::from(line.to_string()));
    }
    publish_loaded(&sensors, &hub);

    let (sources, events) = Sources::start(&config, &mut sensors)?;

    notifier.ready();
    notifier.status(&format!(
        "running: {} sources, {} sensors",
        sources.handles.len(),
        sensors.sensors.len()
    ));
    tracing::info!("fieldcal is running");

    let mut daemon = Daemon {
        notifier,
        hub,
        sensors,
        sources,
        outputs,
        events,
        commands,
        writer,
        save_failures,
        progress,
        reloader: super::reload::Reloader::new(config.path.clone(), reload),
        reload_store,
        running: config,
    };
    daemon.serve(shutdown).await;
    daemon.stop().await;
    Ok(())
}

/// Calibrations loaded from the state directory correct from the start:
/// each is logged and published.
fn publish_loaded(sensors: &Sensors, hub: &Hub) {
    for (_, sensor) in &sensors.sensors {
        if let Some(c) = sensor.calibration() {
            tracing::info!(
                sensor = sensor.name(),
                id = c.id,
                "loaded the stored calibration"
            );
            if let Some(line) = sensor.loaded_line() {
                hub.publish(Lane::Control, Arc::from(line));
            }
        }
    }
}
