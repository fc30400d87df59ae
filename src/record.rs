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
}

/// Writes every `Raw` event to `writer` (times relative to `started_unix`)
/// until `stop` turns true, `duration` has passed, or the source ends.
/// A write error (full disk, pulled USB stick) ends the recording with that
/// error; what was flushed before it stays readable.
pub async fn record<W: Write>(
    mut events: mpsc::Receiver<SourceEvent>,
    writer: &mut CaptureWriter<W>,
    started_unix: f64,
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
                time,
                stream,
                bytes,
            } => {
                writer.write_chunk((time - started_unix).max(0.0), stream, &bytes)?;
                summary.chunks += 1;
                summary.bytes += bytes.len() as u64;
                if last_flush.elapsed() >= Duration::from_millis(500) {
                    writer.flush()?;
                    last_flush = Instant::now();
                }
            }
            SourceEvent::Reading(_) | SourceEvent::Row(_) => summary.readings += 1,
            SourceEvent::Disconnected { .. } => summary.disconnects += 1,
            SourceEvent::Connected { .. } => {}
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
