//! Sources: the I/O tasks that own a port or a file and turn its bytes into
//! timestamped [`Reading`]s. Each is thin: the decoding lives in
//! [`crate::protocol`], the file format in [`crate::capture`].

pub mod bridge;
pub mod clock;
pub mod csv;
pub mod replay;
pub mod serial;

use std::sync::atomic::{AtomicU64, Ordering};

use serde::Serialize;

use crate::io::csv::CsvRow;
use crate::sample::Reading;

/// What a source hands on.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceEvent {
    /// A decoded reading.
    Reading(Reading),
    /// A row of a CSV recording: every column's value, in the order of the
    /// header the source resolved once at start (see [`csv`]).
    Row(CsvRow),
    /// Bytes exactly as they came off the wire, for `record`. `stream`
    /// numbers the byte streams of one source (see [`crate::capture`]).
    /// `at` is the monotonic instant the bytes arrived: a capture's record
    /// times are measured on it, so a step of the wall clock (NTP setting
    /// it, an operator's `date -s`) cannot move them or send them back.
    Raw {
        at: std::time::Instant,
        stream: u8,
        bytes: Vec<u8>,
    },
    /// The device is open and answering (first time, or again).
    Connected { device: String },
    /// The device went away; the source retries until it is back.
    Disconnected { device: String, reason: String },
}

/// Counters a source keeps while it runs; shared with whoever reports them.
#[derive(Debug, Default)]
pub struct SourceCounters {
    pub bytes_read: AtomicU64,
    pub bytes_skipped: AtomicU64,
    pub frames_good: AtomicU64,
    pub frames_bad: AtomicU64,
    pub frames_lost: AtomicU64,
    pub timer_resets: AtomicU64,
    pub polls: AtomicU64,
    pub poll_errors: AtomicU64,
    pub reconnects: AtomicU64,
}

/// A copy of [`SourceCounters`] at one moment.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct CountersSnapshot {
    pub bytes_read: u64,
    pub bytes_skipped: u64,
    pub frames_good: u64,
    pub frames_bad: u64,
    pub frames_lost: u64,
    pub timer_resets: u64,
    pub polls: u64,
    pub poll_errors: u64,
    pub reconnects: u64,
}

impl SourceCounters {
    pub fn snapshot(&self) -> CountersSnapshot {
        let get = |c: &AtomicU64| c.load(Ordering::Relaxed);
        CountersSnapshot {
            bytes_read: get(&self.bytes_read),
            bytes_skipped: get(&self.bytes_skipped),
            frames_good: get(&self.frames_good),
            frames_bad: get(&self.frames_bad),
            frames_lost: get(&self.frames_lost),
            timer_resets: get(&self.timer_resets),
            polls: get(&self.polls),
            poll_errors: get(&self.poll_errors),
            reconnects: get(&self.reconnects),
        }
    }

    pub fn add(counter: &AtomicU64, n: u64) {
        counter.fetch_add(n, Ordering::Relaxed);
    }
}
