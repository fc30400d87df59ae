//! The daemon's sensors on a recording, synchronously and losslessly, for
//! `fieldcal replay --config`: every line `run` would publish, in order, on
//! the recording's clock.

use std::cell::RefCell;
use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use super::DaemonError;
use super::sensors::{Sensors, status_room};
use crate::capture::Playable;
use crate::daemon::config::{Config, SourceKind};
use crate::daemon::messages::{ReadingValues, SourceStatus, StatusMessage, write_line_to};
use crate::daemon::publish::Lane;
use crate::daemon::sensor::Emitter;
use crate::daemon::source_kinds::Csv;
use crate::sample::Reading;
use crate::source::csv::{CsvPlayback, check_csv, play_csv};
use crate::source::replay::{ReplayError, ReplaySummary, Speed, replay_playable};
use crate::source::{CountersSnapshot, SourceCounters, SourceEvent};

/// STATUS lines due at once after a gap in a recording, at most: a longer
/// gap gets one STATUS (at the last interval before the reading), so a
/// time column that jumps cannot make the output unbounded.
pub const MAX_STATUS_CATCH_UP: u32 = 10;

/// When a recording's STATUS lines are due, on its clock: the first at
/// the first whole interval after the first reading, then every interval
/// (counted, so times do not drift by rounding).
#[derive(Clone, Copy)]
struct StatusClock {
    interval: f64,
    /// The next STATUS is at this multiple of the interval.
    next: Option<f64>,
}

impl StatusClock {
    /// Calls `due` with the time of each STATUS due before a reading at
    /// `time`, in order: after a gap of more than
    /// [`MAX_STATUS_CATCH_UP`] intervals, only the one at the last whole
    /// interval.
    fn due_before(&mut self, time: f64, mut due: impl FnMut(f64)) {
        let interval = self.interval;
        let k = self
            .next
            .get_or_insert_with(|| (time / interval).floor() + 1.0);
        if time - *k * interval >= f64::from(MAX_STATUS_CATCH_UP) * interval {
            *k = (time / interval).floor();
        }
        // At most the catch-up and one more: a time so far out that one
        // interval no longer moves the count (1e140 s) steps to the next
        // number instead, so the loop always ends.
        for _ in 0..=MAX_STATUS_CATCH_UP {
            if !(time >= *k * interval) {
                break;
            }
            due(*k * interval);
            let next = *k + 1.0;
            *k = if next > *k { next } else { k.next_up() };
        }
    }
}

/// What the pipeline publishes, in order: a line, a STATUS as its
/// message, or a 2-axis sensor's READING as its values (their lines are
/// written with the others, on the writer's thread at full speed).
enum Out {
    Line(String),
    Status(StatusMessage<String>),
    /// The READING of the configuration's sensor at that place.
    Reading(usize, ReadingValues),
}

/// Writes the pipeline's output: each [`Out`] as its line.
#[derive(Default)]
struct LineWriter {
    /// The configuration's sensors' names, in its order.
    names: Vec<String>,
    /// A READING's line, written again for each.
    line: String,
    /// A STATUS line, written again for each.
    status: Vec<u8>,
}

impl LineWriter {
    fn write(&mut self, item: Out, out: &mut dyn Write) -> std::io::Result<()> {
        match item {
            Out::Line(line) => {
                out.write_all(line.as_bytes())?;
                out.write_all(b"\n")
            }
            Out::Status(message) => {
                self.status.clear();
                self.status
                    .reserve(status_room(message.sensors.len() + message.sources.len()));
                write_line_to(&message, &mut self.status);
                self.status.push(b'\n');
                out.write_all(&self.status)
            }
            Out::Reading(sensor, values) => {
                self.line.clear();
                let name = self.names.get(sensor).map_or("", String::as_str);
                values.message(name).write_line(&mut self.line);
                self.line.push('\n');
                out.write_all(self.line.as_bytes())
            }
        }
    }
}

/// The daemon's sensors run on a recording for `fieldcal replay --config`:
/// every line `run` would publish, in order, on the recording's clock.
struct Pipeline {
    sensors: Sensors,
    index: usize,
    source_name: String,
    /// When STATUS lines are due (at full speed, a copy of it runs on the
    /// reading thread instead, and this one is not used).
    clock: StatusClock,
    realtime: bool,
    /// What is published and not yet written.
    pending: Vec<Out>,
    /// The configuration's sensors' names, as the writer has them.
    names: Vec<String>,
    writer: LineWriter,
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
        let names: Vec<String> = config.sensors.iter().map(|s| s.name.clone()).collect();
        Ok(Pipeline {
            sensors: Sensors::build(config, None).0,
            index,
            source_name: config
                .sources
                .get(index)
                .map_or("replay", |s| s.name.as_str())
                .to_string(),
            clock: StatusClock {
                interval: config.daemon.status_interval.as_secs_f64(),
                next: None,
            },
            realtime: !matches!(speed, Speed::Max),
            pending: Vec::new(),
            writer: LineWriter {
                names: names.clone(),
                ..LineWriter::default()
            },
            names,
            failed: None,
        })
    }

    /// Publishes the STATUS lines due before `time`, then the event's lines,
    /// and writes them; on a write error, keeps it and asks the source to
    /// stop.
    fn handle(
        &mut self,
        time: f64,
        event: SourceEvent,
        counters: CountersSnapshot,
        out: &mut dyn Write,
        stop: &AtomicBool,
    ) {
        if self.failed.is_some() {
            return;
        }
        self.publish(time, event, counters);
        for item in self.pending.drain(..) {
            let written = self
                .writer
                .write(item, out)
                .and_then(|()| if self.realtime { out.flush() } else { Ok(()) });
            if let Err(e) = written {
                self.failed = Some(e);
                stop.store(true, Ordering::Relaxed);
                return;
            }
        }
    }

    /// Publishes the STATUS lines due before `time`, then the event's
    /// lines, to [`Self::pending`].
    fn publish(&mut self, time: f64, event: SourceEvent, counters: CountersSnapshot) {
        let mut clock = self.clock;
        clock.due_before(time, |at| self.status(at, counters));
        self.clock = clock;
        self.event(event);
    }

    /// Publishes the STATUS at `time` with the source's `counters`.
    fn status(&mut self, time: f64, counters: CountersSnapshot) {
        let statuses = vec![SourceStatus {
            source: self.source_name.clone(),
            connected: true,
            counters,
        }];
        let message = self.sensors.status_message(time, statuses, str::to_string);
        self.pending.push(Out::Status(message));
    }

    /// Publishes an event's lines to [`Self::pending`].
    fn event(&mut self, event: SourceEvent) {
        // The lines and the READINGs' values go to one list, in order.
        let pending = RefCell::new(std::mem::take(&mut self.pending));
        let names = &self.names;
        let mut emit = |_: Lane, line: String| pending.borrow_mut().push(Out::Line(line));
        let mut readings = |sensor: &str, values: ReadingValues| {
            // Every sensor is the configuration's; the line at once if not.
            let out = match names.iter().position(|n| n == sensor) {
                Some(place) => Out::Reading(place, values),
                None => Out::Line(values.message(sensor).to_line()),
            };
            pending.borrow_mut().push(out);
        };
        let mut sensor_out = Emitter::deferred(&mut emit, &mut readings);
        match event {
            SourceEvent::Reading(reading) => {
                self.sensors
                    .on_reading(self.index, &reading, &mut sensor_out, &mut |_| {})
            }
            SourceEvent::Row(row) => {
                self.sensors
                    .on_row(self.index, &row, &mut sensor_out, &mut |_| {})
            }
            _ => {}
        }
        self.pending = pending.into_inner();
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
/// state is read or written. A capture opened to be read as it plays
/// ([`crate::capture::open_capture`]) keeps memory from growing with its
/// length; one read whole plays as [`Playable::Whole`].
pub fn replay_through_pipeline(
    config: &Config,
    capture: &mut Playable,
    name: &str,
    source: Option<&str>,
    speed: Speed,
    out: &mut (dyn Write + Send),
) -> Result<ReplaySummary, DaemonError> {
    let play: Play =
        &mut |stop, counters, emit| replay_playable(capture, name, speed, stop, counters, emit);
    through_pipeline(config, source, speed, out, play)
}

/// A replay: plays its readings into the callback, with the stop flag
/// and the counters it keeps.
type Play<'a> = &'a mut (
            dyn FnMut(
    &AtomicBool,
    &SourceCounters,
    &mut dyn FnMut(Reading),
) -> Result<ReplaySummary, ReplayError>
                + Send
        );

/// Readings a replay at full speed hands from its reading thread to the
/// pipeline at once, and batches of them on their way at most (and as
/// many of the pipeline's output to its writer): what is decoded ahead
/// and not yet written is bounded (a few megabytes; a larger batch wakes
/// the other threads less often).
const BATCH: usize = 2048;
const BATCHES_AHEAD: usize = 4;

fn through_pipeline(
    config: &Config,
    source: Option<&str>,
    speed: Speed,
    out: &mut (dyn Write + Send),
    play: Play,
) -> Result<ReplaySummary, DaemonError> {
    let mut pipeline = Pipeline::new(config, source, speed)?;
    let stop = AtomicBool::new(false);
    if matches!(speed, Speed::Max) {
        let played = played_ahead(&mut pipeline, &stop, out, play);
        // A failed write stopped the reading: it is the error, as on one
        // thread, even when the reading (further on here) also failed.
        if let Some(e) = pipeline.failed.take() {
            return Err(DaemonError::Output(e));
        }
        let summary = played?;
        pipeline.finish(out)?;
        return Ok(summary);
    }
    let counters = SourceCounters::default();
    let summary = play(&stop, &counters, &mut |reading| {
        pipeline.handle(
            reading.time,
            SourceEvent::Reading(reading),
            counters.snapshot(),
            out,
            &stop,
        );
    })?;
    pipeline.finish(out)?;
    Ok(summary)
}

/// Readings played ahead of the pipeline, and the STATUS lines due
/// among them: each before the reading at its place, with the source's
/// counters as they stood when that reading was handed on (so it counts
/// what it would have counted on one thread: the output is the same to
/// the byte).
struct Played {
    readings: Vec<Reading>,
    /// (place in `readings`, time, counters), in order.
    statuses: Vec<(usize, f64, CountersSnapshot)>,
}

impl Played {
    /// An empty batch, with room for its readings and for the STATUS
    /// lines of a recording at 20 Hz or slower with a STATUS a second.
    fn new() -> Self {
        Played {
            readings: Vec::with_capacity(BATCH),
            statuses: Vec::with_capacity(BATCH / 16),
        }
    }
}

/// A replay at full speed on three threads (two cores): the capture is
/// read and decoded on a thread of its own, a batch of readings ahead of
/// the pipeline, with the STATUS lines due among them (the pipeline's
/// [`StatusClock`] moves to that thread); the pipeline's output is
/// written on a third, its READINGs' and STATUS lines made there from
/// their values. A failed write stops the reading and the pipeline as
/// before; the readings already decoded are dropped.
fn played_ahead(
    pipeline: &mut Pipeline,
    stop: &AtomicBool,
    out: &mut (dyn Write + Send),
    play: Play,
) -> Result<ReplaySummary, ReplayError> {
    let (send, receive) = std::sync::mpsc::sync_channel::<Played>(BATCHES_AHEAD);
    let (to_writer, written) = std::sync::mpsc::sync_channel::<Vec<Out>>(BATCHES_AHEAD);
    // The writer's emptied batches, for the pipeline to fill again.
    let (give_back, given_back) = std::sync::mpsc::sync_channel::<Vec<Out>>(BATCHES_AHEAD + 1);
    let mut writer = std::mem::take(&mut pipeline.writer);
    let mut clock = pipeline.clock;
    std::thread::scope(|scope| {
        let player = scope.spawn(move || {
            let counters = SourceCounters::default();
            let mut batch = Played::new();
            let played = play(stop, &counters, &mut |reading| {
                let place = batch.readings.len();
                clock.due_before(reading.time, |at| {
                    batch.statuses.push((place, at, counters.snapshot()));
                });
                batch.readings.push(reading);
                if batch.readings.len() == BATCH {
                    let full = std::mem::replace(&mut batch, Played::new());
                    if send.send(full).is_err() {
                        stop.store(true, Ordering::Relaxed);
                    }
                }
            });
            if !batch.readings.is_empty() {
                // The pipeline is gone only when it panicked, or stopped
                // because the writer failed: the rest is not wanted.
                let _ = send.send(batch);
            }
            played
        });
        let lines = scope.spawn(move || {
            for mut batch in written {
                for item in batch.drain(..) {
                    if let Err(e) = writer.write(item, out) {
                        stop.store(true, Ordering::Relaxed);
                        return Some(e);
                    }
                }
                let _ = give_back.try_send(batch);
            }
            None
        });
        // Owned here, so a panic in the pipeline drops them: the reading
        // thread's next send fails and it stops, the writer's batches end,
        // and the panic goes on.
        let (receive, to_writer) = (receive, to_writer);
        for batch in receive {
            let mut statuses = batch.statuses.into_iter().peekable();
            for (place, reading) in batch.readings.into_iter().enumerate() {
                while let Some((_, at, counters)) = statuses.next_if(|&(p, ..)| p == place) {
                    pipeline.status(at, counters);
                }
                pipeline.event(SourceEvent::Reading(reading));
            }
            let empty = given_back.try_recv().unwrap_or_default();
            let full = std::mem::replace(&mut pipeline.pending, empty);
            // The writer is gone only when it failed (or panicked).
            if to_writer.send(full).is_err() {
                stop.store(true, Ordering::Relaxed);
                break;
            }
        }
        drop(to_writer);
        pipeline.failed = lines
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic));
        player
            .join()
            .unwrap_or_else(|panic| std::panic::resume_unwind(panic))
    })
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
    let Some(SourceKind::Csv(Csv {
        files,
        time_column,
        period_s,
        ..
    })) = config.sources.get(pipeline.index).map(|s| &s.kind)
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
            pipeline.handle(
                row.time,
                SourceEvent::Row(row),
                counters.snapshot(),
                out,
                &stop,
            );
        },
    )?;
    pipeline.finish(out)?;
    Ok(summary)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;
    use std::time::Duration;

    fn config() -> Config {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/pipeline.toml");
        let text = std::fs::read_to_string(&path).expect("tests/data/pipeline.toml");
        crate::daemon::config::parse(&text, &path).expect("the pipeline's configuration")
    }

    /// A replay of `readings` readings of a turning magnetometer, 50 ms
    /// apart, which stops when asked; `then` is what it returns.
    fn player(
        readings: u32,
        then: fn() -> Result<(), ReplayError>,
    ) -> impl FnMut(
        &AtomicBool,
        &SourceCounters,
        &mut dyn FnMut(Reading),
    ) -> Result<ReplaySummary, ReplayError>
    + Send {
        move |stop, _, emit| {
            let mut summary = ReplaySummary::default();
            for k in 0..readings {
                if stop.load(Ordering::Relaxed) {
                    summary.stopped = true;
                    break;
                }
                let angle = f64::from(k) * 0.03;
                emit(Reading {
                    time: f64::from(k) * 0.05,
                    mag: Some([
                        (1000.0 * angle.cos()) as i16,
                        (1000.0 * angle.sin()) as i16,
                        0,
                    ]),
                    ..Reading::default()
                });
                summary.readings += 1;
            }
            then().map(|()| summary)
        }
    }

    /// A full-speed replay (three threads, the STATUS times found on the
    /// reading thread) writes what one thread writes, to the byte: the
    /// STATUS lines in their places in four batches (some due at a
    /// batch's first reading), after gaps of a few intervals and of more
    /// than the catch-up, after a time that goes back, each with the
    /// counters as they stood at its reading. (The player here does not
    /// pace itself: `Speed::Times(1.0)` only takes the one-thread path.)
    #[test]
    fn a_full_speed_replay_writes_what_one_thread_writes() {
        let config = config();
        let times: Vec<f64> = (0..3 * BATCH + 700)
            .map(|k| {
                let t = k as f64 * 0.05;
                match k {
                    k if k < BATCH => t,
                    // A gap of 4.5 intervals at the second batch's first
                    // reading (the interval is 1 s), then one of 40
                    // (beyond the catch-up), then back by 7 s.
                    k if k < 4500 => t + 4.5,
                    k if k < 5000 => t + 44.5,
                    _ => t + 37.5,
                }
            })
            .collect();
        let replay = |speed: Speed| {
            let times = times.clone();
            let mut play = move |stop: &AtomicBool,
                                 counters: &SourceCounters,
                                 emit: &mut dyn FnMut(Reading)|
                  -> Result<ReplaySummary, ReplayError> {
                let mut summary = ReplaySummary::default();
                for (k, &time) in times.iter().enumerate() {
                    if stop.load(Ordering::Relaxed) {
                        break;
                    }
                    counters.bytes_read.fetch_add(22, Ordering::Relaxed);
                    counters.frames_good.fetch_add(1, Ordering::Relaxed);
                    let angle = k as f64 * 0.03;
                    emit(Reading {
                        time,
                        mag: Some([
                            (1000.0 * angle.cos()) as i16,
                            (1000.0 * angle.sin()) as i16,
                            0,
                        ]),
                        ..Reading::default()
                    });
                    summary.readings += 1;
                }
                Ok(summary)
            };
            let mut out = Vec::new();
            through_pipeline(&config, None, speed, &mut out, &mut play).expect("the replay");
            // A fit's own duration is the one thing that differs by run.
            let text = String::from_utf8(out).expect("lines of text");
            text.lines()
                .map(|line| match line.find("\"fit_ms\":") {
                    Some(at) => {
                        let end = line[at..].find(',').map_or(line.len(), |e| at + e);
                        format!("{}{}", &line[..at], &line[end..])
                    }
                    None => line.to_string(),
                })
                .collect::<Vec<_>>()
        };
        let (threads, one) = (replay(Speed::Max), replay(Speed::Times(1.0)));
        let count = |class: &str| one.iter().filter(|l| l.contains(class)).count();
        assert!(
            count("\"STATUS\"") > 100,
            "{} STATUS lines",
            count("\"STATUS\"")
        );
        assert!(count("\"CALIBRATION\"") > 0, "no calibration");
        for (k, (a, b)) in threads.iter().zip(&one).enumerate() {
            assert_eq!(a, b, "line {k}");
        }
        assert_eq!(threads.len(), one.len());
    }

    /// An output that panics when written (a defect in what writes it).
    struct Panics;

    impl Write for Panics {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            panic!("the output broke")
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// An output that refuses every write (a full disk).
    struct Full;

    impl Write for Full {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(std::io::Error::new(
                std::io::ErrorKind::StorageFull,
                "disk full",
            ))
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// A panic while the output is written (on the writer's thread) ends
    /// the replay at full speed with that panic, though the reading thread
    /// has far more to hand on than the batches on their way hold (neither
    /// it nor the pipeline waits on them for ever).
    #[test]
    fn a_panic_in_the_pipeline_ends_a_full_speed_replay() {
        let ended = ends_in_a_panic(|| {
            let config = config();
            let mut play = player(100_000, || Ok(()));
            let _ = through_pipeline(&config, None, Speed::Max, &mut Panics, &mut play);
        });
        assert_eq!(
            ended,
            Ok(true),
            "the replay did not end with the pipeline's panic"
        );
    }

    /// A panic on the reading thread ends the replay at full speed with
    /// that panic: the pipeline and the writer do not wait for batches
    /// that will never come.
    #[test]
    fn a_panic_in_the_reading_ends_a_full_speed_replay() {
        let ended = ends_in_a_panic(|| {
            let config = config();
            let mut inner = player(10_000, || Ok(()));
            let mut play = move |stop: &AtomicBool,
                                 counters: &SourceCounters,
                                 emit: &mut dyn FnMut(Reading)|
                  -> Result<ReplaySummary, ReplayError> {
                let mut n = 0;
                inner(stop, counters, &mut |reading| {
                    n += 1;
                    assert!(n < 5_000, "the capture broke");
                    emit(reading);
                })
            };
            let _ = through_pipeline(&config, None, Speed::Max, &mut std::io::sink(), &mut play);
        });
        assert_eq!(
            ended,
            Ok(true),
            "the replay did not end with the reading's panic"
        );
    }

    /// Runs `replay` on a thread of its own: whether it ended in a panic,
    /// or a timeout when it has not ended within a minute (a replay that
    /// waits for ever).
    fn ends_in_a_panic(
        replay: impl FnOnce() + Send + 'static,
    ) -> Result<bool, mpsc::RecvTimeoutError> {
        let (done, finished) = mpsc::channel();
        std::thread::spawn(move || {
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(replay));
            let _ = done.send(outcome.is_err());
        });
        finished.recv_timeout(Duration::from_secs(60))
    }

    /// A failed write is the replay's error, as on one thread, even when
    /// the reading, which ran on ahead of it, failed as well.
    #[test]
    fn a_failed_write_is_the_error_of_a_full_speed_replay() {
        let config = config();
        let mut play = player(10_000, || {
            Err(ReplayError::Read {
                name: "long.fcap".into(),
                source: std::io::Error::other("the disk went away"),
            })
        });
        let outcome = through_pipeline(&config, None, Speed::Max, &mut Full, &mut play);
        assert!(
            matches!(&outcome, Err(DaemonError::Output(e)) if e.kind() == std::io::ErrorKind::StorageFull),
            "{outcome:?}"
        );
    }
}
