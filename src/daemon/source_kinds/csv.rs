//! `kind = "csv"`: CSV recordings on one clock, played row by row on a
//! thread; its sensors name columns of the files' headers.

use std::path::PathBuf;
use std::sync::Arc;

use super::{Checked, Keys, Kind};
use crate::daemon::config::{ConfigError, SensorConfig, SourceConfig, StreamDesc};
use crate::daemon::reload::ReloadError;
use crate::daemon::run::{DaemonError, SourceTask, Start, Started, cannot_start};
use crate::daemon::sensor::Sensor;
use crate::io::csv::CsvLayout;
use crate::source::csv::{CsvSource, check_csv_files, spawn_csv_source};
use crate::source::replay::Speed;

/// A CSV recording played row by row (one stream, 0): the rows' times
/// come from `time_column` (else the first of t, t_s, time, time_s) or,
/// when the file has none, row k is at k * `period_s`. Several files
/// recorded on one clock (`files`, each with its own header and time
/// column) are played merged in time order; a source of one file
/// (`file`) has one here.
#[derive(Debug, Clone, PartialEq)]
pub struct Csv {
    pub files: Vec<PathBuf>,
    pub speed: Speed,
    pub time_column: Option<String>,
    pub period_s: Option<f64>,
}

impl Kind for Csv {
    const NAME: &'static str = "csv";
    const KEYS: &'static [&'static str] = &["file", "files", "speed", "time_column", "period_s"];

    /// The files, speed and clock (a time column, or a period for a single
    /// file), each file's header resolved.
    fn check(keys: &Keys<'_, '_>) -> Result<Checked<Self>, ConfigError> {
        let checker = keys.checker();
        let key = keys.section();
        let (file, files) = (keys.get("file")?, keys.get("files")?);
        let period_s = keys.get::<f64>("period_s")?;
        let time_column = keys.get::<String>("time_column")?;
        let (files, listed) = checker.csv_files(key, file, files)?;
        let speed = checker.check_speed(&keys.key("speed"), keys.raw("speed"))?;
        let period_s = match period_s {
            None => None,
            Some(_) if files.len() > 1 => {
                return Err(keys.error(
                    "period_s",
                    "`period_s` is for a single file without a time column: the files of \
                     one clock are merged by their time columns, so each needs one \
                     (name it with time_column)",
                ));
            }
            Some(p) => {
                checker.seconds(&keys.key("period_s"), p, 86_400.0)?;
                Some(p)
            }
        };
        let time_column = time_column.map(|t| t.trim().to_string());
        let mut found = Vec::with_capacity(files.len());
        for (k, file) in files.iter().enumerate() {
            let on = if listed {
                keys.key(&format!("files[{k}]"))
            } else {
                keys.key("file")
            };
            found.push(checker.csv_layout(key, &on, file, time_column.as_deref(), period_s)?);
        }
        Ok(Checked {
            settings: Csv {
                files,
                speed,
                time_column,
                period_s,
            },
            streams: vec![StreamDesc { id: 0, chip: None }],
            layouts: Some(found),
        })
    }

    fn changed(&self, new: &Self) -> Vec<&'static str> {
        let mut keys = Vec::new();
        if self.files != new.files {
            keys.push(if self.files.len() == 1 && new.files.len() == 1 {
                "file"
            } else {
                "files"
            });
        }
        if self.speed != new.speed {
            keys.push("speed");
        }
        if self.time_column != new.time_column {
            keys.push("time_column");
        }
        if self.period_s != new.period_s {
            keys.push("period_s");
        }
        keys
    }

    /// Each file scanned whole, and its sensors' columns found in the
    /// headers.
    fn preflight(&self, name: &str, sensors: &[SensorConfig]) -> Result<(), ReloadError> {
        let (checked, _) =
            check_csv_files(&self.files, self.time_column.as_deref(), self.period_s)?;
        let layouts: Vec<Arc<CsvLayout>> = checked.into_iter().map(|(l, _)| Arc::new(l)).collect();
        for sensor in sensors.iter().filter(|s| s.source == name) {
            Sensor::new(sensor.clone(), None).bind_csv(&layouts, &self.files)?;
        }
        Ok(())
    }

    fn speed(&self) -> Option<Speed> {
        Some(self.speed)
    }

    /// Checked whole before READY (each header, times that increase, and
    /// clocks that overlap); its sensors are bound to the headers first.
    fn spawn(&self, source: &SourceConfig, start: Start<'_>) -> Result<Started, DaemonError> {
        let files = &self.files;
        let (checked, warning) =
            check_csv_files(files, self.time_column.as_deref(), self.period_s)?;
        if let Some(warning) = warning {
            tracing::warn!("source '{}': {warning}", source.name);
        }
        let layouts: Vec<Arc<CsvLayout>> =
            checked.iter().map(|(l, _)| Arc::new(l.clone())).collect();
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
                speed: self.speed,
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
}
