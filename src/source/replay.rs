//! Replay: plays a capture (or a plain raw dump) back through the same
//! decoders a live source uses, at the pace it was recorded, faster, or as
//! fast as the machine allows.
//!
//! Synchronous on purpose: `--speed max` is a hot path, and a blocking loop
//! over an in-memory file is the fastest way through it. A daemon runs it on
//! a blocking thread.

use std::str::FromStr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;

use crate::capture::{
    CaptureFile, CaptureHeader, CaptureStream, Chunk, ChunkRef, Playable, RawDump, StreamKind,
};
use crate::protocol::chips::Chip;
use crate::protocol::falcon::{DecoderCounters, FalconDecoder, NOMINAL_PERIOD};
use crate::sample::Reading;
use crate::source::SourceCounters;
use crate::source::serial::publish_counters;

/// How fast a replay runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Speed {
    /// N times real time (1 = as recorded).
    Times(f64),
    /// As fast as the machine allows.
    Max,
}

impl FromStr for Speed {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        if text == "max" {
            return Ok(Speed::Max);
        }
        match text.parse::<f64>() {
            Ok(v) => Speed::times(v),
            _ => Err(format!(
                "'{text}' is not a speed: give a positive factor (1 = real time, 10 = ten times faster) or 'max'"
            )),
        }
    }
}

/// Slowest replay speed, as a factor of real time. At 1e-3 one 50 ms
/// Falcon-GX frame takes 50 s to come round and an hour's capture takes six
/// weeks: slower replays show nothing a person can watch, and pace times
/// stay far inside what a `Duration` holds (1e-300 made them overflow it).
pub const MIN_SPEED: f64 = 1e-3;
/// Fastest replay speed as a factor: at 1e6 a day's capture is due in
/// under 0.1 s, which is what `max` does anyway; a larger factor only hides
/// a typing mistake.
pub const MAX_SPEED: f64 = 1e6;

impl Speed {
    /// A factor of real time within [`MIN_SPEED`]..=[`MAX_SPEED`], or why not.
    pub fn times(factor: f64) -> Result<Speed, String> {
        if (MIN_SPEED..=MAX_SPEED).contains(&factor) {
            Ok(Speed::Times(factor))
        } else {
            // 1e-300 in full would fill a screen.
            let shown = match factor.to_string() {
                s if s.len() > 12 => format!("{factor:e}"),
                s => s,
            };
            Err(format!(
                "{shown} is not a speed: give a factor from {MIN_SPEED} to {MAX_SPEED:e} (1 = real time, 10 = ten times faster) or 'max'"
            ))
        }
    }
}

/// Why a file cannot be replayed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error(
        "{name}: neither a fieldcal capture nor a raw dump of Falcon-GX frames (no valid frame in {bytes} bytes); record one with `fieldcal record`"
    )]
    NotACapture { name: String, bytes: usize },
    #[error("{name}: cannot read it: {source}")]
    Read {
        name: String,
        #[source]
        source: std::io::Error,
    },
}

/// What a replay went through.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ReplaySummary {
    /// Readings handed on.
    pub readings: u64,
    /// Chunks of bytes (records of a capture) replayed.
    pub chunks: u64,
    /// The Falcon-GX decoder's counters, over every Falcon stream.
    pub falcon: DecoderCounters,
    /// Chip polls whose bytes did not decode.
    pub chip_errors: u64,
    /// Seconds of recording covered.
    pub span_s: f64,
    /// A torn tail, described, when the capture ended mid-record.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truncated: Option<String>,
    /// The replay was stopped before the end.
    pub stopped: bool,
}

/// Waits until each recorded time comes round, scaled by the speed.
pub(crate) struct Pacer {
    started: Instant,
    speed: Speed,
    /// Recording time not waited for: the gaps skipped ([`Pacer::skip`]).
    skipped: f64,
}

/// A jump forward in a recording's time beyond this is a gap, not a pause
/// to wait through: 1 h. A log's rows come every few milliseconds to a
/// second; an hour between two rows is two sessions in one file, or a
/// clock that jumped (a time of 1e140, a shift by the Unix epoch). The
/// source says so with the row's line and plays on at once, so it never
/// sleeps past this bound in silence.
pub const MAX_GAP_S: f64 = 3600.0;

impl Pacer {
    pub(crate) fn new(speed: Speed) -> Self {
        Pacer {
            started: Instant::now(),
            speed,
            skipped: 0.0,
        }
    }

    /// Plays on past `gap` seconds of recording time without waiting.
    pub(crate) fn skip(&mut self, gap: f64) {
        if gap.is_finite() && gap > 0.0 {
            self.skipped += gap;
        } else {
            // Beyond what a number holds: nothing after it can be paced.
            self.speed = Speed::Max;
        }
    }

    pub(crate) fn wait_for(&self, time: f64, stop: &AtomicBool) {
        let Speed::Times(factor) = self.speed else {
            return;
        };
        let time = time - self.skipped;
        // A capture's times are user data: a due time beyond what a
        // Duration or the clock holds is treated as "a day from now", and the
        // stop flag still ends the wait.
        let day = Duration::from_secs(86_400);
        let wait = Duration::try_from_secs_f64((time / factor).max(0.0))
            .unwrap_or(day)
            .min(day * 366 * 100);
        let due = self
            .started
            .checked_add(wait)
            .or_else(|| Instant::now().checked_add(day))
            .unwrap_or_else(Instant::now);
        // Sleep in slices so a stop request is honoured promptly.
        loop {
            let now = Instant::now();
            if now >= due || stop.load(Ordering::Relaxed) {
                return;
            }
            std::thread::sleep((due - now).min(Duration::from_millis(100)));
        }
    }
}

enum StreamDecoder {
    Falcon(Box<FalconDecoder>),
    Chip(Chip),
}

/// Replays `file`, calling `emit` for every reading in order. `name` is used
/// in messages. Stops early when `stop` turns true.
pub fn replay(
    file: &CaptureFile,
    name: &str,
    speed: Speed,
    stop: &AtomicBool,
    emit: &mut dyn FnMut(Reading),
) -> Result<ReplaySummary, ReplayError> {
    replay_counted(file, name, speed, stop, &SourceCounters::default(), emit)
}

/// [`replay`], keeping `counters` as a live source does while it plays:
/// `bytes_read` per record, the Falcon decoder's `bytes_skipped`,
/// `frames_good`, `frames_bad`, `frames_lost` and `timer_resets`, and a
/// chip poll's reading (good) or decoding error (bad).
pub fn replay_counted(
    file: &CaptureFile,
    name: &str,
    speed: Speed,
    stop: &AtomicBool,
    counters: &SourceCounters,
    emit: &mut dyn FnMut(Reading),
) -> Result<ReplaySummary, ReplayError> {
    let playback = Playback {
        name,
        speed,
        stop,
        counters,
    };
    match file {
        CaptureFile::Raw { bytes } => replay_raw_dump(&mut bytes.as_slice(), playback, emit),
        CaptureFile::Capture {
            header,
            chunks,
            truncated,
        } => {
            let mut records = InMemory(chunks.iter());
            let mut summary = play_records(header, &mut records, playback, emit);
            summary.truncated = truncated.as_ref().map(|t| t.to_string());
            Ok(summary)
        }
    }
}

/// [`replay_counted`] of a capture opened to be read as it plays
/// ([`crate::capture::open_capture`]): memory does not grow with its
/// length, and everything before a torn tail plays.
pub fn replay_playable(
    playable: &mut Playable,
    name: &str,
    speed: Speed,
    stop: &AtomicBool,
    counters: &SourceCounters,
    emit: &mut dyn FnMut(Reading),
) -> Result<ReplaySummary, ReplayError> {
    let playback = Playback {
        name,
        speed,
        stop,
        counters,
    };
    match playable {
        Playable::Whole(file) => replay_counted(file, name, speed, stop, counters, emit),
        Playable::Raw(dump) => replay_raw_dump(dump, playback, emit),
        Playable::Stream(stream) => {
            let header = stream.header().clone();
            let mut summary = play_records(&header, stream.as_mut(), playback, emit);
            if let Some(source) = stream.take_error() {
                return Err(ReplayError::Read {
                    name: name.to_string(),
                    source,
                });
            }
            // Known once the reading reaches it (not when stopped before).
            summary.truncated = stream.truncated().map(|t| t.to_string());
            Ok(summary)
        }
    }
}

/// Records of a capture, one at a time.
trait Records {
    fn next_chunk(&mut self) -> Option<ChunkRef<'_>>;
}

impl Records for CaptureStream {
    fn next_chunk(&mut self) -> Option<ChunkRef<'_>> {
        CaptureStream::next_chunk(self)
    }
}

/// The records of a capture read whole.
struct InMemory<'a>(std::slice::Iter<'a, Chunk>);

impl Records for InMemory<'_> {
    fn next_chunk(&mut self) -> Option<ChunkRef<'_>> {
        self.0.next().map(|c| ChunkRef {
            time: c.time,
            stream: c.stream,
            bytes: &c.bytes,
        })
    }
}

/// Plays the records of a capture with `header` through its streams'
/// decoders.
fn play_records(
    header: &CaptureHeader,
    records: &mut dyn Records,
    playback: Playback,
    emit: &mut dyn FnMut(Reading),
) -> ReplaySummary {
    let Playback {
        name,
        speed,
        stop,
        counters,
    } = playback;
    let mut decoders: Vec<(u8, StreamDecoder, DecoderCounters)> = header
        .streams
        .iter()
        .map(|s| {
            let decoder = match s.kind {
                StreamKind::Falcon => StreamDecoder::Falcon(Box::default()),
                StreamKind::Chip { chip, .. } => StreamDecoder::Chip(chip),
            };
            (s.id, decoder, DecoderCounters::default())
        })
        .collect();
    let mut summary = ReplaySummary::default();
    let mut pacer = Pacer::new(speed);
    let mut frames = Vec::new();
    let mut last = 0.0;
    while let Some(chunk) = records.next_chunk() {
        if stop.load(Ordering::Relaxed) {
            summary.stopped = true;
            break;
        }
        let gap = chunk.time - last;
        if gap > MAX_GAP_S {
            tracing::warn!(
                "{name}: the capture's time jumps {gap:.3e} s at {:.3} s, more than {MAX_GAP_S} s: treated as a gap, played on at once",
                last
            );
            pacer.skip(gap);
        }
        last = chunk.time;
        pacer.wait_for(chunk.time, stop);
        summary.chunks += 1;
        summary.span_s = chunk.time;
        SourceCounters::add(&counters.bytes_read, chunk.bytes.len() as u64);
        let decoder = decoders
            .iter_mut()
            .find(|(id, _, _)| *id == chunk.stream)
            .map(|(_, d, reported)| (d, reported));
        match decoder {
            Some((StreamDecoder::Falcon(decoder), reported)) => {
                // Counted before the readings are handed on, so a
                // STATUS made on a reading includes its frame.
                frames.clear();
                decoder.decode(chunk.bytes, |frame| frames.push(frame));
                publish_counters(decoder, reported, counters);
                for frame in frames.drain(..) {
                    summary.readings += 1;
                    emit(Reading {
                        stream: chunk.stream,
                        ..frame.to_reading(chunk.time)
                    });
                }
            }
            Some((StreamDecoder::Chip(chip), _)) => match chip.decode(chunk.bytes, chunk.time) {
                Ok(reading) => {
                    SourceCounters::add(&counters.frames_good, 1);
                    summary.readings += 1;
                    // As the live bridge stamps it: the chip's stream.
                    emit(Reading {
                        stream: chunk.stream,
                        ..reading
                    });
                }
                Err(e) => {
                    SourceCounters::add(&counters.frames_bad, 1);
                    summary.chip_errors += 1;
                    tracing::warn!("{name}: record at {:.3} s: {e}", chunk.time);
                }
            },
            // The reader refuses records of undeclared streams.
            None => {}
        }
    }
    for (_, decoder, _) in &decoders {
        if let StreamDecoder::Falcon(d) = decoder {
            add_counters(&mut summary.falcon, d.counters());
        }
    }
    summary
}

/// How a replay plays: the name its messages use, its speed, the flag
/// that stops it, and the counters it keeps as a live source would.
#[derive(Clone, Copy)]
struct Playback<'a> {
    name: &'a str,
    speed: Speed,
    stop: &'a AtomicBool,
    counters: &'a SourceCounters,
}

/// A plain dump's bytes, handed on in blocks as often as they are asked
/// for: a file ([`RawDump`]) or bytes in memory (one block).
trait DumpBlocks {
    /// Its length in bytes.
    fn len(&self) -> u64;
    /// Hands its bytes to `each` in order, from the start, until `each`
    /// returns false.
    fn blocks(&mut self, each: &mut dyn FnMut(&[u8]) -> bool) -> std::io::Result<()>;
}

impl DumpBlocks for RawDump {
    fn len(&self) -> u64 {
        RawDump::len(self)
    }

    fn blocks(&mut self, each: &mut dyn FnMut(&[u8]) -> bool) -> std::io::Result<()> {
        RawDump::blocks(self, each)
    }
}

impl DumpBlocks for &[u8] {
    fn len(&self) -> u64 {
        <[u8]>::len(self) as u64
    }

    fn blocks(&mut self, each: &mut dyn FnMut(&[u8]) -> bool) -> std::io::Result<()> {
        each(self);
        Ok(())
    }
}

/// Replays a plain dump (it has no timing) at the nominal period. It is read twice: once to
/// count what it holds (its bytes and bad frames count from the start, as
/// when it is decoded at once), once to hand its frames on.
fn replay_raw_dump(
    dump: &mut dyn DumpBlocks,
    playback: Playback,
    emit: &mut dyn FnMut(Reading),
) -> Result<ReplaySummary, ReplayError> {
    let Playback {
        name,
        speed,
        stop,
        counters,
    } = playback;
    let read_error = |source| ReplayError::Read {
        name: name.to_string(),
        source,
    };
    let mut counted = FalconDecoder::new();
    let mut frames_in_dump = 0u64;
    dump.blocks(&mut |block| {
        counted.decode(block, |_| frames_in_dump += 1);
        true
    })
    .map_err(read_error)?;
    if frames_in_dump == 0 {
        return Err(ReplayError::NotACapture {
            name: name.to_string(),
            bytes: usize::try_from(dump.len()).unwrap_or(usize::MAX),
        });
    }
    SourceCounters::add(&counters.bytes_read, dump.len());
    let decoded = counted.counters();
    publish_counters(
        &counted,
        &mut DecoderCounters {
            frames_good: decoded.frames_good,
            ..DecoderCounters::default()
        },
        counters,
    );
    let period = NOMINAL_PERIOD.as_secs_f64();
    let pacer = Pacer::new(speed);
    let mut summary = ReplaySummary {
        falcon: counted.counters(),
        chunks: 1,
        ..Default::default()
    };
    let mut decoder = FalconDecoder::new();
    let mut frames = Vec::new();
    let mut k = 0u64;
    dump.blocks(&mut |block| {
        frames.clear();
        decoder.decode(block, |frame| frames.push(frame));
        for frame in &frames {
            if stop.load(Ordering::Relaxed) {
                summary.stopped = true;
                return false;
            }
            // Rounded to the nanosecond, as capture times are.
            let time = (k as f64 * period * 1e9).round() / 1e9;
            k += 1;
            pacer.wait_for(time, stop);
            summary.readings += 1;
            summary.span_s = time;
            SourceCounters::add(&counters.frames_good, 1);
            emit(frame.to_reading(time));
        }
        true
    })
    .map_err(read_error)?;
    if counted.pending() > 0 {
        summary.truncated = Some(format!(
            "{name}: the last {} bytes are an incomplete frame",
            counted.pending()
        ));
    }
    Ok(summary)
}

fn add_counters(total: &mut DecoderCounters, more: DecoderCounters) {
    total.bytes_skipped += more.bytes_skipped;
    total.frames_good += more.frames_good;
    total.frames_bad += more.frames_bad;
    total.frames_lost += more.frames_lost;
    total.timer_resets += more.timer_resets;
}
