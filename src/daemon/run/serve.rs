//! The daemon's loop, once everything is started: source events to the
//! sensors, client commands, STATUS and watchdog ticks, reloads and failed
//! saves, until shutdown; then the orderly stop.

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::{mpsc, watch};

use super::outputs::Outputs;
use super::sensors::{Sensors, status_text};
use super::sources::{SourceEvents, SourceHandle, Sources};
use crate::daemon::Calibration;
use crate::daemon::config::Config;
use crate::daemon::messages::{CalibrationEvent, to_line};
use crate::daemon::notify::Notifier;
use crate::daemon::progress::{ProgressFeed, REDRAW};
use crate::daemon::publish::{ClientCommand, Hub, Lane, ReplyTo};
use crate::daemon::reload::{ReloadEvent, Reloader};
use crate::daemon::sensor::Emitter;
use crate::daemon::state::StateStore;
use crate::daemon::state_writer::{SaveFailure, StateWriter};
use crate::source::SourceEvent;
use crate::source::clock::live_now;

/// Events the loop handles in a row before it looks at commands, failures
/// and ticks once: one queue's worth of a 1 kHz source is 0.25 s, well
/// inside a STATUS interval and the watchdog's half period.
const EVENT_BURST: u32 = 256;

/// Where only milestones are logged, how long after the progress snapshot
/// was due the loop wakes for it when nothing else has woken it: with the
/// REDRAW before it, a second after the last snapshot, so a milestone of
/// the last readings before a quiet line is logged within a second of
/// them. Far longer than the 30 to 50 ms between two readings of a serial
/// or bridge source, so that its timer, made anew at each snapshot, never
/// comes due (nor wakes the loop to be moved on, as tokio's timer wheel
/// does with a timer whose level it must step down) while readings flow.
const LOGGED_IDLE: Duration = Duration::from_millis(900);

/// Everything the loop owns once the daemon is started.
pub(super) struct Daemon {
    pub(super) notifier: Notifier,
    pub(super) hub: Hub,
    pub(super) sensors: Sensors,
    pub(super) sources: Sources,
    pub(super) outputs: Outputs,
    pub(super) events: SourceEvents,
    pub(super) commands: mpsc::Receiver<(ClientCommand, ReplyTo)>,
    pub(super) writer: StateWriter,
    pub(super) save_failures: mpsc::UnboundedReceiver<SaveFailure>,
    pub(super) progress: Option<ProgressFeed>,
    pub(super) reloader: Reloader,
    /// Loads the stored calibration of a sensor a reload adds.
    pub(super) reload_store: StateStore,
    /// Sources, outputs and [daemon] as started; sensors as last reloaded.
    pub(super) running: Config,
}

impl Daemon {
    /// Serves until `shutdown` turns true (or every source has ended and
    /// its events are handled).
    pub(super) async fn serve(&mut self, mut shutdown: watch::Receiver<bool>) {
        let mut status_tick = interval(self.running.daemon.status_interval);
        let watchdog = self.notifier.watchdog_interval();
        let mut watchdog_tick = interval(watchdog.unwrap_or(Duration::from_secs(3600)));
        // The progress snapshot rides on the loop's own wake-ups (a
        // reading, a command) at most every REDRAW; a timer wakes the loop
        // when nothing else has for `idle` longer: half a REDRAW where the
        // lines are drawn live, LOGGED_IDLE where only milestones are logged
        // (systemd, a pipe), so that between readings no timer comes due
        // (each such wake-up costs about as much CPU as a reading).
        let idle = match &self.progress {
            Some(feed) if feed.is_live() => REDRAW / 2,
            _ => LOGGED_IDLE,
        };
        let mut progress_due = tokio::time::Instant::now();
        let progress_idle = tokio::time::sleep_until(progress_due + idle);
        tokio::pin!(progress_idle);

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
                _ = watchdog_tick.tick(), if watchdog.is_some() => self.notifier.ping(),
                event = self.events.recv(), if events_in_a_row < EVENT_BURST => {
                    let Some((index, event)) = event else { break };
                    events_in_a_row += 1;
                    self.handle_event(index, event);
                }
                Some(failure) = self.save_failures.recv() => report_save_failure(&self.hub, failure),
                Some((command, reply)) = self.commands.recv() => self.command(command, &reply),
                _ = status_tick.tick() => {
                    let line = self.status_line();
                    self.hub.publish(Lane::Control, Arc::from(line));
                    self.notifier.status(&status_text(&self.sensors));
                }
                event = self.reloader.next() => match event {
                    ReloadEvent::Requested => self.reloader.start(&self.notifier),
                    ReloadEvent::Checked(checked) => {
                        if let Some(interval) = self.reload(*checked) {
                            status_tick = self::interval(interval);
                        }
                    }
                },
                () = &mut progress_idle, if self.progress.is_some() => {}
                () = std::future::ready(()), if events_in_a_row >= EVENT_BURST => {}
            }
            if let Some(progress) = &self.progress {
                let now = tokio::time::Instant::now();
                if now >= progress_due {
                    progress.update(self.sensors.sensors.iter().map(|(_, s)| s));
                    progress_due = now + REDRAW;
                    // A new timer, not the old one reset: tokio moves a
                    // reset to a later time lazily, waking the loop at the
                    // old deadline only to find it moved.
                    progress_idle.set(tokio::time::sleep_until(progress_due + idle));
                }
            }
            if events_in_a_row == handled_before {
                // Something else had its turn.
                events_in_a_row = 0;
            }
        }
    }

    /// Shutdown: stop the sources (the Falcon source sends its stop
    /// command), then handle what they had already delivered, store what
    /// is unsaved, publish the last STATUS and close the outputs.
    pub(super) async fn stop(mut self) {
        self.notifier.stopping();
        tracing::info!("stopping");
        // Their last events are handled while they stop: a source waiting
        // on a full queue would not see its stop.
        let stopped = self.sources.stop();
        tokio::pin!(stopped);
        loop {
            tokio::select! {
                biased;
                () = &mut stopped => break,
                event = self.events.recv() => match event {
                    Some((index, event)) => self.handle_event(index, event),
                    None => {
                        (&mut stopped).await;
                        break;
                    }
                },
            }
        }
        while let Some((index, event)) = self.events.try_recv() {
            self.handle_event(index, event);
        }
        if let Some(progress) = &self.progress {
            progress.settle(self.sensors.sensors.iter().map(|(_, s)| s));
        }
        // Stored before the last STATUS; a hung disk is not waited for beyond
        // what systemd's stop timeout leaves.
        if !self.writer.finish(Duration::from_secs(5)).await {
            tracing::error!("a calibration was still being stored after 5 s; it may be lost");
        }
        while let Ok(failure) = self.save_failures.try_recv() {
            report_save_failure(&self.hub, failure);
        }
        let sources = self.sources.statuses();
        let line = self
            .sensors
            .status_line(live_now().0, &sources, Some(&self.hub));
        self.hub.publish(Lane::Control, Arc::from(line));
        self.hub.close().await;
        self.outputs.stop().await;
    }

    fn status_line(&self) -> String {
        let sources = self.sources.statuses();
        self.sensors
            .status_line(live_now().0, &sources, Some(&self.hub))
    }

    /// A source's event: readings and rows to its sensors (an accepted
    /// calibration is stored), connections to its status.
    fn handle_event(&mut self, index: usize, event: SourceEvent) {
        let (hub, progress, writer) = (&self.hub, &self.progress, &self.writer);
        let mut emit = |lane: Lane, line: String| hub.publish(lane, Arc::from(line));
        // The board takes each fit's outcome just before its line goes out.
        let mut watch = |event: CalibrationEvent| {
            if let Some(progress) = progress {
                progress.calibration(&event);
            }
        };
        let mut out = match progress {
            Some(_) => Emitter::watched(&mut emit, &mut watch),
            None => Emitter::new(&mut emit),
        };
        let mut store = |c: &Calibration| writer.save(c);
        let sensors = &mut self.sensors;
        match event {
            SourceEvent::Reading(reading) => {
                sensors.on_reading(index, &reading, &mut out, &mut store)
            }
            SourceEvent::Row(row) => sensors.on_row(index, &row, &mut out, &mut store),
            SourceEvent::Connected { .. } => set_connected(&mut self.sources.handles, index, true),
            SourceEvent::Disconnected { .. } => {
                set_connected(&mut self.sources.handles, index, false)
            }
            SourceEvent::Raw { .. } => {}
        }
    }

    /// A client's command; every command is answered with a STATUS.
    fn command(&mut self, command: ClientCommand, reply: &ReplyTo) {
        match command {
            ClientCommand::Recalibrate { sensor } => {
                let n = self.sensors.recalibrate(sensor.as_deref());
                tracing::info!(sensors = n, "recalibration requested by a client");
                if n == 0 {
                    reply.send(Arc::from(to_line(&serde_json::json!({
                        "class": "ERROR",
                        "message": format!("no sensor named '{}'", sensor.unwrap_or_default()),
                    }))));
                }
            }
            ClientCommand::Rollback { sensor } => {
                let (mut rolled, mut refused) = (0, Vec::new());
                for (_, s) in &mut self.sensors.sensors {
                    if sensor.as_deref().is_some_and(|name| s.name() != name) {
                        continue;
                    }
                    match s.rollback() {
                        Ok((line, event, calibration)) => {
                            tracing::info!(
                                sensor = %s.name(),
                                id = calibration.id,
                                "rolled back to calibration #{} at a client's request",
                                calibration.id
                            );
                            if let (Some(progress), Some(event)) = (&self.progress, event) {
                                progress.calibration(&event);
                            }
                            self.hub.publish(Lane::Control, Arc::from(line));
                            self.writer.save(&calibration);
                            rolled += 1;
                        }
                        Err(why) => refused.push(why),
                    }
                }
                if rolled == 0 {
                    let message = if refused.is_empty() {
                        format!("no sensor named '{}'", sensor.unwrap_or_default())
                    } else {
                        refused.join("; ")
                    };
                    reply.send(Arc::from(to_line(&serde_json::json!({
                        "class": "ERROR",
                        "message": message,
                    }))));
                }
            }
            ClientCommand::Status => {}
        }
        reply.send_status(&self.status_line());
    }

    /// Applies a checked configuration as far as it can be live; returns
    /// the new STATUS interval where it changed.
    fn reload(
        &mut self,
        checked: Result<Config, crate::daemon::reload::ReloadError>,
    ) -> Option<Duration> {
        let running_sources: Vec<_> = self
            .sources
            .handles
            .iter()
            .map(|s| crate::daemon::reload::RunningSource {
                name: &s.name,
                csv: s
                    .csv_layout
                    .as_ref()
                    .map(|(f, l)| (f.as_slice(), l.as_slice())),
            })
            .collect();
        let outcome = crate::daemon::reload::apply(
            checked,
            &mut self.running,
            &mut self.sensors.sensors,
            &running_sources,
            Some(&self.reload_store),
        );
        self.sensors.link_tilts();
        if let Some(page) = &self.outputs.page {
            page.update(&self.running);
        }
        if let Some(progress) = &self.progress {
            for event in &outcome.calibrations {
                progress.calibration(event);
            }
        }
        for line in outcome.lines {
            self.hub.publish(Lane::Control, Arc::from(line));
        }
        self.reloader
            .done(&self.notifier, &status_text(&self.sensors));
        outcome.status_interval
    }
}

/// A tick that skips what it missed instead of bursting to catch up.
fn interval(period: Duration) -> tokio::time::Interval {
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    tick
}

fn set_connected(sources: &mut [SourceHandle], index: usize, connected: bool) {
    if let Some(s) = sources.get_mut(index) {
        s.connected = connected;
    }
}

/// Readings go on with the new calibration in memory; the stored file stays
/// as it was, and the log and subscribers are told.
pub(super) fn report_save_failure(hub: &Hub, failure: SaveFailure) {
    tracing::error!("{}", failure.message);
    let line = serde_json::json!({
        "class": "ERROR",
        "sensor": failure.sensor,
        "message": failure.message,
    });
    hub.publish(Lane::Control, Arc::from(line.to_string()));
}
