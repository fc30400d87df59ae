//! `kind = "replay"`: a capture (or a raw Falcon-GX dump) played back on
//! a thread, re-stamped on the host's clock.

use std::path::PathBuf;
use std::sync::atomic::Ordering;

use super::{Checked, Keys, Kind};
use crate::capture::open_capture;
use crate::daemon::config::{ConfigError, SensorConfig, SourceConfig};
use crate::daemon::reload::ReloadError;
use crate::daemon::run::{DaemonError, SourceTask, Start, Started};
use crate::source::SourceEvent;
use crate::source::replay::{Speed, replay_playable};
use crate::source::clock::live_now;

/// A capture (or raw Falcon dump) played back.
#[derive(Debug, Clone, PartialEq)]
pub struct Replay {
    pub file: PathBuf,
    pub speed: Speed,
}

impl Kind for Replay {
    const NAME: &'static str = "replay";
    const KEYS: &'static [&'static str] = &["file", "speed"];

    /// The file, and the streams its capture header declares (one for a
    /// raw dump); reads the header only.
    fn check(keys: &Keys<'_, '_>) -> Result<Checked<Self>, ConfigError> {
        let checker = keys.checker();
        let Some(file) = keys
            .get::<PathBuf>("file")?
            .filter(|f| !f.as_os_str().is_empty())
        else {
            return Err(keys.error(
                "file",
                "a replay source needs `file`, a capture or raw dump (relative to the \
                 configuration's directory)",
            ));
        };
        let file = checker.resolve(&file);
        let streams = checker.replay_streams(&keys.key("file"), &file)?;
        let speed = checker.check_speed(&keys.key("speed"), keys.raw("speed"))?;
        Ok(Checked {
            settings: Replay { file, speed },
            streams,
            layouts: None,
        })
    }

    fn changed(&self, new: &Self) -> Vec<&'static str> {
        let mut keys = Vec::new();
        if self.file != new.file {
            keys.push("file");
        }
        if self.speed != new.speed {
            keys.push("speed");
        }
        keys
    }

    /// The capture's header and records, checked as `spawn` reads them.
    fn preflight(&self, _name: &str, _sensors: &[SensorConfig]) -> Result<(), ReloadError> {
        open_capture(&self.file)?;
        Ok(())
    }

    fn speed(&self) -> Option<Speed> {
        Some(self.speed)
    }

    fn spawn(&self, _source: &SourceConfig, start: Start<'_>) -> Result<Started, DaemonError> {
        // Read as it plays: memory does not grow with the capture.
        let mut capture = open_capture(&self.file)?;
        let speed = self.speed;
        let (name, stop) = (self.file.display().to_string(), start.stop_flag.clone());
        let (tx, counters) = (start.tx, start.counters.clone());
        Ok(SourceTask::Thread(std::thread::spawn(move || {
            let _ = tx.blocking_send(SourceEvent::Connected {
                device: name.clone(),
            });
            // Capture times count from the capture's start: on the
            // host's clock, from this source's start.
            let start = live_now().0;
            let result =
                replay_playable(&mut capture, &name, speed, &stop, &counters, &mut |reading| {
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
}
