//! The recorder: writes the raw bytes a source hands on into a capture
//! file, with their receive times, flushing often so a pulled plug or a
//! killed process loses at most the last moment.

use std::io::Write;
use std::time::{Duration, Instant};

use serde::Serialize;
use tokio::sync::{mpsc, watch};

use crate::capture::CaptureWriter;
use crate::source::SourceEvent;

/// What a recording captured.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct RecordSummary {
    pub chunks: u64,
    pub bytes: u64,
    pub readings: u64,
    pub disconnects: u64,
    /// Times the source reported the device open and answering.
    pub connects: u64,
}

/// Why a recording that ended holds no bytes: the device was not there,
/// never became ready (opened and set up), or was ready and stayed silent.
/// Each says what to do.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NothingRecorded {
    #[error(
        "{port}: no such device, so nothing was recorded in {seconds:.1} s: plug the device in, check the cable and the port path (ls /dev/serial/by-id/), then record again"
    )]
    NoSuchDevice { port: String, seconds: f64 },
    #[error(
        "{port}: the device never became ready, so nothing was recorded in {seconds:.1} s: the warning above says why (often the port's permissions: the dialout group; or another program holding it; or a chip behind a bridge not answering); fix that, then record again"
    )]
    NeverReady { port: String, seconds: f64 },
    #[error(
        "{port}: the device opened but sent no bytes in {seconds:.1} s: check that it is powered and streaming, the line speed, and that --device names what is on the port, then record again"
    )]
    NoBytes { port: String, seconds: f64 },
}

impl RecordSummary {
    /// `Ok` when the recording holds at least one chunk of bytes; otherwise
    /// why not, from what the source reported and whether the port's path
    /// exists (`port_exists`, checked by the caller at the end).
    pub fn check_recorded(
        &self,
        port: &str,
        port_exists: bool,
        elapsed: Duration,
    ) -> Result<(), NothingRecorded> {
        if self.chunks > 0 {
            return Ok(());
        }
        let port = port.to_string();
        let seconds = elapsed.as_secs_f64();
        Err(if self.connects > 0 {
            NothingRecorded::NoBytes { port, seconds }
        } else if port_exists {
            NothingRecorded::NeverReady { port, seconds }
        } else {
            NothingRecorded::NoSuchDevice { port, seconds }
        })
    }
}

/// Writes every `Raw` event to `writer` until `stop` turns true, `duration`
/// has passed, or the source ends. A chunk's record time is the monotonic
/// time from `started` (the instant the header's `started_unix` was read) to
/// the chunk's arrival, never the wall clock's difference: a step of the
/// wall clock during a recording moves no record time and sends none back.
/// A write error (full disk, pulled USB stick) ends the recording with that
/// error; what was flushed before it stays readable.
pub async fn record<W: Write>(
    mut events: mpsc::Receiver<SourceEvent>,
    writer: &mut CaptureWriter<W>,
    started: Instant,
    duration: Option<Duration>,
    mut stop: watch::Receiver<bool>,
) -> std::io::Result<RecordSummary> {
    let mut summary = RecordSummary::default();
    let deadline = duration.map(|d| tokio::time::Instant::now() + d);
    let mut last_flush = Instant::now();
    loop {
        let event = tokio::select! {
            event = events.recv() => event,
            _ = stop.changed() => None,
            _ = sleep_until(deadline) => None,
        };
        let Some(event) = event else { break };
        match event {
            SourceEvent::Raw {
                at, stream, bytes, ..
            } => {
                let since = at.saturating_duration_since(started);
                let ns = u64::try_from(since.as_nanos()).unwrap_or(u64::MAX);
                writer.write_chunk_ns(ns, stream, &bytes)?;
                summary.chunks += 1;
                summary.bytes += bytes.len() as u64;
                if last_flush.elapsed() >= Duration::from_millis(500) {
                    writer.flush()?;
                    last_flush = Instant::now();
                }
            }
            SourceEvent::Reading(_) | SourceEvent::Row(_) => summary.readings += 1,
            SourceEvent::Disconnected { .. } => summary.disconnects += 1,
            SourceEvent::Connected { .. } => summary.connects += 1,
        }
    }
    writer.flush()?;
    Ok(summary)
}

async fn sleep_until(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(d) => tokio::time::sleep_until(d).await,
        None => std::future::pending().await,
    }
}
