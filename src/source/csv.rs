//! The csv source: plays a CSV recording row by row, at the pace of its time
//! column (or its `period_s`), faster, or as fast as the machine allows.
//!
//! Thin: the header, the rows and their checks are [`crate::io::csv`]'s
//! (pure code over any reader); this owns the file, the pace, the stop flag
//! and the counters. Synchronous, like the replay source: a daemon runs it
//! on its own thread, `fieldcal replay --config` inline.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use tokio::sync::mpsc;

use serde::Serialize;

use super::replay::{Pacer, Speed};
use super::serial::unix_now;
use super::{SourceCounters, SourceEvent};
use crate::io::csv::{CsvError, CsvLayout, CsvRow, CsvScan, open_rows, scan_rows};

/// Bad rows warned about one by one; beyond these only their count is said,
/// so a file of garbage cannot flood the log.
pub const ROW_WARNINGS: u64 = 5;

/// Opens a recording and checks it in one bounded pass before anything
/// starts: the file, its header, the time base, and times that increase.
pub fn check_csv(
    path: &Path,
    time_column: Option<&str>,
    period_s: Option<f64>,
) -> Result<(CsvLayout, CsvScan), CsvError> {
    let mut rows = open_rows(path, time_column, period_s, &[])?;
    let scan = scan_rows(&mut rows, path)?;
    Ok((rows.layout().clone(), scan))
}

/// What a play went through.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct CsvPlayback {
    /// Rows handed on.
    pub rows: u64,
    /// Rows skipped (see [`crate::io::csv::CsvRows::next_row`]).
    pub bad_rows: u64,
    /// Bytes of the file read.
    pub bytes_read: u64,
    /// Seconds of recording covered, from the first row handed on.
    pub span_s: f64,
    /// The play was stopped before the end.
    pub stopped: bool,
}

/// Plays `path` (whose header must still be `layout`'s) calling `emit` for
/// every good row in order, on the recording's own clock; `required` are
/// the columns someone reads (a row without a number there is skipped).
/// Counts into `counters`: `bytes_read`, `frames_good` (rows handed on),
/// `frames_bad` (rows skipped). Stops at the end of the file, or early when
/// `stop` turns true.
pub fn play_csv(
    path: &Path,
    layout: &CsvLayout,
    required: &[usize],
    speed: Speed,
    stop: &AtomicBool,
    counters: &SourceCounters,
    emit: &mut dyn FnMut(CsvRow),
) -> Result<CsvPlayback, CsvError> {
    let time_column = layout.time_index().map(|i| layout.names[i].as_str());
    let period = match layout.time {
        crate::io::csv::TimeBase::Period(p) => Some(p),
        crate::io::csv::TimeBase::Column(_) => None,
    };
    let mut rows = open_rows(path, time_column, period, required)?;
    if rows.layout() != layout {
        return Err(CsvError::Malformed {
            path: path.to_path_buf(),
            line: rows.layout().header_line,
            message: format!(
                "the header changed since the file was checked (columns now: {}); restart \
                 once the file is complete",
                rows.layout().available()
            ),
        });
    }
    let pacer = Pacer::new(speed);
    let mut summary = CsvPlayback::default();
    let mut first: Option<f64> = None;
    let mut counted_bytes = 0;
    let name = path.display();
    loop {
        if stop.load(Ordering::Relaxed) {
            summary.stopped = true;
            break;
        }
        let next = rows.next_row().map_err(|source| CsvError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let bytes = rows.bytes_read();
        SourceCounters::add(&counters.bytes_read, bytes - counted_bytes);
        counted_bytes = bytes;
        match next {
            None => break,
            Some(Ok(row)) => {
                let t0 = *first.get_or_insert(row.time);
                pacer.wait_for(row.time - t0, stop);
                summary.rows += 1;
                summary.span_s = row.time - t0;
                SourceCounters::add(&counters.frames_good, 1);
                emit(row);
            }
            Some(Err((e, _))) => {
                summary.bad_rows += 1;
                SourceCounters::add(&counters.frames_bad, 1);
                if summary.bad_rows <= ROW_WARNINGS {
                    tracing::warn!("{name}: {e}; the row is skipped");
                }
            }
        }
    }
    summary.bytes_read = counted_bytes;
    if summary.bad_rows > ROW_WARNINGS {
        tracing::warn!(
            "{name}: {} bad rows skipped in all (the first {ROW_WARNINGS} are named above)",
            summary.bad_rows
        );
    }
    Ok(summary)
}

/// A csv source of the daemon, checked and bound: the file, its header as
/// resolved by [`check_csv`], and the columns its sensors read.
#[derive(Debug, Clone)]
pub struct CsvSource {
    /// The source's name, for its thread.
    pub name: String,
    pub file: PathBuf,
    pub layout: Arc<CsvLayout>,
    pub required: Vec<usize>,
    pub speed: Speed,
}

/// Plays the file on its own thread, sending [`SourceEvent::Connected`]
/// and then one [`SourceEvent::Row`] a row, each re-stamped onto the
/// host's Unix clock: the time the source started plus the row's offset
/// from the first row (not divided by the speed: the time between rows
/// stays what the sensor saw). Ends at the end of the file, when `stop`
/// turns true, or when the receiver is gone.
pub fn spawn_csv_source(
    source: CsvSource,
    events: mpsc::Sender<SourceEvent>,
    counters: Arc<SourceCounters>,
    stop: Arc<AtomicBool>,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name(format!("csv-{}", source.name))
        .spawn(move || {
            let name = source.file.display().to_string();
            let _ = events.blocking_send(SourceEvent::Connected {
                device: name.clone(),
            });
            let start = unix_now();
            let mut first: Option<f64> = None;
            let result = play_csv(
                &source.file,
                &source.layout,
                &source.required,
                source.speed,
                &stop,
                &counters,
                &mut |row| {
                    let t0 = *first.get_or_insert(row.time);
                    let row = CsvRow {
                        time: start + (row.time - t0),
                        ..row
                    };
                    if events.blocking_send(SourceEvent::Row(row)).is_err() {
                        stop.store(true, Ordering::Relaxed);
                    }
                },
            );
            match result {
                Ok(summary) => tracing::info!(
                    rows = summary.rows,
                    bad_rows = summary.bad_rows,
                    "replay of {name} finished"
                ),
                Err(e) => tracing::warn!("{e}"),
            }
        })
}
