//! `kind = "usb-iss"`: chips behind a USB-ISS I2C bridge, polled in turn,
//! one stream per chip.

use std::path::PathBuf;
use std::time::Duration;

use super::{Checked, Keys, Kind};
use crate::daemon::config::{ConfigError, SourceConfig, StreamDesc};
use crate::daemon::run::{DaemonError, SourceTask, Start, Started, cannot_start};
use crate::protocol::chips::Chip;
use crate::source::bridge::{BridgeConfig, I2cSpeed, spawn_bridge_source};

/// The longest poll period a bridge takes, in ms.
pub const POLL_MS_MAX: u64 = 60_000;

/// Chips behind a USB-ISS bridge, polled in this order: stream k is
/// `chips[k]`.
#[derive(Debug, Clone, PartialEq)]
pub struct UsbIss {
    pub port: PathBuf,
    pub chips: Vec<(Chip, u8)>,
    pub poll: Duration,
    pub i2c_khz: u32,
}

impl UsbIss {
    /// The bridge's settings, retrying every `retry` after a failure.
    pub fn bridge_config(&self, retry: Duration) -> BridgeConfig {
        BridgeConfig {
            period: self.poll,
            retry_interval: retry,
            speed: if self.i2c_khz == 400 {
                I2cSpeed::Khz400
            } else {
                I2cSpeed::Khz100
            },
            ..BridgeConfig::new(&self.port, self.chips.clone())
        }
    }
}

impl Kind for UsbIss {
    const NAME: &'static str = "usb-iss";
    const KEYS: &'static [&'static str] = &["port", "chips", "poll_ms", "i2c_khz"];

    /// The bridge's port, chips, poll period and bus speed, and a stream
    /// for each chip.
    fn check(keys: &Keys<'_, '_>) -> Result<Checked<Self>, ConfigError> {
        let checker = keys.checker();
        let port = checker.require_port(keys, "/dev/ttyACM0")?;
        let chips = keys.get::<Vec<String>>("chips")?;
        let chips = checker.check_chips(keys.section(), chips.unwrap_or_default())?;
        let poll_ms = keys.get::<u64>("poll_ms")?.unwrap_or(30);
        if !(1..=POLL_MS_MAX).contains(&poll_ms) {
            return Err(keys.error(
                "poll_ms",
                format!("{poll_ms} ms: give 1 to {POLL_MS_MAX} ms between polls"),
            ));
        }
        let i2c_khz = keys.get::<u32>("i2c_khz")?.unwrap_or(100);
        if i2c_khz != 100 && i2c_khz != 400 {
            return Err(keys.error(
                "i2c_khz",
                format!("{i2c_khz} kHz: the USB-ISS runs the bus at 100 or 400 kHz"),
            ));
        }
        let streams = chips
            .iter()
            .enumerate()
            .map(|(k, &chip)| StreamDesc {
                id: u8::try_from(k).unwrap_or(u8::MAX),
                chip: Some(chip),
            })
            .collect();
        Ok(Checked {
            settings: UsbIss {
                port,
                chips,
                poll: Duration::from_millis(poll_ms),
                i2c_khz,
            },
            streams,
            layouts: None,
        })
    }

    fn changed(&self, new: &Self) -> Vec<&'static str> {
        let mut keys = Vec::new();
        if self.port != new.port {
            keys.push("port");
        }
        if self.chips != new.chips {
            keys.push("chips");
        }
        if self.poll != new.poll {
            keys.push("poll_ms");
        }
        if self.i2c_khz != new.i2c_khz {
            keys.push("i2c_khz");
        }
        keys
    }

    /// The bridge, polled on a thread.
    fn spawn(&self, source: &SourceConfig, start: Start<'_>) -> Result<Started, DaemonError> {
        let thread = spawn_bridge_source(
            self.bridge_config(source.retry),
            start.tx,
            start.counters.clone(),
            start.stop_flag.clone(),
        )
        .map_err(|e| cannot_start(source, e))?;
        Ok(SourceTask::Thread(thread).into())
    }
}
