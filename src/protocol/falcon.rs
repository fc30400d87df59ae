//! Falcon-GX-style RS-232 frames (docs/protocols.md §1), sans-IO: bytes in,
//! frames and counters out.
//!
//! A frame is 23 bytes: header `0x02`, magnetometer, accelerometer and
//! angular rate (x, y, z, big-endian `i16` each), a big-endian `u16` timer
//! that wraps, and a big-endian `u16` checksum. The decoder resynchronises
//! the way the MicroStrain MIP parser does: scan for the header, check the
//! checksum, and on a mismatch drop one byte and rescan, because a real
//! frame can start inside a false one.
//!
//! The decoder works on the caller's slice and keeps at most
//! `FRAME_LEN - 1` bytes between calls (a frame cut by a read boundary), so
//! memory stays bounded whatever the input.

use std::time::Duration;

use serde::Serialize;

use crate::sample::Reading;

/// Bytes in one frame, header and checksum included.
pub const FRAME_LEN: usize = 23;
/// First byte of every frame (the echo of command 0x02).
pub const HEADER: u8 = 0x02;
/// Host command that starts the continuous stream.
pub const START_CONTINUOUS: [u8; 3] = [0x10, 0x00, 0x02];
/// Host command that stops the continuous stream.
pub const STOP_CONTINUOUS: [u8; 3] = [0x10, 0x00, 0x00];
/// Line speed, 8N1.
pub const BAUD: u32 = 38_400;
/// Angular-rate counts per degree/second of this project's Falcon-GX-style
/// frame (what `fieldcal simulate --format falcon` writes). A real device's
/// scale is value / (32768000 / gain) with the gain in its EEPROM
/// (protocols.md §1, not verified): give it as the sensor's
/// `gyro_lsb_per_deg_s`. The heading check fits the gyro's scale anyway, so
/// a wrong value shows as a `gyro_scale` away from 1, not as a heading error.
pub const RATE_LSB_PER_DEG_S: f64 = 10.0;
/// One frame per period in continuous mode.
pub const NOMINAL_PERIOD: Duration = Duration::from_millis(50);

/// Offset of the checksum: the bytes before it are what it sums.
const CHECKSUM_AT: usize = FRAME_LEN - 2;
/// Positive timer deltas the default decoder looks at to learn the step.
const LEARN_DELTAS: usize = 8;
/// A jump of more timer steps than this is a reset, not lost frames: a
/// counter of millions of lost frames would say less than "the timer reset".
pub const MAX_GAP_STEPS: u32 = 1000;
/// Forward jumps beyond half the `u16` range are read as the timer going
/// backwards (with wrapping arithmetic the two cannot be told apart).
const HALF_RANGE: u32 = 0x7FFF;

/// One decoded frame, in raw counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct FalconFrame {
    pub mag: [i16; 3],
    pub accel: [i16; 3],
    pub rate: [i16; 3],
    /// Device ticks; wraps at 65536. Tick length is not verified, so it only
    /// serves to detect lost frames.
    pub timer: u16,
}

/// Why a 23-byte block is not a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    #[error("first byte is {0:#04x}, expected the header {HEADER:#04x}")]
    BadHeader(u8),
    #[error("checksum is {found:#06x}, the bytes sum to {computed:#06x}")]
    BadChecksum { found: u16, computed: u16 },
}

impl FalconFrame {
    /// The frame as the device sends it, with a correct checksum.
    pub fn encode(&self) -> [u8; FRAME_LEN] {
        let mut out = [0u8; FRAME_LEN];
        out[0] = HEADER;
        let words = self.mag.iter().chain(&self.accel).chain(&self.rate);
        for (dst, w) in out[1..19].chunks_exact_mut(2).zip(words) {
            dst.copy_from_slice(&w.to_be_bytes());
        }
        out[19..21].copy_from_slice(&self.timer.to_be_bytes());
        let sum = checksum_fixed(&out);
        out[21..23].copy_from_slice(&sum.to_be_bytes());
        out
    }

    /// Parses one block, checking header and checksum (for callers that
    /// already know where a frame starts; streams go through [`FalconDecoder`]).
    pub fn parse(frame: &[u8; FRAME_LEN]) -> Result<Self, FrameError> {
        if frame[0] != HEADER {
            return Err(FrameError::BadHeader(frame[0]));
        }
        let found = u16::from_be_bytes([frame[21], frame[22]]);
        let computed = checksum_fixed(frame);
        if found != computed {
            return Err(FrameError::BadChecksum { found, computed });
        }
        Ok(Self::from_fields(frame))
    }

    /// The fields of a block, unchecked. Every index is a constant below
    /// `FRAME_LEN`, so this cannot panic.
    #[inline(always)]
    fn from_fields(f: &[u8; FRAME_LEN]) -> Self {
        let i = |at: usize| i16::from_be_bytes([f[at], f[at + 1]]);
        FalconFrame {
            mag: [i(1), i(3), i(5)],
            accel: [i(7), i(9), i(11)],
            rate: [i(13), i(15), i(17)],
            timer: u16::from_be_bytes([f[19], f[20]]),
        }
    }

    /// The frame as a [`Reading`] stamped with the host receive time (the
    /// device timer's tick length is not verified, so it is not the time).
    pub fn to_reading(&self, time: f64) -> Reading {
        Reading {
            time,
            mag: Some(self.mag),
            accel: Some(self.accel),
            gyro: Some(self.rate),
            timer: Some(self.timer),
            ..Reading::default()
        }
    }
}

/// Checksum of a frame's first 21 bytes: the header byte plus the following
/// big-endian 16-bit words, mod 65536.
///
/// Any length is accepted so callers cannot make it panic: a trailing odd
/// byte counts as the high byte of a word padded with zero, and an empty
/// slice sums to 0. Pass exactly bytes `0..21` to get the frame's checksum.
pub fn checksum(frame_without_checksum: &[u8]) -> u16 {
    let Some((&first, rest)) = frame_without_checksum.split_first() else {
        return 0;
    };
    let mut words = rest.chunks_exact(2);
    let mut sum = u16::from(first);
    for w in &mut words {
        sum = sum.wrapping_add(u16::from_be_bytes([w[0], w[1]]));
    }
    if let [odd] = words.remainder() {
        sum = sum.wrapping_add(u16::from(*odd) << 8);
    }
    sum
}

/// The hot-path checksum: constant indices into a fixed array, unrolled by
/// the compiler with no bounds checks.
#[inline(always)]
fn checksum_fixed(f: &[u8; FRAME_LEN]) -> u16 {
    let mut sum = u16::from(f[0]);
    let mut at = 1;
    while at < CHECKSUM_AT {
        sum = sum.wrapping_add(u16::from_be_bytes([f[at], f[at + 1]]));
        at += 2;
    }
    sum
}

/// What the decoder has seen since it was made.
///
/// Every byte fed in is, once decided, either skipped or part of a good
/// frame, so `bytes fed == bytes_skipped + 23 * frames_good + pending()`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct DecoderCounters {
    /// Bytes that were not part of a good frame: garbage before a header,
    /// the header byte of each bad candidate, and partial frames dropped by
    /// [`FalconDecoder::discard_partial`].
    pub bytes_skipped: u64,
    /// Frames with a valid checksum, all handed to `emit`.
    pub frames_good: u64,
    /// Header bytes followed by 22 bytes that failed the checksum. Garbage
    /// that contains 0x02 inflates this: each such byte with 22 bytes after
    /// it is a candidate, so it counts candidates rejected, not frames
    /// damaged on the line.
    pub frames_bad: u64,
    /// Frames missing according to timer gaps (see [`FalconDecoder`]).
    pub frames_lost: u64,
    /// Timer deltas that were no gap of whole frames: standing still, going
    /// backwards, or jumping more than [`MAX_GAP_STEPS`] steps (a device reset).
    pub timer_resets: u64,
}

/// Streaming decoder for Falcon-GX-style frames.
///
/// # Lost frames
/// The timer advances by a fixed but unverified number of ticks per frame
/// (the *step*). [`FalconDecoder::new`] learns it as the lower median of the
/// first 8 positive deltas between consecutive good frames (robust to up to
/// 3 gaps among them); [`FalconDecoder::with_ticks_per_frame`] takes it as
/// given. With `d` the wrapping `u16` difference of consecutive timers and
/// `k = round(d / step)`:
/// - `k == 1`: the next frame (so 65535 -> 0 with step 1 is no loss);
/// - `2 <= k <= min(1000, 32767 / step)`: `k - 1` frames lost;
/// - otherwise (`k == 0`: the timer stood still or stepped back; a jump of
///   more than half the timer range, read as going backwards; or more than
///   1000 steps): one timer reset, no loss counted, and counting restarts
///   from this frame with the same step.
///
/// While learning, deltas that are zero or backwards count as resets; the
/// 8 learning deltas are classified by the rule above once the step is known,
/// so gaps among them are counted too (`frames_lost` lags until then). A gap
/// longer than the timer's wrap period cannot be seen at all.
#[derive(Debug, Clone)]
pub struct FalconDecoder {
    /// Start of a frame cut by a read boundary; always begins with HEADER.
    partial: [u8; FRAME_LEN - 1],
    partial_len: usize,
    counters: DecoderCounters,
    timer: TimerTracker,
}

impl Default for FalconDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FalconDecoder {
    /// A decoder that learns the timer step from the stream.
    pub fn new() -> Self {
        FalconDecoder {
            partial: [0; FRAME_LEN - 1],
            partial_len: 0,
            counters: DecoderCounters::default(),
            timer: TimerTracker::default(),
        }
    }

    /// A decoder for a device whose timer advances `ticks` per frame. Zero
    /// means "unknown": the decoder learns it as [`FalconDecoder::new`] does.
    pub fn with_ticks_per_frame(ticks: u16) -> Self {
        let mut d = Self::new();
        d.timer.step = (ticks != 0).then_some(ticks);
        d
    }

    /// The timer step in use: given, learned, or `None` while learning.
    pub fn ticks_per_frame(&self) -> Option<u16> {
        self.timer.step
    }

    /// Consumes bytes in any chunking; calls `emit` for every valid frame,
    /// in order. Frames are decoded straight from `bytes`; only a frame that
    /// spans two calls goes through the small internal buffer.
    pub fn decode(&mut self, bytes: &[u8], mut emit: impl FnMut(FalconFrame)) {
        let mut start = 0;
        if self.partial_len > 0 {
            // Frames starting in the held bytes need at most FRAME_LEN - 1
            // more bytes, so stitch only that much onto a stack copy.
            let held = self.partial_len.min(FRAME_LEN - 1);
            let take = bytes.len().min(FRAME_LEN - 1);
            let mut joined = [0u8; 2 * (FRAME_LEN - 1)];
            joined[..held].copy_from_slice(&self.partial[..held]);
            joined[held..held + take].copy_from_slice(&bytes[..take]);
            let joined = &joined[..held + take];
            let pos = self.scan(joined, held, &mut emit);
            if pos < held {
                // Stalled on a header with too few bytes after it. That can
                // only happen when all of `bytes` fit in `joined`.
                let rest = joined.get(pos..).unwrap_or_default();
                self.keep(rest);
                return;
            }
            start = pos - held;
            self.partial_len = 0;
        }
        let input = bytes.get(start..).unwrap_or_default();
        let pos = self.scan(input, input.len(), &mut emit);
        self.keep(input.get(pos..).unwrap_or_default());
    }

    /// Drops a partial frame held across reads, for the I/O task to call
    /// after an idle timeout (as MIP's parser does): a frame the device never
    /// finished must not swallow the start of the next one. Returns the bytes
    /// dropped, which count as skipped.
    pub fn discard_partial(&mut self) -> usize {
        let n = self.partial_len;
        self.counters.bytes_skipped += n as u64;
        self.partial_len = 0;
        n
    }

    /// Bytes held awaiting more input (always less than `FRAME_LEN`).
    pub fn pending(&self) -> usize {
        self.partial_len
    }

    pub fn counters(&self) -> DecoderCounters {
        self.counters
    }

    /// Holds the undecided tail of the input. `scan` only leaves a tail
    /// shorter than a frame; anything longer would be a bug, and is dropped
    /// as skipped rather than held, to keep memory bounded.
    fn keep(&mut self, rest: &[u8]) {
        match self.partial.get_mut(..rest.len()) {
            Some(dst) => {
                dst.copy_from_slice(rest);
                self.partial_len = rest.len();
            }
            None => {
                self.counters.bytes_skipped += rest.len() as u64;
                self.partial_len = 0;
            }
        }
    }

    /// Decodes frames that start before `limit` in `data`. Returns where it
    /// stopped: at or past `limit`, or on a header with fewer than
    /// `FRAME_LEN` bytes after it (the caller keeps those).
    #[inline(always)]
    fn scan(&mut self, data: &[u8], limit: usize, emit: &mut impl FnMut(FalconFrame)) -> usize {
        let end = limit.min(data.len());
        let mut pos = 0;
        while pos < end {
            let window = data.get(pos..end).unwrap_or_default();
            match window.iter().position(|&b| b == HEADER) {
                Some(0) => {}
                Some(n) => {
                    self.counters.bytes_skipped += n as u64;
                    pos += n;
                }
                None => {
                    self.counters.bytes_skipped += window.len() as u64;
                    return end;
                }
            }
            let Some(block) = data.get(pos..).and_then(<[u8]>::first_chunk::<FRAME_LEN>) else {
                return pos;
            };
            let found = u16::from_be_bytes([block[21], block[22]]);
            if found == checksum_fixed(block) {
                let frame = FalconFrame::from_fields(block);
                self.counters.frames_good += 1;
                self.timer.update(frame.timer, &mut self.counters);
                emit(frame);
                pos += FRAME_LEN;
            } else {
                // Drop only the header byte: a real frame may start inside.
                self.counters.frames_bad += 1;
                self.counters.bytes_skipped += 1;
                pos += 1;
            }
        }
        pos
    }
}

/// Turns timer deltas into lost frames and resets (rule on [`FalconDecoder`]).
#[derive(Debug, Clone, Default)]
struct TimerTracker {
    last: Option<u16>,
    step: Option<u16>,
    learned: [u16; LEARN_DELTAS],
    learned_len: usize,
}

/// What one timer delta means.
enum Gap {
    Next,
    Lost(u64),
    Reset,
}

fn classify(delta: u16, step: u16) -> Gap {
    if delta == step {
        return Gap::Next;
    }
    let step = u32::from(step.max(1));
    let k = (u32::from(delta) + step / 2) / step;
    let max_k = MAX_GAP_STEPS.min(HALF_RANGE / step);
    match k {
        1 => Gap::Next,
        k if k >= 2 && k <= max_k => Gap::Lost(u64::from(k - 1)),
        _ => Gap::Reset,
    }
}

impl TimerTracker {
    #[inline(always)]
    fn update(&mut self, timer: u16, counters: &mut DecoderCounters) {
        let last = self.last.replace(timer);
        let Some(last) = last else { return };
        let delta = timer.wrapping_sub(last);
        match self.step {
            Some(step) if delta == step => {}
            Some(step) => Self::apply(classify(delta, step), counters),
            None => self.learn(delta, counters),
        }
    }

    fn apply(gap: Gap, counters: &mut DecoderCounters) {
        match gap {
            Gap::Next => {}
            Gap::Lost(n) => counters.frames_lost += n,
            Gap::Reset => counters.timer_resets += 1,
        }
    }

    #[cold]
    fn learn(&mut self, delta: u16, counters: &mut DecoderCounters) {
        if delta == 0 || u32::from(delta) > HALF_RANGE {
            counters.timer_resets += 1;
            return;
        }
        let Some(slot) = self.learned.get_mut(self.learned_len) else {
            return;
        };
        *slot = delta;
        self.learned_len += 1;
        if self.learned_len < LEARN_DELTAS {
            return;
        }
        let mut sorted = self.learned;
        sorted.sort_unstable();
        // Lower median: gaps only make deltas larger, so up to 3 of 8 can be
        // gaps without moving it.
        let step = sorted[LEARN_DELTAS / 2 - 1];
        self.step = Some(step);
        for &d in &self.learned {
            Self::apply(classify(d, step), counters);
        }
    }
}
