//! The bridge poll source: a thread that owns a USB-ISS port, sets up the
//! chips behind it and reads them on a steady schedule.
//!
//! A plain thread, not a tokio task: the serial port is blocking, and a
//! thread of its own keeps the runtime free and the schedule steady. Events
//! go out on a tokio channel. Per poll and chip it sends the chip's data
//! bytes as [`SourceEvent::Raw`] (`stream` = the chip's index in
//! [`BridgeConfig::chips`]) and then the decoded [`SourceEvent::Reading`], so
//! a capture replays through [`Chip::decode`] to the same readings.
//!
//! Failures (a port that will not open, a bridge that does not answer, a
//! chip that does not acknowledge) are logged with `tracing::warn!`, naming
//! the port, chip and address, and counted in `poll_errors`; the port is then
//! closed and opened again every `retry_interval` until the device is back.

use std::io;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use serialport::SerialPort;
use tokio::sync::mpsc::{Sender, error::TrySendError};

use super::clock::live_now;
use super::{SourceCounters, SourceEvent};
use crate::i2c::I2cBus;
use crate::i2c::I2cError;
use crate::i2c::usb_iss::UsbIssBus;
use crate::protocol::chips::{Chip, ChipError, init_chip, read_chip};
pub use crate::protocol::usb_iss::I2cSpeed;
use crate::sample::Reading;

/// One poll per 30 ms: 33 Hz, fast enough for a hand-turned sensor.
pub const DEFAULT_PERIOD: Duration = Duration::from_millis(30);
/// A USB-ISS answers within a few ms; 100 ms means it is not answering.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_millis(100);
/// How often a missing or failed device is tried again.
pub const DEFAULT_RETRY_INTERVAL: Duration = Duration::from_secs(2);
/// The longest the thread sleeps without looking at the stop flag.
const STOP_CHECK: Duration = Duration::from_millis(20);
/// How long to wait between tries when the event channel is full.
const FULL_CHANNEL_WAIT: Duration = Duration::from_millis(1);

/// What to poll and how.
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeConfig {
    /// The USB-ISS serial port, e.g. `/dev/ttyACM0`.
    pub port: PathBuf,
    /// The chips and their 7-bit addresses, read in this order each poll.
    pub chips: Vec<(Chip, u8)>,
    /// Time between polls (polls start at start + k * period).
    pub period: Duration,
    pub speed: I2cSpeed,
    /// How long one reply from the bridge may take.
    pub timeout: Duration,
    /// Time between tries to open and set up the device after a failure.
    pub retry_interval: Duration,
}

impl BridgeConfig {
    /// A configuration with the defaults: 30 ms polls, 100 kHz, 100 ms reply
    /// timeout, retry every 2 s.
    pub fn new(port: impl Into<PathBuf>, chips: Vec<(Chip, u8)>) -> Self {
        BridgeConfig {
            port: port.into(),
            chips,
            period: DEFAULT_PERIOD,
            speed: I2cSpeed::default(),
            timeout: DEFAULT_TIMEOUT,
            retry_interval: DEFAULT_RETRY_INTERVAL,
        }
    }

    /// Checks what would make the source useless or ambiguous.
    pub fn validate(&self) -> Result<(), String> {
        let port = self.port.display();
        if self.chips.is_empty() {
            return Err(format!(
                "bridge on {port}: no chips to poll: name at least one"
            ));
        }
        if self.chips.len() > usize::from(u8::MAX) + 1 {
            return Err(format!(
                "bridge on {port}: {} chips, at most 256 can be polled",
                self.chips.len()
            ));
        }
        for (i, &(chip, address)) in self.chips.iter().enumerate() {
            if address > 0x7F {
                return Err(format!(
                    "bridge on {port}: {} at 0x{address:02X}: not a 7-bit I2C address (0x00..=0x7F)",
                    chip.label()
                ));
            }
            if let Some(&(other, _)) = self.chips[..i].iter().find(|&&(_, a)| a == address) {
                return Err(format!(
                    "bridge on {port}: {} and {} both at 0x{address:02X}: give each its own address",
                    other.label(),
                    chip.label()
                ));
            }
        }
        for (name, value) in [
            ("period", self.period),
            ("timeout", self.timeout),
            ("retry interval", self.retry_interval),
        ] {
            if value.is_zero() {
                return Err(format!("bridge on {port}: the {name} must be above zero"));
            }
        }
        Ok(())
    }
}

/// Starts the source on a thread of its own. It runs until `stop` is set
/// (it then ends within about one period, or one reply timeout if a reply
/// is awaited) or the receiver of `events` is dropped.
///
/// Counters: `polls` (complete polls of every chip), `poll_errors` (failed
/// polls and failed tries to open and set up the device), `reconnects`
/// (set-ups that succeeded after the first) and `bytes_read` (data bytes).
pub fn spawn_bridge_source(
    config: BridgeConfig,
    events: Sender<SourceEvent>,
    counters: Arc<SourceCounters>,
    stop: Arc<AtomicBool>,
) -> io::Result<JoinHandle<()>> {
    config
        .validate()
        .map_err(|message| io::Error::new(io::ErrorKind::InvalidInput, message))?;
    let runner = Runner {
        config,
        events,
        counters,
        stop,
    };
    thread::Builder::new()
        .name("fieldcal-bridge".into())
        .spawn(move || runner.run())
}

/// Why setting up the device failed.
#[derive(Debug, thiserror::Error)]
enum SetupError {
    #[error(transparent)]
    Bus(#[from] I2cError),
    #[error(transparent)]
    Chip(#[from] ChipError),
}

/// How a polling run ended without an error.
enum End {
    Stopped,
    ReceiverGone,
}

struct Runner {
    config: BridgeConfig,
    events: Sender<SourceEvent>,
    counters: Arc<SourceCounters>,
    stop: Arc<AtomicBool>,
}

type Bus = UsbIssBus<Box<dyn SerialPort>>;

impl Runner {
    fn run(self) {
        let port = self.config.port.display().to_string();
        let mut connected_before = false;
        // The last set-up failure logged at warn level, so a device that
        // stays missing does not fill the log with one line per retry.
        let mut last_warning: Option<String> = None;
        while !self.stopped() {
            match self.set_up() {
                Ok(mut bus) => {
                    last_warning = None;
                    if connected_before {
                        SourceCounters::add(&self.counters.reconnects, 1);
                    }
                    connected_before = true;
                    let device = self.device_name(&bus);
                    tracing::info!("{device}: polling every {:?}", self.config.period);
                    if !self.send(SourceEvent::Connected {
                        device: device.clone(),
                    }) {
                        return;
                    }
                    match self.poll(&mut bus) {
                        Ok(End::Stopped | End::ReceiverGone) => return,
                        Err(error) => {
                            drop(bus);
                            SourceCounters::add(&self.counters.poll_errors, 1);
                            let reason = error.to_string();
                            tracing::warn!(
                                "USB-ISS on {port}: {reason}; trying again in {:?}",
                                self.config.retry_interval
                            );
                            if !self.send(SourceEvent::Disconnected { device, reason }) {
                                return;
                            }
                        }
                    }
                }
                Err(error) => {
                    SourceCounters::add(&self.counters.poll_errors, 1);
                    let message = match &error {
                        SetupError::Bus(I2cError::Open { .. }) => error.to_string(),
                        _ => format!("USB-ISS on {port}: {error}"),
                    };
                    if last_warning.as_ref() != Some(&message) {
                        tracing::warn!(
                            "{message}; trying again every {:?}",
                            self.config.retry_interval
                        );
                        last_warning = Some(message);
                    } else {
                        tracing::debug!("{message}");
                    }
                }
            }
            if !self.sleep_until(Instant::now() + self.config.retry_interval) {
                return;
            }
        }
    }

    fn stopped(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// Opens the port, sets the I2C mode and sets up every chip.
    fn set_up(&self) -> Result<Bus, SetupError> {
        let mut bus = UsbIssBus::open(&self.config.port, self.config.timeout)?;
        bus.set_mode(self.config.speed)?;
        for &(chip, address) in &self.config.chips {
            init_chip(&mut bus, chip, address)?;
        }
        Ok(bus)
    }

    /// "USB-ISS on /dev/ttyACM0 (LSM303DLHC magnetometer at 0x1E, ...)".
    fn device_name(&self, bus: &Bus) -> String {
        let chips: Vec<String> = self
            .config
            .chips
            .iter()
            .map(|&(chip, address)| format!("{} at 0x{address:02X}", chip.label()))
            .collect();
        format!("{} ({})", bus.describe(), chips.join(", "))
    }

    /// Polls until stopped, the receiver goes or a transfer fails. Poll k is
    /// due at start + k * period; a poll that runs late makes the source
    /// skip the deadlines it missed (and any closer than half a period to
    /// the poll before), never catch up with a burst.
    fn poll(&self, bus: &mut Bus) -> Result<End, ChipError> {
        let period = self.config.period;
        let start = Instant::now();
        let mut k: u64 = 0;
        let mut buf = Vec::new();
        loop {
            if !self.sleep_until(deadline(start, period, k)) {
                return Ok(End::Stopped);
            }
            let poll_start = Instant::now();
            for (stream, &(chip, address)) in self.config.chips.iter().enumerate() {
                read_chip(bus, chip, address, &mut buf)?;
                // The process's live clock: in order across reconnects and
                // a wall clock stepped back.
                let (time, at) = live_now();
                SourceCounters::add(&self.counters.bytes_read, buf.len() as u64);
                // `validate` keeps the chip count within u8 streams.
                let stream = u8::try_from(stream).unwrap_or(u8::MAX);
                let reading = Reading {
                    stream,
                    ..chip.decode(&buf, time)?
                };
                let raw = SourceEvent::Raw {
                    at,
                    stream,
                    bytes: buf.clone(),
                };
                if !self.send(raw) || !self.send(SourceEvent::Reading(reading)) {
                    return Ok(End::ReceiverGone);
                }
            }
            SourceCounters::add(&self.counters.polls, 1);

            k += 1;
            let earliest = Instant::now().max(poll_start + period / 2);
            if deadline(start, period, k) < earliest {
                let due = periods_until(start, period, earliest);
                tracing::debug!(
                    "{}: poll ran late, skipping {} poll(s)",
                    bus.describe(),
                    due - k
                );
                k = due;
            }
        }
    }

    /// Sends an event, waiting while the channel is full. False when the
    /// receiver is gone or the source was stopped while waiting.
    ///
    /// Not `blocking_send`: that would wait past `stop` for a consumer that
    /// stalled.
    fn send(&self, event: SourceEvent) -> bool {
        let mut event = event;
        loop {
            match self.events.try_send(event) {
                Ok(()) => return true,
                Err(TrySendError::Closed(_)) => return false,
                Err(TrySendError::Full(back)) => {
                    if self.stopped() {
                        return false;
                    }
                    event = back;
                    thread::sleep(FULL_CHANNEL_WAIT);
                }
            }
        }
    }

    /// Sleeps until `deadline`, looking at the stop flag at least every
    /// [`STOP_CHECK`]. False if stopped.
    fn sleep_until(&self, deadline: Instant) -> bool {
        loop {
            if self.stopped() {
                return false;
            }
            let now = Instant::now();
            if now >= deadline {
                return true;
            }
            thread::sleep((deadline - now).min(STOP_CHECK));
        }
    }
}

/// start + k * period.
fn deadline(start: Instant, period: Duration, k: u64) -> Instant {
    let nanos = period.as_nanos().saturating_mul(u128::from(k));
    start + Duration::from_nanos(u64::try_from(nanos).unwrap_or(u64::MAX))
}

/// The smallest k with start + k * period >= at.
fn periods_until(start: Instant, period: Duration, at: Instant) -> u64 {
    let elapsed = at.saturating_duration_since(start).as_nanos();
    let period = period.as_nanos().max(1);
    u64::try_from(elapsed.div_ceil(period)).unwrap_or(u64::MAX)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn schedule_arithmetic() {
        let start = Instant::now();
        let p = Duration::from_millis(30);
        assert_eq!(deadline(start, p, 0), start);
        assert_eq!(deadline(start, p, 3), start + Duration::from_millis(90));
        assert_eq!(periods_until(start, p, start), 0);
        assert_eq!(periods_until(start, p, start + Duration::from_millis(1)), 1);
        assert_eq!(
            periods_until(start, p, start + Duration::from_millis(90)),
            3
        );
        assert_eq!(
            periods_until(start, p, start + Duration::from_millis(91)),
            4
        );
    }

    #[test]
    fn validate_rejects_useless_configurations() {
        let ok = BridgeConfig::new("/dev/x", vec![(Chip::Adxl345, 0x53)]);
        assert_eq!(ok.validate(), Ok(()));
        assert!(BridgeConfig::new("/dev/x", vec![]).validate().is_err());
        let twice = BridgeConfig::new("/dev/x", vec![(Chip::Adxl345, 0x53), (Chip::Mpu6050, 0x53)]);
        let err = twice.validate().unwrap_err();
        assert!(err.contains("0x53") && err.contains("MPU-6050"), "{err}");
        let wide = BridgeConfig::new("/dev/x", vec![(Chip::Adxl345, 0x80)]);
        assert!(wide.validate().is_err());
        let mut zero = ok.clone();
        zero.period = Duration::ZERO;
        assert!(zero.validate().unwrap_err().contains("period"));
    }
}
