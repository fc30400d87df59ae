//! The Falcon-GX-style serial source: a tokio task that owns the port.
//!
//! It opens the port, sends the start-continuous command, decodes what
//! arrives and hands readings on. End of stream, a read error or a port that
//! vanishes means the device is gone: the task releases the port and reopens
//! it every `retry_interval` (gpsd retries every 2 s) until the device is
//! back or the task is told to stop. On stop it sends the stop command.

use std::io;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{mpsc, watch};
use tokio_serial::{SerialPortBuilderExt, SerialStream};

use super::clock::live_now;
use super::{SourceCounters, SourceEvent};
use crate::protocol::falcon::{
    BAUD, DecoderCounters, FalconDecoder, START_CONTINUOUS, STOP_CONTINUOUS,
};
use crate::sample::Reading;

/// Settings of the serial source.
#[derive(Debug, Clone, PartialEq)]
pub struct SerialConfig {
    pub port: PathBuf,
    pub baud: u32,
    /// How long to wait before reopening a port that failed or vanished.
    pub retry_interval: Duration,
    /// A partial frame older than this is dropped (the line went quiet
    /// mid-frame), as MIP's parser does.
    pub idle_timeout: Duration,
    /// Also hand on the raw bytes (for `record`).
    pub raw: bool,
}

impl SerialConfig {
    pub fn new(port: impl Into<PathBuf>) -> Self {
        SerialConfig {
            port: port.into(),
            baud: BAUD,
            retry_interval: Duration::from_secs(2),
            idle_timeout: Duration::from_millis(250),
            raw: false,
        }
    }
}

/// The wall clock in seconds since the Unix epoch (0 before it), as a
/// capture's header records it; live messages are stamped by
/// [`super::clock::live_now`], which never goes back.
pub fn unix_now() -> f64 {
    super::clock::unix_time().unwrap_or(0.0)
}

/// Why the port could not be opened, in words that say what to do.
fn open_advice(port: &str, err: &tokio_serial::Error) -> String {
    use tokio_serial::ErrorKind;
    match err.kind() {
        ErrorKind::NoDevice => format!("{port}: no such device: check the cable and the port path"),
        ErrorKind::Io(io::ErrorKind::NotFound) => {
            format!("{port}: no such device: check the cable and the port path")
        }
        ErrorKind::Io(io::ErrorKind::PermissionDenied) => format!(
            "{port}: permission denied: add the user to the port's group (usually dialout) or run as a user that has it"
        ),
        _ => format!("{port}: cannot open: {err}"),
    }
}

/// Runs the source until `stop` turns true or the receiver of `events` goes
/// away. Never returns an error: every failure is logged, counted and retried.
/// Readings are stamped on the process's live clock ([`live_now`]), so their
/// times keep their order across a reconnect and a wall clock stepped back.
pub async fn run_serial_source(
    config: SerialConfig,
    events: mpsc::Sender<SourceEvent>,
    counters: Arc<SourceCounters>,
    mut stop: watch::Receiver<bool>,
) {
    let device = config.port.display().to_string();
    let mut connected_before = false;
    let mut last_open_error = String::new();
    loop {
        if *stop.borrow() {
            return;
        }
        match open(&config) {
            Ok(port) => {
                last_open_error.clear();
                if connected_before {
                    SourceCounters::add(&counters.reconnects, 1);
                }
                connected_before = true;
                tracing::info!(port = %device, "device connected");
                if events
                    .send(SourceEvent::Connected {
                        device: device.clone(),
                    })
                    .await
                    .is_err()
                {
                    return;
                }
                match stream(&config, port, &events, &counters, &mut stop).await {
                    Ended::Stopped | Ended::ReceiverGone => return,
                    Ended::DeviceGone(reason) => {
                        tracing::warn!(port = %device, %reason, "device gone; retrying every {:?}", config.retry_interval);
                        if events
                            .send(SourceEvent::Disconnected {
                                device: device.clone(),
                                reason,
                            })
                            .await
                            .is_err()
                        {
                            return;
                        }
                    }
                }
            }
            Err(e) => {
                let message = open_advice(&device, &e);
                // Say it once, not every retry.
                if message != last_open_error {
                    tracing::warn!("{message}; retrying every {:?}", config.retry_interval);
                    last_open_error = message;
                }
            }
        }
        tokio::select! {
            _ = tokio::time::sleep(config.retry_interval) => {}
            _ = stop.changed() => {}
        }
    }
}

fn open(config: &SerialConfig) -> Result<SerialStream, tokio_serial::Error> {
    let path = config.port.to_string_lossy();
    tokio_serial::new(path, config.baud)
        .data_bits(tokio_serial::DataBits::Eight)
        .parity(tokio_serial::Parity::None)
        .stop_bits(tokio_serial::StopBits::One)
        .flow_control(tokio_serial::FlowControl::None)
        .open_native_async()
}

enum Ended {
    Stopped,
    ReceiverGone,
    DeviceGone(String),
}

async fn stream(
    config: &SerialConfig,
    mut port: SerialStream,
    events: &mpsc::Sender<SourceEvent>,
    counters: &SourceCounters,
    stop: &mut watch::Receiver<bool>,
) -> Ended {
    if let Err(e) = port.write_all(&START_CONTINUOUS).await {
        return Ended::DeviceGone(format!("cannot send the start command: {e}"));
    }
    let mut decoder = FalconDecoder::new();
    let mut reported = DecoderCounters::default();
    let mut buf = vec![0u8; 4096];
    let mut readings: Vec<Reading> = Vec::new();
    // The quiet timer runs only while the decoder holds part of a frame:
    // a line that delivers whole frames arms no timer at all (no timer
    // registered and cancelled on every read).
    let quiet = tokio::time::sleep(config.idle_timeout);
    tokio::pin!(quiet);
    loop {
        let holding = decoder.pending() > 0;
        // Bytes waiting are read before the quiet timer is looked at.
        let n = tokio::select! {
            biased;
            _ = stop.changed() => {
                // Best effort: the device may already be gone.
                let _ = tokio::time::timeout(Duration::from_millis(200), async {
                    port.write_all(&STOP_CONTINUOUS).await?;
                    port.flush().await
                })
                .await;
                return Ended::Stopped;
            }
            read = port.read(&mut buf) => match read {
                Ok(0) => return Ended::DeviceGone("end of stream".into()),
                Ok(n) => n,
                Err(e) => return Ended::DeviceGone(format!("read failed: {e}")),
            },
            () = &mut quiet, if holding => {
                let dropped = decoder.discard_partial();
                tracing::debug!(
                    bytes = dropped,
                    "dropped a partial frame after the line went quiet"
                );
                publish_counters(&decoder, &mut reported, counters);
                continue;
            }
        };
        let (time, at) = live_now();
        let bytes = &buf[..n];
        SourceCounters::add(&counters.bytes_read, n as u64);
        if config.raw
            && events
                .send(SourceEvent::Raw {
                    at,
                    stream: 0,
                    bytes: bytes.to_vec(),
                })
                .await
                .is_err()
        {
            return Ended::ReceiverGone;
        }
        decoder.decode(bytes, |frame| readings.push(frame.to_reading(time)));
        publish_counters(&decoder, &mut reported, counters);
        for reading in readings.drain(..) {
            if events.send(SourceEvent::Reading(reading)).await.is_err() {
                return Ended::ReceiverGone;
            }
        }
        if holding || decoder.pending() > 0 {
            // A partial frame is dropped when nothing more comes for
            // `idle_timeout` from the next read on (not from this one: a
            // full queue may have held the readings' hand-over meanwhile).
            // The timer is made anew, not reset: tokio moves a timer to a
            // later time lazily, waking at the old deadline to find it
            // moved; and one no longer needed is let go, not left to wake.
            quiet.set(tokio::time::sleep(config.idle_timeout));
        }
    }
}

/// Adds what the decoder counted since the last call to the shared counters.
pub(crate) fn publish_counters(
    decoder: &FalconDecoder,
    reported: &mut DecoderCounters,
    counters: &SourceCounters,
) {
    let now = decoder.counters();
    let before = &*reported;
    for (counter, added) in [
        (
            &counters.bytes_skipped,
            now.bytes_skipped - before.bytes_skipped,
        ),
        (&counters.frames_good, now.frames_good - before.frames_good),
        (&counters.frames_bad, now.frames_bad - before.frames_bad),
        (&counters.frames_lost, now.frames_lost - before.frames_lost),
        (
            &counters.timer_resets,
            now.timer_resets - before.timer_resets,
        ),
    ] {
        SourceCounters::add(counter, added);
    }
    *reported = now;
}
