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

use super::clock::live_now;
use super::replay::{MAX_GAP_S, Pacer, Speed};
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
    /// Jumps in time beyond [`MAX_GAP_S`], each said with its line and
    /// played on at once.
    pub gaps: u64,
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
    play_csv_files(
        &[path.to_path_buf()],
        std::slice::from_ref(layout),
        &[required.to_vec()],
        speed,
        stop,
        counters,
        emit,
    )
}

/// Most files one csv source plays together. Each is open while it plays
/// and its next row held, so memory and descriptors stay bounded; 16 is
/// well above the chips of one board (an IMU's magnetometer, accelerometer,
/// gyro, barometer, each logged apart).
pub const MAX_FILES: usize = 16;

/// One file of a play: its rows, its next good row, what it counted.
struct Lane {
    rows: crate::io::csv::CsvRows<std::io::BufReader<std::fs::File>>,
    next: Option<CsvRow>,
    counted_bytes: u64,
    bad_rows: u64,
    done: bool,
}

/// Plays several files recorded on one clock (`files[k]`, whose header
/// must still be `layouts[k]`'s, with `required[k]` its columns someone
/// reads) as one stream: a k-way merge by time, each row tagged with its
/// file ([`CsvRow::file`]) and carrying only that file's columns; on equal
/// times the earlier file in the list goes first. Paced, counted and
/// stopped as [`play_csv`] (which is this with one file).
pub fn play_csv_files(
    files: &[PathBuf],
    layouts: &[CsvLayout],
    required: &[Vec<usize>],
    speed: Speed,
    stop: &AtomicBool,
    counters: &SourceCounters,
    emit: &mut dyn FnMut(CsvRow),
) -> Result<CsvPlayback, CsvError> {
    let mut lanes = Vec::with_capacity(files.len().min(MAX_FILES));
    for (k, (path, layout)) in files.iter().zip(layouts).enumerate().take(MAX_FILES) {
        let time_column = layout.time_index().map(|i| layout.names[i].as_str());
        let period = match layout.time {
            crate::io::csv::TimeBase::Period(p) => Some(p),
            crate::io::csv::TimeBase::Column(_) => None,
        };
        let empty = Vec::new();
        let rows = open_rows(path, time_column, period, required.get(k).unwrap_or(&empty))?;
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
        lanes.push(Lane {
            rows,
            next: None,
            counted_bytes: 0,
            bad_rows: 0,
            done: false,
        });
    }
    let mut pacer = Pacer::new(speed);
    let mut summary = CsvPlayback::default();
    let mut last: Option<f64> = None;
    for (k, lane) in lanes.iter_mut().enumerate() {
        advance(lane, &files[k], counters)?;
    }
    let mut first: Option<f64> = None;
    loop {
        if stop.load(Ordering::Relaxed) {
            summary.stopped = true;
            break;
        }
        // The lane whose next row is earliest; the first such on a tie.
        let mut pick: Option<(usize, f64)> = None;
        for (k, lane) in lanes.iter().enumerate() {
            if let Some(row) = &lane.next
                && pick.is_none_or(|(_, t)| row.time < t)
            {
                pick = Some((k, row.time));
            }
        }
        let Some((k, _)) = pick else { break };
        let Some(row) = lanes[k].next.take() else {
            break;
        };
        let t0 = *first.get_or_insert(row.time);
        if let Some(before) = last
            && !(row.time - before <= MAX_GAP_S)
        {
            let gap = row.time - before;
            summary.gaps += 1;
            tracing::warn!(
                "{}: line {}: the time jumps {gap:.3e} s ahead of the row before ({} s → {} s), more than {MAX_GAP_S} s: treated as a gap, the rows after it play on at once",
                files[k].display(),
                row.line,
                fmt_s(before),
                fmt_s(row.time)
            );
            pacer.skip(gap);
        }
        last = Some(row.time);
        pacer.wait_for(row.time - t0, stop);
        summary.rows += 1;
        summary.span_s = row.time - t0;
        SourceCounters::add(&counters.frames_good, 1);
        emit(CsvRow { file: k, ..row });
        advance(&mut lanes[k], &files[k], counters)?;
    }
    for (lane, path) in lanes.iter().zip(files) {
        summary.bytes_read += lane.counted_bytes;
        summary.bad_rows += lane.bad_rows;
        if lane.bad_rows > ROW_WARNINGS {
            tracing::warn!(
                "{}: {} bad rows skipped in all (the first {ROW_WARNINGS} are named above)",
                path.display(),
                lane.bad_rows
            );
        }
    }
    Ok(summary)
}

/// Reads `lane`'s next good row into `lane.next` (none at the end of its
/// file), counting the bytes and the rows skipped on the way.
fn advance(lane: &mut Lane, path: &Path, counters: &SourceCounters) -> Result<(), CsvError> {
    // Bounded by the file: every turn reads a line or ends.
    while !lane.done {
        let next = lane.rows.next_row().map_err(|source| CsvError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let bytes = lane.rows.bytes_read();
        SourceCounters::add(&counters.bytes_read, bytes - lane.counted_bytes);
        lane.counted_bytes = bytes;
        match next {
            None => lane.done = true,
            Some(Ok(row)) => {
                lane.next = Some(row);
                return Ok(());
            }
            Some(Err((e, _))) => {
                lane.bad_rows += 1;
                SourceCounters::add(&counters.frames_bad, 1);
                if lane.bad_rows <= ROW_WARNINGS {
                    tracing::warn!("{}: {e}; the row is skipped", path.display());
                }
            }
        }
    }
    Ok(())
}

/// The files of one source checked together ([`check_csv`] each), then
/// their clocks: every pair of files must overlap in time (else
/// [`CsvError::Disjoint`], naming the two). Returns each file's layout and
/// scan, and a warning when the time every file covers is less than half
/// of the longest file's span (rows outside it are played, but a sensor
/// reading one file then has no partner in the other).
#[allow(clippy::type_complexity)]
pub fn check_csv_files(
    files: &[PathBuf],
    time_column: Option<&str>,
    period_s: Option<f64>,
) -> Result<(Vec<(CsvLayout, CsvScan)>, Option<String>), CsvError> {
    let mut checked = Vec::with_capacity(files.len().min(MAX_FILES));
    for path in files.iter().take(MAX_FILES) {
        checked.push(check_csv(path, time_column, period_s)?);
    }
    let spans: Vec<(&Path, f64, f64)> = files
        .iter()
        .zip(&checked)
        .filter_map(|(p, (_, scan))| Some((p.as_path(), scan.first_time?, scan.last_time?)))
        .collect();
    let warning = clock_overlap(&spans)?;
    Ok((checked, warning))
}

/// The clocks of several files (`(path, first time, last time)`): an error
/// naming the latest-starting and the earliest-ending file when they do
/// not overlap, a warning when the time all of them cover is less than
/// half of the longest span.
pub fn clock_overlap(spans: &[(&Path, f64, f64)]) -> Result<Option<String>, CsvError> {
    if spans.len() < 2 {
        return Ok(None);
    }
    let latest = spans.iter().max_by(|a, b| a.1.total_cmp(&b.1));
    let earliest = spans.iter().min_by(|a, b| a.2.total_cmp(&b.2));
    let (Some(&(lp, ls, le)), Some(&(ep, es, ee))) = (latest, earliest) else {
        return Ok(None);
    };
    if ls > ee {
        return Err(CsvError::Disjoint {
            first: ep.to_path_buf(),
            first_start: es,
            first_end: ee,
            second: lp.to_path_buf(),
            second_start: ls,
            second_end: le,
        });
    }
    let common = ee - ls;
    let longest = spans.iter().map(|s| s.2 - s.1).fold(0.0, f64::max);
    Ok((common < 0.5 * longest).then(|| {
        format!(
            "the files of this source share only {common:.3} s of {longest:.3} s ({} to {} s, \
             between {} and {}): outside that time some files are silent, and a sensor that \
             tilts with another file's readings goes without",
            fmt_s(ls),
            fmt_s(ee),
            lp.display(),
            ep.display()
        )
    }))
}

fn fmt_s(t: f64) -> String {
    // A time past what a clock counts (1e140) in 4 digits, not 141.
    if t.abs() < 1e12 {
        format!("{t:.3}")
    } else {
        format!("{t:.3e}")
    }
}

/// Which of a source's files holds every column in `names` (the sensor's
/// columns, in order), and their indices there. A name found in no file
/// is [`CsvError::MissingColumn`] (listing each file's columns), in two
/// files [`CsvError::AmbiguousColumn`], and names spread over two files
/// [`CsvError::SplitColumns`].
pub fn locate_columns(
    files: &[PathBuf],
    layouts: &[&CsvLayout],
    names: &[(&str, &'static str)],
) -> Result<(usize, Vec<usize>), CsvError> {
    let mut found: Vec<(usize, usize)> = Vec::with_capacity(names.len());
    for &(name, role) in names {
        let mut hit: Option<(usize, usize)> = None;
        for (k, layout) in layouts.iter().enumerate() {
            if let Some(i) = layout.index(name) {
                if let Some((first, _)) = hit {
                    return Err(CsvError::AmbiguousColumn {
                        name: name.to_string(),
                        first: files.get(first).cloned().unwrap_or_default(),
                        second: files.get(k).cloned().unwrap_or_default(),
                    });
                }
                hit = Some((k, i));
            }
        }
        let Some((k, i)) = hit else {
            let path = if files.len() == 1 {
                files[0].clone()
            } else {
                PathBuf::from(
                    files
                        .iter()
                        .map(|p| p.display().to_string())
                        .collect::<Vec<_>>()
                        .join(", "),
                )
            };
            return Err(CsvError::MissingColumn {
                path,
                name: name.to_string(),
                role,
                flag: "the sensor's keys in the configuration",
                available: describe_columns(files, layouts),
            });
        };
        if let Some(&(first_file, _)) = found.first()
            && first_file != k
        {
            return Err(CsvError::SplitColumns {
                name: names[0].0.to_string(),
                path: files.get(first_file).cloned().unwrap_or_default(),
                other: name.to_string(),
                other_path: files.get(k).cloned().unwrap_or_default(),
            });
        }
        found.push((k, i));
    }
    let file = found.first().map_or(0, |f| f.0);
    Ok((file, found.into_iter().map(|f| f.1).collect()))
}

/// The columns of each file, for messages: one file's as its list, several
/// as "a, b in X; c, d in Y".
pub fn describe_columns(files: &[PathBuf], layouts: &[&CsvLayout]) -> String {
    if layouts.len() == 1 {
        return layouts[0].available();
    }
    layouts
        .iter()
        .zip(files)
        .map(|(l, p)| format!("{} in {}", l.available(), p.display()))
        .collect::<Vec<_>>()
        .join("; ")
}

/// A csv source of the daemon, checked and bound: the file, its header as
/// resolved by [`check_csv`], and the columns its sensors read.
#[derive(Debug, Clone)]
pub struct CsvSource {
    /// The source's name, for its thread.
    pub name: String,
    /// Its files (one, or several on one clock), each with its header and
    /// the columns read in it.
    pub files: Vec<PathBuf>,
    pub layouts: Vec<CsvLayout>,
    pub required: Vec<Vec<usize>>,
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
            let name = source
                .files
                .iter()
                .map(|f| f.display().to_string())
                .collect::<Vec<_>>()
                .join(", ");
            let _ = events.blocking_send(SourceEvent::Connected {
                device: name.clone(),
            });
            let start = live_now().0;
            let mut first: Option<f64> = None;
            let result = play_csv_files(
                &source.files,
                &source.layouts,
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
