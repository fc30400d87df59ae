//! The daemon's sensors, grouped by the source that feeds them: readings
//! and csv rows in, calibrations to store and lines to publish out.

use std::sync::Arc;

use crate::daemon::Calibration;
use crate::daemon::config::Config;
use crate::daemon::messages::{SourceStatus, StatusMessage, to_line_in};
use crate::daemon::publish::Hub;
use crate::daemon::sensor::{Emitter, Sensor};
use crate::daemon::state::StateStore;
use crate::io::csv::{CsvError, CsvLayout, CsvRow};

/// Room a STATUS line of `entries` sensors and sources is given at once
/// (about 250 bytes a sensor and 200 a source).
pub(super) fn status_room(entries: usize) -> usize {
    128 + 384 * entries
}

/// Sensors grouped by the source that feeds them.
pub(crate) struct Sensors {
    pub(super) sensors: Vec<(usize, Sensor)>,
}

impl Sensors {
    /// The sensors of `config`, each with its stored calibration where one
    /// can correct it; the stored ones refused, each said in a sentence for
    /// an ERROR line (the file was moved aside).
    pub(super) fn build(config: &Config, store: Option<&StateStore>) -> (Self, Vec<String>) {
        let mut refused = Vec::new();
        let sensors = config
            .sensors
            .iter()
            .filter_map(|s| {
                let source = config.sources.iter().position(|src| src.name == s.source)?;
                let stored = store.and_then(|store| {
                    match store
                        .load_checked(&s.name, |c| crate::daemon::sensor::stored_problem(s, c))
                    {
                        Ok(found) => found,
                        Err(e) => {
                            let message = format!("{e}; sensor '{}' starts uncalibrated", s.name);
                            tracing::error!("{message}");
                            refused.push(message);
                            None
                        }
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
        (built, refused)
    }

    /// Feeds a reading to the sensors of its source and stream.
    pub(super) fn on_reading(
        &mut self,
        source: usize,
        reading: &crate::sample::Reading,
        out: &mut Emitter<'_>,
        store: &mut dyn FnMut(&Calibration),
    ) {
        let mut accepted_any = false;
        for (src, sensor) in &mut self.sensors {
            if *src == source
                && sensor.wants(reading.stream)
                && let Some(accepted) = sensor.on_reading_to(reading, out)
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
    pub(super) fn link_tilts(&mut self) {
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
    pub(super) fn on_row(
        &mut self,
        source: usize,
        row: &CsvRow,
        out: &mut Emitter<'_>,
        store: &mut dyn FnMut(&Calibration),
    ) {
        let mut accepted_any = false;
        for (src, sensor) in &mut self.sensors {
            if *src == source
                && let Some(accepted) = sensor.on_row_to(row, out)
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
    pub(crate) fn bind_csv(
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

    pub(super) fn recalibrate(&mut self, name: Option<&str>) -> usize {
        let mut n = 0;
        for (_, sensor) in &mut self.sensors {
            if name.is_none_or(|name| sensor.name() == name) {
                sensor.recalibrate();
                n += 1;
            }
        }
        n
    }

    /// The STATUS line at `time` of these sensors, `sources` and the
    /// hub's subscribers (none without one).
    pub(super) fn status_line(
        &self,
        time: f64,
        sources: &[SourceStatus<&str>],
        hub: Option<&Hub>,
    ) -> String {
        let stats = hub.map(Hub::stats).unwrap_or_default();
        let room = status_room(self.sensors.len() + sources.len());
        let mut message = self.status_message(time, sources.to_vec(), |s| s);
        (message.subscribers, message.dropped) = (stats.subscribers, stats.dropped);
        to_line_in(&message, room)
    }

    /// The STATUS message at `time` of these sensors and `sources`, each
    /// text `text(…)` (borrowed, or owned to be written on another
    /// thread), with no subscribers.
    pub(super) fn status_message<'a, S>(
        &'a self,
        time: f64,
        sources: Vec<SourceStatus<S>>,
        text: impl Fn(&'a str) -> S,
    ) -> StatusMessage<S> {
        StatusMessage {
            class: "STATUS",
            time,
            sensors: self
                .sensors
                .iter()
                .map(|(_, s)| s.status().map(&text))
                .collect(),
            sources,
            subscribers: 0,
            dropped: 0,
        }
    }
}

/// The one-line STATUS= text systemd shows.
pub(super) fn status_text(sensors: &Sensors) -> String {
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
