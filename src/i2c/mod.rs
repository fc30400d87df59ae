//! The I2C bus: one trait that every chip driver talks through, so a chip
//! works the same behind a USB-ISS bridge ([`usb_iss`]), Linux i2c-dev
//! (`linux`, with feature `linux-i2c`) or a test double.

#[cfg(feature = "linux-i2c")]
pub mod linux;
pub mod usb_iss;

use std::fmt;
use std::io;
use std::time::Duration;

pub use crate::protocol::usb_iss::I2cSpeed;
use crate::protocol::usb_iss::UsbIssError;

/// Register-level access to the chips on one bus. Addresses are 7-bit.
pub trait I2cBus: Send {
    /// Writes `data` to `register` on (the chip auto-increments or not, as it
    /// does). Fails with [`I2cError::Nack`] when the chip does not ACK.
    fn write_register(&mut self, address: u8, register: u8, data: &[u8]) -> Result<(), I2cError>;
    /// Fills `buf` from `register` on, in one transfer (repeated start). An
    /// empty `buf` is no transfer at all.
    fn read_registers(
        &mut self,
        address: u8,
        register: u8,
        buf: &mut [u8],
    ) -> Result<(), I2cError> {
        if buf.is_empty() {
            return Ok(());
        }
        self.read(address, register, buf)
    }
    /// The transfer behind [`I2cBus::read_registers`]; `buf` is not empty.
    fn read(&mut self, address: u8, register: u8, buf: &mut [u8]) -> Result<(), I2cError>;
    /// The bus and its port, for messages: "USB-ISS on /dev/ttyACM0".
    fn describe(&self) -> String;
}

impl<B: I2cBus + ?Sized> I2cBus for Box<B> {
    fn write_register(&mut self, address: u8, register: u8, data: &[u8]) -> Result<(), I2cError> {
        (**self).write_register(address, register, data)
    }
    fn read(&mut self, address: u8, register: u8, buf: &mut [u8]) -> Result<(), I2cError> {
        (**self).read(address, register, buf)
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
}

/// Whether a transfer was reading or writing, for messages.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    Read,
    Write,
}

impl fmt::Display for Access {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Access::Read => "reading",
            Access::Write => "writing",
        })
    }
}

/// Why an I2C transfer failed. Every message names the bus (and so the port)
/// and says what to check.
#[derive(Debug, thiserror::Error)]
pub enum I2cError {
    #[error(
        "{bus}: no ACK from the device at 0x{address:02X} {access} register 0x{register:02X}: \
         check the wiring and the address"
    )]
    Nack {
        bus: String,
        address: u8,
        register: u8,
        access: Access,
    },
    #[error(
        "{bus}: no complete reply to {command} within {} ms ({received} of {expected} bytes): \
         check that the bridge is plugged in and powered",
        waited.as_millis()
    )]
    Timeout {
        bus: String,
        command: String,
        expected: usize,
        received: usize,
        waited: Duration,
    },
    #[error("{bus}: {source}: check the cable; the port is opened again on the next attempt")]
    Io {
        bus: String,
        #[source]
        source: io::Error,
    },
    #[error("{bus}: {source}")]
    BadReply {
        bus: String,
        #[source]
        source: UsbIssError,
    },
    #[error("{bus}: {source}")]
    BadRequest {
        bus: String,
        #[source]
        source: UsbIssError,
    },
    #[error("cannot open {port}: {reason}: {advice}")]
    Open {
        port: String,
        reason: String,
        advice: &'static str,
    },
}

impl I2cError {
    /// True when the bridge itself stopped answering (as opposed to a chip
    /// refusing a transfer): the caller should re-open the port.
    pub fn is_bridge_failure(&self) -> bool {
        matches!(
            self,
            I2cError::Timeout { .. } | I2cError::Io { .. } | I2cError::Open { .. }
        )
    }
}

/// Advice for a port that would not open, by the kind of I/O error.
pub(crate) fn open_advice(kind: io::ErrorKind) -> &'static str {
    match kind {
        io::ErrorKind::NotFound => "is the device plugged in and the path right?",
        io::ErrorKind::PermissionDenied => {
            "add the user to the group that owns the port (often 'dialout' or 'i2c')"
        }
        _ => "check that the device is plugged in and that no other program holds the port",
    }
}
