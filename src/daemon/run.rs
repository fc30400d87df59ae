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

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use super::Calibration;
use super::config::{Config, SourceKind};
use super::messages::{SourceStatus, StatusMessage, to_line};
use super::notify::Notifier;
use super::progress::{ProgressFeed, REDRAW};
use super::publish::{ClientCommand, Hub, Lane, ReplyTo};
use super::reload::ReloadEvent;
use super::sensor::Sensor;
use super::state::StateStore;
use super::state_writer::{SaveFailure, StateWriter};
use crate::capture::{CaptureFile, read_capture};
use crate::io::csv::{CsvError, CsvLayout, CsvRow};
use crate::source::bridge::{BridgeConfig, spawn_bridge_source};
use crate::source::csv::{
    CsvPlayback, CsvSource, check_csv, check_csv_files, play_csv, spawn_csv_source,
};
use crate::source::replay::{ReplayError, ReplaySummary, Speed, replay_counted};
use crate::source::serial::{SerialConfig, run_serial_source, unix_now};
use crate::source::{SourceCounters, SourceEvent};

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

/// A running source, as the loop sees it.
struct SourceHandle {
    name: String,
    counters: Arc<SourceCounters>,
    connected: bool,
    task: SourceTask,
    /// A csv source's files and their headers, for sensors a reload binds
    /// to them.
    csv_layout: Option<(Vec<std::path::PathBuf>, Vec<Arc<CsvLayout>>)>,
}

enum SourceTask {
    Async(tokio::task::JoinHandle<()>),
    Thread(std::thread::JoinHandle<()>),
}

/// Sensors grouped by the source that feeds them.
struct Sensors {
    sensors: Vec<(usize, Sensor)>,
}

impl Sensors {
    fn build(config: &Config, store: Option<&StateStore>) -> Self {
        let sensors = config
            .sensors
            .iter()
            .filter_map(|s| {
                let source = config.sources.iter().position(|src| src.name == s.source)?;
                let stored = store.and_then(|store| match store.load(&s.name) {
                    Ok(found) => found,
                    Err(e) => {
                        tracing::warn!("{e}; the sensor starts uncalibrated");
                        None
                    }
                });
                if let Some(north) = &s.north {
                    tracing::info!(sensor = %s.name, "{}", north.describe());
                }
                Some((source, Sensor::new(s.clone(), stored)))
            })
            .collect();
        let mut built = Sensors { sensors };
        built.link_tilts();
        built
    }

    /// Feeds a reading to the sensors of its source and stream.
    fn on_reading(
        &mut self,
        source: usize,
        reading: &crate::sample::Reading,
        emit: &mut dyn FnMut(Lane, String),
        store: &mut dyn FnMut(&Calibration),
    ) {
        let mut accepted_any = false;
        for (src, sensor) in &mut self.sensors {
            if *src == source
                && sensor.wants(reading.stream)
                && let Some(accepted) = sensor.on_reading(reading, emit)
            {
                store(&accepted);
                accepted_any = true;
            }
        }
        if accepted_any {
            self.link_tilts();
        }
    }

    /// Gives each 3-axis sensor with a `tilt` source that sensor's current
    /// calibration: at start, after a reload, and when a calibration is
    /// accepted (rare: no cost on the readings' path).
    fn link_tilts(&mut self) {
        let calibrations: Vec<(String, Option<Calibration>)> = self
            .sensors
            .iter()
            .map(|(_, s)| (s.name().to_string(), s.calibration().cloned()))
            .collect();
        for (_, sensor) in &mut self.sensors {
            if let Some(three) = sensor.three_mut()
                && let Some(name) = three.tilt_sensor().map(str::to_string)
            {
                let found = calibrations.iter().find(|(n, _)| *n == name);
                three.set_tilt(found.and_then(|(_, c)| c.as_ref()));
            }
        }
    }

    /// Feeds a row of a csv source to the sensors of that source.
    fn on_row(
        &mut self,
        source: usize,
        row: &CsvRow,
        emit: &mut dyn FnMut(Lane, String),
        store: &mut dyn FnMut(&Calibration),
    ) {
        let mut accepted_any = false;
        for (src, sensor) in &mut self.sensors {
            if *src == source
                && let Some(accepted) = sensor.on_row(row, emit)
            {
                store(&accepted);
                accepted_any = true;
            }
        }
        if accepted_any {
            self.link_tilts();
        }
    }

    /// Binds the sensors of csv source `source` to the headers of the
    /// files it plays (`files[k]` has `layouts[k]`); returns the columns
    /// they read in each file, sorted, once each.
    fn bind_csv(
        &mut self,
        source: usize,
        layouts: &[Arc<CsvLayout>],
        files: &[std::path::PathBuf],
    ) -> Result<Vec<Vec<usize>>, CsvError> {
        let mut required = vec![Vec::new(); layouts.len()];
        for (src, sensor) in &mut self.sensors {
            if *src == source {
                for (file, column) in sensor.bind_csv(layouts, files)? {
                    if let Some(r) = required.get_mut(file) {
                        r.push(column);
                    }
                }
            }
        }
        for r in &mut required {
            r.sort_unstable();
            r.dedup();
        }
        Ok(required)
    }

    fn recalibrate(&mut self, name: Option<&str>) -> usize {
        let mut n = 0;
        for (_, sensor) in &mut self.sensors {
            if name.is_none_or(|name| sensor.name() == name) {
                sensor.recalibrate();
                n += 1;
            }
        }
        n
    }

    fn status_line(&self, time: f64, sources: &[SourceStatus<'_>], hub: Option<&Hub>) -> String {
        let stats = hub.map(Hub::stats).unwrap_or_default();
        to_line(&StatusMessage {
            class: "STATUS",
            time,
            sensors: self.sensors.iter().map(|(_, s)| s.status()).collect(),
            sources: sources.to_vec(),
            subscribers: stats.subscribers,
            dropped: stats.dropped,
        })
    }
}

/// Runs the daemon until `shutdown` turns true. Returns once sources are
/// stopped (the Falcon stop command sent) and subscribers flushed.
pub async fn run(config: Config, shutdown: watch::Receiver<bool>) -> Result<(), DaemonError> {
    run_with(config, shutdown, RunOptions::default()).await
}

/// [`run`], feeding `progress` (the live lines or milestone log of
/// [`super::progress`]) with a snapshot of the sensors every
/// [`super::progress::REDRAW`] and with every CALIBRATION line.
pub async fn run_with_progress(
    config: Config,
    shutdown: watch::Receiver<bool>,
    progress: Option<ProgressFeed>,
) -> Result<(), DaemonError> {
    let options = RunOptions {
        progress,
        ..RunOptions::default()
    };
    run_with(config, shutdown, options).await
}

/// What drives [`run_with`] beside its configuration and `shutdown`.
#[derive(Default)]
pub struct RunOptions {
    /// Fed as in [`run_with_progress`].
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
    mut shutdown: watch::Receiver<bool>,
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
    let mut sensors = Sensors::build(&config, Some(&store));
    let (failures_tx, mut save_failures) = mpsc::unbounded_channel::<SaveFailure>();
    let writer = StateWriter::spawn(
        move |c: &Calibration| store.save(c).map_err(|e| e.to_string()),
        failures_tx,
    )
    .map_err(DaemonError::StateWriter)?;
    let hub = Hub::with_policy(
        config.outputs.queue,
        super::publish::CONTROL_QUEUE_LEN,
        subscriber_policy(&config)?,
    );
    // Sources stop first; outputs only once the last line is published.
    let (stop_tx, stop_rx) = watch::channel(false);
    let (outputs_stop_tx, outputs_stop_rx) = watch::channel(false);
    let (commands_tx, mut commands) = mpsc::channel::<(ClientCommand, ReplyTo)>(64);

    // Listeners first: a bad address stops the start before any port opens.
    let mut unix_path = None;
    if let Some(address) = &config.outputs.tcp {
        let listener = tokio::net::TcpListener::bind(address)
            .await
            .map_err(|source| DaemonError::Tcp {
                address: address.to_string(),
                source,
            })?;
        // The port bound, not 0 when the configuration let the system pick.
        let address = listener.local_addr().unwrap_or(*address);
        tracing::info!(%address, "listening on TCP");
        tokio::spawn({
            let hub = hub.clone();
            let (commands, stop) = (commands_tx.clone(), outputs_stop_rx.clone());
            async move { hub.serve_tcp(listener, commands, stop).await }
        });
    }
    if let Some(path) = &config.outputs.unix {
        let (listener, bound) = super::publish::unix::bind_owned(
            path,
            config.outputs.unix_mode,
            config.outputs.unix_group,
            |p| tokio::net::UnixListener::bind(p),
        )?;
        tracing::info!(path = %path.display(), "listening on a Unix socket");
        unix_path = Some(bound);
        tokio::spawn({
            let hub = hub.clone();
            let (commands, stop) = (commands_tx.clone(), outputs_stop_rx.clone());
            async move { hub.serve_unix(listener, commands, stop).await }
        });
    }
    let page_config = match &config.outputs.http {
        Some(address) => {
            Some(spawn_live_page(*address, &hub, &commands_tx, &outputs_stop_rx, &config).await?)
        }
        None => None,
    };
    let stdout_task = config.outputs.stdout.then(|| {
        let hub = hub.clone();
        let stop = outputs_stop_rx.clone();
        match progress.as_ref().and_then(ProgressFeed::stdout_above) {
            Some(out) => tokio::spawn(hub.serve_writer(out, stop)),
            None => tokio::spawn(hub.serve_writer(tokio::io::stdout(), stop)),
        }
    });
    drop(commands_tx);

    if let Some(message) = unwritable_state {
        let line = serde_json::json!({ "class": "ERROR", "message": message });
        hub.publish(Lane::Control, Arc::from(line.to_string()));
    }
    // Calibrations loaded from the state directory correct from the start.
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

    let (events_tx, mut events) = mpsc::channel::<(usize, SourceEvent)>(8192);
    let stop_flag = Arc::new(AtomicBool::new(false));
    let mut sources = Vec::new();
    for (index, source) in config.sources.iter().enumerate() {
        let counters = Arc::new(SourceCounters::default());
        let (tx, mut rx) = mpsc::channel::<SourceEvent>(4096);
        let mut csv_layout = None;
        let task = match &source.kind {
            SourceKind::Falcon { port, baud } => {
                let serial = SerialConfig {
                    baud: *baud,
                    retry_interval: source.retry,
                    ..SerialConfig::new(port)
                };
                SourceTask::Async(tokio::spawn(run_serial_source(
                    serial,
                    tx,
                    counters.clone(),
                    stop_rx.clone(),
                )))
            }
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
                let thread = spawn_bridge_source(bridge, tx, counters.clone(), stop_flag.clone())
                    .map_err(|e| DaemonError::Source {
                    name: source.name.clone(),
                    source: e,
                })?;
                SourceTask::Thread(thread)
            }
            SourceKind::Replay { file, speed } => {
                let capture = read_capture(file)?;
                let (name, speed, stop) = (file.display().to_string(), *speed, stop_flag.clone());
                let counters = counters.clone();
                SourceTask::Thread(std::thread::spawn(move || {
                    let _ = tx.blocking_send(SourceEvent::Connected {
                        device: name.clone(),
                    });
                    // Capture times count from the capture's start: on the
                    // host's clock, from this source's start.
                    let start = unix_now();
                    let result =
                        replay_counted(&capture, &name, speed, &stop, &counters, &mut |reading| {
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
            }
            SourceKind::Csv {
                files,
                speed,
                time_column,
                period_s,
            } => {
                // Checked whole before READY: each header, times that
                // increase, and clocks that overlap.
                let (checked, warning) = check_csv_files(files, time_column.as_deref(), *period_s)?;
                if let Some(warning) = warning {
                    tracing::warn!("source '{}': {warning}", source.name);
                }
                let layouts: Vec<Arc<CsvLayout>> =
                    checked.iter().map(|(l, _)| Arc::new(l.clone())).collect();
                csv_layout = Some((files.clone(), layouts.clone()));
                let required = sensors.bind_csv(index, &layouts, files)?;
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
                        files: files.clone(),
                        layouts: checked.into_iter().map(|(l, _)| l).collect(),
                        required,
                        speed: *speed,
                    },
                    tx,
                    counters.clone(),
                    stop_flag.clone(),
                )
                .map_err(|e| DaemonError::Source {
                    name: source.name.clone(),
                    source: e,
                })?;
                SourceTask::Thread(thread)
            }
        };
        // One channel for the loop, each event tagged with its source.
        let forward = events_tx.clone();
        tokio::spawn(async move {
            while let Some(event) = rx.recv().await {
                if forward.send((index, event)).await.is_err() {
                    break;
                }
            }
        });
        sources.push(SourceHandle {
            name: source.name.clone(),
            counters,
            connected: false,
            task,
            csv_layout,
        });
    }
    drop(events_tx);

    notifier.ready();
    notifier.status(&format!(
        "running: {} sources, {} sensors",
        sources.len(),
        sensors.sensors.len()
    ));
    tracing::info!("fieldcal is running");

    let mut status_tick = tokio::time::interval(config.daemon.status_interval);
    status_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let watchdog = notifier.watchdog_interval();
    let mut watchdog_tick = tokio::time::interval(watchdog.unwrap_or(Duration::from_secs(3600)));
    watchdog_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);

    let mut progress_tick = tokio::time::interval(REDRAW);
    progress_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);

    // Made once: the readings' path should not clone the hub per event.
    let mut emit = {
        let hub = hub.clone();
        let progress = progress.clone();
        move |lane: Lane, line: String| {
            if lane == Lane::Control
                && let Some(progress) = &progress
            {
                progress.control_line(&line);
            }
            hub.publish(lane, Arc::from(line))
        }
    };
    let mut save = |c: &Calibration| writer.save(c);
    let mut reloader = super::reload::Reloader::new(config.path.clone(), reload);
    // Sources, outputs and [daemon] as started; sensors as last reloaded.
    let mut running = config;

    // Sensor events come before commands and status ticks (biased), so no
    // client can take the time the sensors need; after EVENT_BURST events
    // in a row the other branches get one look, so a saturated source
    // does not starve STATUS and the watchdog.
    let mut events_in_a_row = 0u32;
    loop {
        let handled_before = events_in_a_row;
        tokio::select! {
            biased;
            _ = shutdown.changed() => break,
            _ = watchdog_tick.tick(), if watchdog.is_some() => notifier.ping(),
            event = events.recv(), if events_in_a_row < EVENT_BURST => {
                let Some((index, event)) = event else { break };
                events_in_a_row += 1;
                handle_event(index, event, &mut sources, &mut sensors, &mut emit, &mut save);
            }
            Some(failure) = save_failures.recv() => report_save_failure(&hub, failure),
            Some((command, reply)) = commands.recv() => {
                match command {
                    ClientCommand::Recalibrate { sensor } => {
                        let n = sensors.recalibrate(sensor.as_deref());
                        tracing::info!(sensors = n, "recalibration requested by a client");
                        if n == 0 {
                            reply.send(Arc::from(to_line(&serde_json::json!({
                                "class": "ERROR",
                                "message": format!("no sensor named '{}'", sensor.unwrap_or_default()),
                            }))));
                        }
                    }
                    ClientCommand::Status => {}
                }
                reply.send_status(&sensors.status_line(unix_now(), &source_statuses(&sources), Some(&hub)));
            }
            _ = status_tick.tick() => {
                let line = sensors.status_line(unix_now(), &source_statuses(&sources), Some(&hub));
                hub.publish(Lane::Control, Arc::from(line));
                notifier.status(&status_text(&sensors));
            }
            event = reloader.next() => match event {
                ReloadEvent::Requested => reloader.start(&notifier),
                ReloadEvent::Checked(checked) => {
                    let running_sources: Vec<_> = sources
                        .iter()
                        .map(|s| super::reload::RunningSource {
                            name: &s.name,
                            csv: s.csv_layout.as_ref().map(|(f, l)| (f.as_slice(), l.as_slice())),
                        })
                        .collect();
                    let outcome = super::reload::apply(
                        *checked,
                        &mut running,
                        &mut sensors.sensors,
                        &running_sources,
                        Some(&reload_store),
                    );
                    sensors.link_tilts();
                    if let Some(page) = &page_config {
                        page.update(&running);
                    }
                    for line in outcome.lines {
                        emit(Lane::Control, line);
                    }
                    if let Some(interval) = outcome.status_interval {
                        status_tick = tokio::time::interval(interval);
                        status_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
                    }
                    reloader.done(&notifier, &status_text(&sensors));
                }
            },
            _ = progress_tick.tick(), if progress.is_some() => {
                if let Some(progress) = &progress {
                    progress.update(sensors.sensors.iter().map(|(_, s)| s));
                }
            }
            () = std::future::ready(()), if events_in_a_row >= EVENT_BURST => {}
        }
        if events_in_a_row == handled_before {
            // Something else had its turn.
            events_in_a_row = 0;
        }
    }

    // Shutdown: stop the sources (the Falcon source sends its stop
    // command), then handle what they had already delivered.
    notifier.stopping();
    tracing::info!("stopping");
    let _ = stop_tx.send(true);
    stop_flag.store(true, Ordering::Relaxed);
    for source in &mut sources {
        let task = std::mem::replace(&mut source.task, SourceTask::Async(tokio::spawn(async {})));
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
    while let Ok((index, event)) = events.try_recv() {
        handle_event(
            index,
            event,
            &mut sources,
            &mut sensors,
            &mut emit,
            &mut save,
        );
    }
    if let Some(progress) = &progress {
        progress.settle(sensors.sensors.iter().map(|(_, s)| s));
    }
    // Stored before the last STATUS; a hung disk is not waited for beyond
    // what systemd's stop timeout leaves.
    if !writer.finish(Duration::from_secs(5)).await {
        tracing::error!("a calibration was still being stored after 5 s; it may be lost");
    }
    while let Ok(failure) = save_failures.try_recv() {
        report_save_failure(&hub, failure);
    }
    hub.publish(
        Lane::Control,
        Arc::from(sensors.status_line(unix_now(), &source_statuses(&sources), Some(&hub))),
    );
    hub.close().await;
    let _ = outputs_stop_tx.send(true);
    if let Some(task) = stdout_task {
        let _ = tokio::time::timeout(Duration::from_secs(1), task).await;
    }
    // Only the socket bound at start: a file put at the path since stays.
    if let Some(bound) = unix_path {
        bound.remove_if_ours();
    }
    Ok(())
}

/// Events the loop handles in a row before it looks at commands, failures
/// and ticks once: one queue's worth of a 1 kHz source is 0.25 s, well
/// inside a STATUS interval and the watchdog's half period.
const EVENT_BURST: u32 = 256;

/// The hub's limits and rights from `[outputs]`: the subscriber maximum
/// checked against the descriptor limit (or derived from it), the command
/// and accept rates, who may recalibrate.
fn subscriber_policy(config: &Config) -> Result<super::publish::Policy, DaemonError> {
    use super::publish::{
        Policy, check_max_subscribers, default_max_subscribers, descriptor_limit,
    };
    let nofile = descriptor_limit();
    let max_subscribers = match config.outputs.max_subscribers {
        Some(n) => check_max_subscribers(n, nofile).map_err(DaemonError::Limits)?,
        None => default_max_subscribers(nofile),
    };
    tracing::info!(
        max_subscribers,
        descriptor_limit = nofile,
        recalibrate_from = ?config.outputs.access.recalibrate_from,
        token = config.outputs.access.token.is_some(),
        "subscriber limits"
    );
    Ok(Policy {
        max_subscribers,
        access: config.outputs.access.clone(),
        ..Policy::default()
    })
}

/// Binds the live page's listener and serves it; the log names the bound
/// address (the port chosen when the configuration said port 0).
async fn spawn_live_page(
    address: std::net::SocketAddr,
    hub: &Hub,
    commands: &mpsc::Sender<(ClientCommand, ReplyTo)>,
    stop: &watch::Receiver<bool>,
    config: &Config,
) -> Result<super::publish::http::PageConfig, DaemonError> {
    let listener = tokio::net::TcpListener::bind(address)
        .await
        .map_err(|source| DaemonError::Http {
            address: address.to_string(),
            source,
        })?;
    let bound = listener.local_addr().unwrap_or(address);
    hub.keep_for_replay(super::publish::http::REPLAY_READINGS);
    let (router, page_config) =
        super::publish::http::router_with_config(hub.clone(), commands.clone(), config);
    tracing::info!(address = %bound, "live page at http://{bound}/");
    tokio::spawn(super::publish::http::serve(listener, router, stop.clone()));
    Ok(page_config)
}

/// Readings go on with the new calibration in memory; the stored file stays
/// as it was, and the log and subscribers are told.
fn report_save_failure(hub: &Hub, failure: SaveFailure) {
    tracing::error!("{}", failure.message);
    let line = serde_json::json!({
        "class": "ERROR",
        "sensor": failure.sensor,
        "message": failure.message,
    });
    hub.publish(Lane::Control, Arc::from(line.to_string()));
}

fn handle_event(
    index: usize,
    event: SourceEvent,
    sources: &mut [SourceHandle],
    sensors: &mut Sensors,
    emit: &mut dyn FnMut(Lane, String),
    store: &mut dyn FnMut(&Calibration),
) {
    match event {
        SourceEvent::Reading(reading) => sensors.on_reading(index, &reading, emit, store),
        SourceEvent::Row(row) => sensors.on_row(index, &row, emit, store),
        SourceEvent::Connected { .. } => {
            if let Some(s) = sources.get_mut(index) {
                s.connected = true;
            }
        }
        SourceEvent::Disconnected { .. } => {
            if let Some(s) = sources.get_mut(index) {
                s.connected = false;
            }
        }
        SourceEvent::Raw { .. } => {}
    }
}

fn source_statuses(sources: &[SourceHandle]) -> Vec<SourceStatus<'_>> {
    sources
        .iter()
        .map(|s| SourceStatus {
            source: &s.name,
            connected: s.connected,
            counters: s.counters.snapshot(),
        })
        .collect()
}

/// The one-line STATUS= text systemd shows.
fn status_text(sensors: &Sensors) -> String {
    let parts: Vec<String> = sensors
        .sensors
        .iter()
        .map(|(_, s)| {
            let status = s.status();
            match (status.calibration, status.rotation) {
                (Some(id), None) => format!("{}: calibrated (#{id})", s.name()),
                (_, Some(p)) => format!("{}: collecting {:.0}%", s.name(), p.coverage_pct),
                (None, None) => match status.sphere {
                    Some(p) => format!(
                        "{}: collecting {:.0}% of the sphere",
                        s.name(),
                        p.coverage_pct
                    ),
                    None => format!("{}: waiting", s.name()),
                },
            }
        })
        .collect();
    parts.join("; ")
}

/// STATUS lines due at once after a gap in a recording, at most: a longer
/// gap gets one STATUS (at the last interval before the reading), so a
/// time column that jumps cannot make the output unbounded.
pub const MAX_STATUS_CATCH_UP: u32 = 10;

/// The daemon's sensors run on a recording for `fieldcal replay --config`:
/// every line `run` would publish, in order, on the recording's clock.
struct Pipeline {
    sensors: Sensors,
    index: usize,
    source_name: String,
    interval: f64,
    /// The next STATUS is at this multiple of the interval: the first after
    /// the first reading, then every interval (counted, so times do not
    /// drift by rounding).
    next_status: Option<f64>,
    realtime: bool,
    lines: Vec<String>,
    failed: Option<std::io::Error>,
}

impl Pipeline {
    fn new(config: &Config, source: Option<&str>, speed: Speed) -> Result<Self, DaemonError> {
        let index = match source {
            Some(wanted) => config
                .sources
                .iter()
                .position(|s| s.name == wanted)
                .ok_or_else(|| DaemonError::NoSuchSource(wanted.to_string()))?,
            None => 0,
        };
        Ok(Pipeline {
            sensors: Sensors::build(config, None),
            index,
            source_name: config
                .sources
                .get(index)
                .map_or("replay", |s| s.name.as_str())
                .to_string(),
            interval: config.daemon.status_interval.as_secs_f64(),
            next_status: None,
            realtime: !matches!(speed, Speed::Max),
            lines: Vec::new(),
            failed: None,
        })
    }

    /// Publishes the STATUS lines due before `time`, then the event's lines;
    /// on a write error, keeps it and asks the source to stop.
    fn handle(
        &mut self,
        time: f64,
        event: SourceEvent,
        counters: &SourceCounters,
        out: &mut dyn Write,
        stop: &AtomicBool,
    ) {
        if self.failed.is_some() {
            return;
        }
        let interval = self.interval;
        let k = self
            .next_status
            .get_or_insert_with(|| (time / interval).floor() + 1.0);
        if time - *k * interval >= f64::from(MAX_STATUS_CATCH_UP) * interval {
            *k = (time / interval).floor();
        }
        while time >= *k * interval {
            let statuses = [SourceStatus {
                source: &self.source_name,
                connected: true,
                counters: counters.snapshot(),
            }];
            self.lines
                .push(self.sensors.status_line(*k * interval, &statuses, None));
            *k += 1.0;
        }
        let lines = &mut self.lines;
        let mut emit = |_: Lane, line: String| lines.push(line);
        match event {
            SourceEvent::Reading(reading) => {
                self.sensors
                    .on_reading(self.index, &reading, &mut emit, &mut |_| {})
            }
            SourceEvent::Row(row) => self
                .sensors
                .on_row(self.index, &row, &mut emit, &mut |_| {}),
            _ => {}
        }
        for line in self.lines.drain(..) {
            let written = out
                .write_all(line.as_bytes())
                .and_then(|()| out.write_all(b"\n"))
                .and_then(|()| if self.realtime { out.flush() } else { Ok(()) });
            if let Err(e) = written {
                self.failed = Some(e);
                stop.store(true, Ordering::Relaxed);
                return;
            }
        }
    }

    fn finish(self, out: &mut dyn Write) -> Result<(), DaemonError> {
        if let Some(e) = self.failed {
            return Err(DaemonError::Output(e));
        }
        out.flush().map_err(DaemonError::Output)
    }
}

/// Runs the configured sensors on a capture that stands in for the source
/// `source` (or the only source), writing every line `run` would have
/// published to `out`, losslessly. STATUS lines come every
/// `status_interval_s` of capture time, so the output is the same on every
/// run; their counters are the replay's, as a live source keeps them. No
/// state is read or written.
pub fn replay_through_pipeline(
    config: &Config,
    capture: &CaptureFile,
    name: &str,
    source: Option<&str>,
    speed: Speed,
    out: &mut dyn Write,
) -> Result<ReplaySummary, DaemonError> {
    let mut pipeline = Pipeline::new(config, source, speed)?;
    let stop = AtomicBool::new(false);
    let counters = SourceCounters::default();
    let summary = replay_counted(capture, name, speed, &stop, &counters, &mut |reading| {
        pipeline.handle(
            reading.time,
            SourceEvent::Reading(reading),
            &counters,
            out,
            &stop,
        );
    })?;
    pipeline.finish(out)?;
    Ok(summary)
}

/// [`replay_through_pipeline`] for a CSV recording (`path`) standing in for
/// the csv source `source` (or the first source, which must be a csv
/// source): its time column (or period), and its sensors' columns, come
/// from that source's configuration, resolved against this file's header.
/// The file is checked whole first (header, times that increase), as `run`
/// does before it is ready.
pub fn replay_csv_through_pipeline(
    config: &Config,
    path: &std::path::Path,
    source: Option<&str>,
    speed: Speed,
    out: &mut dyn Write,
) -> Result<CsvPlayback, DaemonError> {
    let mut pipeline = Pipeline::new(config, source, speed)?;
    let Some(SourceKind::Csv {
        files,
        time_column,
        period_s,
        ..
    }) = config.sources.get(pipeline.index).map(|s| &s.kind)
    else {
        return Err(DaemonError::NotCsv(pipeline.source_name.clone()));
    };
    if files.len() > 1 {
        return Err(DaemonError::SeveralCsvFiles(
            pipeline.source_name.clone(),
            files.len(),
        ));
    }
    let (layout, _) = check_csv(path, time_column.as_deref(), *period_s)?;
    let layout = Arc::new(layout);
    let required = pipeline
        .sensors
        .bind_csv(
            pipeline.index,
            std::slice::from_ref(&layout),
            &[path.to_path_buf()],
        )?
        .pop()
        .unwrap_or_default();
    let stop = AtomicBool::new(false);
    let counters = SourceCounters::default();
    let summary = play_csv(
        path,
        &layout,
        &required,
        speed,
        &stop,
        &counters,
        &mut |row| {
            pipeline.handle(row.time, SourceEvent::Row(row), &counters, out, &stop);
        },
    )?;
    pipeline.finish(out)?;
    Ok(summary)
}
