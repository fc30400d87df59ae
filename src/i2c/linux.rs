//! [`I2cBus`] over Linux i2c-dev (`/dev/i2c-N`), for chips wired straight to
//! the host. A register read is one I2C_RDWR transaction (write the register,
//! repeated start, read), so no other master can slip in between.

use std::io;
use std::path::{Path, PathBuf};

use embedded_hal::i2c::{Error as _, ErrorKind, I2c};
use linux_embedded_hal::i2cdev::linux::LinuxI2CError;
use linux_embedded_hal::{I2CError, I2cdev};

use super::{Access, I2cBus, I2cError, open_advice};

/// An i2c-dev adapter.
pub struct LinuxI2cBus {
    dev: I2cdev,
    path: PathBuf,
}

impl std::fmt::Debug for LinuxI2cBus {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LinuxI2cBus")
            .field("path", &self.path)
            .finish_non_exhaustive()
    }
}

impl LinuxI2cBus {
    /// Opens the adapter at `path` (e.g. `/dev/i2c-1`; `modprobe i2c-dev` if
    /// it is missing).
    pub fn open(path: &Path) -> Result<Self, I2cError> {
        let dev = I2cdev::new(path).map_err(|e| {
            let source = to_io(&e);
            I2cError::Open {
                port: path.display().to_string(),
                reason: source.to_string(),
                advice: open_advice(source.kind()),
            }
        })?;
        Ok(LinuxI2cBus {
            dev,
            path: path.to_path_buf(),
        })
    }

    fn error(&self, address: u8, register: u8, access: Access, e: I2CError) -> I2cError {
        match e.kind() {
            ErrorKind::NoAcknowledge(_) => I2cError::Nack {
                bus: self.describe(),
                address,
                register,
                access,
            },
            _ => I2cError::Io {
                bus: self.describe(),
                source: to_io(e.inner()),
            },
        }
    }
}

fn to_io(e: &LinuxI2CError) -> io::Error {
    match e {
        LinuxI2CError::Errno(n) => io::Error::from_raw_os_error(*n),
        LinuxI2CError::Io(e) => io::Error::new(e.kind(), e.to_string()),
    }
}

impl I2cBus for LinuxI2cBus {
    fn write_register(&mut self, address: u8, register: u8, data: &[u8]) -> Result<(), I2cError> {
        let mut bytes = Vec::with_capacity(1 + data.len());
        bytes.push(register);
        bytes.extend_from_slice(data);
        self.dev
            .write(address, &bytes)
            .map_err(|e| self.error(address, register, Access::Write, e))
    }

    fn read(&mut self, address: u8, register: u8, buf: &mut [u8]) -> Result<(), I2cError> {
        self.dev
            .write_read(address, &[register], buf)
            .map_err(|e| self.error(address, register, Access::Read, e))
    }

    fn describe(&self) -> String {
        format!("i2c-dev {}", self.path.display())
    }
}
