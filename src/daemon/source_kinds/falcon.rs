//! `kind = "falcon"`: a Falcon-GX-style IMU on a serial line, one stream.

use std::path::PathBuf;

use super::{Checked, Keys, Kind};
use crate::daemon::config::{ConfigError, SourceConfig, StreamDesc};
use crate::daemon::run::{DaemonError, SourceTask, Start, Started};
use crate::protocol::falcon;
use crate::source::serial::{SerialConfig, run_serial_source};

/// A Falcon-GX-style IMU on a serial line: one stream (0).
#[derive(Debug, Clone, PartialEq)]
pub struct Falcon {
    pub port: PathBuf,
    pub baud: u32,
}

impl Kind for Falcon {
    const NAME: &'static str = "falcon";
    const KEYS: &'static [&'static str] = &["port", "baud"];

    fn check(keys: &Keys<'_, '_>) -> Result<Checked<Self>, ConfigError> {
        let port = keys.checker().require_port(keys, "/dev/ttyUSB0")?;
        let baud = keys.get::<u32>("baud")?.unwrap_or(falcon::BAUD);
        if baud == 0 {
            return Err(keys.error(
                "baud",
                format!(
                    "0 is not a line speed: give the device's, such as {}",
                    falcon::BAUD
                ),
            ));
        }
        Ok(Checked {
            settings: Falcon { port, baud },
            streams: vec![StreamDesc { id: 0, chip: None }],
            layouts: None,
        })
    }

    fn changed(&self, new: &Self) -> Vec<&'static str> {
        let mut keys = Vec::new();
        if self.port != new.port {
            keys.push("port");
        }
        if self.baud != new.baud {
            keys.push("baud");
        }
        keys
    }

    /// An async task on the serial port.
    fn spawn(&self, source: &SourceConfig, start: Start<'_>) -> Result<Started, DaemonError> {
        let serial = SerialConfig {
            baud: self.baud,
            retry_interval: source.retry,
            ..SerialConfig::new(&self.port)
        };
        Ok(SourceTask::Async(tokio::spawn(run_serial_source(
            serial,
            start.tx,
            start.counters.clone(),
            start.stop_rx.clone(),
        )))
        .into())
    }
}
